//! Scenes: a town of parallel streets, the ego car's drive along one of them, and the actors
//! (parked and moving vehicles, cyclists, pedestrians, dogs) that the annotations describe.
//!
//! The town has up to four parallel streets, 120 m apart, at one heading drawn from the seed;
//! scene i drives street i mod 4, so scenes on one street share its houses, trees and ground but
//! not its cars. The ego keeps to a lane at 4–12 m/s with a small acceleration and a gentle lateral
//! sway; its height, pitch and roll follow the ground under its wheels. Key frames are 0.2 s apart
//! (Lyft's 5 Hz) with a few milliseconds of jitter. Vehicles in a lane share one speed (the ego's
//! lane moves with the ego), so they never collide; parked cars line the parking lanes, leaving
//! driveways free; cyclists ride the bike lanes and pedestrians walk or stand on the sidewalks,
//! placed by rejection so that no two boxes overlap at any key frame. Objects are placed wherever
//! they can come within the annotation range (80 m) of the ego during the scene.
//! Not modelled: turns, lane changes, intersections, traffic lights, interactions between actors.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::actors::{self, ActorShape, Category};
use super::noise::layout_rng;
use super::rig::{LidarMount, LYFT_MOUNTS};
use super::shapes::{Hit, Primitive};
use super::street::{Street, StreetLayout};
use super::SynthConfig;
use crate::geometry::{rpy_to_matrix, Box3d, Pose};

/// Seconds between key frames (Lyft samples at 5 Hz).
pub const SAMPLE_PERIOD_S: f64 = 0.2;
/// The most streets a town has.
pub const MAX_STREETS: usize = 4;
/// Distance between parallel streets (m).
const STREET_SPACING: f64 = 120.0;
/// Road before the ego's start and after its end (m): covers the LiDAR range.
const STREET_MARGIN: f64 = 150.0;
/// Half-width (m) of the strip of each street drawn on the map raster.
pub const MAP_HALF_WIDTH: f64 = 40.0;
/// How far (m) the map raster reaches beyond the ego's drive.
const MAP_REACH: f64 = 100.0;
/// Margin (m) between the map raster's edge and the nearest road.
const MAP_MARGIN: f64 = 10.0;
/// Map raster resolution (m per pixel): the devkit's native 0.1 m.
pub const MAP_RESOLUTION: f64 = 0.1;
/// Offset between GPS time (file names) and Unix time (tables): 1980-01-06 in Unix seconds.
pub const GPS_EPOCH_UNIX_S: u64 = 315_964_800;
/// The wheelbase and track of the ego car (m), for pitch and roll from the ground.
const WHEELBASE: f64 = 2.9;
const TRACK: f64 = 1.6;

const TAG_TOWN: u64 = 0x746f_776e;
const TAG_STREET: u64 = 0x7374_7265;
const TAG_SCENE: u64 = 0x7363_656e;
const TAG_CURB_WALLS: u64 = 0x6375_7262;

/// A state of an actor in the real Lyft `attribute.json`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Attribute {
    Parked,
    DrivingStraightForward,
    Stopped,
    Walking,
    Standing,
}

impl Attribute {
    /// The token of this attribute in the real Lyft `attribute.json`.
    pub fn token(self) -> &'static str {
        match self {
            Attribute::Parked => "5466ded30df08d7d825412ac907017d6ae00ff19051c63666de3dcc4a535c8cc",
            Attribute::DrivingStraightForward => {
                "7fc1ca3d36808cd1858e9c01ad4e7630ff3ca9e720065034abd244122646acc8"
            }
            Attribute::Stopped => "1ba8c9a8bda54423fa710b0af1441d849ecca8ed7b7f9393ba1794afe4aa6aa2",
            Attribute::Walking => "29177d5bec11b5063bd3066d583a9391891546e8d54655e804f7366e5fc6254d",
            Attribute::Standing => "8b08df37edc70b7327d54b3fbf9e7e5894e1a31a93fe772102ff7598e35d0f91",
        }
    }
}

