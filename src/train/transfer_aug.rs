//! Augmentation for transfer to other sensors and other cars (issue 29, `--transfer-aug`): what a
//! detector trained on one simulated roof LiDAR needs to see so that it still finds cars in
//! another sensor's sweep.
//!
//! Per training step, on top of SECOND's flip / rotation / translation ([`crate::train::stage1`]):
//! - **object scaling**: each learned box, with probability 0.5, is scaled with its points about
//!   the centre of its bottom face by U(0.9, 1.1) (a Lyft-sized car becomes a compact or a
//!   pickup, the wheels stay on the road);
//! - **global scaling**: with probability 0.5, every point and box by U(0.95, 1.05) about the
//!   sensor (SECOND's global scaling);
//! - **density**: with probability 0.5, every point is kept with one probability U(0.5, 1) (a
//!   sparser sensor, or the same car farther away). Dropped points become NaN, which the voxeliser
//!   and the point-in-box counts skip, so the fused cloud's per-LiDAR ranges stay valid;
//! - **tilt**: with probability 0.5, the cloud is pitched by U(−1.5°, 1.5°) and rolled by
//!   U(−1°, 1°) about the sensor (a road that climbs or falls away, a car that pitches: a car
//!   35 m ahead sits up to 0.9 m higher or lower); box centres follow, boxes stay upright;
//! - **car ray drop** (`--car-drop`, LiDAR-Top's recipe): each box, with probability 0.5, keeps
//!   its points with one probability U(0.2, 0.6), from a stream of its own
//!   ([`TransferAug::draw_car_keep`]): real cars carry 0.13–0.53× the points of simulated ones.
//!
//! Everything is drawn from the step's own ChaCha8 stream, so a resumed run repeats it exactly.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::detect::anchors::RawBox;
use crate::pipeline::FusedCloud;
use crate::train::gt_sampling::Inside;

/// One step's transfer augmentation.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferAug {
    /// Per box (in the order of the boxes given to [`TransferAug::draw`]): its scale.
    pub object_scales: Vec<f32>,
    pub global_scale: f32,
    /// Share of the points kept (1: all).
    pub keep: f32,
    /// Seed of the per-point keep draws.
    pub point_seed: u64,
    /// Pitch (about y) and roll (about x), rad.
    pub tilt: [f32; 2],
    /// Per box (as `object_scales`): the share of its points kept (1: all); empty: none dropped.
    /// The car ray-drop lever (`--car-drop`, docs/notes/2026-12-07-lever-object-ray-drop-rule.md).
    pub car_keep: Vec<f32>,
}

impl TransferAug {
    /// Draws the augmentation of a step with `boxes` learned boxes.
    pub fn draw(rng: &mut ChaCha8Rng, boxes: usize) -> Self {
        let object_scales = (0..boxes).map(|_| half_the_time(rng, 0.9..=1.1)).collect();
        let global_scale = half_the_time(rng, 0.95..=1.05);
        let keep = half_the_time(rng, 0.5..=1.0);
        let point_seed = rng.random();
        let tilt = if rng.random_bool(0.5) {
            [
                rng.random_range(-1.5f32..=1.5).to_radians(),
                rng.random_range(-1.0f32..=1.0).to_radians(),
            ]
        } else {
            [0.0, 0.0]
        };
        Self {
            object_scales,
            global_scale,
            keep,
            point_seed,
            tilt,
            car_keep: Vec::new(),
        }
    }

    /// The car ray-drop lever's draw, from its own stream (the other draws stay as they were):
    /// each box, with probability 0.5, keeps its points with one probability from U(0.2, 0.6).
    pub fn draw_car_keep(rng: &mut ChaCha8Rng, boxes: usize) -> Vec<f32> {
        (0..boxes).map(|_| half_the_time(rng, 0.2..=0.6)).collect()
    }

