//! Loader benchmarks (targets from issue 3): load one three-LiDAR frame of 150 000 points
//! (70k + 40k + 40k, target ≤ 20 ms) and open the tables of a 2000-sample dataset (target ≤ 2 s);
//! and a real Argoverse 2 sweep (two LiDARs, 99k points) and its log's index, against them.
//! Both Lyft datasets are synthetic, written once in the setup into a temporary folder with the
//! library's own writers, and removed at the end.

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mlod::dataset::tables::{
    Attribute, CalibratedSensor, Category, EgoPose, Instance, Log, Map, Sample, SampleAnnotation, SampleData,
    Scene, Sensor, Visibility,
};
use mlod::dataset::{write_bin, Dataset, PointCloud, Table, Tables};
use mlod::geometry::rpy_to_matrix;
use nalgebra::UnitQuaternion;

const CHANNELS: [(&str, [f64; 3], [f64; 3], usize); 3] = [
    ("LIDAR_TOP", [1.197, 0.0, 1.828], [0.0, 0.0226, 3.128], 70_000),
    (
        "LIDAR_FRONT_LEFT",
        [3.473, 0.942, 0.543],
        [-3.1412, -0.031, -1.508],
        40_000,
    ),
    (
        "LIDAR_FRONT_RIGHT",
        [3.498, -0.950, 0.547],
        [3.136, 0.005, 1.623],
        40_000,
    ),
];

fn q_rpy(r: [f64; 3]) -> [f64; 4] {
    let q = UnitQuaternion::from_matrix(&rpy_to_matrix(r[0], r[1], r[2]));
    [q.w, q.i, q.j, q.k]
}

fn token(kind: &str, i: usize) -> String {
    // Lyft tokens are 64 hex characters; keep the same length.
    format!("{kind:0>8}{i:056x}")
}