/// Planar motion along a street: x = x0 + dir·(v0·t + a·t²/2), y = y0 + a sway.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    pub x0: f64,
    pub y0: f64,
    /// +1: heading +x; −1: heading −x.
    pub dir: f64,
    pub v0: f64,
    pub accel: f64,
    pub sway_amp: f64,
    pub sway_omega: f64,
    pub sway_phase: f64,
    /// Added to the heading (parking angle, a standing pedestrian's facing).
    pub yaw_offset: f64,
}

impl Motion {
    fn fixed(x: f64, y: f64, dir: f64, yaw_offset: f64) -> Self {
        Self {
            x0: x,
            y0: y,
            dir,
            v0: 0.0,
            accel: 0.0,
            sway_amp: 0.0,
            sway_omega: 0.0,
            sway_phase: 0.0,
            yaw_offset,
        }
    }

    fn driving(x: f64, y: f64, dir: f64, v0: f64, accel: f64) -> Self {
        Self {
            v0,
            accel,
            ..Self::fixed(x, y, dir, 0.0)
        }
    }

    /// Position and heading (x, y, yaw) at time t (s).
    pub fn at(&self, t: f64) -> [f64; 3] {
        let s = self.v0 * t + 0.5 * self.accel * t * t;
        let x = self.x0 + self.dir * s;
        let y = self.y0 + self.sway_amp * (self.sway_omega * t + self.sway_phase).sin();
        let vx = self.dir * (self.v0 + self.accel * t);
        let vy = self.sway_amp * self.sway_omega * (self.sway_omega * t + self.sway_phase).cos();
        let base = if self.dir > 0.0 { 0.0 } else { std::f64::consts::PI };
        let yaw = if vx.abs() > 0.05 { vy.atan2(vx) } else { base };
        [x, y, crate::geometry::wrap_angle(yaw + self.yaw_offset)]
    }
}

/// An annotated object.
#[derive(Debug, Clone, PartialEq)]
pub struct Actor {
    pub category: Category,
    pub shape: ActorShape,
    pub motion: Motion,
    pub attribute: Attribute,
}

impl Actor {
    /// The annotation box in the street frame at time t: the shape's bottom rests on the ground
    /// under the box centre.
    pub fn box_at(&self, street: &Street, t: f64) -> Box3d {
        let [x, y, yaw] = self.motion.at(t);
        let h = self.shape.size_lwh[2];
        Box3d::new(
            [x, y, street.ground.height(x, y) + 0.5 * h],
            self.shape.size_lwh,
            yaw,
        )
    }

    /// Appends the actor's parts at time t as world primitives owned by `Hit::Actor(id)`.
    pub fn primitives(&self, street: &Street, t: f64, id: u32, out: &mut Vec<Primitive>) {
        let b = self.box_at(street, t);
        let (s, c) = b.yaw.sin_cos();
        for p in &self.shape.parts {
            let o = p.offset;
            let center = [
                b.center[0] + c * o[0] - s * o[1],
                b.center[1] + s * o[0] + c * o[1],
                b.center[2] + o[2],
            ];
            out.push(Primitive::new(center, b.yaw, p.shape, p.material, Hit::Actor(id)));
        }
    }
}

/// One scene: a drive of the ego along a street and the actors around it.
#[derive(Debug, Clone)]
pub struct SceneWorld {
    pub index: usize,
    /// Index into [`Town::streets`].
    pub street: usize,
    pub ego: Motion,
    pub actors: Vec<Actor>,
    /// Key-frame times in GPS nanoseconds (the numbers in the .bin file names).
    pub timestamps_ns: Vec<u64>,
    /// Key-frame times in seconds since the first.
    pub times_s: Vec<f64>,
    /// The roof LiDAR of this scene (sensor randomisation).
    pub roof: super::sensors::RoofSensor,
}

