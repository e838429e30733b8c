use super::*;

#[test]
fn run_with_mlod_i_draws_proposals_refinements_and_ground_truth_counted_like_eval() {
    let models = mlod_models();
    let mut h = harness_with(Some(mlod_session(0.04, ColorMode::Trace)), Some(models.clone()));
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    let rect = h.state().hover_state().0;
    const BLUE: [[u8; 4]; 2] = [PROPOSAL_COLOR, FALSE_POSITIVE_COLOR];
    const RED: [[u8; 4]; 2] = [REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR];
    let before = h.render().unwrap();
    let (blue0, red0) = (
        count_pixels(&before, rect, &BLUE),
        count_pixels(&before, rect, &RED),
    );
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let (view, counts) = h.state().detection().expect("MLOD-I ran");
    assert_eq!(view.case, Case::MlodI);
    let refinement = view
        .refinement
        .as_ref()
        .expect("an MLOD run holds its refinements");
    assert!(!view.detections.is_empty() && !refinement.refined.is_empty());

    // The library on the same frame and perturbation gives the same proposals and refinements.
    let token = h.state().frame().unwrap().sample_token.clone();
    let settings = h.state().session().detection;
    let run = load_mlod(&models, Case::MlodI, Voting::Manifest)
        .unwrap()
        .run(h.state().frame().unwrap(), &h.state().session().fuse)
        .unwrap();
    assert_eq!(run.proposals, view.detections);
    assert_eq!(run.refined, refinement.refined);
    // The counts are those of the evaluation's per-box matching of the drawn refined boxes (score
    // ≥ min score) at the panel's match IoU, no range limit.
    let drawn: Vec<Detection> = run
        .refined
        .iter()
        .map(|r| r.detection.clone())
        .filter(|d| d.score >= settings.min_score)
        .collect();
    let (tp, fp, missed) = eval_counts(&token, drawn.clone(), settings.match_iou, &view.categories);
    assert_eq!(counts.shown, drawn.len());
    assert_eq!(
        (counts.true_positives, counts.false_positives, counts.missed),
        (tp, fp, missed),
        "the panel counts the refined boxes as the evaluation does"
    );
    let proposals = view.proposal_counts(settings.min_score);
    let label = format!(
        "proposals: {} TP, {} FP, {} missed",
        proposals.true_positives, proposals.false_positives, proposals.missed
    );
    assert!(h.query_by_label_contains(&label).is_some(), "{label}");
    assert!(h
        .query_by_label_contains(&format!("{} refined boxes", counts.shown))
        .is_some());

    // Blue proposals, red refinements and green ground truth on screen; each layer's toggle.
    let img = h.render().unwrap();
    let (blue, red) = (count_pixels(&img, rect, &BLUE), count_pixels(&img, rect, &RED));
    let green = count_pixels(&img, rect, &[GT_COLOR]);
    assert!(blue > blue0 + 20, "blue {blue0} -> {blue}");
    assert!(red > red0 + 20, "red {red0} -> {red}");
    assert!(green > 50, "green {green}");
    // (Clicked through accesskit: the View section may be scrolled out of the panel.)
    h.get_by_label("refinements").click_accesskit();
    h.run_steps(2);
    let img = h.render().unwrap();
    assert!(count_pixels(&img, rect, &RED) <= red0, "refinements off");
    assert!(count_pixels(&img, rect, &BLUE) >= blue);
    h.get_by_label("refinements").click_accesskit();
    h.get_by_label("proposals").click_accesskit();
    h.run_steps(2);
    let img = h.render().unwrap();
    assert!(count_pixels(&img, rect, &BLUE) <= blue0, "proposals off");
    assert!(count_pixels(&img, rect, &RED) >= red);
    h.get_by_label("ground-truth boxes").click_accesskit();
    h.run_steps(2);
    let img = h.render().unwrap();
    let green_off = count_pixels(&img, rect, &[GT_COLOR]);
    assert!(green_off < green / 10, "ground truth off: {green} -> {green_off}");
    // The layers and the case are kept in the session.
    let saved = h.state().current_session().detection;
    assert_eq!(saved.case, Case::MlodI);
    assert!(!saved.show && saved.show_refined);
}

