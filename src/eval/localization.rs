//! How well matched detections are localised: the residual of each true positive against its
//! ground truth (centre along and across the true heading, height, size, yaw) and, per category,
//! the mean absolute residuals, the mean signed ones (bias), and the Pearson correlation of
//! predicted against true length, width and height.
//!
//! Why: at IoU ≥ 0.7 a car is found or missed by a few centimetres, so AP alone cannot say whether
//! a detector lacks the points or the regression. A size correlation near 0 with a mean error
//! near 0 means the network predicts the average box, whatever the points show.
//!
//! [`Fix`] and [`with_truth`] answer "what would AP be if this residual were zero": every
//! prediction matched under the per-box rule gets that part of its box from its ground truth, and
//! AP is computed again on the edited predictions (the matching at each AP threshold runs anew).

use serde::Serialize;

use crate::geometry::{Box3d, Detection};

/// Which part of a matched prediction's box is replaced by its ground truth's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fix {
    /// Nothing: the AP as evaluated.
    Nothing,
    /// Length, width and height.
    Size,
    /// The centre's x and y.
    BevCentre,
    /// The centre's z and the height.
    Vertical,
    /// The yaw.
    Yaw,
    /// The whole box: what is left is finding the object and ranking it.
    All,
}

impl Fix {
    pub const ALL: [Fix; 6] = [
        Fix::Nothing,
        Fix::Size,
        Fix::BevCentre,
        Fix::Vertical,
        Fix::Yaw,
        Fix::All,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Fix::Nothing => "as predicted",
            Fix::Size => "true l, w, h",
            Fix::BevCentre => "true x, y",
            Fix::Vertical => "true z, h",
            Fix::Yaw => "true yaw",
            Fix::All => "true box",
        }
    }
}

/// `pred` with the part `fix` names taken from `gt`.
pub fn with_truth(pred: &Box3d, gt: &Box3d, fix: Fix) -> Box3d {
    let mut b = *pred;
    match fix {
        Fix::Nothing => {}
        Fix::Size => b.size_lwh = gt.size_lwh,
        Fix::BevCentre => {
            b.center[0] = gt.center[0];
            b.center[1] = gt.center[1];
        }
        Fix::Vertical => {
            b.center[2] = gt.center[2];
            b.size_lwh[2] = gt.size_lwh[2];
        }
        Fix::Yaw => b.yaw = gt.yaw,
        Fix::All => b = *gt,
    }
    b
}

/// Prediction minus ground truth for one matched pair, in the ground truth's heading frame (m, rad).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct BoxError {
    /// Centre offset along the true heading.
    pub along: f64,
    /// Centre offset across the true heading (to its left).
    pub lateral: f64,
    /// Centre height offset.
    pub dz: f64,
    /// Length, width and height differences.
    pub dl: f64,
    pub dw: f64,
    pub dh: f64,
    /// Yaw difference modulo π in (−π/2, π/2]: a box turned by π covers the same space.
    pub dyaw: f64,
}

impl BoxError {
    pub fn between(pred: &Box3d, gt: &Box3d) -> Self {
        let (s, c) = gt.yaw.sin_cos();
        let d = [
            pred.center[0] - gt.center[0],
            pred.center[1] - gt.center[1],
            pred.center[2] - gt.center[2],
        ];
        let pi = std::f64::consts::PI;
        let mut dyaw = (pred.yaw - gt.yaw).rem_euclid(pi);
        if dyaw > 0.5 * pi {
            dyaw -= pi;
        }
        Self {
            along: c * d[0] + s * d[1],
            lateral: -s * d[0] + c * d[1],
            dz: d[2],
            dl: pred.size_lwh[0] - gt.size_lwh[0],
            dw: pred.size_lwh[1] - gt.size_lwh[1],
            dh: pred.size_lwh[2] - gt.size_lwh[2],
            dyaw,
        }
    }

    fn to_array(self) -> [f64; 7] {
        [
            self.along,
            self.lateral,
            self.dz,
            self.dl,
            self.dw,
            self.dh,
            self.dyaw,
        ]
    }

