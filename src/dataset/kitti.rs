//! The KITTI 3D object benchmark as it lies on disk, read into the same index as a Lyft or
//! nuScenes dataset: each frame becomes a sample with one LiDAR (LIDAR_TOP, the Velodyne HDL-64E),
//! so that everything downstream reads a KITTI frame exactly as it reads a Lyft one.
//!
//! ```text
//! kitti/                    Dataset::open(kitti) opens training/ (or testing/ if alone)
//!   training/               Dataset::open(kitti/training)
//!     velodyne/000000.bin   float32 × 4: x, y, z (LiDAR frame), reflectance 0–1
//!     velodyne_reduced/     the same, cropped to the camera's view (used when velodyne/ is absent)
//!     label_2/000000.txt    type trunc occ alpha x1 y1 x2 y2 h w l x y z ry [score], camera frame
//!     calib/000000.txt      P0–P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo
//! ```
//!
//! How it works:
//! - The base frame is the LiDAR frame (x forward, y left, z up). The in-memory tables place the
//!   LiDAR [`SENSOR_HEIGHT_M`] above an ego frame on the road with identity ego poses, as Lyft
//!   places LIDAR_TOP, so the generic frame code moves boxes back to the LiDAR frame exactly.
//! - A label's bottom centre (x, y, z) in the rectified camera frame becomes the box centre
//!   (x, y − h/2, z) (camera y points down), moved to the LiDAR frame by (R0_rect · Tr_velo_to_cam)⁻¹;
//!   size (l, w, h); yaw = −ry − π/2 (the convention of KITTI's devkit and OpenPCDet).
//! - Categories keep KITTI's names in the tables (`Car`, `Cyclist`, …) and are mapped onto ours by
//!   [`super::categories`]. `DontCare` lines are not boxes: they are 2D regions of the image.
//! - Labels exist only inside the front camera's view. Each sample therefore carries an
//!   [`EvalRegion`]: evaluation ignores predictions whose centre projects outside the image of
//!   camera 2, and predictions whose projected 2D box lies more than half inside a `DontCare`
//!   region, as KITTI's own evaluation ignores them (neither true nor false positives).
//! - Reflectance 0–1 becomes intensity 0–255. KITTI has no ring column: the ring is recovered from
//!   the scan order (each ring is one turn starting at azimuth 0), or −1 when the order does not
//!   allow it (a cropped `velodyne_reduced` file).
//! - A malformed label or calib file, or a missing calib, is an error of that frame only, naming
//!   the file and line; every other frame still loads.

#![deny(clippy::indexing_slicing)]

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix3x4, Matrix4, UnitQuaternion, Vector3, Vector4};

pub use super::extras::FrameIssue;
pub use super::region::{EvalRegion, RegionVerdict};

use super::error::DatasetError;
use super::tables::{
    Attribute, CalibratedSensor, Category, EgoPose, Instance, Log, Map, Sample, SampleAnnotation, SampleData,
    Scene, Sensor, Table, Tables, Visibility,
};
use crate::geometry::Box3d;

/// Height of KITTI's Velodyne above the road (KITTI's setup description: 1.73 m).
pub const SENSOR_HEIGHT_M: f64 = 1.73;

/// Image size of camera 2 used for the field of view when no image is at hand (the most common
/// KITTI image size; frames vary between 1224 × 370 and 1242 × 376 pixels).
pub const IMAGE_WIDTH: f64 = 1242.0;
pub const IMAGE_HEIGHT: f64 = 375.0;

/// A KITTI calib file: the parts needed to move labels into the LiDAR frame and to project into
/// camera 2.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiCalib {
    /// Projection of the rectified camera frame into image 2.
    pub p2: Matrix3x4<f64>,
    /// Rectifying rotation of camera 0.
    pub r0_rect: Matrix3<f64>,
    /// LiDAR frame → camera 0 frame.
    pub tr_velo_to_cam: Matrix3x4<f64>,
}

