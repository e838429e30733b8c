//! Argoverse 2: the reader against values computed independently from the files (numpy on the
//! same feather files, read by pyarrow: tests/fixtures/av2/README.md), the laser split checked by
//! geometry, and bad files (written here with the arrow crate) named by file and column.

use std::sync::Arc;

use arrow_array::{ArrayRef, Float32Array, Float64Array, Int32Array, RecordBatch, StringArray, UInt8Array};
use mlod::dataset::av2::feather::Feather;
use mlod::dataset::{Dataset, DatasetError, DatasetFormat, LidarChannel};

use super::*;

const LOG: &str = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede";
const SWEEP: &str = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede_315966265259836000";

fn av2_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/av2")
}

fn log_dir() -> PathBuf {
    av2_root().join("val").join(LOG)
}

fn close3(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
    a.iter().zip(&b).all(|(x, y)| (x - y).abs() < tol)
}

fn point(c: &PointCloud, i: usize) -> [f64; 3] {
    [f64::from(c.x[i]), f64::from(c.y[i]), f64::from(c.z[i])]
}

#[test]
fn root_split_and_log_folders_open_the_same_two_lidar_sweep() {
    for path in [av2_root(), av2_root().join("val"), log_dir()] {
        let ds = Dataset::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(ds.format(), DatasetFormat::Av2);
        assert_eq!(ds.sample_tokens(), [SWEEP]);
        assert_eq!(ds.format().lidar_name(LidarChannel::Top), "up_lidar");
        assert_eq!(ds.format().lidar_name(LidarChannel::FrontLeft), "down_lidar");
    }
}

#[test]
fn points_per_lidar_and_positions_equal_numpy_on_the_same_file() {
    let ds = Dataset::open(av2_root()).unwrap();
    let f = ds.frame(SWEEP).unwrap();
    // laser_number < 32: 51 785 points; ≥ 32: 47 444 (numpy), none dropped.
    assert_eq!(f.primary.info.channel, LidarChannel::Top);
    assert_eq!(f.primary.points.len(), 51_785);
    assert_eq!(f.auxiliaries.len(), 1);
    let down = &f.auxiliaries[0];
    assert_eq!(down.info.channel, LidarChannel::FrontLeft);
    assert_eq!(down.points.len(), 47_444);
    assert_eq!(f.primary.points.dropped + down.points.dropped, 0);
    // The 11th up_lidar point of the file (row 10) in the base (= up_lidar) frame.
    assert!(close3(
        point(&f.primary.points, 10),
        [-6.171409716117084, 5.820351480471216, -0.91434578125],
        2e-5
    ));
    // The 11th down_lidar point (row 2192, laser 57): its sensor frame, ring and base frame.
    let p = point(&down.points, 10);
    assert!(
        close3(
            p,
            [10.498512267627344, 10.0201710381016, -1.3564595325279902],
            2e-5
        ),
        "{p:?}"
    );
    assert_eq!(down.points.ring[10], 25.0);
    let b = down.info.extrinsic * Point3::from(p);
    assert!(close3(
        [b.x, b.y, b.z],
        [8.395555728653825, -11.82929310201477, 1.256064375],
        2e-5
    ));
    // down_lidar sits 0.115 m under up_lidar (the factory calibration).
    let t = down.info.extrinsic.translation.vector;
    assert!((t.z + 0.115).abs() < 2e-3, "{t}");
    // The ego pose at the sweep's timestamp (city_SE3_egovehicle row).
    let ego = f.primary.info.ego_to_global;
    assert!(quat_close(
        &ego.rotation,
        &[
            0.9599138553892335,
            -0.007445827138736332,
            -0.02152280217162115,
            -0.2793684285610658
        ],
        1e-12
    ));
    assert!(close3(
        ego.translation.vector.into(),
        [5223.81375744143, 2385.3730591883254, 69.06973410393208],
        1e-9
    ));
}