    fn from_array(a: [f64; 7]) -> Self {
        Self {
            along: a[0],
            lateral: a[1],
            dz: a[2],
            dl: a[3],
            dw: a[4],
            dh: a[5],
            dyaw: a[6],
        }
    }
}

/// The localisation of one category's matched pairs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LocalizationSummary {
    pub category: String,
    /// Matched (prediction, ground truth) pairs.
    pub matched: usize,
    /// Mean of |prediction − ground truth| per residual.
    pub mean_abs: BoxError,
    /// Mean of prediction − ground truth per residual.
    pub bias: BoxError,
    /// Pearson correlation of predicted and true length, width, height; `None` where either side
    /// does not vary (fewer than 3 pairs, or a constant).
    pub size_corr: [Option<f64>; 3],
    /// Standard deviation of the true and of the predicted length, width, height (m).
    pub size_std_true: [f64; 3],
    pub size_std_pred: [f64; 3],
}

/// Summarises matched pairs (prediction, ground truth) per category, in first-seen order.
pub fn summarize<'a>(
    pairs: impl IntoIterator<Item = (&'a Detection, &'a Detection)>,
) -> Vec<LocalizationSummary> {
    let mut groups: Vec<(String, Vec<(&Box3d, &Box3d)>)> = Vec::new();
    for (p, g) in pairs {
        match groups.iter_mut().find(|(c, _)| *c == g.category) {
            Some((_, v)) => v.push((&p.box3d, &g.box3d)),
            None => groups.push((g.category.clone(), vec![(&p.box3d, &g.box3d)])),
        }
    }
    groups
        .into_iter()
        .map(|(category, v)| {
            let n = v.len() as f64;
            let mut abs = [0.0; 7];
            let mut sum = [0.0; 7];
            for (p, g) in &v {
                let e = BoxError::between(p, g).to_array();
                for k in 0..7 {
                    abs[k] += e[k].abs() / n;
                    sum[k] += e[k] / n;
                }
            }
            let mut size_corr = [None; 3];
            let mut size_std_true = [0.0; 3];
            let mut size_std_pred = [0.0; 3];
            for k in 0..3 {
                let pr: Vec<f64> = v.iter().map(|(p, _)| p.size_lwh[k]).collect();
                let gt: Vec<f64> = v.iter().map(|(_, g)| g.size_lwh[k]).collect();
                let (c, sp, sg) = pearson(&pr, &gt);
                size_corr[k] = c;
                size_std_pred[k] = sp;
                size_std_true[k] = sg;
            }
            LocalizationSummary {
                category,
                matched: v.len(),
                mean_abs: BoxError::from_array(abs),
                bias: BoxError::from_array(sum),
                size_corr,
                size_std_true,
                size_std_pred,
            }
        })
        .collect()
}

