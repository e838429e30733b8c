//! `mlod eval --transfer` and `--set-intensity` (issue 29): the transfer check's JSON, agreement
//! with the per-box outcomes at 3D IoU 0.5, intensity replaced before the detector, and absurd
//! values refused.

use super::{json, mlod, tuning_fixture};

#[test]
fn transfer_check_reports_found_cars_and_agrees_with_per_box_outcomes() {
    let base = [
        "eval",
        "--dataset",
        "sample_data",
        "--case",
        "top",
        "--samples",
        "3",
    ];
    let r = json(&[&base[..], &["--transfer", "--json"]].concat());
    let t = &r["transfer"];
    let n = |k: &str| t[k].as_f64().unwrap_or(f64::NAN);
    assert_eq!(t["rule"]["category"], "car");
    assert!(n("boxes") > 0.0, "{t}");
    assert!(n("found") <= n("boxes") && n("found_iou") <= n("found") + n("boxes"));
    assert!((n("found_pct") - 100.0 * n("found") / n("boxes")).abs() < 1e-9);
    assert!((0.0..=100.0).contains(&n("ap_centre")));
    assert_eq!(n("frames"), 3.0);
    // Cars within 50 m matched at 3D IoU ≥ 0.5 by a prediction scoring ≥ 0.3: count them from
    // the per-box outcomes of an IoU-0.5 matching restricted to confident predictions (the
    // greedy matching visits predictions by score, so dropping those under 0.3 first is the same
    // as the transfer check's).
    let pb = json(&[&base[..], &["--per-box", "--match-iou", "0.5", "--json"]].concat());
    let mut matched_confident = 0;
    for s in pb["per_box"].as_array().unwrap() {
        for p in s["preds"].as_array().unwrap() {
            let score = p["score"].as_f64().unwrap();
            if p["category"] == "car"
                && p["outcome"] == "true_positive"
                && score >= 0.3
                && p["range"].as_f64().unwrap() < 50.0
            {
                matched_confident += 1;
            }
        }
    }
    assert!(
        n("found_iou") >= matched_confident as f64,
        "found at IoU 0.5 {} < {matched_confident} confident matches",
        n("found_iou")
    );
    // Without --transfer the key is absent.
    let plain = json(&[&base[..], &["--json"]].concat());
    assert!(plain.get("transfer").is_none());
}

#[test]
fn set_intensity_reaches_the_detector_and_absurd_values_are_refused() {
    let args = ["detect", "--dataset", "sample_data", "--case", "top", "--json"];
    let a = json(&args);
    // sample_data holds 100 everywhere, as real Lyft files do: set another value.
    let b = json(&[&args[..], &["--set-intensity", "30"]].concat());
    // The shipped LiDAR-Top was trained without intensity: every point reading 30 changes
    // nothing (that the value reaches every LiDAR's points is `Frame::set_intensity`'s unit test).
    assert_eq!(a["detections"], b["detections"]);
    for bad in ["-1", "NaN", "inf", "70000", "loud"] {
        let arg = format!("--set-intensity={bad}");
        let out = mlod(&[&args[..], &[arg.as_str()]].concat());
        assert!(!out.status.success(), "{bad} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("intensity") && !err.contains("panicked"),
            "{bad}: {err}"
        );
    }
}

#[test]
fn ground_gate_drops_only_floating_boxes_and_refuses_absurd_gates() {
    // On the simulator's own frames the cars stand on the ground: a 5 m gate drops nothing, a
    // 0.5 m gate keeps nearly all of LiDAR-Top's confident boxes, a 1 cm gate drops many; every
    // kept box is one of the ungated, unchanged.
    let args = ["detect", "--dataset", "sample_data", "--case", "top", "--json"];
    let boxes = |extra: &[&str]| {
        json(&[&args[..], extra].concat())["detections"]
            .as_array()
            .cloned()
            .unwrap_or_default()
    };
    let all = boxes(&["--ground-gate", "off"]);
    let (wide, half, tiny) = (
        boxes(&["--ground-gate", "5"]),
        boxes(&["--ground-gate", "0.5"]),
        boxes(&["--ground-gate", "0.01"]),
    );
    // The shipped folder records a 0.5 m gate (`mlod train tune-gate`): the default applies it.
    assert_eq!(boxes(&[]), half);
    let confident = |v: &[serde_json::Value]| {
        v.iter()
            .filter(|d| d["score"].as_f64().unwrap_or(0.0) >= 0.3)
            .count()
    };
    assert_eq!(wide, all);
    assert!(confident(&all) >= 10, "{}", confident(&all));
    assert!(
        10 * confident(&half) >= 9 * confident(&all),
        "{} of {}",
        confident(&half),
        confident(&all)
    );
    assert!(tiny.len() < half.len() && half.len() <= all.len());
    assert!(half.iter().chain(&tiny).all(|d| all.contains(d)));
    for bad in ["0", "-1", "NaN", "6", "high"] {
        let arg = format!("--ground-gate={bad}");
        let out = mlod(&[&args[..], &[arg.as_str()]].concat());
        assert!(!out.status.success(), "{bad} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("ground") && !err.contains("panicked"),
            "{bad}: {err}"
        );
    }
}

