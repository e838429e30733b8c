use super::*;

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
    // MLOD-I at α = 0.04, run on load: proposals (blue), refinements (red, joined to their
    // proposals) and ground truth (green) over the points coloured by tr(Ξ). Needs the shipped
    // refiner in assets/models when the screenshot is taken.
    let mut s = mlod_session(0.04, ColorMode::Trace);
    s.color.scale = mlod::color::Scale::Log;
    s.detection.auto_run = true;
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Chase);
    h.run_steps(2);
    save(&h, "mlod_i");
    // Online calibration at α = 0.1, bird's eye, LiDARs in the paper's colours: the drifted
    // cloud (walls and cars doubled where the LiDARs overlap), then the same view after ICP.
    let mut h = harness(Some(session_at(0.1, ColorMode::Source)));
    h.state_mut().set_preset(View::Bev);
    h.state_mut().focus_camera([12.0, 0.0, 0.0], 30.0);
    h.run_steps(2);
    save(&h, "calibration_before");
    h.get_by_label("calibrate (ICP)").click();
    h.run_steps(3);
    assert!(h.state().session().oc.show_corrected);
    save(&h, "calibration_after");
    // The paper's Fig. 6 on our data: Input Fusion (left) and MLOD-I (right) on the same frame at
    // α = 0.04, one camera, run on load.
    let mut s = session_at(0.04, ColorMode::Trace);
    s.detection.case = Case::Input;
    s.detection.auto_run = true;
    s.compare = Some(Case::MlodI);
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Chase);
    h.run_steps(3);
    assert!(h.state().compare_detection().is_some());
    save(&h, "compare");
    // A selected refined box (the one whose IoU gained most) with its active points, focused.
    let mut s = mlod_session(0.04, ColorMode::Trace);
    s.detection.auto_run = true;
    s.detection.show_active = true;
    let mut h = harness(Some(s));
    h.run_steps(3);
    let k = {
        let r = h.state().detection().unwrap().0.refinement.as_ref().unwrap();
        (0..r.refined.len())
            .filter(|&k| matches!(r.outcomes[k], PredOutcome::TruePositive { .. }))
            .max_by(|&a, &b| {
                (r.iou_after[a] - r.iou_before[a]).total_cmp(&(r.iou_after[b] - r.iou_before[b]))
            })
            .unwrap()
    };
    h.state_mut()
        .select_box(Some((mlod::session::BoxLayer::Refined, k)));
    h.state_mut().set_preset(View::Chase);
    h.state_mut().focus_selection();
    h.run_steps(2);
    save(&h, "selected");
    // The failure browser: MLOD-I over the scene at α = 0.1, scanned on load.
    let mut s = mlod_session(0.1, ColorMode::Trace);
    s.failures = Some(mlod::session::FailureScope::Scene);
    s.detection.auto_run = true;
    let mut h = harness(Some(s));
    h.state_mut().set_preset(View::Bev);
    h.run_steps(3);
    assert!(h
        .state()
        .failure_browser()
        .and_then(|b| b.result.as_ref())
        .is_some());
    save(&h, "failures");
    // The sweep window on the shipped chain's Table II (the walled world, 17 rows with the (OC)
    // cases, the ablations and the cases beyond the paper), over the first sight.
    const SWEEP: &str = "docs/sweeps/v6w/table2";
    let mut h = harness(Some(session_at(0.0, ColorMode::Source)));
    h.state_mut().open_sweep(&dir.join("..").join(SWEEP)).unwrap();
    h.run_steps(2);
    let mut s = h.state().current_session();
    s.dataset = "sample_data".into();
    s.sweep = Some(SWEEP.into());
    s.save(&dir.join("sweep.session.json")).unwrap();
}

