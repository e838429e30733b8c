//! Geometry: SE(3)/SO(3) on nalgebra and the oriented 3D box. Rotated IoU and NMS live in
//! `eval` once they exist; everything here is small, exact and allocation-free.

pub mod box3d;
pub mod so3;

pub use box3d::Box3d;
pub use so3::{
    exp, hat, log, matrix_to_rpy, pose_from_rt, quat_from_wxyz, quat_to_wxyz, rpy_to_matrix, vee, wrap_angle,
    yaw_of, Pose,
};