impl SceneWorld {
    pub fn len(&self) -> usize {
        self.times_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.times_s.is_empty()
    }
}

/// The map raster's extent: pixel (0, 0) is the top-left corner, global (0, 0) the bottom-left
/// corner (the devkit's `MapMask` convention), at [`MAP_RESOLUTION`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapFrame {
    pub width_px: u32,
    pub height_px: u32,
}

/// Everything a dataset is generated from.
#[derive(Debug, Clone)]
pub struct Town {
    pub streets: Vec<Street>,
    /// T_global←street for each street.
    pub street_poses: Vec<Pose>,
    pub scenes: Vec<SceneWorld>,
    pub map: MapFrame,
    /// The x range of each street drawn on the map.
    pub map_x_range: Vec<(f64, f64)>,
}

struct Plan {
    rng: ChaCha8Rng,
    street: usize,
    dir: f64,
    lane: u32,
    v0: f64,
    accel: f64,
    sway: (f64, f64, f64),
    timestamps_ns: Vec<u64>,
    times_s: Vec<f64>,
    travel: f64,
}

impl Town {
    /// Generates the town, its streets and every scene of a configuration.
    pub fn generate(cfg: &SynthConfig) -> Town {
        let seed = cfg.seed;
        let n_streets = cfg.scenes.clamp(1, MAX_STREETS);
        let mut street_rngs: Vec<ChaCha8Rng> = (0..n_streets)
            .map(|s| layout_rng(&[seed, TAG_STREET, s as u64]))
            .collect();
        let layouts: Vec<StreetLayout> = street_rngs.iter_mut().map(Street::random_layout).collect();
        let mut town_rng = layout_rng(&[seed, TAG_TOWN]);
        let heading = town_rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        // Spring 2019, like the real data: GPS ns of 2019-04-20 plus up to 30 days.
        let day_ns: u64 = 86_400_000_000_000;
        let t0_ns = 1_239_753_600_000_000_000 + town_rng.random_range(0..30 * day_ns);

        // Phase 1: each scene's drive, which fixes how long the streets must be.
        let mut scene_start = t0_ns;
        let mut plans: Vec<Plan> = (0..cfg.scenes)
            .map(|i| {
                let mut rng = layout_rng(&[seed, TAG_SCENE, i as u64]);
                let street = i % n_streets;
                let layout = &layouts[street];
                let n = cfg.samples_per_scene;
                let mut timestamps_ns = Vec::with_capacity(n);
                let start = scene_start + rng.random_range(0..1_000_000_000);
                for k in 0..n {
                    let jitter: i64 = rng.random_range(-3_000_000..3_000_000);
                    let nominal = start + k as u64 * 200_000_000;
                    timestamps_ns.push(if k == 0 {
                        nominal
                    } else {
                        nominal.saturating_add_signed(jitter)
                    });
                }
                let last = timestamps_ns.last().copied().unwrap_or(start);
                scene_start = last + 60_000_000_000 + rng.random_range(0..600_000_000_000);
                let times_s: Vec<f64> = timestamps_ns.iter().map(|&t| (t - start) as f64 * 1e-9).collect();
                let duration = times_s.last().copied().unwrap_or(0.0);
                let dir = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let lane = rng.random_range(0..layout.lanes_per_direction);
                let v0 = rng.random_range(4.0..12.0);
                let mut accel: f64 = rng.random_range(-0.5..0.5);
                if duration > 0.0 {
                    // Keep the speed between 2 and 14 m/s (a residential street).
                    accel = accel.clamp((2.0 - v0) / duration, (14.0 - v0) / duration);
                }
                let sway = (
                    rng.random_range(0.0..0.2),
                    std::f64::consts::TAU / rng.random_range(6.0..12.0),
                    rng.random_range(0.0..std::f64::consts::TAU),
                );
                let travel = v0 * duration + 0.5 * accel * duration * duration;
                Plan {
                    rng,
                    street,
                    dir,
                    lane,
                    v0,
                    accel,
                    sway,
                    timestamps_ns,
                    times_s,
                    travel,
                }
            })
            .collect();

        // Phase 2: the streets.
        let lengths: Vec<f64> = (0..n_streets)
            .map(|s| {
                let travel = plans
                    .iter()
                    .filter(|p| p.street == s)
                    .map(|p| p.travel)
                    .fold(0.0, f64::max);
                travel + 2.0 * STREET_MARGIN
            })
            .collect();
        let streets: Vec<Street> = street_rngs
            .iter_mut()
            .enumerate()
            .map(|(s, rng)| {
                let mut street = Street::generate(s, layouts[s], lengths[s], rng);
                let mut walls_rng = layout_rng(&[seed, TAG_CURB_WALLS, s as u64]);
                street.add_curb_walls(cfg.curb_walls, &mut walls_rng);
                street
            })
            .collect();

        // Phase 3: where each scene drives, and its actors.
        let scenes: Vec<SceneWorld> = plans
            .iter_mut()
            .enumerate()
            .map(|(i, p)| {
                let street = &streets[p.street];
                let length = street.length;
                let slack = (length - 2.0 * STREET_MARGIN - p.travel).max(0.0);
                let along = STREET_MARGIN + p.rng.random_range(0.0..=slack);
                let x0 = if p.dir > 0.0 { along } else { length - along };
                let y0 = street.ground.layout.lane_center(p.dir, p.lane);
                let ego = Motion {
                    sway_amp: p.sway.0,
                    sway_omega: p.sway.1,
                    sway_phase: p.sway.2,
                    ..Motion::driving(x0, y0, p.dir, p.v0, p.accel)
                };
                let actors = populate(
                    &mut p.rng,
                    street,
                    &ego,
                    p.lane,
                    &p.times_s,
                    cfg.annotation_range_m + 15.0,
                    cfg.car_sizes,
                );
                SceneWorld {
                    index: i,
                    street: p.street,
                    ego,
                    actors,
                    timestamps_ns: std::mem::take(&mut p.timestamps_ns),
                    times_s: std::mem::take(&mut p.times_s),
                    roof: cfg.roof.draw(seed, i),
                }
            })
            .collect();

        // Phase 4: the streets in the global frame, all inside the map raster.
        let (sn, cs) = heading.sin_cos();
        let normal = [-sn, cs];
        let map_x_range: Vec<(f64, f64)> = (0..n_streets)
            .map(|s| {
                let xs = scenes.iter().filter(|sc| sc.street == s).flat_map(|sc| {
                    sc.times_s
                        .iter()
                        .map(move |&t| sc.ego.at(t)[0])
                        .collect::<Vec<_>>()
                });
                let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(x), b.max(x))
                });
                if lo.is_finite() {
                    (lo - MAP_REACH, hi + MAP_REACH)
                } else {
                    (STREET_MARGIN - MAP_REACH, STREET_MARGIN + MAP_REACH)
                }
            })
            .collect();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for (s, &(x_a, x_b)) in map_x_range.iter().enumerate() {
            let origin = [
                normal[0] * STREET_SPACING * s as f64,
                normal[1] * STREET_SPACING * s as f64,
            ];
            for (x, y) in [
                (x_a, -MAP_HALF_WIDTH),
                (x_a, MAP_HALF_WIDTH),
                (x_b, -MAP_HALF_WIDTH),
                (x_b, MAP_HALF_WIDTH),
            ] {
                let g = [origin[0] + cs * x - sn * y, origin[1] + sn * x + cs * y];
                for k in 0..2 {
                    lo[k] = lo[k].min(g[k]);
                    hi[k] = hi[k].max(g[k]);
                }
            }
        }
        let shift = [MAP_MARGIN - lo[0], MAP_MARGIN - lo[1]];
        let street_poses = (0..n_streets)
            .map(|s| {
                let t = Translation3::new(
                    shift[0] + normal[0] * STREET_SPACING * s as f64,
                    shift[1] + normal[1] * STREET_SPACING * s as f64,
                    0.0,
                );
                Isometry3::from_parts(t, UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading))
            })
            .collect();
        let map = MapFrame {
            width_px: ((hi[0] - lo[0] + 2.0 * MAP_MARGIN) / MAP_RESOLUTION).ceil() as u32,
            height_px: ((hi[1] - lo[1] + 2.0 * MAP_MARGIN) / MAP_RESOLUTION).ceil() as u32,
        };
        Town {
            streets,
            street_poses,
            scenes,
            map,
            map_x_range,
        }
    }

    /// The street a scene drives.
    pub fn street_of(&self, scene: &SceneWorld) -> &Street {
        &self.streets[scene.street]
    }

    /// T_street←ego at key frame k: on the ground under the rear axle, pitched and rolled with it.
    pub fn ego_pose(&self, scene: &SceneWorld, k: usize) -> Pose {
        let street = self.street_of(scene);
        let t = scene.times_s.get(k).copied().unwrap_or(0.0);
        let [x, y, yaw] = scene.ego.at(t);
        let g = &street.ground;
        let (s, c) = yaw.sin_cos();
        let z = g.height(x, y);
        let (mx, my) = (x + 0.5 * WHEELBASE * c, y + 0.5 * WHEELBASE * s);
        let z_front = g.height(x + WHEELBASE * c, y + WHEELBASE * s);
        let z_left = g.height(mx - 0.5 * TRACK * s, my + 0.5 * TRACK * c);
        let z_right = g.height(mx + 0.5 * TRACK * s, my - 0.5 * TRACK * c);
        let pitch = -((z_front - z) / WHEELBASE).atan();
        let roll = ((z_left - z_right) / TRACK).atan();
        let r = rpy_to_matrix(roll, pitch, yaw);
        Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_matrix(&r))
    }

    /// T_global←ego at key frame k.
    pub fn ego_pose_global(&self, scene: &SceneWorld, k: usize) -> Pose {
        self.street_poses[scene.street] * self.ego_pose(scene, k)
    }

    /// T_street←sensor of a mount at key frame k.
    pub fn lidar_pose(&self, scene: &SceneWorld, k: usize, mount: &LidarMount) -> Pose {
        self.ego_pose(scene, k) * mount.pose()
    }

    /// An actor's annotation box in the street frame at key frame k.
    pub fn actor_box(&self, scene: &SceneWorld, actor: usize, k: usize) -> Option<Box3d> {
        let a = scene.actors.get(actor)?;
        let t = scene.times_s.get(k).copied()?;
        Some(a.box_at(self.street_of(scene), t))
    }

    /// An actor's annotation box in the global frame at key frame k.
    pub fn actor_box_global(&self, scene: &SceneWorld, actor: usize, k: usize) -> Option<Box3d> {
        Some(
            self.actor_box(scene, actor, k)?
                .transformed(&self.street_poses[scene.street]),
        )
    }

    /// Mount `l` of the car in `scene`: LIDAR_TOP raised by the scene's roof offset.
    pub fn mount_of(&self, scene: &SceneWorld, l: usize) -> LidarMount {
        let mut m = LYFT_MOUNTS[l.min(LYFT_MOUNTS.len() - 1)];
        if l == 0 {
            m.translation[2] += scene.roof.dz;
        }
        m
    }

    /// The mounts of the car, base LiDAR first.
    pub fn mounts(&self) -> &'static [LidarMount] {
        &LYFT_MOUNTS
    }
}

