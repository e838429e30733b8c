//! A [`Frame`]: one Lyft sample as the MLOD pipeline sees it — each LiDAR's points in its own
//! sensor frame, the nominal extrinsics T^b_{l_i} into the base frame (LIDAR_TOP's frame, the
//! paper's primary LiDAR), and the ground-truth boxes in the base frame.
//!
//! How it works:
//! - LiDARs are the sample's key-frame `sample_data` rows whose calibrated sensor has modality
//!   `lidar`; the channel comes from `sensor.channel`. LIDAR_TOP is required (it defines the base
//!   frame); LIDAR_FRONT_LEFT / LIDAR_FRONT_RIGHT are auxiliaries when present.
//! - Extrinsics go through the global frame with each sweep's OWN ego pose, so sweeps taken at
//!   slightly different times are handled:
//!   T^b_{l_i} = (T^g_{e,top} · T^e_{top})⁻¹ · T^g_{e,i} · T^e_{l_i}.
//! - Boxes are moved exactly as `lyft_dataset_sdk`'s `get_sample_data` does for the LIDAR_TOP
//!   sweep: translate by −ego.translation, rotate by ego.rotation⁻¹, translate by −cs.translation,
//!   rotate by cs.rotation⁻¹. Centre and FULL orientation quaternion are transformed (the box's
//!   roll/pitch in the sensor frame come from the ego's tilt and the sensor mounting); the yaw is
//!   then the heading of the rotated box x axis, atan2(R₁₀, R₀₀) (the devkits' `quaternion_yaw`).
//!   The full base-frame quaternion is kept in [`GtBox::rotation`] for other conventions.

#![deny(clippy::indexing_slicing)]

use std::path::PathBuf;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use super::categories;
use super::error::DatasetError;
use super::index::{Dataset, LidarChannel};
use super::kitti::EvalRegion;
use super::pointcloud::{parse_points, LoadOptions, PointCloud, PointLayout};
use super::tables::{CalibratedSensor, EgoPose, Record, SampleAnnotation, SampleData};
use crate::geometry::{quat_from_wxyz, Box3d, Pose};

/// Where one LiDAR sweep of a sample is and how it is mounted.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarInfo {
    pub channel: LidarChannel,
    pub sample_data_token: String,
    /// The filename as written in sample_data.json, relative to the dataset root.
    pub filename: String,
    /// The filename resolved against the dataset root (checked to stay inside it).
    pub path: PathBuf,
    /// Microseconds.
    pub timestamp: f64,
    pub ego_pose_token: String,
    pub calibrated_sensor_token: String,
    /// T^e_l: sensor frame → ego frame (calibrated_sensor).
    pub sensor_to_ego: Pose,
    /// T^g_e: ego frame → global frame at this sweep's time (ego_pose).
    pub ego_to_global: Pose,
    /// T^b_l: sensor frame → base frame (LIDAR_TOP). Identity for LIDAR_TOP itself.
    pub extrinsic: Pose,
    /// How its point file is laid out (the dataset's format decides).
    pub layout: PointLayout,
}

impl LidarInfo {
    /// Reads this sweep's file. A missing file is [`DatasetError::MissingPointCloud`] naming the
    /// path and the sample_data token.
    fn read_file(&self) -> Result<Vec<u8>, DatasetError> {
        std::fs::read(&self.path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                DatasetError::MissingPointCloud {
                    path: self.path.clone(),
                    token: self.sample_data_token.clone(),
                }
            } else {
                DatasetError::Io {
                    path: self.path.clone(),
                    source,
                }
            }
        })
    }

    /// Reads and decodes this sweep's Argoverse 2 feather file (every LiDAR of the sweep is in it).
    fn read_av2_sweep(&self) -> Result<super::av2::feather::Feather, DatasetError> {
        super::av2::feather::Feather::parse(self.read_file()?, &self.path)
    }

    /// Reads this sweep's points (`.bin`, or its LiDAR's part of an AV2 sweep). A missing file is
    /// [`DatasetError::MissingPointCloud`] naming the path and the sample_data token.
    pub fn load_points(&self, opts: LoadOptions) -> Result<PointCloud, DatasetError> {
        if self.layout == PointLayout::Av2Sweep {
            return super::av2::sweep::lidar_points(
                &self.read_av2_sweep()?,
                self.channel,
                &self.sensor_to_ego,
            );
        }
        parse_points(&self.read_file()?, &self.path, opts, self.layout)
    }
}

