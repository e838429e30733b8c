//! Issue 30's measures of what a user sees, on rendered frames rather than pixel equality: box
//! colours stand apart from the points beneath them (CIE ΔE), a selected box covers many times
//! the pixels it covers unselected, a failure-browser click frames its box inside the visible
//! viewport, a save without a desktop dialog service asks for a path, and at 1280×800 no widget
//! of the controls panel is cut off.

use egui::accesskit::Role;
use egui_kittest::kittest::{NodeT, Queryable};
use egui_kittest::Harness;
use image::RgbaImage;
use mlod::color::{delta_e, ColorMode};
use mlod::geometry::Box3d;
use mlod::gui::{
    default_dataset, MlodApp, FALSE_POSITIVE_COLOR, PROPOSAL_COLOR, REFINED_COLOR,
    REFINED_FALSE_POSITIVE_COLOR, SELECTED_COLOR, SELECTED_HALO_COLOR,
};
use mlod::render::View;
use mlod::session::{BoxLayer, Session};

use super::{harness, harness_with, mlod_models, mlod_session};

/// The screen rectangle of a box's corners, if all of them are in front of the camera.
fn screen_rect(camera: &mlod::render::Camera, b: &Box3d, rect: egui::Rect) -> Option<egui::Rect> {
    let pts: Vec<egui::Pos2> = b
        .corners()
        .iter()
        .filter_map(|c| camera.project([c[0] as f32, c[1] as f32, c[2] as f32], rect))
        .collect();
    (pts.len() == 8).then(|| egui::Rect::from_points(&pts))
}

/// Pixels of `img` inside `r` (UI points, `ppp` pixels each) within ΔE `tol` of any of `colors`.
fn pixels_near(img: &RgbaImage, r: egui::Rect, ppp: f32, colors: &[[u8; 4]], tol: f32) -> usize {
    let (w, h) = (img.width() as f32, img.height() as f32);
    let x0 = (r.left() * ppp).clamp(0.0, w) as u32;
    let x1 = (r.right() * ppp).clamp(0.0, w) as u32;
    let y0 = (r.top() * ppp).clamp(0.0, h) as u32;
    let y1 = (r.bottom() * ppp).clamp(0.0, h) as u32;
    let mut n = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            let p = img.get_pixel(x, y).0;
            if colors.iter().any(|c| delta_e(p, *c) < tol) {
                n += 1;
            }
        }
    }
    n
}

/// The README's compare session (Input Fusion left, MLOD-I right, α = 0.04), on the sample data.
fn readme_compare_session() -> Session {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("screenshots/compare.session.json");
    let mut s = Session::load(&path).expect("the README's compare session");
    s.dataset = default_dataset();
    s
}

#[test]
fn in_the_readme_compare_session_refined_and_proposal_boxes_stand_out_from_the_points_beneath() {
    // The measure: render the session, then the same view with every box hidden. A pixel drawn in
    // a box's colour (ΔE < 6 of it) that has a point (not the background) beneath it in the second
    // frame is compared with that point's pixel: CIE76 ΔE ≥ 20 reads as another colour.
    let mut h = harness_with(Some(readme_compare_session()), Some(mlod_models()));
    h.run_steps(3);
    assert!(h.state().compare_detection().is_some(), "MLOD-I ran on load");
    let with_boxes = h.render().unwrap();
    if let Ok(dir) = std::env::var("MLOD_TEST_DUMP") {
        with_boxes.save(format!("{dir}/compare_frame.png")).unwrap();
    }
    {
        let s = h.state_mut().session_mut();
        s.show_ground_truth = false;
        s.detection.show = false;
        s.detection.show_refined = false;
    }
    h.state_mut().rematch();
    h.run_steps(2);
    let points_only = h.render().unwrap();
    let bg = {
        let [r, g, b] = h.state().viewport().0.settings.background;
        [r, g, b, 255]
    };
    let view = h.state().hover_state().0;
    let ppp = h.ctx.pixels_per_point();
    // Both halves: from the left half's left edge to the right half's right edge.
    let (x0, x1) = (
        (view.left() * ppp) as u32,
        ((2.0 * view.right() - view.left() + 3.0) * ppp) as u32,
    );
    let (y0, y1) = ((view.top() * ppp) as u32, (view.bottom() * ppp) as u32);
    // Each layer in both its colours: true positives and the greyed false positives.
    let layers = [
        ("refined", [REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR]),
        ("proposal", [PROPOSAL_COLOR, FALSE_POSITIVE_COLOR]),
    ];
    for (name, colors) in layers {
        let mut de: Vec<f32> = Vec::new();
        let mut drawn = 0;
        for y in y0..y1.min(with_boxes.height()) {
            for x in x0..x1.min(with_boxes.width()) {
                let p = with_boxes.get_pixel(x, y).0;
                if colors.iter().all(|c| delta_e(p, *c) >= 6.0) {
                    continue;
                }
                drawn += 1;
                let beneath = points_only.get_pixel(x, y).0;
                if delta_e(beneath, bg) > 5.0 {
                    de.push(delta_e(p, beneath));
                }
            }
        }
        de.sort_by(|a, b| a.total_cmp(b));
        let min = de.first().copied().unwrap_or(f32::INFINITY);
        let median = de.get(de.len() / 2).copied().unwrap_or(f32::INFINITY);
        eprintln!(
            "{name} boxes: {drawn} pixels, {} over points; ΔE against the points beneath: min {min:.1}, median {median:.1}",
            de.len()
        );
        assert!(drawn >= 300, "{name} boxes show {drawn} pixels");
        assert!(de.len() >= 50, "{name}: only {} box pixels over points", de.len());
        assert!(
            min >= 20.0,
            "{name}: a box pixel is ΔE {min:.1} from the point beneath it"
        );
    }
}

