//! What the central panel shows: the viewport, a message while nothing is loaded, and the box
//! under the pointer with its tooltip (ground truth: size, distance, points and tr(Ξ) inside,
//! detected or missed; a proposal: score, points, TP/FP with its IoU; a refined box: its scores,
//! its IoU before and after refinement, TP/FP, points gathered). Numbers come from the library
//! (`box_stats`, the refiner's output, the matching in [`super::state::DetectionView`]).

use eframe::egui;
use egui::Color32;

use super::state::Loaded;
use crate::eval::{GtOutcome, PredOutcome};
use crate::pipeline::{box_stats, BoxStats};
use crate::render::{SceneHandle, Viewport};
use crate::session::{BoxLayer, Session};

/// What the overlay reads.
pub struct OverlayInput<'a> {
    pub loaded: &'a Loaded,
    pub session: &'a Session,
    /// Fused-cloud index of each point handed to the scene.
    pub scene_index: &'a [u32],
    /// A load is running (the empty viewport says "loading…").
    pub loading: bool,
    /// Text pinned to points of the scene (the selected box's label, the ego's "forward").
    pub labels: &'a [SceneLabel],
    /// α while "play α" runs, drawn large in the corner.
    pub playing_alpha: Option<f64>,
}

/// A text pinned to a point of the scene, on a dark plate.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneLabel {
    pub at: [f32; 3],
    pub text: String,
    pub color: Color32,
}

/// Draws `labels` where their points project into `rect`, and α in the top-right corner.
pub fn annotate(
    painter: &egui::Painter,
    rect: egui::Rect,
    camera: &crate::render::Camera,
    labels: &[SceneLabel],
    playing_alpha: Option<f64>,
) {
    let painter = painter.with_clip_rect(rect);
    for l in labels {
        // A label whose point is out of view is left out rather than pinned to an edge.
        let Some(pos) = camera.project(l.at, rect).filter(|p| rect.contains(*p)) else {
            continue;
        };
        let galley = painter.layout_no_wrap(l.text.clone(), egui::FontId::proportional(13.0), l.color);
        let size = galley.size() + egui::vec2(10.0, 6.0);
        // Above the point, kept inside the view.
        let min = egui::pos2(
            (pos.x - size.x / 2.0).clamp(rect.left() + 2.0, (rect.right() - size.x - 2.0).max(rect.left())),
            (pos.y - size.y - 6.0).clamp(rect.top() + 2.0, (rect.bottom() - size.y - 2.0).max(rect.top())),
        );
        let plate = egui::Rect::from_min_size(min, size);
        painter.rect_filled(plate, 3.0, Color32::from_black_alpha(200));
        painter.galley(plate.min + egui::vec2(5.0, 3.0), galley, l.color);
    }
    if let Some(alpha) = playing_alpha {
        let text = format!("α = {alpha:.3}");
        let color = Color32::from_gray(240);
        let galley = painter.layout_no_wrap(text, egui::FontId::proportional(22.0), color);
        let size = galley.size() + egui::vec2(16.0, 8.0);
        let plate =
            egui::Rect::from_min_size(egui::pos2(rect.right() - size.x - 10.0, rect.top() + 10.0), size);
        painter.rect_filled(plate, 4.0, Color32::from_black_alpha(200));
        painter.galley(plate.min + egui::vec2(8.0, 4.0), galley, color);
    }
}

/// What happened in the viewport this frame.
pub struct OverlayOutput {
    pub rect: egui::Rect,
    /// The ground-truth box under the pointer (index in the frame) with its statistics.
    pub hovered_box: Option<(usize, BoxStats)>,
    /// The proposal under the pointer (index in the detection on screen).
    pub hovered_detection: Option<usize>,
    /// The refined box under the pointer (index in the refinement on screen).
    pub hovered_refined: Option<usize>,
    /// A click in the viewport (not a drag): the box under the pointer — a refined one first
    /// (the smallest on screen, whatever else competes for the hover), else the hovered one — or
    /// none.
    pub clicked: Option<Option<(BoxLayer, usize)>>,
    /// A message for a toast (a double-clicked point).
    pub message: Option<String>,
}

/// What the pointer is over.
#[derive(Debug, Clone, Copy)]
enum Hovered {
    Truth(usize),
    Proposal(usize),
    Refined(usize),
}

