//! A trained refiner and the MLOD detectors (MLOD-I/F/R = Input/Feature/Result Fusion followed by
//! the refiner, paper §IV-B).
//!
//! How it works: the stage-1 detector of the case proposes boxes on the frame fused with the
//! caller's perturbation; the frame is fused again (the same cloud, with tr(Ξ)) and indexed once;
//! for every proposal of the refiner's category its points are gathered, normalised (eq. 12–13) and
//! 1024 of them drawn with a generator seeded by the proposal's rank (so a run is reproducible bit
//! for bit), and the folded network gives an objectness logit and the residuals of eq. 14. The
//! refined box is the proposal ⊕ residuals; its score is made as the manifest's decoding says
//! (`refined`: sigmoid of the logit, `stage1`: the proposal's, `mean`: their geometric mean), and
//! an optional 3D-IoU NMS follows. A proposal without a single point keeps its box and its stage-1
//! score (the network has nothing to look at). Proposals of other categories pass through.

#![deny(clippy::indexing_slicing)]

use std::path::Path;

use candle_core::Tensor;

use super::coding::decode_f32;
use super::infer::{FastRefiner, RefinerRun};
use super::net::{proposal_features, RefinerConfig, PROPOSAL_FEATURES};
use super::points::{gather, sample, CloudIndex};
use super::RefineError;
use crate::detect::weights::{read_weights, Manifest, RefineTuning};
use crate::detect::{Case, Detection};
use crate::geometry::{nms, vote, Box3d, IouKind};
use crate::pipeline::FusedCloud;

/// 3D IoU above which the NMS after refinement suppresses a union case's box (chosen on the
/// validation scenes, docs/robustness.md).
pub const UNION_NMS_IOU: f64 = 0.5;

/// The file name of the shipped refiner in a models folder.
pub const REFINER_FILE: &str = "refiner.safetensors";

/// Cell of the cloud index, m.
const INDEX_CELL: f64 = 2.0;

/// How the refined score is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScoreRule {
    Refined,
    Stage1,
    Mean,
}

impl ScoreRule {
    pub const ALL: [ScoreRule; 3] = [ScoreRule::Refined, ScoreRule::Stage1, ScoreRule::Mean];

    pub fn as_str(self) -> &'static str {
        match self {
            ScoreRule::Refined => "refined",
            ScoreRule::Stage1 => "stage1",
            ScoreRule::Mean => "mean",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.as_str() == s)
    }

    fn combine(self, stage1: f32, refined: f32) -> f32 {
        match self {
            ScoreRule::Refined => refined,
            ScoreRule::Stage1 => stage1,
            ScoreRule::Mean => (stage1.max(0.0) * refined.max(0.0)).sqrt(),
        }
    }
}

/// The refiner's decoding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoding {
    pub score: ScoreRule,
    /// 3D-IoU NMS after refinement (`None`: none).
    pub nms_iou: Option<f64>,
    /// The 3D-IoU NMS after refinement of the union cases (`mlod-u`, `mlod-ir-drop`), which always
    /// need one: both stage-1 views may propose the same car.
    pub union_nms_iou: f64,
    /// Box voting after the NMS (3D IoU): each kept box becomes the score-weighted mean of the
    /// refined boxes overlapping it by at least this IoU (`None`: none). What a case runs.
    pub vote_iou: Option<f64>,
    /// The union cases' box voting after their NMS: two stage 1s' refined boxes of one car vote.
    pub union_vote_iou: Option<f64>,
}

impl Default for Decoding {
    fn default() -> Self {
        Self {
            score: ScoreRule::Refined,
            nms_iou: None,
            union_nms_iou: UNION_NMS_IOU,
            vote_iou: None,
            union_vote_iou: None,
        }
    }
}