#[test]
fn hovering_or_clicking_a_refined_box_highlights_its_active_points() {
    let mut s = mlod_session(0.04, ColorMode::Source);
    s.detection.auto_run = true;
    s.detection.show_active = true;
    // Only the refined boxes compete for the pointer.
    s.detection.show = false;
    s.show_ground_truth = false;
    let mut h = harness_with(Some(s), Some(mlod_models()));
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    let rect = h.state().hover_state().0;
    let active = |h: &Harness<'static, MlodApp>| {
        let scene = h.state().viewport().1;
        scene
            .colors()
            .iter()
            .filter(|c| **c == ACTIVE_POINT_COLOR)
            .count()
    };
    assert_eq!(active(&h), 0, "nothing hovered or selected: nothing highlighted");
    // The refined box nearest the car with active points, where it is on screen.
    let (k, target) = {
        let app = h.state();
        let r = app.detection().unwrap().0.refinement.as_ref().unwrap();
        let cam = &app.viewport().0.camera;
        let min = app.session().detection.min_score;
        let mut order: Vec<usize> = (0..r.refined.len()).collect();
        order.sort_by(|&a, &b| {
            let d = |k: usize| r.refined[k].detection.box3d.bev_range();
            d(a).total_cmp(&d(b))
        });
        order
            .into_iter()
            .filter(|&k| !r.refined[k].active.is_empty() && r.refined[k].detection.score >= min)
            .find_map(|k| {
                let c = r.refined[k].detection.box3d.center;
                let p = cam.project([c[0] as f32, c[1] as f32, c[2] as f32], rect)?;
                rect.shrink(40.0).contains(p).then_some((k, p))
            })
            .expect("a refined box with active points in view")
    };
    let active_of = |h: &Harness<'static, MlodApp>, k: usize| {
        h.state()
            .detection()
            .unwrap()
            .0
            .refinement
            .as_ref()
            .unwrap()
            .refined[k]
            .active
            .len()
    };
    h.hover_at(target);
    h.run_steps(60);
    let (_, hovered, _) = h.state().hovered_detection();
    let hovered = hovered.expect("a refined box under the pointer");
    assert_eq!(h.state().highlighted_refined(), Some(hovered));
    assert_eq!(
        active(&h),
        active_of(&h, hovered),
        "every active point recoloured"
    );
    assert!(
        h.query_by_label_contains("classification head").is_some(),
        "refined tooltip"
    );
    assert!(h.query_by_label_contains("best GT 3D IoU").is_some());
    assert!(h.query_by_label_contains("points gathered").is_some());
    // A click selects it: the highlight stays once the pointer has left.
    h.drag_at(target);
    h.run_steps(1);
    h.event(egui::Event::PointerButton {
        pos: target,
        button: egui::PointerButton::Primary,
        pressed: false,
        modifiers: egui::Modifiers::NONE,
    });
    h.run_steps(1);
    h.remove_cursor();
    h.run_steps(2);
    let (_, hovered_now, selected) = h.state().hovered_detection();
    assert_eq!((hovered_now, selected), (None, Some(hovered)), "k = {k}");
    assert_eq!(h.state().highlighted_refined(), Some(hovered));
    assert_eq!(active(&h), active_of(&h, hovered));
    // Clicking empty space clears it.
    let empty = rect.min + egui::vec2(8.0, 8.0);
    h.hover_at(empty);
    h.run_steps(1);
    assert_eq!(h.state().hovered_detection().1, None, "the corner is empty");
    h.drag_at(empty);
    h.run_steps(1);
    h.drop_at(empty);
    h.run_steps(2);
    assert_eq!(h.state().hovered_detection().2, None);
    assert_eq!(active(&h), 0);
    // With the toggle off nothing is highlighted, even when selected.
    h.state_mut().select_refined(Some(hovered));
    h.run_steps(1);
    assert_eq!(active(&h), active_of(&h, hovered));
    h.state_mut().session_mut().detection.show_active = false;
    h.run_steps(2);
    assert_eq!(active(&h), 0);
}

