//! `mlod train chain` and `mlod train adapt` (issue 53): a tiny run of each, killed part-way and
//! resumed with the same command, ends with a complete models folder whose manifest records
//! every command.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};

const MLOD: &str = env!("CARGO_BIN_EXE_mlod");

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlod-chain-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch");
    d
}

fn sha(path: &Path) -> String {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    format!("{:x}", Sha256::digest(&bytes))
}

fn run(args: &[String]) -> String {
    let out = Command::new(MLOD).args(args).output().expect("run mlod");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "mlod {args:?}: {err}");
    err
}

/// Starts `args` and SIGKILLs it once `ready()` holds (polled); panics if it ends first or
/// takes more than ten minutes.
fn kill_when(args: &[String], ready: impl Fn() -> bool) {
    let mut child = Command::new(MLOD)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    let t = Instant::now();
    while !ready() {
        assert!(
            child.try_wait().expect("wait").is_none(),
            "mlod {args:?} ended before it could be killed"
        );
        assert!(
            t.elapsed() < Duration::from_secs(600),
            "mlod {args:?}: never ready"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().expect("SIGKILL");
    child.wait().expect("reap");
}

/// Runs `mlod train adapt --dataset DATASET --out OUT` with `extra` first; it must fail, and
/// its stderr is returned.
fn adapt_refused(extra: &[&str], dataset: &Path, out: &Path) -> String {
    let o = Command::new(MLOD)
        .args(["train", "adapt"])
        .args(extra)
        .arg("--dataset")
        .arg(dataset)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run");
    assert!(!o.status.success(), "mlod train adapt {extra:?} succeeded");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn manifest(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("manifest");
    serde_json::from_str(&text).expect("manifest JSON")
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

#[test]
fn a_killed_chain_resumes_to_a_complete_models_folder() {
    let d = scratch("chain");
    let out = d.join("models");
    let init = root().join("assets").join("models");
    let args = strings(&[
        "train",
        "chain",
        "--world",
        "walled",
        "--out",
        out.to_str().expect("utf-8"),
        "--scenes",
        "10",
        "--samples-per-scene",
        "1",
        "--steps",
        "3",
        "--refiner-steps",
        "3",
        "--val-samples",
        "1",
        "--stats-samples",
        "2",
        "--init",
        init.to_str().expect("utf-8"),
    ]);
    // Killed once LiDAR-Top is done (the state file says so), then run again.
    let state = out.join("chain.json");
    kill_when(&args, || {
        std::fs::read_to_string(&state)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v["phases"][1]["wall_time_s"].is_number())
    });
    let top = sha(&out.join("top.safetensors"));
    let log = run(&args);
    assert!(log.contains("[1/15] data: done"), "{log}");
    assert!(log.contains("[2/15] top: done"), "{log}");
    assert_eq!(sha(&out.join("top.safetensors")), top, "a done phase ran again");
    // A complete folder: every weight the manifest names, with its checksum, and the commands.
    let m = manifest(&out);
    for (case, e) in m["models"].as_object().expect("models") {
        let file = e["file"].as_str().expect("file");
        assert_eq!(sha(&out.join(file)), e["sha256"].as_str().expect("sha"), "{case}");
        let cmd = e["command"].as_str().expect("command");
        assert!(
            cmd.starts_with(&format!("mlod train stage1 --case {case} ")),
            "{cmd}"
        );
        // The car ray drop is LiDAR-Top's recipe alone (the case it was measured on).
        assert_eq!(cmd.contains(" --car-drop"), case == "top", "{cmd}");
    }
    assert_eq!(m["models"].as_object().map(|o| o.len()), Some(5));
    for k in [
        "refiner",
        "refiner_notrace",
        "vote",
        "refine",
        "ground_gate",
        "training_stats",
    ] {
        assert!(!m[k].is_null(), "manifest lacks {k}");
    }
    assert_eq!(m["world"], "walled");
    assert!(m["temperature_command"]
        .as_str()
        .is_some_and(|c| c.starts_with("mlod train calibrate-temperature")));
    let phases = m["chain"]["phases"].as_array().expect("phases");
    assert_eq!(phases.len(), 15);
    assert!(phases
        .iter()
        .all(|p| p["wall_time_s"].as_f64().is_some_and(|t| t >= 0.0)));
    assert!(m["chain"]["command"]
        .as_str()
        .is_some_and(|c| c.starts_with("mlod train chain --world walled")));
    // The same folder with other options is refused, not silently mixed.
    let mut other = args.clone();
    let steps = other.iter().position(|a| a == "--steps").expect("--steps");
    other[steps + 1] = "4".into();
    let o = Command::new(MLOD).args(&other).output().expect("run");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("holds another chain"));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_killed_adaptation_resumes_to_a_complete_models_folder() {
    let d = scratch("adapt");
    let out = d.join("adapted");
    let base = root().join("assets").join("models");
    let kitti = Path::new("tests/fixtures/kitti");
    let args = strings(&[
        "train",
        "adapt",
        "--dataset",
        kitti.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--steps",
        "4",
        "--gt-sample",
        "2",
    ]);
    // Killed once the base folder is copied (its manifest is written last), then run again.
    kill_when(&args, || out.join("manifest.json").is_file());
    run(&args);
    let m = manifest(&out);
    let base_m = manifest(&base);
    let a = &m["adapted"];
    assert_eq!(a["base_manifest_sha256"], sha(&base.join("manifest.json")));
    assert_eq!(a["cases"], serde_json::json!(["top"]));
    assert_eq!(a["samples"], 2);
    assert!(a["command"]
        .as_str()
        .is_some_and(|c| c.starts_with("mlod train adapt")));
    // The fixture's two frames hold no car within 50 m: the check ran and found none to find.
    for k in ["top/base", "top/adapted"] {
        assert_eq!(a["fit"][k]["frames"], 2.0, "{k}: {a}");
        assert_eq!(a["fit"][k]["boxes"], 0.0, "{k}: {a}");
    }
    assert_eq!(a["dataset"], "tests/fixtures/kitti");
    assert_eq!(a["base"], "assets/models");
    // The adapted LiDAR-Top starts from the base's and differs from it; the rest is the base's.
    let top = &m["models"]["top"];
    assert_eq!(top["init"]["sha256"], base_m["models"]["top"]["sha256"]);
    assert_ne!(top["sha256"], base_m["models"]["top"]["sha256"]);
    assert_eq!(
        sha(&out.join("top.safetensors")),
        top["sha256"].as_str().expect("sha")
    );
    for case in ["input", "feature", "left", "right"] {
        assert_eq!(m["models"][case], base_m["models"][case], "{case}");
        assert_eq!(
            sha(&out.join(format!("{case}.safetensors"))),
            sha(&base.join(format!("{case}.safetensors")))
        );
    }
    assert_eq!(m["refiner"], base_m["refiner"]);
    // The window and every command open it as a models folder.
    let o = Command::new(MLOD)
        .args([
            "detect",
            "--dataset",
            kitti.to_str().expect("utf-8"),
            "--case",
            "top",
            "--models",
        ])
        .arg(&out)
        .args(["--json"])
        .output()
        .expect("run");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn adapt_refuses_its_base_folder_and_unlabelled_data() {
    let base = root().join("assets").join("models");
    let kitti = root().join("tests").join("fixtures").join("kitti");
    assert!(adapt_refused(&[], &kitti, &base).contains("is the base models folder"));
    // A KITTI folder whose labels hold no box teaches nothing.
    let d = scratch("unlabelled");
    for sub in ["velodyne", "calib", "label_2"] {
        std::fs::create_dir_all(d.join("training").join(sub)).expect("dir");
    }
    let k = kitti.join("training");
    std::fs::copy(
        k.join("velodyne/000000.bin"),
        d.join("training/velodyne/000000.bin"),
    )
    .expect("copy");
    std::fs::copy(k.join("calib/000000.txt"), d.join("training/calib/000000.txt")).expect("copy");
    std::fs::write(d.join("training/label_2/000000.txt"), "").expect("write");
    assert!(adapt_refused(&[], &d, &d.join("out")).contains("no sample has a labelled box"));
    // An absurd learning rate is refused before anything is written.
    assert!(adapt_refused(&["--lr", "nan"], &kitti, &d.join("nan")).contains("--lr must be in (0, 1)"));
    assert!(!d.join("nan").exists(), "a refused run wrote a folder");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn on_a_rig_the_fusion_cases_adapt_too() {
    let d = scratch("adapt-rig");
    let out = d.join("adapted");
    run(&strings(&[
        "train",
        "adapt",
        "--dataset",
        "tests/fixtures/av2",
        "--out",
        out.to_str().expect("utf-8"),
        "--steps",
        "2",
        "--no-fit-check",
    ]));
    let m = manifest(&out);
    assert_eq!(
        m["adapted"]["cases"],
        serde_json::json!(["top", "input", "feature"])
    );
    let base = manifest(&root().join("assets").join("models"));
    for case in ["top", "input", "feature"] {
        assert_ne!(
            m["models"][case]["sha256"], base["models"][case]["sha256"],
            "{case}"
        );
    }
    for case in ["left", "right"] {
        assert_eq!(m["models"][case], base["models"][case], "{case}");
    }
    let _ = std::fs::remove_dir_all(&d);
}
