//! The cases as detectors: the factory that builds any case of the case table
//! ([`crate::detect::case::TABLE`]) from a models folder by its row's [`Build`], and the
//! wrappers it composes: the ground gate, dropping uncertain points, the proposal union, online
//! calibration (OC) and the MLOD refiner ([`Mlod`]). An external case (`ext:NAME`) comes from
//! [`crate::external`].

pub mod drop;
pub mod ground_gate;
pub mod mlod;
pub mod oc;
pub mod run;
pub mod union;

use std::path::Path;
use std::sync::Arc;

use crate::calib::{IcpConfig, OcPrior};
use crate::detect::model::{load_detector_with, Voting};
use crate::detect::{Build, Case, DetectError, Detector};
use crate::refine::Refiner;

pub use mlod::Mlod;
use oc::OcDetector;
use union::UnionDetector;

/// The shipped detector of any case (stage 1, or MLOD with the folder's refiner), decoding as the
/// manifest says, with the caller's box voting in stage 1.
pub fn load_detector(dir: &Path, case: Case, voting: Voting) -> Result<Box<dyn Detector>, DetectError> {
    load_detector_oc(
        dir,
        case,
        voting,
        &IcpConfig::default(),
        OcPrior::default(),
        drop::DROP_TRACE,
    )
}

/// [`load_detector`] with the folder's voting, behind the ground gate `gate` gives its case (the
/// folder's own for a stage-1 case with `GateChoice::Manifest`): what the window and the failure
/// scan run.
pub fn load_gated(
    dir: &Path,
    case: Case,
    gate: ground_gate::GateChoice,
) -> Result<Box<dyn Detector>, DetectError> {
    ground_gate::gated(load_detector(dir, case, Voting::Manifest)?, gate, dir)
}

/// [`load_detector`] with the online calibration's settings of an (OC) case and the threshold
/// of the cases that drop uncertain points: the case's row says how it is built.
pub fn load_detector_oc(
    dir: &Path,
    case: Case,
    voting: Voting,
    icp: &IcpConfig,
    prior: OcPrior,
    drop_trace: f32,
) -> Result<Box<dyn Detector>, DetectError> {
    match case.build() {
        Build::Oc(inner) => {
            let inner = load_detector_oc(dir, inner, voting, icp, prior, drop_trace)?;
            Ok(Box::new(OcDetector::new(case, inner, *icp, prior)?))
        }
        Build::Refine { .. } => Ok(Box::new(load_mlod_with(dir, case, voting, drop_trace)?)),
        _ => load_stage1(dir, case, voting, drop_trace),
    }
}

/// A stage-1 case: a network of the folder, Result Fusion, a "certain points only" case
/// wrapping the fusion case it drops points for, or an external detector.
fn load_stage1(
    dir: &Path,
    case: Case,
    voting: Voting,
    drop_trace: f32,
) -> Result<Box<dyn Detector>, DetectError> {
    if let Case::Ext(_) = case {
        return Ok(Box::new(crate::external::load(case)?));
    }
    match case.build() {
        Build::Drop(base) => {
            let inner = load_detector_with(dir, base, voting)?;
            Ok(Box::new(drop::DropDetector::new(inner, drop_trace)?))
        }
        Build::Network | Build::ResultFusion => load_detector_with(dir, case, voting),
        Build::Oc(_) | Build::Refine { .. } => Err(DetectError::BadParameter(format!(
            "{} is not a stage-1 case",
            case.paper_name()
        ))),
    }
}

/// An MLOD case of a models folder (its stage-1 detector and the folder's refiner).
pub fn load_mlod(dir: &Path, case: Case, voting: Voting) -> Result<Mlod, DetectError> {
    load_mlod_with(dir, case, voting, drop::DROP_TRACE)
}

/// [`load_mlod`] with the tr(Ξ) threshold of a stage 1 that drops uncertain points
/// (`mlod-ir-drop`).
pub fn load_mlod_with(dir: &Path, case: Case, voting: Voting, drop_trace: f32) -> Result<Mlod, DetectError> {
    if !case.is_mlod() || case.is_oc() {
        return Err(DetectError::BadParameter(format!(
            "{} is not an MLOD case",
            case.paper_name()
        )));
    }
    let stage1 = if case.is_union() {
        let parts = case
            .proposal_cases()
            .into_iter()
            .map(|c| load_stage1(dir, c, voting, drop_trace))
            .collect::<Result<Vec<_>, _>>()?;
        Box::new(UnionDetector::new(case, parts)?)
    } else {
        load_stage1(dir, case.stage1(), voting, drop_trace)?
    };
    Ok(Mlod::new(case, stage1, Arc::new(load_refiner(dir, case)?)))
}

/// The folder's refiner for an MLOD case (with or without tr(Ξ)), decoding as that case does
/// (NMS after refinement for a union case).
pub fn load_refiner(dir: &Path, case: Case) -> Result<Refiner, DetectError> {
    let mut refiner =
        Refiner::load_shipped_for(dir, case).map_err(|e| DetectError::Refiner(e.to_string()))?;
    refiner.decoding = refiner.decoding.for_case(case);
    Ok(refiner)
}
