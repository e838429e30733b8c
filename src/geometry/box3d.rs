//! The one box type of the crate, with the conventions of DESIGN.md written once:
//! `center` is the geometric centre, `size` is (l, w, h) with l along the heading, `yaw` turns the
//! heading about +z and the heading is +x at yaw 0. Lyft stores size as [w, l, h] and a full
//! rotation quaternion; the paper's [x, y, z] is the bottom centre. Those forms are converted here,
//! at the edges, and nowhere inside algorithms.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::so3::{wrap_angle, yaw_of, Pose};

/// An oriented 3D box: centre, size (l, w, h) and yaw about +z.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Box3d {
    /// Geometric centre (m).
    pub center: [f64; 3],
    /// Length along the heading, width, height (m).
    pub size_lwh: [f64; 3],
    /// Heading about +z (rad); +x at 0.
    pub yaw: f64,
}

impl Box3d {
    pub fn new(center: [f64; 3], size_lwh: [f64; 3], yaw: f64) -> Self {
        Self {
            center,
            size_lwh,
            yaw,
        }
    }

    /// From Lyft's annotation fields: centre, size [w, l, h], rotation as a unit quaternion.
    /// The yaw is the heading of the rotated +x axis (Lyft boxes rotate about z only).
    pub fn from_lyft(center: [f64; 3], size_wlh: [f64; 3], rotation: &UnitQuaternion<f64>) -> Self {
        let r = rotation.to_rotation_matrix().into_inner();
        Self {
            center,
            size_lwh: [size_wlh[1], size_wlh[0], size_wlh[2]],
            yaw: yaw_of(&r),
        }
    }

    /// Lyft's size order [w, l, h].
    pub fn size_wlh(&self) -> [f64; 3] {
        [self.size_lwh[1], self.size_lwh[0], self.size_lwh[2]]
    }

    /// The rotation as a quaternion about +z (what Lyft stores).
    pub fn rotation(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw)
    }

    /// The paper's [x, y, z]: the centre of the bottom face.
    pub fn bottom_center(&self) -> [f64; 3] {
        [
            self.center[0],
            self.center[1],
            self.center[2] - 0.5 * self.size_lwh[2],
        ]
    }

    /// The box moved by a rigid transform. The new yaw is the heading of the transformed +x axis;
    /// a transform that tilts z keeps the box upright (as the devkits do for yaw-only boxes).
    pub fn transformed(&self, pose: &Pose) -> Self {
        let c = pose.transform_point(&Point3::from(self.center));
        let r = pose.rotation.to_rotation_matrix().into_inner()
            * self.rotation().to_rotation_matrix().into_inner();
        Self {
            center: [c.x, c.y, c.z],
            size_lwh: self.size_lwh,
            yaw: wrap_angle(yaw_of(&r)),
        }
    }

    /// The eight corners: bottom face counter-clockwise from front-left, then the top face.
    pub fn corners(&self) -> [[f64; 3]; 8] {
        let [l, w, h] = self.size_lwh;
        let (s, c) = self.yaw.sin_cos();
        let mut out = [[0.0; 3]; 8];
        let xs = [0.5 * l, -0.5 * l, -0.5 * l, 0.5 * l];
        let ys = [0.5 * w, 0.5 * w, -0.5 * w, -0.5 * w];
        for k in 0..8 {
            let (x, y) = (xs[k % 4], ys[k % 4]);
            let z = if k < 4 { -0.5 * h } else { 0.5 * h };
            out[k] = [
                self.center[0] + c * x - s * y,
                self.center[1] + s * x + c * y,
                self.center[2] + z,
            ];
        }
        out
    }

    /// A point in the box's own frame (x along the heading).
    pub fn to_local(&self, p: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.yaw.sin_cos();
        let dx = p[0] - self.center[0];
        let dy = p[1] - self.center[1];
        [c * dx + s * dy, -s * dx + c * dy, p[2] - self.center[2]]
    }

    /// Whether a point lies inside the box (boundary included), with an optional margin (m).
    pub fn contains(&self, p: [f64; 3], margin: f64) -> bool {
        let q = self.to_local(p);
        q[0].abs() <= 0.5 * self.size_lwh[0] + margin
            && q[1].abs() <= 0.5 * self.size_lwh[1] + margin
            && q[2].abs() <= 0.5 * self.size_lwh[2] + margin
    }

    /// Whether every field is finite and the sizes are positive.
    pub fn is_valid(&self) -> bool {
        self.center
            .iter()
            .chain(self.size_lwh.iter())
            .all(|v| v.is_finite())
            && self.yaw.is_finite()
            && self.size_lwh.iter().all(|&v| v > 0.0)
    }

    /// Distance of the centre from the origin in the xy plane (the paper's difficulty ranges).
    pub fn bev_range(&self) -> f64 {
        self.center[0].hypot(self.center[1])
    }
}

/// A box with a category and a confidence: what a detector outputs and what evaluation scores.
/// Ground truth uses the same type with `score` 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    pub box3d: Box3d,
    pub score: f32,
    pub category: String,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::so3::rpy_to_matrix;
    use nalgebra::{Isometry3, Translation3};

    #[test]
    fn lyft_size_order_is_swapped() {
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.4);
        let b = Box3d::from_lyft([1.0, 2.0, 3.0], [1.9, 4.6, 1.6], &q);
        assert_eq!(b.size_lwh, [4.6, 1.9, 1.6]);
        assert_eq!(b.size_wlh(), [1.9, 4.6, 1.6]);
        assert!((b.yaw - 0.4).abs() < 1e-12);
        assert!((b.bottom_center()[2] - 2.2).abs() < 1e-12);
    }

    #[test]
    fn corners_lie_on_the_box_and_heading_is_plus_x() {
        let b = Box3d::new([10.0, -3.0, 1.0], [4.0, 2.0, 1.5], std::f64::consts::FRAC_PI_2);
        // Heading +x rotated 90° is +y: the front-left corner is at y = -3 + 2, x = 10 - 1.
        let c = b.corners()[0];
        assert!((c[0] - 9.0).abs() < 1e-12 && (c[1] - -1.0).abs() < 1e-12 && (c[2] - 0.25).abs() < 1e-12);
        for c in b.corners() {
            assert!(b.contains(c, 1e-9));
            assert!(!b.contains([c[0] * 1.2, c[1] * 1.2, c[2] + 2.0], 0.0));
        }
    }

    #[test]
    fn transform_moves_centre_and_adds_yaw() {
        let b = Box3d::new([1.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.3);
        let pose = Isometry3::from_parts(
            Translation3::new(5.0, 0.0, 1.0),
            UnitQuaternion::from_matrix(&rpy_to_matrix(0.0, 0.0, std::f64::consts::FRAC_PI_2)),
        );
        let t = b.transformed(&pose);
        assert!((t.center[0] - 5.0).abs() < 1e-12 && (t.center[1] - 1.0).abs() < 1e-12);
        assert!((t.yaw - (0.3 + std::f64::consts::FRAC_PI_2)).abs() < 1e-12);
        // Round trip through the inverse.
        let back = t.transformed(&pose.inverse());
        assert!((back.yaw - b.yaw).abs() < 1e-12);
    }

    #[test]
    fn invalid_boxes_are_detected() {
        assert!(!Box3d::new([f64::NAN, 0.0, 0.0], [1.0; 3], 0.0).is_valid());
        assert!(!Box3d::new([0.0; 3], [1.0, -1.0, 1.0], 0.0).is_valid());
        assert!(Box3d::new([0.0; 3], [1.0; 3], 0.0).is_valid());
    }
}
