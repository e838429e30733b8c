//! The ray caster: one key frame of the three LiDARs, as Lyft `.bin` point clouds.
//!
//! For each LiDAR, 40 channels × 1800 azimuths rays leave the sensor origin. A ray that enters the
//! ego body (boxes in the ego frame, [`super::rig::EGO_BODY`]) returns nothing. Otherwise it is
//! cast against the ground height field (exact curb faces, marched smooth pieces, see
//! [`super::street::Ground`]) and, up to that distance, against every primitive of the scene
//! through a uniform 2D grid (4 m cells in the xy plane, a DDA walk that stops at the first cell
//! whose exit lies beyond the nearest hit): the nearest hit wins, so occlusion is exact.
//!
//! A hit becomes a point if it survives a 1 % random drop-out and a detection test
//! ρ·max(cos θ, 0.05)·(R_ref/r)² ≥ u (u uniform in [0.7, 1.3)): dark, grazing or distant surfaces
//! fade out as on a real sensor (asphalt to ~40 m, car paint beyond 100 m). Its range gets
//! Gaussian noise (σ 2 cm) along the ray; its intensity is 255·ρ·(0.35 + 0.65 cos θ)·1.4 plus a
//! little noise, clamped to 0–255 (or a constant, like the real files' 100). All randomness is a
//! hash of (seed, scene, sample, LiDAR, channel, azimuth), and the columns are cast in parallel
//! with rayon and gathered in order, so the output is byte-identical for a seed.
//! Not modelled: multiple returns, beam divergence and partial hits, rolling-shutter motion
//! distortion within a sweep, rain/fog, sensor saturation and crosstalk. Vehicle side glass is
//! opaque and dark unless [`LidarModel::glass_pass`] lets beams through it (`--glass see-through`).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::noise::{hash_key, RayStream};
use super::rig::{ego_body_blocks, ego_body_blocks_below_roof, LidarModel, LIDAR_COUNT};
use super::scene::{SceneWorld, Town};
pub use super::shapes::Hit;
use super::shapes::{Material, Primitive};

/// One LiDAR's sweep: points in its own sensor frame, exactly as written to the `.bin`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LidarScan {
    /// x, y, z (m, sensor frame), intensity (0–255), ring (channel, 1 = top).
    pub points: Vec<[f32; 5]>,
    /// What each point hit, in the order of `points`.
    pub hits: Vec<Hit>,
    /// Rays that hit the ego car's body.
    pub blocked_by_ego: usize,
}

impl LidarScan {
    /// The point cloud as the bytes of a Lyft `.bin`: float32 little-endian × 5 per point.
    pub fn to_bin_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.points.len() * 20);
        for p in &self.points {
            for v in p {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }
}

/// The three sweeps of one key frame, in [`LYFT_MOUNTS`] order (TOP, FRONT_LEFT, FRONT_RIGHT).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SampleScan {
    pub lidars: Vec<LidarScan>,
}

impl SampleScan {
    /// Points that hit each actor, over all LiDARs (Lyft's `num_lidar_pts`).
    pub fn actor_point_counts(&self, actors: usize) -> Vec<u32> {
        let mut counts = vec![0u32; actors];
        for hit in self.lidars.iter().flat_map(|l| l.hits.iter()) {
            if let Hit::Actor(i) = *hit {
                if let Some(c) = counts.get_mut(i as usize) {
                    *c += 1;
                }
            }
        }
        counts
    }
}

/// A uniform grid over the xy plane; each cell lists the primitives whose bounds overlap it.
struct Grid {
    x0: f64,
    y0: f64,
    cell: f64,
    n: usize,
    z: [f64; 2],
    offsets: Vec<u32>,
    items: Vec<u32>,
    prims: Vec<Primitive>,
}

