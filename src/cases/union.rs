//! The proposal union of the `mlod-u` cases (issue 32): the refiner sees the proposals of
//! LiDAR-Top (which no drift of the auxiliary LiDARs reaches) together with a fusion case's, so a
//! car that one stage-1 view still sees is never lost; a 3D NMS after refinement
//! ([`crate::refine::UNION_NMS_IOU`]) removes the cars both proposed.

use crate::dataset::Frame;
use crate::pipeline::FusedCloud;
pub use crate::refine::UNION_NMS_IOU;

use crate::detect::{Case, DetectError, Detection, Detector};

/// Several stage-1 detectors' proposals as one list, best score first.
pub struct UnionDetector {
    case: Case,
    parts: Vec<Box<dyn Detector>>,
}

impl UnionDetector {
    /// The union of `parts` (at least one), standing for the union case `case`.
    pub fn new(case: Case, parts: Vec<Box<dyn Detector>>) -> Result<Self, DetectError> {
        if !case.is_union() || parts.is_empty() {
            return Err(DetectError::BadParameter(format!(
                "a proposal union needs a union case and detectors, got {} and {} detectors",
                case.paper_name(),
                parts.len()
            )));
        }
        Ok(Self { case, parts })
    }
}

/// The union of proposal lists: every box, best score first (ties keep the lists' order).
pub fn union_of(lists: &[&[Detection]]) -> Vec<Detection> {
    let mut all: Vec<Detection> = lists.iter().flat_map(|l| l.iter().cloned()).collect();
    all.sort_by(|a, b| b.score.total_cmp(&a.score));
    all
}

impl Detector for UnionDetector {
    fn case(&self) -> Case {
        self.case
    }

    fn categories(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for c in self.parts.iter().flat_map(|p| p.categories()) {
            if !out.contains(&c) {
                out.push(c);
            }
        }
        out
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        let lists = self
            .parts
            .iter()
            .map(|p| p.detect_fused(frame, cloud))
            .collect::<Result<Vec<_>, _>>()?;
        let refs: Vec<&[Detection]> = lists.iter().map(|l| l.as_slice()).collect();
        Ok(union_of(&refs))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Box3d;

    fn det(x: f64, score: f32) -> Detection {
        Detection {
            box3d: Box3d::new([x, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0),
            score,
            category: "car".into(),
        }
    }

    #[test]
    fn union_keeps_every_box_best_first() {
        let a = [det(1.0, 0.9), det(2.0, 0.3)];
        let b = [det(3.0, 0.5), det(4.0, 0.3), det(5.0, 0.1)];
        let u = union_of(&[&a, &b]);
        let xs: Vec<f64> = u.iter().map(|d| d.box3d.center[0]).collect();
        assert_eq!(xs, vec![1.0, 3.0, 2.0, 4.0, 5.0]);
        assert!(UnionDetector::new(Case::MlodI, Vec::new()).is_err());
        assert!(UnionDetector::new(Case::MlodU, Vec::new()).is_err());
    }
}
