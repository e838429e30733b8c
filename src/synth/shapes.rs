//! Analytic ray–primitive intersection: the only geometry the ray caster knows besides the ground.
//!
//! A [`Primitive`] is a [`Shape`] placed in the world by a translation and a yaw about +z. Shapes
//! are closed convex solids written in their own frame: cuboids (slab test), cylinders along a
//! local axis (quadratic + slab), ellipsoids (quadratic on the scaled unit sphere) and the
//! intersection of a cuboid with an ellipsoid (a "rounded box": car bodies, cabins and buses get
//! rounded corners and sloped glass while still filling their box exactly at the face centres).
//! Each test returns the entry distance and the outward normal there; rays starting inside a solid
//! do not hit it. Surfaces carry a [`Material`] whose reflectivity drives intensity and detection.

/// What a LiDAR return hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Hit {
    /// The road, curbs, sidewalks, lawns.
    Ground,
    /// A building, wall, hedge, pole, sign or tree (not annotated).
    Static,
    /// The actor with this index in [`super::scene::SceneWorld::actors`].
    Actor(u32),
}

/// Surface reflectivity (0–1), optionally different on steep faces (glass sides of a cabin whose
/// roof is painted).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Reflectivity of faces whose normal is within ~53° of vertical.
    pub rho: f32,
    /// Reflectivity of the other (steep) faces.
    pub side_rho: f32,
}

impl Material {
    pub const fn uniform(rho: f32) -> Self {
        Self { rho, side_rho: rho }
    }

    pub const fn two_tone(top: f32, side: f32) -> Self {
        Self {
            rho: top,
            side_rho: side,
        }
    }

    /// The reflectivity at a point with this unit normal's z component.
    #[inline]
    pub fn reflectivity(&self, normal_z: f64) -> f32 {
        if normal_z.abs() > 0.6 {
            self.rho
        } else {
            self.side_rho
        }
    }
}

/// Reflectivities of the surfaces the simulator knows.
pub mod materials {
    use super::Material;

    pub const ASPHALT: Material = Material::uniform(0.07);
    pub const PAINT_WHITE: Material = Material::uniform(0.55);
    pub const PAINT_YELLOW: Material = Material::uniform(0.45);
    pub const CONCRETE: Material = Material::uniform(0.28);
    pub const CURB: Material = Material::uniform(0.32);
    pub const GRASS: Material = Material::uniform(0.18);
    pub const RUBBER: Material = Material::uniform(0.04);
    pub const GLASS: f32 = 0.03;
    pub const BARK: Material = Material::uniform(0.2);
    pub const FOLIAGE: Material = Material::uniform(0.24);
    pub const METAL: Material = Material::uniform(0.35);
    pub const RETROREFLECTOR: Material = Material::uniform(1.0);
    pub const SKIN: Material = Material::uniform(0.3);
}

/// A coordinate axis of a shape's own frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
}

/// A closed convex solid centred on its own origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// The box |x_i| ≤ half_i.
    Cuboid { half: [f64; 3] },
    /// A cylinder along `axis` of this radius, |axis coordinate| ≤ half_len.
    Cylinder { axis: Axis, radius: f64, half_len: f64 },
    /// The ellipsoid Σ (x_i / r_i)² ≤ 1.
    Ellipsoid { radii: [f64; 3] },
    /// A cuboid intersected with an ellipsoid centred at `offset`.
    RoundedCuboid {
        half: [f64; 3],
        radii: [f64; 3],
        offset: [f64; 3],
    },
}

/// The part of a ray inside a solid: [t_in, t_out] and the (unnormalised) normal at t_in.
#[derive(Debug, Clone, Copy)]
struct Span {
    t_in: f64,
    t_out: f64,
    n_in: [f64; 3],
}

impl Span {
    fn everywhere() -> Self {
        Self {
            t_in: f64::NEG_INFINITY,
            t_out: f64::INFINITY,
            n_in: [0.0, 0.0, 1.0],
        }
    }

