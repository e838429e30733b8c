//! Evaluation of predictions against a Lyft-format dataset: the input side of `mlod eval`.
//!
//! Predictions come as a JSON list in the devkit's format (`sample_token`, global-frame
//! `translation`, `size` [w, l, h], `rotation` [w, x, y, z], `name`, `score`). Every record is
//! validated; a bad one (unknown sample token, missing or non-finite field — `NaN`/`Infinity`
//! literals as Python writes them are read, then rejected — non-positive size, non-unit
//! quaternion, no score) is counted, its first offenders are reported with their index and
//! reason, and it is skipped. Nothing is silently accepted.
//!
//! Ground truth is every annotation of the evaluated samples whose category is one of ours
//! (`dataset::categories`; unmapped ones such as KITTI's `Misc` are left out). The Lyft metric runs on the
//! global-frame records as given; KITTI AP_3D and the per-box outcomes run in the base frame
//! (LIDAR_TOP), where the paper measures distances.

#![deny(clippy::indexing_slicing)]

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::Value;
use thiserror::Error;

use super::kitti::{kitti_ap, KittiConfig, KittiReport, SampleBoxes};
use super::localization::{self, with_truth, BoxError, Fix, LocalizationSummary};
use super::lyft::{lyft_map, thresholds, Footprints, LyftBox, LyftMap};
use super::matching::{match_sample, GtOutcome, MatchRule, PredOutcome, SampleMatch};
use crate::dataset::{Dataset, DatasetError, EvalRegion};
use crate::geometry::{Box3d, Detection, Pose};

/// Errors of reading predictions and evaluating them.
#[derive(Debug, Error)]
pub enum EvalError {
    #[error("cannot read predictions {path}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("predictions {path} are not valid JSON")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("predictions {path}: expected a JSON list of boxes (or an object with a \"results\" list)")]
    NotAList { path: PathBuf },
    #[error(
        "dataset {dataset}: no samples to evaluate (its sample table is empty, or the selection left none)"
    )]
    NoSamples { dataset: PathBuf },
    #[error(transparent)]
    Lyft(#[from] DatasetError),
}

/// A rejected prediction: its position in the input list and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Rejected {
    pub index: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample_token: Option<String>,
    pub reason: String,
}

/// Validated predictions: the accepted ones with their input index, and the rejected ones.
#[derive(Debug, Clone, Default)]
pub struct PredictionSet {
    pub accepted: Vec<(usize, LyftBox)>,
    pub rejected: Vec<Rejected>,
    pub total: usize,
}

/// Replace the non-JSON literals `NaN`, `Infinity` and `-Infinity` outside strings by `null`,
/// so a file written by Python's `json.dump` parses and its bad fields can be named.
// `i` is checked against `b.len()` by the loop before every index and slice.
#[allow(clippy::indexing_slicing)]
fn sanitize_non_finite(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let mut last = 0;
    let mut in_string = false;
    while i < b.len() {
        let c = b[i];
        if in_string {
            if c == b'\\' {
                i += 2;
                continue;
            }
            if c == b'"' {
                in_string = false;
            }
            i += 1;
            continue;
        }
        if c == b'"' {
            in_string = true;
            i += 1;
            continue;
        }
        let rest = &b[i..];
        let token = [&b"-Infinity"[..], b"Infinity", b"NaN"]
            .into_iter()
            .find(|t| rest.starts_with(t));
        if let Some(t) = token {
            out.push_str(&text[last..i]);
            out.push_str("null");
            i += t.len();
            last = i;
            continue;
        }
        i += 1;
    }
    out.push_str(&text[last..]);
    out
}

