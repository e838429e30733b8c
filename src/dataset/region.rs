//! Where evaluation looks in a frame, for formats that label only part of the sweep: KITTI labels
//! only what camera 2 sees. A prediction outside the region is neither a true nor a false
//! positive; the KITTI reader (`super::kitti`) builds one region per frame from its calibration
//! and `DontCare` lines.

use nalgebra::{Matrix3x4, Vector4};

use crate::geometry::Box3d;

/// Where evaluation looks in a frame: KITTI labels only what camera 2 sees.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalRegion {
    /// LiDAR (base) frame → image pixels.
    pub projection: Matrix3x4<f64>,
    pub width: f64,
    pub height: f64,
    /// `DontCare` regions of the image: left, top, right, bottom.
    pub dont_care: Vec<[f64; 4]>,
}

/// Whether a box counts in evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegionVerdict {
    Inside,
    /// Its centre is behind the camera or projects outside the image.
    OutsideView,
    /// Its projected 2D box is more than half inside a `DontCare` region.
    DontCare,
}

impl EvalRegion {
    fn project(&self, p: [f64; 3]) -> Option<(f64, f64)> {
        let q = self.projection * Vector4::new(p[0], p[1], p[2], 1.0);
        (q.z > 1e-3).then(|| (q.x / q.z, q.y / q.z))
    }

    /// Whether `b` (base frame) is evaluated: its centre must project inside the image, and its
    /// 2D box (the projected corners in front of the camera, clipped to the image) must not lie
    /// more than half inside a `DontCare` region (KITTI's rule).
    pub fn verdict(&self, b: &Box3d) -> RegionVerdict {
        let Some((u, v)) = self.project(b.center) else {
            return RegionVerdict::OutsideView;
        };
        if !(0.0..self.width).contains(&u) || !(0.0..self.height).contains(&v) {
            return RegionVerdict::OutsideView;
        }
        let (mut x1, mut y1, mut x2, mut y2) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for c in b.corners() {
            if let Some((cu, cv)) = self.project(c) {
                x1 = x1.min(cu);
                y1 = y1.min(cv);
                x2 = x2.max(cu);
                y2 = y2.max(cv);
            }
        }
        let (x1, y1) = (x1.max(0.0), y1.max(0.0));
        let (x2, y2) = (x2.min(self.width), y2.min(self.height));
        let area = (x2 - x1).max(0.0) * (y2 - y1).max(0.0);
        if area > 0.0 {
            for r in &self.dont_care {
                let iw = (x2.min(r[2]) - x1.max(r[0])).max(0.0);
                let ih = (y2.min(r[3]) - y1.max(r[1])).max(0.0);
                if iw * ih / area > 0.5 {
                    return RegionVerdict::DontCare;
                }
            }
        }
        RegionVerdict::Inside
    }

    /// Whether a point (base frame) lies where the labels speak: in front of the camera, inside
    /// the image's columns and outside every `DontCare` region. Rows are not checked, so a point
    /// below or above the image (the road just ahead, a box's top) still counts. Training uses
    /// it so that anchors the labels say nothing about teach neither "car" nor "background".
    pub fn labels_point(&self, p: [f64; 3]) -> bool {
        let Some((u, v)) = self.project(p) else {
            return false;
        };
        (0.0..self.width).contains(&u)
            && !self
                .dont_care
                .iter()
                .any(|r| (r[0]..=r[2]).contains(&u) && (r[1]..=r[3]).contains(&v))
    }

    /// True when `b` counts in evaluation.
    pub fn contains(&self, b: &Box3d) -> bool {
        self.verdict(b) == RegionVerdict::Inside
    }
}
