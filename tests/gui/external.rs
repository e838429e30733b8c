//! The window with an external detector (issue 31): a session naming one starts nothing until the
//! user has seen the command and said yes; then the case is in the list, Run draws its boxes, and
//! a detector that crashes is a toast that keeps the state.

use mlod::detect::Case;
use mlod::external::{spawn_count, ExternalSpec};
use mlod::session::Session;

use egui_kittest::kittest::{NodeT, Queryable};
use mlod::color::ColorMode;

use super::{harness, session_at};

const FAKE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/detectors/fake.py");

/// A saved session running `ext:NAME` with fake.py in `mode`, loaded back from its file.
fn session_with(dir: &std::path::Path, name: &str, mode: &str) -> (Session, String) {
    let first = mlod::dataset::Dataset::open(mlod::gui::default_dataset())
        .unwrap()
        .first_sample_token()
        .unwrap()
        .to_string();
    let boxes = dir.join("boxes.json");
    let b = serde_json::json!({ first: [
        {"category": "car", "score": 0.8, "center": [12.0, 3.0, -1.0], "size_lwh": [4.5, 1.9, 1.6], "yaw": 0.3}
    ]});
    std::fs::write(&boxes, b.to_string()).unwrap();
    let stats = dir.join(format!("{name}.jsonl"));
    let words = [
        "python3",
        FAKE,
        mode,
        &boxes.display().to_string(),
        &stats.display().to_string(),
    ];
    let spec = ExternalSpec::new(name, words.iter().map(|w| w.to_string()).collect()).unwrap();
    let mut s = session_at(0.0, ColorMode::Source);
    s.detection.case = format!("ext:{name}").parse().unwrap();
    s.external = vec![spec.clone()];
    let path = dir.join(format!("{name}.session.json"));
    s.save(&path).unwrap();
    (Session::load(&path).unwrap(), spec.command_line())
}

#[test]
fn an_external_case_asks_before_anything_runs() {
    let dir = std::env::temp_dir().join(format!("mlod-gui-ext-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (session, command) = session_with(&dir, "guiext", "replay");
    let mut h = harness(Some(session));
    h.run_steps(3);
    assert_eq!(spawn_count(&command), 0, "loading the session started nothing");
    assert!(h.state().consent_pending().is_none());
    // The case list offers it (and the refiner on it).
    h.query_all_by_label("case")
        .find(|n| n.accesskit_node().role() == egui::accesskit::Role::ComboBox)
        .expect("the case list")
        .click();
    h.run_steps(2);
    assert!(h.query_by_label("mlod-ext:guiext").is_some());
    h.key_press(egui::Key::Escape);
    h.run_steps(1);
    // Run asks first, showing the command; nothing runs before the answer.
    h.get_by_label("Run (D)").click();
    h.run_steps(2);
    assert_eq!(h.state().consent_pending().as_deref(), Some(command.as_str()));
    assert!(h.query_by_label_contains("Run an external detector?").is_some());
    assert!(
        h.query_by_label_contains("fake.py").is_some(),
        "the command is shown"
    );
    assert_eq!(spawn_count(&command), 0);
    h.get_by_label("Run it").click();
    h.run_steps(3);
    assert_eq!(spawn_count(&command), 1);
    let (view, counts) = h.state().detection().expect("the detector ran");
    assert_eq!(view.case, "ext:guiext".parse::<Case>().unwrap());
    assert_eq!(view.detections.len(), 1);
    assert_eq!(view.detections[0].box3d.center, [12.0, 3.0, -1.0]);
    assert_eq!(counts.shown, 1);
    // The same process keeps serving: a second run starts nothing new and asks nothing.
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    assert_eq!(spawn_count(&command), 1);
    assert!(h.state().consent_pending().is_none());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_crashing_external_detector_is_a_toast() {
    let dir = std::env::temp_dir().join(format!("mlod-gui-ext-crash-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (session, command) = session_with(&dir, "guicrash", "crash");
    let mut h = harness(Some(session));
    h.get_by_label("Run (D)").click();
    h.run_steps(2);
    h.get_by_label("Run it").click();
    h.run_steps(3);
    assert_eq!(spawn_count(&command), 1);
    assert!(h.state().detection().is_none());
    assert!(h.state().fused().is_some(), "the cloud stays");
    let error = h.state().first_error().expect("an error toast").to_string();
    assert!(
        error.contains("external detector 'guicrash'") && error.contains("exited"),
        "{error}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
