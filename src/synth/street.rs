//! A Palo Alto-like street: cross-section, ground height field, surface materials and the static
//! structures along it (buildings, walls, hedges, street lights, signs, trees).
//!
//! Each street has its own frame: x along the street, y to the left, z up (global z). The
//! cross-section is symmetric: 1 or 2 travel lanes per direction (3.5 m), a bike lane (1.5 m), a
//! parking lane (2.4 m), a 15 cm curb, a planting strip (1.5 m) with trees and poles, a sidewalk
//! (1.6 m), then front yards and houses. The ground is a height field — a gentle plane (grade up to
//! 3 %, cross slope up to 1 %) plus two long sinusoidal undulations — raised by the curb height
//! beyond the curbs. Rays meet it by Lipschitz-safe marching on each piece between curb crossings
//! (then bisection), and meet the curb faces exactly. Materials: asphalt with lane paint (double
//! yellow centre line, dashed lane divider, solid bike and parking lines), concrete curbs,
//! sidewalks and driveways, grass strips and lawns. Not modelled: intersections and cross
//! streets, crosswalks, road crown, potholes, vegetation other than trees and hedges.

use rand::Rng;

use super::shapes::{materials, Axis, Hit, Material, Primitive, Shape};

/// The cross-section of a street (m); everything is symmetric about y = 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreetLayout {
    pub lanes_per_direction: u32,
    pub lane_width: f64,
    pub bike_lane_width: f64,
    pub parking_width: f64,
    pub curb_height: f64,
    pub strip_width: f64,
    pub sidewalk_width: f64,
}

impl StreetLayout {
    /// |y| of the outer edge of the travel lanes.
    pub fn travel_edge(&self) -> f64 {
        f64::from(self.lanes_per_direction) * self.lane_width
    }

    /// |y| of the outer edge of the bike lane.
    pub fn bike_outer(&self) -> f64 {
        self.travel_edge() + self.bike_lane_width
    }

    /// |y| of the curb.
    pub fn curb(&self) -> f64 {
        self.bike_outer() + self.parking_width
    }

    /// |y| of the outer edge of the planting strip.
    pub fn strip_outer(&self) -> f64 {
        self.curb() + self.strip_width
    }

    /// |y| of the outer edge of the sidewalk (the property line).
    pub fn sidewalk_outer(&self) -> f64 {
        self.strip_outer() + self.sidewalk_width
    }

    /// The centre y of travel lane `i` (0 = innermost) for traffic heading `dir` (+1 = +x);
    /// traffic keeps to the right.
    pub fn lane_center(&self, dir: f64, i: u32) -> f64 {
        -dir * (f64::from(i) + 0.5) * self.lane_width
    }
}

/// The ground height field of a street frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Ground {
    pub layout: StreetLayout,
    /// Height at the street origin (global z, m).
    pub z0: f64,
    /// Plane slopes along x and y.
    pub slope: [f64; 2],
    /// Amplitudes (m), wave vectors (rad/m) and phases of two undulations.
    amp: [f64; 2],
    wave: [[f64; 2]; 2],
    phase: [f64; 2],
    /// Driveway x-intervals on the right (y < 0) and left (y > 0) sides, sorted.
    driveways: [Vec<(f64, f64)>; 2],
}

impl Ground {
    fn random(layout: StreetLayout, rng: &mut impl Rng) -> Self {
        let wave = |rng: &mut dyn rand::RngCore, lo: f64, hi: f64| {
            let lambda = rng.random_range(lo..hi);
            let dir = rng.random_range(-0.5..0.5f64);
            let k = std::f64::consts::TAU / lambda;
            [k * dir.cos(), k * dir.sin()]
        };
        Self {
            layout,
            z0: rng.random_range(-25.0..-10.0),
            slope: [rng.random_range(-0.03..0.03), rng.random_range(-0.01..0.01)],
            amp: [rng.random_range(0.1..0.4), rng.random_range(0.03..0.12)],
            wave: [wave(rng, 70.0, 160.0), wave(rng, 30.0, 60.0)],
            phase: [
                rng.random_range(0.0..std::f64::consts::TAU),
                rng.random_range(0.0..std::f64::consts::TAU),
            ],
            driveways: [Vec::new(), Vec::new()],
        }
    }