#[test]
fn tune_gate_records_the_smallest_free_gate_and_detect_applies_it() {
    let (dir, d, m) = tuning_fixture("gate");
    let (d, m, models) = (d.as_str(), m.as_str(), std::path::Path::new(&m));
    let tune = |extra: &[&str]| {
        let args = [&["train", "tune-gate", "--dataset", d, "--models", m][..], extra].concat();
        mlod(&args)
    };
    let out = tune(&["--candidates", "0.5,0.01"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(models.join("manifest.json")).expect("manifest"))
            .expect("JSON");
    let gate = &manifest["ground_gate"];
    assert!(gate["command"].as_str().expect("command").contains("tune-gate"));
    let ap = |k: &str| gate["validation"][k]["mean"].as_f64().expect(k);
    let (off, tiny, half) = (ap("off"), ap("0.01"), ap("0.5"));
    // The smallest gate that costs no validation AP.
    let want = if tiny >= off {
        Some(0.01)
    } else if half >= off {
        Some(0.5)
    } else {
        None
    };
    assert_eq!(
        gate["max_lift_m"].as_f64().map(|v| (v * 100.0).round() / 100.0),
        want,
        "{gate}"
    );
    // detect applies the folder's gate unless told otherwise.
    let detect = |extra: &[&str]| {
        let args = [
            &["detect", "--dataset", d, "--case", "top", "--models", m, "--json"][..],
            extra,
        ]
        .concat();
        json(&args)["detections"].clone()
    };
    let explicit = want.map_or("off".to_string(), |v| v.to_string());
    assert_eq!(detect(&[]), detect(&["--ground-gate", &explicit]));
    // Absurd candidates and MLOD cases are refused by name.
    for (extra, what) in [
        (&["--candidates", "7"][..], "ground gate"),
        (&["--cases", "mlod-i"][..], "stage-1"),
    ] {
        let out = tune(extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(what) && !err.contains("panicked"),
            "{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn gui_refuses_a_models_folder_without_a_manifest_before_opening_a_window() {
    let out = mlod(&["gui", "--models", "/nonexistent/models"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--models /nonexistent/models") && err.contains("manifest.json"),
        "{err}"
    );
}

#[test]
fn failures_load_the_detector_as_detect_does() {
    // `mlod failures` takes `mlod detect`'s detector flags: a 1 cm ground gate drops LiDAR-Top's
    // boxes, so the scan counts more misses; without the flag the scan is the window's (the
    // models folder's decoding), and --set-intensity reaches the detector.
    let scan = |extra: &[&str]| {
        let base = [
            "failures",
            "--dataset",
            "sample_data",
            "--case",
            "top",
            "--samples",
            "2",
            "--json",
        ];
        json(&[&base[..], extra].concat())["samples"].clone()
    };
    let misses = |v: &serde_json::Value| -> u64 {
        v.as_array()
            .expect("samples")
            .iter()
            .map(|s| s["missed"].as_u64().unwrap_or(0))
            .sum()
    };
    let plain = misses(&scan(&[]));
    let gated = misses(&scan(&["--ground-gate", "0.01"]));
    assert!(gated > plain, "a 1 cm gate: {gated} misses against {plain}");
    assert_eq!(
        misses(&scan(&["--ground-gate", "off"])),
        plain,
        "the shipped folder has no gate"
    );
    // The shipped models do not read intensity: a scan with every intensity at 0 is the same.
    assert_eq!(scan(&[]), scan(&["--set-intensity", "0"]));
}

#[test]
fn the_shipped_lidar_top_on_the_real_fixture_frames_keeps_false_positives_low() {
    // Issue 29's false-positive goal on the two committed KITTI frames (tests/fixtures/kitti:
    // no car within 50 m in camera 2's view, so nothing to find): the shipped LiDAR-Top, trained
    // on the simulator only, makes at most 0.5 confident false positives per frame, and the same
    // with every intensity at 100 (as real Lyft files hold it): it does not read intensity.
    let base = [
        "eval",
        "--dataset",
        "tests/fixtures/kitti",
        "--case",
        "top",
        "--transfer",
        "--json",
    ];
    let report = |extra: &[&str]| json(&[&base[..], extra].concat())["transfer"].clone();
    let (t, t100) = (report(&[]), report(&["--set-intensity", "100"]));
    assert_eq!(t, t100);
    assert_eq!(t["frames"], 2, "{t}");
    let fp = t["confident_false_positives_per_frame"].as_f64().unwrap();
    assert!(fp <= 0.5, "{t}");
}
