//! Exact overlap of oriented boxes: the bird's-eye-view (BEV) intersection of two rotated
//! rectangles by convex polygon clipping (Sutherland–Hodgman), the height overlap of two upright
//! boxes, and from them BEV IoU and 3D IoU (intersection volume over union volume), one pair at a
//! time or as an N×M matrix in parallel.
//!
//! A footprint is any rectangle given by its centre and two orthogonal half-axes, so the same
//! clipping serves the true footprint of a [`Box3d`] and the Lyft devkit's mirrored one (see
//! `eval::lyft`). Everything is `f64` and allocation-free per pair.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::Box3d;

/// Which overlap a caller wants.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum IouKind {
    /// Footprint area overlap over footprint union (heights ignored).
    Bev,
    /// Intersection volume over union volume of upright boxes.
    #[default]
    ThreeD,
}

/// A rectangle in the xy plane: corners in counter-clockwise order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    pub corners: [[f64; 2]; 4],
    /// Centre, for the quick rejection test.
    pub center: [f64; 2],
    /// Distance from the centre to a corner.
    pub radius: f64,
    pub area: f64,
}

impl Footprint {
    /// The rectangle `center ± u ± v` for orthogonal half-axes `u`, `v`, re-ordered
    /// counter-clockwise whatever the handedness of (u, v).
    pub fn from_axes(center: [f64; 2], u: [f64; 2], v: [f64; 2]) -> Self {
        let [cx, cy] = center;
        let mut corners = [
            [cx + u[0] + v[0], cy + u[1] + v[1]],
            [cx - u[0] + v[0], cy - u[1] + v[1]],
            [cx - u[0] - v[0], cy - u[1] - v[1]],
            [cx + u[0] - v[0], cy + u[1] - v[1]],
        ];
        if cross(u, v) < 0.0 {
            corners.reverse();
        }
        let area = 4.0 * cross(u, v).abs();
        let radius = (u[0] + v[0])
            .hypot(u[1] + v[1])
            .max((u[0] - v[0]).hypot(u[1] - v[1]));
        Self {
            corners,
            center,
            radius,
            area,
        }
    }

    /// The true footprint of a box: l along the heading, w across it.
    pub fn of_box(b: &Box3d) -> Self {
        let (s, c) = b.yaw.sin_cos();
        let hl = 0.5 * b.size_lwh[0];
        let hw = 0.5 * b.size_lwh[1];
        Self::from_axes([b.center[0], b.center[1]], [hl * c, hl * s], [-hw * s, hw * c])
    }

    /// Area of the intersection with another footprint (exact up to rounding).
    pub fn intersection_area(&self, other: &Footprint) -> f64 {
        let dx = self.center[0] - other.center[0];
        let dy = self.center[1] - other.center[1];
        let reach = self.radius + other.radius;
        if dx * dx + dy * dy > reach * reach {
            return 0.0;
        }
        convex_intersection_area(&self.corners, &other.corners)
    }
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

/// A small fixed-capacity polygon: clipping a quadrilateral by four half-planes never yields
/// more than 8 vertices.
#[derive(Clone, Copy)]
struct Poly {
    v: [[f64; 2]; 12],
    n: usize,
}

impl Poly {
    fn push(&mut self, p: [f64; 2]) {
        if self.n < self.v.len() {
            self.v[self.n] = p;
            self.n += 1;
        }
    }

