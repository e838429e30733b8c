//! A stage-1 model: configuration + network + anchors, from points to [`Detection`]s, and the
//! [`Detector`] of every case (paper §IV-A).
//!
//! How it works: the frame is fused once with the caller's [`FuseParams`] (so perturbed extrinsics
//! reach the auxiliary LiDARs' points); each network branch voxelises the points it is given —
//! one LiDAR's slice of the fused cloud (LiDAR-Top/Left/Right and the Feature Fusion branches) or
//! the whole cloud (Input Fusion). Decoding keeps anchors whose sigmoid score passes the
//! threshold (at most `pre_nms`, best first), decodes SECOND's residuals, puts the heading in the
//! half-turn the direction head chose and runs BEV NMS. Result Fusion (eq. 11) runs the three
//! single-LiDAR detectors, rescales each one's logits by its fitted temperature (Guo et al.,
//! temperature scaling) and merges all boxes with NMS on 3D IoU.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};

use super::anchors::{apply_direction, box3d_of, decode, Anchors};
pub use super::config::ModelConfig;
use super::infer::{FastNet, RawHeads};
use super::net::{HeadOutput, Stage1Net};
use super::voxel::{voxelize, Bev, PointsRef};
use super::weights::{encode_safetensors, read_weights, Manifest};
use super::{Case, DetectError, Detection, Detector};
use crate::dataset::{Frame, LidarChannel};
use crate::geometry::{nms, vote, Box3d, IouKind};
use crate::pipeline::FusedCloud;

/// The points each branch of a case sees, as slices of the fused cloud (`None`: LiDAR absent).
pub fn branch_points<'a>(case: Case, cloud: &'a FusedCloud) -> Vec<Option<PointsRef<'a>>> {
    let slice = |r: std::ops::Range<usize>| PointsRef {
        x: &cloud.x[r.clone()],
        y: &cloud.y[r.clone()],
        z: &cloud.z[r.clone()],
        intensity: &cloud.intensity[r.clone()],
        trace: cloud.trace.get(r).unwrap_or(&[]),
    };
    let of = |ch: LidarChannel| {
        cloud
            .lidars
            .iter()
            .find(|l| l.channel == ch)
            .filter(|l| l.range.end <= cloud.len() && l.range.end <= cloud.intensity.len())
            .map(|l| slice(l.range.clone()))
    };
    match case {
        Case::Input => vec![Some(slice(0..cloud.len().min(cloud.intensity.len())))],
        Case::Feature => LidarChannel::ALL.iter().map(|c| of(*c)).collect(),
        c => vec![c.channel().and_then(of)],
    }
}

/// A BEV as a `[1, C, n, n]` tensor.
pub fn bev_tensor(bev: &Bev) -> candle_core::Result<Tensor> {
    Tensor::from_slice(&bev.data, (1, bev.channels, bev.n, bev.n), &Device::Cpu)
}

/// A stage-1 network with its configuration and anchors.
pub struct Stage1Model {
    pub config: ModelConfig,
    pub net: Stage1Net,
    pub anchors: Anchors,
    /// The trainable variables (present when built for training).
    pub varmap: Option<VarMap>,
    /// The folded inference network (present for loaded, frozen weights).
    pub fast: Option<FastNet>,
}

impl std::fmt::Debug for Stage1Model {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stage1Model")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Stage1Model {
    /// A freshly initialised, trainable model (weights drawn from `seed`).
    pub fn new_trainable(config: ModelConfig, seed: u64) -> Result<Self, DetectError> {
        if !config.case.is_trainable() {
            return Err(DetectError::BadParameter(
                "Result Fusion has no network of its own".into(),
            ));
        }
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = Stage1Net::new(&config.grid, &config.net, &config.branch_names(), vb)?;
        Stage1Net::init_weights(&varmap, seed)?;
        let anchors = Anchors::new(&config.grid, &config.anchor);
        Ok(Self {
            config,
            net,
            anchors,
            varmap: Some(varmap),
            fast: None,
        })
    }

