//! The whole debugger driven headlessly (egui_kittest on wgpu; lavapipe with
//! `WGPU_BACKEND=vulkan` in CI): snapshots of the main states, the α slider moving the fused cloud
//! and the legend, and a session round trip that reproduces identical pixels.

use egui::accesskit::Role;
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use mlod::color::ColorMode;
use mlod::detect::Case;
use mlod::gui::viewport::View;
use mlod::gui::{default_dataset, AppOptions, MlodApp};
use mlod::session::Session;
use mlod::uncertainty::Perturbation;

fn harness(session: Option<Session>) -> Harness<'static, MlodApp> {
    harness_with(session, None)
}

fn harness_with(session: Option<Session>, models: Option<std::path::PathBuf>) -> Harness<'static, MlodApp> {
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .wgpu()
        .build_eframe(move |cc| {
            MlodApp::new(
                cc,
                AppOptions {
                    dataset: default_dataset(),
                    session,
                    synchronous: true,
                    measure_frames: None,
                    models,
                },
            )
        });
    h.run_steps(3);
    h
}

fn session_at(alpha: f64, mode: ColorMode) -> Session {
    let mut s = Session::new(default_dataset());
    s.fuse.perturbation = Perturbation::new(alpha, 0).unwrap();
    s.color.mode = mode;
    s
}

#[test]
fn snapshot_overview() {
    let mut h = harness(None);
    assert!(h.state().fused().is_some(), "the first sample is drawn");
    h.snapshot("overview");
}

#[test]
fn snapshot_alpha_004_trace_and_bev() {
    let mut h = harness(Some(session_at(0.04, ColorMode::Trace)));
    h.snapshot("alpha_0.04_trace");
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    h.snapshot("bev");
}

#[test]
fn alpha_slider_moves_the_cloud_and_changes_the_legend() {
    let mut h = harness(None);
    let before = h.state().fused().unwrap().clone();
    let (frac_before, hist_before) = {
        let (f, hi) = h.state().uncertainty_summary();
        (f, hi.to_vec())
    };
    let img_before = h.render().unwrap();
    // The first slider of the controls panel is α.
    h.get_all_by_role(Role::Slider)
        .next()
        .expect("the α slider")
        .set_value_accesskit(0.04);
    h.run_steps(3);
    let app = h.state();
    assert_eq!(app.session().fuse.perturbation.alpha, 0.04);
    let after = app.fused().unwrap();
    let top = after.lidars[0].range.clone();
    assert_eq!(
        &after.x[top.clone()],
        &before.x[top],
        "LiDAR-Top is the base frame: never moved"
    );
    let aux = after.lidars[1].range.clone();
    assert_ne!(&after.x[aux.clone()], &before.x[aux], "auxiliary points moved");
    let (frac_after, hist_after) = app.uncertainty_summary();
    assert_eq!(frac_before, 0.0);
    assert!(frac_after > 0.05, "uncertain share {frac_after}");
    assert_ne!(
        hist_before,
        hist_after.to_vec(),
        "the histogram (legend panel) changed"
    );
    let img_after = h.render().unwrap();
    assert_ne!(img_before.as_raw(), img_after.as_raw());
}

