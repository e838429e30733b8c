//! One LiDAR of an Argoverse 2 sweep: the feather file holds both roof LiDARs' points in the ego
//! frame; this picks one LiDAR's points by laser number and moves them back into its own sensor
//! frame, so that the pipeline's extrinsics and α act on them exactly as on a Lyft sweep.
//!
//! Which laser numbers are which LiDAR: 0–31 are `up_lidar`, 32–63 `down_lidar` (the devkit
//! splits them the same way). The geometry says so too: a VLP-32C's laser is a cone of fixed
//! elevation in its own frame, and lasers 0–31 hold their elevation to 0.05° (std) in
//! `up_lidar`'s frame against 0.17° in `down_lidar`'s; tests/data/av2.rs checks it on the real
//! sweeps.

#![deny(clippy::indexing_slicing)]

use super::feather::Feather;
use crate::dataset::error::DatasetError;
use crate::dataset::index::LidarChannel;
use crate::dataset::pointcloud::PointCloud;
use crate::geometry::Pose;

/// Lasers per LiDAR (a Velodyne VLP-32C).
pub const LASERS_PER_LIDAR: u8 = 32;

/// The first laser number of a LiDAR slot: `up_lidar` (LIDAR_TOP's slot) 0, `down_lidar`
/// (LIDAR_FRONT_LEFT's slot) 32. `None` for a slot AV2 does not fill.
pub fn first_laser(channel: LidarChannel) -> Option<u8> {
    match channel {
        LidarChannel::Top => Some(0),
        LidarChannel::FrontLeft => Some(LASERS_PER_LIDAR),
        LidarChannel::FrontRight => None,
    }
}

/// The points of one LiDAR of a decoded sweep, in that LiDAR's sensor frame (`sensor_to_ego` is
/// its calibration, T^e_l). Ring is the laser number within the LiDAR (0–31); intensity 0–255 as
/// stored. Points with a non-finite coordinate are dropped and counted in `dropped`.
pub fn lidar_points(
    sweep: &Feather,
    channel: LidarChannel,
    sensor_to_ego: &Pose,
) -> Result<PointCloud, DatasetError> {
    let mut clouds = split(sweep, &[(channel, *sensor_to_ego)])?;
    Ok(clouds.pop().unwrap_or_default())
}

/// Every LiDAR of `lidars` from one decoded sweep in one pass over its rows (see
/// [`lidar_points`]), in the order given.
pub fn split(sweep: &Feather, lidars: &[(LidarChannel, Pose)]) -> Result<Vec<PointCloud>, DatasetError> {
    let path = sweep.path();
    // Per LiDAR slot of the file (laser / 32): which output it goes to and its ego → sensor
    // transform as an f32 3×4 matrix (the coordinates are float16: f32 loses nothing they hold).
    let mut slots: [Option<(usize, [[f32; 4]; 3])>; 2] = [None; 2];
    for (k, (channel, sensor_to_ego)) in lidars.iter().enumerate() {
        let first = first_laser(*channel).ok_or_else(|| DatasetError::BadColumn {
            path: path.to_path_buf(),
            column: None,
            message: format!("an Argoverse 2 sweep has no {channel} LiDAR"),
        })?;
        let h = sensor_to_ego.inverse().to_homogeneous();
        let m =
            std::array::from_fn(|r| std::array::from_fn(|c| h.get((r, c)).copied().unwrap_or(0.0) as f32));
        if let Some(slot) = slots.get_mut(usize::from(first / LASERS_PER_LIDAR)) {
            *slot = Some((k, m));
        }
    }
    let x = sweep.f32s("x")?;
    let y = sweep.f32s("y")?;
    let z = sweep.f32s("z")?;
    let intensity = sweep.u8s("intensity")?;
    let laser = sweep.u8s("laser_number")?;
    if let Some(i) = laser.iter().position(|&l| l >= 2 * LASERS_PER_LIDAR) {
        return Err(DatasetError::BadColumn {
            path: path.to_path_buf(),
            column: Some("laser_number".to_owned()),
            message: format!(
                "row {i} holds {}; the two VLP-32C of an Argoverse 2 sweep number their lasers 0–63",
                laser.get(i).copied().unwrap_or_default()
            ),
        });
    }
    let mut counts = [0usize; 2];
    for &l in &laser {
        if let Some(c) = counts.get_mut(usize::from(l / LASERS_PER_LIDAR)) {
            *c += 1;
        }
    }
    let mut clouds: Vec<PointCloud> = lidars
        .iter()
        .map(|(channel, _)| {
            let slot = first_laser(*channel).map_or(0, |f| usize::from(f / LASERS_PER_LIDAR));
            PointCloud::with_capacity(counts.get(slot).copied().unwrap_or(0))
        })
        .collect();
    for ((((&x, &y), &z), &i), &l) in x.iter().zip(&y).zip(&z).zip(&intensity).zip(&laser) {
        let slot = l / LASERS_PER_LIDAR;
        let Some(Some((k, m))) = slots.get(usize::from(slot)) else {
            continue;
        };
        let Some(cloud) = clouds.get_mut(*k) else { continue };
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            cloud.dropped += 1;
            continue;
        }
        let [m0, m1, m2] = m;
        let t = |r: &[f32; 4]| r[0] * x + r[1] * y + r[2] * z + r[3];
        cloud.push(
            t(m0),
            t(m1),
            t(m2),
            f32::from(i),
            f32::from(l - slot * LASERS_PER_LIDAR),
        );
    }
    Ok(clouds)
}
