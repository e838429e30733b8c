//! `mlod eval --transfer` and `--set-intensity` (issue 29): the transfer check's JSON, agreement
//! with the per-box outcomes at 3D IoU 0.5, intensity replaced before the detector, and absurd
//! values refused.

use super::{json, mlod};

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
    // The shipped (v4) LiDAR-Top was trained without intensity: every point reading 30 changes
    // nothing. The v2 LiDAR-Top reads it: its boxes change.
    assert_eq!(a["detections"], b["detections"]);
    let v2 = [&args[..], &["--models", "assets/models/v2"]].concat();
    let a = json(&v2);
    let b = json(&[&v2[..], &["--set-intensity", "30"]].concat());
    assert_ne!(a["detections"], b["detections"]);
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