#[test]
fn session_round_trip_reproduces_identical_pixels() {
    let mut s = session_at(0.04, ColorMode::Trace);
    s.fuse.perturbation.seed = 5;
    s.color.highlight_above = Some(0.05);
    let mut a = harness(Some(s));
    a.state_mut().set_preset(View::Chase);
    a.run_steps(2);
    let img_a = a.render().unwrap();
    let path = std::env::temp_dir().join(format!("mlod-gui-session-{}.json", std::process::id()));
    a.state().current_session().save(&path).unwrap();
    let loaded = Session::load(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    assert_eq!(
        loaded.sampled,
        a.state().session().sampled,
        "the sampled perturbation is stored"
    );
    let mut b = harness(Some(loaded));
    let img_b = b.render().unwrap();
    assert_eq!(img_a.dimensions(), img_b.dimensions());
    assert!(
        img_a.as_raw() == img_b.as_raw(),
        "the loaded session draws different pixels"
    );
}

#[test]
fn bad_dataset_keeps_the_window_up_with_an_error() {
    let mut h = Harness::builder()
        .with_size(egui::vec2(800.0, 500.0))
        .wgpu()
        .build_eframe(|cc| {
            MlodApp::new(
                cc,
                AppOptions {
                    dataset: "/nonexistent/dataset".into(),
                    session: None,
                    synchronous: true,
                    measure_frames: None,
                    models: None,
                },
            )
        });
    h.run_steps(3);
    assert!(h.state().fused().is_none());
    // The error toast names the folder.
    assert!(h.query_by_label_contains("/nonexistent/dataset").is_some());
    // Opening a good dataset afterwards works.
    h.state_mut().open_dataset(default_dataset());
    h.run_steps(3);
    assert!(h.state().fused().is_some());
}

#[test]
fn hovering_a_ground_truth_box_shows_its_tooltip() {
    let mut h = harness(Some(session_at(0.04, ColorMode::Trace)));
    let (rect, _) = h.state().hover_state();
    // The nearest box in front of the camera, projected like the renderer does.
    let (target, stats_expected) = {
        let app = h.state();
        let frame = app.frame().unwrap();
        let cam = &app.viewport().0.camera;
        let mut best = None;
        for b in &frame.boxes {
            let c = b.box3d.center;
            if let Some(p) = cam.project([c[0] as f32, c[1] as f32, c[2] as f32], rect) {
                if rect.shrink(40.0).contains(p) && b.box3d.bev_range() < 25.0 {
                    best = Some((p, mlod::pipeline::box_stats(app.fused().unwrap(), &b.box3d)));
                    break;
                }
            }
        }
        best.expect("a box near the car is in view")
    };
    h.hover_at(target);
    // Tooltips appear after egui's hover delay: let a second of frames pass.
    h.run_steps(60);
    let (_, hovered) = h.state().hover_state();
    let (_, stats) = hovered.expect("a box is hovered");
    assert!(stats.points > 0);
    assert!(stats_expected.points > 0);
    assert!(
        h.query_by_label_contains("ground truth:").is_some(),
        "tooltip shown"
    );
    assert!(h.query_by_label_contains("mean tr(Ξ) inside").is_some());
}

#[test]
fn run_button_draws_proposals_matched_against_the_ground_truth() {
    let mut s = session_at(0.0, ColorMode::Source);
    s.detection.case = Case::Top;
    let mut h = harness(Some(s));
    assert!(h.state().detection().is_none());
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let (view, counts) = h.state().detection().expect("the detector ran");
    assert_eq!(view.case, Case::Top);
    assert_eq!(view.token, h.state().frame().unwrap().sample_token);
    assert!(counts.shown > 0 && counts.true_positives > 0, "{counts:?}");
    assert_eq!(counts.true_positives + counts.false_positives, counts.shown);
    // Car-only model: only the cars count as missed; every car is either matched or missed.
    let cars = h
        .state()
        .frame()
        .unwrap()
        .boxes
        .iter()
        .filter(|b| b.category == "car")
        .count();
    assert_eq!(counts.ground_truth, cars);
    assert_eq!(counts.missed + counts.true_positives, cars);
    // The panel reports the same counts the app computed.
    assert!(h
        .query_by_label_contains(&format!("{} TP", counts.true_positives))
        .is_some());
    assert!(!h.state().detection_is_stale());
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    h.snapshot("detections_top_bev");
    // Raising the match IoU can only turn true positives into false positives.
    let tp_07 = counts.true_positives;
    h.state_mut().session_mut().detection.match_iou = 0.5;
    h.state_mut().rematch();
    let (_, c05) = h.state().detection().unwrap();
    assert!(c05.true_positives >= tp_07);
    // Moving α makes the result stale (it was computed on the unperturbed cloud).
    h.state_mut().session_mut().fuse.perturbation = Perturbation::new(0.04, 0).unwrap();
    h.state_mut().mark_fuse();
    h.run_steps(2);
    assert!(h.state().detection_is_stale());
    assert!(h.query_by_label_contains("Run again").is_some());
}

#[test]
fn auto_run_follows_the_perturbation() {
    let mut s = session_at(0.0, ColorMode::Trace);
    s.detection.case = Case::Input;
    s.detection.auto_run = true;
    let mut h = harness(Some(s));
    let before = h
        .state()
        .detection()
        .expect("auto-run on load")
        .0
        .detections
        .clone();
    h.state_mut().session_mut().fuse.perturbation = Perturbation::new(0.1, 0).unwrap();
    h.state_mut().mark_fuse();
    h.run_steps(3);
    assert!(!h.state().detection_is_stale());
    let after = &h.state().detection().unwrap().0.detections;
    assert_ne!(&before, after, "Input Fusion sees the perturbed auxiliary LiDARs");
}

#[test]
fn export_fused_cloud_writes_the_cloud_on_screen() {
    let mut h = harness(Some(session_at(0.04, ColorMode::Trace)));
    h.run_steps(2);
    let dir = std::env::temp_dir().join(format!("mlod-gui-export-{}", std::process::id()));
    let path = dir.join("view.ply");
    let n = h.state().export_cloud(&path).expect("export");
    let cloud = h.state().fused().unwrap();
    assert_eq!(n, cloud.len());
    let back = mlod::export::read_file(&path).unwrap();
    assert_eq!(back.x, cloud.x);
    assert_eq!(back.trace, cloud.trace);
    assert!(
        back.comments.iter().any(|c| c.contains("alpha 0.04")),
        "{:?}",
        back.comments
    );
    // No extension, no format: an error naming the file, and nothing written.
    let e = h.state().export_cloud(&dir.join("view")).unwrap_err();
    assert!(e.contains("view"), "{e}");
    assert!(!dir.join("view").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn missing_weights_are_an_error_and_keep_the_cloud() {
    let mut h = harness_with(None, Some("/nonexistent/models".into()));
    h.state_mut().run_detector();
    h.run_steps(3);
    assert!(h.state().detection().is_none());
    assert!(h.state().fused().is_some(), "the cloud stays");
    assert!(
        h.query_by_label_contains("/nonexistent/models").is_some(),
        "the error names the folder"
    );
}

/// Writes the sessions behind `screenshots/*.png` (run by `screenshots/make.sh`).
#[test]
#[ignore]
fn write_screenshot_sessions() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("screenshots");
    let save = |h: &Harness<'static, MlodApp>, name: &str| {
        let mut s = h.state().current_session();
        s.dataset = "sample_data".into();
        s.save(&dir.join(format!("{name}.session.json"))).unwrap();
    };
    // Overview: the three LiDARs in the paper's colours, no perturbation.
    let mut h = harness(Some(session_at(0.0, ColorMode::Source)));
    h.state_mut().set_preset(View::Overview);
    h.run_steps(2);
    save(&h, "overview");
    // α = 0.04, tr(Ξ), close-up on a car near the ego with uncertain points highlighted off.
    let mut s = session_at(0.04, ColorMode::Trace);
    s.color.scale = mlod::color::Scale::Log;
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Chase);
    let target = {
        let f = h.state().frame().unwrap();
        let b = f
            .boxes
            .iter()
            .filter(|b| b.category == "car")
            .min_by(|a, b| a.box3d.bev_range().total_cmp(&b.box3d.bev_range()))
            .unwrap();
        [
            b.box3d.center[0] as f32,
            b.box3d.center[1] as f32,
            b.box3d.center[2] as f32,
        ]
    };
    h.state_mut().focus_camera(target, 14.0);
    h.run_steps(2);
    save(&h, "alpha_0.04_trace");
    // Bird's eye at α = 0.1 with the uncertain points highlighted.
    let mut s = session_at(0.1, ColorMode::Trace);
    s.color.highlight_above = Some(0.05);
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    save(&h, "bev");
    // Stage-1 detection: Input Fusion at α = 0.04 run on load, proposals (blue, false positives
    // greyed) over the ground truth (green), chase view over the cars ahead.
    let mut s = session_at(0.04, ColorMode::Height);
    s.color.scale = mlod::color::Scale::Linear;
    s.auto_range = true;
    s.detection.case = Case::Input;
    s.detection.auto_run = true;
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Chase);
    h.run_steps(2);
    save(&h, "detections");
}