#[test]
fn mlod_without_a_refiner_is_an_error_toast_and_keeps_the_state() {
    let dir = std::env::temp_dir().join(format!("mlod-gui-no-refiner-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let models = stage1_copy(&dir);
    let mut s = session_at(0.0, ColorMode::Source);
    s.detection.case = Case::Input;
    let mut h = harness_with(Some(s), Some(models.clone()));
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let before = h.state().detection().expect("stage 1 runs").0.detections.clone();
    h.state_mut().session_mut().detection.case = Case::MlodI;
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    let (view, _) = h.state().detection().expect("the last detection stays");
    assert_eq!((view.case, &view.detections), (Case::Input, &before));
    assert!(view.refinement.is_none());
    assert!(h.state().fused().is_some(), "the cloud stays");
    let error = h.state().first_error().expect("an error toast").to_string();
    assert!(
        error.contains("manifest.json") && error.contains("mlod train refiner"),
        "{error}"
    );
    assert!(h.query_by_label_contains("no refiner").is_some(), "shown");
    // A corrupt refiner file is an error naming it.
    std::fs::write(models.join("refiner.safetensors"), b"not a safetensors file").unwrap();
    let mut m = Manifest::load(&models).unwrap();
    let mut entry = m.models[&Case::Input].clone();
    entry.file = "refiner.safetensors".into();
    m.refiner = Some(entry);
    m.save(&models).unwrap();
    let mut h = harness_with(Some(mlod_session(0.0, ColorMode::Source)), Some(models));
    h.get_by_label("Run (D)").click();
    h.run_steps(3);
    assert!(h.state().detection().is_none());
    assert!(h.state().fused().is_some());
    let error = h.state().first_error().expect("an error toast").to_string();
    assert!(error.contains("refiner.safetensors"), "{error}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn calibrate_corrects_the_cloud_and_the_session_keeps_it() {
    let mut h = harness(Some(session_at(0.1, ColorMode::Trace)));
    let drifted = h.state().fused().unwrap().clone();
    assert!(h.query_by_label_contains("not calibrated").is_some());
    h.get_by_label("calibrate (ICP)").click();
    h.run_steps(3);
    let app = h.state();
    let cal = app.session().oc.calibration.clone().expect("calibrated");
    assert!(app.session().oc.show_corrected);
    let frame = app.frame().unwrap();
    let fused = app.fused().unwrap();
    assert!(fused.lidars[1].calibrated && fused.lidars[2].calibrated && !fused.lidars[0].calibrated);
    for l in &cal.lidars {
        let truth = frame.lidar(l.channel).unwrap().info.extrinsic;
        let (before, after) = (l.error_before(&truth), l.error(&truth));
        assert!(
            after.rot_deg < 0.1 * before.rot_deg,
            "{:?}: {before:?} -> {after:?}",
            l.channel
        );
    }
    // The cloud on screen is the library's fuse with that calibration, and its auxiliary points
    // carry ICP's (smaller) uncertainty.
    let mut params = app.session().fuse.clone();
    params.calibration = Some(cal.clone());
    let lib = mlod::pipeline::fuse(frame, &params).unwrap();
    assert_eq!(lib.x, fused.x);
    assert_eq!(lib.trace, fused.trace);
    let aux = fused.lidars[1].range.clone();
    let mean = |t: &[f32]| t.iter().map(|&v| v as f64).sum::<f64>() / t.len() as f64;
    assert!(mean(&fused.trace[aux.clone()]) < 0.2 * mean(&drifted.trace[aux.clone()]));
    // The panel shows the error before → after per LiDAR.
    // (two LiDAR rows and the caption)
    assert_eq!(h.query_all_by_label_contains(" -> ").count(), 3);
    // A saved session reopens with the same corrected cloud, pixel for pixel (ICP not rerun);
    // the pointer leaves the window first so no hover differs.
    h.event(egui::Event::PointerGone);
    h.run_steps(2);
    let img_a = h.render().unwrap();
    let session = h.state().current_session();
    let json = serde_json::to_string(&session).unwrap();
    let mut b = harness(Some(serde_json::from_str(&json).unwrap()));
    assert_eq!(b.state().fused().unwrap().x, lib.x);
    let img_b = b.render().unwrap();
    if std::env::var_os("MLOD_DEBUG_IMG").is_some() {
        img_a.save("/tmp/oc_a.png").unwrap();
        img_b.save("/tmp/oc_b.png").unwrap();
    }
    assert!(
        img_a.as_raw() == img_b.as_raw(),
        "the session reopens differently"
    );
    // The toggle shows the drifted cloud again; a new drift drops the calibration.
    h.state_mut().session_mut().oc.show_corrected = false;
    h.state_mut().mark_fuse();
    h.run_steps(2);
    assert_eq!(h.state().fused().unwrap().x, drifted.x);
    assert!(h.state().session().oc.calibration.is_some());
    h.state_mut().session_mut().fuse.perturbation.seed = 9;
    h.state_mut().mark_fuse();
    h.run_steps(2);
    assert!(
        h.state().session().oc.calibration.is_none(),
        "a calibration of another drift was kept"
    );
}

#[test]
fn an_oc_case_calibrates_then_detects_on_the_corrected_cloud() {
    let mut s = session_at(0.1, ColorMode::Source);
    s.detection.case = Case::InputOc;
    let mut h = harness(Some(s));
    h.get_by_label("Run (D)").click();
    h.run_steps(4);
    let app = h.state();
    assert!(app.session().oc.show_corrected && app.session().oc.calibration.is_some());
    let (view, counts) = app.detection().expect("the (OC) case ran");
    assert_eq!(view.case, Case::InputOc);
    assert!(!app.detection_is_stale());
    // Its boxes are the library's Input Fusion (OC) boxes on this frame, behind the folder's gate.
    let det = mlod::cases::load_gated(
        &assets_models(),
        Case::InputOc,
        mlod::cases::ground_gate::GateChoice::Manifest,
    )
    .unwrap();
    let lib = det.detect(app.frame().unwrap(), &app.session().fuse).unwrap();
    assert_eq!(view.detections, lib);
    assert!(counts.true_positives > 0, "{counts:?}");
    // Another case runs on the drifted cloud again.
    h.state_mut().session_mut().detection.case = Case::Input;
    h.state_mut().run_detector();
    h.run_steps(3);
    assert!(!h.state().session().oc.show_corrected);
    assert!(!h.state().fused().unwrap().lidars[1].calibrated);
}
