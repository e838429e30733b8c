//! A serialisable debugging session: everything needed to reproduce a view exactly — the
//! dataset, the sample, the perturbation (α, seed, manual offsets, decoupled prior α,
//! linearisation) together with the perturbation that was actually sampled, the colouring and the
//! camera. Saved as pretty JSON, atomically; loading checks the version and every number.

#![deny(clippy::indexing_slicing)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::calib::{Calibration, OcPrior};
use crate::color::ColorParams;
use crate::dataset::LidarChannel;
use crate::detect::Case;
use crate::external::ExternalSpec;
use crate::io::{write_atomic, IoError};
use crate::pipeline::FuseParams;
use crate::uncertainty::ExtrinsicNoise;

/// The session file format version.
pub const SESSION_VERSION: u32 = 1;

/// Where the camera is (the GUI converts to and from its own camera).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraPose {
    pub target: [f32; 3],
    pub yaw: f32,
    pub pitch: f32,
    pub distance: f32,
    pub fov_y: f32,
    /// Bird's-eye (top-down orthographic) instead of perspective.
    pub bev: bool,
}

/// One debugging session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Session {
    pub version: u32,
    /// Dataset root (or version folder).
    pub dataset: PathBuf,
    /// The sample shown; `None`: the first one.
    pub sample_token: Option<String>,
    pub fuse: FuseParams,
    /// The perturbation each auxiliary LiDAR got when the session was saved (for checking that
    /// a replay draws the same numbers).
    #[serde(default)]
    pub sampled: BTreeMap<LidarChannel, ExtrinsicNoise>,
    pub color: ColorParams,
    /// Recompute the colour range from the data on every change.
    pub auto_range: bool,
    pub camera: Option<CameraPose>,
    /// Per-LiDAR visibility.
    #[serde(default)]
    pub visible: BTreeMap<LidarChannel, bool>,
    pub show_ground_truth: bool,
    /// Point size in UI points.
    pub point_size: f32,
    /// Box line width in UI points (sessions written before it existed: 2.5).
    #[serde(default = "default_line_width")]
    pub line_width: f32,
    /// Detection settings (what the Detection panel shows).
    #[serde(default)]
    pub detection: DetectionSettings,
    /// Online calibration: the last ICP result and whether the corrected cloud is shown.
    #[serde(default, skip_serializing_if = "OcSession::is_unset")]
    pub oc: OcSession,
    /// The selected box (the details panel's), kept across re-runs by the object it is on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selection: Option<BoxSelection>,
    /// Compare mode: this second case runs on the same perturbed frame and is drawn in the right
    /// half of a split viewport with the same camera.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compare: Option<Case>,
    /// The sweep folder whose AP-against-α plot is open (the sweep window).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sweep: Option<PathBuf>,
    /// The failure browser's source, when it is open: reopening the session scans again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failures: Option<FailureScope>,
    /// The external detectors its cases name (`ext:NAME`, `mlod-ext:NAME`), with their commands.
    /// Data that people share: the window asks before running one (`gui::consent`), the CLI
    /// never runs one unless its own command line names it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub external: Vec<ExternalSpec>,
    /// The models folder the window ran its detectors from, when it was not the one the window
    /// started with (File > Open models folder…); reopening the session opens it again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub models: Option<PathBuf>,
    /// The file the session was loaded from (not saved): what a consent to its detectors is
    /// remembered for.
    #[serde(skip)]
    pub source: SessionSource,
}

/// Where a session was read from. Not part of what the session is: any two compare equal and
/// print alike.
#[derive(Clone, Default)]
pub struct SessionSource(pub Option<PathBuf>);

impl std::fmt::Debug for SessionSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SessionSource")
    }
}

impl PartialEq for SessionSource {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

fn default_line_width() -> f32 {
    2.5
}

/// Which samples the failure browser scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureScope {
    /// The scene of the sample on screen.
    Scene,
    /// Every sample of the dataset.
    Dataset,
}

