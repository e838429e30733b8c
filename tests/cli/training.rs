use super::*;

/// The ablation's figures go to the manifest's `refiner_notrace` entry, not the shipped refiner's.
#[test]
fn table1_records_the_notrace_ablation_under_its_own_refiner() {
    let s = Scratch::new("notrace-manifest");
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models");
    for f in [
        "manifest.json",
        "input.safetensors",
        "refiner-notrace.safetensors",
    ] {
        std::fs::copy(shipped.join(f), s.0.join(f)).expect("copy a shipped file");
    }
    let read = || -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(s.0.join("manifest.json")).expect("manifest")).expect("JSON")
    };
    let before = read();
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let out = mlod(&[
        "table1",
        "--dataset",
        sample,
        "--cases",
        "mlod-i-notrace",
        "--samples",
        "3",
        "--models",
        s.0.to_str().expect("utf-8"),
        "--update-manifest",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let after = read();
    assert_eq!(
        after["refiner"], before["refiner"],
        "the shipped refiner's figures are untouched"
    );
    let ap = &after["refiner_notrace"]["test_ap"]["mlod-i-notrace/moderate_ap3d_0.7"];
    assert!(ap.as_f64().is_some_and(|v| (0.0..=100.0).contains(&v)), "{ap}");
}

#[test]
fn stats_prints_text_json_and_writes_plots() {
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let text = mlod(&["stats", "--dataset", sample, "--samples", "2"]);
    assert!(text.status.success(), "{}", String::from_utf8_lossy(&text.stderr));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("LIDAR_TOP") && text.contains("car"), "{text}");
    let v = json(&["stats", "--dataset", sample, "--samples", "2", "--json"]);
    assert_eq!(v["samples"], 2);
    assert_eq!(v["failed_samples"], 0);
    assert_eq!(v["format"], "lyft");
    assert_eq!(v["lidars"][0]["channel"], "LIDAR_TOP");
    assert!(v["lidars"][0]["points_per_sweep"]["median"].as_f64().unwrap() > 1000.0);
    assert!(v["objects"][0]["range_bins"][7]["to_m"].is_null());
    assert!(v.get("boxes").is_none(), "boxes only with --per-box");
    let s = json(&[
        "stats",
        "--dataset",
        sample,
        "--samples",
        "2",
        "--summary",
        "--json",
    ]);
    assert_eq!(s["samples"], 2);
    assert_eq!(s["lidars"].as_array().unwrap().len(), 3);

    let dir = Scratch::new("stats");
    let out = dir.0.to_str().unwrap();
    let kitti = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/kitti");
    let run = mlod(&[
        "stats",
        "--dataset",
        sample,
        "--compare",
        kitti,
        "--per-box",
        "--out",
        out,
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    for f in [
        "stats.json",
        "compare.json",
        "points_per_box.png",
        "intensity.png",
        "range.png",
    ] {
        assert!(dir.0.join(f).is_file(), "{f} missing");
    }
    let k: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.0.join("compare.json")).unwrap()).unwrap();
    assert_eq!(k["format"], "kitti");
    assert_eq!(k["lidars"][0]["rings"], 64);
    assert_eq!(k["lidars"].as_array().unwrap().len(), 1);
    assert!(!k["boxes"].as_array().unwrap().is_empty());
}

#[test]
fn stats_updates_a_manifest_and_detect_and_eval_name_what_differs() {
    let root = env!("CARGO_MANIFEST_DIR");
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let kitti = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/kitti");
    // The summary goes into a copy of the shipped manifest, under training_stats.
    let dir = Scratch::new("stats-manifest");
    let shipped = std::path::Path::new(root).join("assets/models");
    std::fs::copy(shipped.join("manifest.json"), dir.0.join("manifest.json")).unwrap();
    let m = dir.0.to_str().unwrap();
    let run = mlod(&[
        "stats",
        "--dataset",
        sample,
        "--samples",
        "3",
        "--summary",
        "--update-manifest",
        m,
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.0.join("manifest.json")).unwrap()).unwrap();
    let t = &manifest["training_stats"];
    assert!(t["command"]
        .as_str()
        .unwrap()
        .starts_with("mlod stats --dataset "));
    assert_eq!(t["summary"]["samples"], 3);
    assert!(
        manifest["models"]["top"].is_object(),
        "the rest of the manifest is kept"
    );

    // The shipped manifest holds the training data's summary: KITTI differs, sample_data does not.
    assert!(
        mlod::detect::weights::read_training_stats(&shipped)
            .unwrap()
            .is_some(),
        "assets/models/manifest.json has no training_stats"
    );
    let det = mlod(&["detect", "--dataset", kitti, "--case", "top", "--json"]);
    let err = String::from_utf8_lossy(&det.stderr);
    assert!(det.status.success(), "{err}");
    // The shipped (v4) models saw roof LiDARs of 32 to 128 rings: KITTI's 64 are among them.
    assert!(!err.contains("rings"), "{err}");
    assert!(
        err.contains("note: no LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT"),
        "{err}"
    );
    assert!(err.contains("m shorter"), "{err}");
    serde_json::from_slice::<serde_json::Value>(&det.stdout).expect("stdout stays JSON");
    let ev = mlod(&["eval", "--dataset", kitti, "--case", "top", "--json"]);
    let err = String::from_utf8_lossy(&ev.stderr);
    assert!(ev.status.success(), "{err}");
    assert!(err.contains("note: cars are 1.0 m shorter"), "{err}");
    let same = mlod(&["detect", "--dataset", sample, "--case", "top", "--json"]);
    assert!(same.status.success());
    let err = String::from_utf8_lossy(&same.stderr);
    assert!(
        !err.contains("note:"),
        "sample_data is like the training data: {err}"
    );
}

