//! An MLOD case as one detector: a stage-1 detector (or a proposal union) followed by the
//! stage-2 refiner (paper §IV-B), fusing the frame once for both.

use std::sync::Arc;

use crate::dataset::Frame;
use crate::detect::{Case, DetectError, Detection, Detector};
use crate::pipeline::{fuse, FuseParams, FusedCloud};
use crate::refine::{Decoding, MlodRun, Refined, Refiner};

/// An MLOD case: a fusion detector followed by the refiner.
pub struct Mlod {
    case: Case,
    stage1: Box<dyn Detector>,
    refiner: Arc<Refiner>,
}

impl Mlod {
    pub fn new(case: Case, stage1: Box<dyn Detector>, refiner: Arc<Refiner>) -> Self {
        Self {
            case,
            stage1,
            refiner,
        }
    }

    /// Makes this case decode as `d` says (false, and nothing changed, when its refiner is
    /// shared with another holder). `mlod train tune-refiner` runs without NMS this way, so that
    /// [`crate::refine::redecode`] sees every refined box.
    pub fn set_decoding(&mut self, d: Decoding) -> bool {
        match Arc::get_mut(&mut self.refiner) {
            Some(r) => {
                r.decoding = d;
                true
            }
            None => false,
        }
    }

    /// The refiner it runs.
    pub fn refiner(&self) -> &Refiner {
        &self.refiner
    }

    /// Proposals, refinements and the cloud of one frame (fused once, for both stages).
    pub fn run(&self, frame: &Frame, params: &FuseParams) -> Result<MlodRun, DetectError> {
        let cloud = fuse(frame, params)?;
        let (proposals, refined) = self.run_fused(frame, &cloud)?;
        Ok(MlodRun {
            proposals,
            refined,
            cloud,
        })
    }

    /// Stage 1's proposals on `cloud` and their refinements.
    fn run_fused(
        &self,
        frame: &Frame,
        cloud: &FusedCloud,
    ) -> Result<(Vec<Detection>, Vec<Refined>), DetectError> {
        let proposals = self.stage1.detect_fused(frame, cloud)?;
        let refined = self
            .refiner
            .refine(cloud, &proposals)
            .map_err(|e| DetectError::Refiner(e.to_string()))?;
        Ok((proposals, refined))
    }
}

impl Detector for Mlod {
    fn case(&self) -> Case {
        self.case
    }

    fn categories(&self) -> Vec<String> {
        self.stage1.categories()
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        let (_, refined) = self.run_fused(frame, cloud)?;
        Ok(refined.into_iter().map(|r| r.detection).collect())
    }
}
