//! Argoverse 2's sensor dataset as it lies on disk, read into the same index as a Lyft dataset:
//! each log is a scene, each LiDAR sweep a sample with two LiDARs — `up_lidar` (the primary,
//! LIDAR_TOP's slot: its frame is the base frame) and `down_lidar` (the auxiliary, in
//! LIDAR_FRONT_LEFT's slot) — so everything downstream reads an AV2 sweep as it reads a Lyft one.
//!
//! ```text
//! av2/sensor/val/<log>/              Dataset::open(av2), (av2/sensor/val) or (…/<log>)
//!   sensors/lidar/<t_ns>.feather     x y z (float16, ego frame), intensity, laser_number, offset_ns
//!   calibration/egovehicle_SE3_sensor.feather   sensor_name, qw qx qy qz, tx_m ty_m tz_m
//!   city_SE3_egovehicle.feather      timestamp_ns, qw qx qy qz, tx_m ty_m tz_m
//!   annotations.feather              timestamp_ns, track_uuid, category, length/width/height_m,
//!                                    qw qx qy qz, tx_m ty_m tz_m (box centre, ego frame), num_interior_pts
//! ```
//!
//! How it works:
//! - The tables place each LiDAR at its factory calibration (`calibrated_sensor` = the
//!   calibration's pose in the ego frame) and the ego at its city pose at the sweep's timestamp;
//!   cuboids at the sweep's timestamp are moved from the ego frame to the city frame, and the
//!   generic frame code moves them back into `up_lidar`'s frame.
//! - Points: [`sweep::lidar_points`] picks a LiDAR's lasers (0–31 up, 32–63 down) and moves them
//!   from the ego frame into that LiDAR's sensor frame with the inverse of its calibration.
//! - Categories keep AV2's names (`REGULAR_VEHICLE`, …) in the tables and are mapped onto ours by
//!   [`super::categories`]; the unmapped ones are listed by the dataset and never scored.
//! - A log's problem (no calibration file, a bad column in its annotations) is an error of that
//!   log's samples only, naming the file and the column; every other log still opens. A log
//!   without an ego pose at a sweep's timestamp uses the identity (the boxes and points are in
//!   the ego frame either way) and says so.

#![deny(clippy::indexing_slicing)]

pub mod feather;
pub mod sweep;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, Vector3};

use self::feather::Feather;
use super::error::DatasetError;
use super::extras::FrameIssue;
use super::tables::{
    Attribute, CalibratedSensor, Category, EgoPose, Instance, Log, Map, Sample, SampleAnnotation, SampleData,
    Scene, Sensor, Table, Tables, Visibility,
};
use crate::geometry::{quat_from_wxyz, Pose};

/// The calibration file of a log, relative to the log folder.
pub const CALIBRATION: &str = "calibration/egovehicle_SE3_sensor.feather";
/// The ego poses of a log.
pub const POSES: &str = "city_SE3_egovehicle.feather";
/// The cuboids of a log.
pub const ANNOTATIONS: &str = "annotations.feather";
/// The sweeps of a log.
pub const SWEEPS: &str = "sensors/lidar";
/// The two LiDARs, primary first, with the slot each fills.
pub const LIDARS: [(&str, &str); 2] = [("up_lidar", "LIDAR_TOP"), ("down_lidar", "LIDAR_FRONT_LEFT")];

/// An AV2 split found on disk: where filenames are relative to, and its logs.
#[derive(Debug, Clone, PartialEq)]
pub struct Av2Layout {
    /// Table filenames are relative to it (the split folder, or the log folder when one log was
    /// given).
    pub root: PathBuf,
    /// Log folders (each holding `sensors/lidar/`), sorted by name.
    pub logs: Vec<PathBuf>,
    /// Which split was opened when the folder held several.
    pub note: Option<String>,
}

fn is_log(p: &Path) -> bool {
    p.join(SWEEPS).is_dir()
}

fn logs_in(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut logs: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| is_log(p))
        .collect();
    logs.sort();
    logs
}

