//! Integration tests of the dataset layer (`mlod::dataset`). Lyft: the real table excerpt in
//! `tests/fixtures/lyft-real/` (extrinsics and boxes against the official devkit's numbers in
//! `tests/fixtures/devkit_expected/real_boxes.json`), and small synthetic datasets written to a
//! temporary folder with the library's own writers for everything the real excerpt cannot show
//! (points, NaNs, truncated files, missing tables, path traversal, a single-LiDAR sample). KITTI
//! (two real frames in tests/fixtures/kitti) and a nuScenes-style copy come last.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use mlod::dataset::tables::{
    Attribute, CalibratedSensor, Category, EgoPose, Instance, Log, Map, Sample, SampleAnnotation, SampleData,
    Scene, Sensor, Visibility,
};
use mlod::dataset::{
    inspect, list, pyquaternion_yaw, read_bin, write_bin, Dataset, DatasetError, LidarChannel, LoadOptions,
    PointCloud, Table, Tables,
};
use mlod::geometry::{quat_from_wxyz, rpy_to_matrix, yaw_of};
use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};

const REAL_SAMPLE: &str = "199e3146d98e6a2047bafbc222b92f5b67c4640a69b0d1d35b710242de816679";

fn real_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/lyft-real")
}

/// The devkit's boxes of the real fixture (committed: a missing or corrupt file fails the test).
fn devkit_expected() -> serde_json::Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/devkit_expected/real_boxes.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A folder under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        static N: AtomicUsize = AtomicUsize::new(0);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let p = std::env::temp_dir().join(format!(
            "mlod-lyft-test-{tag}-{}-{}-{nanos}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn f64s(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn quat_close(a: &UnitQuaternion<f64>, wxyz: &[f64], tol: f64) -> bool {
    let b = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]));
    a.angle_to(&b) < tol
}

/// Equal JSON, numbers to a relative 1e-15.
fn json_close(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value as V;
    match (a, b) {
        (V::Number(x), V::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-15 * x.abs().max(y.abs())
        }
        (V::Array(x), V::Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| json_close(p, q)),
        (V::Object(x), V::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .zip(y)
                    .all(|((kp, p), (kq, q))| kp == kq && json_close(p, q))
        }
        _ => a == b,
    }
}

// ---------------------------------------------------------------------------------------------
// Synthetic datasets
// ---------------------------------------------------------------------------------------------

/// One LiDAR sweep of a synthetic sample.
struct SynLidar {
    channel: &'static str,
    /// `None`: `lidar/<sample>_<channel>.bin`.
    filename: Option<String>,
    /// Bytes of the .bin; `None`: no file written.
    bin: Option<Vec<u8>>,
    /// T_ego<-sensor as (translation, rotation rpy).
    mount: ([f64; 3], [f64; 3]),
    /// T_global<-ego of this sweep as (translation, yaw).
    ego: ([f64; 3], f64),
}

struct SynBox {
    center: [f64; 3],
    size_wlh: [f64; 3],
    yaw: f64,
    category: &'static str,
}

struct SynSample {
    token: String,
    lidars: Vec<SynLidar>,
    boxes: Vec<SynBox>,
}

fn q_rpy(r: [f64; 3]) -> [f64; 4] {
    let q = UnitQuaternion::from_matrix(&rpy_to_matrix(r[0], r[1], r[2]));
    [q.w, q.i, q.j, q.k]
}

fn bin_of(points: &[[f32; 5]]) -> Vec<u8> {
    points.iter().flatten().flat_map(|v| v.to_le_bytes()).collect()
}

const TOP_MOUNT: ([f64; 3], [f64; 3]) = ([1.197, 0.0, 1.828], [0.0, 0.0226, 3.128]);
const LEFT_MOUNT: ([f64; 3], [f64; 3]) = ([3.473, 0.942, 0.543], [-3.1412, -0.031, -1.508]);
const RIGHT_MOUNT: ([f64; 3], [f64; 3]) = ([3.498, -0.950, 0.547], [3.136, 0.005, 1.623]);

fn lidar(channel: &'static str, points: &[[f32; 5]], ego: ([f64; 3], f64)) -> SynLidar {
    let mount = match channel {
        "LIDAR_TOP" => TOP_MOUNT,
        "LIDAR_FRONT_LEFT" => LEFT_MOUNT,
        _ => RIGHT_MOUNT,
    };
    SynLidar {
        channel,
        filename: None,
        bin: Some(bin_of(points)),
        mount,
        ego,
    }
}

/// Writes a dataset of one scene per entry of `scenes`; returns the root. Samples are written to
/// sample.json in reverse order so that scene order must come from the prev/next chain.
fn write_dataset(root: &Path, scenes: &[Vec<SynSample>]) -> PathBuf {
    write_dataset_in(root, scenes, "v1.01-train")
}