    /// The height of the road surface (curb not included).
    #[inline]
    pub fn base_height(&self, x: f64, y: f64) -> f64 {
        self.z0
            + self.slope[0] * x
            + self.slope[1] * y
            + self.amp[0] * (self.wave[0][0] * x + self.wave[0][1] * y + self.phase[0]).sin()
            + self.amp[1] * (self.wave[1][0] * x + self.wave[1][1] * y + self.phase[1]).sin()
    }

    #[inline]
    fn base_gradient(&self, x: f64, y: f64) -> [f64; 2] {
        let c0 = self.amp[0] * (self.wave[0][0] * x + self.wave[0][1] * y + self.phase[0]).cos();
        let c1 = self.amp[1] * (self.wave[1][0] * x + self.wave[1][1] * y + self.phase[1]).cos();
        [
            self.slope[0] + c0 * self.wave[0][0] + c1 * self.wave[1][0],
            self.slope[1] + c0 * self.wave[0][1] + c1 * self.wave[1][1],
        ]
    }

    /// The curb step at this y: 0 on the road, the curb height beyond the curbs.
    #[inline]
    fn step(&self, y: f64) -> f64 {
        if y.abs() >= self.layout.curb() {
            self.layout.curb_height
        } else {
            0.0
        }
    }

    /// The ground surface height, curbs included.
    #[inline]
    pub fn height(&self, x: f64, y: f64) -> f64 {
        self.base_height(x, y) + self.step(y)
    }

    fn on_driveway(&self, x: f64, y: f64) -> bool {
        let side = usize::from(y > 0.0);
        let list = &self.driveways[side];
        let i = list.partition_point(|&(_, end)| end < x);
        list.get(i).is_some_and(|&(start, _)| start <= x)
    }

    /// Whether a driveway on the side of `side` (−1: y < 0) overlaps [x0, x1].
    pub fn driveway_overlaps(&self, side: f64, x0: f64, x1: f64) -> bool {
        let list = &self.driveways[usize::from(side > 0.0)];
        let i = list.partition_point(|&(_, end)| end < x0);
        list.get(i).is_some_and(|&(start, _)| start <= x1)
    }

    /// The surface material at (x, y) (road paint, sidewalk, grass, driveway).
    pub fn material(&self, x: f64, y: f64) -> Material {
        let l = &self.layout;
        let ay = y.abs();
        if ay < l.curb() {
            if (0.07..0.19).contains(&ay) {
                return materials::PAINT_YELLOW;
            }
            if l.lanes_per_direction > 1 && (ay - l.lane_width).abs() < 0.06 && x.rem_euclid(12.0) < 3.0 {
                return materials::PAINT_WHITE;
            }
            if (ay - l.travel_edge()).abs() < 0.08 || (ay - l.bike_outer()).abs() < 0.05 {
                return materials::PAINT_WHITE;
            }
            return materials::ASPHALT;
        }
        if self.on_driveway(x, y) {
            return materials::CONCRETE;
        }
        if ay < l.strip_outer() {
            materials::GRASS
        } else if ay < l.sidewalk_outer() {
            materials::CONCRETE
        } else {
            materials::GRASS
        }
    }

    /// The unit normal of the surface at (x, y) away from the curb faces.
    pub fn normal(&self, x: f64, y: f64) -> [f64; 3] {
        let g = self.base_gradient(x, y);
        let n = (g[0] * g[0] + g[1] * g[1] + 1.0).sqrt();
        [-g[0] / n, -g[1] / n, 1.0 / n]
    }

