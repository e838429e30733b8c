//! `mlod eval` against the official Lyft devkit and hand-checkable cases.
//!
//! `tests/fixtures/devkit_expected/eval_sample_data/` holds randomly perturbed predictions for
//! sample_data/ as it was before issue 29 regenerated it (its tables are kept in `dataset/`;
//! `tests/devkit/make_predictions.py sample_data OUT --seed 0`, `pred_all.json`,
//! 6 invalid records included) and what lyft-dataset-sdk 0.0.8 computed on the valid ones
//! (`tests/devkit/map_eval.py OUT/pred_valid.json OUT/gt.json devkit.json`).

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use mlod::dataset::Dataset;
use mlod::eval::{self, EvalOptions, Fix, GtOutcome, MatchRule, PredOutcome};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

fn fixture(name: &str) -> PathBuf {
    root()
        .join("tests/fixtures/devkit_expected/eval_sample_data")
        .join(name)
}

/// The tables of `sample_data/` as they were when the devkit's figures were made (before issue 29
/// regenerated it with the v4 simulator): annotations only, no point files, which mAP does not read.
fn sample_data() -> Dataset {
    Dataset::open(fixture("dataset")).expect("the devkit's dataset opens")
}

fn known(tokens: &[String]) -> HashSet<&str> {
    tokens.iter().map(String::as_str).collect()
}

#[test]
fn lyft_map_agrees_with_the_official_devkit() {
    let ds = sample_data();
    let opts = EvalOptions::default();
    let tokens = eval::sample_tokens(&ds, &opts);
    let raw = eval::read_predictions(&fixture("pred_all.json")).expect("predictions");
    let preds = eval::parse_predictions(&raw, &known(&tokens));
    // Exactly the six planted invalid records are rejected, each with its reason.
    assert_eq!(preds.rejected.len(), 6, "{:#?}", preds.rejected);
    let reasons: Vec<&str> = preds.rejected.iter().map(|r| r.reason.as_str()).collect();
    for needle in [
        "translation[1]",
        "unknown sample_token",
        "size[0]",
        "unit quaternion",
        "score",
        "size has 2",
    ] {
        assert!(
            reasons.iter().any(|r| r.contains(needle)),
            "no rejection for {needle}: {reasons:?}"
        );
    }
    let report = eval::evaluate(&ds, &preds, &opts).expect("evaluates");
    assert_eq!(report.samples, 10);

    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("devkit.json")).expect("read")).expect("json");
    let per = expected["per_threshold"].as_array().expect("per_threshold");
    assert_eq!(per.len(), 10);
    for p in per {
        let t = p["iou_threshold"].as_f64().expect("t");
        let key = format!("{t}");
        let ours = report.lyft.per_threshold[&key];
        let theirs = p["mAP"].as_f64().expect("mAP");
        assert!(
            (ours - theirs).abs() < 1e-6,
            "t = {t}: mlod {ours} vs devkit {theirs}"
        );
        for (class, ap) in p["ap_per_class"].as_object().expect("classes") {
            let ours = report.lyft.per_class[&key][class];
            let theirs = ap.as_f64().expect("ap");
            assert!(
                (ours - theirs).abs() < 1e-6,
                "t = {t}, {class}: mlod {ours} vs devkit {theirs}"
            );
        }
    }
    let mean = expected["mAP_mean_over_thresholds"].as_f64().expect("mean");
    assert!((report.lyft.map - mean).abs() < 1e-6);
    // The true footprint judges offsets differently: the exact metric is not the devkit's.
    assert!((report.lyft_exact.map - report.lyft.map).abs() > 1e-3);
}