/// The AV2 logs at `path`: one log folder, a split folder holding logs, or a dataset root
/// holding `sensor/<split>/` (or `<split>/`). Of several splits, `val` is opened first, then
/// `train`, then `test`, and a note names the others.
pub fn find_layout(path: &Path) -> Option<Av2Layout> {
    if is_log(path) {
        return Some(Av2Layout {
            root: path.to_path_buf(),
            logs: vec![path.to_path_buf()],
            note: None,
        });
    }
    let here = logs_in(path);
    if !here.is_empty() {
        return Some(Av2Layout {
            root: path.to_path_buf(),
            logs: here,
            note: None,
        });
    }
    for base in [path.join("sensor"), path.to_path_buf()] {
        let splits: Vec<(PathBuf, Vec<PathBuf>)> = ["val", "train", "test"]
            .iter()
            .map(|s| base.join(s))
            .map(|d| {
                let logs = logs_in(&d);
                (d, logs)
            })
            .filter(|(_, logs)| !logs.is_empty())
            .collect();
        let mut splits = splits.into_iter();
        if let Some((root, logs)) = splits.next() {
            let others: Vec<String> = splits.map(|(d, _)| d.display().to_string()).collect();
            let note = (!others.is_empty()).then(|| {
                format!(
                    "Argoverse 2: opened {}; pass {} to open the other split(s)",
                    root.display(),
                    others.join(" or ")
                )
            });
            return Some(Av2Layout { root, logs, note });
        }
    }
    None
}

/// What [`open`] builds: the tables, per sample the problem that stops it loading, notes.
pub struct Av2Index {
    pub tables: Tables,
    pub issues: HashMap<String, FrameIssue>,
    pub notes: Vec<String>,
}

/// A pose from a row of (qw, qx, qy, qz, tx, ty, tz); the columns are finite (checked by
/// [`Feather::finite_rows`]), the quaternion is checked here.
fn pose(path: &Path, row: usize, v: &[f64; 7]) -> Result<Pose, DatasetError> {
    let [qw, qx, qy, qz, tx, ty, tz] = *v;
    let q = quat_from_wxyz([qw, qx, qy, qz]).ok_or_else(|| DatasetError::BadColumn {
        path: path.to_path_buf(),
        column: Some("qw, qx, qy, qz".to_owned()),
        message: format!("row {row}: ({qw}, {qx}, {qy}, {qz}) is not a unit quaternion"),
    })?;
    Ok(Isometry3::from_parts(Translation3::new(tx, ty, tz), q))
}

const POSE_COLUMNS: [&str; 7] = ["qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m"];

/// The LiDARs' calibration of a log: `up_lidar` and `down_lidar` in the ego frame.
pub fn read_calibration(path: &Path) -> Result<BTreeMap<String, Pose>, DatasetError> {
    let f = Feather::read(path)?;
    let names = f.strings("sensor_name")?;
    let rows = f.finite_rows(POSE_COLUMNS)?;
    let mut out = BTreeMap::new();
    for (i, (name, row)) in names.iter().zip(&rows).enumerate() {
        if LIDARS.iter().any(|(n, _)| n == name) {
            out.insert(name.clone(), pose(path, i, row)?);
        }
    }
    if !out.contains_key("up_lidar") {
        return Err(DatasetError::BadColumn {
            path: path.to_path_buf(),
            column: Some("sensor_name".to_owned()),
            message: "no row for up_lidar (the primary LiDAR, whose frame is the base frame)".to_owned(),
        });
    }
    Ok(out)
}

/// The ego poses of a log by timestamp (ns).
pub fn read_poses(path: &Path) -> Result<HashMap<i64, Pose>, DatasetError> {
    let f = Feather::read(path)?;
    let ts = f.i64s("timestamp_ns")?;
    let rows = f.finite_rows(POSE_COLUMNS)?;
    ts.iter()
        .zip(&rows)
        .enumerate()
        .map(|(i, (t, row))| Ok((*t, pose(path, i, row)?)))
        .collect()
}

