//! What each fuzz target does with its input, shared by the libFuzzer targets in
//! `fuzz/fuzz_targets/` and by the corpus replay in `tests/fuzz_replay.rs`.
//!
//! Every function takes arbitrary bytes, turns them into the files the program reads (written to
//! a scratch folder, since the parsers take paths), runs the parser and what the program does
//! next with a parse that succeeds, and checks the promises that hold whatever the input:
//! no panic (the fuzzer's oracle), no read outside the folder the user pointed at, and a written
//! file that reads back as what was written. Multi-file inputs are split on NUL bytes, which no
//! JSON file holds.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

use mlod::dataset::{parse_bin, parse_points, Dataset, LoadOptions, PointLayout, POINT_BYTES};
use mlod::detect::{Case, Manifest, Stage1Model};
use mlod::refine::{Decoding, Refiner};

/// A folder of its own under the temp dir (tmpfs where there is one), removed on drop.
pub struct Scratch(PathBuf);

impl Scratch {
    pub fn new(tag: &str) -> Self {
        static N: AtomicUsize = AtomicUsize::new(0);
        let base = if Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        let dir = base.join(format!(
            "mlod-fuzz-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch folder");
        Self(dir)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    fn write(&self, rel: &str, bytes: &[u8]) -> PathBuf {
        let p = self.0.join(rel);
        if let Some(d) = p.parent() {
            std::fs::create_dir_all(d).expect("scratch subfolder");
        }
        std::fs::write(&p, bytes).expect("scratch file");
        p
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `data` cut at NUL bytes into at most `n` parts.
fn parts(data: &[u8], n: usize) -> Vec<&[u8]> {
    data.splitn(n, |b| *b == 0).collect()
}

/// The repository's `sample_data/` (this file is compiled from `fuzz/` and from the root).
fn repo_file(rel: &str) -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    if here.join(rel).exists() {
        here.join(rel)
    } else {
        here.parent().unwrap_or(here).join(rel)
    }
}

/// Three points of a `.bin`, for the files a fuzzed dataset names.
fn tiny_bin() -> Vec<u8> {
    let mut out = Vec::new();
    for p in [
        [5.0f32, 0.0, 0.0, 10.0, 1.0],
        [0.0, 7.0, 1.0, 20.0, 2.0],
        [-3.0, -3.0, 0.5, 0.0, 3.0],
    ] {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// A version folder: the 13 tables in `TABLE_NAMES` order, NUL-separated (a missing part is a
/// missing table). What opens is indexed, listed and split; up to four samples are resolved (every
/// LiDAR file must resolve inside the root), given tiny `.bin` files, loaded and fused.
pub fn lyft_tables(data: &[u8]) {
    let s = Scratch::new("lyft");
    let names = mlod::dataset::tables::TABLE_NAMES;
    for (name, part) in names.iter().zip(parts(data, names.len())) {
        s.write(&format!("v1.01-train/{name}.json"), part);
    }
    let Ok(ds) = Dataset::open(s.path()) else { return };
    let _ = ds.samples();
    let _ = mlod::dataset::train_validation_split(&ds);
    let root = std::fs::canonicalize(s.path()).expect("scratch root");
    for token in ds.sample_tokens().into_iter().take(4) {
        let _ = ds.lidar_channels(token);
        let Ok(info) = ds.frame_info(token) else { continue };
        for l in info.lidars() {
            // Confinement: a table never makes the loader leave the dataset root.
            let parent = l.path.parent().map(|p| p.to_path_buf()).unwrap_or_default();
            std::fs::create_dir_all(&parent).ok();
            let inside = std::fs::canonicalize(&parent).is_ok_and(|p| p.starts_with(&root));
            assert!(inside, "{} resolves outside the dataset root", l.filename);
            if !l.path.exists() && !l.path.to_string_lossy().ends_with('/') {
                std::fs::write(&l.path, tiny_bin()).ok();
            }
        }
        let Ok(frame) = ds.frame_with(token, LoadOptions { lenient: true }) else {
            continue;
        };
        let mut params = mlod::pipeline::FuseParams::default();
        params.perturbation.alpha = 0.1;
        if let Ok(cloud) = mlod::pipeline::fuse(&frame, &params) {
            assert_eq!(cloud.x.len(), cloud.trace.len());
        }
    }
}

/// A `.bin` point cloud, strict and lenient: a cloud that parses is consistent, holds only
/// finite values and accounts for every byte.
pub fn point_cloud(data: &[u8]) {
    let path = Path::new("fuzz.bin");
    for lenient in [false, true] {
        let Ok(c) = parse_bin(data, path, LoadOptions { lenient }) else {
            continue;
        };
        assert!(c.is_consistent());
        assert_eq!((c.len() + c.dropped) * POINT_BYTES + c.trimmed_bytes, data.len());
        assert!(c.x.iter().chain(&c.y).chain(&c.z).all(|v| v.is_finite()));
    }
    // The same bytes as KITTI records (4 float32; reflectance scaled, rings from scan order).
    for lenient in [false, true] {
        let Ok(c) = parse_points(data, path, LoadOptions { lenient }, PointLayout::XyzReflectance) else {
            continue;
        };
        assert!(c.is_consistent());
        assert_eq!((c.len() + c.dropped) * 16 + c.trimmed_bytes, data.len());
        assert!(c.intensity.iter().chain(&c.ring).all(|v| v.is_finite()));
    }
}

/// A KITTI frame: label, calib and point file (split on NUL). The parsers never panic; a frame
/// that loads fuses, and the evaluation region judges its boxes without a panic.
pub fn kitti(data: &[u8]) {
    let p = parts(data, 3);
    let (label, calib, bin) = (
        p.first().copied().unwrap_or_default(),
        p.get(1).copied().unwrap_or_default(),
        p.get(2).copied().unwrap_or_default(),
    );
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    let _ = mlod::dataset::kitti::parse_labels(&text(label), Path::new("label_2/000000.txt"));
    let _ = mlod::dataset::kitti::KittiCalib::parse(&text(calib), Path::new("calib/000000.txt"));
    let s = Scratch::new("kitti");
    s.write("training/label_2/000000.txt", label);
    s.write("training/calib/000000.txt", calib);
    s.write("training/velodyne/000000.bin", bin);
    let Ok(ds) = Dataset::open(s.path()) else { return };
    let _ = ds.notes();
    let Ok(frame) = ds.frame_with("000000", LoadOptions { lenient: true }) else {
        return;
    };
    for b in &frame.boxes {
        assert!(
            b.box3d.center.iter().all(|v| v.is_finite()),
            "a box from finite labels is finite"
        );
        let _ = frame.evaluates(&b.box3d);
    }
    if let Ok(cloud) = mlod::pipeline::fuse(&frame, &mlod::pipeline::FuseParams::default()) {
        assert_eq!(cloud.x.len(), frame.num_points());
    }
}

/// A session file: one that loads saves and loads again as the same session, and its fuse
/// parameters fuse a small frame without a panic.
pub fn session(data: &[u8]) {
    let s = Scratch::new("session");
    let p = s.write("a.session.json", data);
    let Ok(session) = mlod::session::Session::load(&p) else {
        return;
    };
    let q = s.path().join("b.session.json");
    session.save(&q).expect("a loaded session saves");
    let again = mlod::session::Session::load(&q).expect("a saved session loads");
    assert_eq!(format!("{session:?}"), format!("{again:?}"));
    let params = session.fuse_params();
    let _ = mlod::pipeline::fuse(sample_frame(), &params);
}

/// A models folder's `manifest.json`: every weights file it names resolves inside the folder,
/// and asking it for any model fails cleanly (the folder holds no weights).
pub fn manifest(data: &[u8]) {
    let s = Scratch::new("manifest");
    s.write(Manifest::FILE, data);
    let Ok(m) = Manifest::load(s.path()) else { return };
    let entries = m
        .models
        .values()
        .chain(m.refiner.iter())
        .chain(m.refiner_notrace.iter());
    for e in entries {
        if let Ok(p) = e.path_in(s.path()) {
            assert_eq!(p.parent(), Some(s.path()), "{} leaves the models folder", e.file);
        }
    }
    for case in Case::ALL {
        let _ = Stage1Model::load_shipped(s.path(), case);
    }
    let _ = Refiner::load_shipped(s.path());
    let _ = Refiner::load_shipped_for(s.path(), Case::MlodINoTrace);
}

/// A safetensors weights file, read as a stage-1 model of the case its metadata names and as a
/// refiner; a refiner that loads refines one proposal on a small frame.
pub fn weights(data: &[u8]) {
    let s = Scratch::new("weights");
    let p = s.write("w.safetensors", data);
    let Ok(w) = mlod::detect::weights::read_weights(&p, None) else {
        return;
    };
    if let Some(cfg) = w.metadata.get("mlod.config") {
        let case = serde_json::from_str::<serde_json::Value>(cfg)
            .ok()
            .and_then(|v| v.get("case").cloned())
            .and_then(|c| serde_json::from_value::<Case>(c).ok());
        if let Some(case) = case {
            let _ = Stage1Model::load(&p, case, None);
        }
    }
    if let Ok(r) = Refiner::load(&p, None, Decoding::default()) {
        let cloud = sample_cloud();
        let proposal = mlod::geometry::Detection {
            box3d: mlod::geometry::Box3d::new([10.0, 0.0, 0.0], [4.5, 1.9, 1.6], 0.3),
            score: 0.6,
            category: "car".into(),
        };
        let _ = r.refine(cloud, &[proposal]);
    }
}

/// A predictions file for `mlod eval`, evaluated against `sample_data/`.
pub fn predictions(data: &[u8]) {
    let s = Scratch::new("predictions");
    let p = s.write("preds.json", data);
    let Ok(values) = mlod::eval::read_predictions(&p) else {
        return;
    };
    let ds = sample_dataset();
    let tokens = ds.sample_tokens();
    let known: std::collections::HashSet<&str> = tokens.iter().copied().collect();
    let set = mlod::eval::parse_predictions(&values, &known);
    assert_eq!(set.accepted.len() + set.rejected.len(), set.total);
    let opts = mlod::eval::EvalOptions {
        samples: Some(2),
        ..Default::default()
    };
    if let Ok(report) = mlod::eval::evaluate(ds, &set, &opts) {
        let _ = serde_json::to_string(&report);
    }
}

/// A sweep folder: `config.json`, then the unit files in unit order, NUL-separated. What the
/// sweep window and `mlod sweep merge` read of it.
pub fn sweep_folder(data: &[u8]) {
    let s = Scratch::new("sweep");
    let ps = parts(data, 64);
    s.write("config.json", ps[0]);
    if let Ok(cfg) = mlod::analysis::sweep::read_config(s.path()) {
        if cfg.validate().is_ok() {
            for (u, part) in cfg.units().iter().zip(&ps[1..]) {
                s.write(&format!("units/{}", u.file()), part);
            }
        }
    }
    if let Ok(p) = mlod::analysis::sweep::progress(s.path()) {
        assert!(p.rows.len() <= p.total);
        let out = Scratch::new("sweep-merged");
        let _ = mlod::analysis::sweep::merge(out.path(), &[s.path().to_path_buf()]);
    }
}

fn sample_dataset() -> &'static Dataset {
    static DS: OnceLock<Dataset> = OnceLock::new();
    DS.get_or_init(|| Dataset::open(repo_file("sample_data")).expect("sample_data opens"))
}

fn sample_frame() -> &'static mlod::dataset::Frame {
    static F: OnceLock<mlod::dataset::Frame> = OnceLock::new();
    F.get_or_init(|| {
        let ds = sample_dataset();
        let t = ds.first_sample_token().expect("a sample").to_owned();
        let mut f = ds.frame(&t).expect("the first sample loads");
        // Every 100th point: the fuzzer's throughput, not the cloud's size, is what matters.
        for scan in std::iter::once(&mut f.primary).chain(f.auxiliaries.iter_mut()) {
            let p = &mut scan.points;
            for v in [&mut p.x, &mut p.y, &mut p.z, &mut p.intensity, &mut p.ring] {
                *v = v.iter().step_by(100).copied().collect();
            }
        }
        f
    })
}

fn sample_cloud() -> &'static mlod::pipeline::FusedCloud {
    static C: OnceLock<mlod::pipeline::FusedCloud> = OnceLock::new();
    C.get_or_init(|| {
        let mut params = mlod::pipeline::FuseParams::default();
        params.perturbation.alpha = 0.1;
        mlod::pipeline::fuse(sample_frame(), &params).expect("the first sample fuses")
    })
}

/// An Argoverse 2 log: the first byte picks which of its four files the rest replaces (sweep,
/// calibration, poses, annotations; the others are the real fixture's), then the log is opened,
/// its sweep loaded and fused. Every decoded column is also read directly.
pub fn av2(data: &[u8]) {
    use mlod::dataset::av2::feather::Feather;
    let (which, bytes) = data.split_first().map_or((0, &[][..]), |(w, b)| (*w, b));
    if let Ok(f) = Feather::parse(bytes.to_vec(), Path::new("x.feather")) {
        for c in ["x", "y", "z", "qw", "tx_m", "length_m"] {
            let _ = (f.f32s(c), f.f64s(c));
        }
        let _ = (
            f.u8s("laser_number"),
            f.i64s("timestamp_ns"),
            f.strings("category"),
        );
        let _ = f.finite_rows(["qw", "qx", "qy", "qz"]);
    }
    const FILES: [&str; 4] = [
        "sensors/lidar/315966265259836000.feather",
        "calibration/egovehicle_SE3_sensor.feather",
        "city_SE3_egovehicle.feather",
        "annotations.feather",
    ];
    let fixture = fixture_dir().join("av2/val/7fab2350-7eaf-3b7e-a39d-6937a4c1bede");
    let s = Scratch::new("av2");
    for (k, rel) in FILES.iter().enumerate() {
        let body = if k == usize::from(which % 4) {
            bytes.to_vec()
        } else {
            std::fs::read(fixture.join(rel)).expect("the AV2 fixture (tests/fixtures/av2)")
        };
        s.write(&format!("log/{rel}"), &body);
    }
    let Ok(ds) = Dataset::open(s.path()) else { return };
    let _ = ds.notes();
    let Some(token) = ds.first_sample_token().map(str::to_owned) else {
        return;
    };
    let Ok(frame) = ds.frame(&token) else { return };
    for b in &frame.boxes {
        assert!(
            b.box3d.center.iter().all(|v| v.is_finite()),
            "finite cuboids give finite boxes"
        );
    }
    if let Ok(cloud) = mlod::pipeline::fuse(&frame, &mlod::pipeline::FuseParams::default()) {
        assert_eq!(cloud.x.len(), frame.num_points());
        assert!(cloud.x.iter().all(|v| v.is_finite()), "loaded points are finite");
    }
}

/// tests/fixtures, from the repository (tests) or from fuzz/ (cargo fuzz).
fn fixture_dir() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    [here.join("tests/fixtures"), here.join("../tests/fixtures")]
        .into_iter()
        .find(|p| p.is_dir())
        .unwrap_or_else(|| here.join("tests/fixtures"))
}
