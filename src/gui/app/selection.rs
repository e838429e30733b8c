//! The selected box: a click (or the API) picks a box of any layer, the session stores it by the
//! object it is on ([`BoxSelection`]: the ground-truth annotation, else its position), and every
//! re-fuse, re-run or re-match finds that object again among the boxes on screen — so the
//! selection survives α changes and a saved session reopens with it. The details panel's numbers
//! come from [`crate::analysis::inspect`]; F points the camera at the box, Escape clears it.

use super::MlodApp;
use crate::analysis::inspect::{points_inside, prediction_details, TruthRef};
use crate::eval::PredOutcome;
use crate::geometry::{iou_3d, Box3d};
use crate::gui::state::SelectionDetails;
use crate::session::{BoxLayer, BoxSelection};

impl MlodApp {
    /// Selects a box on screen (layer and index), or clears the selection.
    pub fn select_box(&mut self, pick: Option<(BoxLayer, usize)>) {
        self.session.selection = pick.and_then(|p| self.anchor_of(p));
        self.loaded.selected = pick.filter(|_| self.session.selection.is_some());
        self.selection_changed();
    }

    /// Selects a refined box (index into the refinement on screen), or clears the selection.
    pub fn select_refined(&mut self, k: Option<usize>) {
        self.select_box(k.map(|k| (BoxLayer::Refined, k)));
    }

    /// The selected box on screen, if the session's selection is found there.
    pub fn selected_box(&self) -> Option<(BoxLayer, usize)> {
        self.loaded.selected
    }

    /// What the details panel shows.
    pub fn selection_details(&self) -> Option<&SelectionDetails> {
        self.loaded.selection_details.as_ref()
    }

    /// Finds the session's selection among the boxes on screen again (after a re-fuse, a new
    /// detection or a re-match) and follows the object's position.
    pub(super) fn resolve_selection(&mut self) {
        let found = self.session.selection.as_ref().and_then(|s| self.find(s));
        self.loaded.selected = found;
        if let (Some(p), Some(sel)) = (found, self.session.selection.as_ref()) {
            if let Some(now) = self.anchor_of(p) {
                let annotation = sel.annotation.clone().or(now.annotation);
                self.session.selection = Some(BoxSelection { annotation, ..now });
            }
        }
        self.selection_changed();
        if found.is_some() && std::mem::take(&mut self.focus_pending) {
            self.focus_selection();
        }
    }

    fn selection_changed(&mut self) {
        self.loaded.selection_details = self.details();
        self.update_highlight();
        self.rebuild_lines();
    }

    /// Points the camera at the selected box, close enough to see its points.
    pub fn focus_selection(&mut self) {
        let Some(b) = self.loaded.selected.and_then(|p| self.box_of(p)) else {
            return;
        };
        let c = b.center;
        self.view.camera.target = [c[0] as f32, c[1] as f32, c[2] as f32];
        // Far enough to see the box with its surroundings (a car: ~25 m), never right on it.
        self.view.camera.distance = (5.5 * b.size_lwh[0].max(b.size_lwh[1]) as f32).clamp(15.0, 50.0);
    }

    /// The box of a layer and index on screen.
    pub(super) fn box_of(&self, (layer, i): (BoxLayer, usize)) -> Option<Box3d> {
        let d = self.loaded.detection.as_ref();
        match layer {
            BoxLayer::Truth => self.loaded.frame.as_ref()?.boxes.get(i).map(|b| b.box3d),
            BoxLayer::Proposal => d?.detections.get(i).map(|x| x.box3d),
            BoxLayer::Refined => d?.refinement.as_ref()?.refined.get(i).map(|r| r.detection.box3d),
        }
    }

    /// The annotation token of the frame's `gt`-th box.
    fn annotation(&self, gt: usize) -> Option<String> {
        Some(
            self.loaded
                .frame
                .as_ref()?
                .boxes
                .get(gt)?
                .annotation_token
                .clone(),
        )
    }

    /// What identifies a box on screen across re-runs.
    fn anchor_of(&self, pick: (BoxLayer, usize)) -> Option<BoxSelection> {
        let b = self.box_of(pick)?;
        let (layer, i) = pick;
        let d = self.loaded.detection.as_ref();
        let (category, outcome) = match layer {
            BoxLayer::Truth => {
                let g = self.loaded.frame.as_ref()?.boxes.get(i)?;
                return Some(BoxSelection {
                    layer,
                    annotation: Some(g.annotation_token.clone()),
                    center: b.center,
                    category: g.category.clone(),
                });
            }
            BoxLayer::Proposal => {
                let d = d?;
                (d.detections.get(i)?.category.clone(), d.outcomes.get(i).copied())
            }
            BoxLayer::Refined => {
                let r = d?.refinement.as_ref()?;
                (
                    r.refined.get(i)?.detection.category.clone(),
                    r.outcomes.get(i).copied(),
                )
            }
        };
        let annotation = match outcome {
            Some(PredOutcome::TruePositive { gt, .. }) => self.annotation(gt),
            _ => None,
        };
        Some(BoxSelection {
            layer,
            annotation,
            center: b.center,
            category,
        })
    }