    /// An inference model from tensors (no gradients tracked).
    pub fn from_tensors(
        config: ModelConfig,
        tensors: std::collections::HashMap<String, Tensor>,
    ) -> Result<Self, DetectError> {
        let fast = FastNet::build(&config, &|name: &str| tensors.get(name).cloned())?;
        let vb = VarBuilder::from_tensors(tensors, DType::F32, &Device::Cpu);
        let net = Stage1Net::new(&config.grid, &config.net, &config.branch_names(), vb)?;
        let anchors = Anchors::new(&config.grid, &config.anchor);
        Ok(Self {
            config,
            net,
            anchors,
            varmap: None,
            fast: Some(fast),
        })
    }

    /// Loads a weights file, checking its sha256 when given and that it is a model of `case`.
    pub fn load(path: &Path, case: Case, expected_sha256: Option<&str>) -> Result<Self, DetectError> {
        let w = read_weights(path, expected_sha256)?;
        let bad = |what: String| DetectError::Weights {
            path: path.to_path_buf(),
            what,
        };
        let config = w.model_config()?;
        if config.case != case {
            return Err(DetectError::WrongCase {
                path: path.to_path_buf(),
                expected: case,
                found: config.case.to_string(),
            });
        }
        Self::from_tensors(config, w.tensors).map_err(|e| bad(format!("does not fit the network: {e}")))
    }

    /// Loads the shipped model of `case` from a models folder (manifest + checksum), decoding
    /// with the manifest's box voting when it has one.
    pub fn load_shipped(dir: &Path, case: Case) -> Result<Self, DetectError> {
        let manifest = Manifest::load(dir)?;
        let entry = manifest.entry(dir, case)?;
        let mut model = Self::load(&entry.path_in(dir)?, case, Some(&entry.sha256))?;
        if let Some(v) = manifest.vote_iou() {
            model.config.vote_iou = Some(v);
        }
        Ok(model)
    }

    /// The weights (trainable variables or loaded tensors) as a safetensors file with the
    /// configuration in its metadata, plus `extra` tensors and metadata (checkpoints).
    pub fn to_safetensors(
        &self,
        extra: BTreeMap<String, Tensor>,
        extra_meta: BTreeMap<String, String>,
    ) -> Result<Vec<u8>, DetectError> {
        let varmap = self
            .varmap
            .as_ref()
            .ok_or_else(|| DetectError::BadParameter("only a trainable model can be saved".into()))?;
        let mut tensors = crate::detect::weights::varmap_tensors(varmap)?;
        tensors.extend(extra);
        let mut meta = extra_meta;
        meta.insert(
            "mlod.config".into(),
            serde_json::to_string(&self.config).map_err(|e| DetectError::BadParameter(e.to_string()))?,
        );
        encode_safetensors(&tensors, &meta)
    }

    /// The BEV of each branch (`None` where the LiDAR is absent).
    pub fn voxelize(&self, cloud: &FusedCloud) -> Vec<Option<Bev>> {
        branch_points(self.config.case, cloud)
            .into_iter()
            .map(|p| p.map(|p| voxelize(&self.config.grid, p)))
            .collect()
    }

    /// The head outputs on BEV inputs (one per branch): the folded network for loaded weights,
    /// candle's forward for a model being trained.
    pub fn heads(&self, bevs: &[Option<Bev>]) -> Result<RawHeads, DetectError> {
        match &self.fast {
            Some(f) if bevs.iter().any(|b| b.is_some()) => f.forward(bevs),
            _ => Ok(RawHeads::from_candle(&self.forward(bevs, false)?)?),
        }
    }

