//! Weights on disk: safetensors files (`assets/models/<case>.safetensors`) whose `__metadata__`
//! holds the model configuration, and `assets/models/manifest.json` with each file's sha256, the
//! exact command, seed, steps, wall time and test-split AP.
//!
//! How it works: the writer lays out the safetensors format itself (8-byte little-endian header
//! length, JSON header with dtype/shape/offsets per tensor in name order, then the raw
//! little-endian f32 data), so a file is built in memory and written atomically, and the same
//! weights always give the same bytes. Reading hashes the bytes first; a checksum that differs from
//! the manifest, a truncated file or a bad header is a [`DetectError`] naming the file.

#![deny(clippy::indexing_slicing)]

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::{Case, DetectError};

/// The sha256 of bytes, lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Serialises f32 tensors and string metadata as a safetensors file (tensors sorted by name).
pub fn encode_safetensors(
    tensors: &BTreeMap<String, Tensor>,
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>, DetectError> {
    let mut header = serde_json::Map::new();
    header.insert(
        "__metadata__".into(),
        serde_json::to_value(metadata).map_err(bad_json)?,
    );
    let mut data: Vec<u8> = Vec::new();
    for (name, t) in tensors {
        let v: Vec<f32> = t.to_dtype(candle_core::DType::F32)?.flatten_all()?.to_vec1()?;
        let start = data.len();
        for x in &v {
            data.extend_from_slice(&x.to_le_bytes());
        }
        header.insert(
            name.clone(),
            serde_json::json!({"dtype": "F32", "shape": t.dims(), "data_offsets": [start, data.len()]}),
        );
    }
    let mut h = serde_json::to_vec(&serde_json::Value::Object(header)).map_err(bad_json)?;
    // Pad the header to a multiple of 8 bytes with spaces (the format allows it).
    while h.len() % 8 != 0 {
        h.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + h.len() + data.len());
    out.extend_from_slice(&(h.len() as u64).to_le_bytes());
    out.extend_from_slice(&h);
    out.extend_from_slice(&data);
    Ok(out)
}

fn bad_json(e: serde_json::Error) -> DetectError {
    DetectError::BadParameter(format!("cannot serialise: {e}"))
}

/// A weights file read from disk.
#[derive(Debug, Clone)]
pub struct WeightsFile {
    pub path: PathBuf,
    pub sha256: String,
    pub tensors: HashMap<String, Tensor>,
    pub metadata: BTreeMap<String, String>,
}

impl WeightsFile {
    /// The stage-1 model configuration its metadata holds (`mlod.config`): the one reader of a
    /// weights file's configuration (loading, resuming, the manifest's intensity question).
    pub fn model_config(&self) -> Result<super::config::ModelConfig, DetectError> {
        let bad = |what: String| DetectError::Weights {
            path: self.path.clone(),
            what,
        };
        let cfg = self
            .metadata
            .get("mlod.config")
            .ok_or_else(|| bad("no mlod.config in its metadata".into()))?;
        serde_json::from_str(cfg).map_err(|e| bad(format!("bad mlod.config: {e}")))
    }
}

/// Reads a safetensors file; with `expected_sha256` the bytes must hash to it.
pub fn read_weights(path: &Path, expected_sha256: Option<&str>) -> Result<WeightsFile, DetectError> {
    let bytes = std::fs::read(path).map_err(|e| crate::io::IoError::new("cannot read", path, e))?;
    let sha = sha256_hex(&bytes);
    if let Some(expected) = expected_sha256 {
        if !sha.eq_ignore_ascii_case(expected) {
            return Err(DetectError::Checksum {
                path: path.to_path_buf(),
                expected: expected.to_string(),
                actual: sha,
            });
        }
    }
    let bad = |what: String| DetectError::Weights {
        path: path.to_path_buf(),
        what,
    };
    let len_bytes: [u8; 8] = bytes.get(..8).and_then(|b| b.try_into().ok()).ok_or_else(|| {
        bad(format!(
            "{} bytes is too short for a safetensors file",
            bytes.len()
        ))
    })?;
    let n = u64::from_le_bytes(len_bytes) as usize;
    let header = bytes
        .get(8..8usize.saturating_add(n))
        .ok_or_else(|| bad(format!("header of {n} bytes runs past the end of the file")))?;
    let header: serde_json::Value =
        serde_json::from_slice(header).map_err(|e| bad(format!("header is not JSON: {e}")))?;
    let metadata: BTreeMap<String, String> = match header.get("__metadata__") {
        Some(m) => serde_json::from_value(m.clone()).map_err(|e| bad(format!("bad __metadata__: {e}")))?,
        None => BTreeMap::new(),
    };
    let tensors =
        candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).map_err(|e| bad(e.to_string()))?;
    Ok(WeightsFile {
        path: path.to_path_buf(),
        sha256: sha,
        tensors,
        metadata,
    })
}