/// [`write_dataset`] into the version folder `version`, with every category its boxes name.
fn write_dataset_in(root: &Path, scenes: &[Vec<SynSample>], version: &str) -> PathBuf {
    let mut categories = vec!["car", "pedestrian", "truck"];
    for b in scenes.iter().flatten().flat_map(|s| &s.boxes) {
        if !categories.contains(&b.category) {
            categories.push(b.category);
        }
    }
    let category: Vec<Category> = categories
        .iter()
        .map(|c| Category {
            description: String::new(),
            token: format!("cat-{c}"),
            name: (*c).into(),
        })
        .collect();
    let channels = ["LIDAR_TOP", "LIDAR_FRONT_LEFT", "LIDAR_FRONT_RIGHT", "CAM_FRONT"];
    let sensor: Vec<Sensor> = channels
        .iter()
        .map(|c| Sensor {
            modality: if c.starts_with("CAM") { "camera" } else { "lidar" }.into(),
            channel: (*c).into(),
            token: format!("sensor-{c}"),
        })
        .collect();
    let mut scene = Vec::new();
    let mut sample = Vec::new();
    let mut sample_data = Vec::new();
    let mut calibrated_sensor = Vec::new();
    let mut ego_pose = Vec::new();
    let mut sample_annotation = Vec::new();
    let mut instance = Vec::new();
    let mut ts = 1.0e15;
    for (si, samples) in scenes.iter().enumerate() {
        let scene_token = format!("scene-{si}");
        for (k, s) in samples.iter().enumerate() {
            ts += 200_000.0;
            let prev = if k == 0 {
                String::new()
            } else {
                samples[k - 1].token.clone()
            };
            let next = samples.get(k + 1).map(|n| n.token.clone()).unwrap_or_default();
            sample.push(Sample {
                next,
                prev,
                token: s.token.clone(),
                scene_token: scene_token.clone(),
                timestamp: ts,
            });
            for l in &s.lidars {
                let sd_token = format!("sd-{}-{}", s.token, l.channel);
                let cs_token = format!("cs-{}-{}", s.token, l.channel);
                let ep_token = format!("ep-{}-{}", s.token, l.channel);
                calibrated_sensor.push(CalibratedSensor {
                    sensor_token: format!("sensor-{}", l.channel),
                    rotation: q_rpy(l.mount.1),
                    camera_intrinsic: vec![],
                    translation: l.mount.0,
                    token: cs_token.clone(),
                });
                ego_pose.push(EgoPose {
                    rotation: q_rpy([0.0, 0.0, l.ego.1]),
                    translation: l.ego.0,
                    token: ep_token.clone(),
                    timestamp: ts,
                });
                let filename = l
                    .filename
                    .clone()
                    .unwrap_or_else(|| format!("lidar/{}_{}.bin", s.token, l.channel));
                if let Some(bytes) = &l.bin {
                    let p = root.join(&filename);
                    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                    std::fs::write(&p, bytes).unwrap();
                }
                sample_data.push(SampleData {
                    is_key_frame: true,
                    prev: String::new(),
                    fileformat: "bin".into(),
                    ego_pose_token: ep_token,
                    timestamp: ts,
                    next: String::new(),
                    token: sd_token,
                    sample_token: s.token.clone(),
                    filename,
                    calibrated_sensor_token: cs_token,
                    width: None,
                    height: None,
                });
            }
            // A camera row and a non-key-frame LiDAR row, which the loader must skip.
            if let Some(l0) = s.lidars.first() {
                let cs_token = format!("cs-{}-cam", s.token);
                calibrated_sensor.push(CalibratedSensor {
                    sensor_token: "sensor-CAM_FRONT".into(),
                    rotation: [0.5, -0.5, 0.5, -0.5],
                    camera_intrinsic: vec![
                        vec![1000.0, 0.0, 960.0],
                        vec![0.0, 1000.0, 540.0],
                        vec![0.0, 0.0, 1.0],
                    ],
                    translation: [1.5, 0.0, 1.6],
                    token: cs_token.clone(),
                });
                for (key, fmt) in [(true, "jpeg"), (false, "bin")] {
                    sample_data.push(SampleData {
                        is_key_frame: key,
                        prev: String::new(),
                        fileformat: fmt.into(),
                        ego_pose_token: format!("ep-{}-{}", s.token, l0.channel),
                        timestamp: ts + 50_000.0,
                        next: String::new(),
                        token: format!("sd-{}-extra-{fmt}", s.token),
                        sample_token: s.token.clone(),
                        filename: format!("other/{}.{fmt}", s.token),
                        calibrated_sensor_token: if key {
                            cs_token.clone()
                        } else {
                            format!("cs-{}-{}", s.token, l0.channel)
                        },
                        width: key.then_some(1920),
                        height: key.then_some(1080),
                    });
                }
            }
            for (bi, b) in s.boxes.iter().enumerate() {
                let ann_token = format!("ann-{}-{bi}", s.token);
                let inst_token = format!("inst-{}-{bi}", s.token);
                instance.push(Instance {
                    last_annotation_token: ann_token.clone(),
                    category_token: format!("cat-{}", b.category),
                    token: inst_token.clone(),
                    first_annotation_token: ann_token.clone(),
                    nbr_annotations: 1,
                });
                sample_annotation.push(SampleAnnotation {
                    token: ann_token,
                    num_lidar_pts: 7,
                    size: b.size_wlh,
                    sample_token: s.token.clone(),
                    rotation: q_rpy([0.0, 0.0, b.yaw]),
                    prev: String::new(),
                    translation: b.center,
                    num_radar_pts: 0,
                    attribute_tokens: vec![],
                    next: String::new(),
                    instance_token: inst_token,
                    visibility_token: "4".into(),
                });
            }
        }
        scene.push(Scene {
            description: String::new(),
            log_token: "log-0".into(),
            name: format!("synthetic-{si}"),
            first_sample_token: samples.first().map(|s| s.token.clone()).unwrap_or_default(),
            last_sample_token: samples.last().map(|s| s.token.clone()).unwrap_or_default(),
            nbr_samples: samples.len() as u32,
            token: scene_token,
        });
    }
    sample.reverse();
    let tables = Tables {
        scene: Table::new(scene).unwrap(),
        sample: Table::new(sample).unwrap(),
        sample_data: Table::new(sample_data).unwrap(),
        calibrated_sensor: Table::new(calibrated_sensor).unwrap(),
        sensor: Table::new(sensor).unwrap(),
        ego_pose: Table::new(ego_pose).unwrap(),
        sample_annotation: Table::new(sample_annotation).unwrap(),
        instance: Table::new(instance).unwrap(),
        category: Table::new(category).unwrap(),
        attribute: Table::new(vec![Attribute {
            description: String::new(),
            token: "attr-0".into(),
            name: "object_action_parked".into(),
        }])
        .unwrap(),
        visibility: Table::new(vec![Visibility {
            level: "v80-100".into(),
            description: "visibility of whole object is between 80 and 100%".into(),
            token: "4".into(),
        }])
        .unwrap(),
        log: Table::new(vec![Log {
            date_captured: "2024-01-01".into(),
            location: "Nowhere".into(),
            token: "log-0".into(),
            vehicle: "syn".into(),
            logfile: String::new(),
        }])
        .unwrap(),
        map: Table::new(vec![Map {
            log_tokens: vec!["log-0".into()],
            token: "map-0".into(),
            filename: "maps/map.png".into(),
            category: "semantic_prior".into(),
        }])
        .unwrap(),
    };
    tables.write(&root.join(version)).unwrap();
    root.to_path_buf()
}