    /// The folded inference network of the current weights (of a model being trained too).
    pub fn fast_net(&self) -> Result<FastNet, DetectError> {
        if let Some(f) = &self.fast {
            return Ok(f.clone());
        }
        let varmap = self
            .varmap
            .as_ref()
            .ok_or_else(|| DetectError::BadParameter("model has no weights".into()))?;
        let data = varmap
            .data()
            .lock()
            .map_err(|_| DetectError::BadParameter("variable map lock poisoned".into()))?;
        FastNet::build(&self.config, &|name: &str| {
            data.get(name).map(|v| v.as_tensor().clone())
        })
    }

    /// The candle network on BEV inputs (one per branch).
    pub fn forward(&self, bevs: &[Option<Bev>], train: bool) -> Result<HeadOutput, DetectError> {
        let inputs = bevs
            .iter()
            .map(|b| b.as_ref().map(bev_tensor).transpose())
            .collect::<candle_core::Result<Vec<_>>>()?;
        if inputs.iter().all(|i| i.is_none()) {
            return Err(DetectError::BadParameter(format!(
                "{}: none of its LiDARs is present",
                self.config.case.paper_name()
            )));
        }
        Ok(self.net.forward_t(&inputs, train)?)
    }

    /// Decodes head outputs into boxes with their logits (before the score threshold is applied
    /// as a probability), best first, after NMS.
    pub fn decode(&self, heads: &RawHeads, temperature: f64) -> Result<Vec<(Detection, f32)>, DetectError> {
        let cls = &heads.cls;
        let c = &self.config;
        let t = temperature.max(1e-3) as f32;
        let logit_min = {
            let p = c.score_threshold.clamp(1e-6, 1.0 - 1e-6);
            (p / (1.0 - p)).ln() * t
        };
        let n = cls
            .len()
            .min(self.anchors.len())
            .min(heads.reg.len() / 7)
            .min(heads.dir.len() / 2);
        let mut cand: Vec<usize> = (0..n)
            .filter(|&i| cls[i] >= logit_min && cls[i].is_finite())
            .collect();
        cand.sort_by(|&a, &b| cls[b].total_cmp(&cls[a]).then(a.cmp(&b)));
        cand.truncate(c.pre_nms);
        if cand.is_empty() {
            return Ok(Vec::new());
        }
        let mut boxes = Vec::with_capacity(cand.len());
        let mut scores = Vec::with_capacity(cand.len());
        let mut logits = Vec::with_capacity(cand.len());
        for &i in &cand {
            let r: [f32; 7] = std::array::from_fn(|j| heads.reg[7 * i + j]);
            let mut b = decode(&r, &self.anchors.boxes[i]);
            let d = u32::from(heads.dir[2 * i + 1] > heads.dir[2 * i]);
            b[6] = apply_direction(b[6], d);
            let b3 = box3d_of(&b);
            if !b3.is_valid() {
                continue;
            }
            boxes.push(b3);
            let z = cls[i] / t;
            scores.push(1.0 / (1.0 + (-z).exp()));
            logits.push(cls[i]);
        }
        let mut keep = nms(&boxes, &scores, c.nms_iou, IouKind::Bev);
        keep.truncate(c.max_detections);
        let kept_boxes = match c.vote_iou {
            Some(v) => vote(&boxes, &scores, &keep, v, IouKind::Bev),
            None => keep.iter().map(|&k| boxes[k]).collect(),
        };
        Ok(keep
            .into_iter()
            .zip(kept_boxes)
            .map(|(k, box3d)| {
                (
                    Detection {
                        box3d,
                        score: scores[k],
                        category: c.anchor.category.clone(),
                    },
                    logits[k],
                )
            })
            .collect())
    }

    /// Detections on an already fused cloud.
    pub fn detect_cloud(&self, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        let bevs = self.voxelize(cloud);
        let heads = self.heads(&bevs)?;
        Ok(self.decode(&heads, 1.0)?.into_iter().map(|(d, _)| d).collect())
    }