/// Where and how one shipped model was made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelEntry {
    /// File name relative to the manifest's folder.
    pub file: String,
    pub sha256: String,
    /// The exact command that trained it.
    pub command: String,
    pub seed: u64,
    pub steps: u64,
    /// Wall time of the training (s).
    pub wall_time_s: f64,
    /// Test-split AP figures (filled by `mlod eval`), e.g. `{"moderate_ap3d_0.7": 61.2}`.
    #[serde(default)]
    pub test_ap: BTreeMap<String, f64>,
    /// The weights this training started from (`--init`), if it was a warm start.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<InitRecord>,
}

impl ModelEntry {
    /// The weights file in the models folder `dir`: `file` must be a plain file name (no
    /// separator, no `..`), so a manifest cannot make the program read outside its folder.
    pub fn path_in(&self, dir: &Path) -> Result<std::path::PathBuf, DetectError> {
        let f = self.file.as_str();
        let plain = !f.is_empty()
            && f != "."
            && f != ".."
            && !f.contains(['/', '\\'])
            && Path::new(f).components().count() == 1;
        if !plain {
            return Err(DetectError::Manifest {
                path: dir.join(Manifest::FILE),
                what: format!(
                    "model file '{f}' must be a file name inside the models folder (no '/', '\\' or '..')"
                ),
            });
        }
        Ok(dir.join(f))
    }
}

/// The starting point of a warm-started training: file name and its sha256 when it was read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitRecord {
    pub file: String,
    pub sha256: String,
    /// The starting model's own manifest entry (from the manifest beside it, matched by sha256),
    /// so the whole chain of trainings stays on record.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub entry: Option<Box<ModelEntry>>,
}

impl InitRecord {
    /// Describes the weights file `path`: its name, sha256 and, when the manifest in its folder
    /// lists a model with that checksum, that entry.
    pub fn of_file(path: &Path) -> Self {
        let file = file_name_of(path);
        let sha256 = match std::fs::read(path) {
            Ok(b) => sha256_hex(&b),
            Err(e) => {
                return Self {
                    file,
                    sha256: format!("unreadable: {e}"),
                    entry: None,
                }
            }
        };
        let entry = folder_of(path)
            .and_then(|d| Manifest::load(d).ok())
            .and_then(|m| m.models.into_values().find(|e| e.sha256 == sha256))
            .map(Box::new);
        Self { file, sha256, entry }
    }
}

/// `assets/models/manifest.json`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Manifest {
    /// The simulator world the models were trained in (`mlod synth --world NAME`,
    /// `crate::synth::World`); absent for models trained on other data.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world: Option<String>,
    /// Per trained case.
    pub models: BTreeMap<Case, ModelEntry>,
    /// Result Fusion's temperature per generator (`top`, `left`, `right`), fitted on validation.
    #[serde(default)]
    pub temperatures: BTreeMap<Case, f64>,
    /// How the temperatures were fitted.
    #[serde(default)]
    pub temperature_command: String,
    /// Box voting chosen on the validation split (`mlod train tune-vote`); absent: plain NMS.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vote: Option<VoteTuning>,
    /// The stage-2 refiner of the MLOD cases (`mlod train refiner`), one for all three.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refiner: Option<ModelEntry>,
    /// The ablation's refiner, trained like `refiner` but without the tr(Ξ) point feature
    /// (`mlod train refiner --no-trace`), used by `mlod-i-notrace`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refiner_notrace: Option<ModelEntry>,
    /// How the refiner's output is decoded, chosen on the validation split
    /// (`mlod train tune-refiner`); absent: the refined score alone, no NMS after refinement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refine: Option<RefineTuning>,
    /// The training data's sensor statistics (`mlod stats --update-manifest`): what `mlod detect`
    /// and `mlod eval` compare a dataset with, to name what lies outside the training data.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training_stats: Option<crate::dataset::TrainingStats>,
    /// The ground gate chosen on the validation split (`mlod train tune-gate`, issue 29): the
    /// stage-1 cases drop boxes floating more than this above the ground; absent: no gate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ground_gate: Option<GateTuning>,
    /// Present when the folder was adapted to real data (`mlod train adapt`): from which folder,
    /// on which data, with which command, and the figures it reached.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adapted: Option<AdaptRecord>,
    /// Present when the folder was made by `mlod train chain`: its command and each phase's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chain: Option<ChainRecord>,
}

