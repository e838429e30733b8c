//! The case table: every case of the product is one row of [`TABLE`] (its name, the paper's
//! name, one line of description, the group it is listed in and how it is built), and every list
//! (the CLI's help, the window's menu, sweep defaults, the (OC) list) is derived from it.
//!
//! A case is named by its lowercase name ([`Case::as_str`]) on the command line, in JSON and in
//! file names; `ext:NAME` and `mlod-ext:NAME` name a detector in another process (`crate::external`).
//! `crate::cases::load_detector` is the factory that builds any case from a models folder by
//! reading its row's [`Build`].

use serde::{Deserialize, Serialize};

use std::collections::BTreeSet;
use std::sync::Mutex;

use crate::dataset::{Frame, LidarChannel};

/// A case: a stage-1 detector, a wrapper around one, or an MLOD case (stage 1 + the refiner).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Case {
    Top,
    Left,
    Right,
    Input,
    Feature,
    Result,
    MlodI,
    MlodF,
    MlodR,
    InputOc,
    FeatureOc,
    ResultOc,
    MlodIOc,
    MlodFOc,
    MlodROc,
    InputDrop,
    MlodINoTrace,
    MlodU,
    MlodIrDrop,
    /// Result Fusion on the certain points: a proposal source of [`Case::MlodIrDrop`] only, not
    /// listed and not accepted on the command line.
    ResultDrop,
    /// `ext:NAME`: the detector NAME, served by another process over `mlod-detector/1`
    /// (`crate::external`). Holds the whole case name (`ext:NAME`), interned, so a case stays `Copy`.
    Ext(&'static str),
    /// `mlod-ext:NAME`: the shipped refiner on the proposals of the external detector NAME (holds
    /// `mlod-ext:NAME`, interned).
    MlodExt(&'static str),
}

/// Where a case is listed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Group {
    /// The paper's stage-1 cases (Table I).
    Stage1,
    /// The paper's two-stage cases (Table I's MLOD rows).
    Mlod,
    /// The online-calibration cases (Table II's "(OC)" rows).
    Oc,
    /// Ablations the README reports.
    Ablation,
    /// Beyond the paper: the cases that lead Table II on the validation scenes.
    Beyond,
    /// Built only as another case's part; never listed or parsed.
    Internal,
}

/// How a case's detector is made from a models folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Build {
    /// One trained stage-1 network, its weights named after the case in the manifest.
    Network,
    /// The three single-LiDAR networks, temperature-calibrated, merged by 3D NMS (eq. 11).
    ResultFusion,
    /// The case on the fused cloud without its uncertain points (tr(Ξ) above a threshold).
    Drop(Case),
    /// Online calibration (point-to-plane ICP) of the auxiliary LiDARs, then the case.
    Oc(Case),
    /// The stage-2 refiner on these cases' proposals (merged by NMS after refinement when there
    /// are several); `trace`: the refiner that sees tr(Ξ) (else the manifest's `refiner_notrace`).
    Refine { proposals: &'static [Case], trace: bool },
}

/// One row of the case table.
#[derive(Debug, Clone, Copy)]
pub struct CaseRow {
    pub case: Case,
    /// The lowercase name of the command line, JSON and file names.
    pub name: &'static str,
    /// The paper's name (or ours, for a case beyond it).
    pub paper_name: &'static str,
    /// One line on what it does (`mlod detect --help`, the window's tooltip).
    pub description: &'static str,
    pub group: Group,
    pub build: Build,
}

const fn row(
    case: Case,
    name: &'static str,
    paper_name: &'static str,
    description: &'static str,
    group: Group,
    build: Build,
) -> CaseRow {
    CaseRow {
        case,
        name,
        paper_name,
        description,
        group,
        build,
    }
}

const OC_FUSION: &str = "online calibration (point-to-plane ICP) first, then the fusion case";
const OC_MLOD: &str = "online calibration (point-to-plane ICP) first, then the MLOD case";

