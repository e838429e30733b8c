//! Stage-1 detectors (paper §IV-A): LiDAR-Top/Left/Right, Input, Feature and Result Fusion, behind
//! one [`Detector`] trait, with their training and their shipped weights.
//!
//! How it is cut (OpenPCDet's stage order):
//! - [`voxel`]: points in the base frame → height-compressed BEV (SECOND v1.5 mean-point FLN:
//!   in-voxel mean x, y, z and density per voxel).
//! - [`net`]: 2D middle layers (one branch per LiDAR in Feature Fusion, max-fused, eq. 10), SECOND's
//!   RPN and heads, focal / smooth-L1 / direction losses.
//! - [`infer`]: the same network folded for inference (BatchNorm in the weights, HWC maps, one
//!   gemm per band of rows, in parallel): what every loaded model runs; candle's forward is kept
//!   for training.
//! - [`anchors`]: anchors, target assignment, SECOND's box coding.
//! - [`model`]: a trained network + its configuration → [`Detection`]s (decoding, NMS), the
//!   [`Detector`] implementations of every [`Case`], Result Fusion (eq. 11) with temperature
//!   scaling.
//! - [`weights`]: safetensors files with their configuration, sha256-checked through
//!   `assets/models/manifest.json`.
//! - [`gt_sampling`]: SECOND's ground-truth (dataset) sampling for training.
//! - [`train`]: the training loop (§V-A-5 augmentation, AdamW, resumable checkpoints, loss CSV) and
//!   the temperature calibration of Result Fusion.

pub mod anchors;
pub mod calibrate;
pub mod checkpoint;
pub mod config;
pub mod drop;
pub mod external;
pub mod fastconv;
pub mod ground_gate;
pub mod gt_sampling;
pub mod infer;
pub mod model;
pub mod native;
pub mod net;
pub mod oc;
pub mod optim;
pub mod train;
pub mod transfer_aug;
pub mod union;
pub mod voxel;
pub mod warm_start;
pub mod weights;

use serde::{Deserialize, Serialize};

use crate::dataset::{Frame, LidarChannel};
use crate::pipeline::{FuseParams, FusedCloud};

/// A detector's output: a base-frame box, its confidence in [0, 1] (calibrated by temperature
/// scaling in Result Fusion) and its Lyft category.
pub use crate::geometry::Detection;
pub use model::{ModelConfig, ResultFusion, Stage1Model};
pub use weights::{Manifest, ModelEntry};

