use super::*;

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
    assert_eq!(
        h.state().session().color.mode,
        ColorMode::Source,
        "first sight: the LiDARs in their colours"
    );
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
    assert_eq!(
        app.session().color.mode,
        ColorMode::Trace,
        "α left 0: the colouring shows tr(Ξ)"
    );
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
fn a_colouring_the_user_chose_survives_the_first_drift() {
    let mut h = harness(None);
    h.get_by_label("height").click();
    h.run_steps(2);
    assert_eq!(h.state().session().color.mode, ColorMode::Height);
    h.get_all_by_role(Role::Slider)
        .next()
        .expect("the α slider")
        .set_value_accesskit(0.02);
    h.run_steps(3);
    assert_eq!(h.state().session().fuse.perturbation.alpha, 0.02);
    assert_eq!(h.state().session().color.mode, ColorMode::Height);
    // A session (here: the default one, given explicitly) keeps its colouring at any α.
    let mut s = Session::new(default_dataset());
    s.color.mode = ColorMode::Source;
    s.fuse.perturbation = Perturbation::new(0.04, 0).unwrap();
    let h = harness(Some(s));
    assert_eq!(h.state().session().color.mode, ColorMode::Source);
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
                    measure_run: false,
                    models: None,
                    session_file: None,
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
fn a_models_folder_with_a_ground_gate_runs_its_stage1_behind_it_and_says_so() {
    use mlod::cases::ground_gate::{gated, GateChoice};
    let mut s = session_at(0.0, ColorMode::Source);
    s.detection.case = Case::Top;
    // The shipped folder records a 0.5 m gate (`mlod train tune-gate`).
    let models = assets_models();
    let mut h = harness_with(Some(s.clone()), Some(models.clone()));
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let (view, _) = h.state().detection().expect("the detector ran");
    assert!(h.query_by_label_contains("ground gate 0.5 m").is_some());
    // The window's boxes are those of the folder's detector behind its gate, as `mlod detect`
    // runs it.
    let frame = h.state().frame().unwrap().clone();
    let det = gated(
        mlod::detect::model::load_detector(&models, Case::Top).unwrap(),
        GateChoice::Manifest,
        &models,
    )
    .unwrap();
    let want = det
        .detect(&frame, &mlod::pipeline::FuseParams::default())
        .unwrap();
    assert_eq!(view.detections, want);
    // Its checkbox switches the gate off: the case runs again, and shows what the gate dropped.
    h.get_by_label("ground gate 0.5 m").click();
    h.run_steps(3);
    assert!(!h.state().session().detection.ground_gate);
    let ungated = mlod::detect::model::load_detector(&models, Case::Top)
        .unwrap()
        .detect(&frame, &mlod::pipeline::FuseParams::default())
        .unwrap();
    let (view, _) = h.state().detection().expect("the detector ran again");
    assert_eq!(view.detections, ungated);
    assert!(ungated.len() > want.len(), "the gate drops something here");
    h.get_by_label("ground gate 0.5 m").click();
    h.run_steps(3);
    assert_eq!(h.state().detection().unwrap().0.detections, want);
    // A folder without a gate: the panel says nothing of one.
    let no_gate = common::shipped_without("gui-gate", &["ground_gate"]);
    let mut h = harness_with(Some(s), Some(no_gate));
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    assert!(h.state().detection().is_some());
    assert!(h.query_by_label_contains("ground gate").is_none());
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
    let toasts = h.state().toast_texts().join("\n");
    assert!(
        toasts.contains("/nonexistent/models"),
        "the error names the folder: {toasts}"
    );
}