/// Read a predictions file into its raw records (a list, or an object with a list under
/// `results`/`predictions`).
pub fn read_predictions(path: &Path) -> Result<Vec<Value>, EvalError> {
    let text = std::fs::read_to_string(path).map_err(|source| EvalError::Read {
        path: path.to_owned(),
        source,
    })?;
    let doc: Value = serde_json::from_str(&sanitize_non_finite(&text)).map_err(|source| EvalError::Json {
        path: path.to_owned(),
        source,
    })?;
    match doc {
        Value::Array(v) => Ok(v),
        Value::Object(mut m) => ["results", "predictions"]
            .into_iter()
            .find_map(|k| match m.remove(k) {
                Some(Value::Array(v)) => Some(v),
                _ => None,
            })
            .ok_or_else(|| EvalError::NotAList {
                path: path.to_owned(),
            }),
        _ => Err(EvalError::NotAList {
            path: path.to_owned(),
        }),
    }
}

fn numbers<const N: usize>(v: &Value, field: &str) -> Result<[f64; N], String> {
    let arr = v
        .get(field)
        .and_then(Value::as_array)
        .ok_or_else(|| format!("{field} is missing or not a list"))?;
    if arr.len() != N {
        return Err(format!("{field} has {} elements, expected {N}", arr.len()));
    }
    let mut out = [0.0; N];
    for (k, (o, x)) in out.iter_mut().zip(arr).enumerate() {
        *o = x
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{field}[{k}] is not a finite number ({x})"))?;
    }
    Ok(out)
}

/// Largest accepted deviation of a rotation quaternion's norm from 1.
pub const UNIT_TOLERANCE: f64 = 1e-5;

fn parse_one(v: &Value, known: &HashSet<&str>) -> Result<LyftBox, (Option<String>, String)> {
    let token = v.get("sample_token").and_then(Value::as_str).map(str::to_owned);
    let fail = |reason: String| (token.clone(), reason);
    if !v.is_object() {
        return Err(fail("not a JSON object".into()));
    }
    let Some(sample_token) = token.clone() else {
        return Err(fail("sample_token is missing or not a string".into()));
    };
    if !known.contains(sample_token.as_str()) {
        return Err(fail(
            "unknown sample_token (not a sample of the evaluated dataset)".into(),
        ));
    }
    let translation = numbers::<3>(v, "translation").map_err(fail)?;
    let size = numbers::<3>(v, "size").map_err(fail)?;
    if let Some((k, s)) = size.iter().enumerate().find(|(_, &s)| s <= 0.0) {
        return Err(fail(format!("size[{k}] = {s} is not positive")));
    }
    let rotation = numbers::<4>(v, "rotation").map_err(fail)?;
    let norm = rotation.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > UNIT_TOLERANCE {
        return Err(fail(format!("rotation is not a unit quaternion (norm {norm})")));
    }
    let name = v
        .get("name")
        .and_then(Value::as_str)
        .filter(|s| !s.is_empty())
        .ok_or_else(|| fail("name is missing or empty".into()))?;
    let score = v
        .get("score")
        .and_then(Value::as_f64)
        .filter(|s| s.is_finite())
        .ok_or_else(|| fail("score is missing or not a finite number".into()))?;
    Ok(LyftBox {
        sample_token,
        translation,
        size,
        rotation,
        name: name.to_owned(),
        score: Some(score),
    })
}

/// Validate raw records against the sample tokens being evaluated.
pub fn parse_predictions(values: &[Value], known: &HashSet<&str>) -> PredictionSet {
    let mut set = PredictionSet {
        total: values.len(),
        ..Default::default()
    };
    for (index, v) in values.iter().enumerate() {
        match parse_one(v, known) {
            Ok(b) => set.accepted.push((index, b)),
            Err((sample_token, reason)) => set.rejected.push(Rejected {
                index,
                sample_token,
                reason,
            }),
        }
    }
    set
}