/// One ground-truth box, in the base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct GtBox {
    pub annotation_token: String,
    pub instance_token: String,
    /// Our category name (`car`, `pedestrian`, ...): the source's name mapped by
    /// [`super::categories`], or the source's own name when it has no counterpart.
    pub category: String,
    /// The name as the dataset writes it (`vehicle.car`, `Car`, `car`).
    pub source_category: String,
    /// Centre, size (l, w, h) and yaw in the base frame.
    pub box3d: Box3d,
    /// The full orientation in the base frame (roll and pitch kept), box frame → base frame.
    pub rotation: UnitQuaternion<f64>,
    /// As in the table (`-1` in real Lyft data).
    pub num_lidar_pts: i64,
    /// What the label says of how much of the object is hidden, where the format says it (KITTI:
    /// 0 fully visible, 1 partly occluded, 2 largely occluded, 3 unknown).
    pub occlusion: Option<u8>,
    /// The share of the object outside the image, where the format says it (KITTI, 0–1).
    pub truncation: Option<f32>,
}

impl GtBox {
    /// The box as a detection of its category with score 1 (how evaluation and the GUI match
    /// predictions against it).
    pub fn as_detection(&self) -> crate::geometry::Detection {
        crate::geometry::Detection {
            box3d: self.box3d,
            score: 1.0,
            category: self.category.clone(),
        }
    }
}

/// A sample's LiDAR layout and boxes, without the points.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInfo {
    pub sample_token: String,
    pub scene_token: String,
    /// Microseconds.
    pub timestamp: f64,
    /// LIDAR_TOP; its frame is the base frame.
    pub primary: LidarInfo,
    /// LIDAR_FRONT_LEFT then LIDAR_FRONT_RIGHT, those present.
    pub auxiliaries: Vec<LidarInfo>,
    pub boxes: Vec<GtBox>,
    /// Where evaluation looks, when the format restricts it (KITTI: camera 2's view without its
    /// DontCare regions); `None`: everywhere.
    pub eval_region: Option<EvalRegion>,
    /// Things that did not stop loading (an unknown LiDAR channel, a trimmed file).
    pub warnings: Vec<String>,
}

impl FrameInfo {
    /// Primary first, then the auxiliaries.
    pub fn lidars(&self) -> impl Iterator<Item = &LidarInfo> {
        std::iter::once(&self.primary).chain(self.auxiliaries.iter())
    }
}

/// One LiDAR of a frame: where it is and its points (in its own sensor frame).
#[derive(Debug, Clone, PartialEq)]
pub struct LidarScan {
    pub info: LidarInfo,
    pub points: PointCloud,
}

/// One sample, ready for the pipeline.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub sample_token: String,
    pub scene_token: String,
    /// Microseconds.
    pub timestamp: f64,
    /// LIDAR_TOP; its frame is the base frame.
    pub primary: LidarScan,
    /// LIDAR_FRONT_LEFT then LIDAR_FRONT_RIGHT, those present.
    pub auxiliaries: Vec<LidarScan>,
    /// Ground truth in the base frame.
    pub boxes: Vec<GtBox>,
    /// Where evaluation looks, when the format restricts it (KITTI: camera 2's view without its
    /// DontCare regions); `None`: everywhere.
    pub eval_region: Option<EvalRegion>,
    /// Things that did not stop loading (an unknown LiDAR channel, a trimmed file).
    pub warnings: Vec<String>,
}