    /// Applies it to a cloud and its boxes (`boxes` as at the draw; extra boxes are not scaled).
    pub fn apply(&self, cloud: &mut FusedCloud, boxes: &mut [RawBox]) {
        let n = cloud.x.len().min(cloud.y.len()).min(cloud.z.len());
        for (b, &s) in boxes.iter_mut().zip(&self.object_scales) {
            if s == 1.0 {
                continue;
            }
            let inside = Inside::new(b);
            let bottom = [b[0], b[1], b[2] - 0.5 * b[5]];
            for i in 0..n {
                if inside.contains(cloud.x[i], cloud.y[i], cloud.z[i]) {
                    cloud.x[i] = bottom[0] + s * (cloud.x[i] - bottom[0]);
                    cloud.y[i] = bottom[1] + s * (cloud.y[i] - bottom[1]);
                    cloud.z[i] = bottom[2] + s * (cloud.z[i] - bottom[2]);
                }
            }
            *b = [
                b[0],
                b[1],
                bottom[2] + 0.5 * s * b[5],
                s * b[3],
                s * b[4],
                s * b[5],
                b[6],
            ];
        }
        let g = self.global_scale;
        if g != 1.0 {
            for v in cloud.x[..n]
                .iter_mut()
                .chain(&mut cloud.y[..n])
                .chain(&mut cloud.z[..n])
            {
                *v *= g;
            }
            for b in boxes.iter_mut() {
                for v in &mut b[..6] {
                    *v *= g;
                }
            }
        }
        if self.tilt != [0.0, 0.0] {
            let rot = |p: [f32; 3]| -> [f32; 3] {
                let (sp, cp) = self.tilt[0].sin_cos();
                let (sr, cr) = self.tilt[1].sin_cos();
                // Pitch about y, then roll about x.
                let (x, z) = (cp * p[0] + sp * p[2], -sp * p[0] + cp * p[2]);
                let (y, z) = (cr * p[1] - sr * z, sr * p[1] + cr * z);
                [x, y, z]
            };
            for i in 0..n {
                [cloud.x[i], cloud.y[i], cloud.z[i]] = rot([cloud.x[i], cloud.y[i], cloud.z[i]]);
            }
            for b in boxes.iter_mut() {
                [b[0], b[1], b[2]] = rot([b[0], b[1], b[2]]);
            }
        }
        if self.keep < 1.0 {
            let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(self.point_seed);
            for i in 0..n {
                if rng.random::<f32>() >= self.keep {
                    drop_point(cloud, i);
                }
            }
        }
        if self.car_keep.iter().any(|&k| k < 1.0) {
            let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(self.point_seed ^ 0x00ca_7d70);
            for (b, &k) in boxes.iter().zip(&self.car_keep) {
                if k >= 1.0 {
                    continue;
                }
                let inside = Inside::new(b);
                for i in 0..n {
                    if inside.contains(cloud.x[i], cloud.y[i], cloud.z[i]) && rng.random::<f32>() >= k {
                        drop_point(cloud, i);
                    }
                }
            }
        }
    }
}

/// With probability 0.5 a factor drawn from `range`, else 1 (no change): every factor of
/// [`TransferAug`] is drawn this way, one `random_bool` and at most one `random_range` each.
fn half_the_time(rng: &mut ChaCha8Rng, range: std::ops::RangeInclusive<f32>) -> f32 {
    if rng.random_bool(0.5) {
        rng.random_range(range)
    } else {
        1.0
    }
}

