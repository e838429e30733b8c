//! The simulated car: the three LiDAR mounts of a real Lyft Level 5 vehicle (host-a101), a
//! 40-channel Hesai Pandar40 beam model, and the ego body that occludes rays.
//!
//! The mounts are the real `calibrated_sensor` rows of the Lyft fixture, verbatim: LIDAR_TOP on the
//! roof turned ~180° about z, LIDAR_FRONT_LEFT / LIDAR_FRONT_RIGHT on the front bumper corners,
//! upside down. Each LiDAR scans 40 channels at the Pandar40's elevations (+7° … −16°, 1/3° apart
//! between +2° and −6°, 1° elsewhere) and 1800 azimuths (0.2°, 10 Hz); the sweep is treated as
//! instantaneous (no rolling-shutter motion distortion) and the per-channel azimuth offsets and
//! intrinsic calibration errors of a real unit are not modelled.
//!
//! The ego body is three axis-aligned boxes in the ego frame (origin on the ground under the rear
//! axle, x forward): lower body, a narrower nose and the cabin. Rays that hit it return nothing, so
//! the top LiDAR loses its lowest beams over the roof and each bumper LiDAR sees about 225°.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::geometry::{quat_from_wxyz, Pose};

/// The number of LiDARs on the car.
pub const LIDAR_COUNT: usize = 3;

/// One LiDAR mounted on the ego car.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LidarMount {
    /// The Lyft channel name (`LIDAR_TOP`, ...).
    pub channel: &'static str,
    /// The index in real file names: `lidar1` is LIDAR_TOP, `lidar0` FRONT_LEFT, `lidar2` FRONT_RIGHT.
    pub file_index: u8,
    /// The real `sensor` table token of this channel.
    pub sensor_token: &'static str,
    /// Sensor origin in the ego frame (m), verbatim from the real calibrated_sensor row.
    pub translation: [f64; 3],
    /// Sensor → ego rotation [w, x, y, z], verbatim from the real calibrated_sensor row.
    pub rotation_wxyz: [f64; 4],
}

impl LidarMount {
    /// T_ego←sensor. The real quaternions are unit to ~1e-9 and are normalised here.
    pub fn pose(&self) -> Pose {
        let q = quat_from_wxyz(self.rotation_wxyz).unwrap_or_else(UnitQuaternion::identity);
        let [x, y, z] = self.translation;
        Isometry3::from_parts(Translation3::new(x, y, z), q)
    }
}

/// The three mounts, base LiDAR first: [LIDAR_TOP, LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT].
pub const LYFT_MOUNTS: [LidarMount; LIDAR_COUNT] = [
    LidarMount {
        channel: "LIDAR_TOP",
        file_index: 1,
        sensor_token: "25bf751d7e35f295393d8a418731474b21c1f702e878c4553f112397caa48c08",
        translation: [1.1970962545449502, 3.680498291456359e-05, 1.8279670539933053],
        rotation_wxyz: [
            0.006336712035703651,
            -0.011344169002788682,
            7.18908018654885e-05,
            0.9999155718069028,
        ],
    },
    LidarMount {
        channel: "LIDAR_FRONT_LEFT",
        file_index: 0,
        sensor_token: "629da739ea3a0814b9d79ffc3b99cdbc8bdbb6f97abf139f1ad33bd12f8fa94d",
        translation: [3.47289236509973, 0.941603244416182, 0.5427200389242757],
        rotation_wxyz: [
            0.01046934325147815,
            0.7290775169266195,
            -0.6842510224225216,
            0.011700661422809379,
        ],
    },
    LidarMount {
        channel: "LIDAR_FRONT_RIGHT",
        file_index: 2,
        sensor_token: "953faed96fd3d2fae3ec03cd2838b312b8c1a9bb7a0629481982870cb28acb67",
        translation: [3.4979440634654573, -0.9496511625133583, 0.5473180779313758],
        rotation_wxyz: [
            0.003651633245269522,
            0.6883656521848035,
            0.7253545303479662,
            0.0004469569487147289,
        ],
    },
];

/// The Hesai Pandar40's 40 channel elevations in degrees, channel 1 (top) first.
pub fn pandar40_elevations_deg() -> [f64; 40] {
    let mut e = [0.0; 40];
    // Channels 1–6: +7° … +2° in 1° steps.
    for (i, v) in e.iter_mut().take(6).enumerate() {
        *v = 7.0 - i as f64;
    }
    // Channels 7–30: +5/3° … −6° in 1/3° steps (the dense band around the horizon).
    for (i, v) in e.iter_mut().skip(6).take(24).enumerate() {
        *v = 5.0 / 3.0 - i as f64 / 3.0;
    }
    // Channels 31–40: −7° … −16° in 1° steps.
    for (i, v) in e.iter_mut().skip(30).enumerate() {
        *v = -7.0 - i as f64;
    }
    e
}

/// How every LiDAR of the car samples and measures.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarModel {
    /// Channel elevations (degrees, sensor frame), channel 1 first; the ring written to the .bin is
    /// the 1-based channel number, as in the real Lyft files (the +7° beam has ring 1).
    pub elevations_deg: Vec<f64>,
    /// Azimuth samples per revolution (1800 = 0.2° at 10 Hz).
    pub azimuth_steps: usize,
    /// Standard deviation of the Gaussian range noise (m).
    pub range_noise_m: f64,
    /// Returns beyond this range are dropped (m).
    pub max_range_m: f64,
    /// Returns closer than this are dropped (m).
    pub min_range_m: f64,
    /// Range at which a target of reflectivity 1 seen head-on is at the detection threshold (m);
    /// the threshold scales as reflectivity × cos(incidence) / range².
    pub reference_range_m: f64,
    /// Probability that a ray returns nothing regardless of its target.
    pub dropout: f64,
    /// `Some(v)`: write this intensity for every point (the real Lyft files hold a constant 100);
    /// `None`: intensity from material reflectivity and incidence angle, 0–255.
    pub constant_intensity: Option<f32>,
    /// Probability that a beam which meets a car's side glass passes through it (0: glass is an
    /// opaque, dark surface, as before issue 29's `--glass see-through`). A passing beam goes on
    /// through the cabin and returns from what lies behind: the lower body's top (the seats and
    /// the far door at belt height), another object or the ground behind the car (see
    /// `raycast::through_glass`).
    pub glass_pass: f64,
    /// `false` reproduces the first see-through data (`--glass see-through-no-ground`, the
    /// v5-glass candidate's `data/v5g`): a beam that passes the glass and meets nothing else
    /// returns nothing instead of the ground behind the car.
    pub glass_ground: bool,
}