fn pick<T: Copy>(rng: &mut impl Rng, table: &[(T, f64)]) -> T {
    let total: f64 = table.iter().map(|(_, w)| w).sum();
    let mut u = rng.random_range(0.0..total);
    for &(v, w) in table {
        if u < w {
            return v;
        }
        u -= w;
    }
    table[table.len() - 1].0
}

/// Footprint (centre, half l/w, yaw) of an actor at t, for overlap tests.
fn footprint(a: &Actor, t: f64) -> ([f64; 2], [f64; 2], f64) {
    let [x, y, yaw] = a.motion.at(t);
    (
        [x, y],
        [0.5 * a.shape.size_lwh[0], 0.5 * a.shape.size_lwh[1]],
        yaw,
    )
}

/// Whether two oriented rectangles (grown by `margin`) overlap: separating axis test.
fn rects_overlap(a: ([f64; 2], [f64; 2], f64), b: ([f64; 2], [f64; 2], f64), margin: f64) -> bool {
    let axes = |yaw: f64| {
        let (s, c) = yaw.sin_cos();
        [[c, s], [-s, c]]
    };
    let (aa, ba) = (axes(a.2), axes(b.2));
    let d = [b.0[0] - a.0[0], b.0[1] - a.0[1]];
    for axis in aa.iter().chain(ba.iter()) {
        let proj = |ax: &[[f64; 2]; 2], half: [f64; 2]| {
            (half[0] + margin) * (ax[0][0] * axis[0] + ax[0][1] * axis[1]).abs()
                + (half[1] + margin) * (ax[1][0] * axis[0] + ax[1][1] * axis[1]).abs()
        };
        let dist = (d[0] * axis[0] + d[1] * axis[1]).abs();
        if dist > proj(&aa, a.1) + proj(&ba, b.1) {
            return false;
        }
    }
    true
}

