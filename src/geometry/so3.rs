//! SO(3) and SE(3) helpers on nalgebra: the hat/vee operators, the exponential and logarithm
//! maps of so(3) (Barfoot & Furgale 2014, the paper's reference for eq. 1–2), roll/pitch/yaw
//! with R = Rz(yaw)·Ry(pitch)·Rx(roll), and Lyft's [w, x, y, z] quaternions.

use nalgebra::{Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A rigid transform T = [R | t]: `transform_point(p) = R p + t`.
pub type Pose = Isometry3<f64>;

/// The skew-symmetric matrix v^ such that v^ w = v × w.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The inverse of [`hat`]: reads the vector out of a (nearly) skew-symmetric matrix,
/// averaging the two mirrored entries.
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(
        0.5 * (m[(2, 1)] - m[(1, 2)]),
        0.5 * (m[(0, 2)] - m[(2, 0)]),
        0.5 * (m[(1, 0)] - m[(0, 1)]),
    )
}

/// exp(φ^) by Rodrigues' formula; exact to rounding for every φ, with a Taylor branch near 0.
pub fn exp(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let k = hat(phi);
    let (a, b) = if theta2 < 1e-12 {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        let theta = theta2.sqrt();
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2)
    };
    Matrix3::identity() + k * a + k * k * b
}

/// log(R)^∨: the rotation vector φ with exp(φ^) = R, |φ| ∈ [0, π].
pub fn log(r: &Matrix3<f64>) -> Vector3<f64> {
    // nalgebra's scaled_axis handles the θ ≈ π branch robustly via the quaternion.
    let rot = Rotation3::from_matrix(r);
    UnitQuaternion::from_rotation_matrix(&rot).scaled_axis()
}

/// R = Rz(yaw)·Ry(pitch)·Rx(roll), angles in radians.
pub fn rpy_to_matrix(roll: f64, pitch: f64, yaw: f64) -> Matrix3<f64> {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    Matrix3::new(
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )
}

/// The inverse of [`rpy_to_matrix`]: (roll, pitch, yaw) with pitch in [-π/2, π/2].
pub fn matrix_to_rpy(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let pitch = (-r[(2, 0)]).clamp(-1.0, 1.0).asin();
    if r[(2, 0)].abs() < 1.0 - 1e-9 {
        let roll = r[(2, 1)].atan2(r[(2, 2)]);
        let yaw = r[(1, 0)].atan2(r[(0, 0)]);
        (roll, pitch, yaw)
    } else {
        // Gimbal lock: only roll ∓ yaw is defined; put it all in yaw.
        let yaw = (-r[(0, 1)]).atan2(r[(1, 1)]);
        (0.0, pitch, yaw)
    }
}

/// A unit quaternion from Lyft's [w, x, y, z] order. `None` if any entry is not finite or the
/// norm is far from 1 (more than 1e-3 off), so that bad data is reported rather than renormalised silently.
pub fn quat_from_wxyz(q: [f64; 4]) -> Option<UnitQuaternion<f64>> {
    if q.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let quat = Quaternion::new(q[0], q[1], q[2], q[3]);
    let n = quat.norm();
    if (n - 1.0).abs() > 1e-3 {
        return None;
    }
    Some(UnitQuaternion::from_quaternion(quat))
}

/// Lyft's [w, x, y, z] order of a unit quaternion.
pub fn quat_to_wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// A pose from a rotation matrix (re-orthonormalised through a quaternion) and a translation.
pub fn pose_from_rt(r: &Matrix3<f64>, t: &Vector3<f64>) -> Pose {
    let rot = UnitQuaternion::from_matrix(r);
    Isometry3::from_parts(Translation3::from(*t), rot)
}

/// Yaw of a rotation: the heading angle of its x axis projected on the xy plane.
pub fn yaw_of(r: &Matrix3<f64>) -> f64 {
    r[(1, 0)].atan2(r[(0, 0)])
}

/// Wraps an angle into (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut x = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    if x <= -std::f64::consts::PI {
        x += two_pi;
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close(a: &Matrix3<f64>, b: &Matrix3<f64>, tol: f64) -> bool {
        (a - b).abs().max() <= tol
    }

    #[test]
    fn hat_is_cross_product_and_vee_inverts_it() {
        let v = Vector3::new(1.0, -2.0, 3.0);
        let w = Vector3::new(0.5, 4.0, -1.0);
        assert!((hat(&v) * w - v.cross(&w)).norm() < 1e-15);
        assert_eq!(vee(&hat(&v)), v);
    }

    #[test]
    fn rpy_matches_composition_of_elementary_rotations() {
        let (r, p, y) = (0.3, -0.2, 1.1);
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), y);
        let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), p);
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), r);
        let expect = (rz * ry * rx).into_inner();
        assert!(close(&rpy_to_matrix(r, p, y), &expect, 1e-14));
        let (r2, p2, y2) = matrix_to_rpy(&expect);
        assert!((r2 - r).abs() < 1e-12 && (p2 - p).abs() < 1e-12 && (y2 - y).abs() < 1e-12);
    }

    #[test]
    fn quaternion_wxyz_order() {
        // 90° about z: w = cos 45°, z = sin 45°.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let q = quat_from_wxyz([s, 0.0, 0.0, s]).unwrap();
        let r = q.to_rotation_matrix().into_inner();
        assert!(close(
            &r,
            &rpy_to_matrix(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            1e-12
        ));
        assert_eq!(quat_to_wxyz(&q), [q.w, 0.0, 0.0, q.k]);
        assert!(quat_from_wxyz([1.0, f64::NAN, 0.0, 0.0]).is_none());
        assert!(quat_from_wxyz([2.0, 0.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn exp_of_small_and_zero_vectors() {
        assert!(close(&exp(&Vector3::zeros()), &Matrix3::identity(), 0.0));
        let tiny = Vector3::new(1e-9, -2e-9, 3e-9);
        assert!(close(&exp(&tiny), &(Matrix3::identity() + hat(&tiny)), 1e-17));
    }

    #[test]
    fn wrap_angle_range() {
        use std::f64::consts::PI;
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
    }

    proptest! {
        #[test]
        fn exp_log_round_trip(x in -3.0f64..3.0, y in -3.0f64..3.0, z in -3.0f64..3.0) {
            let phi = Vector3::new(x, y, z);
            prop_assume!(phi.norm() < std::f64::consts::PI - 1e-6);
            let r = exp(&phi);
            // exp lands in SO(3) ...
            prop_assert!(close(&(r.transpose() * r), &Matrix3::identity(), 1e-12));
            prop_assert!((r.determinant() - 1.0).abs() < 1e-12);
            // ... and log inverts it.
            prop_assert!((log(&r) - phi).norm() < 1e-9);
        }

        #[test]
        fn log_exp_round_trip_from_rpy(r in -3.1f64..3.1, p in -1.5f64..1.5, y in -3.1f64..3.1) {
            let m = rpy_to_matrix(r, p, y);
            prop_assert!(close(&exp(&log(&m)), &m, 1e-9));
            let (r2, p2, y2) = matrix_to_rpy(&m);
            prop_assert!(close(&rpy_to_matrix(r2, p2, y2), &m, 1e-9));
        }

        #[test]
        fn exp_matches_nalgebra(x in -3.0f64..3.0, y in -3.0f64..3.0, z in -3.0f64..3.0) {
            let phi = Vector3::new(x, y, z);
            let reference = Rotation3::new(phi).into_inner();
            prop_assert!(close(&exp(&phi), &reference, 1e-12));
        }
    }
}
