//! A Lyft dataset on disk: the dataset root (where `lidar/` and `maps/` live), its version folder
//! (`v1.01-train/`, the folder holding the JSON tables), the 13 tables indexed by token, and the
//! reverse indexes a loader needs (key-frame sample_data and annotations per sample).
//!
//! How it works: [`Dataset::open`] accepts either the root or the version folder, reads every table
//! (see [`Tables::load`]), and orders samples as the scenes do (`scene.first_sample_token`, then
//! each sample's `next`). Samples the chains do not reach (a partial excerpt, a broken link) follow
//! their scene's chain in timestamp order, so every sample is listed exactly once. Nothing else is
//! checked at open: a dangling reference is an error of the sample that uses it, and every other
//! sample still loads. Filenames from the tables are resolved with [`Dataset::resolve`], which
//! rejects absolute paths and `..`.

#![deny(clippy::indexing_slicing)]

use std::collections::{HashMap, HashSet};
use std::path::{Component, Path, PathBuf};

use serde::Serialize;

use super::av2;
use super::categories;
use super::error::DatasetError;
use super::extras::{FrameIssue, LabelExtras};
use super::kitti::{self, EvalRegion};
use super::pointcloud::PointLayout;
use super::tables::{Record, Tables};

/// The three LiDARs of the Lyft car, in the paper's order: LiDAR-Top (primary, base frame),
/// LiDAR-Left and LiDAR-Right (auxiliaries).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, serde::Deserialize)]
pub enum LidarChannel {
    #[serde(rename = "LIDAR_TOP")]
    Top,
    #[serde(rename = "LIDAR_FRONT_LEFT")]
    FrontLeft,
    #[serde(rename = "LIDAR_FRONT_RIGHT")]
    FrontRight,
}

impl LidarChannel {
    /// All three, primary first.
    pub const ALL: [LidarChannel; 3] = [Self::Top, Self::FrontLeft, Self::FrontRight];

    /// The `sensor.channel` string.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Top => "LIDAR_TOP",
            Self::FrontLeft => "LIDAR_FRONT_LEFT",
            Self::FrontRight => "LIDAR_FRONT_RIGHT",
        }
    }

    /// Parses a `sensor.channel` string; `None` for any other channel.
    pub fn from_channel(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == s)
    }

    /// The paper's name: LiDAR-Top, LiDAR-Left, LiDAR-Right.
    pub fn paper_name(self) -> &'static str {
        match self {
            Self::Top => "LiDAR-Top",
            Self::FrontLeft => "LiDAR-Left",
            Self::FrontRight => "LiDAR-Right",
        }
    }
}

impl std::fmt::Display for LidarChannel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One line of the sample list: what `mlod inspect --list` prints.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SampleSummary {
    pub sample_token: String,
    pub scene_token: String,
    /// `""` when the scene row is missing.
    pub scene_name: String,
    /// Microseconds.
    pub timestamp: f64,
    /// Key-frame LiDAR channels of the sample: LIDAR_TOP, LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT
    /// first (those present), then any other LiDAR channel by name.
    pub lidar_channels: Vec<String>,
    /// Number of sample_annotation rows of the sample.
    pub num_boxes: usize,
}

/// The on-disk format a dataset was read from. Only [`Dataset::open`] and the notes shown to the
/// user look at it: everything downstream reads frames the same way whatever their format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DatasetFormat {
    /// Lyft Level 5 (`v1.01-train/`) or a dataset our simulator wrote.
    Lyft,
    /// nuScenes (`v1.0-mini/`, `v1.0-trainval/`, …): the same 13 tables, other category names.
    NuScenes,
    /// The KITTI 3D object benchmark (`training/velodyne`, `label_2`, `calib`).
    Kitti,
    /// Argoverse 2's sensor dataset (`sensor/<split>/<log>/sensors/lidar/*.feather`): two roof
    /// LiDARs, `up_lidar` in LIDAR_TOP's slot and `down_lidar` in LIDAR_FRONT_LEFT's.
    Av2,
}