    /// The first intersection of the ray o + t·d (d unit) with the ground for 0 < t < t_max:
    /// distance, unit normal and material.
    pub fn intersect(&self, o: &[f64; 3], d: &[f64; 3], t_max: f64) -> Option<(f64, [f64; 3], Material)> {
        let curb = self.layout.curb();
        // Split the ray where it crosses the curb lines; the surface is smooth in between.
        let mut cuts = [0.0, t_max, t_max, t_max];
        let mut n = 1;
        if d[1].abs() > 1e-12 {
            for yc in [-curb, curb] {
                let t = (yc - o[1]) / d[1];
                if t > 0.0 && t < t_max {
                    cuts[n] = t;
                    n += 1;
                }
            }
        }
        cuts[n] = t_max;
        cuts[1..n].sort_by(f64::total_cmp);
        for w in cuts[..=n].windows(2) {
            let (ta, tb) = (w[0], w[1]);
            if tb <= ta {
                continue;
            }
            let mid_y = o[1] + 0.5 * (ta + tb) * d[1];
            let level = self.step(mid_y);
            if ta > 0.0 {
                // Entering a raised piece: the ray may hit the curb face.
                let before = self.step(o[1] + (ta - 1e-9) * d[1]);
                if level > before {
                    let (x, y) = (o[0] + ta * d[0], o[1] + ta * d[1]);
                    let z = o[2] + ta * d[2];
                    if z < self.base_height(x, y) + level {
                        return Some((ta, [0.0, -d[1].signum(), 0.0], materials::CURB));
                    }
                }
            }
            if let Some(t) = self.march(o, d, ta, tb, level) {
                let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
                return Some((t, self.normal(x, y), self.material(x, y)));
            }
        }
        None
    }

    /// The first root of f(t) = z(t) − base(x(t), y(t)) − level in [ta, tb].
    fn march(&self, o: &[f64; 3], d: &[f64; 3], ta: f64, tb: f64, level: f64) -> Option<f64> {
        let f = |t: f64| o[2] + t * d[2] - self.base_height(o[0] + t * d[0], o[1] + t * d[1]) - level;
        // f = plane part (linear in t) − undulation (|·| ≤ U); no root where the plane part > U.
        let u = self.amp[0] + self.amp[1] + 1e-9;
        let m = d[2] - self.slope[0] * d[0] - self.slope[1] * d[1];
        let plane = |t: f64| {
            o[2] + t * d[2]
                - self.z0
                - self.slope[0] * (o[0] + t * d[0])
                - self.slope[1] * (o[1] + t * d[1])
                - level
        };
        let p0 = plane(ta);
        let mut t = ta;
        if p0 > u {
            if m >= 0.0 {
                return None;
            }
            t = ta + (p0 - u) / -m;
            if t >= tb {
                return None;
            }
        }
        // Lipschitz bound of f': no root within |f| / L of t.
        let lip = m.abs()
            + self.amp[0] * (self.wave[0][0] * d[0] + self.wave[0][1] * d[1]).abs()
            + self.amp[1] * (self.wave[1][0] * d[0] + self.wave[1][1] * d[1]).abs()
            + 1e-9;
        let mut ft = f(t);
        if ft <= 0.0 {
            return Some(t);
        }
        for _ in 0..200 {
            if ft < 1e-4 {
                return Some(t);
            }
            let step = (ft / lip).max(1e-3 + 2e-3 * t);
            let t_next = t + step;
            if t_next >= tb {
                let fb = f(tb);
                if fb > 0.0 {
                    return None;
                }
                return Some(bisect(&f, t, tb));
            }
            let f_next = f(t_next);
            if f_next <= 0.0 {
                return Some(bisect(&f, t, t_next));
            }
            t = t_next;
            ft = f_next;
        }
        None
    }
}

/// Bisection for a sign change f(a) > 0 ≥ f(b), to ~0.1 mm.
fn bisect(f: &impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    for _ in 0..40 {
        if b - a < 1e-4 {
            break;
        }
        let m = 0.5 * (a + b);
        if f(m) > 0.0 {
            a = m;
        } else {
            b = m;
        }
    }
    b
}

/// A street: its cross-section and ground, its length and the static structures along it.
#[derive(Debug, Clone)]
pub struct Street {
    pub index: usize,
    pub ground: Ground,
    /// The street runs from x = 0 to x = length (m); structures extend a little beyond.
    pub length: f64,
    /// Buildings, walls, hedges, poles, signs and trees (not annotated).
    pub statics: Vec<Primitive>,
}

impl Street {
    /// A random layout of a street (lanes) before its length is known.
    pub fn random_layout(rng: &mut impl Rng) -> StreetLayout {
        StreetLayout {
            lanes_per_direction: if rng.random_bool(0.35) { 2 } else { 1 },
            lane_width: 3.5,
            bike_lane_width: 1.5,
            parking_width: 2.4,
            curb_height: 0.15,
            strip_width: 1.5,
            sidewalk_width: 1.6,
        }
    }

