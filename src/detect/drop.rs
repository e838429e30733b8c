//! The `input-drop` ablation: the "straightforward idea" the paper sets aside in §IV-B — remove
//! the points whose tr(Ξ) is above a threshold and run Input Fusion on the rest. Its sensitivity
//! to the threshold is what the paper argues against (`docs/robustness.md`).

use crate::dataset::Frame;
use crate::pipeline::{FusedCloud, FusedLidar};

use super::{Case, DetectError, Detection, Detector};

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

/// Input Fusion on the certain points only.
pub struct DropDetector {
    inner: Box<dyn Detector>,
    pub threshold: f32,
}

impl DropDetector {
    /// Wraps the Input Fusion detector.
    pub fn new(inner: Box<dyn Detector>, threshold: f32) -> Result<Self, DetectError> {
        if inner.case() != Case::Input || !(threshold.is_finite() && threshold >= 0.0) {
            return Err(DetectError::BadParameter(format!(
                "input-drop wraps Input Fusion with a threshold ≥ 0, got {} and {threshold}",
                inner.case().paper_name()
            )));
        }
        Ok(Self { inner, threshold })
    }
}

impl Detector for DropDetector {
    fn case(&self) -> Case {
        Case::InputDrop
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
}
