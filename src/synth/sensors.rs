//! Roof LiDARs other than Lyft's Pandar40, for sensor randomisation (issue 29): a scene may carry
//! one of several real beam patterns on the roof, mounted a little higher or lower, so that a
//! detector trained on the simulator sees the point densities and ground patterns of the sensors
//! it will meet (KITTI's HDL-64E, nuScenes' HDL-32E, Lyft's 40- and 64-beam roof units, a 128-beam
//! unit).
//!
//! The beam tables are the published vertical angles, simplified where a datasheet gives
//! per-unit calibration (each HDL-64E laser has its own correction): what matters for training is
//! the spread of the beams (how far down they reach, where they crowd) and the azimuth step, which
//! together fix the points per object against range. The azimuth steps are those of the sweep
//! rates the datasets use: 10 Hz (Lyft, KITTI), 20 Hz (nuScenes' HDL-32E).
//!
//! The per-scene draw is a hash of (seed, scene), apart from the layout's generators, so a
//! dataset without sensor randomisation is byte-identical to one made before it existed.

use rand::Rng;

use super::noise::layout_rng;
use super::rig::pandar40_elevations_deg;

/// A roof LiDAR model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SensorPreset {
    /// Hesai Pandar40 (Lyft's roof LiDAR on most hosts): 40 beams, +7° … −16°, 0.2°.
    Pandar40,
    /// Hesai Pandar64 (Lyft's host-a101/a102 roof): 64 beams, +15° … −25°, 0.2°.
    Pandar64,
    /// Velodyne HDL-64E (KITTI): 64 beams, +2° … −24.8°, about 0.17°.
    Hdl64e,
    /// Velodyne HDL-32E at 20 Hz (nuScenes): 32 beams, +10.67° … −30.67°, about 0.33°.
    Hdl32e,
    /// A 128-beam unit (Velodyne VLS-128-like): +15° … −25°, 0.2°.
    Vls128,
}

impl SensorPreset {
    pub const ALL: [SensorPreset; 5] = [
        SensorPreset::Pandar40,
        SensorPreset::Pandar64,
        SensorPreset::Hdl64e,
        SensorPreset::Hdl32e,
        SensorPreset::Vls128,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SensorPreset::Pandar40 => "pandar40",
            SensorPreset::Pandar64 => "pandar64",
            SensorPreset::Hdl64e => "hdl64e",
            SensorPreset::Hdl32e => "hdl32e",
            SensorPreset::Vls128 => "vls128",
        }
    }

    /// The preset of a name (as [`Self::name`] writes it).
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|p| p.name() == s.trim().to_ascii_lowercase())
    }

    /// Beam elevations in degrees, top beam first.
    pub fn elevations_deg(self) -> Vec<f64> {
        match self {
            SensorPreset::Pandar40 => pandar40_elevations_deg().to_vec(),
            SensorPreset::Pandar64 => {
                // 6 sparse beams above, 48 at 1/6° around the horizon, 10 below to −25°.
                let mut e = vec![15.0, 11.0, 8.0, 5.0, 3.0, 2.0];
                e.extend((0..48).map(|i| 11.0 / 6.0 - i as f64 / 6.0));
                e.extend([-7.0, -8.0, -9.0, -10.0, -12.0, -14.0, -16.0, -19.0, -22.0, -25.0]);
                e
            }
            SensorPreset::Hdl64e => {
                // Upper block: 32 lasers +2° … −8.33° (1/3°); lower block: 32 lasers
                // −8.83° … −24.33° (1/2°).
                let mut e: Vec<f64> = (0..32).map(|i| 2.0 - i as f64 / 3.0).collect();
                e.extend((0..32).map(|i| -8.83 - 0.5 * i as f64));
                e
            }
            SensorPreset::Hdl32e => (0..32).map(|i| 10.67 - 4.0 / 3.0 * i as f64).collect(),
            SensorPreset::Vls128 => {
                // 16 sparse beams above, 96 at 0.11° around the horizon, 16 below to −25°.
                let mut e: Vec<f64> = (0..16).map(|i| 15.0 - i as f64 * 11.5 / 15.0).collect();
                e.extend((0..96).map(|i| 3.2 - 0.11 * i as f64));
                e.extend((0..16).map(|i| -7.5 - i as f64 * 17.5 / 15.0));
                e
            }
        }
    }

    /// Azimuth samples per revolution.
    pub fn azimuth_steps(self) -> usize {
        match self {
            SensorPreset::Hdl64e => 2080,
            SensorPreset::Hdl32e => 1084,
            _ => 1800,
        }
    }
}