/// What to evaluate and how.
#[derive(Debug, Clone, Default)]
pub struct EvalOptions {
    /// Evaluate only the first N samples (dataset order).
    pub samples: Option<usize>,
    pub kitti: KittiConfig,
    /// Report every box's outcome under this rule.
    pub per_box: Option<MatchRule>,
    /// With `per_box`: AP again with each part of the matched boxes taken from the truth.
    pub attribution: bool,
    /// Only the validation scenes of a training dataset (every 10th scene, the split that
    /// training holds out: [`crate::train::stage1::split`]), for tuning without the test split.
    pub validation_only: bool,
    /// Only these samples, in this order (a sweep's spread subset); before `samples`.
    pub only: Option<Vec<String>>,
    /// Also the transfer check (found by centre distance, confident false positives).
    pub transfer: Option<super::transfer::TransferRule>,
}

/// How many predictions were read, used and rejected.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictionSummary {
    pub total: usize,
    pub accepted: usize,
    pub rejected: usize,
    /// The first (up to 10) rejected records.
    pub first_rejected: Vec<Rejected>,
    /// Accepted predictions outside the samples' evaluation regions (KITTI: outside camera 2's
    /// view or in a DontCare region): neither true nor false positives.
    pub outside_region: usize,
}

/// One prediction's outcome in the per-box report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredReport {
    /// Index in the input list (or in the detector's output).
    pub index: usize,
    pub category: String,
    pub score: f32,
    pub range: f64,
    #[serde(flatten)]
    pub outcome: PredOutcome,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gt_annotation: Option<String>,
}

/// One ground-truth box's outcome in the per-box report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GtReport {
    pub annotation_token: String,
    pub category: String,
    pub range: f64,
    #[serde(flatten)]
    pub outcome: GtOutcome,
    /// The matched prediction minus this box (absent unless matched).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<BoxError>,
}

/// Per-box outcomes of one sample.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SampleReport {
    pub sample_token: String,
    pub preds: Vec<PredReport>,
    pub gts: Vec<GtReport>,
}

/// The output of `mlod eval`.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// AP_3D in percent: class → "iou_0.7"/"iou_0.5" → easy/moderate/hard.
    pub kitti: KittiReport,
    /// The official devkit metric (mirrored-heading footprint), in [0, 1].
    pub lyft: LyftMap,
    /// The same with the true footprint.
    pub lyft_exact: LyftMap,
    pub samples: usize,
    pub predictions: PredictionSummary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub per_box: Option<Vec<SampleReport>>,
    /// With `per_box`: per category, how the matches under its rule are localised.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub localization: Option<Vec<LocalizationSummary>>,
    /// With `attribution`: the AP with each part of the matched predictions replaced by the truth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attribution: Option<Vec<Attribution>>,
    /// With `transfer`: the transfer check (issue 29's measures on real frames).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transfer: Option<super::transfer::TransferReport>,
}

/// The AP when one part of every matched prediction's box is taken from its ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct Attribution {
    pub fixed: Fix,
    pub kitti: KittiReport,
}

/// One evaluated sample: ground truth in both frames and the base → global transform.
struct SampleTruth {
    token: String,
    base_to_global: Pose,
    gts: Vec<Detection>,
    gt_tokens: Vec<String>,
    /// Per ground-truth box: what the transfer check's per-car table shows beyond the box.
    gt_info: Vec<super::transfer::GtInfo>,
    lyft: Vec<LyftBox>,
    /// Where the format evaluates (KITTI: camera 2's view without DontCare regions); predictions
    /// outside it are neither true nor false positives.
    region: Option<EvalRegion>,
}

impl SampleTruth {
    fn evaluates(&self, b: &Box3d) -> bool {
        self.region.as_ref().is_none_or(|r| r.contains(b))
    }
}