    fn and(self, other: Span) -> Option<Span> {
        let (t_in, n_in) = if other.t_in > self.t_in {
            (other.t_in, other.n_in)
        } else {
            (self.t_in, self.n_in)
        };
        let t_out = self.t_out.min(other.t_out);
        (t_in <= t_out).then_some(Span { t_in, t_out, n_in })
    }
}

#[inline]
fn slab(o: f64, d: f64, lo: f64, hi: f64, axis: usize) -> Option<Span> {
    if d.abs() < 1e-12 {
        return (o >= lo && o <= hi).then(Span::everywhere);
    }
    let inv = 1.0 / d;
    let (t0, t1) = ((lo - o) * inv, (hi - o) * inv);
    let mut n = [0.0; 3];
    if t0 <= t1 {
        n[axis] = -1.0;
        Some(Span {
            t_in: t0,
            t_out: t1,
            n_in: n,
        })
    } else {
        n[axis] = 1.0;
        Some(Span {
            t_in: t1,
            t_out: t0,
            n_in: n,
        })
    }
}

#[inline]
fn box_span(o: &[f64; 3], d: &[f64; 3], half: &[f64; 3]) -> Option<Span> {
    slab(o[0], d[0], -half[0], half[0], 0)?
        .and(slab(o[1], d[1], -half[1], half[1], 1)?)?
        .and(slab(o[2], d[2], -half[2], half[2], 2)?)
}

#[inline]
fn ellipsoid_span(o: &[f64; 3], d: &[f64; 3], c: &[f64; 3], r: &[f64; 3]) -> Option<Span> {
    let p = [(o[0] - c[0]) / r[0], (o[1] - c[1]) / r[1], (o[2] - c[2]) / r[2]];
    let q = [d[0] / r[0], d[1] / r[1], d[2] / r[2]];
    let a = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
    let b = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let cc = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - 1.0;
    let disc = b * b - a * cc;
    if disc < 0.0 || a <= 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t_in = (-b - s) / a;
    let t_out = (-b + s) / a;
    let e = [p[0] + t_in * q[0], p[1] + t_in * q[1], p[2] + t_in * q[2]];
    Some(Span {
        t_in,
        t_out,
        n_in: [e[0] / r[0], e[1] / r[1], e[2] / r[2]],
    })
}

#[inline]
fn cylinder_span(o: &[f64; 3], d: &[f64; 3], axis: Axis, radius: f64, half_len: f64) -> Option<Span> {
    let k = axis.index();
    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
    let a = d[i] * d[i] + d[j] * d[j];
    let b = o[i] * d[i] + o[j] * d[j];
    let c = o[i] * o[i] + o[j] * o[j] - radius * radius;
    let radial = if a < 1e-14 {
        if c > 0.0 {
            return None;
        }
        Span::everywhere()
    } else {
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        let t_in = (-b - s) / a;
        let mut n = [0.0; 3];
        n[i] = o[i] + t_in * d[i];
        n[j] = o[j] + t_in * d[j];
        Span {
            t_in,
            t_out: (-b + s) / a,
            n_in: n,
        }
    };
    radial.and(slab(o[k], d[k], -half_len, half_len, k)?)
}

impl Shape {
    #[inline]
    fn span(&self, o: &[f64; 3], d: &[f64; 3]) -> Option<Span> {
        match self {
            Shape::Cuboid { half } => box_span(o, d, half),
            Shape::Cylinder {
                axis,
                radius,
                half_len,
            } => cylinder_span(o, d, *axis, *radius, *half_len),
            Shape::Ellipsoid { radii } => ellipsoid_span(o, d, &[0.0; 3], radii),
            Shape::RoundedCuboid { half, radii, offset } => {
                box_span(o, d, half)?.and(ellipsoid_span(o, d, offset, radii)?)
            }
        }
    }