impl DatasetFormat {
    pub fn name(self) -> &'static str {
        match self {
            Self::Lyft => "Lyft Level 5",
            Self::NuScenes => "nuScenes",
            Self::Kitti => "KITTI object",
            Self::Av2 => "Argoverse 2",
        }
    }

    /// The name this format gives the LiDAR in a slot (`up_lidar` for AV2's LIDAR_TOP slot);
    /// the channel name for the formats whose channels are the slots.
    pub fn lidar_name(self, channel: LidarChannel) -> &'static str {
        match (self, channel) {
            (Self::Av2, LidarChannel::Top) => "up_lidar",
            (Self::Av2, LidarChannel::FrontLeft) => "down_lidar",
            _ => channel.as_str(),
        }
    }

    /// The LiDAR slots this format fills (Argoverse 2: LIDAR_TOP and LIDAR_FRONT_LEFT; the others
    /// may fill all three).
    pub fn lidars(self) -> &'static [LidarChannel] {
        match self {
            Self::Av2 => &[LidarChannel::Top, LidarChannel::FrontLeft],
            _ => &LidarChannel::ALL,
        }
    }

    /// The rig in one line, for banners and `mlod inspect`; `None` for the formats whose
    /// LiDARs are the channels' own.
    pub fn rig(self) -> Option<&'static str> {
        match self {
            Self::Av2 => Some(
                "Argoverse 2 rig: two stacked Velodyne VLP-32C on the roof; up_lidar is the primary \
                 (LiDAR-Top's role, its frame the base frame), down_lidar the one auxiliary (LiDAR-Left's role; \
                 no LiDAR-Right)",
            ),
            _ => None,
        }
    }
}

/// A source category our names do not cover, with how many boxes carry it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct UnmappedCategory {
    pub name: String,
    pub boxes: usize,
}

/// An opened dataset: tables, indexes, sample order.
#[derive(Debug, Clone)]
pub struct Dataset {
    root: PathBuf,
    version_dir: PathBuf,
    tables: Tables,
    format: DatasetFormat,
    layout: PointLayout,
    /// Per sample: where evaluation looks (KITTI: camera 2's view minus DontCare regions).
    regions: HashMap<String, EvalRegion>,
    /// Per sample: a problem found while indexing that stops it loading (KITTI calib/labels).
    issues: HashMap<String, FrameIssue>,
    /// Things the user should know about the dataset as a whole (which split was opened, …).
    notes: Vec<String>,
    /// Per annotation token: what a format's labels say beyond the box (KITTI's occlusion and
    /// truncation).
    extras: HashMap<String, LabelExtras>,
    /// sample token → positions of its key-frame sample_data rows, in file order.
    keyframes_by_sample: HashMap<String, Vec<usize>>,
    /// sample token → positions of its sample_annotation rows, in file order.
    annotations_by_sample: HashMap<String, Vec<usize>>,
    /// Positions in sample.json, in scene order.
    sample_order: Vec<usize>,
}