fn truth(dataset: &Dataset, token: &str, transfer: bool) -> Result<SampleTruth, DatasetError> {
    let mut info = dataset.frame_info(token)?;
    // Categories with no counterpart among ours (nuScenes barriers, KITTI Misc) are never scored.
    info.boxes
        .retain(|b| crate::dataset::categories::canonical(&b.category).is_some());
    let base_to_global = info.primary.ego_to_global * info.primary.sensor_to_ego;
    let category: HashMap<&str, &str> = info
        .boxes
        .iter()
        .map(|b| (b.annotation_token.as_str(), b.category.as_str()))
        .collect();
    let t = dataset.tables();
    let lyft = dataset
        .annotation_rows(token)
        .iter()
        .filter_map(|&i| t.sample_annotation.rows().get(i))
        .filter_map(|a| {
            category.get(a.token.as_str()).map(|c| LyftBox {
                sample_token: token.to_owned(),
                translation: a.translation,
                size: a.size,
                rotation: a.rotation,
                name: (*c).to_owned(),
                score: None,
            })
        })
        .collect();
    // The transfer check's table counts each box's points (every LiDAR, base frame, unperturbed).
    let points: Option<Vec<usize>> = if transfer {
        let frame = dataset.frame(token)?;
        crate::pipeline::fuse(&frame, &crate::pipeline::FuseParams::default())
            .ok()
            .map(|c| {
                info.boxes
                    .iter()
                    .map(|b| crate::pipeline::box_stats(&c, &b.box3d).points)
                    .collect()
            })
    } else {
        None
    };
    let gt_info = info
        .boxes
        .iter()
        .enumerate()
        .map(|(k, b)| super::transfer::GtInfo {
            points: points.as_ref().and_then(|p| p.get(k).copied()),
            occlusion: b.occlusion,
            truncation: b.truncation,
        })
        .collect();
    Ok(SampleTruth {
        token: token.to_owned(),
        base_to_global,
        gt_info,
        gts: info.boxes.iter().map(|b| b.as_detection()).collect(),
        gt_tokens: info.boxes.iter().map(|b| b.annotation_token.clone()).collect(),
        lyft,
        region: info.eval_region,
    })
}

/// A global-frame devkit record as a base-frame box, the way the loader turns annotations into
/// base-frame boxes (so a prediction equal to an annotation lands exactly on its GT box).
fn to_base(b: &LyftBox, global_to_base: &Pose) -> Box3d {
    let c = global_to_base.transform_point(&nalgebra::Point3::from(b.translation));
    let rot = global_to_base.rotation * b.unit_rotation();
    Box3d::from_lyft([c.x, c.y, c.z], b.size, &rot)
}

fn evaluated_tokens(dataset: &Dataset, opts: &EvalOptions) -> Vec<String> {
    let mut all: Vec<String> = if let Some(only) = &opts.only {
        only.clone()
    } else if opts.validation_only {
        crate::dataset::train_validation_split(dataset).1
    } else {
        dataset.sample_tokens().iter().map(|s| (*s).to_owned()).collect()
    };
    all.truncate(opts.samples.unwrap_or(all.len()));
    all
}

/// The sample tokens `evaluate` will use (for validating predictions before evaluating).
pub fn sample_tokens(dataset: &Dataset, opts: &EvalOptions) -> Vec<String> {
    evaluated_tokens(dataset, opts)
}

/// Ground truth of every evaluated sample.
fn truths(dataset: &Dataset, opts: &EvalOptions) -> Result<Vec<SampleTruth>, EvalError> {
    let tokens = evaluated_tokens(dataset, opts);
    if tokens.is_empty() {
        return Err(EvalError::NoSamples {
            dataset: dataset.root().to_path_buf(),
        });
    }
    Ok(tokens
        .iter()
        .map(|t| truth(dataset, t, opts.transfer.is_some()))
        .collect::<Result<Vec<_>, _>>()?)
}

