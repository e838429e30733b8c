//! The refiner's box coding (paper eq. 14) and its inverse.
//!
//! The target of a proposal b_p = (x_p, y_p, z_p, l_p, w_p, h_p, γ_p) toward a box b is
//! u = [Δx/l_p, Δy/w_p, Δz/h_p, (l − l_p)/l_p, (w − w_p)/w_p, (h − h_p)/h_p, sin(γ − γ_p),
//! cos(γ − γ_p)], where (Δx, Δy, Δz) is b's centre minus the proposal's *in the proposal's frame*
//! (rotated by −γ_p): b's centre normalised by eq. 12–13 exactly as the points are, so that the
//! network, which sees the points in that frame, regresses offsets in that frame. Decoding inverts
//! it: the centre offset rotated back by γ_p, sizes (1 + u)·size_p (at least 1 cm), heading
//! γ_p + atan2(u_sin, u_cos).

use crate::geometry::Box3d;

/// Number of residuals.
pub const RESIDUALS: usize = 8;

/// Eq. 14: the residuals of `target` relative to `proposal`.
pub fn encode(proposal: &Box3d, target: &Box3d) -> [f64; RESIDUALS] {
    let q = proposal.to_local(target.center);
    let [l, w, h] = proposal.size_lwh;
    let d = target.yaw - proposal.yaw;
    [
        q[0] / l,
        q[1] / w,
        q[2] / h,
        (target.size_lwh[0] - l) / l,
        (target.size_lwh[1] - w) / w,
        (target.size_lwh[2] - h) / h,
        d.sin(),
        d.cos(),
    ]
}

/// The box `proposal ⊕ u` (the inverse of [`encode`]).
pub fn decode(proposal: &Box3d, u: &[f64; RESIDUALS]) -> Box3d {
    let [l, w, h] = proposal.size_lwh;
    let (dx, dy, dz) = (u[0] * l, u[1] * w, u[2] * h);
    let (s, c) = proposal.yaw.sin_cos();
    let center = [
        proposal.center[0] + c * dx - s * dy,
        proposal.center[1] + s * dx + c * dy,
        proposal.center[2] + dz,
    ];
    let size = |k: usize, base: f64| ((1.0 + u[k]) * base).max(0.01);
    let d = u[6].atan2(u[7]);
    let mut yaw = proposal.yaw + if d.is_finite() { d } else { 0.0 };
    // Keep the heading in (−π, π].
    yaw = yaw.sin().atan2(yaw.cos());
    Box3d::new(center, [size(3, l), size(4, w), size(5, h)], yaw)
}

/// The residuals as the network outputs them (f32) → decoded box.
pub fn decode_f32(proposal: &Box3d, u: &[f32]) -> Box3d {
    let mut v = [0.0f64; RESIDUALS];
    for (k, x) in u.iter().take(RESIDUALS).enumerate() {
        v[k] = if x.is_finite() { *x as f64 } else { 0.0 };
    }
    if u.len() < RESIDUALS || (v[6] == 0.0 && v[7] == 0.0) {
        v[7] = 1.0;
    }
    decode(proposal, &v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn encode_then_decode_gives_the_box_back() {
        let mut rng = ChaCha8Rng::seed_from_u64(14);
        for _ in 0..1000 {
            let p = Box3d::new(
                [
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-2.0..1.0),
                ],
                [
                    rng.random_range(3.0..6.0),
                    rng.random_range(1.5..2.5),
                    rng.random_range(1.3..2.0),
                ],
                rng.random_range(-3.1..3.1),
            );
            let g = Box3d::new(
                [
                    p.center[0] + rng.random_range(-1.0..1.0),
                    p.center[1] + rng.random_range(-1.0..1.0),
                    p.center[2] + rng.random_range(-0.5..0.5),
                ],
                [
                    rng.random_range(3.0..6.0),
                    rng.random_range(1.5..2.5),
                    rng.random_range(1.3..2.0),
                ],
                rng.random_range(-3.1..3.1),
            );
            let b = decode(&p, &encode(&p, &g));
            for k in 0..3 {
                assert!((b.center[k] - g.center[k]).abs() < 1e-6, "{b:?} {g:?}");
                assert!((b.size_lwh[k] - g.size_lwh[k]).abs() < 1e-6);
            }
            let dyaw = (b.yaw - g.yaw).sin().abs().max((b.yaw - g.yaw).cos() - 1.0);
            assert!(dyaw < 1e-6, "{} vs {}", b.yaw, g.yaw);
        }
    }

    #[test]
    fn residuals_live_in_the_proposal_frame() {
        // A proposal heading +y; the target 1 m further along its heading and 0.2 m to its left.
        let p = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.5], std::f64::consts::FRAC_PI_2);
        let g = Box3d::new(
            [-0.2, 1.0, 0.3],
            [4.4, 2.0, 1.5],
            std::f64::consts::FRAC_PI_2 + 0.1,
        );
        let u = encode(&p, &g);
        let want = [0.25, 0.1, 0.2, 0.1, 0.0, 0.0, 0.1f64.sin(), 0.1f64.cos()];
        for (a, b) in u.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{u:?}");
        }
        // The identity and bad network output decode to the proposal itself.
        assert_eq!(
            decode(&p, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]).center,
            p.center
        );
        let b = decode_f32(&p, &[f32::NAN, 0.0, 0.0, 0.0, 0.0, -5.0, 0.0, 0.0]);
        assert_eq!(b.center, p.center);
        assert!(b.size_lwh[2] >= 0.01 && b.is_valid());
    }
}