#[test]
fn a_selected_box_shows_what_eval_per_box_reports_and_survives_alpha_and_sessions() {
    use mlod::eval::BoxError;
    use mlod::gui::SelectionDetails;
    use mlod::session::BoxLayer;
    let models = mlod_models();
    let mut s = mlod_session(0.04, ColorMode::Trace);
    s.detection.auto_run = true;
    let mut h = harness_with(Some(s), Some(models.clone()));
    h.run_steps(3);
    let settings = h.state().session().detection;
    // The best-scoring refined box that is a true positive.
    let (k, drawn) = {
        let (v, _) = h.state().detection().expect("MLOD-I ran on load");
        let r = v.refinement.as_ref().unwrap();
        let k = (0..r.refined.len())
            .find(|&k| matches!(r.outcomes[k], PredOutcome::TruePositive { .. }))
            .expect("a true positive");
        let drawn: Vec<Detection> = r
            .refined
            .iter()
            .map(|x| x.detection.clone())
            .filter(|d| d.score >= settings.min_score)
            .collect();
        (k, drawn)
    };
    h.state_mut().select_box(Some((BoxLayer::Refined, k)));
    h.run_steps(2);
    let d = match h.state().selection_details() {
        Some(SelectionDetails::Prediction { details, .. }) => (**details).clone(),
        other => panic!("prediction details expected, got {other:?}"),
    };
    let truth = d.truth.clone().expect("its ground truth");
    assert!(truth.matched);
    // `mlod eval --per-box` on the drawn refined boxes, at the panel's match IoU: the same truth,
    // IoU and residuals.
    let token = h.state().frame().unwrap().sample_token.clone();
    let sample = per_box_sample(&token, drawn, settings.match_iou);
    let g = sample
        .gts
        .iter()
        .find(|g| g.annotation_token == truth.annotation_token)
        .expect("the truth in the per-box report");
    let GtOutcome::Matched { iou, .. } = g.outcome else {
        panic!("eval says {:?}", g.outcome)
    };
    assert!(
        (d.iou_after.unwrap() - iou).abs() < 1e-12,
        "{:?} vs {iou}",
        d.iou_after
    );
    assert_eq!(d.residual_after, g.error);
    // Before refinement: the proposal against the same truth.
    let frame = h.state().frame().unwrap();
    let (v, _) = h.state().detection().unwrap();
    let proposal = &v.detections[v.refinement.as_ref().unwrap().refined[k].proposal];
    let gt_box = &frame.boxes[truth.index].box3d;
    assert_eq!(
        d.residual_before,
        Some(BoxError::between(&proposal.box3d, gt_box))
    );
    assert_eq!(d.proposal_score, proposal.score);
    // The points inside are the library's count, split over the LiDARs.
    let refined_box = v.refinement.as_ref().unwrap().refined[k].detection.box3d;
    let stats = mlod::pipeline::box_stats(h.state().fused().unwrap(), &refined_box);
    assert_eq!(d.inside.total, stats.points);
    assert_eq!(
        d.inside.per_lidar.iter().map(|p| p.1).sum::<usize>(),
        stats.points
    );
    assert!(
        d.active.as_ref().is_some_and(|a| a.total > 0),
        "active points counted"
    );
    // The panel shows them.
    assert!(h.query_by_label_contains("Selected box").is_some());
    assert!(
        h.query_by_label(&format!("{iou:.3}")).is_some(),
        "IoU after {iou:.3} shown"
    );
    let active = d.active.as_ref().unwrap().total;
    assert!(h
        .query_by_label_contains(&format!("active points {active}:"))
        .is_some());

    // F points the camera at it.
    h.key_press(egui::Key::F);
    h.run_steps(2);
    let target = h.state().viewport().0.camera.target;
    let c = refined_box.center;
    assert!(
        (target[0] as f64 - c[0]).abs() < 1e-3 && (target[1] as f64 - c[1]).abs() < 1e-3,
        "{target:?} vs {c:?}"
    );

    // Another α: re-fused and re-run, the same object is selected again.
    h.get_all_by_role(Role::Slider)
        .next()
        .expect("the α slider")
        .set_value_accesskit(0.02);
    h.run_steps(4);
    assert_eq!(h.state().session().fuse.perturbation.alpha, 0.02);
    let sel = h.state().session().selection.clone().expect("kept");
    assert_eq!(sel.annotation.as_deref(), Some(truth.annotation_token.as_str()));
    let (layer, k2) = h.state().selected_box().expect("found again at α = 0.02");
    assert_eq!(layer, BoxLayer::Refined);
    let (v, _) = h.state().detection().unwrap();
    let PredOutcome::TruePositive { gt, .. } = v.refinement.as_ref().unwrap().outcomes[k2] else {
        panic!("the re-found box is not a match")
    };
    assert_eq!(gt, truth.index, "on the same ground-truth object");

    // A saved session reopens with the same selection, pixel for pixel.
    let path = std::env::temp_dir().join(format!("mlod-gui-selection-{}.json", std::process::id()));
    h.state().current_session().save(&path).unwrap();
    let loaded = Session::load(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    assert_eq!(loaded.selection, h.state().session().selection);
    let img_a = h.render().unwrap();
    let mut b = harness_with(Some(loaded), Some(models));
    b.run_steps(3);
    assert_eq!(b.state().selected_box(), h.state().selected_box());
    assert_eq!(b.state().selection_details(), h.state().selection_details());
    let img_b = b.render().unwrap();
    assert!(
        img_a.as_raw() == img_b.as_raw(),
        "the reopened session draws other pixels"
    );

    // Escape clears it; a ground-truth box can be selected too.
    h.key_press(egui::Key::Escape);
    h.run_steps(2);
    assert!(h.state().session().selection.is_none() && h.state().selected_box().is_none());
    h.state_mut().select_box(Some((BoxLayer::Truth, truth.index)));
    h.run_steps(2);
    match h.state().selection_details() {
        Some(SelectionDetails::Truth {
            annotation,
            detected_iou,
            ..
        }) => {
            assert_eq!(annotation, &truth.annotation_token);
            assert!(detected_iou.is_some(), "detected at α = 0.02");
        }
        other => panic!("truth details expected, got {other:?}"),
    }
}

#[test]
fn compare_mode_runs_two_cases_on_the_same_frame_counted_like_eval() {
    let models = mlod_models();
    let mut s = mlod_session(0.04, ColorMode::Trace);
    s.detection.case = Case::Input;
    s.compare = Some(Case::MlodI);
    let mut h = harness_with(Some(s), Some(models.clone()));
    h.state_mut().set_preset(View::Bev);
    h.run_steps(2);
    h.get_by_label("Run (D)").click();
    h.run_steps(4);
    let settings = h.state().session().detection;
    let token = h.state().frame().unwrap().sample_token.clone();
    let (a, ca) = h.state().detection().expect("Input Fusion ran");
    let (b, cb) = h.state().compare_detection().expect("MLOD-I ran beside it");
    assert_eq!((a.case, b.case), (Case::Input, Case::MlodI));
    // Both on the same perturbed frame: MLOD-I's proposals are Input Fusion's boxes before the
    // folder's ground gate (the gate is for stage-1 cases), so Input Fusion's are among them.
    let ungated = mlod::cases::load_detector(&models, Case::Input, Voting::Manifest)
        .unwrap()
        .detect(h.state().frame().unwrap(), &h.state().session().fuse)
        .unwrap();
    assert_eq!(b.detections, ungated);
    assert!(a.detections.iter().all(|d| ungated.contains(d)));
    let run = load_mlod(&models, Case::MlodI, Voting::Manifest)
        .unwrap()
        .run(h.state().frame().unwrap(), &h.state().session().fuse)
        .unwrap();
    assert_eq!(&run.refined, &b.refinement.as_ref().unwrap().refined);
    let drawn = |d: Vec<Detection>| {
        d.into_iter()
            .filter(|x| x.score >= settings.min_score)
            .collect::<Vec<_>>()
    };
    let a_eval = eval_counts(
        &token,
        drawn(a.detections.clone()),
        settings.match_iou,
        &a.categories,
    );
    let b_boxes: Vec<Detection> = run.refined.iter().map(|r| r.detection.clone()).collect();
    let b_eval = eval_counts(&token, drawn(b_boxes), settings.match_iou, &b.categories);
    assert_eq!((ca.true_positives, ca.false_positives, ca.missed), a_eval);
    assert_eq!((cb.true_positives, cb.false_positives, cb.missed), b_eval);
    // The difference, spelled out.
    let diff = format!(
        "Input Fusion vs MLOD-I: {:+} TP, {:+} FP, {:+} missed",
        a_eval.0 as i64 - b_eval.0 as i64,
        a_eval.1 as i64 - b_eval.1 as i64,
        a_eval.2 as i64 - b_eval.2 as i64
    );
    assert!(h.query_by_label(&diff).is_some(), "{diff}");
    // Two halves: the refined (red) boxes only in the right one, the same camera.
    let img = h.render().unwrap();
    let left = h.state().hover_state().0;
    let right = egui::Rect::from_min_max(
        egui::pos2(left.max.x + 3.0, left.min.y),
        egui::pos2(2.0 * left.max.x - left.min.x + 3.0, left.max.y),
    );
    const RED: [[u8; 4]; 2] = [REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR];
    let (red_a, red_b) = (count_pixels(&img, left, &RED), count_pixels(&img, right, &RED));
    assert!(
        red_b > 20 && red_b > 5 * red_a.max(1),
        "red left {red_a}, right {red_b}"
    );
    assert!(
        count_pixels(&img, right, &[GT_COLOR]) > 50,
        "ground truth in the right half"
    );
    // The session keeps compare mode and reopens pixel for pixel; switching it off joins the
    // halves.
    assert_eq!(h.state().current_session().compare, Some(Case::MlodI));
    let mut reopened = h.state().current_session();
    reopened.detection.auto_run = true;
    h.state_mut().session_mut().detection.auto_run = true;
    let mut b = harness_with(Some(reopened.clone()), Some(models.clone()));
    b.run_steps(4);
    assert_eq!(b.state().compare_detection().map(|d| d.1), Some(cb));
    // `mlod screenshot --session` renders both halves.
    let shot = mlod::gui::screenshot(
        AppOptions {
            dataset: default_dataset(),
            session: Some(reopened.clone()),
            synchronous: true,
            measure_frames: None,
            measure_run: false,
            models: Some(models.clone()),
            session_file: None,
        },
        (643, 400),
    )
    .unwrap();
    // (count_pixels takes 1280-wide coordinates.)
    let red_in = |x0: f32, x1: f32| {
        let r = egui::Rect::from_min_max(egui::pos2(x0, 0.0), egui::pos2(x1, 800.0));
        count_pixels(&shot, r, &RED)
    };
    assert_eq!(shot.dimensions(), (643, 400));
    assert!(
        red_in(646.0, 1280.0) > 5 * red_in(0.0, 636.0).max(1),
        "MLOD-I's red boxes on the right"
    );
    let mut c = harness_with(Some(reopened), Some(models.clone()));
    c.run_steps(4);
    assert!(
        b.render().unwrap().as_raw() == c.render().unwrap().as_raw(),
        "the session does not reopen pixel for pixel"
    );
    // The two halves are those of the window it was saved from (its panels differ only by
    // the pointer's hover).
    let (ia, ib) = (h.render().unwrap(), b.render().unwrap());
    let halves = |img: &image::RgbaImage| {
        let (x0, x1) = (left.min.x as u32, right.max.x as u32);
        let (y0, y1) = (left.min.y as u32 + 40, left.max.y as u32);
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .map(|(x, y)| img.get_pixel(x, y).0)
            .collect::<Vec<_>>()
    };
    assert!(halves(&ia) == halves(&ib), "the reopened halves differ");
    h.state_mut().set_compare(None);
    h.run_steps(2);
    assert!(h.state().hover_state().0.width() > 1.8 * left.width());
}