/// The stage-1 cases of the paper (§V-A-4).
///
/// Written as its lowercase name ([`Case::as_str`]) on the command line, in JSON and in file
/// names; `ext:NAME` and `mlod-ext:NAME` name a detector in another process ([`external`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Case {
    /// LiDAR-Top: the primary LiDAR alone.
    Top,
    /// LiDAR-Left: LIDAR_FRONT_LEFT alone, in the base frame.
    Left,
    /// LiDAR-Right: LIDAR_FRONT_RIGHT alone, in the base frame.
    Right,
    /// Input Fusion: all LiDARs' points, one network.
    Input,
    /// Feature Fusion: one middle-layer branch per LiDAR, max-fused BEV features, one RPN.
    Feature,
    /// Result Fusion: the three single-LiDAR detectors, calibrated, merged by 3D NMS.
    Result,
    /// MLOD-I: Input Fusion's proposals refined by the stage-2 network (`crate::refine`).
    MlodI,
    /// MLOD-F: Feature Fusion + the refiner.
    MlodF,
    /// MLOD-R: Result Fusion + the refiner.
    MlodR,
    /// Input Fusion (OC): online calibration (point-to-plane ICP, `crate::calib`) first, then
    /// Input Fusion on the corrected cloud.
    InputOc,
    /// Feature Fusion (OC).
    FeatureOc,
    /// Result Fusion (OC).
    ResultOc,
    /// MLOD-I (OC): online calibration, then MLOD-I.
    MlodIOc,
    /// MLOD-F (OC).
    MlodFOc,
    /// MLOD-R (OC).
    MlodROc,
    /// The "straightforward idea" of §IV-B, an ablation: Input Fusion on the fused cloud without
    /// its uncertain points (tr(Ξ) above a threshold chosen on the validation scenes, `drop`).
    InputDrop,
    /// An ablation: MLOD-I with a refiner trained identically (same data, seed and steps) but
    /// without the tr(Ξ) point feature (`mlod train refiner --no-trace`): what the uncertainty
    /// channel itself brings.
    MlodINoTrace,
    /// Beyond the paper (issue 32): Input Fusion trained with the perturbation injected (α drawn
    /// as the refiner's training draws it), so its proposals survive drift.
    InputPa,
    /// Beyond the paper: Input Fusion whose voxel features also hold the mean tr(Ξ) of each
    /// voxel's points, trained under drift: the network learns how far to trust each point.
    InputTr,
    /// The refiner on [`Case::InputPa`]'s proposals.
    MlodIPa,
    /// The refiner on [`Case::InputTr`]'s proposals.
    MlodITr,
    /// The refiner on the union of LiDAR-Top's and Input Fusion's proposals, 3D NMS after it: a
    /// car that the calibration-free LiDAR-Top still sees is never lost.
    MlodU,
    /// The refiner on the union of LiDAR-Top's and [`Case::InputTr`]'s proposals, 3D NMS after.
    MlodUTr,
    /// The refiner on [`Case::InputDrop`]'s proposals (Input Fusion without its uncertain points):
    /// the refiner still sees every point, with its tr(Ξ).
    MlodIDrop,
    /// Result Fusion on the certain points: the three single-LiDAR detectors on the fused cloud
    /// without the points whose tr(Ξ) is above the threshold of [`Case::InputDrop`].
    ResultDrop,
    /// The refiner (on every point, with its tr(Ξ)) on [`Case::ResultDrop`]'s proposals: MLOD-R
    /// when calibrated, LiDAR-Top plus what the auxiliaries still see certainly under drift.
    MlodRDrop,
    /// The refiner on the union of [`Case::ResultDrop`]'s and [`Case::InputDrop`]'s proposals,
    /// merged after refinement: two fusion schemes' views of the certain points.
    MlodIrDrop,
    /// `ext:NAME`: the detector NAME, served by another process over `mlod-detector/1`
    /// ([`external`]). Holds the whole case name (`ext:NAME`), interned, so a case stays `Copy`.
    Ext(&'static str),
    /// `mlod-ext:NAME`: the shipped refiner on the proposals of the external detector NAME (holds
    /// `mlod-ext:NAME`, interned).
    MlodExt(&'static str),
}

impl Case {
    pub const ALL: [Case; 6] = [
        Case::Top,
        Case::Left,
        Case::Right,
        Case::Input,
        Case::Feature,
        Case::Result,
    ];

    /// The three two-stage cases (paper Table I's MLOD rows).
    pub const MLOD: [Case; 3] = [Case::MlodI, Case::MlodF, Case::MlodR];

    /// The stage-1 cases and the MLOD cases.
    pub const EVERY: [Case; 9] = [
        Case::Top,
        Case::Left,
        Case::Right,
        Case::Input,
        Case::Feature,
        Case::Result,
        Case::MlodI,
        Case::MlodF,
        Case::MlodR,
    ];

    /// The six online-calibration cases (paper Table II's "(OC)" rows).
    pub const OC: [Case; 6] = [
        Case::InputOc,
        Case::FeatureOc,
        Case::ResultOc,
        Case::MlodIOc,
        Case::MlodFOc,
        Case::MlodROc,
    ];

    /// The cases beyond the paper (issue 32): stage 1 trained under drift, tr(Ξ) in stage 1,
    /// and the proposal union, each with the refiner.
    pub const BEYOND: [Case; 10] = [
        Case::InputPa,
        Case::InputTr,
        Case::MlodIPa,
        Case::MlodITr,
        Case::MlodU,
        Case::MlodUTr,
        Case::MlodIDrop,
        Case::ResultDrop,
        Case::MlodRDrop,
        Case::MlodIrDrop,
    ];

    /// Every case: [`Case::EVERY`], [`Case::OC`], the ablations [`Case::InputDrop`] and
    /// [`Case::MlodINoTrace`], then [`Case::BEYOND`].
    pub const WITH_OC: [Case; 27] = [
        Case::Top,
        Case::Left,
        Case::Right,
        Case::Input,
        Case::Feature,
        Case::Result,
        Case::MlodI,
        Case::MlodF,
        Case::MlodR,
        Case::InputOc,
        Case::FeatureOc,
        Case::ResultOc,
        Case::MlodIOc,
        Case::MlodFOc,
        Case::MlodROc,
        Case::InputDrop,
        Case::MlodINoTrace,
        Case::InputPa,
        Case::InputTr,
        Case::MlodIPa,
        Case::MlodITr,
        Case::MlodU,
        Case::MlodUTr,
        Case::MlodIDrop,
        Case::ResultDrop,
        Case::MlodRDrop,
        Case::MlodIrDrop,
    ];

    /// The stage-1 case whose proposals an MLOD case refines (itself for a stage-1 case); the
    /// (OC) variant for an MLOD (OC) case.
    pub fn stage1(self) -> Case {
        match self {
            Case::MlodI | Case::MlodINoTrace => Case::Input,
            Case::MlodF => Case::Feature,
            Case::MlodR => Case::Result,
            Case::MlodIOc => Case::InputOc,
            Case::MlodFOc => Case::FeatureOc,
            Case::MlodROc => Case::ResultOc,
            Case::MlodIPa => Case::InputPa,
            Case::MlodITr | Case::MlodUTr => Case::InputTr,
            Case::MlodU => Case::Input,
            Case::MlodIDrop => Case::InputDrop,
            Case::MlodRDrop | Case::MlodIrDrop => Case::ResultDrop,
            Case::MlodExt(_) => external::ext_case(self.external_name().unwrap_or_default()),
            c => c,
        }
    }

    /// Every stage-1 case whose proposals this case refines (or outputs): LiDAR-Top and the
    /// fusion case for a union case, else [`Case::stage1`] alone.
    pub fn proposal_cases(self) -> Vec<Case> {
        match self {
            Case::MlodU | Case::MlodUTr => vec![Case::Top, self.stage1()],
            Case::MlodIrDrop => vec![Case::ResultDrop, Case::InputDrop],
            c => vec![c.stage1()],
        }
    }

    /// The stage-1 case a "certain points only" case runs on the cloud without its uncertain
    /// points ([`Case::InputDrop`] → Input Fusion, [`Case::ResultDrop`] → Result Fusion).
    pub fn dropped(self) -> Option<Case> {
        match self {
            Case::InputDrop => Some(Case::Input),
            Case::ResultDrop => Some(Case::Result),
            _ => None,
        }
    }

    /// The "certain points only" variant of a stage-1 case, if there is one.
    pub fn with_drop(self) -> Option<Case> {
        [Case::InputDrop, Case::ResultDrop]
            .into_iter()
            .find(|c| c.dropped() == Some(self))
    }

    /// The name of the stage 1 whose proposals this case shows (`LiDAR-Top + Input Fusion` for
    /// a union case).
    pub fn proposals_name(self) -> String {
        self.proposal_cases()
            .iter()
            .map(|c| c.paper_name())
            .collect::<Vec<_>>()
            .join(" + ")
    }

    /// Whether this case refines the union of several stage-1 cases' proposals (and so needs
    /// NMS after refinement: both may propose the same car).
    pub fn is_union(self) -> bool {
        matches!(self, Case::MlodU | Case::MlodUTr | Case::MlodIrDrop)
    }

    /// The network layout and point selection of a trainable case: Input Fusion's for the
    /// Input Fusion variants beyond the paper (same branch, same weight names), else itself.
    pub fn network(self) -> Case {
        match self {
            Case::InputPa | Case::InputTr => Case::Input,
            c => c,
        }
    }

    /// Whether this case's stage-1 network is trained with the perturbation injected into the
    /// auxiliary LiDARs (the paper trains stage 1 on calibrated data only).
    pub fn trains_under_drift(self) -> bool {
        matches!(self, Case::InputPa | Case::InputTr)
    }

    /// The MLOD case built on this fusion scheme, if any.
    pub fn refined(self) -> Option<Case> {
        match self {
            Case::Input => Some(Case::MlodI),
            Case::Feature => Some(Case::MlodF),
            Case::Result => Some(Case::MlodR),
            Case::InputPa => Some(Case::MlodIPa),
            Case::InputTr => Some(Case::MlodITr),
            Case::InputDrop => Some(Case::MlodIDrop),
            Case::ResultDrop => Some(Case::MlodRDrop),
            Case::InputOc => Some(Case::MlodIOc),
            Case::FeatureOc => Some(Case::MlodFOc),
            Case::ResultOc => Some(Case::MlodROc),
            Case::Ext(_) => self.external_name().map(external::mlod_ext_case),
            _ => None,
        }
    }

    /// Whether this case runs the stage-2 refiner.
    pub fn is_mlod(self) -> bool {
        Case::MLOD.contains(&self.without_oc())
            || matches!(
                self,
                Case::MlodINoTrace
                    | Case::MlodExt(_)
                    | Case::MlodIPa
                    | Case::MlodITr
                    | Case::MlodU
                    | Case::MlodUTr
                    | Case::MlodIDrop
                    | Case::MlodRDrop
                    | Case::MlodIrDrop
            )
    }

    /// The external detector's name of an `ext:NAME` or `mlod-ext:NAME` case.
    pub fn external_name(self) -> Option<&'static str> {
        match self {
            Case::Ext(s) => s.strip_prefix(external::EXT_PREFIX),
            Case::MlodExt(s) => s.strip_prefix(external::MLOD_EXT_PREFIX),
            _ => None,
        }
    }

    /// Whether this MLOD case's refiner sees tr(Ξ) (all but the ablation [`Case::MlodINoTrace`],
    /// whose refiner is the manifest's `refiner_notrace`).
    pub fn refiner_sees_trace(self) -> bool {
        self != Case::MlodINoTrace
    }

    /// Whether this case calibrates the auxiliary LiDARs online before detecting.
    pub fn is_oc(self) -> bool {
        Case::OC.contains(&self)
    }

    /// The case without online calibration (itself if it has none).
    pub fn without_oc(self) -> Case {
        match self {
            Case::InputOc => Case::Input,
            Case::FeatureOc => Case::Feature,
            Case::ResultOc => Case::Result,
            Case::MlodIOc => Case::MlodI,
            Case::MlodFOc => Case::MlodF,
            Case::MlodROc => Case::MlodR,
            c => c,
        }
    }

    /// The (OC) variant of a fusion or MLOD case.
    pub fn with_oc(self) -> Option<Case> {
        Case::OC.into_iter().find(|c| c.without_oc() == self)
    }

    /// The lowercase name used on the command line and in file names.
    pub fn as_str(self) -> &'static str {
        match self {
            Case::Top => "top",
            Case::Left => "left",
            Case::Right => "right",
            Case::Input => "input",
            Case::Feature => "feature",
            Case::Result => "result",
            Case::MlodI => "mlod-i",
            Case::MlodF => "mlod-f",
            Case::MlodR => "mlod-r",
            Case::InputOc => "input-oc",
            Case::FeatureOc => "feature-oc",
            Case::ResultOc => "result-oc",
            Case::MlodIOc => "mlod-i-oc",
            Case::MlodFOc => "mlod-f-oc",
            Case::MlodROc => "mlod-r-oc",
            Case::InputDrop => "input-drop",
            Case::MlodINoTrace => "mlod-i-notrace",
            Case::InputPa => "input-pa",
            Case::InputTr => "input-tr",
            Case::MlodIPa => "mlod-i-pa",
            Case::MlodITr => "mlod-i-tr",
            Case::MlodU => "mlod-u",
            Case::MlodUTr => "mlod-u-tr",
            Case::MlodIDrop => "mlod-i-drop",
            Case::ResultDrop => "result-drop",
            Case::MlodRDrop => "mlod-r-drop",
            Case::MlodIrDrop => "mlod-ir-drop",
            Case::Ext(s) | Case::MlodExt(s) => s,
        }
    }

    /// The paper's name.
    pub fn paper_name(self) -> &'static str {
        match self {
            Case::Top => "LiDAR-Top",
            Case::Left => "LiDAR-Left",
            Case::Right => "LiDAR-Right",
            Case::Input => "Input Fusion",
            Case::Feature => "Feature Fusion",
            Case::Result => "Result Fusion",
            Case::MlodI => "MLOD-I",
            Case::MlodF => "MLOD-F",
            Case::MlodR => "MLOD-R",
            Case::InputOc => "Input Fusion (OC)",
            Case::FeatureOc => "Feature Fusion (OC)",
            Case::ResultOc => "Result Fusion (OC)",
            Case::MlodIOc => "MLOD-I (OC)",
            Case::MlodFOc => "MLOD-F (OC)",
            Case::MlodROc => "MLOD-R (OC)",
            Case::InputDrop => "Input Fusion, uncertain points dropped",
            Case::MlodINoTrace => "MLOD-I without tr(Ξ)",
            Case::InputPa => "Input Fusion, trained under drift",
            Case::InputTr => "Input Fusion with tr(Ξ) voxels",
            Case::MlodIPa => "MLOD-I, stage 1 trained under drift",
            Case::MlodITr => "MLOD-I with tr(Ξ) in stage 1",
            Case::MlodU => "MLOD-U (Top + Input proposals)",
            Case::MlodUTr => "MLOD-U with tr(Ξ) in stage 1",
            Case::MlodIDrop => "MLOD-I on the certain points' proposals",
            Case::ResultDrop => "Result Fusion, uncertain points dropped",
            Case::MlodRDrop => "MLOD-R on the certain points' proposals",
            Case::MlodIrDrop => "MLOD-IR (Result + Input on the certain points)",
            Case::Ext(s) | Case::MlodExt(s) => s,
        }
    }

    /// One line on what the case does (`mlod detect --help`, the window's case tooltip).
    pub fn description(self) -> &'static str {
        match self {
            Case::Top => "the roof LiDAR alone (drift of the others never reaches it)",
            Case::Left => "LIDAR_FRONT_LEFT alone, in the base frame",
            Case::Right => "LIDAR_FRONT_RIGHT alone, in the base frame",
            Case::Input => "all LiDARs' points fused before one network (paper §IV-A-1)",
            Case::Feature => "one middle-layer branch per LiDAR, max-fused BEV features (§IV-A-2)",
            Case::Result => "the three single-LiDAR detectors, calibrated, merged by 3D NMS (§IV-A-3)",
            Case::MlodI => "Input Fusion's proposals refined on the uncertain points (§IV-B)",
            Case::MlodF => "Feature Fusion's proposals refined on the uncertain points",
            Case::MlodR => "Result Fusion's proposals refined on the uncertain points",
            Case::InputOc | Case::FeatureOc | Case::ResultOc => {
                "online calibration (point-to-plane ICP) first, then the fusion case"
            }
            Case::MlodIOc | Case::MlodFOc | Case::MlodROc => {
                "online calibration (point-to-plane ICP) first, then the MLOD case"
            }
            Case::InputDrop => "Input Fusion without the points whose tr(Ξ) is above a threshold",
            Case::MlodINoTrace => "MLOD-I with a refiner trained without the tr(Ξ) point feature",
            Case::InputPa => "Input Fusion trained with drift injected (beyond the paper)",
            Case::InputTr => "Input Fusion with each voxel's mean tr(Ξ) as input, trained under drift",
            Case::MlodIPa => "the refiner on input-pa's proposals",
            Case::MlodITr => "the refiner on input-tr's proposals",
            Case::MlodU => "the refiner on LiDAR-Top's and Input Fusion's proposals together, NMS after",
            Case::MlodUTr => "the refiner on LiDAR-Top's and input-tr's proposals together, NMS after",
            Case::MlodIDrop => "the refiner (on every point) on input-drop's proposals",
            Case::ResultDrop => "Result Fusion without the points whose tr(Ξ) is above a threshold",
            Case::MlodRDrop => "the refiner (on every point) on result-drop's proposals",
            Case::MlodIrDrop => {
                "the refiner on result-drop's and input-drop's proposals together, merged after"
            }
            Case::Ext(_) => "an external detector over mlod-detector/1",
            Case::MlodExt(_) => "the refiner on an external detector's proposals",
        }
    }

    /// The single LiDAR of a single-LiDAR case.
    pub fn channel(self) -> Option<LidarChannel> {
        match self {
            Case::Top => Some(LidarChannel::Top),
            Case::Left => Some(LidarChannel::FrontLeft),
            Case::Right => Some(LidarChannel::FrontRight),
            _ => None,
        }
    }

    /// The LiDARs this case reads: its one LiDAR for a single-LiDAR case, all three otherwise.
    pub fn lidars(self) -> Vec<LidarChannel> {
        match self.channel() {
            Some(c) => vec![c],
            None => LidarChannel::ALL.to_vec(),
        }
    }

    /// The LiDARs this case reads that `frame` lacks (most real Lyft samples and every KITTI or
    /// nuScenes sample have LIDAR_TOP only).
    pub fn missing_lidars(self, frame: &Frame) -> Vec<LidarChannel> {
        self.lidars()
            .into_iter()
            .filter(|c| frame.lidar(*c).is_none())
            .collect()
    }

    /// What to tell the user when the case reads LiDARs the sample lacks: a fusion case runs on
    /// the LiDARs that are there; a single-LiDAR case on a missing LiDAR has nothing to see.
    /// `None` when every LiDAR the case reads is there.
    pub fn missing_lidars_note(self, frame: &Frame) -> Option<String> {
        let missing = self.missing_lidars(frame);
        if missing.is_empty() {
            return None;
        }
        let names = missing.iter().map(|c| c.as_str()).collect::<Vec<_>>().join(", ");
        let present = frame
            .lidars()
            .map(|l| l.info.channel.as_str())
            .collect::<Vec<_>>()
            .join(", ");
        Some(if self.channel().is_some() {
            format!(
                "{}: sample {} has no {names}: there is nothing for this case to detect on",
                self.paper_name(),
                frame.sample_token
            )
        } else {
            format!(
                "{}: sample {} lacks {names}; it runs on what is there ({present}){}",
                self.paper_name(),
                frame.sample_token,
                if self.is_oc() {
                    ", with no auxiliary LiDAR to calibrate"
                } else {
                    ""
                }
            )
        })
    }

    /// Whether one stage-1 network is trained for this case (all single-network stage-1 cases).
    pub fn is_trainable(self) -> bool {
        matches!(
            self,
            Case::Top
                | Case::Left
                | Case::Right
                | Case::Input
                | Case::Feature
                | Case::InputPa
                | Case::InputTr
        )
    }
}

