//! The one error type of the Lyft loader. Every variant says what went wrong and where: the file
//! (with line and column for JSON), the table and token, or the field that was bad, so that a user
//! pointing the tool at their own Lyft copy can fix the data without reading our code.

use std::path::PathBuf;

/// Everything that can go wrong while reading a Lyft/nuScenes-format dataset.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// Neither the given folder nor any folder directly inside it holds `sample.json`.
    #[error(
        "no dataset at {path}: expected a Lyft or nuScenes version folder (a folder holding sample.json) \
         at or directly inside it, a KITTI object folder (velodyne/, calib/, label_2/, or training/ holding them), \
         or Argoverse 2 sensor data (a log folder holding sensors/lidar/, a split folder of logs, or a root holding sensor/<split>/)"
    )]
    VersionFolderNotFound { path: PathBuf },

    /// The given folder holds several version folders and it is not clear which one is meant.
    #[error(
        "{path} holds several Lyft version folders ({}); pass one of them",
        candidates.join(", ")
    )]
    AmbiguousVersionFolder { path: PathBuf, candidates: Vec<String> },

    /// One of the 13 tables is absent from the version folder.
    #[error("table {table} is missing: {path} does not exist")]
    MissingTable { table: &'static str, path: PathBuf },

    /// A file could not be read (other than a missing table or point cloud).
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A table is not valid JSON or does not have the fields and types of its table.
    #[error("{path}:{line}:{column}: invalid {table} table: {source}")]
    Json {
        table: &'static str,
        path: PathBuf,
        line: usize,
        column: usize,
        #[source]
        source: serde_json::Error,
    },

    /// Two rows of one table share a token.
    #[error("{table}.json: token {token} appears more than once")]
    DuplicateToken { table: &'static str, token: String },

    /// A row names a token that its target table does not hold.
    #[error("{table} {token}: field {field} names {target} token {missing:?}, which does not exist")]
    DanglingReference {
        table: &'static str,
        token: String,
        field: &'static str,
        target: &'static str,
        missing: String,
    },

    /// The sample token asked for is not in sample.json.
    #[error("unknown sample token {token:?}")]
    UnknownSample { token: String },

    /// The dataset has no sample at all.
    #[error("the dataset at {path} has no samples")]
    NoSamples { path: PathBuf },

    /// Statistics were asked for and none of the selected samples could be read.
    #[error("no sample of the dataset at {path} could be read ({failed} failed; the first: {first})")]
    NoUsableSamples {
        path: PathBuf,
        failed: usize,
        first: String,
    },

    /// A sample without a key-frame LIDAR_TOP sweep: it has no base frame.
    #[error(
        "sample {sample_token} has no key-frame LIDAR_TOP sample_data; \
         the base frame is LIDAR_TOP's, so the sample cannot be loaded"
    )]
    NoLidarTop { sample_token: String },

    /// Two key-frame sweeps of the same LiDAR in one sample.
    #[error("sample {sample_token} has two key-frame {channel} sample_data: {first} and {second}")]
    DuplicateLidar {
        sample_token: String,
        channel: &'static str,
        first: String,
        second: String,
    },

    /// A filename from a table is absolute or climbs out of the dataset root with `..`.
    #[error("{table} {token}: filename {filename:?} is rejected: {reason}")]
    UnsafePath {
        table: &'static str,
        token: String,
        filename: String,
        reason: &'static str,
    },

    /// The `.bin` file a LiDAR sample_data names does not exist.
    #[error("point cloud {path} (sample_data {token}) is missing")]
    MissingPointCloud { path: PathBuf, token: String },

    /// A point file whose size is not a whole number of records.
    #[error(
        "point cloud {path}: size {size} bytes is not a multiple of {record} \
         ({layout}); the file is truncated or of another format"
    )]
    TruncatedPointCloud {
        path: PathBuf,
        size: u64,
        record: usize,
        layout: &'static str,
    },

    /// A file of a KITTI or Argoverse 2 dataset that cannot be read or is missing (a label,
    /// calib or calibration file; line 0: the file as a whole; an empty path: the message says
    /// it all).
    #[error("{}", located(path, *line, message))]
    BadFile {
        path: PathBuf,
        line: usize,
        message: String,
    },

    /// A feather (Arrow IPC) file that cannot be decoded, or a column that is missing, of another
    /// type, or holds a bad value (`column: None`: the file as a whole).
    #[error("{}{}: {message}", path.display(), column.as_ref().map_or(String::new(), |c| format!(", column {c}")))]
    BadColumn {
        path: PathBuf,
        column: Option<String>,
        message: String,
    },

    /// A quaternion field that is not finite or not of unit norm.
    #[error("{table} {token}: field {field} = {value:?} is not a unit quaternion [w, x, y, z]")]
    BadQuaternion {
        table: &'static str,
        token: String,
        field: &'static str,
        value: [f64; 4],
    },

    /// A vector field (translation, size) with a non-finite entry.
    #[error("{table} {token}: field {field} = {value:?} has a non-finite entry")]
    NonFinite {
        table: &'static str,
        token: String,
        field: &'static str,
        value: [f64; 3],
    },
}

/// `path:line: message`, `path: message` (line 0) or `message` (no path).
fn located(path: &std::path::Path, line: usize, message: &str) -> String {
    match (path.as_os_str().is_empty(), line) {
        (true, _) => message.to_owned(),
        (false, 0) => format!("{}: {message}", path.display()),
        (false, l) => format!("{}:{l}: {message}", path.display()),
    }
}