fn some_points(n: usize, seed: f32) -> Vec<[f32; 5]> {
    (0..n)
        .map(|i| {
            let a = i as f32 * 0.37 + seed;
            [
                10.0 * a.cos(),
                10.0 * a.sin(),
                0.1 * (i % 7) as f32 - 0.3,
                (i % 255) as f32,
                (i % 40) as f32,
            ]
        })
        .collect()
}

fn three_lidar_sample(token: &str, egos: [([f64; 3], f64); 3]) -> SynSample {
    SynSample {
        token: token.into(),
        lidars: vec![
            lidar("LIDAR_TOP", &some_points(50, 0.0), egos[0]),
            lidar("LIDAR_FRONT_LEFT", &some_points(30, 1.0), egos[1]),
            lidar("LIDAR_FRONT_RIGHT", &some_points(20, 2.0), egos[2]),
        ],
        boxes: vec![],
    }
}

const EGO: ([f64; 3], f64) = ([100.0, 200.0, -18.0], 0.7);

// ---------------------------------------------------------------------------------------------
// Other formats: KITTI object (tests/fixtures/kitti: two real frames, see its NOTICE.md) and a
// nuScenes-style copy written here.

fn kitti_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/kitti")
}

/// The fixture's labels moved to the LiDAR frame by an independent conversion (numpy:
/// inv(R0_rect · Tr_velo_to_cam) · (x, y − h/2, z, 1), yaw −ry − π/2), DontCare lines left out.
/// (frame, our category, centre, size l w h, yaw).
type ExpectedBox = (&'static str, &'static str, [f64; 3], [f64; 3], f64);

const KITTI_EXPECTED: [ExpectedBox; 4] = [
    (
        "000000",
        "pedestrian",
        [8.7364, -1.8681, -0.6548],
        [1.2, 0.48, 1.89],
        -1.5808,
    ),
    (
        "000001",
        "truck",
        [69.7099, -0.4626, 0.5835],
        [12.34, 2.63, 2.85],
        -0.0108,
    ),
    (
        "000001",
        "car",
        [58.7721, 16.5508, -0.8412],
        [3.69, 1.87, 1.67],
        -3.1408,
    ),
    (
        "000001",
        "bicycle",
        [46.1156, -4.5819, -0.0316],
        [2.02, 0.6, 1.86],
        -0.0208,
    ),
];
mod sample_data;
mod synth;

mod av2;
mod kitti_nuscenes;
mod lyft_real;
mod lyft_written;