fn collides(candidate: &Actor, placed: &[Actor], times: &[f64]) -> bool {
    times.iter().any(|&t| {
        let fc = footprint(candidate, t);
        placed.iter().any(|p| rects_overlap(fc, footprint(p, t), 0.15))
    })
}

/// The x range of starting positions from which an actor moving at (v0, accel) in direction
/// `dir` comes within `reach` of the ego at some key frame.
fn start_range(ego: &Motion, times: &[f64], dir: f64, v0: f64, accel: f64, reach: f64) -> (f64, f64) {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for &t in times {
        let xe = ego.at(t)[0];
        let s = dir * (v0 * t + 0.5 * accel * t * t);
        lo = lo.min(xe - reach - s);
        hi = hi.max(xe + reach - s);
    }
    if lo.is_finite() {
        (lo, hi)
    } else {
        (ego.x0 - reach, ego.x0 + reach)
    }
}

fn populate(
    rng: &mut ChaCha8Rng,
    street: &Street,
    ego: &Motion,
    ego_lane: u32,
    times: &[f64],
    reach: f64,
    car_sizes: actors::CarSizes,
) -> Vec<Actor> {
    let layout = street.ground.layout;
    let mut actors: Vec<Actor> = Vec::new();
    let ego_x0 = ego.x0;

    // Parked vehicles along both parking lanes, nose in the direction of traffic on that side.
    let (park_lo, park_hi) = start_range(ego, times, 1.0, 0.0, 0.0, reach);
    for side in [-1.0f64, 1.0] {
        let dir = -side;
        let y_lane = side * (layout.curb() - 1.25);
        let mut x = park_lo + rng.random_range(0.0..5.0);
        while x < park_hi {
            if rng.random_bool(0.62) {
                let cat = pick(
                    rng,
                    &[
                        (Category::Car, 0.86),
                        (Category::OtherVehicle, 0.1),
                        (Category::Motorcycle, 0.04),
                    ],
                );
                let shape = actors::build_with(cat, car_sizes, rng);
                let l = shape.size_lwh[0];
                let cx = x + 0.5 * l;
                let y = y_lane + rng.random_range(-0.1..0.1);
                let yaw = rng.random_range(-0.03..0.03);
                if !street.ground.driveway_overlaps(side, x - 0.3, x + l + 0.3) {
                    actors.push(Actor {
                        category: cat,
                        shape,
                        motion: Motion::fixed(cx, y, dir, yaw),
                        attribute: Attribute::Parked,
                    });
                }
                x += l + rng.random_range(0.8..3.5);
            } else {
                x += rng.random_range(3.0..7.0);
            }
        }
    }

    // Traffic: every lane has one speed; the ego's lane moves with the ego.
    for dir in [1.0f64, -1.0] {
        for lane in 0..layout.lanes_per_direction {
            let is_ego_lane = dir == ego.dir && lane == ego_lane;
            let (v0, accel, attribute) = if is_ego_lane {
                (ego.v0, ego.accel, Attribute::DrivingStraightForward)
            } else if rng.random_bool(0.08) {
                (0.0, 0.0, Attribute::Stopped)
            } else {
                (
                    rng.random_range(5.0..14.0),
                    0.0,
                    Attribute::DrivingStraightForward,
                )
            };
            let y_lane = layout.lane_center(dir, lane);
            let (lo, hi) = start_range(ego, times, dir, v0, accel, reach);
            let mut x = lo + rng.random_range(0.0..20.0);
            while x < hi {
                let cat = pick(
                    rng,
                    &[
                        (Category::Car, 0.8),
                        (Category::OtherVehicle, 0.08),
                        (Category::Truck, 0.05),
                        (Category::Bus, 0.03),
                        (Category::Motorcycle, 0.025),
                        (Category::EmergencyVehicle, 0.015),
                    ],
                );
                let shape = actors::build_with(cat, car_sizes, rng);
                let l = shape.size_lwh[0];
                let cx = x + 0.5 * l;
                // Keep clear of the ego car (x from −1 to 3.9 m along its heading) in its lane.
                let ego_mid = ego_x0 + dir * 1.45;
                if is_ego_lane && (cx - ego_mid).abs() < 0.5 * l + 2.45 + 6.0 {
                    x += 2.0;
                    continue;
                }
                let y = y_lane + rng.random_range(-0.2..0.2);
                actors.push(Actor {
                    category: cat,
                    shape,
                    motion: Motion::driving(cx, y, dir, v0, accel),
                    attribute,
                });
                x += l + rng.random_range(6.0..45.0);
            }
        }
    }

    // Cyclists in the bike lanes, with the traffic on their side.
    for side in [-1.0f64, 1.0] {
        let dir = -side;
        let count = pick(rng, &[(0usize, 0.4), (1, 0.4), (2, 0.2)]);
        for _ in 0..count {
            let v0 = rng.random_range(3.0..7.0);
            let (lo, hi) = start_range(ego, times, dir, v0, 0.0, reach);
            let shape = actors::build(Category::Bicycle, rng);
            for _ in 0..20 {
                let x = rng.random_range(lo..hi);
                let y = side * (layout.travel_edge() + 0.75) + rng.random_range(-0.15..0.15);
                let a = Actor {
                    category: Category::Bicycle,
                    shape: shape.clone(),
                    motion: Motion::driving(x, y, dir, v0, 0.0),
                    attribute: Attribute::DrivingStraightForward,
                };
                if !collides(&a, &actors, times) {
                    actors.push(a);
                    break;
                }
            }
        }
    }

    // Pedestrians walking or standing on the sidewalks, and now and then a dog.
    let walkers = rng.random_range(4..=10);
    let standers = rng.random_range(1..=4);
    let dogs = usize::from(rng.random_bool(0.4));
    let walk_in = layout.strip_outer() + 0.45;
    let walk_out = layout.sidewalk_outer() - 0.45;
    for n in 0..walkers + standers + dogs {
        let category = if n < walkers + standers {
            Category::Pedestrian
        } else {
            Category::Animal
        };
        let shape = actors::build(category, rng);
        let walking = n < walkers || category == Category::Animal;
        for _ in 0..20 {
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let y = side * rng.random_range(walk_in..walk_out);
            let motion = if walking {
                let dir = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let v0 = if category == Category::Animal {
                    rng.random_range(0.8..2.0)
                } else {
                    rng.random_range(0.9..1.6)
                };
                let (lo, hi) = start_range(ego, times, dir, v0, 0.0, reach);
                Motion {
                    sway_amp: 0.03,
                    sway_omega: std::f64::consts::TAU / 1.1,
                    sway_phase: rng.random_range(0.0..std::f64::consts::TAU),
                    ..Motion::driving(rng.random_range(lo..hi), y, dir, v0, 0.0)
                }
            } else {
                let (lo, hi) = start_range(ego, times, 1.0, 0.0, 0.0, reach);
                Motion::fixed(
                    rng.random_range(lo..hi),
                    y,
                    1.0,
                    rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
                )
            };
            let attribute = if walking {
                Attribute::Walking
            } else {
                Attribute::Standing
            };
            let a = Actor {
                category,
                shape: shape.clone(),
                motion,
                attribute,
            };
            if !collides(&a, &actors, times) {
                actors.push(a);
                break;
            }
        }
    }
    actors
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_heading_follows_direction() {
        let m = Motion::driving(0.0, 0.0, -1.0, 5.0, 0.0);
        let [x, _, yaw] = m.at(2.0);
        assert!((x + 10.0).abs() < 1e-12 && (yaw.abs() - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn separating_axis_test() {
        let a = ([0.0, 0.0], [2.0, 1.0], 0.0);
        assert!(rects_overlap(a, ([3.9, 0.0], [2.0, 1.0], 0.0), 0.0));
        assert!(!rects_overlap(a, ([4.1, 0.0], [2.0, 1.0], 0.0), 0.0));
        assert!(rects_overlap(a, ([2.5, 1.5], [1.0, 1.0], 0.7), 0.0));
        assert!(!rects_overlap(a, ([3.0, 2.0], [1.0, 1.0], 0.7), 0.0));
        assert!(!rects_overlap(
            a,
            ([0.0, 3.5], [2.0, 1.0], std::f64::consts::FRAC_PI_2),
            0.0
        ));
    }

    #[test]
    fn no_two_actors_overlap_and_the_ego_lane_is_clear() {
        let cfg = SynthConfig {
            scenes: 2,
            samples_per_scene: 5,
            ..SynthConfig::default()
        };
        let town = Town::generate(&cfg);
        for scene in &town.scenes {
            assert!(scene.actors.len() > 20, "{} actors", scene.actors.len());
            let cats: std::collections::BTreeSet<_> = scene.actors.iter().map(|a| a.category).collect();
            assert!(cats.contains(&Category::Car) && cats.contains(&Category::Pedestrian));
            for (k, &t) in scene.times_s.iter().enumerate() {
                let fp: Vec<_> = scene.actors.iter().map(|a| footprint(a, t)).collect();
                for i in 0..fp.len() {
                    for j in i + 1..fp.len() {
                        assert!(
                            !rects_overlap(fp[i], fp[j], 0.0),
                            "actors {i} and {j} overlap at {k}"
                        );
                    }
                }
                let e = town.ego_pose(scene, k);
                let yaw = crate::geometry::yaw_of(&e.rotation.to_rotation_matrix().into_inner());
                let (s, c) = yaw.sin_cos();
                let ego_fp = (
                    [e.translation.x + 1.45 * c, e.translation.y + 1.45 * s],
                    [2.45, 0.95],
                    yaw,
                );
                for (i, f) in fp.iter().enumerate() {
                    assert!(
                        !rects_overlap(ego_fp, *f, 0.0),
                        "actor {i} overlaps the ego at {k}"
                    );
                }
            }
        }
    }
}