    /// Detections with their raw logits (for temperature calibration).
    pub fn detect_cloud_logits(&self, cloud: &FusedCloud) -> Result<Vec<(Detection, f32)>, DetectError> {
        let bevs = self.voxelize(cloud);
        let heads = self.heads(&bevs)?;
        self.decode(&heads, 1.0)
    }
}

impl Detector for Stage1Model {
    fn case(&self) -> Case {
        self.config.case
    }

    fn categories(&self) -> Vec<String> {
        vec![self.config.anchor.category.clone()]
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        if let Some(ch) = self.config.case.channel() {
            if frame.lidar(ch).is_none() {
                return Err(DetectError::MissingLidar {
                    sample: frame.sample_token.clone(),
                    channel: ch,
                });
            }
        }
        self.detect_cloud(cloud)
    }
}

/// Result Fusion (paper eq. 11): the single-LiDAR detectors, each with its temperature, merged by
/// NMS on 3D IoU.
#[derive(Debug)]
pub struct ResultFusion {
    /// (detector, temperature) of LiDAR-Top, -Left, -Right.
    pub generators: Vec<(Stage1Model, f64)>,
    /// 3D IoU above which the merge suppresses a box.
    pub nms_iou: f64,
    pub max_detections: usize,
    /// Box voting in the merge (as [`ModelConfig::vote_iou`], on 3D IoU): each kept box becomes
    /// the score-weighted mean of the generators' boxes overlapping it by at least this much.
    pub vote_iou: Option<f64>,
}

impl ResultFusion {
    /// Loads the three shipped single-LiDAR models and their temperatures.
    pub fn load_shipped(dir: &Path) -> Result<Self, DetectError> {
        let manifest = Manifest::load(dir)?;
        let vote_iou = manifest.vote_iou();
        let mut generators = Vec::new();
        for case in [Case::Top, Case::Left, Case::Right] {
            let entry = manifest.entry(dir, case)?;
            let mut model = Stage1Model::load(&entry.path_in(dir)?, case, Some(&entry.sha256))?;
            model.config.vote_iou = vote_iou;
            let t = manifest.temperatures.get(&case).copied().unwrap_or(1.0);
            generators.push((model, t));
        }
        Ok(Self {
            generators,
            nms_iou: 0.1,
            max_detections: 100,
            vote_iou,
        })
    }

    /// Merges per-generator detections (already calibrated) by 3D NMS.
    pub fn merge(&self, all: Vec<Detection>) -> Vec<Detection> {
        let boxes: Vec<Box3d> = all.iter().map(|d| d.box3d).collect();
        let scores: Vec<f32> = all.iter().map(|d| d.score).collect();
        let mut keep = nms(&boxes, &scores, self.nms_iou, IouKind::ThreeD);
        keep.truncate(self.max_detections);
        let voted = match self.vote_iou {
            Some(v) => vote(&boxes, &scores, &keep, v, IouKind::ThreeD),
            None => keep.iter().map(|&k| boxes[k]).collect(),
        };
        keep.into_iter()
            .zip(voted)
            .filter_map(|(k, box3d)| all.get(k).map(|d| Detection { box3d, ..d.clone() }))
            .collect()
    }

    /// Detections on a fused cloud (generators whose LiDAR is absent contribute nothing).
    pub fn detect_cloud(&self, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        // The generators are independent: run them side by side (their layers' row bands share
        // the rayon pool), then merge in generator order so the output does not depend on
        // scheduling.
        let per_generator: Vec<Vec<Detection>> = self
            .generators
            .par_iter()
            .map(|(model, t)| -> Result<Vec<Detection>, DetectError> {
                let present = model
                    .config
                    .case
                    .channel()
                    .is_some_and(|ch| cloud.lidars.iter().any(|l| l.channel == ch));
                if !present {
                    return Ok(Vec::new());
                }
                let heads = model.heads(&model.voxelize(cloud))?;
                Ok(model.decode(&heads, *t)?.into_iter().map(|(d, _)| d).collect())
            })
            .collect::<Result<_, _>>()?;
        Ok(self.merge(per_generator.into_iter().flatten().collect()))
    }
}