impl KittiCalib {
    /// Parses a calib file (`key: v v v …` per line). `P2`, `R0_rect` (or `R_rect`) and
    /// `Tr_velo_to_cam` (or `Tr_velo_cam`) are required; other keys are ignored.
    pub fn parse(text: &str, path: &Path) -> Result<Self, DatasetError> {
        let mut values: HashMap<&str, (usize, Vec<f64>)> = HashMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let Some((key, rest)) = line.split_once(':') else {
                return Err(calib_error(
                    path,
                    i + 1,
                    format!("expected `key: values`, got {line:?}"),
                ));
            };
            let mut nums = Vec::new();
            for (j, tok) in rest.split_whitespace().enumerate() {
                match tok.parse::<f64>() {
                    Ok(v) if v.is_finite() => nums.push(v),
                    _ => {
                        return Err(calib_error(
                            path,
                            i + 1,
                            format!("{}: value {} is {tok:?}, not a finite number", key.trim(), j + 1),
                        ))
                    }
                }
            }
            values.insert(key.trim(), (i + 1, nums));
        }
        let get = |names: &[&str], n: usize| -> Result<Vec<f64>, DatasetError> {
            let Some((line, v)) = names.iter().find_map(|k| values.get(k)) else {
                return Err(calib_error(path, 0, format!("no {} line", names.join(" or "))));
            };
            if v.len() != n {
                return Err(calib_error(
                    path,
                    *line,
                    format!("{} has {} values, expected {n}", names.join(" / "), v.len()),
                ));
            }
            Ok(v.clone())
        };
        let p2 = Matrix3x4::from_row_slice(&get(&["P2"], 12)?);
        let r0_rect = Matrix3::from_row_slice(&get(&["R0_rect", "R_rect"], 9)?);
        let tr_velo_to_cam = Matrix3x4::from_row_slice(&get(&["Tr_velo_to_cam", "Tr_velo_cam"], 12)?);
        let calib = Self {
            p2,
            r0_rect,
            tr_velo_to_cam,
        };
        if calib.rect_to_velo().is_none() {
            return Err(calib_error(
                path,
                0,
                "R0_rect · Tr_velo_to_cam is not invertible".to_owned(),
            ));
        }
        Ok(calib)
    }

    /// LiDAR frame → rectified camera frame: R0_rect · Tr_velo_to_cam, as a 4 × 4 matrix.
    pub fn velo_to_rect(&self) -> Matrix4<f64> {
        let mut r0 = Matrix4::identity();
        r0.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.r0_rect);
        let mut tr = Matrix4::identity();
        tr.fixed_view_mut::<3, 4>(0, 0).copy_from(&self.tr_velo_to_cam);
        r0 * tr
    }

    /// Rectified camera frame → LiDAR frame; `None` when the calibration is singular.
    pub fn rect_to_velo(&self) -> Option<Matrix4<f64>> {
        self.velo_to_rect().try_inverse()
    }

    /// LiDAR frame → image 2 pixels (homogeneous 3 × 4).
    pub fn velo_to_image(&self) -> Matrix3x4<f64> {
        self.p2 * self.velo_to_rect()
    }
}

fn calib_error(path: &Path, line: usize, message: String) -> DatasetError {
    DatasetError::BadFile {
        path: path.to_path_buf(),
        line,
        message,
    }
}

/// One line of a KITTI label file.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiLabel {
    /// `Car`, `Van`, `Truck`, `Pedestrian`, `Person_sitting`, `Cyclist`, `Tram`, `Misc`, `DontCare`.
    pub kind: String,
    pub truncated: f64,
    pub occluded: i64,
    pub alpha: f64,
    /// 2D box in image 2: left, top, right, bottom (pixels).
    pub bbox: [f64; 4],
    /// Height, width, length (m).
    pub dims_hwl: [f64; 3],
    /// Bottom centre in the rectified camera frame (m).
    pub location: [f64; 3],
    /// Rotation about the camera's y axis (rad).
    pub rotation_y: f64,
    /// Detection score (result files only).
    pub score: Option<f64>,
}

const LABEL_FIELDS: [&str; 15] = [
    "type",
    "truncated",
    "occluded",
    "alpha",
    "bbox left",
    "bbox top",
    "bbox right",
    "bbox bottom",
    "height",
    "width",
    "length",
    "x",
    "y",
    "z",
    "rotation_y",
];

impl KittiLabel {
    /// `DontCare`: a 2D region, not an object.
    pub fn is_dont_care(&self) -> bool {
        self.kind == "DontCare"
    }