impl Decoding {
    /// The decoding `case` runs: a union case's NMS is `union_nms_iou`.
    pub fn for_case(self, case: Case) -> Self {
        Self {
            nms_iou: if case.is_union() {
                Some(self.union_nms_iou)
            } else {
                self.nms_iou
            },
            vote_iou: if case.is_union() {
                self.union_vote_iou
            } else {
                None
            },
            ..self
        }
    }

    /// The decoding a manifest records (the default when it records none).
    pub fn of(t: Option<&RefineTuning>) -> Result<Self, String> {
        let Some(t) = t else { return Ok(Self::default()) };
        let score = ScoreRule::parse(&t.score)
            .ok_or_else(|| format!("refine.score {:?} is not refined, stage1 or mean", t.score))?;
        for (field, v) in [
            ("nms_iou", t.nms_iou),
            ("union_nms_iou", t.union_nms_iou),
            ("union_vote_iou", t.union_vote_iou),
        ] {
            if let Some(v) = v {
                if !(v > 0.0 && v <= 1.0) {
                    return Err(format!("refine.{field} {v} is not in (0, 1]"));
                }
            }
        }
        Ok(Self {
            score,
            nms_iou: t.nms_iou,
            union_nms_iou: t.union_nms_iou.unwrap_or(UNION_NMS_IOU),
            vote_iou: None,
            union_vote_iou: t.union_vote_iou,
        })
    }
}

/// One refined proposal.
#[derive(Debug, Clone, PartialEq)]
pub struct Refined {
    /// The refined box, its decoded score and category.
    pub detection: Detection,
    /// The proposal it came from (index into the proposals given).
    pub proposal: usize,
    /// The classification head's probability (the stage-1 score when unrefined).
    pub refined_score: f32,
    /// Fused-cloud indices of the active points: the points that won the max-pool in at least one
    /// channel (§V-C), distinct, ascending.
    pub active: Vec<u32>,
    /// Fused-cloud indices of the points the network was given (the sampled rows), distinct,
    /// ascending.
    pub input: Vec<u32>,
    /// How many points the enlarged box held.
    pub gathered: usize,
    /// Whether the network saw no point and the proposal was kept as it was.
    pub unrefined: bool,
}

/// A trained stage-2 refiner.
#[derive(Debug, Clone)]
pub struct Refiner {
    pub config: RefinerConfig,
    pub decoding: Decoding,
    fast: FastRefiner,
}

impl Refiner {
    /// A refiner from its configuration and tensors.
    pub fn from_tensors(
        config: RefinerConfig,
        get: &dyn Fn(&str) -> Option<Tensor>,
        decoding: Decoding,
    ) -> Result<Self, RefineError> {
        Ok(Self {
            fast: FastRefiner::build(&config, get)?,
            config,
            decoding,
        })
    }

    /// Loads a weights file (its sha256 checked when given).
    pub fn load(path: &Path, expected_sha256: Option<&str>, decoding: Decoding) -> Result<Self, RefineError> {
        let w = read_weights(path, expected_sha256)?;
        let bad = |what: String| RefineError::File {
            path: path.to_path_buf(),
            what,
        };
        let cfg = w
            .metadata
            .get("mlod.refiner")
            .ok_or_else(|| bad("no mlod.refiner configuration in its metadata (not a refiner?)".into()))?;
        let config: RefinerConfig =
            serde_json::from_str(cfg).map_err(|e| bad(format!("bad mlod.refiner: {e}")))?;
        Self::from_tensors(config, &|n: &str| w.tensors.get(n).cloned(), decoding)
            .map_err(|e| bad(e.to_string()))
    }

    /// The refiner of a models folder, checked against its manifest, with the manifest's decoding.
    pub fn load_shipped(dir: &Path) -> Result<Self, RefineError> {
        Self::load_shipped_for(dir, Case::MlodI)
    }