/// Draws the viewport and the hover tooltip.
pub fn show(
    ui: &mut egui::Ui,
    view: &mut Viewport,
    scene: &SceneHandle,
    input: &OverlayInput<'_>,
) -> OverlayOutput {
    let out = crate::render::show(ui, view, scene);
    annotate(
        ui.painter(),
        out.response.rect,
        &view.camera,
        input.labels,
        input.playing_alpha,
    );
    let mut result = OverlayOutput {
        rect: out.response.rect,
        hovered_box: None,
        hovered_detection: None,
        hovered_refined: None,
        clicked: None,
        message: None,
    };
    if input.loaded.frame.is_none() {
        let msg = if input.loading {
            "loading…"
        } else {
            "no sample loaded — File > Open dataset…"
        };
        ui.painter().text(
            out.response.rect.center(),
            egui::Align2::CENTER_CENTER,
            msg,
            egui::FontId::proportional(18.0),
            Color32::from_gray(170),
        );
    }
    if let Some(i) = out.picked {
        if let (Some(cloud), Some(&k)) = (&input.loaded.fused, input.scene_index.get(i)) {
            let k = k as usize;
            let ch = cloud
                .lidars
                .iter()
                .find(|l| l.range.contains(&k))
                .map(|l| {
                    crate::gui::state::lidar_name(
                        input.loaded.dataset.as_ref().map(|d| d.format()),
                        l.channel,
                    )
                })
                .unwrap_or("?");
            result.message = Some(format!("focused a {ch} point, tr(Ξ) = {:.4} m²", cloud.trace[k]));
        }
    }
    let clicked = out.response.clicked();
    // A click whose pointer left in the same frame still has the press position.
    let pointer = out
        .response
        .hover_pos()
        .or_else(|| clicked.then(|| out.response.interact_pointer_pos()).flatten());
    let Some(pointer) = pointer else {
        if clicked {
            result.clicked = Some(None);
        }
        return result;
    };
    let (Some(frame), Some(cloud)) = (&input.loaded.frame, &input.loaded.fused) else {
        return result;
    };
    let rect = out.response.rect;
    let camera = &view.camera;
    // The box under the pointer with the smallest screen rectangle; GT and proposals compete.
    let screen_rect = |corners: [[f64; 3]; 8]| -> Option<egui::Rect> {
        let pts: Vec<egui::Pos2> = corners
            .iter()
            .filter_map(|c| camera.project([c[0] as f32, c[1] as f32, c[2] as f32], rect))
            .collect();
        (pts.len() == 8).then(|| egui::Rect::from_points(&pts))
    };
    let mut best: Option<(Hovered, f32)> = None;
    let mut best_refined: Option<(usize, f32)> = None;
    let mut consider = |h: Hovered, r: Option<egui::Rect>| {
        if let Some(r) = r {
            if !r.contains(pointer) {
                return;
            }
            if best.is_none_or(|(_, a)| r.area() < a) {
                best = Some((h, r.area()));
            }
            if let Hovered::Refined(k) = h {
                if best_refined.is_none_or(|(_, a)| r.area() < a) {
                    best_refined = Some((k, r.area()));
                }
            }
        }
    };
    if input.session.show_ground_truth {
        for (bi, b) in frame.boxes.iter().enumerate() {
            consider(Hovered::Truth(bi), screen_rect(b.box3d.corners()));
        }
    }
    let settings = input.session.detection;
    if let Some(d) = input.loaded.detection.as_ref() {
        if settings.show {
            for (i, det) in d.detections.iter().enumerate() {
                if det.score >= settings.min_score {
                    consider(Hovered::Proposal(i), screen_rect(det.box3d.corners()));
                }
            }
        }
        if let Some(r) = d.refinement.as_ref().filter(|_| settings.show_refined) {
            for (k, x) in r.refined.iter().enumerate() {
                if x.detection.score >= settings.min_score {
                    consider(Hovered::Refined(k), screen_rect(x.detection.box3d.corners()));
                }
            }
        }
    }
    if clicked {
        let pick = best_refined
            .map(|(k, _)| (BoxLayer::Refined, k))
            .or(best.map(|(h, _)| match h {
                Hovered::Truth(i) => (BoxLayer::Truth, i),
                Hovered::Proposal(i) => (BoxLayer::Proposal, i),
                Hovered::Refined(k) => (BoxLayer::Refined, k),
            }));
        result.clicked = Some(pick);
    }
    match best {
        Some((Hovered::Truth(bi), _)) => {
            let b = &frame.boxes[bi];
            let stats = box_stats(cloud, &b.box3d);
            result.hovered_box = Some((bi, stats));
            let [l, w, h] = b.box3d.size_lwh;
            let matched = input
                .loaded
                .detection
                .as_ref()
                .and_then(|d| d.final_gt_outcomes().get(bi).copied());
            out.response.on_hover_ui_at_pointer(|ui| {
                ui.strong(format!("ground truth: {}", b.category));
                ui.label(format!("size l×w×h  {l:.2} × {w:.2} × {h:.2} m"));
                ui.label(format!("distance  {:.1} m", b.box3d.bev_range()));
                ui.label(format!("points inside  {}", stats.points));
                ui.label(format!("mean tr(Ξ) inside  {:.4} m²", stats.mean_trace));
                ui.label(format!(
                    "uncertain (tr Ξ > 0.05)  {:.0} %",
                    100.0 * stats.uncertain_fraction
                ));
                match matched {
                    Some(GtOutcome::Matched { iou, .. }) => {
                        ui.label(format!("detected: 3D IoU {iou:.2}"));
                    }
                    Some(GtOutcome::Missed) => {
                        ui.label("missed by the detector");
                    }
                    _ => {}
                }
            });
        }
        Some((Hovered::Proposal(i), _)) => {
            result.hovered_detection = Some(i);
            let Some(d) = input.loaded.detection.as_ref() else {
                return result;
            };
            let det = &d.detections[i];
            let stats = box_stats(cloud, &det.box3d);
            let [l, w, h] = det.box3d.size_lwh;
            let outcome = d.outcomes[i];
            let case = d.case;
            out.response.on_hover_ui_at_pointer(|ui| {
                ui.strong(format!("proposal ({}): {}", case.proposals_name(), det.category));
                ui.label(format!("score  {:.3}", det.score));
                ui.label(format!("size l×w×h  {l:.2} × {w:.2} × {h:.2} m"));
                ui.label(format!("distance  {:.1} m", det.box3d.bev_range()));
                ui.label(format!("points inside  {}", stats.points));
                ui.label(format!("mean tr(Ξ) inside  {:.4} m²", stats.mean_trace));
                match outcome {
                    PredOutcome::TruePositive { iou, .. } => {
                        ui.label(format!("true positive: 3D IoU {iou:.2}"));
                    }
                    PredOutcome::FalsePositive { best_iou } => {
                        ui.label(format!("false positive: best 3D IoU {best_iou:.2}"));
                    }
                    PredOutcome::Ignored => {}
                }
            });
        }
        Some((Hovered::Refined(k), _)) => {
            result.hovered_refined = Some(k);
            let Some((d, r)) = input
                .loaded
                .detection
                .as_ref()
                .and_then(|d| Some((d, d.refinement.as_ref()?)))
            else {
                return result;
            };
            let x = &r.refined[k];
            let det = &x.detection;
            let stats = box_stats(cloud, &det.box3d);
            let [l, w, h] = det.box3d.size_lwh;
            let (outcome, before, after) = (r.outcomes[k], r.iou_before[k], r.iou_after[k]);
            let case = d.case;
            out.response.on_hover_ui_at_pointer(|ui| {
                ui.strong(format!("refined ({}): {}", case.paper_name(), det.category));
                ui.label(format!("score  {:.3}", det.score));
                ui.label(format!("classification head  {:.3}", x.refined_score));
                if let Some(p) = d.detections.get(x.proposal) {
                    ui.label(format!("proposal's score  {:.3}", p.score));
                }
                ui.label(format!("best GT 3D IoU  {before:.2} before, {after:.2} after"));
                match outcome {
                    PredOutcome::TruePositive { iou, .. } => {
                        ui.label(format!("true positive: 3D IoU {iou:.2}"));
                    }
                    PredOutcome::FalsePositive { best_iou } => {
                        ui.label(format!("false positive: best 3D IoU {best_iou:.2}"));
                    }
                    PredOutcome::Ignored => {}
                }
                ui.label(format!("size l×w×h  {l:.2} × {w:.2} × {h:.2} m"));
                ui.label(format!("distance  {:.1} m", det.box3d.bev_range()));
                ui.label(format!("points gathered (box + margin)  {}", x.gathered));
                ui.label(format!("points inside  {}", stats.points));
                ui.label(format!("mean tr(Ξ) inside  {:.4} m²", stats.mean_trace));
                if x.unrefined {
                    ui.label("no points: kept as proposed");
                } else {
                    ui.label(format!("active points  {}", x.active.len()));
                }
            });
        }
        None => {}
    }
    result
}