/// The layer a selected box belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxLayer {
    /// A ground-truth box (green).
    Truth,
    /// A stage-1 box (blue; an MLOD case's proposal).
    Proposal,
    /// An MLOD case's refined box (red).
    Refined,
}

/// A selected box, stored by what identifies its object across α changes and re-runs: the
/// ground-truth annotation it is on (the box itself for `truth`, the matched truth for a
/// prediction), else the position it was at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoxSelection {
    pub layer: BoxLayer,
    /// The annotation token of the object, if the box is (or matched) a ground-truth box.
    pub annotation: Option<String>,
    /// The box's centre when last found (base frame, m): an unmatched prediction is found again
    /// as the nearest box of its layer and category within [`BoxSelection::REFIND_RADIUS`].
    pub center: [f64; 3],
    pub category: String,
}

impl BoxSelection {
    /// How far (m, centre to centre in x–y) an unmatched prediction may have moved and still be
    /// "the same" box after a re-run.
    pub const REFIND_RADIUS: f64 = 2.0;
}

/// The online calibration of a session (the window's "calibrate (ICP)").
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct OcSession {
    /// The last calibration of the sample on screen, kept so a session reopens with the same
    /// corrected extrinsics (ICP is not rerun).
    pub calibration: Option<Calibration>,
    /// Fuse with the corrected extrinsics instead of the drifted ones.
    pub show_corrected: bool,
    /// Fuse with the dataset's own extrinsics (the factory calibration on real data): no
    /// perturbation, no calibration; tr(Ξ) keeps the prior of the α set.
    pub show_factory: bool,
    /// The uncertainty the calibrated LiDARs' points carry (and the tr(Ξ) colouring shows).
    pub prior: OcPrior,
}

impl OcSession {
    pub fn is_unset(&self) -> bool {
        *self == Self::default()
    }
}

/// The Detection panel's settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DetectionSettings {
    /// Which case the Run button runs (a stage-1 case or MLOD-I/F/R).
    pub case: Case,
    /// Run the detector again after every change of sample or perturbation.
    pub auto_run: bool,
    /// Proposals are drawn from this score up (the matching uses all of them).
    pub min_score: f32,
    /// 3D IoU a proposal needs to count as a true positive.
    pub match_iou: f64,
    /// Draw stage 1's boxes (an MLOD case's proposals).
    pub show: bool,
    /// Draw an MLOD case's refined boxes and the lines joining them to their proposals.
    pub show_refined: bool,
    /// Highlight the active points (§V-C) of the hovered or selected refined box.
    pub show_active: bool,
    /// Run the stage-1 cases behind the models folder's ground gate, if it has one (off: see the
    /// boxes the gate drops).
    pub ground_gate: bool,
}

impl Default for DetectionSettings {
    fn default() -> Self {
        Self {
            case: Case::Input,
            auto_run: false,
            min_score: 0.3,
            match_iou: 0.7,
            show: true,
            show_refined: true,
            show_active: false,
            ground_gate: true,
        }
    }
}

impl Session {
    /// The fuse parameters of the view: the perturbation, plus the calibration when the corrected
    /// cloud is shown (with the session's choice of prior); without either in the factory view.
    pub fn fuse_params(&self) -> FuseParams {
        let mut p = self.fuse.clone();
        if self.oc.show_factory {
            p.prior_alpha = Some(p.effective_prior_alpha());
            p.perturbation.alpha = 0.0;
            p.manual.clear();
            p.calibration = None;
            return p;
        }
        p.calibration = match (&self.oc.calibration, self.oc.show_corrected) {
            (Some(c), true) => Some(Calibration {
                prior: self.oc.prior,
                ..c.clone()
            }),
            _ => None,
        };
        p
    }

