//! The library half of `mlod inspect`: a JSON-ready summary of one sample (LiDARs with point
//! counts and extrinsics T^b_{l_i}, ground-truth boxes in the base frame) and the sample list.
//!
//! How it works: [`inspect`] builds the frame's geometry with [`Dataset::frame_info`] (tables only),
//! then tries to read every LiDAR's `.bin`. A LiDAR whose file cannot be read keeps its entry with
//! `num_points`/`dropped_points` = null and its error goes to [`InspectReport::errors`] (not part
//! of the JSON), so the CLI can print the boxes and still exit non-zero naming the missing files —
//! which is what happens on the real Lyft table excerpt, whose `.bin` files are not shipped.

#![deny(clippy::indexing_slicing)]

use serde::Serialize;

use super::error::DatasetError;
use super::frame::LidarInfo;
use super::index::{Dataset, SampleSummary};
use super::pointcloud::LoadOptions;
use crate::geometry::{quat_to_wxyz, Pose};

/// `{"sample_token", "lidars": [...], "boxes": [...]}`.
#[derive(Debug, Serialize)]
pub struct InspectReport {
    pub sample_token: String,
    /// The format the dataset was read from (`lyft`, `nuscenes`, `kitti`).
    pub format: super::DatasetFormat,
    /// LIDAR_TOP first, then LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT (those present).
    pub lidars: Vec<InspectLidar>,
    /// In sample_annotation.json order.
    pub boxes: Vec<InspectBox>,
    /// Point clouds that could not be read (missing, truncated, unreadable); not serialized.
    #[serde(skip)]
    pub errors: Vec<DatasetError>,
    /// Non-fatal notes (unknown LiDAR channels, trimmed files); not serialized.
    #[serde(skip)]
    pub warnings: Vec<String>,
}

impl InspectReport {
    /// Every LiDAR's points were read.
    pub fn is_complete(&self) -> bool {
        self.errors.is_empty()
    }
}

/// `{"channel", "num_points", "dropped_points", "file", "extrinsic"}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InspectLidar {
    pub channel: String,
    /// Finite points read; `null` when the file could not be read.
    pub num_points: Option<usize>,
    /// Non-finite points dropped; `null` when the file could not be read.
    pub dropped_points: Option<usize>,
    /// The `.bin` path (dataset root as given, joined with the table's filename).
    pub file: String,
    /// T^b_{l_i}: this LiDAR's frame → the base frame.
    pub extrinsic: InspectExtrinsic,
}

/// `{"translation": [x, y, z], "rotation_wxyz": [w, x, y, z]}`, with w ≥ 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InspectExtrinsic {
    pub translation: [f64; 3],
    pub rotation_wxyz: [f64; 4],
}

impl From<&Pose> for InspectExtrinsic {
    fn from(p: &Pose) -> Self {
        let mut q = quat_to_wxyz(&p.rotation);
        if q[0] < 0.0 {
            q = q.map(|v| -v);
        }
        let t = p.translation.vector;
        Self {
            translation: [t.x, t.y, t.z],
            rotation_wxyz: q,
        }
    }
}

/// `{"category", "center", "size_lwh", "yaw"}` in the base frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InspectBox {
    /// Our category name (`car`, …).
    pub category: String,
    /// The name as the dataset writes it (`vehicle.car`, `Car`, `car`).
    pub source_category: String,
    pub center: [f64; 3],
    pub size_lwh: [f64; 3],
    /// Heading of the box x axis about +z, atan2(R₁₀, R₀₀) ∈ [−π, π] (rad).
    pub yaw: f64,
}

/// Inspects a sample (the first in scene order when `sample` is `None`), reading point clouds
/// strictly. Errors only when the sample itself cannot be built (unknown token, no LIDAR_TOP,
/// broken tables); unreadable point clouds are collected in [`InspectReport::errors`].
pub fn inspect(dataset: &Dataset, sample: Option<&str>) -> Result<InspectReport, DatasetError> {
    inspect_with(dataset, sample, LoadOptions::default())
}

/// [`inspect`] with explicit point-cloud options (e.g. lenient reading of truncated files).
pub fn inspect_with(
    dataset: &Dataset,
    sample: Option<&str>,
    opts: LoadOptions,
) -> Result<InspectReport, DatasetError> {
    let token = match sample {
        Some(t) => t,
        None => dataset
            .first_sample_token()
            .ok_or_else(|| DatasetError::NoSamples {
                path: dataset.root().to_path_buf(),
            })?,
    };
    let info = dataset.frame_info(token)?;
    let mut errors = Vec::new();
    let mut warnings = info.warnings.clone();
    let mut lidars = Vec::with_capacity(1 + info.auxiliaries.len());
    for l in info.lidars() {
        let (num_points, dropped_points) = match l.load_points(opts) {
            Ok(cloud) => {
                if cloud.trimmed_bytes > 0 {
                    warnings.push(format!(
                        "{}: ignored the last {} bytes (size not a multiple of 20)",
                        l.path.display(),
                        cloud.trimmed_bytes
                    ));
                }
                (Some(cloud.len()), Some(cloud.dropped))
            }
            Err(e) => {
                errors.push(e);
                (None, None)
            }
        };
        lidars.push(lidar_entry(l, num_points, dropped_points));
    }
    let boxes = info
        .boxes
        .iter()
        .map(|b| InspectBox {
            category: b.category.clone(),
            source_category: b.source_category.clone(),
            center: b.box3d.center,
            size_lwh: b.box3d.size_lwh,
            yaw: b.box3d.yaw,
        })
        .collect();
    Ok(InspectReport {
        sample_token: info.sample_token,
        format: dataset.format(),
        lidars,
        boxes,
        errors,
        warnings,
    })
}

fn lidar_entry(l: &LidarInfo, num_points: Option<usize>, dropped_points: Option<usize>) -> InspectLidar {
    InspectLidar {
        channel: l.channel.as_str().to_owned(),
        num_points,
        dropped_points,
        file: l.path.display().to_string(),
        extrinsic: InspectExtrinsic::from(&l.extrinsic),
    }
}

/// Every sample in scene order with its LiDAR channels and box count (`mlod inspect --list`).
pub fn list(dataset: &Dataset) -> Vec<SampleSummary> {
    dataset.samples()
}
