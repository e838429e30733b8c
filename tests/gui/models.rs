//! File > Open models folder…: the window switches its detectors to another folder (and says
//! which), refuses a folder whose manifest does not load without losing what is on screen, and a
//! saved session reopens on the folder it used. On one-LiDAR (real) samples the shipped chain
//! runs behind its ground gate.

use egui_kittest::kittest::Queryable;
use mlod::cases::ground_gate::{gated, GateChoice};
use mlod::detect::Case;
use mlod::pipeline::FuseParams;
use mlod::session::Session;

use super::{assets_models, harness, harness_full, kitti_fixture};

/// LiDAR-Top of `models` behind the folder's gate on the frame on screen, as `mlod detect` runs it.
fn cli_top(models: &std::path::Path, frame: &mlod::dataset::Frame) -> Vec<mlod::detect::Detection> {
    let det = gated(
        mlod::detect::model::load_detector(models, Case::Top).unwrap(),
        GateChoice::Manifest,
        models,
    )
    .unwrap();
    det.detect(frame, &FuseParams::default()).unwrap()
}

#[test]
fn a_one_lidar_sample_runs_the_shipped_chain_and_another_folder_takes_over() {
    // A second folder: the shipped weights without the ground gate and the box voting.
    let other = crate::common::shipped_without("gui-models", &["ground_gate", "vote"]);
    let (mut h, _) = harness_full(kitti_fixture(), None, None);
    assert_eq!(h.state().session().detection.case, Case::Top);
    assert!(h.query_by_label_contains("models: assets/models").is_some());
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let frame = h.state().frame().unwrap().clone();
    let shipped = h.state().detection().expect("LiDAR-Top ran").0.detections.clone();
    // The shipped chain runs behind its ground gate, as `mlod detect` runs it.
    assert_eq!(shipped, cli_top(&assets_models(), &frame));
    assert!(h.query_by_label_contains("ground gate 0.5 m").is_some());

    // File > Open models folder… switches the folder and runs the case again from it.
    h.state_mut().open_models(other.clone(), 0.0);
    assert!(h
        .state()
        .toast_texts()
        .iter()
        .any(|t| t.starts_with("detectors from") && t.ends_with("models")));
    h.run_steps(3);
    assert_eq!(h.state().models_dir(), other.as_path());
    let (view, _) = h.state().detection().expect("the switch ran LiDAR-Top again");
    assert_eq!(view.detections, cli_top(&other, &frame));
    assert_ne!(view.detections, shipped, "another model gives other boxes");
    assert!(h.query_by_label_contains("models: assets/models").is_none());
    assert!(
        h.query_by_label_contains("ground gate").is_none(),
        "the second folder records no gate"
    );

    // The session remembers the folder, and a window opened on it runs from it.
    let s = h.state().current_session();
    assert_eq!(s.models.as_deref(), Some(other.as_path()));
    let json = serde_json::to_string(&s).unwrap();
    let back: Session = serde_json::from_str(&json).unwrap();
    let (h2, _) = harness_full(kitti_fixture(), Some(back), None);
    assert_eq!(h2.state().models_dir(), other.as_path());
    assert!(h2.query_by_label_contains("models: assets/models").is_none());
}

#[test]
fn a_models_folder_that_does_not_load_leaves_the_window_as_it_was() {
    let dir = std::env::temp_dir().join(format!("mlod-gui-bad-models-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("manifest.json"), b"{ \"models\": ").unwrap();
    let mut h = harness(None);
    h.state_mut().session_mut().detection.case = Case::Top;
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let before = h.state().detection().expect("LiDAR-Top ran").0.detections.clone();
    h.state_mut().open_models(dir.clone(), 0.0);
    h.run_steps(2);
    assert_eq!(h.state().models_dir(), assets_models().as_path());
    assert_eq!(h.state().current_session().models, None);
    let toasts = h.state().toast_texts().join("\n");
    assert!(
        toasts.contains("cannot open the models folder") && toasts.contains("manifest.json"),
        "{toasts}"
    );
    assert_eq!(h.state().detection().unwrap().0.detections, before);
    // A folder with no manifest at all: the same.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    h.state_mut().open_models(empty, 0.0);
    h.run_steps(2);
    assert_eq!(h.state().models_dir(), assets_models().as_path());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_adapted_folder_is_named_as_such() {
    // The shipped weights with the record `mlod train adapt` writes.
    let dir = crate::common::shipped_without("gui-adapted", &[]);
    let path = dir.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    m["adapted"] = serde_json::json!({
        "base": "assets/models", "base_manifest_sha256": "0", "dataset": "my-kitti",
        "samples": 10, "cases": ["top"], "steps": 1500, "command": "mlod train adapt"
    });
    std::fs::write(&path, serde_json::to_string(&m).unwrap()).unwrap();
    let (mut h, _) = harness_full(kitti_fixture(), None, None);
    assert!(h.query_by_label_contains("(adapted)").is_none());
    h.state_mut().open_models(dir.clone(), 0.0);
    h.run_steps(2);
    assert!(h.query_by_label_contains("(adapted)").is_some());
    let toasts = h.state().toast_texts().join("\n");
    assert!(
        toasts.contains("adapted to my-kitti (10 labelled frames; top) from assets/models"),
        "{toasts}"
    );
}
