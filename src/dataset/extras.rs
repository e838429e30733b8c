//! What a format's index keeps beyond the Lyft tables it builds: the problem that stops one
//! sample loading (found while indexing, reported when that sample is loaded), and what a label
//! says of an object beyond its box. KITTI and Argoverse 2 fill them; a leaf of `dataset`.

use std::path::PathBuf;

use serde::Serialize;

use super::error::DatasetError;

/// A problem of one frame found while indexing; reported when that frame is loaded.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameIssue {
    pub path: PathBuf,
    pub line: usize,
    pub message: String,
}

impl FrameIssue {
    pub fn to_error(&self) -> DatasetError {
        DatasetError::BadFile {
            path: self.path.clone(),
            line: self.line,
            message: self.message.clone(),
        }
    }
}

impl From<DatasetError> for FrameIssue {
    fn from(e: DatasetError) -> Self {
        match e {
            DatasetError::BadFile { path, line, message } => Self { path, line, message },
            other => Self {
                path: PathBuf::new(),
                line: 0,
                message: other.to_string(),
            },
        }
    }
}

/// What a label says of an object beyond its box, where the format says it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct LabelExtras {
    /// KITTI: 0 fully visible, 1 partly occluded, 2 largely occluded, 3 unknown.
    pub occlusion: Option<u8>,
    /// KITTI: the share of the object outside the image (0–1).
    pub truncation: Option<f32>,
}
