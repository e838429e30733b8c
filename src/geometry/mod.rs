//! Geometry: SE(3)/SO(3) on nalgebra, the oriented 3D box, rotated BEV/3D IoU and NMS;
//! everything here is small, exact and allocation-free per box or pair.

pub mod box3d;
pub mod iou;
pub mod nms;
pub mod so3;

pub use box3d::{Box3d, Detection};
pub use iou::{iou_3d, iou_bev, iou_matrix, IouKind};
pub use nms::{nms, vote};
pub use so3::{
    exp, hat, log, matrix_to_rpy, pose_from_rt, quat_from_wxyz, quat_to_wxyz, rpy_to_matrix, vee, wrap_angle,
    yaw_of, Pose,
};