    /// The box on screen that is `sel`'s object: the one on (or matched to) its annotation, else
    /// the nearest drawn box of its layer and category within the re-find radius.
    fn find(&self, sel: &BoxSelection) -> Option<(BoxLayer, usize)> {
        let frame = self.loaded.frame.as_ref()?;
        if sel.layer == BoxLayer::Truth {
            let a = sel.annotation.as_deref()?;
            return frame
                .boxes
                .iter()
                .position(|b| b.annotation_token == a)
                .map(|j| (BoxLayer::Truth, j));
        }
        let d = self.loaded.detection.as_ref()?;
        let min_score = self.session.detection.min_score;
        // (index, box, score, outcome) of the layer's boxes.
        let boxes: Vec<(usize, &Box3d, f32, &str, PredOutcome)> = match sel.layer {
            BoxLayer::Proposal => d
                .detections
                .iter()
                .zip(&d.outcomes)
                .enumerate()
                .map(|(i, (x, o))| (i, &x.box3d, x.score, x.category.as_str(), *o))
                .collect(),
            _ => {
                let r = d.refinement.as_ref()?;
                r.refined
                    .iter()
                    .zip(&r.outcomes)
                    .enumerate()
                    .map(|(i, (x, o))| {
                        (
                            i,
                            &x.detection.box3d,
                            x.detection.score,
                            x.detection.category.as_str(),
                            *o,
                        )
                    })
                    .collect()
            }
        };
        let drawn = boxes.iter().filter(|b| b.2 >= min_score && b.3 == sel.category);
        if let Some(a) = sel.annotation.as_deref() {
            let on_it = drawn.clone().find(|b| {
                matches!(b.4, PredOutcome::TruePositive { gt, .. }
                    if frame.boxes.get(gt).is_some_and(|g| g.annotation_token == a))
            });
            if let Some(b) = on_it {
                return Some((sel.layer, b.0));
            }
        }
        let dist = |b: &Box3d| (b.center[0] - sel.center[0]).hypot(b.center[1] - sel.center[1]);
        drawn
            .filter(|b| dist(b.1) <= BoxSelection::REFIND_RADIUS)
            .min_by(|a, b| dist(a.1).total_cmp(&dist(b.1)))
            .map(|b| (sel.layer, b.0))
    }

    /// The details of the selected box on screen.
    fn details(&self) -> Option<SelectionDetails> {
        let (layer, i) = self.loaded.selected?;
        let frame = self.loaded.frame.as_ref()?;
        let cloud = self.loaded.fused.as_ref()?;
        let d = self.loaded.detection.as_ref();
        if layer == BoxLayer::Truth {
            let g = frame.boxes.get(i)?;
            let detected_iou = d.and_then(|d| match d.final_gt_outcomes().get(i) {
                Some(crate::eval::GtOutcome::Matched { iou, .. }) => Some(*iou),
                _ => None,
            });
            return Some(SelectionDetails::Truth {
                index: i,
                annotation: g.annotation_token.clone(),
                category: g.category.clone(),
                inside: points_inside(cloud, &g.box3d),
                detected_iou,
            });
        }
        let d = d?;
        let (proposal, refined, outcome) = match layer {
            BoxLayer::Proposal => (d.detections.get(i)?, None, *d.outcomes.get(i)?),
            _ => {
                let r = d.refinement.as_ref()?;
                let x = r.refined.get(i)?;
                (d.detections.get(x.proposal)?, Some(x), *r.outcomes.get(i)?)
            }
        };
        let shown = refined.map_or(&proposal.box3d, |r| &r.detection.box3d);
        // The truth it is compared with: its match, else the best-overlapping truth of its class.
        let truth = match outcome {
            PredOutcome::TruePositive { gt, .. } => Some((gt, true)),
            _ => frame
                .boxes
                .iter()
                .enumerate()
                .filter(|(_, g)| g.category == proposal.category)
                .map(|(j, g)| (j, iou_3d(shown, &g.box3d)))
                .filter(|&(_, iou)| iou > 0.0)
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| (j, false)),
        };
        let truth = truth.and_then(|(j, matched)| {
            let g = frame.boxes.get(j)?;
            Some((
                TruthRef {
                    index: j,
                    annotation_token: g.annotation_token.clone(),
                    matched,
                },
                &g.box3d,
            ))
        });
        Some(SelectionDetails::Prediction {
            layer,
            index: i,
            details: Box::new(prediction_details(cloud, proposal, refined, truth)),
        })
    }
}