impl Dataset {
    /// Opens a dataset in whatever format the folder holds:
    /// - Lyft or nuScenes: the root (the folder holding `v1.01-train/` or `v1.0-mini/`, `lidar/` or
    ///   `samples/`, `maps/`) or the version folder itself;
    /// - KITTI object: the split folder (`training/`) or the folder above it;
    /// - Argoverse 2 sensor data: a log folder, a split folder of logs, or the root holding
    ///   `sensor/<split>/`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, DatasetError> {
        let path = path.as_ref();
        let version_dir = match find_version_dir(path) {
            Ok(v) => v,
            Err(DatasetError::VersionFolderNotFound { .. }) if kitti::find_layout(path).is_some() => {
                return Self::open_kitti(path);
            }
            Err(DatasetError::VersionFolderNotFound { .. }) => {
                if let Some(layout) = av2::find_layout(path) {
                    return Self::open_av2(&layout);
                }
                return Err(DatasetError::VersionFolderNotFound {
                    path: path.to_path_buf(),
                });
            }
            Err(e) => return Err(e),
        };
        let root = match version_dir.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let tables = Tables::load(&version_dir)?;
        let mut ds = Self::from_tables(root, version_dir, tables);
        // nuScenes names its version folders v1.0-*; its categories are dotted (vehicle.car).
        let version_name = ds
            .version_dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if version_name.starts_with("v1.0-") || ds.tables.category.rows().iter().any(|c| c.name.contains('.'))
        {
            ds.format = DatasetFormat::NuScenes;
        }
        Ok(ds)
    }

    fn open_kitti(path: &Path) -> Result<Self, DatasetError> {
        let Some(layout) = kitti::find_layout(path) else {
            return Err(DatasetError::VersionFolderNotFound {
                path: path.to_path_buf(),
            });
        };
        let index = kitti::open(&layout)?;
        let mut ds = Self::from_tables(layout.split_dir.clone(), layout.split_dir, index.tables);
        ds.format = DatasetFormat::Kitti;
        ds.layout = PointLayout::XyzReflectance;
        ds.regions = index.regions;
        ds.issues = index.issues;
        ds.notes = index.notes;
        ds.extras = index.extras;
        Ok(ds)
    }

    fn open_av2(layout: &av2::Av2Layout) -> Result<Self, DatasetError> {
        let index = av2::open(layout)?;
        let mut ds = Self::from_tables(layout.root.clone(), layout.root.clone(), index.tables);
        ds.format = DatasetFormat::Av2;
        ds.layout = PointLayout::Av2Sweep;
        ds.issues = index.issues;
        ds.notes = index.notes;
        Ok(ds)
    }

    /// Builds the indexes over tables already in memory. `root` is where the tables' filenames
    /// are resolved.
    pub fn from_tables(root: PathBuf, version_dir: PathBuf, tables: Tables) -> Self {
        let mut keyframes_by_sample: HashMap<String, Vec<usize>> = HashMap::new();
        for (i, sd) in tables.sample_data.rows().iter().enumerate() {
            if sd.is_key_frame {
                keyframes_by_sample
                    .entry(sd.sample_token.clone())
                    .or_default()
                    .push(i);
            }
        }
        let mut annotations_by_sample: HashMap<String, Vec<usize>> = HashMap::new();
        for (i, a) in tables.sample_annotation.rows().iter().enumerate() {
            annotations_by_sample
                .entry(a.sample_token.clone())
                .or_default()
                .push(i);
        }
        let sample_order = scene_order(&tables);
        Self {
            root,
            version_dir,
            tables,
            format: DatasetFormat::Lyft,
            layout: PointLayout::default(),
            regions: HashMap::new(),
            issues: HashMap::new(),
            notes: Vec::new(),
            extras: HashMap::new(),
            keyframes_by_sample,
            annotations_by_sample,
            sample_order,
        }
    }

    /// The dataset root: `lidar/...` and `maps/...` filenames are relative to it.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The folder holding the JSON tables.
    pub fn version_dir(&self) -> &Path {
        &self.version_dir
    }

    /// The format the dataset was read from.
    pub fn format(&self) -> DatasetFormat {
        self.format
    }

    /// How its point files are laid out.
    pub fn point_layout(&self) -> PointLayout {
        self.layout
    }

    /// Where evaluation looks in a sample, when the format restricts it (KITTI: camera 2's view).
    pub fn eval_region(&self, sample_token: &str) -> Option<&EvalRegion> {
        self.regions.get(sample_token)
    }

    /// What the labels say of an annotation beyond its box (KITTI's occlusion and truncation).
    pub fn label_extras(&self, annotation_token: &str) -> Option<&LabelExtras> {
        self.extras.get(annotation_token)
    }

    /// The problem that stops a sample loading, found while indexing (KITTI calib or labels).
    pub fn sample_issue(&self, sample_token: &str) -> Option<&FrameIssue> {
        self.issues.get(sample_token)
    }

    /// What the user should know about the dataset as a whole: which split or folder was opened,
    /// categories that are not ours, samples that will not load.
    pub fn notes(&self) -> Vec<String> {
        let mut out = self.notes.clone();
        let unmapped = self.unmapped_categories();
        if !unmapped.is_empty() {
            out.push(format!(
                "{}: {} categor{} not among ours (kept with their own names, never scored): {}",
                self.format.name(),
                unmapped.len(),
                if unmapped.len() == 1 { "y is" } else { "ies are" },
                unmapped
                    .iter()
                    .map(|u| format!(
                        "{} ({} box{})",
                        u.name,
                        u.boxes,
                        if u.boxes == 1 { "" } else { "es" }
                    ))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        if !self.issues.is_empty() {
            let mut ids: Vec<&String> = self.issues.keys().collect();
            ids.sort();
            let first = ids.first().and_then(|id| self.issues.get(*id).map(|i| (id, i)));
            if let Some((id, issue)) = first {
                out.push(format!(
                    "{} sample{} will not load (first: {id}: {})",
                    ids.len(),
                    if ids.len() == 1 { "" } else { "s" },
                    issue.to_error()
                ));
            }
        }
        out
    }

    /// Source categories that do not map onto ours, with their box counts, by name.
    pub fn unmapped_categories(&self) -> Vec<UnmappedCategory> {
        let t = &self.tables;
        let mut counts: std::collections::BTreeMap<&str, usize> = std::collections::BTreeMap::new();
        for a in t.sample_annotation.rows() {
            let Some(cat) = t
                .instance
                .get(&a.instance_token)
                .and_then(|i| t.category.get(&i.category_token))
            else {
                continue;
            };
            if categories::canonical(&cat.name).is_none() {
                *counts.entry(cat.name.as_str()).or_default() += 1;
            }
        }
        counts
            .into_iter()
            .map(|(name, boxes)| UnmappedCategory {
                name: name.to_owned(),
                boxes,
            })
            .collect()
    }

    /// All tables, for direct access to rows.
    pub fn tables(&self) -> &Tables {
        &self.tables
    }

    /// Sample tokens in scene order.
    pub fn sample_tokens(&self) -> Vec<&str> {
        let rows = self.tables.sample.rows();
        self.sample_order
            .iter()
            .filter_map(|&i| rows.get(i))
            .map(|s| s.token.as_str())
            .collect()
    }

    /// The first sample in scene order.
    pub fn first_sample_token(&self) -> Option<&str> {
        let i = *self.sample_order.first()?;
        self.tables.sample.rows().get(i).map(|s| s.token.as_str())
    }

    /// Positions (in sample_data.json) of the sample's key-frame sample_data rows.
    pub fn keyframe_rows(&self, sample_token: &str) -> &[usize] {
        self.keyframes_by_sample
            .get(sample_token)
            .map_or(&[], Vec::as_slice)
    }

    /// Positions (in sample_annotation.json) of the sample's annotations, in file order.
    pub fn annotation_rows(&self, sample_token: &str) -> &[usize] {
        self.annotations_by_sample
            .get(sample_token)
            .map_or(&[], Vec::as_slice)
    }

    /// The LiDAR channel names of a sample's key-frame sample_data, best effort (rows with
    /// dangling calibrated_sensor or sensor links are skipped). Known channels come first in the
    /// paper's order, then others by name.
    pub fn lidar_channels(&self, sample_token: &str) -> Vec<String> {
        let t = &self.tables;
        let mut known = Vec::new();
        let mut other = Vec::new();
        for &i in self.keyframe_rows(sample_token) {
            let Some(sd) = t.sample_data.rows().get(i) else {
                continue;
            };
            let Some(cs) = t.calibrated_sensor.get(&sd.calibrated_sensor_token) else {
                continue;
            };
            let Some(sensor) = t.sensor.get(&cs.sensor_token) else {
                continue;
            };
            if sensor.modality != "lidar" {
                continue;
            }
            match LidarChannel::from_channel(&sensor.channel) {
                Some(c) => known.push(c),
                None => other.push(sensor.channel.clone()),
            }
        }
        known.sort();
        known.dedup();
        other.sort();
        other.dedup();
        known
            .into_iter()
            .map(|c| c.as_str().to_owned())
            .chain(other)
            .collect()
    }

    /// Every sample in scene order with its LiDAR channels and box count.
    pub fn samples(&self) -> Vec<SampleSummary> {
        let rows = self.tables.sample.rows();
        self.sample_order
            .iter()
            .filter_map(|&i| rows.get(i))
            .map(|s| SampleSummary {
                sample_token: s.token.clone(),
                scene_token: s.scene_token.clone(),
                scene_name: self
                    .tables
                    .scene
                    .get(&s.scene_token)
                    .map(|sc| sc.name.clone())
                    .unwrap_or_default(),
                timestamp: s.timestamp,
                lidar_channels: self.lidar_channels(&s.token),
                num_boxes: self.annotation_rows(&s.token).len(),
            })
            .collect()
    }

    /// Resolves a filename from a table row of `T` (whose token is `token`) against the root.
    /// Absolute paths, drive prefixes and any `..` component are rejected, so that every file
    /// read stays inside the dataset root (symbolic links the user placed there are followed).
    pub fn resolve<T: Record>(&self, token: &str, filename: &str) -> Result<PathBuf, DatasetError> {
        resolve_inside(&self.root, T::TABLE, token, filename)
    }
}

/// Joins `filename` to `root` after checking it is a plain relative path.
pub fn resolve_inside(
    root: &Path,
    table: &'static str,
    token: &str,
    filename: &str,
) -> Result<PathBuf, DatasetError> {
    let reject = |reason: &'static str| DatasetError::UnsafePath {
        table,
        token: token.to_owned(),
        filename: filename.to_owned(),
        reason,
    };
    if filename.is_empty() {
        return Err(reject("the filename is empty"));
    }
    // Both separators count, whatever the platform, so a Windows-style "..\\x" is caught too.
    if filename.starts_with('/') || filename.starts_with('\\') {
        return Err(reject(
            "absolute paths are not allowed; filenames are relative to the dataset root",
        ));
    }
    if filename.split(['/', '\\']).any(|part| part == "..") {
        return Err(reject("'..' components would leave the dataset root"));
    }
    let rel = Path::new(filename);
    for c in rel.components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err(reject("'..' components would leave the dataset root")),
            Component::RootDir | Component::Prefix(_) => {
                return Err(reject(
                    "absolute paths are not allowed; filenames are relative to the dataset root",
                ))
            }
        }
    }
    Ok(root.join(rel))
}