    /// The refiner an MLOD case runs: the manifest's `refiner`, or its `refiner_notrace` for the
    /// ablation [`Case::MlodINoTrace`].
    pub fn load_shipped_for(dir: &Path, case: Case) -> Result<Self, RefineError> {
        let manifest = Manifest::load(dir)?;
        let (entry, train) = if case.refiner_sees_trace() {
            (manifest.refiner.as_ref(), "mlod train refiner")
        } else {
            (manifest.refiner_notrace.as_ref(), "mlod train refiner --no-trace")
        };
        let entry = entry.ok_or_else(|| RefineError::File {
            path: dir.join(Manifest::FILE),
            what: format!("no refiner for {case}: train one with `{train}`"),
        })?;
        let decoding = Decoding::of(manifest.refine.as_ref()).map_err(|what| RefineError::File {
            path: dir.join(Manifest::FILE),
            what,
        })?;
        let path = entry.path_in(dir).map_err(|e| RefineError::File {
            path: dir.join(Manifest::FILE),
            what: e.to_string(),
        })?;
        let refiner = Self::load(&path, Some(&entry.sha256), decoding)?;
        if refiner.config.gather.features.trace != case.refiner_sees_trace() {
            return Err(RefineError::File {
                path,
                what: format!(
                    "its points {} tr(Ξ), but {case}'s refiner must {}",
                    if refiner.config.gather.features.trace {
                        "carry"
                    } else {
                        "lack"
                    },
                    if case.refiner_sees_trace() {
                        "see it"
                    } else {
                        "not see it"
                    }
                ),
            });
        }
        Ok(refiner)
    }

    /// Refines `proposals` on `cloud` (boxes in the base frame). The refined boxes come in the
    /// proposals' order, then the decoding's NMS (if any) drops some; best score first.
    pub fn refine(&self, cloud: &FusedCloud, proposals: &[Detection]) -> Result<Vec<Refined>, RefineError> {
        let index = CloudIndex::new(cloud, INDEX_CELL);
        self.refine_indexed(cloud, &index, proposals)
    }

    /// [`Self::refine`] with an index the caller built.
    // `mine` holds positions in `proposals`; `inputs` is `mine` mapped, so `k_mine` indexes both;
    // `pts.index` is indexed by the sampler's picks, which are positions in `pts`.
    #[allow(clippy::indexing_slicing)]
    pub fn refine_indexed(
        &self,
        cloud: &FusedCloud,
        index: &CloudIndex,
        proposals: &[Detection],
    ) -> Result<Vec<Refined>, RefineError> {
        let n = self.config.gather.points;
        let mine: Vec<usize> = (0..proposals.len())
            .filter(|&i| proposals[i].category == self.config.category && proposals[i].box3d.is_valid())
            .collect();
        // Gather, sample and run in parallel; the sampling seed of proposal i is i.
        use rayon::prelude::*;
        let inputs: Vec<Prepared> = mine
            .par_iter()
            .map(|&i| {
                let p = &proposals[i];
                let pts = gather(cloud, index, &p.box3d, &self.config.gather);
                let s = sample(&pts, n, i as u64);
                Prepared {
                    pick: s.pick.iter().map(|&k| pts.index[k as usize]).collect(),
                    rows: s.rows,
                    gathered: pts.len(),
                    features: proposal_features(&p.box3d, p.score),
                }
            })
            .collect();
        let runs: Vec<RefinerRun> = inputs
            .par_iter()
            .filter(|p| !p.pick.is_empty())
            .map(|p| self.fast.run(&p.rows, n, &p.features))
            .collect::<Result<_, _>>()?;
        let mut runs = runs.into_iter();
        let mut out = Vec::with_capacity(proposals.len());
        let mut k_mine = 0;
        for (i, p) in proposals.iter().enumerate() {
            if mine.get(k_mine) != Some(&i) {
                out.push(passthrough(i, p, 0));
                continue;
            }
            let Prepared { pick, gathered, .. } = &inputs[k_mine];
            k_mine += 1;
            if pick.is_empty() {
                out.push(passthrough(i, p, *gathered));
                continue;
            }
            let Some(run) = runs.next() else {
                return Err(RefineError::Shape(
                    "fewer network runs than proposals with points".into(),
                ));
            };
            let prob = 1.0 / (1.0 + (-run.logit).exp());
            let mut active: Vec<u32> = run
                .argmax
                .iter()
                .filter_map(|&r| pick.get(r as usize).copied())
                .collect();
            active.sort_unstable();
            active.dedup();
            let mut input = pick.clone();
            input.sort_unstable();
            input.dedup();
            out.push(Refined {
                detection: Detection {
                    box3d: decode_f32(&p.box3d, &run.residuals),
                    score: self.decoding.score.combine(p.score, prob),
                    category: p.category.clone(),
                },
                proposal: i,
                refined_score: prob,
                active,
                input,
                gathered: *gathered,
                unrefined: false,
            });
        }
        Ok(rank_and_suppress(
            out,
            self.decoding.nms_iou,
            self.decoding.vote_iou,
        ))
    }
}

