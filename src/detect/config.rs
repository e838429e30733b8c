//! What defines a trained stage-1 model besides its weights: grid, network, anchors and decoding
//! settings. It sits below both [`super::model`] (candle's graph, training) and [`super::infer`]
//! (the folded inference network), which each build a network from it.

use serde::{Deserialize, Serialize};

use super::anchors::AnchorConfig;
use super::net::NetConfig;
use super::voxel::GridConfig;
use super::Case;

/// Everything that defines a trained stage-1 model besides its weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    pub case: Case,
    pub grid: GridConfig,
    pub net: NetConfig,
    pub anchor: AnchorConfig,
    /// Detections below this score are dropped.
    pub score_threshold: f32,
    /// Candidates kept before NMS.
    pub pre_nms: usize,
    /// BEV IoU above which NMS suppresses a box.
    pub nms_iou: f64,
    /// Detections kept after NMS.
    pub max_detections: usize,
    /// Box voting after NMS ([`crate::geometry::nms::vote`]): each kept box becomes the
    /// score-weighted mean of the candidates overlapping it by at least this BEV IoU. `None`
    /// (the default, and every model trained before it existed) keeps NMS's boxes as they are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vote_iou: Option<f64>,
}

impl ModelConfig {
    /// The default configuration of a trainable case.
    pub fn new(case: Case) -> Self {
        Self {
            case,
            grid: GridConfig::default(),
            net: NetConfig::default(),
            anchor: AnchorConfig::default(),
            score_threshold: 0.05,
            pre_nms: 500,
            nms_iou: 0.1,
            max_detections: 100,
            vote_iou: None,
        }
    }

    /// The names of the network branches: one per LiDAR in Feature Fusion, else one.
    pub fn branch_names(&self) -> Vec<&'static str> {
        match self.case {
            Case::Feature => vec!["top", "left", "right"],
            c => vec![c.as_str()],
        }
    }
}