    /// Generates the ground and the static structures of a street of this length.
    pub fn generate(index: usize, layout: StreetLayout, length: f64, rng: &mut impl Rng) -> Self {
        let mut ground = Ground::random(layout, rng);
        let mut statics = Vec::new();
        let (x_lo, x_hi) = (-60.0, length + 60.0);
        let walk = layout.sidewalk_outer();
        let curb = layout.curb();
        for (side_index, side) in [-1.0f64, 1.0].into_iter().enumerate() {
            // Lots: a driveway at the start of each, a house, sometimes a wall or hedge, yard trees.
            let mut driveways = Vec::new();
            let mut x = x_lo + rng.random_range(0.0..10.0);
            while x < x_hi {
                let lot = rng.random_range(14.0..24.0);
                let drive = (x + 0.5, x + 3.5);
                driveways.push(drive);
                if rng.random_bool(0.88) {
                    let bw = lot - rng.random_range(3.5..7.0);
                    let bd = rng.random_range(9.0..16.0);
                    let setback = rng.random_range(4.0..10.0);
                    let bh = rng.random_range(3.5..8.0);
                    let cx = x + 3.5 + 0.5 * bw;
                    let cy = side * (walk + setback + 0.5 * bd);
                    let g = ground.height(cx, cy);
                    let rho = rng.random_range(0.2..0.5);
                    statics.push(Primitive::new(
                        [cx, cy, g + 0.5 * bh - 0.3],
                        rng.random_range(-0.03..0.03),
                        Shape::Cuboid {
                            half: [0.5 * bw, 0.5 * bd, 0.5 * bh + 0.3],
                        },
                        Material::uniform(rho),
                        Hit::Static,
                    ));
                    let fence = rng.random_range(0.0..1.0);
                    // The fence's centre and half-length along the lot, behind the sidewalk.
                    let fx = [x + 4.0 + 0.5 * (lot - 4.5), 0.5 * (lot - 4.5)];
                    if fence < 0.3 {
                        let wh = rng.random_range(0.8..1.8);
                        let wall = Material::uniform(rng.random_range(0.15..0.4));
                        push_wall(
                            &mut statics,
                            &ground,
                            fx,
                            [side * (walk + 0.4), 0.1],
                            [wh, 0.1],
                            wall,
                        );
                    } else if fence < 0.5 {
                        let hh = rng.random_range(0.9..1.8);
                        let fy = [side * (walk + 0.9), 0.45];
                        push_wall(&mut statics, &ground, fx, fy, [hh, 0.1], materials::FOLIAGE);
                    }
                    if setback > 5.0 && rng.random_bool(0.5) {
                        let tx = x + rng.random_range(5.0..lot - 1.0);
                        let ty = side * (walk + rng.random_range(2.0..setback - 2.0));
                        push_tree(&mut statics, &ground, tx, ty, rng);
                    }
                }
                x += lot;
            }
            ground.driveways[side_index] = driveways;
            // Street lights and signs near the curb; trees in the planting strip between them.
            let mut poles: Vec<f64> = Vec::new();
            let mut x = x_lo + rng.random_range(0.0..40.0);
            while x < x_hi {
                let y = side * (curb + 0.45);
                if !ground.on_driveway(x, y) {
                    push_street_light(&mut statics, &ground, x, y, side, rng);
                    poles.push(x);
                }
                x += rng.random_range(35.0..50.0);
            }
            let mut x = x_lo + rng.random_range(0.0..30.0);
            while x < x_hi {
                let y = side * (curb + 0.3);
                if rng.random_bool(0.5)
                    && !ground.on_driveway(x, y)
                    && poles.iter().all(|p| (p - x).abs() > 2.0)
                {
                    push_sign(&mut statics, &ground, x, y, side);
                    poles.push(x);
                }
                x += rng.random_range(40.0..80.0);
            }
            let mut x = x_lo + rng.random_range(0.0..8.0);
            while x < x_hi {
                let y = side * (curb + 0.5 * layout.strip_width);
                let clear = poles.iter().all(|p| (p - x).abs() > 3.0)
                    && !ground.on_driveway(x - 0.6, y)
                    && !ground.on_driveway(x + 0.6, y);
                if clear && rng.random_bool(0.75) {
                    push_tree(&mut statics, &ground, x, y, rng);
                }
                x += rng.random_range(7.0..14.0);
            }
        }
        Self {
            index,
            ground,
            length,
            statics,
        }
    }
}

