//! External detectors over mlod-detector/1 (issue 31), played by `tests/fixtures/detectors/fake.py`
//! (python3, standard library only): the boxes it serves are evaluated exactly like the same
//! boxes in-process, the cloud it receives is the one `mlod export` writes, a sweep runs it and
//! the refiner on it, and every way it can misbehave ends mlod with a message naming it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::{json as ok_json, mlod as run};

const FAKE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/detectors/fake.py");
const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlod-ext-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn tokens(n: usize) -> Vec<String> {
    let ds = mlod::dataset::Dataset::open(DATA).unwrap();
    ds.sample_tokens().iter().take(n).map(|s| s.to_string()).collect()
}

/// LiDAR-Top's boxes of the first `n` samples, by token, as `mlod detect --json` prints them.
fn top_boxes(n: usize, dir: &Path) -> PathBuf {
    let mut all = serde_json::Map::new();
    for t in tokens(n) {
        let v = ok_json(&[
            "detect",
            "--dataset",
            DATA,
            "--case",
            "top",
            "--sample",
            &t,
            "--json",
        ]);
        all.insert(t, v["detections"].clone());
    }
    let path = dir.join("boxes.json");
    std::fs::write(&path, serde_json::to_vec(&all).unwrap()).unwrap();
    path
}

fn replay(boxes: &Path, stats: Option<&Path>) -> String {
    let stats = stats.map(|s| format!(" '{}'", s.display())).unwrap_or_default();
    format!("X=python3 '{FAKE}' replay '{}'{stats}", boxes.display())
}