    /// The box in the LiDAR frame: centre (x, y − h/2, z) moved by `rect_to_velo`, yaw −ry − π/2.
    pub fn to_box(&self, rect_to_velo: &Matrix4<f64>) -> Box3d {
        let [h, w, l] = self.dims_hwl;
        let [x, y, z] = self.location;
        let c = rect_to_velo * Vector4::new(x, y - 0.5 * h, z, 1.0);
        let yaw = crate::geometry::wrap_angle(-self.rotation_y - std::f64::consts::FRAC_PI_2);
        Box3d::new([c.x, c.y, c.z], [l, w, h], yaw)
    }
}

/// Parses a label file: 15 fields per line (16 with a score). A bad line is an error naming the
/// file, the line and the field.
pub fn parse_labels(text: &str, path: &Path) -> Result<Vec<KittiLabel>, DatasetError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.is_empty() {
            continue;
        }
        let bad = |message: String| DatasetError::BadFile {
            path: path.to_path_buf(),
            line: i + 1,
            message,
        };
        if fields.len() != 15 && fields.len() != 16 {
            return Err(bad(format!(
                "{} fields, expected 15 (type, truncated, occluded, alpha, 2D box, h w l, x y z, rotation_y) \
                 or 16 (with a score)",
                fields.len()
            )));
        }
        let mut v = [0.0f64; 15];
        for (k, (slot, tok)) in v.iter_mut().zip(fields.iter()).enumerate().skip(1) {
            *slot = match tok.parse::<f64>() {
                Ok(x) if x.is_finite() => x,
                _ => {
                    let name = LABEL_FIELDS.get(k).copied().unwrap_or("value");
                    return Err(bad(format!(
                        "field {} ({name}) is {tok:?}, not a finite number",
                        k + 1
                    )));
                }
            };
        }
        let score = match fields.get(15) {
            Some(tok) => match tok.parse::<f64>() {
                Ok(x) if x.is_finite() => Some(x),
                _ => return Err(bad(format!("field 16 (score) is {tok:?}, not a finite number"))),
            },
            None => None,
        };
        let kind = fields.first().copied().unwrap_or_default().to_owned();
        let [_, truncated, occluded, alpha, x1, y1, x2, y2, h, w, l, x, y, z, ry] = v;
        let label = KittiLabel {
            kind,
            truncated,
            occluded: occluded as i64,
            alpha,
            bbox: [x1, y1, x2, y2],
            dims_hwl: [h, w, l],
            location: [x, y, z],
            rotation_y: ry,
            score,
        };
        let positive = h > 0.0 && w > 0.0 && l > 0.0;
        if !label.is_dont_care() && !positive {
            return Err(bad(format!(
                "{}: size h w l = {h} {w} {l} is not positive",
                label.kind
            )));
        }
        out.push(label);
    }
    Ok(out)
}

/// A KITTI split folder found on disk.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiLayout {
    /// The split folder (`training/`): table filenames are relative to it.
    pub split_dir: PathBuf,
    /// `velodyne` or `velodyne_reduced`.
    pub points_dir: &'static str,
    /// A note for the user (which split or point folder was chosen and why).
    pub note: Option<String>,
}

/// The KITTI split at `path`: `path` itself when it holds `velodyne/` (or `velodyne_reduced/`),
/// else `path/training` (preferred) or `path/testing`, also below `path/object/`.
pub fn find_layout(path: &Path) -> Option<KittiLayout> {
    let points_dir = |d: &Path| -> Option<&'static str> {
        ["velodyne", "velodyne_reduced"]
            .into_iter()
            .find(|p| d.join(p).is_dir())
    };
    if let Some(p) = points_dir(path) {
        return Some(KittiLayout {
            split_dir: path.to_path_buf(),
            points_dir: p,
            note: (p == "velodyne_reduced").then(|| {
                "KITTI: velodyne/ is absent; reading velodyne_reduced/ (points cropped to the camera's view)"
                    .to_owned()
            }),
        });
    }
    for base in [path.to_path_buf(), path.join("object")] {
        let training = base.join("training");
        let testing = base.join("testing");
        for (split, other) in [(&training, &testing), (&testing, &training)] {
            if let Some(p) = points_dir(split) {
                let mut layout = KittiLayout {
                    split_dir: split.clone(),
                    points_dir: p,
                    note: None,
                };
                if points_dir(other).is_some() {
                    layout.note = Some(format!(
                        "KITTI: opened {}; pass {} to open the other split",
                        split.display(),
                        other.display()
                    ));
                }
                return Some(layout);
            }
        }
    }
    None
}