impl Grid {
    fn build(all: Vec<Primitive>, center: [f64; 2], half: f64, cell: f64) -> Self {
        let n = ((2.0 * half / cell).ceil() as usize).max(1);
        let (x0, y0) = (center[0] - half, center[1] - half);
        let extent = n as f64 * cell;
        let cell_of = |v: f64, o: f64| (((v - o) / cell).floor().max(0.0) as usize).min(n - 1);
        let mut prims = Vec::with_capacity(all.len());
        let mut ranges = Vec::with_capacity(all.len());
        let mut z = [f64::INFINITY, f64::NEG_INFINITY];
        for p in all {
            let (lo, hi) = p.world_bounds();
            if hi[0] < x0 || hi[1] < y0 || lo[0] > x0 + extent || lo[1] > y0 + extent {
                continue;
            }
            z = [z[0].min(lo[2]), z[1].max(hi[2])];
            ranges.push([
                cell_of(lo[0], x0),
                cell_of(hi[0], x0),
                cell_of(lo[1], y0),
                cell_of(hi[1], y0),
            ]);
            prims.push(p);
        }
        let mut counts = vec![0u32; n * n + 1];
        for r in &ranges {
            for iy in r[2]..=r[3] {
                for ix in r[0]..=r[1] {
                    counts[iy * n + ix + 1] += 1;
                }
            }
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let mut fill = counts.clone();
        let mut items = vec![0u32; counts[n * n] as usize];
        for (pi, r) in ranges.iter().enumerate() {
            for iy in r[2]..=r[3] {
                for ix in r[0]..=r[1] {
                    let c = iy * n + ix;
                    items[fill[c] as usize] = pi as u32;
                    fill[c] += 1;
                }
            }
        }
        Self {
            x0,
            y0,
            cell,
            n,
            z,
            offsets: counts,
            items,
            prims,
        }
    }

    /// The nearest primitive hit by o + t·d with 0 < t < t_max: (t, primitive index, normal).
    fn cast(&self, o: &[f64; 3], d: &[f64; 3], t_max: f64) -> Option<(f64, usize, [f64; 3])> {
        if self.prims.is_empty() {
            return None;
        }
        let extent = self.n as f64 * self.cell;
        let lo = [self.x0, self.y0, self.z[0]];
        let hi = [self.x0 + extent, self.y0 + extent, self.z[1]];
        let (mut t0, mut t1) = (0.0f64, t_max);
        for k in 0..3 {
            if d[k].abs() < 1e-12 {
                if o[k] < lo[k] || o[k] > hi[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
            if t0 > t1 {
                return None;
            }
        }
        let n = self.n as i64;
        let start = |k: usize, origin: f64| {
            let v = o[k] + t0 * d[k];
            (((v - origin) / self.cell).floor() as i64).clamp(0, n - 1)
        };
        let mut ix = start(0, self.x0);
        let mut iy = start(1, self.y0);
        let axis = |k: usize, i: i64, origin: f64| -> (i64, f64, f64) {
            if d[k].abs() < 1e-12 {
                return (0, f64::INFINITY, f64::INFINITY);
            }
            let step = if d[k] > 0.0 { 1 } else { -1 };
            let boundary = origin + (i + i64::from(d[k] > 0.0)) as f64 * self.cell;
            (step, (boundary - o[k]) / d[k], self.cell / d[k].abs())
        };
        let (sx, mut tx, dtx) = axis(0, ix, self.x0);
        let (sy, mut ty, dty) = axis(1, iy, self.y0);
        let mut best_t = t1;
        let mut best: Option<(usize, [f64; 3])> = None;
        loop {
            let c = (iy * n + ix) as usize;
            let (a, b) = (self.offsets[c] as usize, self.offsets[c + 1] as usize);
            for &pi in &self.items[a..b] {
                if let Some((t, normal)) = self.prims[pi as usize].intersect(o, d, 1e-6, best_t) {
                    best_t = t;
                    best = Some((pi as usize, normal));
                }
            }
            let t_exit = tx.min(ty);
            if (best.is_some() && best_t <= t_exit) || t_exit > t1 {
                break;
            }
            if tx < ty {
                ix += sx;
                tx += dtx;
            } else {
                iy += sy;
                ty += dty;
            }
            if ix < 0 || iy < 0 || ix >= n || iy >= n {
                break;
            }
        }
        best.map(|(pi, normal)| (best_t, pi, normal))
    }
}

/// A LiDAR's pose at one key frame: R_world←sensor and its origin in the street frame,
/// R_ego←sensor and its origin in the ego frame.
struct SensorFrame {
    r_world: Matrix3<f64>,
    o_world: [f64; 3],
    r_ego: Matrix3<f64>,
    o_ego: [f64; 3],
}

/// The returns of one azimuth column (point and what it hit) and its rays blocked by the ego.
type Column = (Vec<([f32; 5], Hit)>, usize);

fn to_array(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// The nearest hit after see-through glass: while the hit is a vehicle's side glass and the
/// beam passes it (probability `model.glass_pass`, drawn from the ray's own glass stream, keyed by the ray's
/// key words `ray` and [`GLASS_STREAM`], so that the ray's other draws are unchanged), the cast
/// goes on from just behind the glass up to the `ground` hit (else the maximum range). A
/// primitive is only entered from outside, so the beam leaves the cabin unseen and returns from
/// what lies behind it (the lower body's top, another object) or, when it meets nothing else,
/// from the ground behind the car. Unless `model.glass_ground` is set such a beam returns
/// nothing: the first see-through data (`--glass see-through-no-ground`, which the v5-glass
/// candidate was trained on) had that bug, and it is kept so that they reproduce. At most four
/// panes are crossed.
fn through_glass(
    grid: &Grid,
    o: &[f64; 3],
    d: &[f64; 3],
    mut best: Option<(f64, [f64; 3], Material, Hit)>,
    ground: Option<(f64, [f64; 3], Material, Hit)>,
    model: &LidarModel,
    ray: &[u64; 6],
) -> Option<(f64, [f64; 3], Material, Hit)> {
    let limit = ground.map_or(model.max_range_m, |g| g.0);
    let behind = if model.glass_ground { ground } else { None };
    let mut stream: Option<RayStream> = None;
    for _ in 0..4 {
        let Some((t, normal, material, Hit::Actor(_))) = best else {
            return best;
        };
        if material.reflectivity(normal[2]) != super::shapes::materials::GLASS {
            return best;
        }
        let rs = stream.get_or_insert_with(|| {
            let [a, b, c, l, r, j] = *ray;
            RayStream::new(hash_key(&[a, b, c, l, r, j, GLASS_STREAM]))
        });
        if rs.uniform() >= model.glass_pass {
            return best;
        }
        let t0 = t + 1e-3;
        let o2 = [o[0] + t0 * d[0], o[1] + t0 * d[1], o[2] + t0 * d[2]];
        best = grid
            .cast(&o2, d, limit - t0)
            .map(|(tp, pi, n)| {
                let p = &grid.prims[pi];
                (t0 + tp, n, p.material, p.owner)
            })
            .or(behind);
    }
    best
}

/// Key word of the see-through-glass draws (kept apart from a ray's other draws).
const GLASS_STREAM: u64 = 0x6C61_7373;

/// Casts every ray of the three LiDARs at key frame `k` of a scene.
pub fn scan_sample(town: &Town, scene: &SceneWorld, k: usize, model: &LidarModel, seed: u64) -> SampleScan {
    let street = town.street_of(scene);
    let t = scene.times_s.get(k).copied().unwrap_or(0.0);
    let ego = town.ego_pose(scene, k);
    let ego_xy = [ego.translation.x, ego.translation.y];
    let reach = model.max_range_m + 5.0;

    let mut prims: Vec<Primitive> = street.statics.clone();
    for (i, actor) in scene.actors.iter().enumerate() {
        let b = actor.box_at(street, t);
        let r = 0.5 * b.size_lwh[0].hypot(b.size_lwh[1]);
        if (b.center[0] - ego_xy[0]).hypot(b.center[1] - ego_xy[1]) <= reach + r {
            actor.primitives(street, t, i as u32, &mut prims);
        }
    }
    let grid = Grid::build(prims, ego_xy, reach, 4.0);

    // Per LiDAR: its beams (sin, cos of the elevations) and azimuth steps; the roof LiDAR is the
    // scene's preset when sensor randomisation drew one.
    let sin_cos = |e: &[f64]| -> Vec<(f64, f64)> { e.iter().map(|e| e.to_radians().sin_cos()).collect() };
    let default_beams = sin_cos(&model.elevations_deg);
    let lidar_beams: Vec<(Vec<(f64, f64)>, usize)> = (0..LIDAR_COUNT)
        .map(|l| match scene.roof.preset {
            Some(p) if l == 0 => (sin_cos(&p.elevations_deg()), p.azimuth_steps()),
            _ => (default_beams.clone(), model.azimuth_steps.max(1)),
        })
        .collect();
    // Column idx of LiDAR l starts at offsets[l].
    let mut offsets = [0usize; LIDAR_COUNT + 1];
    for l in 0..LIDAR_COUNT {
        offsets[l + 1] = offsets[l] + lidar_beams[l].1;
    }
    let frames: Vec<SensorFrame> = (0..LIDAR_COUNT)
        .map(|l| town.mount_of(scene, l))
        .map(|m| {
            let ego_from_sensor = m.pose();
            let world_from_sensor = ego * ego_from_sensor;
            SensorFrame {
                r_world: world_from_sensor.rotation.to_rotation_matrix().into_inner(),
                o_world: to_array(&world_from_sensor.translation.vector),
                r_ego: ego_from_sensor.rotation.to_rotation_matrix().into_inner(),
                o_ego: to_array(&ego_from_sensor.translation.vector),
            }
        })
        .collect();
    let ground = &street.ground;
    let key_base = [seed, scene.index as u64, k as u64];

    let columns: Vec<Column> = (0..offsets[LIDAR_COUNT])
        .into_par_iter()
        .map(|idx| {
            let l = offsets.partition_point(|&o| o <= idx) - 1;
            let j = idx - offsets[l];
            let (beams, steps) = (&lidar_beams[l].0, lidar_beams[l].1);
            let SensorFrame {
                r_world: r_ws,
                o_world: o_w,
                r_ego: r_es,
                o_ego: o_e,
            } = &frames[l];
            let (sa, ca) = (std::f64::consts::TAU * j as f64 / steps as f64).sin_cos();
            let mut out = Vec::with_capacity(beams.len());
            let mut blocked = 0;
            for (ring, &(se, ce)) in beams.iter().enumerate() {
                let ds = Vector3::new(ce * ca, ce * sa, se);
                let de = to_array(&(r_es * ds));
                let blocks = if l == 0 && scene.roof.preset.is_some() {
                    ego_body_blocks_below_roof(o_e, &de)
                } else {
                    ego_body_blocks(o_e, &de)
                };
                if blocks {
                    blocked += 1;
                    continue;
                }
                let dw = to_array(&(r_ws * ds));
                let ground_hit = ground
                    .intersect(o_w, &dw, model.max_range_m)
                    .map(|(tg, n, m)| (tg, n, m, Hit::Ground));
                let limit = ground_hit.map_or(model.max_range_m, |g| g.0);
                let mut best = ground_hit;
                if let Some((tp, pi, n)) = grid.cast(o_w, &dw, limit) {
                    let p = &grid.prims[pi];
                    best = Some((tp, n, p.material, p.owner));
                }
                // Every random draw of this ray is keyed by these words.
                let ray = [
                    key_base[0],
                    key_base[1],
                    key_base[2],
                    l as u64,
                    ring as u64,
                    j as u64,
                ];
                if model.glass_pass > 0.0 {
                    best = through_glass(&grid, o_w, &dw, best, ground_hit, model, &ray);
                }
                let Some((range, normal, material, hit)) = best else {
                    continue;
                };
                if range < model.min_range_m {
                    continue;
                }
                let mut rs = RayStream::new(hash_key(&ray));
                if rs.uniform() < model.dropout {
                    continue;
                }
                let cos = (normal[0] * dw[0] + normal[1] * dw[1] + normal[2] * dw[2]).abs();
                let rho = f64::from(material.reflectivity(normal[2]));
                let snr = rho * cos.max(0.05) * (model.reference_range_m / range).powi(2);
                if snr < 0.7 + 0.6 * rs.uniform() {
                    continue;
                }
                let measured = range + model.range_noise_m * rs.gaussian();
                let intensity = match model.constant_intensity {
                    Some(v) => v,
                    None => {
                        let v = 255.0 * rho * (0.35 + 0.65 * cos) * 1.4 + 2.0 * rs.gaussian();
                        v.clamp(0.0, 255.0).round() as f32
                    }
                };
                let p = ds * measured;
                out.push((
                    [p.x as f32, p.y as f32, p.z as f32, intensity, (ring + 1) as f32],
                    hit,
                ));
            }
            (out, blocked)
        })
        .collect();

    let mut lidars: Vec<LidarScan> = (0..LIDAR_COUNT).map(|_| LidarScan::default()).collect();
    for (idx, (points, blocked)) in columns.into_iter().enumerate() {
        let scan = &mut lidars[offsets.partition_point(|&o| o <= idx) - 1];
        scan.blocked_by_ego += blocked;
        for (p, h) in points {
            scan.points.push(p);
            scan.hits.push(h);
        }
    }
    SampleScan { lidars }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::shapes::{materials, Shape};

    /// A glass pane (a car's side glass: steep face of reflectivity GLASS) 10 m along +x and,
    /// with `wall`, a painted wall 20 m along +x, both owned by actors; a ground hit at 30 m;
    /// and where the beams along +x end (`None`: no return).
    fn pane_and_wall(pass: f64, rays: usize, wall: bool, glass_ground: bool) -> Vec<Option<(f64, Hit)>> {
        let cuboid = |x: f64, material, owner| {
            Primitive::new(
                [x, 0.0, 0.0],
                0.0,
                Shape::Cuboid {
                    half: [0.5, 2.0, 2.0],
                },
                material,
                Hit::Actor(owner),
            )
        };
        let mut prims = vec![cuboid(10.0, Material::two_tone(0.4, materials::GLASS), 0)];
        if wall {
            prims.push(cuboid(20.0, Material::uniform(0.4), 1));
        }
        let grid = Grid::build(prims, [10.0, 0.0], 16.0, 4.0);
        let (o, d) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        let ground = Some((30.0, [0.0, 0.0, 1.0], Material::uniform(0.2), Hit::Ground));
        let model = LidarModel {
            glass_pass: pass,
            glass_ground,
            ..LidarModel::default()
        };
        (0..rays)
            .map(|j| {
                let first = grid
                    .cast(&o, &d, 30.0)
                    .map(|(t, pi, n)| (t, n, grid.prims[pi].material, grid.prims[pi].owner));
                through_glass(&grid, &o, &d, first, ground, &model, &[7, 0, 0, 0, 0, j as u64])
                    .map(|(t, _, _, h)| (t, h))
            })
            .collect()
    }

    #[test]
    fn see_through_glass_passes_the_drawn_share_of_beams_and_reproduces() {
        let opaque = pane_and_wall(0.0, 200, true, true);
        assert!(opaque.iter().all(|&r| r == Some((9.5, Hit::Actor(0)))));
        let clear = pane_and_wall(1.0, 200, true, true);
        assert!(clear
            .iter()
            .all(|r| matches!(r, Some((t, Hit::Actor(1))) if (t - 19.5).abs() < 1e-6)));
        let half = pane_and_wall(0.5, 2000, true, true);
        let passed = half
            .iter()
            .filter(|r| matches!(r, Some((_, Hit::Actor(1)))))
            .count();
        assert!((850..1150).contains(&passed), "{passed} of 2000 passed at 0.5");
        assert_eq!(half, pane_and_wall(0.5, 2000, true, true));
    }

    #[test]
    fn a_beam_through_the_glass_returns_the_ground_behind_unless_the_old_data_are_asked_for() {
        let fixed = pane_and_wall(1.0, 50, false, true);
        assert!(fixed.iter().all(|&r| r == Some((30.0, Hit::Ground))));
        let old = pane_and_wall(1.0, 50, false, false);
        assert!(old.iter().all(Option::is_none));
        // The same draws pass in both: only what a passing beam returns differs.
        let pass = |v: &[Option<(f64, Hit)>]| {
            v.iter()
                .map(|r| r.map(|x| x.1) == Some(Hit::Actor(0)))
                .collect::<Vec<_>>()
        };
        assert_eq!(
            pass(&pane_and_wall(0.5, 500, false, true)),
            pass(&pane_and_wall(0.5, 500, false, false))
        );
    }
}