/// Writes a dataset of `scenes` × `per_scene` samples, each with three key-frame LiDAR sweeps,
/// three non-key-frame sweeps and `boxes` annotations; `points` writes `.bin` files for the first
/// sample only (other sweeps name files that are not written: table opening never reads them).
fn write_dataset(root: &Path, scenes: usize, per_scene: usize, boxes: usize, points: bool) {
    let mut scene = Vec::new();
    let mut sample = Vec::new();
    let mut sample_data = Vec::new();
    let mut calibrated_sensor = Vec::new();
    let mut ego_pose = Vec::new();
    let mut sample_annotation = Vec::new();
    let mut instance = Vec::new();
    let sensor: Vec<Sensor> = CHANNELS
        .iter()
        .enumerate()
        .map(|(k, c)| Sensor {
            modality: "lidar".into(),
            channel: c.0.into(),
            token: token("sensor", k),
        })
        .collect();
    let category = vec![Category {
        description: String::new(),
        token: token("cat", 0),
        name: "car".into(),
    }];
    let mut n_sd = 0;
    for sc in 0..scenes {
        for (k, c) in CHANNELS.iter().enumerate() {
            calibrated_sensor.push(CalibratedSensor {
                sensor_token: token("sensor", k),
                rotation: q_rpy(c.2),
                camera_intrinsic: vec![],
                translation: c.1,
                token: token("cs", sc * 3 + k),
            });
        }
        for b in 0..boxes {
            instance.push(Instance {
                last_annotation_token: token("ann", (sc * per_scene + per_scene - 1) * boxes + b),
                category_token: token("cat", 0),
                token: token("inst", sc * boxes + b),
                first_annotation_token: token("ann", sc * per_scene * boxes + b),
                nbr_annotations: per_scene as u32,
            });
        }
        for j in 0..per_scene {
            let s = sc * per_scene + j;
            let ts = 1.5e15 + s as f64 * 200_000.0;
            sample.push(Sample {
                next: if j + 1 < per_scene {
                    token("sample", s + 1)
                } else {
                    String::new()
                },
                prev: if j > 0 {
                    token("sample", s - 1)
                } else {
                    String::new()
                },
                token: token("sample", s),
                scene_token: token("scene", sc),
                timestamp: ts,
            });
            for (key, dt) in [(true, 0.0), (false, 100_000.0)] {
                for (k, c) in CHANNELS.iter().enumerate() {
                    let i = n_sd;
                    n_sd += 1;
                    let x = s as f64 * 2.0 + dt * 1e-5;
                    ego_pose.push(EgoPose {
                        rotation: q_rpy([0.01, -0.02, 0.3 + 1e-3 * s as f64]),
                        translation: [x, 0.5 * x, -18.0],
                        token: token("ep", i),
                        timestamp: ts + dt,
                    });
                    sample_data.push(SampleData {
                        is_key_frame: key,
                        prev: String::new(),
                        fileformat: "bin".into(),
                        ego_pose_token: token("ep", i),
                        timestamp: ts + dt,
                        next: String::new(),
                        token: token("sd", i),
                        sample_token: token("sample", s),
                        filename: format!("lidar/host-a000_lidar{k}_{i}.bin"),
                        calibrated_sensor_token: token("cs", sc * 3 + k),
                        width: None,
                        height: None,
                    });
                    if points && s == 0 && key {
                        let n = c.3;
                        let mut cloud = PointCloud::with_capacity(n);
                        for p in 0..n {
                            let a = p as f32 * 0.0137;
                            let r = 3.0 + (p % 997) as f32 * 0.07;
                            cloud.push(
                                r * a.cos(),
                                r * a.sin(),
                                (p % 40) as f32 * 0.05 - 1.5,
                                20.0,
                                (p % 40) as f32,
                            );
                        }
                        write_bin(&root.join(format!("lidar/host-a000_lidar{k}_{i}.bin")), &cloud)
                            .expect("write .bin");
                    }
                }
            }
            for b in 0..boxes {
                let a = s * boxes + b;
                let x = s as f64 * 2.0 + (b as f64 - boxes as f64 / 2.0) * 3.0;
                sample_annotation.push(SampleAnnotation {
                    token: token("ann", a),
                    num_lidar_pts: -1,
                    size: [1.9, 4.6, 1.6],
                    sample_token: token("sample", s),
                    rotation: q_rpy([0.0, 0.0, 0.1 * b as f64]),
                    prev: if j > 0 {
                        token("ann", a - boxes)
                    } else {
                        String::new()
                    },
                    translation: [x, 0.5 * x + 7.0, -17.2],
                    num_radar_pts: 0,
                    attribute_tokens: vec![token("attr", 0)],
                    next: if j + 1 < per_scene {
                        token("ann", a + boxes)
                    } else {
                        String::new()
                    },
                    instance_token: token("inst", sc * boxes + b),
                    visibility_token: "4".into(),
                });
            }
        }
        scene.push(Scene {
            description: String::new(),
            log_token: token("log", 0),
            name: format!("synthetic-{sc}"),
            first_sample_token: token("sample", sc * per_scene),
            last_sample_token: token("sample", sc * per_scene + per_scene - 1),
            nbr_samples: per_scene as u32,
            token: token("scene", sc),
        });
    }
    let tables = Tables {
        scene: Table::new(scene).expect("scene"),
        sample: Table::new(sample).expect("sample"),
        sample_data: Table::new(sample_data).expect("sample_data"),
        calibrated_sensor: Table::new(calibrated_sensor).expect("calibrated_sensor"),
        sensor: Table::new(sensor).expect("sensor"),
        ego_pose: Table::new(ego_pose).expect("ego_pose"),
        sample_annotation: Table::new(sample_annotation).expect("sample_annotation"),
        instance: Table::new(instance).expect("instance"),
        category: Table::new(category).expect("category"),
        attribute: Table::new(vec![Attribute {
            description: String::new(),
            token: token("attr", 0),
            name: "object_action_parked".into(),
        }])
        .expect("attribute"),
        visibility: Table::new(vec![Visibility {
            level: "v80-100".into(),
            description: String::new(),
            token: "4".into(),
        }])
        .expect("visibility"),
        log: Table::new(vec![Log {
            date_captured: "2019-05-01".into(),
            location: "Synthetic".into(),
            token: token("log", 0),
            vehicle: "a000".into(),
            logfile: String::new(),
        }])
        .expect("log"),
        map: Table::new(vec![Map {
            log_tokens: vec![token("log", 0)],
            token: token("map", 0),
            filename: "maps/map.png".into(),
            category: "semantic_prior".into(),
        }])
        .expect("map"),
    };
    tables.write(&root.join("v1.01-train")).expect("write tables");
}

struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn temp_dir(tag: &str) -> TempDir {
    let p = std::env::temp_dir().join(format!("mlod-lyft-bench-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(&p).expect("temp dir");
    TempDir(p)
}

fn bench(c: &mut Criterion) {
    // One sample with 70k + 40k + 40k points and 30 boxes.
    let frame_dir = temp_dir("frame");
    write_dataset(&frame_dir.0, 1, 1, 30, true);
    let ds = Dataset::open(&frame_dir.0).expect("open frame dataset");
    let sample = ds.first_sample_token().expect("a sample").to_owned();
    let n_points = ds.frame(&sample).expect("frame").num_points();
    assert_eq!(n_points, 150_000);
    let mut g = c.benchmark_group("lyft_frame");
    g.throughput(Throughput::Elements(n_points as u64));
    g.bench_function("frame_3lidar_150k", |b| {
        b.iter(|| ds.frame(black_box(&sample)).expect("frame"))
    });
    g.finish();
    // Tables only: extrinsics and 30 boxes, no point cloud read.
    c.bench_function("lyft_frame/frame_info_30_boxes", |b| {
        b.iter(|| ds.frame_info(black_box(&sample)).expect("info"))
    });

    // 20 scenes × 100 samples; 6 sweeps and 30 boxes per sample.
    let tables_dir = temp_dir("tables");
    write_dataset(&tables_dir.0, 20, 100, 30, false);
    let size: u64 = std::fs::read_dir(tables_dir.0.join("v1.01-train"))
        .expect("read dir")
        .filter_map(Result::ok)
        .filter_map(|e| e.metadata().ok())
        .map(|m| m.len())
        .sum();
    eprintln!("2000-sample tables: {:.1} MB of JSON", size as f64 / 1e6);
    let mut g = c.benchmark_group("lyft_tables");
    g.sample_size(10);
    g.throughput(Throughput::Bytes(size));
    g.bench_function("open_2000_samples", |b| {
        b.iter(|| {
            let d = Dataset::open(black_box(&tables_dir.0)).expect("open");
            assert_eq!(d.tables().sample.len(), 2000);
            d
        })
    });
    g.finish();

    // The real Argoverse 2 sweep of tests/fixtures/av2: one feather file, two LiDARs (51 785 +
    // 47 444 points), decoded, split by laser and moved into each sensor frame; per point it
    // should cost what a Lyft frame does.
    let av2 = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/av2");
    let ds = Dataset::open(&av2).expect("open the AV2 fixture");
    let sweep = ds.first_sample_token().expect("a sweep").to_owned();
    let n = ds.frame(&sweep).expect("AV2 frame").num_points();
    let mut g = c.benchmark_group("av2_frame");
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function("sweep_2lidar_99k", |b| {
        b.iter(|| ds.frame(black_box(&sweep)).expect("frame"))
    });
    g.finish();
    let path = av2.join("val/7fab2350-7eaf-3b7e-a39d-6937a4c1bede/sensors/lidar/315966265259836000.feather");
    let mut g = c.benchmark_group("av2_frame");
    g.bench_function("decode_feather", |b| {
        b.iter(|| mlod::dataset::av2::feather::Feather::read(black_box(&path)).expect("decode"))
    });
    let sweep_file = mlod::dataset::av2::feather::Feather::read(&path).expect("decode");
    let up = ds.frame(&sweep).expect("frame").primary.info.sensor_to_ego;
    g.bench_function("split_up_lidar", |b| {
        b.iter(|| {
            mlod::dataset::av2::sweep::lidar_points(
                black_box(&sweep_file),
                mlod::dataset::LidarChannel::Top,
                &up,
            )
            .expect("points")
        })
    });
    g.finish();
    let mut g = c.benchmark_group("av2_log");
    g.sample_size(10);
    g.bench_function("open_log_11k_cuboids", |b| {
        b.iter(|| Dataset::open(black_box(&av2)).expect("open"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
