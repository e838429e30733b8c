//! Multi-LiDAR datasets behind one [`Frame`]: Lyft Level 5 in its on-disk (nuScenes-style) format
//! (the 13 JSON tables, the dataset index, `.bin` point clouds, and the writers the simulator uses
//! to emit the same format); KITTI ([`kitti`]) and Argoverse 2 ([`av2`]) are read into the same
//! in-memory tables.
//!
//! ```text
//! root/                      Dataset::open(root) or Dataset::open(root/v1.01-train)
//!   v1.01-train/*.json       tables::Tables (serde structs in the exact on-disk form)
//!   lidar/*.bin              pointcloud: float32 × 5 (x, y, z, intensity, ring), sensor frame
//!   maps/*.png
//! ```
//!
//! `dataset.frame(sample_token)` gives a [`Frame`]: LIDAR_TOP as the primary LiDAR (its frame is
//! the base frame, as in the paper), LIDAR_FRONT_LEFT / LIDAR_FRONT_RIGHT as auxiliaries, each with
//! its points in its own frame and its nominal extrinsic T^b_{l_i}, and the ground-truth boxes
//! moved into the base frame exactly as `lyft_dataset_sdk` does. Quaternions are [w, x, y, z];
//! annotation sizes are [w, l, h] on disk and (l, w, h) in [`crate::geometry::Box3d`]; timestamps
//! are float microseconds. Errors are [`DatasetError`], naming the file, table, token or field.

pub mod av2;
pub mod categories;
pub mod error;
pub mod extras;
pub mod frame;
pub mod index;
pub mod inspect;
pub mod kitti;
pub mod pointcloud;
pub mod region;
pub mod stats;
pub mod tables;

pub use error::DatasetError;
pub use extras::{FrameIssue, LabelExtras};
pub use frame::{pyquaternion_yaw, Frame, FrameInfo, GtBox, LidarInfo, LidarScan};
pub use index::{
    resolve_inside, train_validation_split, Dataset, DatasetFormat, LidarChannel, SampleSummary,
    UnmappedCategory,
};
pub use inspect::{inspect, inspect_with, list, InspectBox, InspectExtrinsic, InspectLidar, InspectReport};
pub use kitti::{EvalRegion, RegionVerdict};
pub use pointcloud::{
    encode_bin, parse_bin, parse_points, read_bin, write_bin, LoadOptions, PointCloud, PointLayout,
    POINT_BYTES,
};
pub use stats::{
    dataset_stats, out_of_depth_notes, summarize, DatasetStats, StatsOptions, StatsSummary, TrainingStats,
};
pub use tables::{to_devkit_json, write_table, Record, Table, Tables};