/// The case table: every built-in case, in the order every list shows them.
pub const TABLE: [CaseRow; 20] = {
    use Build::*;
    use Case::*;
    use Group as G;
    [
        row(
            Top,
            "top",
            "LiDAR-Top",
            "the roof LiDAR alone (drift of the others never reaches it)",
            G::Stage1,
            Network,
        ),
        row(
            Left,
            "left",
            "LiDAR-Left",
            "LIDAR_FRONT_LEFT alone, in the base frame",
            G::Stage1,
            Network,
        ),
        row(
            Right,
            "right",
            "LiDAR-Right",
            "LIDAR_FRONT_RIGHT alone, in the base frame",
            G::Stage1,
            Network,
        ),
        row(
            Input,
            "input",
            "Input Fusion",
            "all LiDARs' points fused before one network (paper §IV-A-1)",
            G::Stage1,
            Network,
        ),
        row(
            Feature,
            "feature",
            "Feature Fusion",
            "one middle-layer branch per LiDAR, max-fused BEV features (§IV-A-2)",
            G::Stage1,
            Network,
        ),
        row(
            Result,
            "result",
            "Result Fusion",
            "the three single-LiDAR detectors, calibrated, merged by 3D NMS (§IV-A-3)",
            G::Stage1,
            ResultFusion,
        ),
        row(
            MlodI,
            "mlod-i",
            "MLOD-I",
            "Input Fusion's proposals refined on the uncertain points (§IV-B)",
            G::Mlod,
            Refine {
                proposals: &[Input],
                trace: true,
            },
        ),
        row(
            MlodF,
            "mlod-f",
            "MLOD-F",
            "Feature Fusion's proposals refined on the uncertain points",
            G::Mlod,
            Refine {
                proposals: &[Feature],
                trace: true,
            },
        ),
        row(
            MlodR,
            "mlod-r",
            "MLOD-R",
            "Result Fusion's proposals refined on the uncertain points",
            G::Mlod,
            Refine {
                proposals: &[Result],
                trace: true,
            },
        ),
        row(
            InputOc,
            "input-oc",
            "Input Fusion (OC)",
            OC_FUSION,
            G::Oc,
            Oc(Input),
        ),
        row(
            FeatureOc,
            "feature-oc",
            "Feature Fusion (OC)",
            OC_FUSION,
            G::Oc,
            Oc(Feature),
        ),
        row(
            ResultOc,
            "result-oc",
            "Result Fusion (OC)",
            OC_FUSION,
            G::Oc,
            Oc(Result),
        ),
        row(MlodIOc, "mlod-i-oc", "MLOD-I (OC)", OC_MLOD, G::Oc, Oc(MlodI)),
        row(MlodFOc, "mlod-f-oc", "MLOD-F (OC)", OC_MLOD, G::Oc, Oc(MlodF)),
        row(MlodROc, "mlod-r-oc", "MLOD-R (OC)", OC_MLOD, G::Oc, Oc(MlodR)),
        row(
            InputDrop,
            "input-drop",
            "Input Fusion, uncertain points dropped",
            "Input Fusion without the points whose tr(Ξ) is above a threshold (§IV-B's straightforward idea)",
            G::Ablation,
            Drop(Input),
        ),
        row(
            MlodINoTrace,
            "mlod-i-notrace",
            "MLOD-I without tr(Ξ)",
            "MLOD-I with a refiner trained without the tr(Ξ) point feature",
            G::Ablation,
            Refine {
                proposals: &[Input],
                trace: false,
            },
        ),
        row(
            MlodU,
            "mlod-u",
            "MLOD-U (Top + Input proposals)",
            "the refiner on LiDAR-Top's and Input Fusion's proposals together, NMS after",
            G::Beyond,
            Refine {
                proposals: &[Top, Input],
                trace: true,
            },
        ),
        row(
            MlodIrDrop,
            "mlod-ir-drop",
            "MLOD-IR (Result + Input on the certain points)",
            "the refiner on Result and Input Fusion's proposals on the certain points, merged after",
            G::Beyond,
            Refine {
                proposals: &[ResultDrop, InputDrop],
                trace: true,
            },
        ),
        row(
            ResultDrop,
            "result-drop",
            "Result Fusion, uncertain points dropped",
            "Result Fusion without the points whose tr(Ξ) is above a threshold",
            G::Internal,
            Drop(Result),
        ),
    ]
};

/// The cases of some groups, in table order; a compile error when `N` is not their count.
const fn of_groups<const N: usize>(groups: &[Group]) -> [Case; N] {
    let mut out = [Case::Top; N];
    let (mut i, mut k) = (0, 0);
    while i < TABLE.len() {
        let mut g = 0;
        while g < groups.len() {
            if TABLE[i].group as u8 == groups[g] as u8 {
                out[k] = TABLE[i].case;
                k += 1;
            }
            g += 1;
        }
        i += 1;
    }
    assert!(k == N, "a case list's length does not match the case table");
    out
}

