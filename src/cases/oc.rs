//! The (OC) cases (paper §V-A-4): online calibration by point-to-plane ICP
//! ([`crate::pipeline::calibrate`]), then the wrapped case on the cloud fused with the corrected
//! extrinsics. The wrapped detector is unchanged: the same weights see a better-aligned cloud.

use crate::calib::{IcpConfig, OcPrior};
use crate::dataset::Frame;
use crate::pipeline::{calibrate, FuseParams, FusedCloud};

use crate::detect::{Case, DetectError, Detection, Detector};

/// A detector that calibrates the frame online before detecting.
pub struct OcDetector {
    case: Case,
    inner: Box<dyn Detector>,
    pub config: IcpConfig,
    pub prior: OcPrior,
}

impl OcDetector {
    /// Wraps the detector of `case.without_oc()`; `case` must be an (OC) case.
    pub fn new(
        case: Case,
        inner: Box<dyn Detector>,
        config: IcpConfig,
        prior: OcPrior,
    ) -> Result<Self, DetectError> {
        if !case.is_oc() || inner.case() != case.without_oc() {
            return Err(DetectError::BadParameter(format!(
                "{} cannot wrap {} for online calibration",
                case.paper_name(),
                inner.case().paper_name()
            )));
        }
        config
            .validate()
            .map_err(|e| DetectError::BadParameter(e.to_string()))?;
        Ok(Self {
            case,
            inner,
            config,
            prior,
        })
    }

    /// The calibrated fuse parameters of `frame`: `params` with the online calibration in them
    /// (an existing calibration in `params` is kept: `fuse` checks it belongs to this frame).
    pub fn calibrated_params(&self, frame: &Frame, params: &FuseParams) -> Result<FuseParams, DetectError> {
        let mut p = params.clone();
        if p.calibration.is_none() {
            p.calibration = Some(calibrate(frame, params, &self.config, self.prior)?);
        }
        Ok(p)
    }
}

impl Detector for OcDetector {
    fn case(&self) -> Case {
        self.case
    }

    fn categories(&self) -> Vec<String> {
        self.inner.categories()
    }

    /// `cloud` must have been fused with a calibration (see [`OcDetector::calibrated_params`]);
    /// a drifted cloud is refused rather than detected on as if it were calibrated.
    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        if !frame.auxiliaries.is_empty() && !cloud.lidars.iter().skip(1).any(|l| l.calibrated) {
            return Err(DetectError::BadParameter(format!(
                "{} needs a cloud fused with an online calibration (use detect, or calibrate first)",
                self.case.paper_name()
            )));
        }
        self.inner.detect_fused(frame, cloud)
    }

    fn fuse_params(&self, frame: &Frame, params: &FuseParams) -> Result<FuseParams, DetectError> {
        self.calibrated_params(frame, params)
    }
}