/// One cuboid of a log, in the ego frame at its timestamp.
#[derive(Debug, Clone, PartialEq)]
pub struct Cuboid {
    pub timestamp_ns: i64,
    pub track_uuid: String,
    pub category: String,
    /// Length, width, height (m).
    pub size: [f64; 3],
    /// Box frame → ego frame; translation = the box centre.
    pub pose: Pose,
    pub num_interior_pts: i64,
}

/// Every cuboid of a log.
pub fn read_annotations(path: &Path) -> Result<Vec<Cuboid>, DatasetError> {
    let f = Feather::read(path)?;
    let ts = f.i64s("timestamp_ns")?;
    let track = f.strings("track_uuid")?;
    let category = f.strings("category")?;
    let sizes = f.finite_rows(["length_m", "width_m", "height_m"])?;
    let poses = f.finite_rows(POSE_COLUMNS)?;
    let interior = f.i64s("num_interior_pts")?;
    let mut out = Vec::with_capacity(ts.len());
    for (i, ((((t, tr), c), size), (p, n))) in ts
        .iter()
        .zip(track)
        .zip(category)
        .zip(sizes)
        .zip(poses.iter().zip(&interior))
        .enumerate()
    {
        if let Some(bad) = size.iter().position(|v| *v < 0.0) {
            return Err(DatasetError::BadColumn {
                path: path.to_path_buf(),
                column: ["length_m", "width_m", "height_m"]
                    .get(bad)
                    .map(|s| (*s).to_owned()),
                message: format!("row {i}: a negative size"),
            });
        }
        out.push(Cuboid {
            timestamp_ns: *t,
            track_uuid: tr,
            category: c,
            size,
            pose: pose(path, i, p)?,
            num_interior_pts: *n,
        });
    }
    Ok(out)
}

/// The sweep timestamps of a log (from the file names), sorted; names that are not
/// `<integer>.feather` are skipped and counted.
fn sweeps(log: &Path) -> Result<(Vec<i64>, usize), DatasetError> {
    let dir = log.join(SWEEPS);
    let entries = std::fs::read_dir(&dir).map_err(|source| DatasetError::Io {
        path: dir.clone(),
        source,
    })?;
    let mut ts = Vec::new();
    let mut skipped = 0;
    for e in entries.filter_map(Result::ok) {
        let name = e.file_name().to_string_lossy().into_owned();
        match name.strip_suffix(".feather").and_then(|s| s.parse::<i64>().ok()) {
            Some(t) => ts.push(t),
            None => skipped += 1,
        }
    }
    ts.sort_unstable();
    Ok((ts, skipped))
}

/// A sample's token: `<log id>_<timestamp ns>`.
pub fn sample_token(log_id: &str, timestamp_ns: i64) -> String {
    format!("{log_id}_{timestamp_ns}")
}

/// The file name relative to `root` (forward slashes, as the tables write filenames).
fn relative(root: &Path, p: &Path) -> String {
    p.strip_prefix(root)
        .unwrap_or(p)
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("/")
}

/// The tables being filled, log by log.
#[derive(Default)]
struct Builder {
    scenes: Vec<Scene>,
    samples: Vec<Sample>,
    sample_data: Vec<SampleData>,
    calibrated: Vec<CalibratedSensor>,
    ego: Vec<EgoPose>,
    annotations: Vec<SampleAnnotation>,
    instances: Vec<Instance>,
    categories: BTreeMap<String, String>,
    logs: Vec<Log>,
    issues: HashMap<String, FrameIssue>,
    notes: Vec<String>,
}

fn wxyz(p: &Pose) -> [f64; 4] {
    let q = p.rotation;
    [q.w, q.i, q.j, q.k]
}