impl Detector for ResultFusion {
    fn case(&self) -> Case {
        Case::Result
    }

    fn categories(&self) -> Vec<String> {
        let mut c: Vec<String> = self.generators.iter().flat_map(|(m, _)| m.categories()).collect();
        c.sort();
        c.dedup();
        c
    }

    fn detect_fused(&self, _frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        self.detect_cloud(cloud)
    }
}

/// How a loaded detector's boxes are voted after NMS.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Voting {
    /// As the models folder's manifest says (plain NMS when it says nothing).
    #[default]
    Manifest,
    /// Plain NMS.
    Off,
    /// Box voting at this IoU, in (0, 1].
    Iou(f64),
}

impl Voting {
    /// Voting at `v`, which must be an IoU in (0, 1].
    pub fn iou(v: f64) -> Result<Self, String> {
        crate::geometry::nms::check_vote_iou(v).map(Self::Iou)
    }
}

impl std::str::FromStr for Voting {
    type Err = String;

    /// `manifest`, `off`, or an IoU in (0, 1].
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "manifest" => Ok(Self::Manifest),
            "off" => Ok(Self::Off),
            _ => Self::iou(
                s.parse()
                    .map_err(|_| format!("expected manifest, off or an IoU in (0, 1], got {s:?}"))?,
            ),
        }
    }
}

impl std::fmt::Display for Voting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Manifest => f.write_str("manifest"),
            Self::Off => f.write_str("off"),
            Self::Iou(v) => write!(f, "{v}"),
        }
    }
}

/// The shipped detector of any case, behind the one trait (decoding as its manifest says).
pub fn load_detector(dir: &Path, case: Case) -> Result<Box<dyn Detector>, DetectError> {
    load_detector_with(dir, case, Voting::Manifest)
}