    fn area(&self) -> f64 {
        let mut twice = 0.0;
        for i in 0..self.n {
            let a = self.v[i];
            let b = self.v[(i + 1) % self.n];
            twice += cross(a, b);
        }
        0.5 * twice.abs()
    }
}

/// Area of the intersection of two convex quadrilaterals given counter-clockwise: `subject` is
/// clipped by each edge of `clip` in turn (Sutherland–Hodgman); a vertex exactly on an edge
/// counts as inside, so touching rectangles give 0 and identical ones their own area.
pub fn convex_intersection_area(subject: &[[f64; 2]; 4], clip: &[[f64; 2]; 4]) -> f64 {
    let mut cur = Poly {
        v: [[0.0; 2]; 12],
        n: 4,
    };
    cur.v[..4].copy_from_slice(subject);
    for e in 0..4 {
        let p = clip[e];
        let q = clip[(e + 1) % 4];
        let edge = [q[0] - p[0], q[1] - p[1]];
        let side = |a: [f64; 2]| cross(edge, [a[0] - p[0], a[1] - p[1]]);
        let mut next = Poly {
            v: [[0.0; 2]; 12],
            n: 0,
        };
        for i in 0..cur.n {
            let s = cur.v[i];
            let t = cur.v[(i + 1) % cur.n];
            let ds = side(s);
            let dt = side(t);
            if ds >= 0.0 {
                next.push(s);
            }
            if (ds >= 0.0) != (dt >= 0.0) {
                let k = ds / (ds - dt);
                next.push([s[0] + k * (t[0] - s[0]), s[1] + k * (t[1] - s[1])]);
            }
        }
        if next.n < 3 {
            return 0.0;
        }
        cur = next;
    }
    cur.area()
}

/// Overlap of the vertical extents of two upright boxes (m), ≥ 0.
pub fn height_overlap(a: &Box3d, b: &Box3d) -> f64 {
    let lo = (a.center[2] - 0.5 * a.size_lwh[2]).max(b.center[2] - 0.5 * b.size_lwh[2]);
    let hi = (a.center[2] + 0.5 * a.size_lwh[2]).min(b.center[2] + 0.5 * b.size_lwh[2]);
    (hi - lo).max(0.0)
}

fn ratio(inter: f64, union: f64) -> f64 {
    if union > 0.0 && inter.is_finite() {
        (inter / union).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// BEV IoU: footprint intersection over footprint union.
pub fn iou_bev(a: &Box3d, b: &Box3d) -> f64 {
    let (fa, fb) = (Footprint::of_box(a), Footprint::of_box(b));
    let inter = fa.intersection_area(&fb);
    ratio(inter, fa.area + fb.area - inter)
}

/// 3D IoU of upright boxes: footprint intersection × height overlap over the union volume.
pub fn iou_3d(a: &Box3d, b: &Box3d) -> f64 {
    let h = height_overlap(a, b);
    if h <= 0.0 {
        return 0.0;
    }
    let inter = Footprint::of_box(a).intersection_area(&Footprint::of_box(b)) * h;
    let vol = |x: &Box3d| x.size_lwh[0] * x.size_lwh[1] * x.size_lwh[2];
    ratio(inter, vol(a) + vol(b) - inter)
}

/// IoU of one pair by kind.
pub fn iou(a: &Box3d, b: &Box3d, kind: IouKind) -> f64 {
    match kind {
        IouKind::Bev => iou_bev(a, b),
        IouKind::ThreeD => iou_3d(a, b),
    }
}

/// Pairs below which the matrix is computed on one thread.
const PARALLEL_PAIRS: usize = 4096;

/// The N×M IoU matrix, row-major (`out[i * m + j]` = IoU(a[i], b[j])), rows in parallel.
pub fn iou_matrix(a: &[Box3d], b: &[Box3d], kind: IouKind) -> Vec<f64> {
    let m = b.len();
    let mut out = vec![0.0; a.len() * m];
    if m == 0 {
        return out;
    }
    let fb: Vec<Footprint> = b.iter().map(Footprint::of_box).collect();
    let row = |(i, r): (usize, &mut [f64])| {
        let ai = &a[i];
        let fa = Footprint::of_box(ai);
        let va = ai.size_lwh[0] * ai.size_lwh[1] * ai.size_lwh[2];
        for (j, out) in r.iter_mut().enumerate() {
            let bj = &b[j];
            *out = match kind {
                IouKind::Bev => {
                    let inter = fa.intersection_area(&fb[j]);
                    ratio(inter, fa.area + fb[j].area - inter)
                }
                IouKind::ThreeD => {
                    let h = height_overlap(ai, bj);
                    if h <= 0.0 {
                        0.0
                    } else {
                        let inter = fa.intersection_area(&fb[j]) * h;
                        let vb = bj.size_lwh[0] * bj.size_lwh[1] * bj.size_lwh[2];
                        ratio(inter, va + vb - inter)
                    }
                }
            };
        }
    };
    if a.len() * m >= PARALLEL_PAIRS {
        out.par_chunks_mut(m).enumerate().for_each(row);
    } else {
        out.chunks_mut(m).enumerate().for_each(row);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_4, PI};

    fn bx(x: f64, y: f64, l: f64, w: f64, yaw: f64) -> Box3d {
        Box3d::new([x, y, 0.0], [l, w, 2.0], yaw)
    }

    #[test]
    fn identical_boxes_have_iou_one() {
        let b = bx(3.0, -2.0, 4.0, 2.0, 0.7);
        assert!((iou_bev(&b, &b) - 1.0).abs() < 1e-12);
        assert!((iou_3d(&b, &b) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn half_shifted_axis_aligned() {
        // 4×2 shifted 2 m along x: intersection 2×2 = 4, union 12.
        let a = bx(0.0, 0.0, 4.0, 2.0, 0.0);
        let b = bx(2.0, 0.0, 4.0, 2.0, 0.0);
        assert!((iou_bev(&a, &b) - 4.0 / 12.0).abs() < 1e-12);
    }

    #[test]
    fn touching_and_disjoint_are_zero() {
        let a = bx(0.0, 0.0, 4.0, 2.0, 0.0);
        assert_eq!(iou_bev(&a, &bx(4.0, 0.0, 4.0, 2.0, 0.0)), 0.0);
        assert_eq!(iou_bev(&a, &bx(0.0, 2.0, 4.0, 2.0, 0.0)), 0.0);
        assert_eq!(iou_bev(&a, &bx(10.0, 0.0, 4.0, 2.0, 0.3)), 0.0);
    }

    #[test]
    fn nested_box() {
        // 1×1 inside 4×2: IoU = 1/8.
        let a = bx(0.0, 0.0, 4.0, 2.0, 0.0);
        let b = bx(0.5, 0.2, 1.0, 1.0, 0.3);
        assert!((iou_bev(&a, &b) - 1.0 / 8.0).abs() < 1e-12);
    }

    #[test]
    fn square_rotated_45_degrees() {
        // Unit-half-side square and the same square turned 45°: the overlap is a regular
        // octagon of area 8(√2 − 1); union 8 − that.
        let a = bx(0.0, 0.0, 2.0, 2.0, 0.0);
        let b = bx(0.0, 0.0, 2.0, 2.0, FRAC_PI_4);
        let oct = 8.0 * (2f64.sqrt() - 1.0);
        assert!((iou_bev(&a, &b) - oct / (8.0 - oct)).abs() < 1e-12);
    }

    #[test]
    fn yaw_pi_is_the_same_box() {
        let a = bx(1.0, 2.0, 4.5, 1.9, 0.4);
        let b = bx(1.3, 2.2, 4.0, 2.0, 0.1);
        let c = bx(1.3, 2.2, 4.0, 2.0, 0.1 + PI);
        assert!((iou_3d(&a, &b) - iou_3d(&a, &c)).abs() < 1e-12);
    }

    #[test]
    fn height_overlap_scales_3d_iou() {
        let a = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 2.0], 0.0);
        let b = Box3d::new([0.0, 0.0, 1.0], [4.0, 2.0, 2.0], 0.0);
        // Same footprint, half the height shared: 8 / (16 + 16 − 8).
        assert!((iou_3d(&a, &b) - 8.0 / 24.0).abs() < 1e-12);
        assert!((iou_bev(&a, &b) - 1.0).abs() < 1e-12);
        let c = Box3d::new([0.0, 0.0, 2.0], [4.0, 2.0, 2.0], 0.0);
        assert_eq!(iou_3d(&a, &c), 0.0);
    }

    #[test]
    fn matrix_matches_pairs() {
        let a: Vec<Box3d> = (0..7)
            .map(|i| bx(i as f64 * 0.7, 0.1 * i as f64, 4.0, 2.0, 0.2 * i as f64))
            .collect();
        let b: Vec<Box3d> = (0..5)
            .map(|i| bx(i as f64, -0.2, 3.5, 1.8, -0.3 * i as f64))
            .collect();
        for kind in [IouKind::Bev, IouKind::ThreeD] {
            let m = iou_matrix(&a, &b, kind);
            for i in 0..a.len() {
                for j in 0..b.len() {
                    assert_eq!(m[i * b.len() + j], iou(&a[i], &b[j], kind));
                }
            }
        }
        assert!(iou_matrix(&a, &[], IouKind::Bev).is_empty());
    }
}