impl LidarScan {
    /// A scan built in memory (no dataset behind it): `extrinsic` maps its points into the base
    /// frame; tokens and paths are empty. Useful for tests, benchmarks and non-Lyft data.
    pub fn in_memory(channel: LidarChannel, extrinsic: Pose, points: PointCloud) -> Self {
        Self {
            info: LidarInfo {
                channel,
                sample_data_token: String::new(),
                filename: String::new(),
                path: PathBuf::new(),
                timestamp: 0.0,
                ego_pose_token: String::new(),
                calibrated_sensor_token: String::new(),
                sensor_to_ego: extrinsic,
                ego_to_global: Pose::identity(),
                extrinsic,
                layout: PointLayout::default(),
            },
            points,
        }
    }
}

impl Frame {
    /// A frame built in memory from scans (primary first) and boxes in the base frame.
    pub fn in_memory(
        sample_token: &str,
        primary: LidarScan,
        auxiliaries: Vec<LidarScan>,
        boxes: Vec<GtBox>,
    ) -> Self {
        Self {
            sample_token: sample_token.to_string(),
            scene_token: String::new(),
            timestamp: 0.0,
            primary,
            auxiliaries,
            boxes,
            eval_region: None,
            warnings: Vec::new(),
        }
    }

    /// Primary first, then the auxiliaries.
    pub fn lidars(&self) -> impl Iterator<Item = &LidarScan> {
        std::iter::once(&self.primary).chain(self.auxiliaries.iter())
    }

    /// The LiDAR of a channel, if the sample has it.
    pub fn lidar(&self, channel: LidarChannel) -> Option<&LidarScan> {
        self.lidars().find(|l| l.info.channel == channel)
    }

    /// Every LiDAR's intensities replaced by `v` (`--set-intensity`: real Lyft files hold 100
    /// everywhere).
    pub fn set_intensity(&mut self, v: f32) {
        for scan in std::iter::once(&mut self.primary).chain(self.auxiliaries.iter_mut()) {
            scan.points.intensity.fill(v);
        }
    }

    /// Only LIDAR_TOP.
    pub fn is_single_lidar(&self) -> bool {
        self.auxiliaries.is_empty()
    }

    /// The auxiliary LiDARs this sample lacks (of LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT).
    pub fn missing_auxiliaries(&self) -> Vec<LidarChannel> {
        [LidarChannel::FrontLeft, LidarChannel::FrontRight]
            .into_iter()
            .filter(|c| self.lidar(*c).is_none())
            .collect()
    }

    /// Whether a box counts in evaluation of this frame (always, unless the format restricts
    /// evaluation to a region: KITTI's camera view).
    pub fn evaluates(&self, b: &Box3d) -> bool {
        self.eval_region.as_ref().is_none_or(|r| r.contains(b))
    }

    /// Points kept over all LiDARs.
    pub fn num_points(&self) -> usize {
        self.lidars().map(|l| l.points.len()).sum()
    }
}