/// The command that trained a whole models folder (`mlod train chain`) and its phases.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ChainRecord {
    pub command: String,
    pub phases: Vec<ChainPhase>,
}

/// One phase of a chain: the command it ran (as a user would type it alone) and its wall time.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ChainPhase {
    pub name: String,
    pub command: String,
    pub wall_time_s: f64,
}

/// How a models folder was adapted to a user's labelled frames (`mlod train adapt`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AdaptRecord {
    /// The models folder it started from, as given.
    pub base: String,
    /// sha256 of the base folder's manifest.json, which holds every base weight's sha256.
    pub base_manifest_sha256: String,
    /// The labelled real data, as given, and how many of its samples taught.
    pub dataset: String,
    pub samples: usize,
    /// The adapted cases (the others are the base folder's, unchanged).
    pub cases: Vec<Case>,
    pub steps: u64,
    pub command: String,
    /// Per case and model (`base`, `adapted`): figures of `mlod eval --transfer` on the
    /// adaptation frames themselves. They say the run learned; they are not a held-out check.
    #[serde(default)]
    pub fit: BTreeMap<String, BTreeMap<String, f64>>,
}

/// The largest ground gate a user or a manifest may give (m).
pub const MAX_GATE_M: f32 = 5.0;

/// Checks a ground gate (m): finite, in (0, [`MAX_GATE_M`]].
pub fn check_gate(m: f32) -> Result<f32, String> {
    if m.is_finite() && m > 0.0 && m <= MAX_GATE_M {
        Ok(m)
    } else {
        Err(format!(
            "a ground gate is a height in (0, {MAX_GATE_M}] m, got {m}"
        ))
    }
}

/// The ground gate of a models folder's stage-1 cases and how it was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GateTuning {
    /// The chosen gate (m); `None`: every candidate cost validation AP.
    pub max_lift_m: Option<f64>,
    /// The command that chose it.
    pub command: String,
    /// Per candidate (`off`, `0.5`, ...): car moderate AP_3D@0.7 (%) on the validation scenes,
    /// per case and their mean (`mean`).
    pub validation: BTreeMap<String, BTreeMap<String, f64>>,
}

/// The refiner's decoding and how it was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RefineTuning {
    /// How a refined box's score is made: `refined` (the classification head's), `stage1` (the
    /// proposal's) or `mean` (their geometric mean).
    pub score: String,
    /// 3D-IoU NMS after refinement at this IoU; `None`: none.
    pub nms_iou: Option<f64>,
    /// The union cases' NMS after refinement (`mlod-u`, issue 32); absent: the default
    /// (`detect::union::UNION_NMS_IOU`), as in manifests written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub union_nms_iou: Option<f64>,
    /// The union cases' box voting after that NMS (3D IoU); absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub union_vote_iou: Option<f64>,
    /// The command that chose it.
    pub command: String,
    /// Per candidate: car moderate AP_3D@0.7 (%) on the validation scenes per case and their mean.
    pub validation: BTreeMap<String, BTreeMap<String, f64>>,
}

/// The box-voting IoU every shipped detector decodes with, and how it was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VoteTuning {
    /// The chosen IoU; `None`: no candidate beat plain NMS on validation.
    pub iou: Option<f64>,
    /// The command that chose it.
    pub command: String,
    /// Per candidate (`off`, `0.3`, ...): car moderate AP_3D@0.7 (%) on the validation scenes,
    /// per case and their mean (`mean`), which picks the winner.
    pub validation: BTreeMap<String, BTreeMap<String, f64>>,
}

impl Manifest {
    /// The ground gate it records for its stage-1 cases (m; `mlod train tune-gate`), if any.
    pub fn ground_gate_m(&self) -> Option<f32> {
        self.ground_gate
            .as_ref()
            .and_then(|g| g.max_lift_m)
            .map(|v| v as f32)
    }