#[test]
fn synth_glass_see_through_changes_the_sweeps_and_refuses_unknown_values() {
    let dir = std::env::temp_dir().join(format!("mlod-cli-glass-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let make = |name: &str, glass: &str| {
        let out = dir.join(name);
        let run = mlod(&[
            "synth",
            "--out",
            out.to_str().expect("utf-8"),
            "--samples-per-scene",
            "1",
            "--seed",
            "5",
            "--glass",
            glass,
        ]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let lidar = out.join("lidar");
        let mut bins: Vec<_> = std::fs::read_dir(&lidar)
            .expect("lidar/")
            .map(|e| e.expect("entry").path())
            .collect();
        bins.sort();
        bins.iter()
            .map(|p| std::fs::read(p).expect("bin"))
            .collect::<Vec<_>>()
    };
    let (opaque, clear) = (make("opaque", "opaque"), make("clear", "see-through"));
    assert_eq!(opaque.len(), clear.len());
    assert_ne!(opaque, clear, "see-through glass changed no sweep");
    let bad = mlod(&[
        "synth",
        "--out",
        dir.join("bad").to_str().expect("utf-8"),
        "--glass",
        "foggy",
    ]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--glass"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_refiner_of_chosen_widths_trains_and_loads_and_bad_widths_are_refused() {
    // `mlod train refiner --point-mlp … --head …` (issue 32's capacity lever).
    let dir = std::env::temp_dir().join(format!("mlod-cli-widths-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let sd = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let (props, out) = (dir.join("props"), dir.join("refiner.safetensors"));
    let (props_s, out_s) = (props.to_str().unwrap(), out.to_str().unwrap());
    let train = |widths: &[&str]| {
        let mut args = vec![
            "train",
            "refiner",
            "--dataset",
            sd,
            "--proposals",
            props_s,
            "--out",
            out_s,
        ];
        args.extend_from_slice(&[
            "--steps",
            "2",
            "--batch",
            "4",
            "--points",
            "64",
            "--log-every",
            "1",
        ]);
        args.extend_from_slice(widths);
        mlod(&args)
    };
    let bad = train(&["--point-mlp", "8,0", "--head", "16"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("--point-mlp"), "{err}");
    assert!(!out.exists());
    let db = mlod(&[
        "train",
        "proposals",
        "--dataset",
        sd,
        "--out",
        props_s,
        "--cases",
        "input",
        "--max-samples",
        "2",
    ]);
    assert!(db.status.success(), "{}", String::from_utf8_lossy(&db.stderr));
    let ok = train(&["--point-mlp", "8,16", "--head", "16"]);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let r = mlod::refine::Refiner::load(&out, None, Default::default()).expect("the trained refiner loads");
    assert_eq!(
        (r.config.point_mlp.as_slice(), r.config.head.as_slice()),
        ([8, 16].as_slice(), [16].as_slice())
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn analyze_takes_the_drop_threshold_of_a_drop_case() {
    // `mlod-ir-drop` at α = 0.1: its proposals come from Result and Input Fusion on the points
    // under the threshold, so another --drop-trace gives the refiner other proposals to look at.
    let dir = std::env::temp_dir().join(format!("mlod-analyze-drop-{}", std::process::id()));
    let csv = |trace: &str| {
        let out_dir = dir.join(trace);
        let out = out_dir.to_str().unwrap();
        let args = [
            "analyze",
            "active-points",
            "--dataset",
            "sample_data",
            "--case",
            "mlod-ir-drop",
            "--alpha",
            "0.1",
            "--samples",
            "1",
            "--drop-trace",
            trace,
            "--out",
            out,
        ];
        let o = mlod(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out_dir.join("active_points.csv")).unwrap()
    };
    assert_ne!(csv("0.1"), csv("0.005"));
    let _ = std::fs::remove_dir_all(&dir);
}