fn xyz(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl Builder {
    fn log(&mut self, root: &Path, log: &Path) -> Result<(), DatasetError> {
        let log_id = log
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "log".to_owned());
        let (stamps, skipped) = sweeps(log)?;
        if skipped > 0 {
            self.notes.push(format!(
                "Argoverse 2 log {log_id}: {skipped} file(s) in {SWEEPS}/ are not <timestamp_ns>.feather and are ignored"
            ));
        }
        if stamps.is_empty() {
            self.notes
                .push(format!("Argoverse 2 log {log_id}: no sweeps in {SWEEPS}/"));
            return Ok(());
        }
        let tokens: Vec<String> = stamps.iter().map(|t| sample_token(&log_id, *t)).collect();
        // A problem of the log's files is an issue of each of its samples.
        let log_issue = |this: &mut Self, e: DatasetError| {
            let issue = FrameIssue::from(e);
            for t in &tokens {
                this.issues.insert(t.clone(), issue.clone());
            }
        };

        let calib_path = log.join(CALIBRATION);
        let calibration = if calib_path.is_file() {
            match read_calibration(&calib_path) {
                Ok(c) => c,
                Err(e) => {
                    log_issue(self, e);
                    BTreeMap::new()
                }
            }
        } else {
            self.notes.push(format!(
                "Argoverse 2 log {log_id}: {} is missing; its sweeps do not load",
                calib_path.display()
            ));
            log_issue(
                self,
                DatasetError::BadFile {
                    path: calib_path.clone(),
                    line: 0,
                    message: format!(
                        "log {log_id}: the calibration file is missing (it places up_lidar and down_lidar on the car)"
                    ),
                },
            );
            BTreeMap::new()
        };
        for (name, _) in LIDARS {
            if let Some(p) = calibration.get(name) {
                self.calibrated.push(CalibratedSensor {
                    sensor_token: format!("av2-{name}"),
                    rotation: wxyz(p),
                    camera_intrinsic: Vec::new(),
                    translation: xyz(&p.translation.vector),
                    token: format!("{log_id}-{name}"),
                });
            }
        }

        let poses_path = log.join(POSES);
        let poses = if poses_path.is_file() {
            read_poses(&poses_path).unwrap_or_else(|e| {
                log_issue(self, e);
                HashMap::new()
            })
        } else {
            HashMap::new()
        };
        let ann_path = log.join(ANNOTATIONS);
        let cuboids = if ann_path.is_file() {
            read_annotations(&ann_path).unwrap_or_else(|e| {
                log_issue(self, e);
                Vec::new()
            })
        } else {
            self.notes.push(format!(
                "Argoverse 2 log {log_id}: no {ANNOTATIONS}: its sweeps have no ground truth"
            ));
            Vec::new()
        };
        let mut by_time: HashMap<i64, Vec<&Cuboid>> = HashMap::new();
        for c in &cuboids {
            by_time.entry(c.timestamp_ns).or_default().push(c);
        }

        let mut without_pose = 0;
        for (k, (&t, token)) in stamps.iter().zip(&tokens).enumerate() {
            let timestamp = t as f64 / 1000.0;
            let neighbour = |j: Option<usize>| j.and_then(|j| tokens.get(j)).cloned().unwrap_or_default();
            let (prev, next) = (neighbour(k.checked_sub(1)), neighbour(Some(k + 1)));
            self.samples.push(Sample {
                next: next.clone(),
                prev: prev.clone(),
                token: token.clone(),
                scene_token: log_id.clone(),
                timestamp,
            });
            let ego_pose = poses.get(&t).copied().unwrap_or_else(|| {
                without_pose += 1;
                Pose::identity()
            });
            let ego_token = format!("{token}-ego");
            self.ego.push(EgoPose {
                rotation: wxyz(&ego_pose),
                translation: xyz(&ego_pose.translation.vector),
                token: ego_token.clone(),
                timestamp,
            });
            let filename = relative(root, &log.join(SWEEPS).join(format!("{t}.feather")));
            for (name, _) in LIDARS {
                if !calibration.contains_key(name) {
                    continue;
                }
                let link = |s: &str| {
                    if s.is_empty() {
                        String::new()
                    } else {
                        format!("{s}-{name}")
                    }
                };
                self.sample_data.push(SampleData {
                    is_key_frame: true,
                    prev: link(&prev),
                    fileformat: "feather".to_owned(),
                    ego_pose_token: ego_token.clone(),
                    timestamp,
                    next: link(&next),
                    token: format!("{token}-{name}"),
                    sample_token: token.clone(),
                    filename: filename.clone(),
                    calibrated_sensor_token: format!("{log_id}-{name}"),
                    width: None,
                    height: None,
                });
            }
            for (j, c) in by_time
                .get(&t)
                .map(Vec::as_slice)
                .unwrap_or_default()
                .iter()
                .enumerate()
            {
                let global = ego_pose * c.pose;
                let cat_token = self
                    .categories
                    .entry(c.category.clone())
                    .or_insert_with(|| format!("av2-category-{}", c.category))
                    .clone();
                let ann_token = format!("{token}-{j}");
                let inst_token = format!("{token}-{j}-{}", c.track_uuid);
                let [l, w, h] = c.size;
                self.annotations.push(SampleAnnotation {
                    token: ann_token.clone(),
                    num_lidar_pts: c.num_interior_pts,
                    size: [w, l, h],
                    sample_token: token.clone(),
                    rotation: wxyz(&global),
                    prev: String::new(),
                    translation: xyz(&global.translation.vector),
                    num_radar_pts: 0,
                    attribute_tokens: Vec::new(),
                    next: String::new(),
                    instance_token: inst_token.clone(),
                    visibility_token: String::new(),
                });
                self.instances.push(Instance {
                    last_annotation_token: ann_token.clone(),
                    category_token: cat_token,
                    token: inst_token,
                    first_annotation_token: ann_token,
                    nbr_annotations: 1,
                });
            }
        }
        if without_pose > 0 && !poses.is_empty() {
            self.notes.push(format!(
                "Argoverse 2 log {log_id}: {without_pose} sweep(s) have no pose in {POSES} at their timestamp; \
                 the identity is used (points and boxes are in the ego frame either way)"
            ));
        }
        self.scenes.push(Scene {
            description: format!("Argoverse 2 log {log_id}"),
            log_token: log_id.clone(),
            name: log_id.clone(),
            first_sample_token: tokens.first().cloned().unwrap_or_default(),
            last_sample_token: tokens.last().cloned().unwrap_or_default(),
            nbr_samples: u32::try_from(tokens.len()).unwrap_or(u32::MAX),
            token: log_id.clone(),
        });
        self.logs.push(Log {
            date_captured: String::new(),
            location: String::new(),
            token: log_id,
            vehicle: "argoverse2".to_owned(),
            logfile: String::new(),
        });
        Ok(())
    }

    fn finish(self) -> Result<Av2Index, DatasetError> {
        let tables = Tables {
            scene: Table::new(self.scenes)?,
            sample: Table::new(self.samples)?,
            sample_data: Table::new(self.sample_data)?,
            calibrated_sensor: Table::new(self.calibrated)?,
            sensor: Table::new(
                LIDARS
                    .iter()
                    .map(|(name, slot)| Sensor {
                        modality: "lidar".to_owned(),
                        channel: (*slot).to_owned(),
                        token: format!("av2-{name}"),
                    })
                    .collect(),
            )?,
            ego_pose: Table::new(self.ego)?,
            sample_annotation: Table::new(self.annotations)?,
            instance: Table::new(self.instances)?,
            category: Table::new(
                self.categories
                    .into_iter()
                    .map(|(name, token)| Category {
                        description: "Argoverse 2 category".to_owned(),
                        token,
                        name,
                    })
                    .collect(),
            )?,
            attribute: Table::new(Vec::<Attribute>::new())?,
            visibility: Table::new(Vec::<Visibility>::new())?,
            log: Table::new(self.logs)?,
            map: Table::new(Vec::<Map>::new())?,
        };
        Ok(Av2Index {
            tables,
            issues: self.issues,
            notes: self.notes,
        })
    }
}

/// Reads every log's calibration, poses and cuboids into in-memory tables (a scene per log, a
/// sample per sweep). Sweeps are read only when a frame is loaded.
pub fn open(layout: &Av2Layout) -> Result<Av2Index, DatasetError> {
    let mut b = Builder::default();
    b.notes.extend(layout.note.iter().cloned());
    for log in &layout.logs {
        b.log(&layout.root, log)?;
    }
    if b.samples.is_empty() {
        return Err(DatasetError::NoSamples {
            path: layout.root.clone(),
        });
    }
    b.finish()
}
