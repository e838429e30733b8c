//! The viewport camera: an orbit camera around a target point (perspective) and a bird's-eye view
//! (top-down orthographic, +x of the base frame pointing up on screen), both in the LiDAR base
//! frame (z up, metres).
//!
//! How it works: the camera stores a target, a yaw (heading of the viewing direction, about +z,
//! 0 = looking along +x), a pitch (downward tilt, positive = looking down), a distance from the
//! target and a vertical field of view. The perspective projection uses reversed depth with an
//! infinite far plane (depth 1 at the near plane, 0 at infinity) for precision over a 100 m scene;
//! the bird's-eye projection is an orthographic box of half-height `distance · tan(fov/2)`, so
//! zooming feels the same in both modes, with the same reversed depth.

use egui::{PointerButton, Pos2, Rect, Response, Ui, Vec2};
use glam::{Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use crate::render::SceneHandle;

/// Perspective orbit or top-down orthographic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Projection {
    Perspective,
    /// Bird's-eye view: orthographic, looking down −z; `yaw` is the heading shown up on screen.
    BirdsEye,
}

/// Preset views, chosen for debugging a car's surroundings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum View {
    /// Perspective from behind and above the car, the whole scene in view.
    Overview,
    /// Bird's-eye view, +x up, the whole scene in view.
    Bev,
    /// Low chase view from behind the car looking forward (+x).
    Chase,
    /// From in front of the car looking back at it (−x).
    Front,
    /// From the car's left (+y) looking right.
    Left,
    /// From the car's right (−y) looking left.
    Right,
}

impl View {
    pub const ALL: [View; 6] = [
        View::Overview,
        View::Bev,
        View::Chase,
        View::Front,
        View::Left,
        View::Right,
    ];

    pub fn name(self) -> &'static str {
        match self {
            View::Overview => "Overview",
            View::Bev => "Bird's eye",
            View::Chase => "Chase",
            View::Front => "Front",
            View::Left => "Left",
            View::Right => "Right",
        }
    }
}

/// Closest the camera may come to its target (m).
pub const MIN_DISTANCE: f32 = 0.5;
/// Pitch limits: a little below the horizon to almost straight down.
const MIN_PITCH: f32 = -10.0 * std::f32::consts::PI / 180.0;
const MAX_PITCH: f32 = 89.0 * std::f32::consts::PI / 180.0;
/// Radians per UI point of drag.
const ROTATE_SPEED: f32 = 0.006;
/// Zoom factor exponent per UI point of scroll.
const ZOOM_SPEED: f32 = 0.0015;
/// How far (UI points) from the cursor a double-click still picks a point.
pub const PICK_RADIUS: f32 = 6.0;

/// An orbit / bird's-eye camera. Serialisable so sessions can store the exact view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// The point orbited around and looked at (base frame, m).
    pub target: [f32; 3],
    /// Heading of the viewing direction about +z (rad); 0 looks along +x.
    pub yaw: f32,
    /// Downward tilt (rad), positive looks down.
    pub pitch: f32,
    /// Distance from the eye to the target (m); in bird's-eye mode sets the zoom.
    pub distance: f32,
    /// Vertical field of view (rad).
    pub fov_y: f32,
    pub projection: Projection,
}

impl Default for Camera {
    fn default() -> Self {
        Self::preset(View::Overview, 50.0)
    }
}

impl Camera {
    /// A preset view of a scene of the given radius (m) around the base-frame origin.
    pub fn preset(view: View, scene_radius: f32) -> Self {
        let radius = if scene_radius.is_finite() && scene_radius > 1.0 {
            scene_radius
        } else {
            50.0
        };
        let fov_y = 50f32.to_radians();
        let deg = f32::to_radians;
        let orbit = |target: [f32; 3], yaw: f32, pitch: f32, distance: f32| Self {
            target,
            yaw,
            pitch,
            distance,
            fov_y,
            projection: Projection::Perspective,
        };
        let fit = radius / (0.5 * fov_y).tan();
        match view {
            View::Overview => orbit([0.0; 3], 0.0, deg(40.0), 0.8 * fit),
            View::Bev => Self {
                projection: Projection::BirdsEye,
                ..orbit([0.0; 3], 0.0, MAX_PITCH, fit)
            },
            View::Chase => orbit([10.0, 0.0, 0.0], 0.0, deg(15.0), 25.0),
            View::Front => orbit([0.0; 3], std::f32::consts::PI, deg(15.0), 20.0),
            View::Left => orbit([0.0; 3], -std::f32::consts::FRAC_PI_2, deg(20.0), 20.0),
            View::Right => orbit([0.0; 3], std::f32::consts::FRAC_PI_2, deg(20.0), 20.0),
        }
    }