impl Street {
    /// `mlod synth --curb-walls P`: walls and hedges right behind the curb, as on narrow streets
    /// where a garden wall or a hedge lines the road and a parked car stands half a metre from
    /// it. Each stretch between two driveways on either side gets one with probability `share`:
    /// a wall (60 %: 0.2 m thick, 1.0–2.8 m high, reflectivity 0.15–0.45) or a hedge (0.6–1.0 m
    /// thick, 1.0–2.5 m high), starting 0.25–0.6 m behind the curb and ending within the planting
    /// strip (the sidewalk stays free; a street light or tree there stands in the wall), with the
    /// driveways left open.
    /// `rng` is a stream of its own, so the streets and actors are those without the walls: only
    /// what the LiDARs see changes.
    pub fn add_curb_walls(&mut self, share: f64, rng: &mut impl Rng) {
        if share <= 0.0 {
            return;
        }
        let curb = self.ground.layout.curb();
        for (side_index, side) in [-1.0f64, 1.0].into_iter().enumerate() {
            for pair in self.ground.driveways[side_index].windows(2) {
                let (x0, x1) = (pair[0].1 + 0.3, pair[1].0 - 0.3);
                if x1 - x0 < 2.0 || !rng.random_bool(share.min(1.0)) {
                    continue;
                }
                let hedge = rng.random_bool(0.4);
                let (half_width, material) = if hedge {
                    (0.5 * rng.random_range(0.6..1.0), materials::FOLIAGE)
                } else {
                    (0.1, Material::uniform(rng.random_range(0.15..0.45)))
                };
                let height = if hedge {
                    rng.random_range(1.0..2.5)
                } else {
                    rng.random_range(1.0..2.8)
                };
                // Within the planting strip, clear of the sidewalk's pedestrians.
                let room = self.ground.layout.strip_width - 2.0 * half_width - 0.05;
                let y = side * (curb + rng.random_range(0.25f64..0.6).min(room) + half_width);
                let x = [0.5 * (x0 + x1), 0.5 * (x1 - x0)];
                push_wall(
                    &mut self.statics,
                    &self.ground,
                    x,
                    [y, half_width],
                    [height, 0.2],
                    material,
                );
            }
        }
    }
}

/// A straight wall, fence or hedge along the street: `x` and `y` its centre and half-extent
/// along each axis, `height` above the ground at its centre (`[height, sink]`: it reaches `sink`
/// below that ground, so a slope shows no gap under it).
fn push_wall(
    out: &mut Vec<Primitive>,
    ground: &Ground,
    x: [f64; 2],
    y: [f64; 2],
    [height, sink]: [f64; 2],
    material: Material,
) {
    out.push(Primitive::new(
        [x[0], y[0], ground.height(x[0], y[0]) + 0.5 * height - sink],
        0.0,
        Shape::Cuboid {
            half: [x[1], y[1], 0.5 * height + sink],
        },
        material,
        Hit::Static,
    ));
}

/// A tree: trunk cylinder and an ellipsoidal crown whose bottom stays above 2.5 m (clear of
/// pedestrians and of vans parked beside it).
fn push_tree(out: &mut Vec<Primitive>, ground: &Ground, x: f64, y: f64, rng: &mut impl Rng) {
    let g = ground.height(x, y);
    let trunk_h = rng.random_range(2.8..4.0);
    let r = rng.random_range(0.12..0.25);
    out.push(Primitive::new(
        [x, y, g + 0.5 * trunk_h - 0.1],
        0.0,
        Shape::Cylinder {
            axis: Axis::Z,
            radius: r,
            half_len: 0.5 * trunk_h + 0.1,
        },
        materials::BARK,
        Hit::Static,
    ));
    let rc = rng.random_range(1.8..3.2);
    let rz = rng.random_range(1.6..2.8);
    out.push(Primitive::new(
        [x, y, g + trunk_h + rz - 0.3],
        rng.random_range(0.0..std::f64::consts::PI),
        Shape::Ellipsoid {
            radii: [rc, rc * rng.random_range(0.85..1.0), rz],
        },
        materials::FOLIAGE,
        Hit::Static,
    ));
}

