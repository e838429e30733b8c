//! Evaluation: per-box outcomes (TP / FP / miss) with the residuals of each match, KITTI-style AP_3D as the paper reports it
//! (§V-A-2), and Lyft's official mAP exactly as the devkit computes it (plus a variant with the
//! true footprint). `dataset` ties them to a Lyft dataset and a predictions file, the input of
//! `mlod eval`.

pub mod ap;
pub mod dataset;
pub mod kitti;
pub mod localization;
pub mod lyft;
pub mod matching;
pub mod transfer;

pub use ap::Interpolation;
pub use dataset::{
    evaluate, evaluate_detections, parse_predictions, read_predictions, recall_by_range, sample_tokens,
    Attribution, EvalError, EvalOptions, EvalReport, PredictionSet,
};
pub use kitti::{kitti_ap, KittiConfig, SampleBoxes};
pub use localization::{with_truth, BoxError, Fix, LocalizationSummary};
pub use lyft::{lyft_iou, lyft_map, Footprints, LyftBox, LyftMap};
pub use matching::{match_drawn, match_sample, GtOutcome, MatchRule, PredOutcome, SampleMatch};
pub use transfer::{transfer_check, TransferReport, TransferRule};