    pub const FILE: &'static str = "manifest.json";

    /// Reads `dir/manifest.json`.
    pub fn load(dir: &Path) -> Result<Self, DetectError> {
        let path = dir.join(Self::FILE);
        let bytes = std::fs::read(&path).map_err(|e| crate::io::IoError::new("cannot read", &path, e))?;
        let manifest: Self = serde_json::from_slice(&bytes).map_err(|e| DetectError::Manifest {
            path: path.clone(),
            what: e.to_string(),
        })?;
        if let Some(v) = manifest.ground_gate.as_ref().and_then(|g| g.max_lift_m) {
            check_gate(v as f32).map_err(|e| DetectError::Manifest {
                path: path.clone(),
                what: format!("ground_gate.max_lift_m: {e}"),
            })?;
        }
        // Every detector decodes with this IoU.
        if let Some(v) = manifest.vote_iou() {
            crate::geometry::nms::check_vote_iou(v).map_err(|e| DetectError::Manifest {
                path,
                what: format!("vote.iou: {e}"),
            })?;
        }
        Ok(manifest)
    }

    /// The box-voting IoU the shipped detectors decode with (`None`: plain NMS).
    pub fn vote_iou(&self) -> Option<f64> {
        self.vote.as_ref().and_then(|v| v.iou)
    }

    /// Writes `dir/manifest.json` atomically.
    pub fn save(&self, dir: &Path) -> Result<(), DetectError> {
        let mut s = serde_json::to_string_pretty(self).map_err(bad_json)?;
        s.push('\n');
        crate::io::write_atomic(&dir.join(Self::FILE), s.as_bytes())?;
        Ok(())
    }

    /// One line naming an adapted folder (`mlod train adapt`): which cases, on which data, from
    /// which folder; `None` for a folder trained on simulated data alone.
    pub fn adapted_summary(&self) -> Option<String> {
        let a = self.adapted.as_ref()?;
        let cases: Vec<&str> = a.cases.iter().map(|c| c.as_str()).collect();
        Some(format!(
            "adapted to {} ({} labelled frames; {}) from {}",
            a.dataset,
            a.samples,
            cases.join(", "),
            a.base
        ))
    }

    /// The entry of a case, or an error naming the manifest.
    pub fn entry(&self, dir: &Path, case: Case) -> Result<&ModelEntry, DetectError> {
        self.models.get(&case).ok_or_else(|| DetectError::Manifest {
            path: dir.join(Self::FILE),
            what: format!("no model for case {case}"),
        })
    }
}

/// The training data's summary stored in `dir/manifest.json` (`None` when the manifest has none).
pub fn read_training_stats(dir: &Path) -> Result<Option<crate::dataset::StatsSummary>, DetectError> {
    Ok(Manifest::load(dir)?.training_stats.map(|t| t.summary))
}

/// Whether the models in `dir` read intensity: LiDAR-Top's configuration says so (v4 models are
/// trained without it); true when it cannot be read, as for every model made before the option.
pub fn models_read_intensity(dir: &Path) -> bool {
    let config = || -> Option<super::config::ModelConfig> {
        let manifest = Manifest::load(dir).ok()?;
        let path = manifest.entry(dir, super::Case::Top).ok()?.path_in(dir).ok()?;
        read_weights(&path, None).ok()?.model_config().ok()
    };
    config().is_none_or(|c| c.grid.intensity)
}

/// What differs between `data` and the training data of the models in `dir`, in words
/// ([`crate::dataset::out_of_depth_notes`]), without the notes about intensity when the models do
/// not read it. Empty when the manifest has no training statistics.
pub fn training_notes(dir: &Path, data: &crate::dataset::StatsSummary) -> Vec<String> {
    let Ok(Some(trained)) = read_training_stats(dir) else {
        return Vec::new();
    };
    let mut notes = crate::dataset::out_of_depth_notes(&trained, data);
    let about_intensity = |n: &String| n.starts_with("intensity");
    if notes.iter().any(about_intensity) && !models_read_intensity(dir) {
        notes.retain(|n| !about_intensity(n));
    }
    notes
}

/// The folder whose manifest lists a weights file: its parent (`.` for a bare file name).
pub(crate) fn folder_of(path: &Path) -> Option<&Path> {
    path.parent().map(|d| {
        if d.as_os_str().is_empty() {
            Path::new(".")
        } else {
            d
        }
    })
}