impl Case {
    /// The paper's six stage-1 cases.
    pub const ALL: [Case; 6] = of_groups(&[Group::Stage1]);

    /// The three two-stage cases (paper Table I's MLOD rows).
    pub const MLOD: [Case; 3] = of_groups(&[Group::Mlod]);

    /// The stage-1 cases and the MLOD cases.
    pub const EVERY: [Case; 9] = of_groups(&[Group::Stage1, Group::Mlod]);

    /// The six online-calibration cases (paper Table II's "(OC)" rows).
    pub const OC: [Case; 6] = of_groups(&[Group::Oc]);

    /// The cases beyond the paper.
    pub const BEYOND: [Case; 2] = of_groups(&[Group::Beyond]);

    /// Every listed case (the help, the window's menu, a full sweep): all but the internal ones.
    pub const LISTED: [Case; 19] = of_groups(&[
        Group::Stage1,
        Group::Mlod,
        Group::Oc,
        Group::Ablation,
        Group::Beyond,
    ]);

    /// This case's row (`None` for an external case).
    pub fn row(self) -> Option<&'static CaseRow> {
        TABLE.iter().find(|r| r.case == self)
    }

    /// How this case is built (an external case: a network of its own).
    pub fn build(self) -> Build {
        match self {
            Case::MlodExt(_) => Build::Refine {
                proposals: &[],
                trace: true,
            },
            c => c.row().map_or(Build::Network, |r| r.build),
        }
    }

    /// The stage-1 case whose proposals an MLOD case refines (itself for a stage-1 case); the
    /// (OC) variant for an MLOD (OC) case.
    pub fn stage1(self) -> Case {
        if let Case::MlodExt(_) = self {
            return ext_case(self.external_name().unwrap_or_default());
        }
        match self.build() {
            // A union case's "stage 1" is its fusion part (LiDAR-Top rides along).
            Build::Refine { proposals, .. } => proposals
                .iter()
                .copied()
                .find(|c| *c != Case::Top)
                .unwrap_or(self),
            Build::Oc(inner) if inner.is_mlod() => {
                let s = inner.stage1();
                s.with_oc().unwrap_or(s)
            }
            _ => self,
        }
    }

    /// Every stage-1 case whose proposals this case refines (or outputs): several for a union
    /// case, else [`Case::stage1`] alone.
    pub fn proposal_cases(self) -> Vec<Case> {
        match self.build() {
            Build::Refine { proposals, .. } if proposals.len() > 1 => proposals.to_vec(),
            _ => vec![self.stage1()],
        }
    }

    /// The stage-1 case a "certain points only" case runs on the cloud without its uncertain
    /// points.
    pub fn dropped(self) -> Option<Case> {
        match self.build() {
            Build::Drop(c) => Some(c),
            _ => None,
        }
    }

    /// The "certain points only" variant of a stage-1 case, if there is one.
    pub fn with_drop(self) -> Option<Case> {
        TABLE
            .iter()
            .find(|r| r.build == Build::Drop(self))
            .map(|r| r.case)
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
        matches!(self.build(), Build::Refine { proposals, .. } if proposals.len() > 1)
    }

    /// The MLOD case built on this stage-1 case, if any.
    pub fn refined(self) -> Option<Case> {
        match self {
            Case::Ext(_) => return self.external_name().map(mlod_ext_case),
            _ if self.is_oc() => return self.without_oc().refined().and_then(Case::with_oc),
            _ => {}
        }
        TABLE
            .iter()
            .find(|r| matches!(r.build, Build::Refine { proposals, trace: true } if proposals == [self]))
            .map(|r| r.case)
    }

    /// Whether this case runs the stage-2 refiner.
    pub fn is_mlod(self) -> bool {
        match self.build() {
            Build::Refine { .. } => true,
            Build::Oc(inner) => inner.is_mlod(),
            _ => false,
        }
    }

    /// The external detector's name of an `ext:NAME` or `mlod-ext:NAME` case.
    pub fn external_name(self) -> Option<&'static str> {
        match self {
            Case::Ext(s) => s.strip_prefix(EXT_PREFIX),
            Case::MlodExt(s) => s.strip_prefix(MLOD_EXT_PREFIX),
            _ => None,
        }
    }

    /// Whether this MLOD case's refiner sees tr(Ξ) (all but the ablation [`Case::MlodINoTrace`],
    /// whose refiner is the manifest's `refiner_notrace`).
    pub fn refiner_sees_trace(self) -> bool {
        match self.build() {
            Build::Refine { trace, .. } => trace,
            Build::Oc(inner) => inner.refiner_sees_trace(),
            _ => true,
        }
    }

    /// Whether this case calibrates the auxiliary LiDARs online before detecting.
    pub fn is_oc(self) -> bool {
        matches!(self.build(), Build::Oc(_))
    }

    /// The case without online calibration (itself if it has none).
    pub fn without_oc(self) -> Case {
        match self.build() {
            Build::Oc(inner) => inner,
            _ => self,
        }
    }

    /// The (OC) variant of a fusion or MLOD case.
    pub fn with_oc(self) -> Option<Case> {
        TABLE.iter().find(|r| r.build == Build::Oc(self)).map(|r| r.case)
    }

    /// Whether one stage-1 network is trained for this case.
    pub fn is_trainable(self) -> bool {
        self.row().is_some_and(|r| r.build == Build::Network)
    }

    /// The lowercase name used on the command line and in file names.
    pub fn as_str(self) -> &'static str {
        match self {
            Case::Ext(s) | Case::MlodExt(s) => s,
            c => c.row().map_or("", |r| r.name),
        }
    }

    /// The paper's name.
    pub fn paper_name(self) -> &'static str {
        match self {
            Case::Ext(s) | Case::MlodExt(s) => s,
            c => c.row().map_or("", |r| r.paper_name),
        }
    }

    /// One line on what the case does (`mlod detect --help`, the window's case tooltip).
    pub fn description(self) -> &'static str {
        match self {
            Case::Ext(_) => "an external detector over mlod-detector/1",
            Case::MlodExt(_) => "the refiner on an external detector's proposals",
            c => c.row().map_or("", |r| r.description),
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
}