/// Predictions equal to the ground truth: every metric is perfect.
#[test]
fn ground_truth_as_predictions_is_perfect() {
    let ds = sample_data();
    let opts = EvalOptions {
        per_box: Some(MatchRule::default()),
        ..Default::default()
    };
    let mut dets = HashMap::new();
    for tok in eval::sample_tokens(&ds, &opts) {
        let info = ds.frame_info(&tok).expect("frame");
        let boxes = info
            .boxes
            .iter()
            .map(|b| mlod::geometry::Detection {
                box3d: b.box3d,
                score: 0.5,
                category: b.category.clone(),
            })
            .collect();
        dets.insert(tok, boxes);
    }
    let report = eval::evaluate_detections(&ds, &dets, &opts).expect("evaluates");
    // IoU 1 is above every threshold, 0.95 included.
    assert!((report.lyft.map - 1.0).abs() < 1e-9, "{}", report.lyft.map);
    assert!(
        (report.lyft_exact.map - 1.0).abs() < 1e-9,
        "{}",
        report.lyft_exact.map
    );
    for (class, per_t) in &report.kitti.0 {
        for (t, per_d) in &per_t.0 {
            for (d, ap) in &per_d.0 {
                if let Some(ap) = ap {
                    assert!((ap - 100.0).abs() < 1e-9, "{class} {t} {d}: {ap}");
                }
            }
        }
    }
    let per_box = report.per_box.expect("per-box");
    for s in &per_box {
        for p in &s.preds {
            assert!(
                matches!(p.outcome, PredOutcome::TruePositive { iou, .. } if (iou - 1.0).abs() < 1e-9)
                    || (p.range >= 50.0 && p.outcome == PredOutcome::Ignored),
                "{p:?}"
            );
        }
        assert!(s.gts.iter().all(|g| !matches!(g.outcome, GtOutcome::Missed)));
        // Every match carries its residuals, all zero for predictions equal to the truth.
        for g in &s.gts {
            match (g.outcome, g.error) {
                (GtOutcome::Matched { .. }, Some(e)) => {
                    let worst = [e.along, e.lateral, e.dz, e.dl, e.dw, e.dh, e.dyaw]
                        .iter()
                        .fold(0.0f64, |m, v| m.max(v.abs()));
                    assert!(worst < 1e-9, "{e:?}");
                }
                (GtOutcome::Matched { .. }, None) => panic!("a match without residuals: {g:?}"),
                (_, e) => assert!(e.is_none(), "{g:?}"),
            }
        }
    }
    let loc = report.localization.expect("localisation with per-box");
    let car = loc
        .iter()
        .find(|l| l.category == "car")
        .expect("cars are matched");
    assert!(car.matched > 10, "{}", car.matched);
    assert!(car.mean_abs.along < 1e-9 && car.mean_abs.dl < 1e-9 && car.bias.dyaw.abs() < 1e-9);
    for k in 0..3 {
        let c = car.size_corr[k].expect("sample_data's cars vary in size");
        assert!((c - 1.0).abs() < 1e-9, "size {k}: {c}");
        assert!((car.size_std_true[k] - car.size_std_pred[k]).abs() < 1e-9);
    }
}

/// Boxes 0.4 m too high (cars are 1.4–1.9 m tall) miss IoU 0.7 but not 0.5; the attribution finds that the vertical
/// residual (and only it, besides the whole box) costs the AP at 0.7.
#[test]
fn attribution_names_the_residual_that_costs_the_ap() {
    let ds = sample_data();
    let opts = EvalOptions {
        per_box: Some(MatchRule {
            iou_threshold: 0.5,
            ..MatchRule::default()
        }),
        attribution: true,
        ..Default::default()
    };
    let mut dets = HashMap::new();
    for tok in eval::sample_tokens(&ds, &opts) {
        let info = ds.frame_info(&tok).expect("frame");
        let boxes = info
            .boxes
            .iter()
            .filter(|b| b.category == "car")
            .map(|b| {
                let mut box3d = b.box3d;
                box3d.center[2] += 0.4;
                mlod::geometry::Detection {
                    box3d,
                    score: 0.5,
                    category: b.category.clone(),
                }
            })
            .collect();
        dets.insert(tok, boxes);
    }
    let report = eval::evaluate_detections(&ds, &dets, &opts).expect("evaluates");
    let att = report.attribution.expect("attribution");
    let fixes: Vec<Fix> = att.iter().map(|a| a.fixed).collect();
    assert_eq!(fixes, Fix::ALL.to_vec());
    let moderate = |a: &eval::Attribution, t: &str| -> f64 {
        a.kitti
            .get("car")
            .and_then(|per_t| per_t.get(t))
            .and_then(|d| d.get("moderate"))
            .copied()
            .flatten()
            .expect("car AP")
    };
    for a in &att {
        let (ap7, ap5) = (moderate(a, "iou_0.7"), moderate(a, "iou_0.5"));
        assert!((ap5 - 100.0).abs() < 1e-9, "{:?} at 0.5: {ap5}", a.fixed);
        let fixed = matches!(a.fixed, Fix::Vertical | Fix::All);
        if fixed {
            assert!((ap7 - 100.0).abs() < 1e-9, "{:?} at 0.7: {ap7}", a.fixed);
        } else {
            assert!(ap7 < 1e-9, "{:?} at 0.7: {ap7}", a.fixed);
        }
    }
    // The unedited row is the report's own AP.
    let own = report
        .kitti
        .get("car")
        .and_then(|t| t.get("iou_0.7"))
        .and_then(|d| d.get("moderate"));
    assert_eq!(own.copied().flatten(), Some(moderate(&att[0], "iou_0.7")));
}
