//! The `input-drop` ablation: the "straightforward idea" the paper sets aside in §IV-B — remove
//! the points whose tr(Ξ) is above a threshold and run Input Fusion on the rest. Its sensitivity
//! to the threshold is what the paper argues against (`docs/robustness.md`).

use crate::dataset::Frame;
use crate::pipeline::{FusedCloud, FusedLidar};

use crate::detect::{Case, DetectError, Detection, Detector};

/// The threshold on tr(Ξ) (m²) chosen on the validation scenes (`docs/robustness.md`).
pub const DROP_TRACE: f32 = 0.1;

/// `cloud` without the points whose tr(Ξ) is above `threshold` (per-LiDAR ranges kept right).
pub fn drop_uncertain(cloud: &FusedCloud, threshold: f32) -> FusedCloud {
    let mut out = FusedCloud::default();
    for l in &cloud.lidars {
        let start = out.x.len();
        for i in l
            .range
            .clone()
            .filter(|&i| i < cloud.len() && cloud.trace[i] <= threshold)
        {
            out.x.push(cloud.x[i]);
            out.y.push(cloud.y[i]);
            out.z.push(cloud.z[i]);
            out.intensity.push(cloud.intensity[i]);
            out.source.push(cloud.source[i]);
            out.trace.push(cloud.trace[i]);
        }
        out.lidars.push(FusedLidar {
            range: start..out.x.len(),
            ..l.clone()
        });
    }
    out
}

/// A fusion case (Input or Result Fusion) on the certain points only (`input-drop`,
/// `result-drop`).
pub struct DropDetector {
    inner: Box<dyn Detector>,
    case: Case,
    pub threshold: f32,
}

impl DropDetector {
    /// Wraps the Input or Result Fusion detector.
    pub fn new(inner: Box<dyn Detector>, threshold: f32) -> Result<Self, DetectError> {
        let case = inner.case().with_drop();
        match case {
            Some(case) if threshold.is_finite() && threshold >= 0.0 => Ok(Self {
                inner,
                case,
                threshold,
            }),
            _ => Err(DetectError::BadParameter(format!(
                "a drop case wraps Input or Result Fusion with a threshold ≥ 0, got {} and {threshold}",
                inner.case().paper_name()
            ))),
        }
    }
}

impl Detector for DropDetector {
    fn case(&self) -> Case {
        self.case
    }

    fn categories(&self) -> Vec<String> {
        self.inner.categories()
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        self.inner
            .detect_fused(frame, &drop_uncertain(cloud, self.threshold))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::LidarChannel;

    #[test]
    fn drops_exactly_the_uncertain_points_and_keeps_ranges() {
        let mut c = FusedCloud::default();
        for (i, t) in [0.01f32, 0.2, 0.03, 0.06, 0.05].iter().enumerate() {
            c.x.push(i as f32);
            c.y.push(0.0);
            c.z.push(0.0);
            c.intensity.push(1.0);
            c.source.push(if i < 2 { 0 } else { 1 });
            c.trace.push(*t);
        }
        let lidar = FusedLidar::identity;
        c.lidars = vec![
            lidar(LidarChannel::Top, 0..2),
            lidar(LidarChannel::FrontLeft, 2..5),
        ];
        let d = drop_uncertain(&c, 0.05);
        assert_eq!(d.x, vec![0.0, 2.0, 4.0]);
        assert_eq!(d.lidars[0].range, 0..1);
        assert_eq!(d.lidars[1].range, 1..3);
        assert_eq!(d.source, vec![0, 1, 1]);
    }

    /// A stand-in detector of a given case (constructors only look at the case).
    struct Fake(Case);

    impl Detector for Fake {
        fn case(&self) -> Case {
            self.0
        }
        fn categories(&self) -> Vec<String> {
            vec!["car".into()]
        }
        fn detect_fused(&self, _: &Frame, _: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
            Ok(Vec::new())
        }
    }

    #[test]
    fn wraps_input_and_result_fusion_only() {
        let wrap = |c: Case, t: f32| DropDetector::new(Box::new(Fake(c)), t).map(|d| d.case());
        assert_eq!(wrap(Case::Input, 0.1).unwrap(), Case::InputDrop);
        assert_eq!(wrap(Case::Result, 0.1).unwrap(), Case::ResultDrop);
        for bad in [Case::Feature, Case::Top, Case::MlodI, Case::InputDrop] {
            assert!(wrap(bad, 0.1).is_err(), "{bad}");
        }
        for t in [-0.1, f32::NAN, f32::INFINITY] {
            assert!(wrap(Case::Result, t).is_err(), "{t}");
        }
        // The cases built on them: what each refines and which stage 1 runs on the kept points.
        assert_eq!(Case::ResultDrop.dropped(), Some(Case::Result));
        assert_eq!(Case::Input.with_drop(), Some(Case::InputDrop));
        assert_eq!(Case::Feature.with_drop(), None);
        assert_eq!(
            Case::MlodIrDrop.proposal_cases(),
            vec![Case::ResultDrop, Case::InputDrop]
        );
        assert!(Case::MlodIrDrop.is_union() && Case::MlodIrDrop.is_mlod());
        assert_eq!(Case::ResultDrop.refined(), None);
        assert_eq!(Case::MlodIrDrop.stage1(), Case::ResultDrop);
        // result-drop is a part of mlod-ir-drop only: not listed, not a name the CLI takes.
        assert!(!Case::LISTED.contains(&Case::ResultDrop));
        assert!("result-drop".parse::<Case>().is_err());
        let c = Case::MlodIrDrop;
        assert_eq!(c.as_str().parse::<Case>().unwrap(), c);
        assert!(Case::BEYOND.contains(&c) && Case::LISTED.contains(&c));
    }
}