#[test]
fn a_selected_box_covers_at_least_four_times_the_pixels_it_covers_unselected() {
    let mut s = mlod_session(0.04, ColorMode::Trace);
    s.detection.auto_run = true;
    let mut h = harness_with(Some(s), Some(mlod_models()));
    h.state_mut().set_preset(View::Chase);
    h.run_steps(3);
    // Close enough that the box's edges do not run into each other on screen.
    let target = {
        let r = h.state().detection().unwrap().0.refinement.as_ref().unwrap();
        let k = (0..r.refined.len())
            .filter(|&k| matches!(r.outcomes[k], mlod::eval::PredOutcome::TruePositive { .. }))
            .min_by(|&a, &b| {
                let d = |k: usize| r.refined[k].detection.box3d.bev_range();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        r.refined[k].detection.box3d.center.map(|v| v as f32)
    };
    h.state_mut().focus_camera(target, 12.0);
    h.run_steps(2);
    let view_rect = h.state().hover_state().0;
    let camera = h.state().viewport().0.camera.clone();
    // The largest true-positive refined box wholly on screen.
    let (k, r) = {
        let r = h.state().detection().unwrap().0.refinement.as_ref().unwrap();
        (0..r.refined.len())
            .filter(|&k| matches!(r.outcomes[k], mlod::eval::PredOutcome::TruePositive { .. }))
            .filter_map(|k| {
                let sr = screen_rect(&camera, &r.refined[k].detection.box3d, view_rect)?;
                view_rect.contains_rect(sr.expand(14.0)).then_some((k, sr))
            })
            .max_by(|a, b| a.1.area().total_cmp(&b.1.area()))
            .expect("a refined box on screen")
    };
    let ppp = h.ctx.pixels_per_point();
    let around = r.expand(12.0);
    let before = pixels_near(&h.render().unwrap(), around, ppp, &[REFINED_COLOR], 10.0);
    h.state_mut().select_box(Some((BoxLayer::Refined, k)));
    h.run_steps(2);
    let after = pixels_near(
        &h.render().unwrap(),
        around,
        ppp,
        &[SELECTED_COLOR, SELECTED_HALO_COLOR],
        10.0,
    );
    let ratio = after as f32 / before.max(1) as f32;
    eprintln!("selected box: {after} pixels, unselected: {before} ({ratio:.1}×)");
    assert!(before > 50, "the unselected box shows ({before} pixels)");
    assert!(
        ratio >= 4.0,
        "selected {after} vs unselected {before} pixels: {ratio:.2}×"
    );
}

#[test]
fn a_failure_browser_click_frames_its_box_inside_the_visible_viewport() {
    let mut s = mlod_session(0.1, ColorMode::Trace);
    s.failures = Some(mlod::session::FailureScope::Scene);
    s.detection.auto_run = true;
    let mut h = harness_with(Some(s), Some(mlod_models()));
    h.run_steps(3);
    assert!(h
        .state()
        .failure_browser()
        .and_then(|b| b.result.as_ref())
        .is_some());
    // The browser is docked: its header lies below the viewport, never over it.
    let header = h.get_by_label("Failure cases").rect();
    let view = h.state().hover_state().0;
    assert!(
        header.top() >= view.bottom() - 0.5,
        "browser {header:?} over viewport {view:?}"
    );
    // The first listed box (the worst sample's), visible in the docked list.
    let links: Vec<_> = h.get_all_by_role(Role::Link).collect();
    assert!(!links.is_empty(), "the browser lists failing boxes");
    links[0].click();
    for _ in 0..4 {
        h.run_steps(2);
    }
    let (layer, i) = h.state().selected_box().expect("the clicked box is selected");
    let b = match layer {
        BoxLayer::Truth => h.state().frame().unwrap().boxes[i].box3d,
        BoxLayer::Proposal => h.state().detection().unwrap().0.detections[i].box3d,
        BoxLayer::Refined => {
            h.state()
                .detection()
                .unwrap()
                .0
                .refinement
                .as_ref()
                .unwrap()
                .refined[i]
                .detection
                .box3d
        }
    };
    let view = h.state().hover_state().0;
    let camera = h.state().viewport().0.camera.clone();
    let r = screen_rect(&camera, &b, view).expect("the box in front of the camera");
    eprintln!("box on screen at {r:?} in viewport {view:?}");
    assert!(view.contains_rect(r), "box {r:?} outside the viewport {view:?}");
    // At a sensible distance: neither a speck nor filling the view.
    let share = r.area() / view.area();
    assert!(
        (0.002..0.25).contains(&share),
        "box covers {:.1} % of the view",
        share * 100.0
    );
}

#[test]
fn a_save_with_no_dialog_service_asks_for_a_path_and_names_the_file() {
    let mut h = harness(None);
    h.get_by_label("File").click();
    h.run_steps(2);
    h.get_by_label_contains("Save session").click();
    h.run_steps(2);
    // No desktop dialog can open in a test: the path field is there instead.
    let field = h.get_by_role(Role::TextInput);
    assert!(
        field.value().is_some_and(|v| v.ends_with("session.json")),
        "{:?}",
        field.value()
    );
    let dir = std::env::temp_dir().join(format!("mlod-gui-save-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("saved.session.json");
    field.set_text_value_accesskit(&path.display().to_string());
    h.run_steps(2);
    h.get_by_label("save").click();
    h.run_steps(2);
    assert!(
        h.query_by_role(Role::TextInput).is_none(),
        "the path field closed"
    );
    assert!(path.is_file(), "the session was written");
    assert!(Session::load(&path).is_ok());
    // The toast names the file; the title names the session.
    let toasts = h.state().toast_texts();
    assert!(
        toasts.iter().any(|t| t.contains(&path.display().to_string())),
        "a toast names the file: {toasts:?}"
    );
    assert!(
        h.state().title().ends_with("saved.session.json"),
        "{}",
        h.state().title()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every widget whose centre lies in the controls panel lies wholly inside it, and (`fits`) the
/// open sections fit the panel's height (egui's layout: content height against the visible one).
fn assert_controls_unclipped(h: &Harness<'static, MlodApp>, what: &str, fits: bool) {
    let (panel, overflow) = h.state().controls_layout().expect("the controls panel is shown");
    eprintln!("{what}: the open sections run {overflow:.0} points past the panel's height");
    if fits {
        assert!(overflow <= 0.0, "{what}: {overflow} points below the fold");
    }
    let mut checked = 0;
    let mut clipped = Vec::new();
    for node in h.get_all(egui_kittest::kittest::by()) {
        let Some(b) = node.accesskit_node().bounding_box() else {
            continue;
        };
        let r = egui::Rect::from_min_max(
            egui::pos2(b.x0 as f32, b.y0 as f32),
            egui::pos2(b.x1 as f32, b.y1 as f32),
        );
        let role = node.accesskit_node().role();
        if !r.is_positive() || !panel.contains(r.center()) || role == Role::Splitter {
            continue;
        }
        checked += 1;
        if !panel.expand(0.5).contains_rect(r) {
            clipped.push(format!(
                "{:?} {:?} at {r:?}",
                node.accesskit_node().role(),
                node.accesskit_node().label()
            ));
        }
    }
    eprintln!("{what}: {checked} widgets inside the controls panel {panel:?}");
    assert!(checked > 20, "{what}: only {checked} widgets found");
    assert!(clipped.is_empty(), "{what}: clipped widgets: {clipped:#?}");
}

#[test]
fn at_1280_by_800_no_widget_of_the_controls_panel_is_clipped() {
    let h = harness(None);
    assert_controls_unclipped(&h, "first sight", true);
    let mut h = harness_with(Some(readme_compare_session()), Some(mlod_models()));
    h.run_steps(2);
    assert_controls_unclipped(&h, "the README's compare session", false);
    let mut s = mlod_session(0.1, ColorMode::Source);
    s.detection.auto_run = true;
    let mut h = harness_with(Some(s), Some(mlod_models()));
    h.get_by_label("calibrate (ICP)").click();
    h.run_steps(3);
    assert_controls_unclipped(&h, "after ICP", false);
}
