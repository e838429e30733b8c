//! How a case runs on a dataset: the options every front end shares (the CLI's `mlod detect` and
//! `mlod eval --case`, the Python package) and the loop over samples, so that each gives the same
//! boxes for the same inputs by construction.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use rayon::prelude::*;

use crate::calib::{IcpConfig, OcPrior};
use crate::dataset::{Dataset, Frame};
use crate::detect::model::Voting;
use crate::detect::weights::default_models_dir;
use crate::detect::{Case, DetectError, Detection, Detector};
use crate::pipeline::FuseParams;
use crate::uncertainty::Perturbation;

use super::ground_gate::{gated, GateChoice};

/// Which detector of a models folder runs, on which perturbation, decoded how.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOptions {
    /// α of the perturbation injected into the auxiliary LiDARs (one draw for every sample).
    pub alpha: f64,
    /// Seed of the perturbation draw.
    pub seed: u64,
    /// Models folder with manifest.json (`None`: the shipped one).
    pub models: Option<PathBuf>,
    pub vote_iou: Voting,
    /// (OC) cases: the uncertainty the calibrated LiDARs' points carry into the refiner.
    pub oc_prior: OcPrior,
    /// `input-drop`, `mlod-ir-drop`: the tr(Ξ) threshold (m²).
    pub drop_trace: f32,
    /// Every point's intensity replaced by this before the detector runs.
    pub set_intensity: Option<f32>,
    pub ground_gate: GateChoice,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            alpha: 0.0,
            seed: 0,
            models: None,
            vote_iou: Voting::Manifest,
            oc_prior: OcPrior::default(),
            drop_trace: super::drop::DROP_TRACE,
            set_intensity: None,
            ground_gate: GateChoice::Manifest,
        }
    }
}

/// What a run over samples noticed besides the boxes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunNotes {
    /// Samples lacking LiDARs the case reads.
    pub lacking: usize,
    /// The note of the first such sample (in token order).
    pub first: Option<String>,
}

impl RunOptions {
    /// The models folder asked for, or the shipped one.
    pub fn models_dir(&self) -> PathBuf {
        self.models.clone().unwrap_or_else(default_models_dir)
    }

    /// The perturbation asked for, as fuse parameters (an absurd α is an error).
    pub fn fuse_params(&self) -> Result<FuseParams, DetectError> {
        Ok(FuseParams {
            perturbation: Perturbation::new(self.alpha, self.seed)
                .map_err(crate::pipeline::PipelineError::from)?,
            ..Default::default()
        })
    }

    /// `set_intensity`: every LiDAR's intensities replaced.
    pub fn apply_intensity(&self, frame: &mut Frame) {
        if let Some(v) = self.set_intensity {
            frame.set_intensity(v);
        }
    }

    /// The detector of `case` from the models folder, with the decoding asked for and behind the
    /// ground gate. An external case must have been defined ([`crate::external::define`]).
    pub fn load(&self, case: Case) -> Result<Box<dyn Detector>, DetectError> {
        let dir = self.models_dir();
        let detector = super::load_detector_oc(
            &dir,
            case,
            self.vote_iou,
            &IcpConfig::default(),
            self.oc_prior,
            self.drop_trace,
        )?;
        gated(detector, self.ground_gate, &dir)
    }

    /// Runs `detector` (of `case`) over `tokens`, samples in parallel; `done` is called once per
    /// finished sample (a progress bar). The error names the sample.
    pub fn detect_samples(
        &self,
        dataset: &Dataset,
        tokens: &[String],
        detector: &dyn Detector,
        case: Case,
        done: &(dyn Fn() + Sync),
    ) -> Result<(HashMap<String, Vec<Detection>>, RunNotes), DetectError> {
        let params = self.fuse_params()?;
        let lacking = AtomicUsize::new(0);
        let first: Mutex<Option<(String, String)>> = Mutex::new(None);
        let dets = tokens
            .par_iter()
            .map(|tok| -> Result<(String, Vec<Detection>), DetectError> {
                let mut frame = dataset.frame(tok)?;
                self.apply_intensity(&mut frame);
                if let Some(note) = case.missing_lidars_note(&frame) {
                    lacking.fetch_add(1, Ordering::Relaxed);
                    if let Ok(mut f) = first.lock() {
                        if f.as_ref().is_none_or(|(t, _)| tok < t) {
                            *f = Some((tok.clone(), note));
                        }
                    }
                }
                let d = detector
                    .detect(&frame, &params)
                    .map_err(|e| DetectError::Sample {
                        case: case.paper_name().to_string(),
                        sample: tok.clone(),
                        source: Box::new(e),
                    })?;
                done();
                Ok((tok.clone(), d))
            })
            .collect::<Result<HashMap<_, _>, _>>()?;
        let notes = RunNotes {
            lacking: lacking.into_inner(),
            first: first.into_inner().ok().flatten().map(|(_, n)| n),
        };
        Ok((dets, notes))
    }
}

/// A sample's detections as `mlod detect --json` prints them (base frame).
pub fn detections_json(token: &str, case: Case, dets: &[Detection]) -> serde_json::Value {
    serde_json::json!({
        "sample_token": token,
        "case": case,
        "frame": "base (LIDAR_TOP)",
        "detections": dets.iter().map(|d| serde_json::json!({
            "center": d.box3d.center,
            "size_lwh": d.box3d.size_lwh,
            "yaw": d.box3d.yaw,
            "score": d.score,
            "category": d.category,
        })).collect::<Vec<_>>(),
    })
}