/// (correlation, std of a, std of b); the correlation is `None` below 3 values or when a side is
/// constant (std below 1e-9).
fn pearson(a: &[f64], b: &[f64]) -> (Option<f64>, f64, f64) {
    let n = a.len().min(b.len());
    if n == 0 {
        return (None, 0.0, 0.0);
    }
    let nf = n as f64;
    let ma = a.iter().take(n).sum::<f64>() / nf;
    let mb = b.iter().take(n).sum::<f64>() / nf;
    let (mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b).take(n) {
        let (dx, dy) = (x - ma, y - mb);
        saa += dx * dx;
        sbb += dy * dy;
        sab += dx * dy;
    }
    let (sa, sb) = ((saa / nf).sqrt(), (sbb / nf).sqrt());
    let corr = (n >= 3 && sa > 1e-9 && sb > 1e-9).then(|| (sab / (saa * sbb).sqrt()).clamp(-1.0, 1.0));
    (corr, sa, sb)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(center: [f64; 3], size: [f64; 3], yaw: f64) -> Detection {
        Detection {
            box3d: Box3d::new(center, size, yaw),
            score: 0.9,
            category: "car".into(),
        }
    }

    #[test]
    fn residuals_are_in_the_true_heading_frame() {
        let half_pi = std::f64::consts::FRAC_PI_2;
        let gt = Box3d::new([10.0, 5.0, -1.0], [4.5, 1.9, 1.6], half_pi);
        // 0.3 m further along +y (the heading), 0.1 m towards −x (its left), turned by π + 0.02.
        let p = Box3d::new(
            [9.9, 5.3, -0.9],
            [4.7, 1.8, 1.6],
            half_pi + std::f64::consts::PI + 0.02,
        );
        let e = BoxError::between(&p, &gt);
        assert!(
            (e.along - 0.3).abs() < 1e-12 && (e.lateral - 0.1).abs() < 1e-12,
            "{e:?}"
        );
        assert!((e.dz - 0.1).abs() < 1e-12);
        assert!((e.dl - 0.2).abs() < 1e-12 && (e.dw + 0.1).abs() < 1e-12 && e.dh.abs() < 1e-12);
        assert!((e.dyaw - 0.02).abs() < 1e-9, "{}", e.dyaw);
    }

    #[test]
    fn a_detector_that_predicts_the_mean_size_has_no_size_correlation() {
        let lengths = [4.2, 4.5, 4.8, 5.0];
        let gts: Vec<Detection> = lengths
            .iter()
            .enumerate()
            .map(|(i, &l)| det([i as f64 * 10.0, 0.0, 0.0], [l, 1.9, 1.6], 0.0))
            .collect();
        let exact: Vec<Detection> = gts.clone();
        let mean: Vec<Detection> = gts
            .iter()
            .map(|g| det(g.box3d.center, [4.625, 1.9, 1.6], 0.0))
            .collect();
        let s = summarize(exact.iter().zip(&gts));
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].matched, 4);
        assert!((s[0].size_corr[0].unwrap() - 1.0).abs() < 1e-12);
        assert!(s[0].mean_abs.dl.abs() < 1e-12);
        // Width and height never vary: no correlation to report.
        assert_eq!(s[0].size_corr[1], None);
        let m = summarize(mean.iter().zip(&gts));
        assert_eq!(m[0].size_corr[0], None);
        assert!(m[0].bias.dl.abs() < 1e-12, "the mean size has no bias");
        assert!((m[0].mean_abs.dl - 0.275).abs() < 1e-12, "{}", m[0].mean_abs.dl);
        assert!((m[0].size_std_true[0] - 0.3031).abs() < 1e-3 && m[0].size_std_pred[0] < 1e-12);
    }

    #[test]
    fn with_truth_replaces_only_the_named_part() {
        let gt = Box3d::new([10.0, 5.0, -1.0], [4.5, 1.9, 1.6], 0.2);
        let p = Box3d::new([10.3, 4.9, -0.9], [4.7, 1.8, 1.5], 0.25);
        assert_eq!(with_truth(&p, &gt, Fix::Nothing), p);
        assert_eq!(with_truth(&p, &gt, Fix::All), gt);
        let s = with_truth(&p, &gt, Fix::Size);
        assert_eq!((s.center, s.size_lwh, s.yaw), (p.center, gt.size_lwh, p.yaw));
        let c = with_truth(&p, &gt, Fix::BevCentre);
        assert_eq!((c.center, c.size_lwh), ([10.0, 5.0, -0.9], p.size_lwh));
        let v = with_truth(&p, &gt, Fix::Vertical);
        assert_eq!((v.center, v.size_lwh), ([10.3, 4.9, -1.0], [4.7, 1.8, 1.6]));
        let y = with_truth(&p, &gt, Fix::Yaw);
        assert_eq!((y.center, y.yaw), (p.center, gt.yaw));
    }

    #[test]
    fn categories_are_summarised_separately() {
        let a = det([0.0; 3], [4.5, 1.9, 1.6], 0.0);
        let mut b = det([0.0; 3], [0.8, 0.6, 1.7], 0.0);
        b.category = "pedestrian".into();
        let s = summarize([(&a, &a), (&b, &b), (&a, &a)]);
        let names: Vec<(&str, usize)> = s.iter().map(|x| (x.category.as_str(), x.matched)).collect();
        assert_eq!(names, vec![("car", 2), ("pedestrian", 1)]);
    }
}