    /// The shape's axis-aligned bounds (min, max) in its own frame.
    pub fn local_bounds(&self) -> ([f64; 3], [f64; 3]) {
        match self {
            Shape::Cuboid { half } => ([-half[0], -half[1], -half[2]], *half),
            Shape::Cylinder {
                axis,
                radius,
                half_len,
            } => {
                let mut h = [*radius; 3];
                h[axis.index()] = *half_len;
                ([-h[0], -h[1], -h[2]], h)
            }
            Shape::Ellipsoid { radii } => ([-radii[0], -radii[1], -radii[2]], *radii),
            Shape::RoundedCuboid { half, radii, offset } => {
                let lo = std::array::from_fn(|k| (-half[k]).max(offset[k] - radii[k]));
                let hi = std::array::from_fn(|k| half[k].min(offset[k] + radii[k]));
                (lo, hi)
            }
        }
    }

    /// Whether a point of the shape's own frame lies inside the solid (with a tolerance in m).
    pub fn contains(&self, p: &[f64; 3], tol: f64) -> bool {
        let in_ellipsoid = |c: &[f64; 3], r: &[f64; 3]| {
            let s: f64 = (0..3).map(|k| ((p[k] - c[k]) / (r[k] + tol)).powi(2)).sum();
            s <= 1.0
        };
        match self {
            Shape::Cuboid { half } => (0..3).all(|k| p[k].abs() <= half[k] + tol),
            Shape::Cylinder {
                axis,
                radius,
                half_len,
            } => {
                let k = axis.index();
                let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                p[k].abs() <= half_len + tol && p[i].hypot(p[j]) <= radius + tol
            }
            Shape::Ellipsoid { radii } => in_ellipsoid(&[0.0; 3], radii),
            Shape::RoundedCuboid { half, radii, offset } => {
                (0..3).all(|k| p[k].abs() <= half[k] + tol) && in_ellipsoid(offset, radii)
            }
        }
    }
}

/// A shape placed in the world: centre, yaw about +z, material and what it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    pub center: [f64; 3],
    cos: f64,
    sin: f64,
    pub shape: Shape,
    pub material: Material,
    pub owner: Hit,
}

impl Primitive {
    pub fn new(center: [f64; 3], yaw: f64, shape: Shape, material: Material, owner: Hit) -> Self {
        let (sin, cos) = yaw.sin_cos();
        Self {
            center,
            cos,
            sin,
            shape,
            material,
            owner,
        }
    }