/// Evaluate devkit-format predictions (already validated) on a dataset.
pub fn evaluate(
    dataset: &Dataset,
    preds: &PredictionSet,
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let truths = truths(dataset, opts)?;
    let mut by_sample: HashMap<&str, Vec<(usize, Detection)>> = HashMap::new();
    let g2b: HashMap<&str, Pose> = truths
        .iter()
        .map(|s| (s.token.as_str(), s.base_to_global.inverse()))
        .collect();
    let by_token: HashMap<&str, &SampleTruth> = truths.iter().map(|s| (s.token.as_str(), s)).collect();
    let mut lyft_preds: Vec<LyftBox> = Vec::with_capacity(preds.accepted.len());
    for (index, b) in &preds.accepted {
        let Some(pose) = g2b.get(b.sample_token.as_str()) else {
            lyft_preds.push(b.clone());
            continue;
        };
        let box3d = to_base(b, pose);
        if !by_token
            .get(b.sample_token.as_str())
            .is_none_or(|s| s.evaluates(&box3d))
        {
            continue;
        }
        lyft_preds.push(b.clone());
        by_sample.entry(b.sample_token.as_str()).or_default().push((
            *index,
            Detection {
                box3d,
                score: b.score.unwrap_or(0.0) as f32,
                category: b.name.clone(),
            },
        ));
    }
    Ok(finish(&truths, &by_sample, lyft_preds, preds, opts))
}

/// Evaluate base-frame detections (a detector's output), keyed by sample token; the Lyft metric
/// sees them converted to the devkit's global-frame records.
pub fn evaluate_detections(
    dataset: &Dataset,
    detections: &HashMap<String, Vec<Detection>>,
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let truths = truths(dataset, opts)?;
    let mut by_sample: HashMap<&str, Vec<(usize, Detection)>> = HashMap::new();
    let mut lyft_preds = Vec::new();
    let mut total = 0;
    for s in &truths {
        let dets = detections.get(&s.token).map(Vec::as_slice).unwrap_or(&[]);
        let kept: Vec<(usize, Detection)> = dets
            .iter()
            .cloned()
            .enumerate()
            .filter(|(_, d)| s.evaluates(&d.box3d))
            .collect();
        for (_, d) in &kept {
            lyft_preds.push(LyftBox::from_base(
                &s.token,
                &d.box3d,
                &s.base_to_global,
                &d.category,
                Some(f64::from(d.score)),
            ));
        }
        by_sample.insert(s.token.as_str(), kept);
        total += dets.len();
    }
    let set = PredictionSet {
        accepted: Vec::new(),
        rejected: Vec::new(),
        total,
    };
    let mut report = finish(&truths, &by_sample, lyft_preds, &set, opts);
    report.predictions.accepted = total;
    report.predictions.outside_region = total.saturating_sub(by_sample.values().map(Vec::len).sum::<usize>());
    Ok(report)
}