#[test]
fn ext_eval_equals_the_same_boxes_in_process() {
    let dir = tmp("eval");
    let boxes = top_boxes(3, &dir);
    let common = ["eval", "--dataset", DATA, "--samples", "3", "--json"];
    let mut inproc = ok_json(&[&common[..], &["--case", "top"]].concat());
    // Through the shipped example adapter.
    let adapter = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/detectors/replay.py");
    let det = format!("X=python3 '{adapter}' '{}'", boxes.display());
    let mut ext = ok_json(&[&common[..], &["--case", "ext:X", "--detector", &det]].concat());
    for v in [&mut inproc, &mut ext] {
        v.as_object_mut().unwrap().remove("case");
    }
    assert_eq!(inproc, ext);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_cloud_sent_is_what_export_writes() {
    let dir = tmp("cloud");
    let t = tokens(2).pop().unwrap();
    let boxes = dir.join("none.json");
    std::fs::write(&boxes, "{}").unwrap();
    let stats = dir.join("stats.jsonl");
    let det = replay(&boxes, Some(&stats));
    let v = ok_json(&[
        "detect",
        "--dataset",
        DATA,
        "--sample",
        &t,
        "--alpha",
        "0.1",
        "--seed",
        "4",
        "--case",
        "ext:X",
        "--detector",
        &det,
        "--json",
    ]);
    assert_eq!(v["case"], "ext:X");
    let ply = dir.join("cloud.ply");
    let ply_s = ply.display().to_string();
    let out = run(&[
        "export",
        "--dataset",
        DATA,
        "--sample",
        &t,
        "--alpha",
        "0.1",
        "--seed",
        "4",
        "--out",
        &ply_s,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let cloud = mlod::export::read_file(&ply).unwrap();
    let got: serde_json::Value =
        serde_json::from_str(std::fs::read_to_string(&stats).unwrap().lines().next().unwrap()).unwrap();
    assert_eq!(got["sample_token"], t.as_str());
    assert_eq!(got["protocol"], "mlod-detector/1");
    assert_eq!(got["frame"], "base");
    assert_eq!(
        got["fields"],
        serde_json::json!(["x", "y", "z", "intensity", "lidar", "trace"])
    );
    assert_eq!(got["num_points"], cloud.len());
    assert_eq!(got["rows"], cloud.len());
    let sum: f64 = cloud.trace.iter().map(|t| f64::from(*t)).sum();
    let theirs = got["trace_sum"].as_f64().unwrap();
    assert!(
        (sum - theirs).abs() <= 1e-9 * sum.abs().max(1.0),
        "{sum} vs {theirs}"
    );
    let mut ids: Vec<u8> = cloud.lidar.clone();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(got["lidars"], serde_json::json!(ids));
    assert_eq!(ids, [0, 1, 2]);
    let first: Vec<f64> = got["first"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let want = [
        cloud.x[0],
        cloud.y[0],
        cloud.z[0],
        cloud.intensity[0],
        f32::from(cloud.lidar[0]),
        cloud.trace[0],
    ];
    assert_eq!(first, want.map(f64::from));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sweep_runs_top_ext_and_the_refiner_on_ext() {
    let dir = tmp("sweep");
    let boxes = top_boxes(2, &dir);
    let out = dir.join("sweep");
    let out_s = out.display().to_string();
    let det = replay(&boxes, None);
    let o = run(&[
        "sweep",
        "--dataset",
        DATA,
        "--samples",
        "2",
        "--trials",
        "1",
        "--alphas",
        "0.1",
        "--cases",
        "top,ext:X,mlod-ext:X",
        "--detector",
        &det,
        "--out",
        &out_s,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    for case in ["top,", "ext:X,", "mlod-ext:X,"] {
        assert!(csv.lines().any(|l| l.starts_with(case)), "{case} in {csv}");
    }
    let cfg: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert!(cfg["detectors"]["X"].as_str().unwrap().contains("fake.py"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The PyTorch LiDAR-Top of `examples/detectors/torch_top.py` serves the boxes of the built-in
/// `top` case: on two samples the same count and, matched by order (both highest score first,
/// NMS's visiting order), every centre, size, yaw (as an angle) and score within 1e-4; they agree
/// to ~4e-6 (float32 rounding of the convolutions). Skipped, with a message, where python3 has no
/// torch.
#[test]
fn torch_top_equals_the_built_in_top() {
    let has_torch = std::process::Command::new("python3")
        .args(["-c", "import torch, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_torch {
        println!("skipped torch_top_equals_the_built_in_top: `python3 -c \"import torch, numpy\"` fails");
        return;
    }
    const TOL: f64 = 1e-4;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/detectors/torch_top.py");
    let models = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/models");
    let det = format!("torch=python3 '{script}' --models '{models}' --threads 1");
    for t in tokens(2) {
        let detect = |case: &[&str]| {
            let args = [&["detect", "--dataset", DATA, "--sample", &t, "--json"][..], case].concat();
            ok_json(&args)["detections"].as_array().unwrap().clone()
        };
        let top = detect(&["--case", "top"]);
        let torch = detect(&["--case", "ext:torch", "--detector", &det]);
        assert!(!top.is_empty(), "{t}: LiDAR-Top found nothing");
        assert_eq!(top.len(), torch.len(), "{t}: box counts");
        let num = |v: &serde_json::Value| v.as_f64().unwrap();
        for (i, (a, b)) in top.iter().zip(&torch).enumerate() {
            assert_eq!(a["category"], b["category"], "{t} box {i}");
            let fields = |d: &serde_json::Value| -> Vec<f64> {
                let mut f: Vec<f64> = ["center", "size_lwh"]
                    .iter()
                    .flat_map(|k| d[k].as_array().unwrap().iter().map(num))
                    .collect();
                f.extend([num(&d["yaw"]), num(&d["score"])]);
                f
            };
            let (fa, fb) = (fields(a), fields(b));
            assert_eq!(fa.len(), 8);
            for (k, (x, y)) in fa.iter().zip(&fb).enumerate() {
                // Yaw as an angle: π and −π are one heading.
                let d = if k == 6 {
                    mlod::geometry::wrap_angle(x - y).abs()
                } else {
                    (x - y).abs()
                };
                assert!(
                    d <= TOL,
                    "{t} box {i} field {k} (x y z l w h yaw score): built-in {x} vs torch {y}"
                );
            }
        }
    }
}

/// Processes whose command line holds `marker`.
fn alive(marker: &str) -> usize {
    let Ok(rd) = std::fs::read_dir("/proc") else {
        return 0;
    };
    rd.flatten()
        .filter_map(|e| std::fs::read(e.path().join("cmdline")).ok())
        .filter(|c| String::from_utf8_lossy(c).contains(marker))
        .count()
}

/// `mlod detect` with a misbehaving detector: a non-zero exit within a minute, a message naming
/// the detector and saying what it did, no panic, the child gone.
fn misbehaves(mode: &str, expect: &str) {
    let marker = format!("marker-{}-{mode}", std::process::id());
    let det = format!("bad=python3 '{FAKE}' {mode} {marker}");
    let t0 = Instant::now();
    let o = run(&[
        "detect",
        "--dataset",
        DATA,
        "--case",
        "ext:bad",
        "--detector",
        &det,
        "--detector-timeout",
        "10",
    ]);
    let took = t0.elapsed();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{mode}: succeeded");
    assert!(took < Duration::from_secs(60), "{mode}: {took:?}");
    assert!(err.contains("external detector 'bad'"), "{mode}: {err}");
    assert!(err.contains(expect), "{mode}: wanted {expect:?} in {err}");
    assert!(!err.contains("panicked"), "{mode}: {err}");
    if cfg!(target_os = "linux") {
        assert_eq!(alive(&marker), 0, "{mode}: the child outlived mlod");
    }
}

#[test]
fn a_crashing_detector_is_named() {
    misbehaves("crash", "exited (exit status 3) without answering");
    misbehaves("silent-exit", "exited (exit status 0) without answering");
}

#[test]
fn garbage_errors_and_wrong_samples_are_named() {
    misbehaves("garbage", "is not a mlod-detector/1 answer");
    misbehaves("error", "answered an error for sample");
    misbehaves("wrong", "answered for sample");
}

#[test]
fn a_hanging_detector_times_out() {
    let t0 = Instant::now();
    misbehaves("hang", "did not answer sample");
    assert!(t0.elapsed() >= Duration::from_secs(9));
}

#[test]
fn a_detector_that_does_not_start_or_is_not_defined_is_named() {
    let o = run(&[
        "detect",
        "--dataset",
        DATA,
        "--case",
        "ext:gone",
        "--detector",
        "gone=/nonexistent/serve --x",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("external detector 'gone'") && err.contains("did not start"),
        "{err}"
    );
    // Only detectors the command line defines ever run.
    let o = run(&["detect", "--dataset", DATA, "--case", "ext:nobody"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("no external detector 'nobody' is defined"), "{err}");
}

#[test]
fn detectors_files_define_cases_for_every_command() {
    let dir = tmp("file");
    let boxes = top_boxes(1, &dir);
    let file = dir.join("detectors.toml");
    std::fs::write(
        &file,
        format!(
            "[detectors.filed]\ncommand = [\"python3\", {FAKE:?}, \"replay\", \"boxes.json\"]\ndir = \".\"\ntimeout = 20\n"
        ),
    )
    .unwrap();
    assert!(boxes.starts_with(&dir));
    let file_s = file.display().to_string();
    let t = tokens(1).pop().unwrap();
    let v = ok_json(&[
        "detect",
        "--dataset",
        DATA,
        "--sample",
        &t,
        "--case",
        "mlod-ext:filed",
        "--detectors",
        &file_s,
        "--json",
    ]);
    assert_eq!(v["case"], "mlod-ext:filed");
    assert!(!v["detections"].as_array().unwrap().is_empty());
    let v = ok_json(&[
        "failures",
        "--dataset",
        DATA,
        "--samples",
        "1",
        "--case",
        "ext:filed",
        "--detectors",
        &file_s,
        "--json",
    ]);
    assert_eq!(v["case"], "ext:filed");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_failed_sweep_unit_is_reported_and_retried_on_resume() {
    let dir = tmp("resume");
    let out = dir.join("sweep");
    let out_s = out.display().to_string();
    // The boxes file is missing at first: the detector dies at its first frame.
    let boxes = dir.join("later.json");
    let det = replay(&boxes, None);
    let args = [
        "sweep",
        "--dataset",
        DATA,
        "--samples",
        "1",
        "--trials",
        "1",
        "--alphas",
        "0.1",
        "--cases",
        "top,ext:X",
        "--detector",
        &det,
        "--out",
        &out_s,
    ];
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("external detector 'X'") && err.contains("retried when the sweep is resumed"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    std::fs::write(&boxes, "{}").unwrap();
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert!(csv.lines().any(|l| l.starts_with("ext:X,0.1,0,")), "{csv}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_cli_never_runs_a_session_s_detector() {
    let dir = tmp("session");
    let marker = format!("marker-{}-session", std::process::id());
    let words = ["python3", FAKE, "instant", &marker].map(String::from).to_vec();
    let mut s = mlod::session::Session::new(DATA.into());
    s.detection.case = "ext:shared".parse().unwrap();
    s.external = vec![mlod::external::ExternalSpec::new("shared", words).unwrap()];
    let path = dir.join("shared.session.json");
    s.save(&path).unwrap();
    let gif = dir.join("clip.gif");
    let o = run(&[
        "clip",
        "--session",
        path.to_str().unwrap(),
        "--frames",
        "2",
        "--out",
        gif.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("--detector shared=COMMAND"), "{err}");
    assert!(!gif.exists());
    assert_eq!(alive(&marker), 0);
    let _ = std::fs::remove_dir_all(&dir);
}