    /// The nearest entry of the ray o + t·d (d unit, world frame) with t_min < t < t_max, and the
    /// unit outward normal there (world frame).
    #[inline]
    pub fn intersect(&self, o: &[f64; 3], d: &[f64; 3], t_min: f64, t_max: f64) -> Option<(f64, [f64; 3])> {
        let (c, s) = (self.cos, self.sin);
        let p = [
            o[0] - self.center[0],
            o[1] - self.center[1],
            o[2] - self.center[2],
        ];
        let lo = [c * p[0] + s * p[1], -s * p[0] + c * p[1], p[2]];
        let ld = [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]];
        let span = self.shape.span(&lo, &ld)?;
        if span.t_in <= t_min || span.t_in >= t_max {
            return None;
        }
        let n = span.n_in;
        let w = [c * n[0] - s * n[1], s * n[0] + c * n[1], n[2]];
        let len = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        if len <= 0.0 || !len.is_finite() {
            return Some((span.t_in, [0.0, 0.0, 1.0]));
        }
        Some((span.t_in, [w[0] / len, w[1] / len, w[2] / len]))
    }

    /// A world point in this primitive's own frame.
    pub fn to_local(&self, p: &[f64; 3]) -> [f64; 3] {
        let (c, s) = (self.cos, self.sin);
        let q = [
            p[0] - self.center[0],
            p[1] - self.center[1],
            p[2] - self.center[2],
        ];
        [c * q[0] + s * q[1], -s * q[0] + c * q[1], q[2]]
    }

    /// Conservative world-frame axis-aligned bounds (min, max).
    pub fn world_bounds(&self) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.shape.local_bounds();
        let (c, s) = (self.cos.abs(), self.sin.abs());
        let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        let half = [0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1])];
        let cx = self.center[0] + self.cos * mid[0] - self.sin * mid[1];
        let cy = self.center[1] + self.sin * mid[0] + self.cos * mid[1];
        let ex = c * half[0] + s * half[1];
        let ey = s * half[0] + c * half[1];
        (
            [cx - ex, cy - ey, self.center[2] + lo[2]],
            [cx + ex, cy + ey, self.center[2] + hi[2]],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prim(shape: Shape, yaw: f64) -> Primitive {
        Primitive::new([10.0, 0.0, 1.0], yaw, shape, materials::METAL, Hit::Static)
    }

    #[test]
    fn cuboid_entry_distance_and_normal() {
        let p = prim(
            Shape::Cuboid {
                half: [1.0, 2.0, 0.5],
            },
            0.0,
        );
        let (t, n) = p
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 9.0).abs() < 1e-12);
        assert_eq!(n, [-1.0, 0.0, 0.0]);
        // Rotated by 90°, the box is 4 m long along x.
        let p = prim(
            Shape::Cuboid {
                half: [1.0, 2.0, 0.5],
            },
            std::f64::consts::FRAC_PI_2,
        );
        let (t, _) = p
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 8.0).abs() < 1e-12);
        assert!(p
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 7.0)
            .is_none());
        assert!(p
            .intersect(&[0.0, 0.0, 3.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .is_none());
    }

    #[test]
    fn cylinder_and_ellipsoid() {
        let c = prim(
            Shape::Cylinder {
                axis: Axis::Z,
                radius: 0.5,
                half_len: 2.0,
            },
            0.3,
        );
        let (t, n) = c
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 9.5).abs() < 1e-12 && (n[0] + 1.0).abs() < 1e-12);
        let wheel = prim(
            Shape::Cylinder {
                axis: Axis::Y,
                radius: 0.5,
                half_len: 0.1,
            },
            0.0,
        );
        let (t, n) = wheel
            .intersect(&[10.0, -5.0, 1.0], &[0.0, 1.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 4.9).abs() < 1e-12 && (n[1] + 1.0).abs() < 1e-12);
        let e = prim(
            Shape::Ellipsoid {
                radii: [2.0, 1.0, 1.0],
            },
            0.0,
        );
        let (t, n) = e
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 8.0).abs() < 1e-12 && (n[0] + 1.0).abs() < 1e-12);
        let (t, n) = e
            .intersect(&[10.0, 0.0, 5.0], &[0.0, 0.0, -1.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 3.0).abs() < 1e-12 && (n[2] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rounded_cuboid_cuts_corners_but_keeps_face_centres() {
        let shape = Shape::RoundedCuboid {
            half: [2.0, 1.0, 0.5],
            radii: [2.2, 1.6, 5.0],
            offset: [0.0; 3],
        };
        let p = prim(shape, 0.0);
        // Face centre: same as the cuboid.
        let (t, _) = p
            .intersect(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!((t - 8.0).abs() < 1e-12);
        // Near a corner the ellipsoid cuts in.
        let (t, n) = p
            .intersect(&[0.0, 0.9, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .unwrap();
        assert!(t > 8.05 && n[1] > 0.0);
        let (lo, hi) = shape.local_bounds();
        assert_eq!((lo, hi), ([-2.0, -1.0, -0.5], [2.0, 1.0, 0.5]));
    }

    #[test]
    fn rays_from_inside_do_not_hit() {
        let p = prim(Shape::Cuboid { half: [1.0; 3] }, 0.0);
        assert!(p
            .intersect(&[10.0, 0.0, 1.0], &[1.0, 0.0, 0.0], 0.0, 100.0)
            .is_none());
    }

    #[test]
    fn world_bounds_contain_the_rotated_shape() {
        let p = prim(
            Shape::Cuboid {
                half: [2.0, 1.0, 0.5],
            },
            0.7,
        );
        let (lo, hi) = p.world_bounds();
        for sx in [-1.0, 1.0] {
            for sy in [-1.0, 1.0] {
                let (s, c) = 0.7f64.sin_cos();
                let x = 10.0 + c * 2.0 * sx - s * sy;
                let y = s * 2.0 * sx + c * sy;
                assert!(x >= lo[0] - 1e-12 && x <= hi[0] + 1e-12 && y >= lo[1] - 1e-12 && y <= hi[1] + 1e-12);
            }
        }
    }
}