/// Per laser, the elevation angle is constant in the LiDAR's own frame (a VLP-32C's laser is a
/// cone): the median over lasers of its spread is small in the right frame and 3× larger in the
/// other LiDAR's frame. This is what says lasers 0–31 are up_lidar's.
#[test]
fn each_lidars_lasers_are_cones_in_its_own_frame() {
    let ds = Dataset::open(av2_root()).unwrap();
    let f = ds.frame(SWEEP).unwrap();
    let down = &f.auxiliaries[0];
    let up_to_down = down.info.extrinsic.inverse();
    let spread = |c: &PointCloud, to: &mlod::geometry::Pose| {
        let mut per_laser: Vec<Vec<f64>> = vec![Vec::new(); 32];
        for i in 0..c.len() {
            let p = to * Point3::from(point(c, i));
            if p.coords.norm() > 5.0 {
                per_laser[c.ring[i] as usize].push(p.z.atan2(p.x.hypot(p.y)).to_degrees());
            }
        }
        let mut stds: Vec<f64> = per_laser
            .iter()
            .filter(|v| v.len() > 10)
            .map(|v| {
                let m = v.iter().sum::<f64>() / v.len() as f64;
                (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
            })
            .collect();
        stds.sort_by(f64::total_cmp);
        stds[stds.len() / 2]
    };
    let id = mlod::geometry::Pose::identity();
    let up_own = spread(&f.primary.points, &id);
    let up_other = spread(&f.primary.points, &up_to_down);
    let down_own = spread(&down.points, &id);
    let down_other = spread(&down.points, &down.info.extrinsic);
    assert!(up_own < 0.08 && down_own < 0.08, "{up_own} {down_own}");
    assert!(up_other > 0.12 && down_other > 0.12, "{up_other} {down_other}");
}

#[test]
fn cuboids_become_boxes_in_the_base_frame_with_our_names() {
    let ds = Dataset::open(av2_root()).unwrap();
    let f = ds.frame(SWEEP).unwrap();
    assert_eq!(f.boxes.len(), 81);
    assert_eq!(f.boxes.iter().filter(|b| b.category == "car").count(), 44);
    assert!(f
        .boxes
        .iter()
        .all(|b| b.category != "car" || b.source_category == "REGULAR_VEHICLE"));
    // The nearest car (track d5bc0f50…): its eight corners from numpy (box pose in the ego
    // frame, then the inverse of up_lidar's calibration).
    let car = f
        .boxes
        .iter()
        .find(|b| b.instance_token.ends_with("d5bc0f50-ee6c-4794-89ed-114eaa0ddc69"))
        .unwrap();
    assert_eq!(car.num_lidar_pts, 959);
    let expected = [
        [-4.243518372799908, -1.4305160673836654, -0.2934911468091894],
        [-4.243518372799908, -1.4305160673836654, -1.9180639007154394],
        [-4.2628150369527855, -3.46910720212957, -0.2934911468091894],
        [-4.2628150369527855, -3.46910720212957, -1.9180639007154394],
        [-8.950338763812393, -1.385962782144053, -0.2934911468091894],
        [-8.950338763812393, -1.385962782144053, -1.9180639007154394],
        [-8.96963542796527, -3.4245539168899586, -0.2934911468091894],
        [-8.96963542796527, -3.4245539168899586, -1.9180639007154394],
    ];
    let ours = car.box3d.corners();
    for e in expected {
        assert!(
            ours.iter().any(|c| close3(*c, e, 1e-4)),
            "corner {e:?} not in {ours:?}"
        );
    }
    let unmapped: Vec<String> = ds.unmapped_categories().into_iter().map(|u| u.name).collect();
    assert!(unmapped.contains(&"BOLLARD".to_owned()), "{unmapped:?}");
}

/// A copy of the fixture log under `dir/<name>`.
fn copy_log(dir: &Path, name: &str) -> PathBuf {
    let to = dir.join(name);
    for rel in [
        "annotations.feather",
        "city_SE3_egovehicle.feather",
        "calibration/egovehicle_SE3_sensor.feather",
        "sensors/lidar/315966265259836000.feather",
    ] {
        let p = to.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::copy(log_dir().join(rel), &p).unwrap();
    }
    to
}

#[test]
fn a_log_without_calibration_is_named_and_the_others_still_open() {
    let tmp = TempDir::new("av2-nocalib");
    copy_log(tmp.path(), "good");
    let bad = copy_log(tmp.path(), "nocalib");
    std::fs::remove_file(bad.join("calibration/egovehicle_SE3_sensor.feather")).unwrap();
    let ds = Dataset::open(tmp.path()).unwrap();
    assert_eq!(ds.sample_tokens().len(), 2);
    assert!(ds.frame("good_315966265259836000").is_ok());
    let err = ds.frame("nocalib_315966265259836000").unwrap_err().to_string();
    assert!(
        err.contains("egovehicle_SE3_sensor.feather") && err.contains("missing"),
        "{err}"
    );
    assert!(
        ds.notes().iter().any(|n| n.contains("nocalib")),
        "{:?}",
        ds.notes()
    );
}

fn write_feather(path: &Path, columns: Vec<(&str, ArrayRef)>) {
    let batch = RecordBatch::try_from_iter(columns).unwrap();
    let file = std::fs::File::create(path).unwrap();
    let opts = arrow_ipc::writer::IpcWriteOptions::default()
        .try_with_compression(Some(arrow_ipc::CompressionType::LZ4_FRAME))
        .unwrap();
    let mut w = arrow_ipc::writer::FileWriter::try_new_with_options(file, &batch.schema(), opts).unwrap();
    w.write(&batch).unwrap();
    w.finish().unwrap();
}

fn sweep_columns(x: ArrayRef, laser: Vec<u8>) -> Vec<(&'static str, ArrayRef)> {
    let n = laser.len();
    vec![
        ("x", x),
        ("y", Arc::new(Float32Array::from(vec![1.0f32; n]))),
        ("z", Arc::new(Float32Array::from(vec![0.5f32; n]))),
        ("intensity", Arc::new(UInt8Array::from(vec![7u8; n]))),
        ("laser_number", Arc::new(UInt8Array::from(laser))),
        ("offset_ns", Arc::new(Int32Array::from(vec![0; n]))),
    ]
}

#[test]
fn bad_sweeps_are_errors_naming_the_file_and_the_column() {
    let tmp = TempDir::new("av2-bad");
    let log = copy_log(tmp.path(), "log");
    let sweep = log.join("sensors/lidar/315966265259836000.feather");
    let ds = Dataset::open(&log).unwrap();
    let load = || ds.frame("log_315966265259836000");

    // A written sweep of float32 columns reads (NaN points dropped and counted).
    let x: ArrayRef = Arc::new(Float32Array::from(vec![3.0, f32::NAN, 4.0, 5.0]));
    write_feather(&sweep, sweep_columns(x, vec![0, 1, 40, 63]));
    let f = load().unwrap();
    assert_eq!((f.primary.points.len(), f.primary.points.dropped), (1, 1));
    assert_eq!(f.auxiliaries[0].points.len(), 2);

    let expect_err = |what: &str, column: Option<&str>, needle: &str| {
        let err = load().unwrap_err();
        let DatasetError::BadColumn {
            path,
            column: c,
            message,
        } = &err
        else {
            panic!("{what}: {err}");
        };
        assert_eq!(path, &sweep, "{what}");
        assert_eq!(c.as_deref(), column, "{what}: {err}");
        assert!(message.contains(needle), "{what}: {err}");
        assert!(err.to_string().contains("315966265259836000.feather"), "{err}");
    };
    // A missing column.
    let mut cols = sweep_columns(Arc::new(Float32Array::from(vec![1.0f32])), vec![0]);
    cols.retain(|(n, _)| *n != "laser_number");
    write_feather(&sweep, cols);
    expect_err("missing column", Some("laser_number"), "missing");
    // A wrong type.
    write_feather(
        &sweep,
        sweep_columns(Arc::new(Int32Array::from(vec![1])), vec![0]),
    );
    expect_err(
        "wrong type",
        Some("x"),
        "expected float16 or float32, found Int32",
    );
    // A laser number past the two LiDARs.
    write_feather(
        &sweep,
        sweep_columns(Arc::new(Float32Array::from(vec![1.0f32])), vec![70]),
    );
    expect_err("laser 70", Some("laser_number"), "0–63");
    // A truncated file.
    let real = std::fs::read(log_dir().join("sensors/lidar/315966265259836000.feather")).unwrap();
    std::fs::write(&sweep, &real[..real.len() / 2]).unwrap();
    expect_err("truncated", None, "not a readable feather");
}

#[test]
fn a_nan_in_the_calibration_names_its_column() {
    let tmp = TempDir::new("av2-badcal");
    let log = copy_log(tmp.path(), "log");
    let cal = log.join("calibration/egovehicle_SE3_sensor.feather");
    let col = |v: f64| -> ArrayRef { Arc::new(Float64Array::from(vec![v, v])) };
    write_feather(
        &cal,
        vec![
            (
                "sensor_name",
                Arc::new(StringArray::from(vec!["up_lidar", "down_lidar"])) as ArrayRef,
            ),
            ("qw", col(1.0)),
            ("qx", col(0.0)),
            ("qy", col(0.0)),
            ("qz", col(0.0)),
            ("tx_m", col(f64::NAN)),
            ("ty_m", col(0.0)),
            ("tz_m", col(1.6)),
        ],
    );
    let ds = Dataset::open(&log).unwrap();
    let err = ds.frame("log_315966265259836000").unwrap_err().to_string();
    assert!(
        err.contains("egovehicle_SE3_sensor.feather") && err.contains("column tx_m"),
        "{err}"
    );
}

/// Cut and corrupted copies of a real sweep decode to an error or to columns, never a panic.
#[test]
fn corrupted_sweeps_never_panic() {
    let real = std::fs::read(log_dir().join("sensors/lidar/315966265259836000.feather")).unwrap();
    let mut inputs: Vec<Vec<u8>> = (1..40).map(|k| real[..real.len() * k / 40].to_vec()).collect();
    for k in 0..60usize {
        let mut v = real.clone();
        let at = (k * 7919 * 131) % v.len();
        v[at] ^= 0x5a;
        inputs.push(v);
    }
    let mut decoded = 0;
    for bytes in inputs {
        let r = std::panic::catch_unwind(|| {
            if let Ok(f) = Feather::parse(bytes, Path::new("x.feather")) {
                let _ = (f.f32s("x"), f.u8s("laser_number"), f.u8s("intensity"));
                true
            } else {
                false
            }
        });
        decoded += usize::from(r.expect("no panic"));
    }
    assert!(decoded > 0, "a flipped byte in the data is still a file");
}

/// An AV2 sweep fused at α = 0.04 and exported as PLY and PCD reads back point for point: both
/// LiDARs, their tr(Ξ), and down_lidar in LiDAR-Left's slot.
#[test]
fn an_exported_av2_sweep_reads_back() {
    use mlod::export::{encode, read, ExportOptions, Format};
    use mlod::pipeline::{fuse, FuseParams};
    let ds = Dataset::open(av2_root()).unwrap();
    let f = ds.frame(SWEEP).unwrap();
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(0.04, 0).unwrap(),
        ..Default::default()
    };
    let cloud = fuse(&f, &params).unwrap();
    for format in [Format::Ply, Format::Pcd] {
        let opts = ExportOptions {
            format,
            covariance: None,
            comment: "av2 fixture",
        };
        let back = read(&encode(&cloud, &opts).unwrap()).unwrap();
        assert_eq!(back.len(), 99_229);
        assert_eq!(
            (back.x.clone(), back.y.clone(), back.z.clone()),
            (cloud.x.clone(), cloud.y.clone(), cloud.z.clone())
        );
        assert_eq!(back.trace, cloud.trace);
        let down = back
            .lidar
            .iter()
            .filter(|&&l| mlod::export::lidar_channel(l) == Some(LidarChannel::FrontLeft))
            .count();
        assert_eq!(down, 47_444);
    }
}
