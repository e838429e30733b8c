//! The points handed to the renderer: the visible LiDARs' fused points, their colours (the
//! session's colouring, with the highlighted box's active points painted over), both viewports'
//! copies in compare mode, and the histogram and |P_u|/|P| the colour panel shows.

use eframe::egui::Color32;

use super::detection::{EGO_ARROW, GROUND_Z};
use super::{MlodApp, HISTOGRAM_BINS};
use crate::color::{auto_range, colorize, histogram, scalars, ColorMode, Scale};
use crate::dataset::LidarChannel;
use crate::gui::overlay::SceneLabel;
use crate::gui::state::{color32, SelectionDetails, SELECTED_COLOR};
use crate::render::ego_lines;
use crate::session::BoxLayer;
use crate::uncertainty::UNCERTAIN_TRACE;

impl MlodApp {
    fn visible(&self, ch: LidarChannel) -> bool {
        self.session.visible.get(&ch).copied().unwrap_or(true)
    }

    /// Hands positions, colours and lines of the visible LiDARs to the renderer.
    pub(super) fn rebuild_scene(&mut self) {
        self.needs_color = false;
        let Some(cloud) = &self.loaded.fused else { return };
        let mut index = Vec::with_capacity(cloud.len());
        for l in &cloud.lidars {
            if self.visible(l.channel) {
                index.extend(l.range.start as u32..l.range.end as u32);
            }
        }
        let positions: Vec<[f32; 3]> = index
            .iter()
            .map(|&i| {
                let i = i as usize;
                [cloud.x[i], cloud.y[i], cloud.z[i]]
            })
            .collect();
        self.scene_index = index;
        let colors = self.colors();
        if self.session.compare.is_some() {
            if let Err(e) = self.scene_b.set_points(positions.clone(), colors.clone()) {
                eprintln!("mlod: {e}");
            }
        }
        if let Err(e) = self.scene.set_points(positions, colors) {
            eprintln!("mlod: {e}");
        }
        self.rebuild_lines();
        self.update_histogram();
    }

    /// Recolours without moving points (colour mode, range, highlight).
    pub(super) fn recolor(&mut self) {
        self.needs_color = false;
        let colors = self.colors();
        let b_ok = self.session.compare.is_none() || self.scene_b.set_colors(colors.clone()).is_ok();
        if !b_ok || self.scene.set_colors(colors).is_err() {
            self.rebuild_scene();
        }
        self.update_histogram();
    }

    pub(super) fn colors(&mut self) -> Vec<[u8; 4]> {
        let Some(cloud) = &self.loaded.fused else {
            return Vec::new();
        };
        if self.session.auto_range && self.session.color.mode != ColorMode::Source {
            self.session.color.range =
                auto_range(scalars(cloud, self.session.color.mode), self.session.color.scale);
        }
        let all = colorize(cloud, &self.session.color);
        let mut out: Vec<[u8; 4]> = self.scene_index.iter().map(|&i| all[i as usize]).collect();
        self.paint_active(&mut out);
        out
    }

    /// The texts pinned in the viewport: the ego vehicle's "forward", and (`selection`) the
    /// selected box's layer, class and numbers above it.
    pub(super) fn scene_labels(&self, selection: bool) -> Vec<SceneLabel> {
        let mut out = Vec::new();
        if self.loaded.frame.is_some() {
            let (_, tip) = ego_lines(self.ego_heading, GROUND_Z, EGO_ARROW);
            out.push(SceneLabel {
                at: tip,
                text: "forward".into(),
                color: Color32::from_gray(225),
            });
        }
        let Some(pick) = self.loaded.selected.filter(|_| selection) else {
            return out;
        };
        let Some(b) = self.box_of(pick) else { return out };
        let text = match (&self.loaded.selection_details, pick.0) {
            (
                Some(SelectionDetails::Truth {
                    category,
                    detected_iou,
                    ..
                }),
                _,
            ) => match detected_iou {
                Some(iou) => format!("ground truth {category} · detected, IoU {iou:.2}"),
                None => format!("ground truth {category} · missed"),
            },
            (Some(SelectionDetails::Prediction { details, .. }), layer) => {
                let what = if layer == BoxLayer::Refined {
                    "refined"
                } else {
                    "proposal"
                };
                let iou = details.iou_after.or(details.iou_before);
                let iou = iou.map(|v| format!(" · IoU {v:.2}")).unwrap_or_default();
                let score = details.refined_score.unwrap_or(details.proposal_score);
                format!("{what} {} · score {score:.2}{iou}", details.category)
            }
            _ => "selected".into(),
        };
        let c = b.center;
        out.push(SceneLabel {
            at: [c[0] as f32, c[1] as f32, (c[2] + b.size_lwh[2] / 2.0) as f32],
            text,
            color: color32(SELECTED_COLOR),
        });
        out
    }

    fn update_histogram(&mut self) {
        let Some(cloud) = &self.loaded.fused else { return };
        let c = &self.session.color;
        // In source-LiDAR mode the histogram still shows tr(Ξ), on its own log range.
        let (values, range, scale) = if c.mode == ColorMode::Source {
            (&cloud.trace[..], auto_range(&cloud.trace, Scale::Log), Scale::Log)
        } else {
            (scalars(cloud, c.mode), c.range, c.scale)
        };
        self.loaded.histogram = histogram(values, range, scale, HISTOGRAM_BINS);
        let trace = matches!(c.mode, ColorMode::Source | ColorMode::Trace);
        self.loaded.histogram_axis = Some((range, scale, trace));
        self.loaded.uncertain_fraction = cloud.uncertain_fraction(UNCERTAIN_TRACE);
    }
}