/// The folder holding `sample.json`: `path` itself or exactly one folder directly inside it.
fn find_version_dir(path: &Path) -> Result<PathBuf, DatasetError> {
    if path.join("sample.json").is_file() {
        return Ok(path.to_path_buf());
    }
    let entries = std::fs::read_dir(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut candidates: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir() && p.join("sample.json").is_file())
        .collect();
    candidates.sort();
    match candidates.len() {
        0 => Err(DatasetError::VersionFolderNotFound {
            path: path.to_path_buf(),
        }),
        1 => Ok(candidates.remove(0)),
        _ => Err(DatasetError::AmbiguousVersionFolder {
            path: path.to_path_buf(),
            candidates: candidates
                .iter()
                .filter_map(|p| p.file_name())
                .map(|n| n.to_string_lossy().into_owned())
                .collect(),
        }),
    }
}

/// Sample positions in scene order: scenes in file order, each scene's `first_sample_token` →
/// `next` chain, then the scene's samples the chain missed by timestamp; last, samples whose
/// scene is unknown, by timestamp. Each sample appears once; cycles end a chain.
// Every index is a position in `samples` (from `enumerate`, `Table::position` or `get`), and
// `placed` has the same length.
#[allow(clippy::indexing_slicing)]
fn scene_order(t: &Tables) -> Vec<usize> {
    let samples = t.sample.rows();
    let mut placed = vec![false; samples.len()];
    let mut order = Vec::with_capacity(samples.len());
    let mut by_scene: HashMap<&str, Vec<usize>> = HashMap::new();
    for (i, s) in samples.iter().enumerate() {
        by_scene.entry(s.scene_token.as_str()).or_default().push(i);
    }
    let by_time = |v: &mut Vec<usize>| {
        v.sort_by(|&a, &b| {
            samples[a]
                .timestamp
                .total_cmp(&samples[b].timestamp)
                .then(a.cmp(&b))
        });
    };
    let mut seen_scenes = HashSet::new();
    for scene in t.scene.rows() {
        if !seen_scenes.insert(scene.token.as_str()) {
            continue;
        }
        let mut cur = t.sample.position(&scene.first_sample_token);
        while let Some(i) = cur {
            let Some(s) = samples.get(i) else { break };
            if placed[i] || s.scene_token != scene.token {
                break;
            }
            placed[i] = true;
            order.push(i);
            cur = t.sample.position(&s.next);
        }
        let mut rest: Vec<usize> = by_scene
            .get(scene.token.as_str())
            .map(|v| v.iter().copied().filter(|&i| !placed[i]).collect())
            .unwrap_or_default();
        by_time(&mut rest);
        for i in rest {
            placed[i] = true;
            order.push(i);
        }
    }
    let mut orphans: Vec<usize> = (0..samples.len()).filter(|&i| !placed[i]).collect();
    by_time(&mut orphans);
    order.extend(orphans);
    order
}