impl std::fmt::Display for Case {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Case {
    type Err = String;

    /// A case by its name: one of [`Case::LISTED`], `ext:NAME` or `mlod-ext:NAME`.
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(c) = Case::LISTED.into_iter().find(|c| c.as_str() == s) {
            return Ok(c);
        }
        if let Some(name) = s.strip_prefix(EXT_PREFIX) {
            return check_name(name).map(|()| ext_case(name));
        }
        if let Some(name) = s.strip_prefix(MLOD_EXT_PREFIX) {
            return check_name(name).map(|()| mlod_ext_case(name));
        }
        let names = Case::LISTED.map(|c| c.as_str()).join(", ");
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
    /// What mlod wrote: a listed case, an internal one (a proposal database may hold
    /// `result-drop`'s proposals) or an external one.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        match TABLE.iter().find(|r| r.name == s) {
            Some(r) => Ok(r.case),
            None => s.parse().map_err(serde::de::Error::custom),
        }
    }
}

/// The prefix of an external detector's case.
pub const EXT_PREFIX: &str = "ext:";
/// The prefix of the refiner on an external detector's proposals.
pub const MLOD_EXT_PREFIX: &str = "mlod-ext:";

/// Checks a detector name: 1–64 of ASCII letters, digits, `_`, `-` and `.`, not starting with
/// `.` or `-` (it becomes part of case names and file names).
pub fn check_name(name: &str) -> Result<(), String> {
    let ok_char = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.');
    let first_ok = name
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_');
    if name.len() > 64 || !first_ok || !name.chars().all(ok_char) {
        return Err(format!(
            "'{name}' is not a detector name: 1-64 letters, digits, '_', '-' or '.', starting with a letter, digit or '_'"
        ));
    }
    Ok(())
}

/// One string per distinct name, for the life of the process.
fn intern(s: String) -> &'static str {
    static NAMES: Mutex<BTreeSet<&'static str>> = Mutex::new(BTreeSet::new());
    let mut names = match NAMES.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    };
    if let Some(found) = names.get(s.as_str()) {
        return found;
    }
    let leaked: &'static str = Box::leak(s.into_boxed_str());
    names.insert(leaked);
    leaked
}

/// The case `ext:NAME` (NAME already checked).
pub fn ext_case(name: &str) -> Case {
    Case::Ext(intern(format!("{EXT_PREFIX}{name}")))
}

/// The case `mlod-ext:NAME` (NAME already checked).
pub fn mlod_ext_case(name: &str) -> Case {
    Case::MlodExt(intern(format!("{MLOD_EXT_PREFIX}{name}")))
}