/// [`load_detector`] with the box voting chosen by the caller: in a model's decoding on BEV IoU,
/// and in Result Fusion in every generator and in the 3D-IoU merge.
pub fn load_detector_with(dir: &Path, case: Case, voting: Voting) -> Result<Box<dyn Detector>, DetectError> {
    let vote_iou = match voting {
        Voting::Manifest => None,
        Voting::Off => Some(None),
        Voting::Iou(v) => {
            Voting::iou(v).map_err(DetectError::BadParameter)?;
            Some(Some(v))
        }
    };
    if case.is_oc() || case.dropped().is_some() {
        return Err(DetectError::BadParameter(format!(
            "{} wraps another detector: load it with mlod::cases::load_detector",
            case.paper_name()
        )));
    }
    Ok(match case {
        Case::Ext(_) => {
            return Err(DetectError::BadParameter(format!(
                "{case} is an external detector: load it with mlod::cases::load_detector"
            )))
        }
        c if c.is_mlod() => {
            return Err(DetectError::BadParameter(format!(
                "{} needs the stage-2 refiner: load it with mlod::cases::load_detector",
                case.paper_name()
            )))
        }
        Case::Result => {
            let mut r = ResultFusion::load_shipped(dir)?;
            if let Some(v) = vote_iou {
                r.generators.iter_mut().for_each(|(m, _)| m.config.vote_iou = v);
                r.vote_iou = v;
            }
            Box::new(r)
        }
        c => {
            let mut m = Stage1Model::load_shipped(dir, c)?;
            if let Some(v) = vote_iou {
                m.config.vote_iou = v;
            }
            Box::new(m)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Dataset;
    use crate::pipeline::{fuse, FuseParams};

    fn sample_frame() -> Frame {
        let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let token = ds.first_sample_token().unwrap().to_string();
        ds.frame(&token).unwrap()
    }

    #[test]
    fn feature_fusion_with_one_lidar_equals_that_branch() {
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Feature), 3).unwrap();
        let frame = sample_frame();
        let cloud = fuse(&frame, &FuseParams::default()).unwrap();
        let bevs = model.voxelize(&cloud);
        assert_eq!(bevs.len(), 3);
        assert!(
            bevs.iter().all(|b| b.is_some()),
            "sample_data has all three LiDARs"
        );
        for k in 0..3 {
            // Only LiDAR k present: the fused map is branch k's map, and so are the heads.
            let only: Vec<Option<Bev>> = (0..3)
                .map(|j| if j == k { bevs[j].clone() } else { None })
                .collect();
            let inputs: Vec<Option<Tensor>> = only
                .iter()
                .map(|b| b.as_ref().map(|b| bev_tensor(b).unwrap()))
                .collect();
            let fused = model.net.features(&inputs, false).unwrap();
            let x = inputs[k].as_ref().unwrap();
            let branch = model.net.branches[k].1.forward_t(x, false).unwrap();
            let diff = (fused - &branch)
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            assert_eq!(diff, 0.0);
            let a = model.forward(&only, false).unwrap();
            let b = model.net.rpn.forward_t(&branch, false).unwrap();
            let d = (a.cls - b.cls)
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            assert_eq!(d, 0.0);
        }
        // All three present: the element-wise maximum of the branch maps.
        let inputs: Vec<Option<Tensor>> = bevs
            .iter()
            .map(|b| b.as_ref().map(|b| bev_tensor(b).unwrap()))
            .collect();
        let fused = model.net.features(&inputs, false).unwrap();
        let maps: Vec<Tensor> = (0..3)
            .map(|k| {
                model.net.branches[k]
                    .1
                    .forward_t(inputs[k].as_ref().unwrap(), false)
                    .unwrap()
            })
            .collect();
        let expect = maps[0].maximum(&maps[1]).unwrap().maximum(&maps[2]).unwrap();
        let d = (fused - expect)
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert_eq!(d, 0.0);
    }

    #[test]
    fn saved_model_loads_back_and_corrupt_or_wrong_files_are_named() {
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 5).unwrap();
        let bytes = model.to_safetensors(BTreeMap::new(), BTreeMap::new()).unwrap();
        let dir = std::env::temp_dir().join(format!("mlod-model-{}", std::process::id()));
        let path = dir.join("top.safetensors");
        crate::io::write_atomic(&path, &bytes).unwrap();
        let sha = super::super::weights::sha256_hex(&bytes);
        let frame = sample_frame();
        let cloud = fuse(&frame, &FuseParams::default()).unwrap();
        let loaded = Stage1Model::load(&path, Case::Top, Some(&sha)).unwrap();
        let a = model.forward(&model.voxelize(&cloud), false).unwrap();
        let b = loaded.forward(&loaded.voxelize(&cloud), false).unwrap();
        let d = (a.reg - b.reg)
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert_eq!(d, 0.0, "save/load round trip is exact");
        // A model of another case.
        let e = Stage1Model::load(&path, Case::Input, Some(&sha)).unwrap_err();
        assert!(matches!(e, DetectError::WrongCase { .. }), "{e}");
        // Corrupted bytes: the checksum error names the file.
        let mut bad = bytes.clone();
        let mid = bad.len() / 2;
        bad[mid] ^= 0x40;
        crate::io::write_atomic(&path, &bad).unwrap();
        let e = Stage1Model::load(&path, Case::Top, Some(&sha)).unwrap_err();
        assert!(
            e.to_string().contains("top.safetensors") && e.to_string().contains("sha256"),
            "{e}"
        );
        // Truncated without a checksum: a format error naming the file.
        crate::io::write_atomic(&path, &bytes[..bytes.len() / 3]).unwrap();
        let e = Stage1Model::load(&path, Case::Top, None).unwrap_err();
        assert!(
            matches!(e, DetectError::Weights { .. }) && e.to_string().contains("top.safetensors"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