/// Sensor randomisation of the roof LiDAR: each scene draws one preset of `presets` (uniformly)
/// and a mount height offset uniform in ±`height_jitter_m`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RoofRandomisation {
    /// Empty: every scene keeps the configured LiDAR model (no randomisation).
    pub presets: Vec<SensorPreset>,
    pub height_jitter_m: f64,
}

/// The roof LiDAR of one scene.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RoofSensor {
    /// `None`: the configured LiDAR model (Pandar40 by default).
    pub preset: Option<SensorPreset>,
    /// Added to LIDAR_TOP's mount height (m).
    pub dz: f64,
}

const TAG_ROOF: u64 = 0x524f_4f46;

impl RoofRandomisation {
    /// Scene `scene`'s roof LiDAR under seed `seed`.
    pub fn draw(&self, seed: u64, scene: usize) -> RoofSensor {
        if self.presets.is_empty() && self.height_jitter_m == 0.0 {
            return RoofSensor::default();
        }
        let mut rng = layout_rng(&[seed, TAG_ROOF, scene as u64]);
        let preset =
            (!self.presets.is_empty()).then(|| self.presets[rng.random_range(0..self.presets.len())]);
        let dz = if self.height_jitter_m > 0.0 {
            rng.random_range(-self.height_jitter_m..=self.height_jitter_m)
        } else {
            0.0
        };
        RoofSensor { preset, dz }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beam_tables_have_their_beam_counts_and_spans() {
        let cases = [
            (SensorPreset::Pandar40, 40, 7.0, -16.0),
            (SensorPreset::Pandar64, 64, 15.0, -25.0),
            (SensorPreset::Hdl64e, 64, 2.0, -24.33),
            (SensorPreset::Hdl32e, 32, 10.67, -30.67),
            (SensorPreset::Vls128, 128, 15.0, -25.0),
        ];
        for (p, n, top, bottom) in cases {
            let e = p.elevations_deg();
            assert_eq!(e.len(), n, "{}", p.name());
            assert!((e[0] - top).abs() < 1e-9, "{} top {}", p.name(), e[0]);
            assert!(
                (e[n - 1] - bottom).abs() < 0.01,
                "{} bottom {}",
                p.name(),
                e[n - 1]
            );
            assert!(e.windows(2).all(|w| w[0] > w[1]), "{} not descending", p.name());
            assert_eq!(SensorPreset::parse(p.name()), Some(p));
        }
        assert_eq!(SensorPreset::parse("HDL64E"), Some(SensorPreset::Hdl64e));
        assert_eq!(SensorPreset::parse("velodyne"), None);
    }

    #[test]
    fn draws_are_per_scene_and_reproducible() {
        let r = RoofRandomisation {
            presets: SensorPreset::ALL.to_vec(),
            height_jitter_m: 0.3,
        };
        let draws: Vec<RoofSensor> = (0..40).map(|s| r.draw(7, s)).collect();
        assert_eq!(draws, (0..40).map(|s| r.draw(7, s)).collect::<Vec<_>>());
        for p in SensorPreset::ALL {
            assert!(
                draws.iter().any(|d| d.preset == Some(p)),
                "{} never drawn",
                p.name()
            );
        }
        assert!(draws.iter().all(|d| d.dz.abs() <= 0.3));
        assert_eq!(RoofRandomisation::default().draw(7, 3), RoofSensor::default());
    }
}