/// Drops point `i`: NaN, which the voxeliser and the point-in-box counts skip.
fn drop_point(cloud: &mut FusedCloud, i: usize) {
    cloud.x[i] = f32::NAN;
    cloud.y[i] = f32::NAN;
    cloud.z[i] = f32::NAN;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::voxel::{voxelize, GridConfig, PointsRef};
    use rand::SeedableRng;

    fn cloud(pts: &[[f32; 3]]) -> FusedCloud {
        let mut c = FusedCloud::default();
        for p in pts {
            c.x.push(p[0]);
            c.y.push(p[1]);
            c.z.push(p[2]);
            c.intensity.push(100.0);
            c.source.push(0);
            c.trace.push(0.0);
        }
        c
    }

    /// An augmentation that changes nothing (one box), for the tests to set one field of.
    fn neutral() -> TransferAug {
        TransferAug {
            object_scales: vec![1.0],
            global_scale: 1.0,
            keep: 1.0,
            point_seed: 0,
            tilt: [0.0, 0.0],
            car_keep: Vec::new(),
        }
    }

    #[test]
    fn object_scaling_keeps_the_bottom_and_moves_only_its_points() {
        // A 4 × 2 × 1.6 box standing on z = −1.8 at (10, 0); a point inside, one outside.
        let mut boxes = [[10.0f32, 0.0, -1.0, 4.0, 2.0, 1.6, 0.0]];
        let mut c = cloud(&[[11.0, 0.5, -0.2], [20.0, 0.0, -1.0]]);
        let aug = TransferAug {
            object_scales: vec![1.1],
            ..neutral()
        };
        aug.apply(&mut c, &mut boxes);
        let b = boxes[0];
        assert!(
            (b[2] - 0.5 * b[5] - (-1.8)).abs() < 1e-5,
            "bottom stays on the road"
        );
        assert!((b[3] - 4.4).abs() < 1e-5 && (b[5] - 1.76).abs() < 1e-5);
        assert!((c.x[0] - 11.1).abs() < 1e-5 && (c.y[0] - 0.55).abs() < 1e-5);
        assert!((c.z[0] - (-1.8 + 1.1 * 1.6)).abs() < 1e-5, "{}", c.z[0]);
        assert_eq!([c.x[1], c.y[1], c.z[1]], [20.0, 0.0, -1.0]);
    }

    #[test]
    fn global_scaling_and_density_are_applied_and_dropped_points_are_skipped() {
        let pts: Vec<[f32; 3]> = (0..2000)
            .map(|i| [1.0 + (i % 50) as f32 * 0.3, (i / 50) as f32 * 0.3, -1.0])
            .collect();
        let mut c = cloud(&pts);
        let mut boxes = [[10.0f32, 2.0, -1.0, 4.0, 2.0, 1.6, 0.3]];
        let aug = TransferAug {
            global_scale: 1.05,
            keep: 0.6,
            point_seed: 9,
            ..neutral()
        };
        aug.apply(&mut c, &mut boxes);
        assert!((boxes[0][0] - 10.5).abs() < 1e-5 && (boxes[0][3] - 4.2).abs() < 1e-5);
        assert!((boxes[0][6] - 0.3).abs() < 1e-7, "yaw unchanged");
        let kept = c.x.iter().filter(|v| !v.is_nan()).count();
        assert!((1100..1300).contains(&kept), "kept {kept} of 2000 at 0.6");
        let bev = voxelize(
            &GridConfig::default(),
            PointsRef {
                x: &c.x,
                y: &c.y,
                z: &c.z,
                intensity: &c.intensity,
                trace: &c.trace,
            },
        );
        assert_eq!(bev.points_used, kept);
        // A pitch lifts what lies ahead: −1° raises a point 30 m ahead by 30·sin 1°.
        let mut c = cloud(&[[30.0, 0.0, -1.8]]);
        let mut boxes = [[30.0f32, 0.0, -1.0, 4.0, 2.0, 1.6, 0.0]];
        let tilt = TransferAug {
            tilt: [-1f32.to_radians(), 0.0],
            ..neutral()
        };
        tilt.apply(&mut c, &mut boxes);
        let lift = 30.0 * 1f32.to_radians().sin();
        assert!(
            (c.z[0] - (-1.8 * 1f32.to_radians().cos() + lift)).abs() < 1e-4,
            "{}",
            c.z[0]
        );
        assert!((boxes[0][2] - c.z[0] - 0.8 * 1f32.to_radians().cos()).abs() < 1e-3);
        assert_eq!(boxes[0][3..], [4.0, 2.0, 1.6, 0.0], "size and yaw kept");
        // The draw is reproducible for a stream.
        let a = TransferAug::draw(&mut ChaCha8Rng::seed_from_u64(3), 4);
        assert_eq!(a, TransferAug::draw(&mut ChaCha8Rng::seed_from_u64(3), 4));
        assert_eq!(a.object_scales.len(), 4);
    }

    #[test]
    fn car_drop_thins_only_the_points_of_its_box() {
        let pts: Vec<[f32; 3]> = (0..4000)
            .map(|i| {
                [
                    8.5 + (i % 40) as f32 * 0.08,
                    -0.98 + (i / 40) as f32 * 0.0195,
                    -1.0,
                ]
            })
            .collect();
        let mut c = cloud(&pts);
        c.x.push(30.0);
        c.y.push(0.0);
        c.z.push(-1.0);
        let mut boxes = [[10.0f32, 0.0, -1.0, 4.0, 2.0, 1.6, 0.0]];
        let aug = TransferAug {
            point_seed: 3,
            car_keep: vec![0.4],
            ..neutral()
        };
        aug.apply(&mut c, &mut boxes);
        let kept = c.x[..4000].iter().filter(|v| !v.is_nan()).count();
        assert!(
            (1400..=1800).contains(&kept),
            "{kept} of 4000 kept, expected about 1600"
        );
        assert_eq!(c.x[4000], 30.0, "a point outside the box stays");
        let keeps = TransferAug::draw_car_keep(&mut ChaCha8Rng::seed_from_u64(1), 1000);
        let dropped = keeps.iter().filter(|&&k| k < 1.0).count();
        assert!((400..=600).contains(&dropped));
        assert!(keeps.iter().all(|&k| k == 1.0 || (0.2..=0.6).contains(&k)));
    }
}