/// The refined detections of a run decoded another way (`run` made with any decoding): each
/// refined box's score made again from its proposal's and the head's probability, then the NMS.
/// What `mlod train tune-refiner` compares without running the network again.
pub fn redecode(run: &MlodRun, d: Decoding) -> Vec<Detection> {
    let rescored: Vec<Refined> = run
        .refined
        .iter()
        .map(|r| {
            let stage1 = run.proposals.get(r.proposal).map_or(r.refined_score, |p| p.score);
            let mut r = r.clone();
            if !r.unrefined {
                r.detection.score = d.score.combine(stage1, r.refined_score);
            } else {
                r.detection.score = stage1;
            }
            r
        })
        .collect();
    rank_and_suppress(rescored, d.nms_iou, d.vote_iou)
        .into_iter()
        .map(|r| r.detection)
        .collect()
}

/// Best score first (ties: the earlier proposal first), then the decoding's 3D-IoU NMS if any,
/// then its box voting if any (the kept boxes' scores stay theirs).
fn rank_and_suppress(mut out: Vec<Refined>, nms_iou: Option<f64>, vote_iou: Option<f64>) -> Vec<Refined> {
    out.sort_by(|a, b| {
        b.detection
            .score
            .total_cmp(&a.detection.score)
            .then(a.proposal.cmp(&b.proposal))
    });
    if let Some(iou) = nms_iou {
        let boxes: Vec<Box3d> = out.iter().map(|r| r.detection.box3d).collect();
        let scores: Vec<f32> = out.iter().map(|r| r.detection.score).collect();
        let kept = nms(&boxes, &scores, iou, IouKind::ThreeD);
        let keep: std::collections::HashSet<usize> = kept.iter().copied().collect();
        if let Some(v) = vote_iou {
            let voted = vote(&boxes, &scores, &kept, v, IouKind::ThreeD);
            for (k, b) in kept.iter().zip(voted) {
                if let Some(r) = out.get_mut(*k) {
                    r.detection.box3d = b;
                }
            }
        }
        out = out
            .into_iter()
            .enumerate()
            .filter(|(k, _)| keep.contains(k))
            .map(|(_, r)| r)
            .collect();
    }
    out
}

/// A proposal's sampled points, ready for the network.
struct Prepared {
    /// Fused-cloud index of each sampled row (empty: no point).
    pick: Vec<u32>,
    rows: Vec<f32>,
    gathered: usize,
    features: [f32; PROPOSAL_FEATURES],
}

fn passthrough(i: usize, p: &Detection, gathered: usize) -> Refined {
    Refined {
        detection: p.clone(),
        proposal: i,
        refined_score: p.score,
        active: Vec::new(),
        input: Vec::new(),
        gathered,
        unrefined: true,
    }
}

