//! A deterministic ray-cast simulator of Lyft Level 5's three-LiDAR car, writing datasets in the
//! real Lyft on-disk format (13 JSON tables, `lidar/*.bin`, a map raster).
//!
//! How it works:
//! - [`rig`]: the real mounts of LIDAR_TOP / LIDAR_FRONT_LEFT / LIDAR_FRONT_RIGHT (verbatim
//!   calibrated_sensor rows of the Lyft fixture), a Hesai Pandar40 beam table (40 channels,
//!   +7° … −16°, 0.2° azimuth steps) and the ego body that occludes rays;
//! - [`street`] and [`scene`]: a town of parallel Palo Alto-like streets (height-field ground with
//!   curbs, lane paint, sidewalks, houses, walls, trees, street lights, signs) and per scene a drive
//!   of the ego car with parked and moving vehicles, cyclists, pedestrians and dogs;
//! - [`actors`] and [`shapes`]: every actor is a union of analytic convex parts that fills its
//!   annotation box exactly (cars have a rounded body, a cabin and wheels, not a cuboid);
//! - [`raycast`]: 3 × 40 × 1800 rays per key frame against the ground and a 2D grid of
//!   primitives, nearest hit wins, with range noise, intensity, drop-outs — in parallel with
//!   rayon and byte-identical for a seed (per-ray randomness is a hash, not a shared generator);
//! - [`writer`]: [`generate`] writes the dataset (tables through [`crate::dataset::tables`], atomic
//!   writes, tokens derived from the seed).
//!
//! What it does not model is listed in each module; in short: no intersections or turns, no
//! cameras or radars, no multi-echo/beam divergence/motion distortion, opaque glass and foliage.

pub mod actors;
mod map;
pub(crate) mod noise;
pub mod raycast;
pub mod rig;
pub mod scene;
pub mod sensors;
pub mod shapes;
pub mod street;
pub mod world;
pub mod writer;

use std::path::PathBuf;

pub use actors::CarSizes;
pub use actors::{ActorShape, Category};
pub use raycast::{scan_sample, Hit, LidarScan, SampleScan};
pub use rig::{pandar40_elevations_deg, LidarModel, LidarMount, EGO_BODY, LIDAR_COUNT, LYFT_MOUNTS};
pub use scene::{Actor, Attribute, SceneWorld, Town, SAMPLE_PERIOD_S};
pub use sensors::{RoofRandomisation, RoofSensor, SensorPreset};
pub use world::World;
pub use writer::{generate, HOST};

/// The most scenes one dataset may have.
pub const MAX_SCENES: usize = 1000;
/// The most key frames per scene: 50 s of driving keeps a street and its map raster (0.1 m per
/// pixel) at a few hundred metres.
pub const MAX_SAMPLES_PER_SCENE: usize = 250;

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    /// Everything (layout, motion, noise, tokens) is a function of this seed.
    pub seed: u64,
    /// Number of scenes (each its own log, on one of up to four streets).
    pub scenes: usize,
    /// Key frames per scene, 0.2 s apart.
    pub samples_per_scene: usize,
    /// The sensors.
    pub lidar: LidarModel,
    /// Objects whose box centre is farther than this from the ego (m) are not annotated.
    pub annotation_range_m: f64,
    /// Objects with fewer LiDAR points than this (all LiDARs together) are not annotated.
    pub min_points_per_box: u32,
    /// Sensor randomisation of the roof LiDAR (none by default).
    pub roof: RoofRandomisation,
    /// How car sizes are drawn.
    pub car_sizes: CarSizes,
    /// Share of the stretches between driveways that get a wall or hedge right behind the curb
    /// (0: none, as up to v5; see [`street::Street::add_curb_walls`]).
    pub curb_walls: f64,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            scenes: 1,
            samples_per_scene: 10,
            lidar: LidarModel::default(),
            annotation_range_m: 80.0,
            min_points_per_box: 1,
            roof: RoofRandomisation::default(),
            car_sizes: CarSizes::default(),
            curb_walls: 0.0,
        }
    }
}

impl SynthConfig {
    /// Checks the numbers a user can give.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |msg: String| Err(SynthError::InvalidConfig(msg));
        if self.scenes == 0 || self.scenes > MAX_SCENES {
            return bad(format!("scenes must be in 1..={MAX_SCENES}, got {}", self.scenes));
        }
        if self.samples_per_scene == 0 || self.samples_per_scene > MAX_SAMPLES_PER_SCENE {
            return bad(format!(
                "samples per scene must be in 1..={MAX_SAMPLES_PER_SCENE} (50 s; real Lyft scenes have 126), got {}",
                self.samples_per_scene
            ));
        }
        let m = &self.lidar;
        if m.elevations_deg.is_empty() || m.elevations_deg.len() > 256 {
            return bad(format!(
                "the LiDAR needs 1..=256 channels, got {}",
                m.elevations_deg.len()
            ));
        }
        if m.elevations_deg.iter().any(|e| !e.is_finite() || e.abs() >= 90.0) {
            return bad("channel elevations must be finite and within ±90°".into());
        }
        if m.azimuth_steps == 0 || m.azimuth_steps > 36_000 {
            return bad(format!(
                "azimuth steps must be in 1..=36000, got {}",
                m.azimuth_steps
            ));
        }
        let positive = [m.max_range_m, m.reference_range_m, self.annotation_range_m];
        if positive.iter().any(|v| !v.is_finite() || *v <= 0.0) {
            return bad("ranges must be finite and positive".into());
        }
        let noise_ok = m.range_noise_m.is_finite() && m.range_noise_m >= 0.0;
        let min_ok = m.min_range_m.is_finite() && m.min_range_m >= 0.0 && m.min_range_m < m.max_range_m;
        if !noise_ok || !min_ok || !(0.0..1.0).contains(&m.dropout) {
            return bad("range noise, minimum range or drop-out out of range".into());
        }
        if !(0.0..=1.0).contains(&m.glass_pass) {
            return bad(format!(
                "glass pass probability must be within 0..=1, got {}",
                m.glass_pass
            ));
        }
        if !(0.0..=1.0).contains(&self.curb_walls) {
            return bad(format!(
                "curb wall share must be within 0..=1, got {}",
                self.curb_walls
            ));
        }
        let jitter = self.roof.height_jitter_m;
        if !jitter.is_finite() || !(0.0..=1.0).contains(&jitter) {
            return bad(format!("roof height jitter must be within 0..=1 m, got {jitter}"));
        }
        if let Some(v) = m.constant_intensity {
            if !v.is_finite() {
                return bad("constant intensity must be finite".into());
            }
        }
        Ok(())
    }
}

/// What [`generate`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSummary {
    /// The version folder holding the 13 tables (`<out>/v1.01-train`).
    pub version_dir: PathBuf,
    /// The map raster (`<out>/maps/map_raster_palo_alto.png`).
    pub map_file: PathBuf,
    pub scenes: usize,
    pub samples: usize,
    /// LiDAR sample_data rows (= .bin files).
    pub sample_data: usize,
    pub annotations: usize,
    pub instances: usize,
    /// Points written, all LiDARs.
    pub points: u64,
    /// Bytes of all files written.
    pub bytes: u64,
}

/// Everything that can go wrong while generating a dataset.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid synth configuration: {0}")]
    InvalidConfig(String),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error("cannot serialise table {path}: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("cannot encode map raster {path}: {source}")]
    Png {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}