    fn target_v(&self) -> Vec3 {
        Vec3::from_array(self.target)
    }

    /// Unit viewing direction (from the eye towards the target).
    pub fn forward(&self) -> Vec3 {
        match self.projection {
            Projection::Perspective => {
                let (sp, cp) = self.pitch.sin_cos();
                let (sy, cy) = self.yaw.sin_cos();
                Vec3::new(cp * cy, cp * sy, -sp)
            }
            Projection::BirdsEye => Vec3::NEG_Z,
        }
    }

    /// The on-screen up direction in the world.
    fn up(&self) -> Vec3 {
        match self.projection {
            // The orbit camera keeps +z up; at the pitch limits look_at stays well defined.
            Projection::Perspective => Vec3::Z,
            Projection::BirdsEye => Vec3::new(self.yaw.cos(), self.yaw.sin(), 0.0),
        }
    }

    /// Eye position (m). In bird's-eye mode: `distance` above the target.
    pub fn eye(&self) -> Vec3 {
        self.target_v() - self.forward() * self.distance
    }

    /// Near plane (m) of the perspective projection, scaled with the distance.
    fn near(&self) -> f32 {
        (self.distance * 0.01).clamp(0.01, 1.0)
    }

    /// World-to-clip transform for a viewport of the given aspect (width / height), with reversed
    /// depth (near = 1, far = 0).
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        let view = Mat4::look_at_rh(self.eye(), self.target_v(), self.up());
        match self.projection {
            Projection::Perspective => {
                Mat4::perspective_infinite_reverse_rh(self.fov_y, aspect, self.near()) * view
            }
            Projection::BirdsEye => {
                let half_h = self.half_height();
                let half_w = half_h * aspect;
                // Depth range generous enough for any scene around the target.
                let depth = 10_000.0;
                let ortho = Mat4::orthographic_rh(
                    -half_w,
                    half_w,
                    -half_h,
                    half_h,
                    self.distance - depth,
                    self.distance + depth,
                );
                // Flip depth to match the reversed-z convention (z' = w − z).
                let flip = Mat4::from_cols(
                    Vec4::X,
                    Vec4::Y,
                    Vec4::new(0.0, 0.0, -1.0, 0.0),
                    Vec4::new(0.0, 0.0, 1.0, 1.0),
                );
                flip * ortho * view
            }
        }
    }

    /// World height (m) of half the viewport in bird's-eye mode, or at the target in perspective.
    pub fn half_height(&self) -> f32 {
        self.distance * (0.5 * self.fov_y).tan()
    }

    /// The clip-space w below which geometry is behind the near plane (for line clipping).
    pub(crate) fn near_w(&self) -> f32 {
        match self.projection {
            Projection::Perspective => self.near(),
            Projection::BirdsEye => 0.0,
        }
    }

    /// Projects a world point into `rect` (UI points); `None` when behind the camera.
    pub fn project(&self, point: [f32; 3], rect: Rect) -> Option<Pos2> {
        let clip = self.view_proj(rect.aspect_ratio()) * Vec3::from_array(point).extend(1.0);
        if clip.w <= 0.0 {
            return None;
        }
        let ndc = clip.truncate() / clip.w;
        Some(Pos2::new(
            rect.min.x + (ndc.x + 1.0) * 0.5 * rect.width(),
            rect.min.y + (1.0 - ndc.y) * 0.5 * rect.height(),
        ))
    }

    /// The index of the front-most point whose projection lies within `radius` UI points of
    /// `cursor` (a CPU pick over the points the app handed over).
    pub fn pick(&self, points: &[[f32; 3]], rect: Rect, cursor: Pos2, radius: f32) -> Option<usize> {
        let vp = self.view_proj(rect.aspect_ratio());
        let r2 = radius * radius;
        let mut best: Option<(usize, f32)> = None;
        for (i, p) in points.iter().enumerate() {
            let clip = vp * Vec3::from_array(*p).extend(1.0);
            if clip.w.is_nan() || clip.w <= 0.0 {
                continue;
            }
            let ndc = clip.truncate() / clip.w;
            if !(0.0..=1.0).contains(&ndc.z) {
                continue; // clipped by the near plane
            }
            let x = rect.min.x + (ndc.x + 1.0) * 0.5 * rect.width();
            let y = rect.min.y + (1.0 - ndc.y) * 0.5 * rect.height();
            let d2 = (x - cursor.x).powi(2) + (y - cursor.y).powi(2);
            // Reversed depth: larger z is nearer the eye.
            if d2 <= r2 && best.is_none_or(|(_, z)| ndc.z > z) {
                best = Some((i, ndc.z));
            }
        }
        best.map(|(i, _)| i)
    }

    /// Moves the target to `point`, keeping the viewing direction and distance.
    pub fn focus_on(&mut self, point: [f32; 3]) {
        if point.iter().all(|v| v.is_finite()) {
            self.target = point;
        }
    }

    /// The zoom range (m) allowed for a scene of the given radius.
    pub fn zoom_bounds(scene_radius: f32) -> (f32, f32) {
        let r = if scene_radius.is_finite() {
            scene_radius
        } else {
            0.0
        };
        (MIN_DISTANCE, (4.0 * r).max(40.0))
    }

    /// Multiplies the distance by `factor` (< 1 zooms in), within [`Self::zoom_bounds`].
    pub fn zoom(&mut self, factor: f32, scene_radius: f32) {
        let (lo, hi) = Self::zoom_bounds(scene_radius);
        if factor.is_finite() && factor > 0.0 {
            self.distance = (self.distance * factor).clamp(lo, hi);
        }
    }

    /// Rotates by a drag of `delta` UI points (yaw from x, pitch from y; pitch only in perspective).
    pub fn rotate(&mut self, delta: Vec2) {
        self.yaw = (self.yaw - delta.x * ROTATE_SPEED).rem_euclid(std::f32::consts::TAU);
        if self.projection == Projection::Perspective {
            self.pitch = (self.pitch + delta.y * ROTATE_SPEED).clamp(MIN_PITCH, MAX_PITCH);
        }
    }

    /// Pans so the scene follows a drag of `delta` UI points in a viewport `height` points high.
    pub fn pan(&mut self, delta: Vec2, height: f32) {
        if height.is_nan() || height <= 0.0 {
            return;
        }
        let metres_per_point = 2.0 * self.half_height() / height;
        let forward = self.forward();
        let right = forward.cross(self.up()).normalize_or_zero();
        let up = right.cross(forward).normalize_or_zero();
        let shift = (-right * delta.x + up * delta.y) * metres_per_point;
        self.target = (self.target_v() + shift).to_array();
    }

    /// Drag = rotate (bird's eye: pan), right-drag / shift-drag / middle-drag = pan (bird's eye:
    /// right-drag rotates), scroll or pinch = zoom within the scene's bounds, double-click = focus
    /// on the point under the cursor. Returns the index of the double-clicked point, if any.
    pub fn handle_input(&mut self, response: &Response, ui: &Ui, scene: &SceneHandle) -> Option<usize> {
        let rect = response.rect;
        let shift = ui.input(|i| i.modifiers.shift);
        let delta = response.drag_delta();
        let primary = response.dragged_by(PointerButton::Primary);
        let secondary = response.dragged_by(PointerButton::Secondary);
        let middle = response.dragged_by(PointerButton::Middle);
        let (rotating, panning) = match self.projection {
            Projection::Perspective => (primary && !shift, secondary || middle || (primary && shift)),
            Projection::BirdsEye => (secondary, primary || middle),
        };
        if delta != Vec2::ZERO {
            if rotating {
                self.rotate(delta);
            } else if panning {
                self.pan(delta, rect.height());
            }
        }
        if response.hovered() {
            let (scroll, pinch) = ui.input(|i| (i.smooth_scroll_delta.y, i.zoom_delta()));
            let factor = (-scroll * ZOOM_SPEED).exp() / pinch;
            if factor != 1.0 {
                self.zoom(factor, scene.radius());
            }
        }
        if response.double_clicked() {
            let cursor = response.interact_pointer_pos()?;
            let picked = self.pick(scene.points(), rect, cursor, PICK_RADIUS)?;
            if let Some(p) = scene.points().get(picked) {
                self.focus_on(*p);
            }
            return Some(picked);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect() -> Rect {
        Rect::from_min_size(Pos2::new(100.0, 50.0), egui::vec2(800.0, 600.0))
    }

    #[test]
    fn target_projects_to_the_centre_in_every_preset() {
        for view in View::ALL {
            let mut cam = Camera::preset(view, 60.0);
            cam.target = [3.0, -2.0, 0.5];
            let p = cam.project(cam.target, rect()).unwrap();
            let c = rect().center();
            assert!((p - c).length() < 1e-2, "{view:?}: {p:?} vs {c:?}");
        }
    }

    #[test]
    fn bev_puts_plus_x_up_and_plus_y_left() {
        let cam = Camera::preset(View::Bev, 50.0);
        let c = rect().center();
        let ahead = cam.project([10.0, 0.0, 0.0], rect()).unwrap();
        assert!(ahead.y < c.y - 10.0 && (ahead.x - c.x).abs() < 1e-3);
        let left = cam.project([0.0, 10.0, 0.0], rect()).unwrap();
        assert!(left.x < c.x - 10.0 && (left.y - c.y).abs() < 1e-3);
        // Orthographic: height does not move a point on screen.
        let high = cam.project([10.0, 0.0, 5.0], rect()).unwrap();
        assert!((high - ahead).length() < 1e-3);
    }

    #[test]
    fn depth_is_reversed_and_in_range() {
        for view in [View::Overview, View::Bev] {
            let cam = Camera::preset(view, 50.0);
            let vp = cam.view_proj(1.5);
            let depth = |p: Vec3| {
                let c = vp * p.extend(1.0);
                c.z / c.w
            };
            let near = depth(cam.eye() + cam.forward() * 5.0);
            let far = depth(cam.eye() + cam.forward() * 50.0);
            assert!(near > far, "{view:?}: {near} {far}");
            assert!((0.0..=1.0).contains(&near) && (0.0..=1.0).contains(&far));
        }
    }

    #[test]
    fn zoom_is_bounded_by_the_scene() {
        let mut cam = Camera::preset(View::Overview, 50.0);
        for _ in 0..200 {
            cam.zoom(0.5, 50.0);
        }
        assert_eq!(cam.distance, MIN_DISTANCE);
        for _ in 0..200 {
            cam.zoom(2.0, 50.0);
        }
        assert_eq!(cam.distance, 200.0);
        cam.zoom(f32::NAN, 50.0);
        assert_eq!(cam.distance, 200.0);
    }

    #[test]
    fn pick_prefers_the_front_point_and_respects_the_radius() {
        let cam = Camera::preset(View::Chase, 50.0);
        let eye = cam.eye();
        let dir = cam.forward();
        let front = (eye + dir * 10.0).to_array();
        let back = (eye + dir * 30.0).to_array();
        let points = [back, front, [0.0, 80.0, 0.0]];
        let c = rect().center();
        assert_eq!(cam.pick(&points, rect(), c, 4.0), Some(1));
        assert_eq!(cam.pick(&points, rect(), c + egui::vec2(200.0, 0.0), 4.0), None);
        assert_eq!(cam.pick(&[], rect(), c, 4.0), None);
    }

    #[test]
    fn pan_moves_the_target_with_the_drag() {
        let mut cam = Camera::preset(View::Bev, 50.0);
        cam.pan(egui::vec2(0.0, 100.0), 600.0);
        // Dragging the scene down moves the target towards +x (what was above comes to the centre).
        assert!(cam.target[0] > 1.0 && cam.target[1].abs() < 1e-4);
    }

    #[test]
    fn camera_round_trips_through_json() {
        let cam = Camera::preset(View::Left, 30.0);
        let json = serde_json::to_string(&cam).unwrap();
        let back: Camera = serde_json::from_str(&json).unwrap();
        assert_eq!(cam, back);
    }
}