/// Proposals and their refinements of one frame.
#[derive(Debug, Clone)]
pub struct MlodRun {
    /// Stage 1's boxes, highest score first.
    pub proposals: Vec<Detection>,
    /// The refined boxes, highest score first, each linked to its proposal.
    pub refined: Vec<Refined>,
    /// The fused cloud both saw.
    pub cloud: FusedCloud,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_cases_decode_with_their_own_nms() {
        let mut t = RefineTuning {
            score: "mean".into(),
            nms_iou: None,
            union_nms_iou: None,
            union_vote_iou: None,
            command: String::new(),
            validation: Default::default(),
        };
        let d = Decoding::of(Some(&t)).unwrap();
        assert_eq!(d.for_case(Case::MlodI).nms_iou, None);
        assert_eq!(d.for_case(Case::MlodU).nms_iou, Some(UNION_NMS_IOU));
        assert_eq!(d.for_case(Case::MlodIrDrop).nms_iou, Some(UNION_NMS_IOU));
        t.union_nms_iou = Some(0.3);
        t.nms_iou = Some(0.1);
        let d = Decoding::of(Some(&t)).unwrap();
        assert_eq!(d.for_case(Case::MlodU).nms_iou, Some(0.3));
        assert_eq!(d.for_case(Case::MlodF).nms_iou, Some(0.1));
        t.union_nms_iou = Some(1.5);
        let e = Decoding::of(Some(&t)).unwrap_err();
        assert!(e.contains("union_nms_iou"), "{e}");
        // A manifest written before the field existed reads as no choice.
        let old = r#"{"score":"mean","nms_iou":null,"command":"","validation":{}}"#;
        let parsed: RefineTuning = serde_json::from_str(old).unwrap();
        assert_eq!(parsed.union_nms_iou, None);
    }

    fn refined(x: f64, score: f32, proposal: usize) -> Refined {
        Refined {
            detection: Detection {
                box3d: Box3d::new([x, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0),
                score,
                category: "car".into(),
            },
            proposal,
            refined_score: score,
            active: Vec::new(),
            input: Vec::new(),
            gathered: 0,
            unrefined: false,
        }
    }

    #[test]
    fn a_union_case_votes_after_its_nms() {
        let t = RefineTuning {
            score: "mean".into(),
            nms_iou: None,
            union_nms_iou: Some(0.3),
            union_vote_iou: Some(0.5),
            command: String::new(),
            validation: Default::default(),
        };
        let d = Decoding::of(Some(&t)).unwrap();
        assert_eq!(d.for_case(Case::MlodIrDrop).vote_iou, Some(0.5));
        assert_eq!(d.for_case(Case::MlodU).vote_iou, Some(0.5));
        assert_eq!(d.for_case(Case::MlodINoTrace).vote_iou, None);
        assert_eq!(d.for_case(Case::MlodI).vote_iou, None);
        // Two refinements of one car 0.4 m apart (3D IoU 0.82), equal scores, and a far car.
        let out = vec![refined(0.0, 0.9, 0), refined(0.4, 0.9, 1), refined(20.0, 0.5, 2)];
        let plain = rank_and_suppress(out.clone(), Some(0.3), None);
        let voted = rank_and_suppress(out, Some(0.3), Some(0.5));
        assert_eq!(plain.len(), 2);
        assert_eq!(voted.len(), 2);
        assert_eq!(plain[0].detection.box3d.center[0], 0.0);
        // The kept box moves to the mean of the two; its score and the far car stay.
        assert!((voted[0].detection.box3d.center[0] - 0.2).abs() < 1e-9);
        assert_eq!(voted[0].detection.score, 0.9);
        assert_eq!(voted[1], plain[1]);
        // A vote IoU above 1 is refused when read from a manifest.
        let bad = RefineTuning {
            union_vote_iou: Some(1.5),
            ..t
        };
        assert!(Decoding::of(Some(&bad)).unwrap_err().contains("union_vote_iou"));
    }
}