fn push_street_light(
    out: &mut Vec<Primitive>,
    ground: &Ground,
    x: f64,
    y: f64,
    side: f64,
    rng: &mut impl Rng,
) {
    let g = ground.height(x, y);
    let h = rng.random_range(7.0..9.0);
    out.push(Primitive::new(
        [x, y, g + 0.5 * h - 0.1],
        0.0,
        Shape::Cylinder {
            axis: Axis::Z,
            radius: 0.1,
            half_len: 0.5 * h + 0.1,
        },
        materials::METAL,
        Hit::Static,
    ));
    // The arm reaches over the road; the lamp hangs at its end.
    out.push(Primitive::new(
        [x, y - side * 0.9, g + h - 0.1],
        0.0,
        Shape::Cuboid {
            half: [0.05, 0.9, 0.05],
        },
        materials::METAL,
        Hit::Static,
    ));
    out.push(Primitive::new(
        [x, y - side * 1.7, g + h - 0.25],
        0.0,
        Shape::Cuboid {
            half: [0.25, 0.15, 0.08],
        },
        materials::METAL,
        Hit::Static,
    ));
}

fn push_sign(out: &mut Vec<Primitive>, ground: &Ground, x: f64, y: f64, side: f64) {
    let g = ground.height(x, y);
    out.push(Primitive::new(
        [x, y, g + 1.2],
        0.0,
        Shape::Cylinder {
            axis: Axis::Z,
            radius: 0.035,
            half_len: 1.3,
        },
        materials::METAL,
        Hit::Static,
    ));
    // The plate faces the traffic on its side of the street.
    out.push(Primitive::new(
        [x - side * 0.05, y, g + 2.25],
        0.0,
        Shape::Cuboid {
            half: [0.015, 0.3, 0.3],
        },
        materials::RETROREFLECTOR,
        Hit::Static,
    ));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::noise::layout_rng;

    fn street() -> Street {
        let mut rng = layout_rng(&[9]);
        let layout = Street::random_layout(&mut rng);
        Street::generate(0, layout, 300.0, &mut rng)
    }

    #[test]
    fn downward_rays_land_on_the_height_field() {
        let s = street();
        let g = &s.ground;
        for (i, &(x, y)) in [(10.0, -2.0), (50.0, 1.0), (120.0, -3.0), (200.0, 5.0)]
            .iter()
            .enumerate()
        {
            let o = [x - 20.0, y + 0.5 * i as f64, g.height(x, y) + 1.8];
            let (dx, dy, dz) = (x - o[0], y - o[1], g.height(x, y) - o[2]);
            let n = (dx * dx + dy * dy + dz * dz).sqrt();
            let d = [dx / n, dy / n, dz / n];
            let (t, normal, _) = g.intersect(&o, &d, 200.0).unwrap();
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            assert!((p[2] - g.height(p[0], p[1])).abs() < 2e-3, "{p:?}");
            assert!(normal[2] > 0.99);
        }
        // Upward rays never hit.
        assert!(g
            .intersect(&[0.0, 0.0, g.height(0.0, 0.0) + 1.8], &[0.0, 0.6, 0.8], 200.0)
            .is_none());
    }

    #[test]
    fn low_rays_toward_the_sidewalk_hit_the_curb_face() {
        let s = street();
        let g = &s.ground;
        let curb = g.layout.curb();
        let x = 100.0;
        let z = g.base_height(x, curb) + 0.07;
        let (t, n, m) = g.intersect(&[x, 0.0, z], &[0.0, 1.0, 0.0], 100.0).unwrap();
        assert!((t - curb).abs() < 1e-9);
        assert_eq!((n, m), ([0.0, -1.0, 0.0], materials::CURB));
    }

    #[test]
    fn lane_paint_and_sidewalks_have_their_materials() {
        let s = street();
        let g = &s.ground;
        assert_eq!(g.material(5.0, 0.12), materials::PAINT_YELLOW);
        assert_eq!(g.material(5.0, -g.layout.travel_edge()), materials::PAINT_WHITE);
        assert_eq!(g.material(5.0, -1.7), materials::ASPHALT);
        let walk = 0.5 * (g.layout.strip_outer() + g.layout.sidewalk_outer());
        let m = g.material(5.0, walk);
        assert!(m == materials::CONCRETE);
        assert!(!s.statics.is_empty());
    }
}
