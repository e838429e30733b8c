//! Lyft Level 5's official 3D detection metric, computed exactly as the official devkit
//! (lyft-dataset-sdk 0.0.8, `eval/detection/mAP_evaluation.py`) computes it, plus a variant with
//! the true box footprint.
//!
//! - IoU = BEV footprint intersection × height overlap / (volume_a + volume_b − intersection).
//! - Per class, predictions sorted by score (stable: ties keep input order); each is compared with
//!   *all* ground truth of its sample and takes the one of highest IoU (first on ties); it is a TP
//!   only if that IoU is strictly above the threshold and that box is still unclaimed, else a FP.
//! - AP: VOC all-point interpolation with a precision envelope ([`voc_ap`]); mAP is the mean over
//!   the classes of the ground truth (a class without predictions scores 0; prediction classes
//!   absent from the ground truth are ignored); the challenge figure averages thresholds
//!   0.5, 0.55, …, 0.95.
//!
//! **The devkit's footprint quirk.** The devkit builds each footprint from cos = R[0,0] and
//! sin = R[0,1] of the box's rotation matrix R. For a yaw-only rotation R[0,1] = −sin(yaw), so
//! every footprint is the true rectangle turned to heading −yaw about its (correct) centre. Equal
//! boxes still score 1, but offsets are judged in a mirrored orientation: a 4.5 × 1.9 m car
//! displaced 1.5 m along its 30° heading scores IoU 0.166 in the devkit and 0.455 in truth.
//! [`Footprints::Devkit`] reproduces the official numbers (comparable with published Lyft
//! results); [`Footprints::Exact`] uses the true footprint.

use std::collections::HashMap;

use nalgebra::{Quaternion, UnitQuaternion};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::ap::{pr_curve, voc_ap};
use crate::geometry::iou::Footprint;
use crate::geometry::{Box3d, Pose};

/// A box in the devkit's format (global frame). `score` is absent for ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LyftBox {
    pub sample_token: String,
    /// Centre (m), global frame.
    pub translation: [f64; 3],
    /// [w, l, h] (m).
    pub size: [f64; 3],
    /// [w, x, y, z].
    pub rotation: [f64; 4],
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub score: Option<f64>,
}

impl LyftBox {
    /// A base-frame box as a devkit record, given the base → global transform of its sample.
    pub fn from_base(
        sample_token: &str,
        box3d: &Box3d,
        base_to_global: &Pose,
        name: &str,
        score: Option<f64>,
    ) -> Self {
        let g = box3d.transformed(base_to_global);
        let q = g.rotation();
        Self {
            sample_token: sample_token.to_owned(),
            translation: g.center,
            size: g.size_wlh(),
            rotation: [q.w, q.i, q.j, q.k],
            name: name.to_owned(),
            score,
        }
    }

    /// The rotation (normalised, as pyquaternion does before building a matrix).
    pub fn unit_rotation(&self) -> UnitQuaternion<f64> {
        let [w, x, y, z] = self.rotation;
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    }

    fn volume(&self) -> f64 {
        self.size[0] * self.size[1] * self.size[2]
    }

    fn z_range(&self) -> (f64, f64) {
        let h = self.size[2];
        (self.translation[2] - h / 2.0, self.translation[2] + h / 2.0)
    }
}

/// Which footprint the metric uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Footprints {
    /// cos = R[0,0], sin = R[0,1]: the official devkit's (mirrored heading).
    Devkit,
    /// The true footprint: heading atan2(R[1,0], R[0,0]).
    Exact,
}

/// A box prepared for repeated IoU: footprint, vertical extent, volume.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    foot: Footprint,
    z: (f64, f64),
    volume: f64,
}

fn prepare(b: &LyftBox, mode: Footprints) -> Prepared {
    let r = b.unit_rotation().to_rotation_matrix().into_inner();
    let [w, l, _] = b.size;
    let c = [b.translation[0], b.translation[1]];
    let foot = match mode {
        // The devkit's corners are c ± l/2·(cos, sin) ± w/2·(sin, −cos).
        Footprints::Devkit => {
            let (cos, sin) = (r[(0, 0)], r[(0, 1)]);
            Footprint::from_axes(c, [l / 2.0 * cos, l / 2.0 * sin], [w / 2.0 * sin, -w / 2.0 * cos])
        }
        Footprints::Exact => {
            let (sin, cos) = r[(1, 0)].atan2(r[(0, 0)]).sin_cos();
            Footprint::from_axes(c, [l / 2.0 * cos, l / 2.0 * sin], [-w / 2.0 * sin, w / 2.0 * cos])
        }
    };
    Prepared {
        foot,
        z: b.z_range(),
        volume: b.volume(),
    }
}