/// What [`open`] builds: the tables, and per sample its evaluation region or the problem that
/// stops it loading.
pub struct KittiIndex {
    pub tables: Tables,
    /// Per annotation token: the label's occlusion and truncation.
    pub extras: HashMap<String, super::extras::LabelExtras>,
    pub regions: HashMap<String, EvalRegion>,
    pub issues: HashMap<String, FrameIssue>,
    pub notes: Vec<String>,
}

fn read_text(path: &Path) -> Result<Option<String>, DatasetError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(Some(String::from_utf8_lossy(&bytes).into_owned())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(DatasetError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Reads a KITTI split's frame list, calibs and labels into in-memory tables (one scene, one
/// sample per frame in frame-id order, LIDAR_TOP only).
pub fn open(layout: &KittiLayout) -> Result<KittiIndex, DatasetError> {
    let split = &layout.split_dir;
    let points = split.join(layout.points_dir);
    let entries = std::fs::read_dir(&points).map_err(|source| DatasetError::Io {
        path: points.clone(),
        source,
    })?;
    let mut frames: Vec<String> = entries
        .filter_map(Result::ok)
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_suffix(".bin").map(str::to_owned)
        })
        .filter(|id| !id.is_empty())
        .collect();
    frames.sort();
    if frames.is_empty() {
        return Err(DatasetError::NoSamples { path: points });
    }
    let mut notes: Vec<String> = layout.note.iter().cloned().collect();
    let has_labels = split.join("label_2").is_dir();
    if !has_labels {
        notes.push(format!(
            "KITTI: {} has no label_2/ folder: the frames have no ground truth",
            split.display()
        ));
    }
    let split_name = split
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "kitti".to_owned());
    let scene_token = format!("kitti-{split_name}");
    let log_token = "kitti-log".to_owned();
    let sensor_token = "kitti-velodyne".to_owned();

    let mut regions = HashMap::new();
    let mut issues = HashMap::new();
    let mut extras = HashMap::new();
    let mut samples = Vec::with_capacity(frames.len());
    let mut sample_data = Vec::with_capacity(frames.len());
    let mut calibrated = Vec::with_capacity(frames.len());
    let mut ego = Vec::with_capacity(frames.len());
    let mut annotations = Vec::new();
    let mut instances = Vec::new();
    let mut categories: BTreeMap<String, String> = BTreeMap::new();

    for (k, id) in frames.iter().enumerate() {
        let timestamp = k as f64 * 1e5;
        let prev = k
            .checked_sub(1)
            .and_then(|p| frames.get(p))
            .cloned()
            .unwrap_or_default();
        let next = frames.get(k + 1).cloned().unwrap_or_default();
        samples.push(Sample {
            next: next.clone(),
            prev: prev.clone(),
            token: id.clone(),
            scene_token: scene_token.clone(),
            timestamp,
        });
        let cs_token = format!("{id}-calibrated_sensor");
        sample_data.push(SampleData {
            is_key_frame: true,
            prev: if prev.is_empty() {
                prev.clone()
            } else {
                format!("{prev}-lidar")
            },
            fileformat: "bin".to_owned(),
            ego_pose_token: format!("{id}-ego_pose"),
            timestamp,
            next: if next.is_empty() {
                next.clone()
            } else {
                format!("{next}-lidar")
            },
            token: format!("{id}-lidar"),
            sample_token: id.clone(),
            filename: format!("{}/{id}.bin", layout.points_dir),
            calibrated_sensor_token: cs_token.clone(),
            width: None,
            height: None,
        });
        calibrated.push(CalibratedSensor {
            sensor_token: sensor_token.clone(),
            rotation: [1.0, 0.0, 0.0, 0.0],
            camera_intrinsic: Vec::new(),
            translation: [0.0, 0.0, SENSOR_HEIGHT_M],
            token: cs_token,
        });
        ego.push(EgoPose {
            rotation: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0, 0.0, 0.0],
            token: format!("{id}-ego_pose"),
            timestamp,
        });

        // Calib and labels: a problem stays with this frame.
        let calib_path = split.join("calib").join(format!("{id}.txt"));
        let calib = match read_text(&calib_path)? {
            Some(text) => KittiCalib::parse(&text, &calib_path),
            None => Err(DatasetError::BadFile {
                path: calib_path.clone(),
                line: 0,
                message: format!(
                    "frame {id}: the calib file is missing (it is needed to place the labels and the camera's view)"
                ),
            }),
        };
        let calib = match calib {
            Ok(c) => c,
            Err(e) => {
                issues.insert(id.clone(), FrameIssue::from(e));
                continue;
            }
        };
        let Some(rect_to_velo) = calib.rect_to_velo() else {
            continue;
        };
        let label_path = split.join("label_2").join(format!("{id}.txt"));
        let labels = if has_labels {
            match read_text(&label_path)? {
                Some(text) => match parse_labels(&text, &label_path) {
                    Ok(l) => l,
                    Err(e) => {
                        issues.insert(id.clone(), FrameIssue::from(e));
                        continue;
                    }
                },
                None => {
                    issues.insert(
                        id.clone(),
                        FrameIssue {
                            path: label_path.clone(),
                            line: 0,
                            message: format!("frame {id}: the label file is missing"),
                        },
                    );
                    continue;
                }
            }
        } else {
            Vec::new()
        };
        let mut dont_care = Vec::new();
        for (j, label) in labels.iter().enumerate() {
            if label.is_dont_care() {
                dont_care.push(label.bbox);
                continue;
            }
            let b = label.to_box(&rect_to_velo);
            let cat_token = categories
                .entry(label.kind.clone())
                .or_insert_with(|| format!("kitti-category-{}", label.kind))
                .clone();
            let ann_token = format!("{id}-{j}");
            let inst_token = format!("{id}-{j}-instance");
            extras.insert(
                ann_token.clone(),
                super::extras::LabelExtras {
                    occlusion: u8::try_from(label.occluded).ok(),
                    truncation: Some(label.truncated as f32),
                },
            );
            let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), b.yaw);
            annotations.push(SampleAnnotation {
                token: ann_token.clone(),
                num_lidar_pts: -1,
                size: b.size_wlh(),
                sample_token: id.clone(),
                rotation: [q.w, q.i, q.j, q.k],
                prev: String::new(),
                translation: [b.center[0], b.center[1], b.center[2] + SENSOR_HEIGHT_M],
                num_radar_pts: 0,
                attribute_tokens: Vec::new(),
                next: String::new(),
                instance_token: inst_token.clone(),
                visibility_token: String::new(),
            });
            instances.push(Instance {
                last_annotation_token: ann_token.clone(),
                category_token: cat_token,
                token: inst_token,
                first_annotation_token: ann_token,
                nbr_annotations: 1,
            });
        }
        regions.insert(
            id.clone(),
            EvalRegion {
                projection: calib.velo_to_image(),
                width: IMAGE_WIDTH,
                height: IMAGE_HEIGHT,
                dont_care,
            },
        );
    }

    let scene = Scene {
        description: format!("KITTI object {split_name} ({})", split.display()),
        log_token: log_token.clone(),
        name: scene_token.clone(),
        first_sample_token: frames.first().cloned().unwrap_or_default(),
        last_sample_token: frames.last().cloned().unwrap_or_default(),
        nbr_samples: u32::try_from(frames.len()).unwrap_or(u32::MAX),
        token: scene_token,
    };
    let tables = Tables {
        scene: Table::new(vec![scene])?,
        sample: Table::new(samples)?,
        sample_data: Table::new(sample_data)?,
        calibrated_sensor: Table::new(calibrated)?,
        sensor: Table::new(vec![Sensor {
            modality: "lidar".to_owned(),
            channel: "LIDAR_TOP".to_owned(),
            token: sensor_token,
        }])?,
        ego_pose: Table::new(ego)?,
        sample_annotation: Table::new(annotations)?,
        instance: Table::new(instances)?,
        category: Table::new(
            categories
                .into_iter()
                .map(|(name, token)| Category {
                    description: "KITTI object class".to_owned(),
                    token,
                    name,
                })
                .collect(),
        )?,
        attribute: Table::new(Vec::<Attribute>::new())?,
        visibility: Table::new(Vec::<Visibility>::new())?,
        log: Table::new(vec![Log {
            date_captured: String::new(),
            location: "Karlsruhe".to_owned(),
            token: log_token,
            vehicle: "kitti".to_owned(),
            logfile: String::new(),
        }])?,
        map: Table::new(Vec::<Map>::new())?,
    };
    Ok(KittiIndex {
        tables,
        extras,
        regions,
        issues,
        notes,
    })
}