/// A weights file's name as its manifest entry records it.
pub(crate) fn file_name_of(path: &Path) -> String {
    path.file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The default model folder: `assets/models` of the crate.
pub fn default_models_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets")
        .join("models")
}

/// Every variable of a candle variable map by name (what a trainable model saves).
pub fn varmap_tensors(
    varmap: &candle_nn::VarMap,
) -> Result<BTreeMap<String, candle_core::Tensor>, DetectError> {
    let data = varmap
        .data()
        .lock()
        .map_err(|_| DetectError::BadParameter("variable map lock poisoned".into()))?;
    Ok(data
        .iter()
        .map(|(k, v)| (k.clone(), v.as_tensor().clone()))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manifest_cannot_point_outside_its_folder() {
        let entry = |file: &str| ModelEntry {
            file: file.into(),
            sha256: String::new(),
            command: String::new(),
            seed: 0,
            steps: 0,
            wall_time_s: 0.0,
            test_ap: BTreeMap::new(),
            init: None,
        };
        let dir = Path::new("/models");
        assert_eq!(
            entry("top.safetensors").path_in(dir).unwrap(),
            dir.join("top.safetensors")
        );
        for bad in [
            "",
            ".",
            "..",
            "../x.safetensors",
            "/etc/passwd",
            "a/b.safetensors",
            "..\\x",
            "sub\\w",
        ] {
            let e = entry(bad).path_in(dir).unwrap_err().to_string();
            assert!(
                e.contains("manifest.json") && e.contains("file name"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn safetensors_round_trip_and_corruption_is_named() {
        let mut t = BTreeMap::new();
        t.insert(
            "a.weight".to_string(),
            Tensor::new(&[[1f32, -2.5], [3.0, 4.0]], &Device::Cpu).unwrap(),
        );
        t.insert("b".to_string(), Tensor::new(&[0.5f32], &Device::Cpu).unwrap());
        let mut m = BTreeMap::new();
        m.insert("case".to_string(), "top".to_string());
        let bytes = encode_safetensors(&t, &m).unwrap();
        assert_eq!(bytes, encode_safetensors(&t, &m).unwrap(), "deterministic");
        let dir = std::env::temp_dir().join(format!("mlod-weights-{}", std::process::id()));
        let p = dir.join("w.safetensors");
        crate::io::write_atomic(&p, &bytes).unwrap();
        let w = read_weights(&p, Some(&sha256_hex(&bytes))).unwrap();
        assert_eq!(w.metadata, m);
        let a: Vec<Vec<f32>> = w.tensors["a.weight"].to_vec2().unwrap();
        assert_eq!(a, vec![vec![1.0, -2.5], vec![3.0, 4.0]]);
        // One flipped byte: the checksum names the file.
        let mut bad = bytes.clone();
        let last = bad.len() - 1;
        bad[last] ^= 1;
        crate::io::write_atomic(&p, &bad).unwrap();
        let e = read_weights(&p, Some(&sha256_hex(&bytes))).unwrap_err();
        assert!(
            matches!(e, DetectError::Checksum { .. }) && e.to_string().contains("w.safetensors"),
            "{e}"
        );
        // Truncated, no checksum given: a format error naming the file.
        crate::io::write_atomic(&p, &bytes[..20]).unwrap();
        let e = read_weights(&p, None).unwrap_err();
        assert!(
            matches!(e, DetectError::Weights { .. }) && e.to_string().contains("w.safetensors"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_vote_iou_outside_the_unit_interval_is_a_manifest_error() {
        let dir = std::env::temp_dir().join(format!("mlod-manifest-vote-{}", std::process::id()));
        let vote = |iou: f64| Manifest {
            vote: Some(VoteTuning {
                iou: Some(iou),
                command: "test".into(),
                validation: BTreeMap::new(),
            }),
            ..Default::default()
        };
        vote(0.5).save(&dir).unwrap();
        assert_eq!(Manifest::load(&dir).unwrap().vote.and_then(|v| v.iou), Some(0.5));
        for bad in [0.0, -0.3, 1.5] {
            vote(bad).save(&dir).unwrap();
            let e = Manifest::load(&dir).unwrap_err();
            assert!(
                matches!(e, DetectError::Manifest { .. })
                    && e.to_string().contains("vote.iou")
                    && e.to_string().contains("manifest.json"),
                "{bad}: {e}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