    pub fn new(dataset: PathBuf) -> Self {
        Self {
            version: SESSION_VERSION,
            dataset,
            sample_token: None,
            fuse: FuseParams::default(),
            sampled: BTreeMap::new(),
            color: ColorParams::default(),
            auto_range: true,
            camera: None,
            visible: BTreeMap::new(),
            show_ground_truth: true,
            point_size: 2.0,
            line_width: default_line_width(),
            detection: DetectionSettings::default(),
            oc: OcSession::default(),
            selection: None,
            compare: None,
            sweep: None,
            failures: None,
            external: Vec::new(),
            models: None,
            source: SessionSource::default(),
        }
    }

    /// Writes the session as pretty JSON, atomically.
    pub fn save(&self, path: &Path) -> Result<(), SessionError> {
        self.validate(path)?;
        let json = serde_json::to_vec_pretty(self).map_err(|e| SessionError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        write_atomic(path, &json)?;
        Ok(())
    }

    /// Reads and checks a session file.
    pub fn load(path: &Path) -> Result<Self, SessionError> {
        let bytes = std::fs::read(path).map_err(|e| IoError::new("cannot read session", path, e))?;
        let s: Session = serde_json::from_slice(&bytes).map_err(|e| SessionError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        s.validate(path)?;
        Ok(Session {
            source: SessionSource(Some(path.to_path_buf())),
            ..s
        })
    }

    fn validate(&self, path: &Path) -> Result<(), SessionError> {
        let bad = |field: &str, why: String| SessionError::Invalid {
            path: path.to_path_buf(),
            field: field.to_string(),
            why,
        };
        if self.version != SESSION_VERSION {
            return Err(bad(
                "version",
                format!("{} (this build reads {SESSION_VERSION})", self.version),
            ));
        }
        let a = self.fuse.perturbation.alpha;
        if !a.is_finite() || a < 0.0 {
            return Err(bad(
                "fuse.perturbation.alpha",
                format!("{a} (must be finite and >= 0)"),
            ));
        }
        if let Some(pa) = self.fuse.prior_alpha {
            if !pa.is_finite() || pa < 0.0 {
                return Err(bad("fuse.prior_alpha", format!("{pa} (must be finite and >= 0)")));
            }
        }
        for (ch, n) in self.fuse.manual.iter().chain(self.sampled.iter()) {
            if !n.is_finite() {
                return Err(bad(
                    "fuse.manual / sampled",
                    format!("offset of {ch} is not finite"),
                ));
            }
        }
        let (lo, hi) = self.color.range;
        if !(lo.is_finite() && hi.is_finite()) || hi < lo {
            return Err(bad("color.range", format!("[{lo}, {hi}]")));
        }
        if !self.line_width.is_finite() || !(0.5..=12.0).contains(&self.line_width) {
            return Err(bad(
                "line_width",
                format!("{} (must be in 0.5..=12)", self.line_width),
            ));
        }
        if !self.point_size.is_finite() || !(0.5..=50.0).contains(&self.point_size) {
            return Err(bad(
                "point_size",
                format!("{} (must be in 0.5..=50)", self.point_size),
            ));
        }
        let d = &self.detection;
        if !d.min_score.is_finite() || !(0.0..=1.0).contains(&d.min_score) {
            return Err(bad(
                "detection.min_score",
                format!("{} (must be in 0..=1)", d.min_score),
            ));
        }
        if !(d.match_iou.is_finite() && d.match_iou > 0.0 && d.match_iou <= 1.0) {
            return Err(bad(
                "detection.match_iou",
                format!("{} (must be in (0, 1])", d.match_iou),
            ));
        }
        for (i, e) in self.external.iter().enumerate() {
            e.validate()
                .map_err(|err| bad(&format!("external[{i}]"), err.to_string()))?;
        }
        if let Some(sel) = &self.selection {
            if sel.center.iter().any(|v| !v.is_finite()) {
                return Err(bad("selection.center", "has a non-finite value".into()));
            }
        }
        if let Some(c) = &self.camera {
            let vals = [
                c.target[0],
                c.target[1],
                c.target[2],
                c.yaw,
                c.pitch,
                c.distance,
                c.fov_y,
            ];
            if vals.iter().any(|v| !v.is_finite()) || c.distance <= 0.0 || c.fov_y <= 0.0 {
                return Err(bad("camera", "has a non-finite or non-positive value".into()));
            }
        }
        Ok(())
    }
}

/// Errors reading or writing a session file, naming it.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("session {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("session {path}: field {field} is invalid: {why}")]
    Invalid {
        path: PathBuf,
        field: String,
        why: String,
    },
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::uncertainty::Perturbation;

    #[test]
    fn round_trip_and_bad_files() {
        let dir = std::env::temp_dir().join(format!("mlod-session-{}", std::process::id()));
        let path = dir.join("s.json");
        let mut s = Session::new(PathBuf::from("sample_data"));
        s.fuse.perturbation = Perturbation::new(0.04, 7).unwrap();
        s.fuse.manual.insert(
            LidarChannel::FrontLeft,
            ExtrinsicNoise {
                rho: [0.01, 0.0, 0.0],
                phi: [0.0, 0.0, 0.002],
            },
        );
        s.camera = Some(CameraPose {
            target: [1.0, 2.0, 0.0],
            yaw: 0.3,
            pitch: 0.5,
            distance: 40.0,
            fov_y: 0.8,
            bev: false,
        });
        s.save(&path).unwrap();
        assert_eq!(Session::load(&path).unwrap(), s);

        std::fs::write(&path, b"{ not json").unwrap();
        let e = Session::load(&path).unwrap_err().to_string();
        assert!(e.contains("s.json"), "{e}");
        let mut bad = s.clone();
        bad.point_size = f32::NAN;
        assert!(bad.save(&path).is_err());
        let text = serde_json::to_string(&s)
            .unwrap()
            .replace("\"alpha\":0.04", "\"alpha\":-1.0");
        std::fs::write(&path, text).unwrap();
        let e = Session::load(&path).unwrap_err().to_string();
        assert!(e.contains("alpha"), "{e}");
        // Detection settings: an absurd score names its field; files from before they existed load
        // with the defaults.
        let text = serde_json::to_string(&s)
            .unwrap()
            .replace("\"min_score\":0.3", "\"min_score\":7.0");
        std::fs::write(&path, text).unwrap();
        let e = Session::load(&path).unwrap_err().to_string();
        assert!(e.contains("detection.min_score"), "{e}");
        let mut v = serde_json::to_value(&s).unwrap();
        v.as_object_mut().unwrap().remove("detection");
        std::fs::write(&path, v.to_string()).unwrap();
        assert_eq!(
            Session::load(&path).unwrap().detection,
            DetectionSettings::default()
        );
        // An MLOD case and the layer toggles round-trip; a file from before the refiner existed
        // (no show_refined / show_active) loads with their defaults.
        let mut m = s.clone();
        m.detection.case = Case::MlodI;
        m.detection.show_refined = false;
        m.detection.show_active = true;
        m.save(&path).unwrap();
        assert!(std::fs::read_to_string(&path).unwrap().contains("\"mlod-i\""));
        assert_eq!(Session::load(&path).unwrap(), m);
        let mut v = serde_json::to_value(&s).unwrap();
        let d = v["detection"].as_object_mut().unwrap();
        d.remove("show_refined");
        d.remove("show_active");
        d.insert("case".into(), "feature".into());
        std::fs::write(&path, v.to_string()).unwrap();
        let old = Session::load(&path).unwrap().detection;
        assert_eq!(old.case, Case::Feature);
        assert!(old.show_refined && !old.show_active);
        assert!(Session::load(&dir.join("missing.json"))
            .unwrap_err()
            .to_string()
            .contains("missing.json"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