fn finish(
    truths: &[SampleTruth],
    by_sample: &HashMap<&str, Vec<(usize, Detection)>>,
    lyft_preds: Vec<LyftBox>,
    preds: &PredictionSet,
    opts: &EvalOptions,
) -> EvalReport {
    let empty = Vec::new();
    let samples: Vec<SampleBoxes> = truths
        .iter()
        .map(|s| SampleBoxes {
            preds: by_sample
                .get(s.token.as_str())
                .unwrap_or(&empty)
                .iter()
                .map(|(_, d)| d.clone())
                .collect(),
            gts: s.gts.clone(),
        })
        .collect();
    let kitti = kitti_ap(&samples, &opts.kitti);
    let transfer = opts.transfer.as_ref().map(|rule| {
        let frames: Vec<super::transfer::TransferFrame> = truths
            .iter()
            .map(|s| super::transfer::TransferFrame {
                token: s.token.clone(),
                gts: s.gt_info.clone(),
            })
            .collect();
        super::transfer::transfer_check_with(&samples, &frames, rule)
    });
    let lyft_gt: Vec<LyftBox> = truths.iter().flat_map(|s| s.lyft.iter().cloned()).collect();
    let th = thresholds();
    let lyft = lyft_map(&lyft_gt, &lyft_preds, &th, Footprints::Devkit);
    let lyft_exact = lyft_map(&lyft_gt, &lyft_preds, &th, Footprints::Exact);
    let matches: Option<Vec<SampleMatch>> = opts.per_box.map(|rule| {
        samples
            .iter()
            .map(|sb| match_sample(&sb.preds, &sb.gts, &rule))
            .collect()
    });
    let per_box = matches.as_ref().map(|matches| {
        truths
            .iter()
            .zip(&samples)
            .zip(matches)
            .map(|((s, sb), m)| {
                let idx = by_sample.get(s.token.as_str()).unwrap_or(&empty);
                SampleReport {
                    sample_token: s.token.clone(),
                    preds: sb
                        .preds
                        .iter()
                        .zip(&m.preds)
                        .zip(idx)
                        .map(|((d, o), (index, _))| PredReport {
                            index: *index,
                            category: d.category.clone(),
                            score: d.score,
                            range: d.box3d.bev_range(),
                            outcome: *o,
                            gt_annotation: match o {
                                PredOutcome::TruePositive { gt, .. } => s.gt_tokens.get(*gt).cloned(),
                                _ => None,
                            },
                        })
                        .collect(),
                    gts: sb
                        .gts
                        .iter()
                        .zip(&m.gts)
                        .zip(&s.gt_tokens)
                        .map(|((g, o), tok)| GtReport {
                            annotation_token: tok.clone(),
                            category: g.category.clone(),
                            range: g.box3d.bev_range(),
                            outcome: *o,
                            error: match o {
                                GtOutcome::Matched { pred, .. } => {
                                    sb.preds.get(*pred).map(|p| BoxError::between(&p.box3d, &g.box3d))
                                }
                                _ => None,
                            },
                        })
                        .collect(),
                }
            })
            .collect()
    });
    let localization = matches.as_ref().map(|matches| {
        let pairs: Vec<(&Detection, &Detection)> = samples
            .iter()
            .zip(matches)
            .flat_map(|(sb, m)| {
                m.gts
                    .iter()
                    .zip(&sb.gts)
                    .filter_map(|(o, g)| match o {
                        GtOutcome::Matched { pred, .. } => sb.preds.get(*pred).map(|p| (p, g)),
                        _ => None,
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        localization::summarize(pairs)
    });
    let attribution = matches.as_ref().filter(|_| opts.attribution).map(|matches| {
        Fix::ALL
            .iter()
            .map(|&fix| {
                let edited: Vec<SampleBoxes> = samples
                    .iter()
                    .zip(matches)
                    .map(|(sb, m)| {
                        let mut preds = sb.preds.clone();
                        for (o, g) in m.gts.iter().zip(&sb.gts) {
                            if let GtOutcome::Matched { pred, .. } = o {
                                if let Some(p) = preds.get_mut(*pred) {
                                    p.box3d = with_truth(&p.box3d, &g.box3d, fix);
                                }
                            }
                        }
                        SampleBoxes {
                            preds,
                            gts: sb.gts.clone(),
                        }
                    })
                    .collect();
                Attribution {
                    fixed: fix,
                    kitti: kitti_ap(&edited, &opts.kitti),
                }
            })
            .collect()
    });
    EvalReport {
        attribution,
        transfer,
        localization,
        kitti,
        lyft,
        lyft_exact,
        samples: truths.len(),
        predictions: PredictionSummary {
            total: preds.total,
            accepted: preds.accepted.len(),
            rejected: preds.rejected.len(),
            first_rejected: preds.rejected.iter().take(10).cloned().collect(),
            outside_region: preds
                .accepted
                .len()
                .saturating_sub(by_sample.values().map(Vec::len).sum::<usize>()),
        },
        per_box,
    }
}

/// Recall of one category per BEV range band, from per-box outcomes: `bands` are the upper
/// edges (m, increasing; the first band starts at 0). Per band: (ground truth boxes not ignored,
/// of them matched). Boxes at or beyond the last edge are not counted.
pub fn recall_by_range(per_box: &[SampleReport], category: &str, bands: &[f64]) -> Vec<(usize, usize)> {
    let mut out = vec![(0usize, 0usize); bands.len()];
    for g in per_box
        .iter()
        .flat_map(|s| &s.gts)
        .filter(|g| g.category == category)
    {
        let Some(b) = bands.iter().position(|&edge| g.range < edge) else {
            continue;
        };
        let Some(slot) = out.get_mut(b) else { continue };
        match g.outcome {
            GtOutcome::Matched { .. } => {
                slot.0 += 1;
                slot.1 += 1;
            }
            GtOutcome::Missed => slot.0 += 1,
            GtOutcome::Ignored => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recall_by_range_counts_matched_and_missed_per_band() {
        let gt = |range: f64, outcome: GtOutcome, category: &str| GtReport {
            annotation_token: String::new(),
            category: category.into(),
            range,
            outcome,
            error: None,
        };
        let hit = GtOutcome::Matched { pred: 0, iou: 0.8 };
        let per_box = vec![SampleReport {
            sample_token: "s".into(),
            preds: Vec::new(),
            gts: vec![
                gt(5.0, hit, "car"),
                gt(9.9, GtOutcome::Missed, "car"),
                gt(12.0, hit, "car"),
                gt(15.0, GtOutcome::Ignored, "car"),
                gt(3.0, hit, "pedestrian"),
                gt(25.0, GtOutcome::Missed, "car"),
            ],
        }];
        assert_eq!(
            recall_by_range(&per_box, "car", &[10.0, 20.0]),
            vec![(2, 1), (1, 1)]
        );
        assert_eq!(
            recall_by_range(&per_box, "car", &[]),
            Vec::<(usize, usize)>::new()
        );
    }
    use serde_json::json;

    #[test]
    fn non_finite_literals_become_null_outside_strings() {
        let s =
            sanitize_non_finite(r#"[{"a": NaN, "b": "NaN \" Infinity", "c": [-Infinity, Infinity, 1.5]}]"#);
        assert_eq!(
            s,
            r#"[{"a": null, "b": "NaN \" Infinity", "c": [null, null, 1.5]}]"#
        );
    }

    #[test]
    fn bad_records_are_rejected_with_a_reason() {
        let known: HashSet<&str> = ["s1"].into_iter().collect();
        let good = json!({"sample_token": "s1", "translation": [1, 2, 3], "size": [2, 4, 1.5],
                          "rotation": [1, 0, 0, 0], "name": "car", "score": 0.5});
        let mut records = vec![good.clone()];
        let mut bad = |f: &dyn Fn(&mut Value)| {
            let mut v = good.clone();
            f(&mut v);
            records.push(v);
        };
        bad(&|v| v["sample_token"] = json!("nope"));
        bad(&|v| v["translation"] = json!([1, null, 3]));
        bad(&|v| v["size"] = json!([2, -4, 1.5]));
        bad(&|v| v["rotation"] = json!([1, 0, 0, 0.5]));
        bad(&|v| v["score"] = json!(null));
        bad(&|v| v["name"] = json!(""));
        bad(&|v| v["size"] = json!([2, 4]));
        records.push(json!(42));
        let set = parse_predictions(&records, &known);
        assert_eq!(set.accepted.len(), 1);
        assert_eq!(set.total, 9);
        let reasons: Vec<&str> = set.rejected.iter().map(|r| r.reason.as_str()).collect();
        assert!(reasons[0].contains("unknown sample_token"));
        assert!(reasons[1].contains("translation[1]"));
        assert!(reasons[2].contains("size[1] = -4"));
        assert!(reasons[3].contains("unit quaternion"));
        assert!(reasons[4].contains("score"));
        assert!(reasons[5].contains("name"));
        assert!(reasons[6].contains("3"));
        assert_eq!(set.rejected[7].index, 8);
    }
}