impl Default for LidarModel {
    fn default() -> Self {
        Self {
            elevations_deg: pandar40_elevations_deg().to_vec(),
            azimuth_steps: 1800,
            range_noise_m: 0.02,
            max_range_m: 120.0,
            min_range_m: 0.5,
            reference_range_m: 600.0,
            dropout: 0.01,
            constant_intensity: None,
            glass_pass: 0.0,
            glass_ground: true,
        }
    }
}

/// The ego car body as axis-aligned boxes (min, max) in the ego frame (m).
pub const EGO_BODY: [([f64; 3], [f64; 3]); 3] = [
    // Lower body, full width, up to the rear of the bumper LiDARs.
    ([-1.0, -0.95, 0.15], [3.3, 0.95, 1.0]),
    // Nose (hood and front bumper), narrower so the bumper LiDARs at the corners see forward.
    ([3.3, -0.5, 0.15], [3.9, 0.5, 1.0]),
    // Cabin and roof.
    ([-0.8, -0.85, 1.0], [2.4, 0.85, 1.6]),
];

/// Whether a ray (origin and unit direction in the ego frame) hits the ego body at t > 0.
#[inline]
pub fn ego_body_blocks(o: &[f64; 3], d: &[f64; 3]) -> bool {
    body_blocks(&EGO_BODY, o, d)
}

/// [`ego_body_blocks`] without the cabin: a roof LiDAR of sensor randomisation sits on a mast
/// or rack above the roof (as KITTI's HDL-64E does), so its steep beams clear the cabin and only
/// the hood and the trunk hide the road next to the car.
#[inline]
pub fn ego_body_blocks_below_roof(o: &[f64; 3], d: &[f64; 3]) -> bool {
    body_blocks(&EGO_BODY[..2], o, d)
}

#[inline]
fn body_blocks(body: &[([f64; 3], [f64; 3])], o: &[f64; 3], d: &[f64; 3]) -> bool {
    body.iter().any(|(lo, hi)| {
        let mut t0 = 0.0f64;
        let mut t1 = f64::INFINITY;
        for k in 0..3 {
            if d[k].abs() < 1e-12 {
                if o[k] < lo[k] || o[k] > hi[k] {
                    return false;
                }
                continue;
            }
            let inv = 1.0 / d[k];
            let (a, b) = ((lo[k] - o[k]) * inv, (hi[k] - o[k]) * inv);
            let (a, b) = if a < b { (a, b) } else { (b, a) };
            t0 = t0.max(a);
            t1 = t1.min(b);
            if t0 > t1 {
                return false;
            }
        }
        true
    })
}

/// The unit direction of a beam in its sensor frame.
#[inline]
pub fn beam_direction(elevation_rad: f64, azimuth_rad: f64) -> Vector3<f64> {
    let (se, ce) = elevation_rad.sin_cos();
    let (sa, ca) = azimuth_rad.sin_cos();
    Vector3::new(ce * ca, ce * sa, se)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{matrix_to_rpy, yaw_of};

    #[test]
    fn pandar40_table_is_dense_near_the_horizon() {
        let e = pandar40_elevations_deg();
        assert!((e[0] - 7.0).abs() < 1e-12 && (e[39] + 16.0).abs() < 1e-12);
        assert!(e.windows(2).all(|w| w[0] > w[1]));
        let dense = e.iter().filter(|&&v| (-6.0..=2.0).contains(&v)).count();
        assert_eq!(dense, 25);
        assert!((e[29] + 6.0).abs() < 1e-12);
    }

    #[test]
    fn mounts_match_the_real_table() {
        let top = LYFT_MOUNTS[0].pose();
        let r = top.rotation.to_rotation_matrix().into_inner();
        assert!((yaw_of(&r).to_degrees().abs() - 179.3).abs() < 0.1);
        for m in &LYFT_MOUNTS[1..] {
            let r = m.pose().rotation.to_rotation_matrix().into_inner();
            let (roll, _, _) = matrix_to_rpy(&r);
            assert!(roll.to_degrees().abs() > 179.0, "{} is upside down", m.channel);
            // Each bumper LiDAR sits outside the body it is occluded by.
            assert!(!EGO_BODY
                .iter()
                .any(|(lo, hi)| (0..3).all(|k| m.translation[k] >= lo[k] && m.translation[k] <= hi[k])));
        }
    }

    #[test]
    fn ego_body_blocks_rays_into_the_car() {
        let o = LYFT_MOUNTS[0].translation;
        assert!(ego_body_blocks(&o, &[0.0, 0.0, -1.0]));
        assert!(!ego_body_blocks(&o, &[1.0, 0.0, 0.0]));
        let fl = LYFT_MOUNTS[1].translation;
        assert!(ego_body_blocks(&fl, &[0.0, -1.0, 0.0]));
        assert!(!ego_body_blocks(&fl, &[0.0, 1.0, 0.0]));
    }
}