/// The project's train/validation split of a dataset, by scene: the scenes in scene order, every
/// 10th (index % 10 == 9) is held out for validation (temperature fitting, tuning), the rest is
/// trained on. Returns the sample tokens of each, in scene order. Test scenes live in another
/// dataset generated with another seed.
pub fn train_validation_split(dataset: &Dataset) -> (Vec<String>, Vec<String>) {
    let mut scenes: Vec<String> = Vec::new();
    let (mut train, mut val) = (Vec::new(), Vec::new());
    for s in dataset.samples() {
        let idx = match scenes.iter().position(|x| *x == s.scene_token) {
            Some(i) => i,
            None => {
                scenes.push(s.scene_token.clone());
                scenes.len() - 1
            }
        };
        if idx % 10 == 9 {
            val.push(s.sample_token);
        } else {
            train.push(s.sample_token);
        }
    }
    (train, val)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolve_rejects_escapes() {
        let root = Path::new("/data/lyft");
        let ok = resolve_inside(root, "sample_data", "t", "lidar/a.bin").unwrap();
        assert_eq!(ok, Path::new("/data/lyft/lidar/a.bin"));
        assert!(resolve_inside(root, "sample_data", "t", "./lidar/a.bin").is_ok());
        for bad in [
            "../x.bin",
            "/etc/passwd",
            "lidar/../../x.bin",
            "lidar/..",
            "",
            "\\\\server\\x",
            "..\\x.bin",
        ] {
            let err = resolve_inside(root, "sample_data", "tok", bad).unwrap_err();
            let msg = err.to_string();
            assert!(msg.contains("tok") && msg.contains("sample_data"), "{msg}");
        }
    }

    #[test]
    fn channels_round_trip() {
        for c in LidarChannel::ALL {
            assert_eq!(LidarChannel::from_channel(c.as_str()), Some(c));
        }
        assert_eq!(LidarChannel::from_channel("CAM_FRONT"), None);
        assert_eq!(
            serde_json::to_string(&LidarChannel::FrontLeft).unwrap(),
            "\"LIDAR_FRONT_LEFT\""
        );
    }
}