fn prepared_iou(a: &Prepared, b: &Prepared) -> f64 {
    let h = (a.z.1.min(b.z.1) - a.z.0.max(b.z.0)).max(0.0);
    let inter = h * a.foot.intersection_area(&b.foot);
    let union = a.volume + b.volume - inter;
    if union > 0.0 {
        (inter / union).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The devkit's IoU of two boxes (with the chosen footprint).
pub fn lyft_iou(a: &LyftBox, b: &LyftBox, mode: Footprints) -> f64 {
    prepared_iou(&prepare(a, mode), &prepare(b, mode))
}

/// The official thresholds 0.5, 0.55, …, 0.95 (each the double nearest to its decimal).
pub fn thresholds() -> Vec<f64> {
    (0..10).map(|i| (50 + 5 * i) as f64 / 100.0).collect()
}

/// One class, prepared once and reused over all thresholds.
struct ClassCase {
    /// Number of GT boxes per sample group (a group is one sample's GT of this class).
    group_sizes: Vec<usize>,
    num_gt: usize,
    /// Per prediction in score order: its sample's group (None: no GT there) and its IoU with
    /// each GT of that group.
    rows: Vec<(Option<usize>, Vec<f64>)>,
}

fn prepare_class(gt: &[&LyftBox], preds: &[&LyftBox], mode: Footprints) -> ClassCase {
    let mut group_of: HashMap<&str, usize> = HashMap::new();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (j, g) in gt.iter().enumerate() {
        let k = *group_of.entry(g.sample_token.as_str()).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[k].push(j);
    }
    let gp: Vec<Prepared> = gt.iter().map(|g| prepare(g, mode)).collect();
    let mut order: Vec<usize> = (0..preds.len()).collect();
    // Stable sort, descending score: ties keep the input order (Python's sorted(reverse=True)).
    order.sort_by(|&a, &b| {
        let (sa, sb) = (preds[a].score.unwrap_or(-1.0), preds[b].score.unwrap_or(-1.0));
        sb.partial_cmp(&sa).unwrap_or(std::cmp::Ordering::Equal)
    });
    let rows = order
        .par_iter()
        .map(|&i| {
            let group = group_of.get(preds[i].sample_token.as_str()).copied();
            let p = prepare(preds[i], mode);
            let row = group.map_or_else(Vec::new, |k| {
                groups[k].iter().map(|&j| prepared_iou(&p, &gp[j])).collect()
            });
            (group, row)
        })
        .collect();
    ClassCase {
        group_sizes: groups.iter().map(Vec::len).collect(),
        num_gt: gt.len(),
        rows,
    }
}

/// The devkit's `recall_precision` + `get_ap` for one class at one threshold.
fn class_ap(case: &ClassCase, threshold: f64) -> f64 {
    let mut claimed: Vec<Vec<bool>> = case.group_sizes.iter().map(|&n| vec![false; n]).collect();
    let tp: Vec<bool> = case
        .rows
        .iter()
        .map(|(group, row)| {
            let Some(k) = *group else { return false };
            // np.max / np.argmax: the first maximum.
            let mut best = f64::NEG_INFINITY;
            let mut jmax = 0;
            for (j, &v) in row.iter().enumerate() {
                if v > best {
                    best = v;
                    jmax = j;
                }
            }
            if best > threshold && !claimed[k][jmax] {
                claimed[k][jmax] = true;
                return true;
            }
            false
        })
        .collect();
    let (recall, precision) = pr_curve(&tp, case.num_gt);
    voc_ap(&recall, &precision)
}

/// mAP per threshold and the mean over thresholds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LyftMap {
    /// Threshold → mAP (keys like "0.5", "0.55").
    pub per_threshold: std::collections::BTreeMap<String, f64>,
    #[serde(rename = "mAP")]
    pub map: f64,
    /// Threshold → class → AP.
    pub per_class: std::collections::BTreeMap<String, std::collections::BTreeMap<String, f64>>,
}

/// The devkit's `get_average_precisions` for every threshold, averaged per threshold over the
/// ground-truth classes, then over thresholds.
pub fn lyft_map(gt: &[LyftBox], preds: &[LyftBox], thresholds: &[f64], mode: Footprints) -> LyftMap {
    let mut classes: Vec<&str> = gt.iter().map(|g| g.name.as_str()).collect();
    classes.sort_unstable();
    classes.dedup();
    let cases: Vec<Option<ClassCase>> = classes
        .iter()
        .map(|&c| {
            let g: Vec<&LyftBox> = gt.iter().filter(|b| b.name == c).collect();
            let p: Vec<&LyftBox> = preds.iter().filter(|b| b.name == c).collect();
            (!p.is_empty()).then(|| prepare_class(&g, &p, mode))
        })
        .collect();
    let mut per_threshold = std::collections::BTreeMap::new();
    let mut per_class = std::collections::BTreeMap::new();
    let mut maps = Vec::with_capacity(thresholds.len());
    for &t in thresholds {
        let aps: Vec<f64> = cases
            .iter()
            .map(|c| c.as_ref().map_or(0.0, |case| class_ap(case, t)))
            .collect();
        let m = if aps.is_empty() {
            0.0
        } else {
            aps.iter().sum::<f64>() / aps.len() as f64
        };
        per_threshold.insert(format!("{t}"), m);
        per_class.insert(
            format!("{t}"),
            classes
                .iter()
                .zip(&aps)
                .map(|(c, a)| (c.to_string(), *a))
                .collect(),
        );
        maps.push(m);
    }
    let map = if maps.is_empty() {
        0.0
    } else {
        maps.iter().sum::<f64>() / maps.len() as f64
    };
    LyftMap {
        per_threshold,
        map,
        per_class,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(x: f64, y: f64, yaw: f64, score: Option<f64>, sample: &str) -> LyftBox {
        let (s, c) = (0.5 * yaw).sin_cos();
        LyftBox {
            sample_token: sample.into(),
            translation: [x, y, 1.0],
            size: [1.9, 4.5, 1.6],
            rotation: [c, 0.0, 0.0, s],
            name: "car".into(),
            score,
        }
    }

    #[test]
    fn footprint_quirk_example_of_the_readme() {
        // A 4 × 2 m car displaced 1.5 m along its 30° heading.
        let yaw = 30f64.to_radians();
        let mut a = car(0.0, 0.0, yaw, None, "s");
        let mut b = car(1.5 * yaw.cos(), 1.5 * yaw.sin(), yaw, Some(0.9), "s");
        a.size = [2.0, 4.0, 1.6];
        b.size = a.size;
        // True IoU: (4 − 1.5) / (4 + 1.5) = 5/11.
        let exact = lyft_iou(&a, &b, Footprints::Exact);
        assert!((exact - 5.0 / 11.0).abs() < 1e-12, "{exact}");
        // What lyft-dataset-sdk 0.0.8's Box3D.get_iou printed for the same pair.
        let devkit = lyft_iou(&a, &b, Footprints::Devkit);
        assert!((devkit - 0.16602150570262278).abs() < 1e-12, "{devkit}");
        // Equal boxes and heading 0 agree in both.
        assert!((lyft_iou(&a, &a, Footprints::Devkit) - 1.0).abs() < 1e-12);
        let c = car(0.0, 0.0, 0.0, None, "s");
        let d = car(1.0, 0.2, 0.0, None, "s");
        assert!((lyft_iou(&c, &d, Footprints::Devkit) - lyft_iou(&c, &d, Footprints::Exact)).abs() < 1e-12);
    }

    #[test]
    fn strict_threshold_and_claimed_gt() {
        let gt = vec![car(0.0, 0.0, 0.0, None, "s"), car(10.0, 0.0, 0.0, None, "s")];
        // Highest score: a duplicate of GT 0, then the exact GT 0, then GT 1 exactly.
        let preds = vec![
            car(0.3, 0.0, 0.0, Some(0.9), "s"),
            car(0.0, 0.0, 0.0, Some(0.8), "s"),
            car(10.0, 0.0, 0.0, Some(0.7), "s"),
        ];
        let r = lyft_map(&gt, &preds, &[0.5], Footprints::Devkit);
        // TP, FP (GT 0 claimed), TP: recall .5 .5 1, precision 1 .5 .667 → AP .5 + .5·2/3.
        assert!((r.per_threshold["0.5"] - (0.5 + 0.5 * 2.0 / 3.0)).abs() < 1e-12);
        // IoU exactly 1 is not > 1.
        let r = lyft_map(&gt, &preds, &[1.0], Footprints::Devkit);
        assert_eq!(r.per_threshold["1"], 0.0);
    }

    #[test]
    fn classes_come_from_the_ground_truth() {
        let mut ped = car(5.0, 5.0, 0.0, None, "s");
        ped.name = "pedestrian".into();
        let gt = vec![car(0.0, 0.0, 0.0, None, "s"), ped];
        let mut bus = car(20.0, 0.0, 0.0, Some(0.5), "s");
        bus.name = "bus".into();
        let preds = vec![car(0.0, 0.0, 0.0, Some(0.9), "s"), bus];
        // car AP 1, pedestrian AP 0 (no predictions); bus is not a GT class.
        let r = lyft_map(&gt, &preds, &thresholds(), Footprints::Devkit);
        assert!((r.map - 0.5).abs() < 1e-12);
        assert_eq!(r.per_class["0.95"].len(), 2);
        assert_eq!(thresholds()[1], 0.55);
        assert_eq!(format!("{}", thresholds()[9]), "0.95");
    }
}