/// The yaw pyquaternion's `yaw_pitch_roll[0]` gives for a rotation:
/// atan2(2(wz − xy), 1 − 2(y² + z²)). It is what e.g. mmdetection3d's Lyft converter stores.
/// It equals the heading yaw atan2(R₁₀, R₀₀) used by [`GtBox::box3d`] only for rotations about z;
/// for real Lyft boxes in the LIDAR_TOP frame (tilted by the ego's roll/pitch) they differ by up
/// to about 6e-4 rad.
pub fn pyquaternion_yaw(q: &UnitQuaternion<f64>) -> f64 {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    (2.0 * (w * z - x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// A validated pose from a row's translation and [w, x, y, z] rotation.
fn pose_from_row(
    table: &'static str,
    token: &str,
    translation: [f64; 3],
    rotation: [f64; 4],
) -> Result<Pose, DatasetError> {
    let t = finite3(table, token, "translation", translation)?;
    let q = quat(table, token, "rotation", rotation)?;
    Ok(Isometry3::from_parts(Translation3::from(t), q))
}

fn finite3(
    table: &'static str,
    token: &str,
    field: &'static str,
    v: [f64; 3],
) -> Result<Vector3<f64>, DatasetError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(Vector3::from(v))
    } else {
        Err(DatasetError::NonFinite {
            table,
            token: token.to_owned(),
            field,
            value: v,
        })
    }
}

fn quat(
    table: &'static str,
    token: &str,
    field: &'static str,
    v: [f64; 4],
) -> Result<UnitQuaternion<f64>, DatasetError> {
    quat_from_wxyz(v).ok_or_else(|| DatasetError::BadQuaternion {
        table,
        token: token.to_owned(),
        field,
        value: v,
    })
}

fn dangling(
    table: &'static str,
    token: &str,
    field: &'static str,
    target: &'static str,
    missing: &str,
) -> DatasetError {
    DatasetError::DanglingReference {
        table,
        token: token.to_owned(),
        field,
        target,
        missing: missing.to_owned(),
    }
}

impl Dataset {
    /// The sample's LiDARs, extrinsics and ground-truth boxes, without reading any point cloud.
    pub fn frame_info(&self, sample_token: &str) -> Result<FrameInfo, DatasetError> {
        let t = self.tables();
        let sample = t
            .sample
            .get(sample_token)
            .ok_or_else(|| DatasetError::UnknownSample {
                token: sample_token.to_owned(),
            })?;
        if let Some(issue) = self.sample_issue(sample_token) {
            return Err(issue.to_error());
        }
        let mut warnings = Vec::new();

        // The key-frame LiDAR sweeps, one per known channel.
        let mut found: [Option<(&SampleData, &CalibratedSensor)>; 3] = [None; 3];
        for &i in self.keyframe_rows(sample_token) {
            let Some(sd) = t.sample_data.rows().get(i) else {
                continue;
            };
            let cs = t
                .calibrated_sensor
                .get(&sd.calibrated_sensor_token)
                .ok_or_else(|| {
                    dangling(
                        SampleData::TABLE,
                        &sd.token,
                        "calibrated_sensor_token",
                        CalibratedSensor::TABLE,
                        &sd.calibrated_sensor_token,
                    )
                })?;
            let sensor = t.sensor.get(&cs.sensor_token).ok_or_else(|| {
                dangling(
                    CalibratedSensor::TABLE,
                    &cs.token,
                    "sensor_token",
                    "sensor",
                    &cs.sensor_token,
                )
            })?;
            if sensor.modality != "lidar" {
                continue;
            }
            let Some(channel) = LidarChannel::from_channel(&sensor.channel) else {
                warnings.push(format!(
                    "sample {sample_token}: LiDAR channel {} (sample_data {}) is not LIDAR_TOP, \
                     LIDAR_FRONT_LEFT or LIDAR_FRONT_RIGHT and is ignored",
                    sensor.channel, sd.token
                ));
                continue;
            };
            // `found` has one slot per `LidarChannel` variant, so the discriminant is in bounds.
            #[allow(clippy::indexing_slicing)]
            let slot = &mut found[channel as usize];
            if let Some((first, _)) = slot {
                return Err(DatasetError::DuplicateLidar {
                    sample_token: sample_token.to_owned(),
                    channel: channel.as_str(),
                    first: first.token.clone(),
                    second: sd.token.clone(),
                });
            }
            *slot = Some((sd, cs));
        }
        let [top, left, right] = found;
        let Some(top) = top else {
            return Err(DatasetError::NoLidarTop {
                sample_token: sample_token.to_owned(),
            });
        };

        // Sensor → global for each sweep, with the sweep's own ego pose.
        let lidar = |channel: LidarChannel, (sd, cs): (&SampleData, &CalibratedSensor)| {
            let ego = t.ego_pose.get(&sd.ego_pose_token).ok_or_else(|| {
                dangling(
                    SampleData::TABLE,
                    &sd.token,
                    "ego_pose_token",
                    EgoPose::TABLE,
                    &sd.ego_pose_token,
                )
            })?;
            let sensor_to_ego =
                pose_from_row(CalibratedSensor::TABLE, &cs.token, cs.translation, cs.rotation)?;
            let ego_to_global = pose_from_row(EgoPose::TABLE, &ego.token, ego.translation, ego.rotation)?;
            let path = self.resolve::<SampleData>(&sd.token, &sd.filename)?;
            Ok::<_, DatasetError>(LidarInfo {
                channel,
                sample_data_token: sd.token.clone(),
                filename: sd.filename.clone(),
                path,
                timestamp: sd.timestamp,
                ego_pose_token: sd.ego_pose_token.clone(),
                calibrated_sensor_token: cs.token.clone(),
                sensor_to_ego,
                ego_to_global,
                extrinsic: Pose::identity(),
                layout: self.point_layout(),
            })
        };
        let primary = lidar(LidarChannel::Top, top)?;
        let top_to_global = primary.ego_to_global * primary.sensor_to_ego;
        let global_to_base = top_to_global.inverse();
        let mut auxiliaries = Vec::with_capacity(2);
        for (channel, row) in [(LidarChannel::FrontLeft, left), (LidarChannel::FrontRight, right)] {
            let Some(row) = row else { continue };
            let mut info = lidar(channel, row)?;
            info.extrinsic = global_to_base * info.ego_to_global * info.sensor_to_ego;
            auxiliaries.push(info);
        }

        // Boxes: global → ego (LIDAR_TOP's ego pose) → LIDAR_TOP, as the devkit does.
        let ego_rot_inv = primary.ego_to_global.rotation.inverse();
        let ego_t = primary.ego_to_global.translation.vector;
        let cs_rot_inv = primary.sensor_to_ego.rotation.inverse();
        let cs_t = primary.sensor_to_ego.translation.vector;
        let mut boxes = Vec::with_capacity(self.annotation_rows(sample_token).len());
        for &i in self.annotation_rows(sample_token) {
            let Some(ann) = t.sample_annotation.rows().get(i) else {
                continue;
            };
            let table = SampleAnnotation::TABLE;
            let instance = t.instance.get(&ann.instance_token).ok_or_else(|| {
                dangling(
                    table,
                    &ann.token,
                    "instance_token",
                    "instance",
                    &ann.instance_token,
                )
            })?;
            let category = t.category.get(&instance.category_token).ok_or_else(|| {
                dangling(
                    "instance",
                    &instance.token,
                    "category_token",
                    "category",
                    &instance.category_token,
                )
            })?;
            let center = finite3(table, &ann.token, "translation", ann.translation)?;
            let size = finite3(table, &ann.token, "size", ann.size)?;
            let q_box = quat(table, &ann.token, "rotation", ann.rotation)?;
            let c_ego = ego_rot_inv * (center - ego_t);
            let c_base = cs_rot_inv * (c_ego - cs_t);
            let rotation = cs_rot_inv * (ego_rot_inv * q_box);
            boxes.push(GtBox {
                annotation_token: ann.token.clone(),
                instance_token: ann.instance_token.clone(),
                category: categories::display_name(&category.name),
                source_category: category.name.clone(),
                box3d: Box3d::from_lyft(
                    [c_base.x, c_base.y, c_base.z],
                    [size.x, size.y, size.z],
                    &rotation,
                ),
                rotation,
                num_lidar_pts: ann.num_lidar_pts,
                occlusion: self.label_extras(&ann.token).and_then(|e| e.occlusion),
                truncation: self.label_extras(&ann.token).and_then(|e| e.truncation),
            });
        }

        Ok(FrameInfo {
            sample_token: sample.token.clone(),
            scene_token: sample.scene_token.clone(),
            timestamp: sample.timestamp,
            primary,
            auxiliaries,
            boxes,
            eval_region: self.eval_region(sample_token).cloned(),
            warnings,
        })
    }

    /// The sample with every LiDAR's points (strict: truncated files are errors).
    pub fn frame(&self, sample_token: &str) -> Result<Frame, DatasetError> {
        self.frame_with(sample_token, LoadOptions::default())
    }

    /// The sample with every LiDAR's points, read in parallel. The first failing LiDAR (in
    /// primary, left, right order) is the error.
    pub fn frame_with(&self, sample_token: &str, opts: LoadOptions) -> Result<Frame, DatasetError> {
        let info = self.frame_info(sample_token)?;
        let FrameInfo {
            sample_token,
            scene_token,
            timestamp,
            primary,
            auxiliaries,
            boxes,
            eval_region,
            mut warnings,
        } = info;
        let mut infos = Vec::with_capacity(1 + auxiliaries.len());
        infos.push(primary);
        infos.extend(auxiliaries);
        // An Argoverse 2 sweep holds every LiDAR in one file: decode it once, split in one pass.
        let shared_sweep = infos.first().filter(|first| {
            infos
                .iter()
                .all(|l| l.layout == PointLayout::Av2Sweep && l.path == first.path)
        });
        let clouds: Vec<Result<PointCloud, DatasetError>> = match shared_sweep {
            Some(first) => {
                let lidars: Vec<_> = infos.iter().map(|l| (l.channel, l.sensor_to_ego)).collect();
                super::av2::sweep::split(&first.read_av2_sweep()?, &lidars)?
                    .into_iter()
                    .map(Ok)
                    .collect()
            }
            None => infos.par_iter().map(|l| l.load_points(opts)).collect(),
        };
        let mut scans = Vec::with_capacity(infos.len());
        for (info, cloud) in infos.into_iter().zip(clouds) {
            let points = cloud?;
            if points.trimmed_bytes > 0 {
                warnings.push(format!(
                    "{}: ignored the last {} bytes (size not a multiple of {})",
                    info.path.display(),
                    points.trimmed_bytes,
                    info.layout.point_bytes()
                ));
            }
            scans.push(LidarScan { info, points });
        }
        let mut scans = scans.into_iter();
        let Some(primary) = scans.next() else {
            return Err(DatasetError::NoLidarTop { sample_token });
        };
        Ok(Frame {
            sample_token,
            scene_token,
            timestamp,
            primary,
            auxiliaries: scans.collect(),
            boxes,
            eval_region,
            warnings,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{rpy_to_matrix, yaw_of};

    #[test]
    fn pyquaternion_yaw_equals_heading_yaw_about_z_only() {
        let q = UnitQuaternion::from_matrix(&rpy_to_matrix(0.0, 0.0, 2.5));
        assert!((pyquaternion_yaw(&q) - 2.5).abs() < 1e-12);
        let tilted = UnitQuaternion::from_matrix(&rpy_to_matrix(0.05, 0.02, 2.5));
        let heading = yaw_of(tilted.to_rotation_matrix().matrix());
        assert!((pyquaternion_yaw(&tilted) - heading).abs() > 1e-4);
    }

    #[test]
    fn set_intensity_reaches_every_lidar() {
        let ds = crate::dataset::Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let mut frame = ds.frame(ds.first_sample_token().unwrap()).unwrap();
        assert!(frame.lidars().count() == 3);
        frame.set_intensity(30.0);
        for l in frame.lidars() {
            assert!(!l.points.intensity.is_empty());
            assert!(
                l.points.intensity.iter().all(|v| *v == 30.0),
                "{}",
                l.info.channel.as_str()
            );
        }
    }
}