impl std::fmt::Display for Case {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Case {
    type Err = String;

    /// A case by its name: one of [`Case::WITH_OC`], `ext:NAME` or `mlod-ext:NAME`.
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(c) = Case::WITH_OC.into_iter().find(|c| c.as_str() == s) {
            return Ok(c);
        }
        if let Some(name) = s.strip_prefix(external::EXT_PREFIX) {
            return external::check_name(name).map(|()| external::ext_case(name));
        }
        if let Some(name) = s.strip_prefix(external::MLOD_EXT_PREFIX) {
            return external::check_name(name).map(|()| external::mlod_ext_case(name));
        }
        let names = Case::WITH_OC.map(|c| c.as_str()).join(", ");
        Err(format!(
            "'{s}' is not a case: one of {names}, ext:NAME (an external detector) or mlod-ext:NAME"
        ))
    }
}

impl Serialize for Case {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for Case {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Errors of the detectors.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error("weights file {path}: {what}")]
    Weights { path: std::path::PathBuf, what: String },
    #[error("weights file {path}: sha256 {actual} does not match the manifest's {expected} (corrupt or replaced file)")]
    Checksum {
        path: std::path::PathBuf,
        expected: String,
        actual: String,
    },
    #[error("weights file {path} is for case {found}, expected {expected}")]
    WrongCase {
        path: std::path::PathBuf,
        expected: Case,
        found: String,
    },
    #[error("manifest {path}: {what}")]
    Manifest { path: std::path::PathBuf, what: String },
    #[error("sample {sample}: LiDAR {channel} is not present")]
    MissingLidar { sample: String, channel: LidarChannel },
    #[error("bad parameter: {0}")]
    BadParameter(String),
    /// The stage-2 refiner of an MLOD case could not be loaded or run (its message names the file).
    #[error("{0}")]
    Refiner(String),
    #[error("network: {0}")]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    #[error(transparent)]
    Lyft(#[from] crate::dataset::DatasetError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error(transparent)]
    External(#[from] external::ExternalError),
}

/// One entry point for every stage-1 case.
pub trait Detector: Send + Sync {
    /// The case this detector implements.
    fn case(&self) -> Case;

    /// The Lyft categories it can output (`car`, ...); ground truth of other classes is not its
    /// business.
    fn categories(&self) -> Vec<String>;

    /// Detects objects on `cloud`, the frame fused by the caller (`pipeline::fuse`); boxes are in
    /// the base frame, highest score first. A caller that needs the cloud too (the MLOD refiner)
    /// fuses once.
    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError>;

    /// The parameters [`Detector::detect`] fuses `frame` with: `params` itself, or for an (OC)
    /// case `params` with the online calibration in them. A detector wrapping another passes
    /// this on, so that a wrapped (OC) case still detects on its calibrated cloud.
    fn fuse_params(&self, frame: &Frame, params: &FuseParams) -> Result<FuseParams, DetectError> {
        let _ = frame;
        Ok(params.clone())
    }

    /// Fuses the frame with [`Detector::fuse_params`] (so perturbations reach the auxiliary
    /// LiDARs) and detects.
    fn detect(&self, frame: &Frame, params: &FuseParams) -> Result<Vec<Detection>, DetectError> {
        let cloud = crate::pipeline::fuse(frame, &self.fuse_params(frame, params)?)?;
        self.detect_fused(frame, &cloud)
    }
}