/// Ring indices recovered from the scan order of a full KITTI sweep: the Velodyne driver writes
/// one ring after another, each a full turn that starts at azimuth 0 (straight ahead) and goes
/// counter-clockwise, so a new ring begins where the azimuth crosses from negative to
/// non-negative. `None` when the count is not a plausible beam count (16–128), e.g. for a cloud
/// cropped to the camera's view.
pub fn rings_from_scan_order(x: &[f32], y: &[f32]) -> Option<Vec<f32>> {
    let mut rings = Vec::with_capacity(x.len());
    let mut ring = 0u32;
    let mut prev: Option<f32> = None;
    for (&px, &py) in x.iter().zip(y) {
        let az = py.atan2(px);
        if let Some(p) = prev {
            if p < 0.0 && az >= 0.0 && (az - p) < 1.0 {
                ring += 1;
            }
        }
        prev = Some(az);
        rings.push(ring as f32);
    }
    let count = ring + 1;
    (16..=128).contains(&count).then_some(rings)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CALIB: &str = "P2: 7.070493e+02 0 6.040814e+02 4.575831e+01 0 7.070493e+02 1.805066e+02 -3.454157e-01 0 0 1 4.981016e-03\n\
R0_rect: 9.999128e-01 1.009263e-02 -8.511932e-03 -1.012729e-02 9.999406e-01 -4.037671e-03 8.470675e-03 4.123522e-03 9.999556e-01\n\
Tr_velo_to_cam: 6.927964e-03 -9.999722e-01 -2.757829e-03 -2.457729e-02 -1.162982e-03 2.749836e-03 -9.999955e-01 -6.127237e-02 9.999753e-01 6.931141e-03 -1.143899e-03 -3.321029e-01\n";

    #[test]
    fn identity_calib_box_by_hand() {
        // With identity R0 and a pure axis swap for Tr (x_cam = -y_velo, y_cam = -z_velo,
        // z_cam = x_velo), the box centre is hand-computable.
        let text = "P2: 1 0 0 0 0 1 0 0 0 0 1 0\nR0_rect: 1 0 0 0 1 0 0 0 1\n\
                    Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n";
        let calib = KittiCalib::parse(text, Path::new("c.txt")).unwrap();
        let labels = parse_labels(
            "Car 0.00 0 -1.0 10 20 30 40 1.5 1.6 3.9 2.0 1.7 20.0 0.3\n",
            Path::new("l.txt"),
        )
        .unwrap();
        let b = labels[0].to_box(&calib.rect_to_velo().unwrap());
        // camera (2, 1.7 - 0.75, 20) → LiDAR (20, -2, -0.95)
        assert!((b.center[0] - 20.0).abs() < 1e-12);
        assert!((b.center[1] + 2.0).abs() < 1e-12);
        assert!((b.center[2] + 0.95).abs() < 1e-12);
        assert_eq!(b.size_lwh, [3.9, 1.6, 1.5]);
        assert!((b.yaw - (-0.3 - std::f64::consts::FRAC_PI_2)).abs() < 1e-12);
    }

    #[test]
    fn real_calib_moves_a_label_as_openpcdet_does() {
        let calib = KittiCalib::parse(CALIB, Path::new("000000.txt")).unwrap();
        // The pedestrian of frame 000000 (h 1.89 at x 1.84, y 1.47, z 8.41).
        let l = &parse_labels(
            "Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01\n",
            Path::new("000000.txt"),
        )
        .unwrap()[0];
        let b = l.to_box(&calib.rect_to_velo().unwrap());
        // Independent: solve R0·Tr·p = c with the numbers above (computed with numpy).
        let expect = [8.73636, -1.86806, -0.65479];
        for (a, e) in b.center.iter().zip(expect) {
            assert!((a - e).abs() < 1e-4, "{:?} vs {expect:?}", b.center);
        }
        // It lies inside camera 2's view and in front.
        let region = EvalRegion {
            projection: calib.velo_to_image(),
            width: IMAGE_WIDTH,
            height: IMAGE_HEIGHT,
            dont_care: vec![],
        };
        assert_eq!(region.verdict(&b), RegionVerdict::Inside);
        let behind = Box3d::new([-10.0, 0.0, -1.0], [4.0, 1.8, 1.5], 0.0);
        assert_eq!(region.verdict(&behind), RegionVerdict::OutsideView);
        let side = Box3d::new([2.0, 15.0, -1.0], [4.0, 1.8, 1.5], 0.0);
        assert_eq!(region.verdict(&side), RegionVerdict::OutsideView);
        // A DontCare region covering the pedestrian's image box ignores it.
        let covered = EvalRegion {
            dont_care: vec![[600.0, 100.0, 900.0, 375.0]],
            ..region.clone()
        };
        assert_eq!(covered.verdict(&b), RegionVerdict::DontCare);
        // A small DontCare region beside it does not.
        let beside = EvalRegion {
            dont_care: vec![[0.0, 0.0, 50.0, 50.0]],
            ..region
        };
        assert_eq!(beside.verdict(&b), RegionVerdict::Inside);
    }

    #[test]
    fn malformed_labels_and_calibs_name_file_line_and_field() {
        let p = Path::new("label_2/000007.txt");
        let cases = [
            ("Car 0 0 0 1 2 3 4 1.5 1.6 3.9 2.0 1.7\n", "13 fields"),
            ("Car 0 0 0 1 2 3 4 1.5 1.6 3.9 2.0 abc 20 0.1\n", "field 13 (y)"),
            ("Car 0 0 0 1 2 3 4 1.5 nan 3.9 2.0 1 20 0.1\n", "field 10 (width)"),
            ("Car 0 0 0 1 2 3 4 1.5 0 3.9 2.0 1 20 0.1\n", "not positive"),
            ("Car 0 0 0 1 2 3 4 1.5 1 3.9 2.0 1 20 0.1 x\n", "score"),
        ];
        for (text, want) in cases {
            let msg = parse_labels(&format!("\n{text}"), p).unwrap_err().to_string();
            assert!(
                msg.contains("000007.txt") && msg.contains(":2") && msg.contains(want),
                "{msg}"
            );
        }
        // DontCare lines with -1 sizes are fine.
        let dc = parse_labels("DontCare -1 -1 -10 1 2 3 4 -1 -1 -1 -1000 -1000 -1000 -10\n", p).unwrap();
        assert!(dc[0].is_dont_care());

        let c = Path::new("calib/000007.txt");
        let no_p2 = CALIB.lines().skip(1).collect::<Vec<_>>().join("\n");
        let msg = KittiCalib::parse(&no_p2, c).unwrap_err().to_string();
        assert!(msg.contains("000007.txt") && msg.contains("no P2"), "{msg}");
        let short = CALIB.replace("R0_rect: 9.999128e-01 ", "R0_rect: ");
        let msg = KittiCalib::parse(&short, c).unwrap_err().to_string();
        assert!(msg.contains("R0_rect") && msg.contains("8 values"), "{msg}");
        let bad = CALIB.replace("4.575831e+01", "x");
        let msg = KittiCalib::parse(&bad, c).unwrap_err().to_string();
        assert!(msg.contains(":1") && msg.contains("P2"), "{msg}");
        let msg = KittiCalib::parse("garbage line\n", c).unwrap_err().to_string();
        assert!(msg.contains("key: values"), "{msg}");
        let singular = "P2: 1 0 0 0 0 1 0 0 0 0 1 0\nR0_rect: 0 0 0 0 0 0 0 0 0\nTr_velo_to_cam: 1 0 0 0 0 1 0 0 0 0 1 0\n";
        let msg = KittiCalib::parse(singular, c).unwrap_err().to_string();
        assert!(msg.contains("not invertible"), "{msg}");
    }

    #[test]
    fn rings_follow_the_scan_order() {
        // Three turns of 8 points from azimuth 0 counter-clockwise, then a short cloud.
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for _ in 0..20 {
            for k in 0..8 {
                let a = k as f32 * std::f32::consts::TAU / 8.0 + 0.01;
                x.push(a.cos());
                y.push(a.sin());
            }
        }
        let r = rings_from_scan_order(&x, &y).unwrap();
        assert_eq!(r.first(), Some(&0.0));
        assert_eq!(r.last(), Some(&19.0));
        assert!(rings_from_scan_order(&x[..24], &y[..24]).is_none());
    }
}
