//! Anchors, target assignment and SECOND's box coding, kept apart from the network (as OpenPCDet's
//! anchor head template does).
//!
//! How it works:
//! - Anchors: one class (car, Lyft's mean size l 4.7 × w 1.9 × h 1.7 m) at two orientations (0 and
//!   π/2) on every cell of the 0.8 m head grid, order (row, column, orientation).
//! - Assignment (SECOND): the BEV IoU of each ground-truth box with the anchors near it, both turned
//!   to their nearest axis-aligned rectangle (SECOND's "nearest BEV" similarity, cheap enough to run
//!   every step after augmentation). IoU ≥ 0.6: positive; < 0.45: negative; in between: ignored;
//!   each box also gets its best anchor. Boxes with too few points to be seen are "don't care":
//!   anchors on them are ignored rather than negatives.
//! - Box coding (SECOND): with d = √(l_a² + w_a²), residuals (Δx/d, Δy/d, Δz/h_a, ln l/l_a,
//!   ln w/w_a, ln h/h_a, θ − θ_a). The angle is learned through sin(θ_p − θ_t) (π-periodic), so a
//!   direction classifier says which half-turn the heading lies in, measured from `DIR_OFFSET`.

use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use serde::{Deserialize, Serialize};

use super::voxel::GridConfig;
use crate::geometry::Box3d;

/// A box as the network sees it: x, y, z (centre), l, w, h, yaw.
pub type RawBox = [f32; 7];

/// A [`Box3d`] as the network sees it.
pub fn raw_box(b: &Box3d) -> RawBox {
    [
        b.center[0] as f32,
        b.center[1] as f32,
        b.center[2] as f32,
        b.size_lwh[0] as f32,
        b.size_lwh[1] as f32,
        b.size_lwh[2] as f32,
        b.yaw as f32,
    ]
}

/// A raw box as a [`Box3d`].
pub fn box3d_of(b: &RawBox) -> Box3d {
    Box3d::new(
        [b[0] as f64, b[1] as f64, b[2] as f64],
        [b[3] as f64, b[4] as f64, b[5] as f64],
        b[6] as f64,
    )
}

/// The direction classes split headings at this angle (π/4 keeps the common headings 0, ±π/2, π
/// away from the class boundary).
pub const DIR_OFFSET: f32 = FRAC_PI_4;

/// Anchor and assignment settings of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnchorConfig {
    pub category: String,
    /// Anchor size (l, w, h) in m.
    pub size_lwh: [f32; 3],
    /// Anchor centre height in the base frame (m).
    pub z_center: f32,
    /// Head cell = `stride` input cells.
    pub stride: usize,
    pub pos_iou: f32,
    pub neg_iou: f32,
    /// Ground-truth boxes with fewer points than this are "don't care" in training.
    pub min_points: usize,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        Self {
            category: "car".into(),
            size_lwh: [4.7, 1.9, 1.7],
            z_center: -0.95,
            stride: 2,
            pos_iou: 0.6,
            neg_iou: 0.45,
            min_points: 5,
        }
    }
}

/// Orientations of the anchors of one cell.
pub const ROTATIONS: [f32; 2] = [0.0, FRAC_PI_2];

/// The anchors of a grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Anchors {
    pub boxes: Vec<RawBox>,
    /// Head cells along x and y.
    pub n: usize,
    /// Head cell size (m).
    pub cell: f32,
    pub xy_min: f32,
}

impl Anchors {
    pub fn new(grid: &GridConfig, cfg: &AnchorConfig) -> Self {
        let n = grid.n / cfg.stride.max(1);
        let cell = grid.cell * cfg.stride.max(1) as f32;
        let [l, w, h] = cfg.size_lwh;
        let mut boxes = Vec::with_capacity(n * n * ROTATIONS.len());
        for iy in 0..n {
            for ix in 0..n {
                let x = grid.xy_min + (ix as f32 + 0.5) * cell;
                let y = grid.xy_min + (iy as f32 + 0.5) * cell;
                for r in ROTATIONS {
                    boxes.push([x, y, cfg.z_center, l, w, h, r]);
                }
            }
        }
        Self {
            boxes,
            n,
            cell,
            xy_min: grid.xy_min,
        }
    }

    pub fn len(&self) -> usize {
        self.boxes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }
}

/// SECOND's residuals of `gt` relative to anchor `a`.
pub fn encode(gt: &RawBox, a: &RawBox) -> [f32; 7] {
    let d = (a[3] * a[3] + a[4] * a[4]).sqrt();
    [
        (gt[0] - a[0]) / d,
        (gt[1] - a[1]) / d,
        (gt[2] - a[2]) / a[5],
        (gt[3] / a[3]).ln(),
        (gt[4] / a[4]).ln(),
        (gt[5] / a[5]).ln(),
        gt[6] - a[6],
    ]
}

/// The box of residuals `r` on anchor `a` (inverse of [`encode`]; the yaw is not wrapped).
pub fn decode(r: &[f32; 7], a: &RawBox) -> RawBox {
    let d = (a[3] * a[3] + a[4] * a[4]).sqrt();
    [
        a[0] + r[0] * d,
        a[1] + r[1] * d,
        a[2] + r[2] * a[5],
        a[3] * r[3].exp(),
        a[4] * r[4].exp(),
        a[5] * r[5].exp(),
        a[6] + r[6],
    ]
}

/// The direction class of a heading: which half-turn from [`DIR_OFFSET`] it lies in.
pub fn dir_class(yaw: f32) -> u32 {
    let t = (yaw - DIR_OFFSET).rem_euclid(2.0 * PI);
    u32::from(t >= PI)
}

/// A decoded yaw moved into the half-turn its direction class names, wrapped to (−π, π].
pub fn apply_direction(yaw: f32, dir: u32) -> f32 {
    let base = (yaw - DIR_OFFSET).rem_euclid(PI) + DIR_OFFSET + if dir == 1 { PI } else { 0.0 };
    let w = base.rem_euclid(2.0 * PI);
    if w > PI {
        w - 2.0 * PI
    } else {
        w
    }
}

/// The nearest axis-aligned BEV rectangle [x0, y0, x1, y1] of a box (SECOND): l and w swap when
/// the heading is closer to ±y than to ±x.
pub fn nearest_bev_rect(b: &RawBox) -> [f32; 4] {
    let t = (b[6] + FRAC_PI_4).rem_euclid(PI);
    let (ex, ey) = if t >= FRAC_PI_2 {
        (b[4], b[3])
    } else {
        (b[3], b[4])
    };
    [b[0] - 0.5 * ex, b[1] - 0.5 * ey, b[0] + 0.5 * ex, b[1] + 0.5 * ey]
}

fn rect_iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
    if union > 0.0 {
        inter / union
    } else {
        0.0
    }
}

/// Training targets of one sample.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Targets {
    /// Per anchor: 1 positive, 0 otherwise.
    pub labels: Vec<f32>,
    /// Per anchor: 1 for positives and negatives, 0 for ignored anchors.
    pub cls_weights: Vec<f32>,
    /// Indices of the positive anchors.
    pub positives: Vec<u32>,
    /// Per positive: its 7 residuals, row-major.
    pub reg: Vec<f32>,
    /// Per positive: its direction class.
    pub dir: Vec<u32>,
}

/// Assigns anchors to ground truth (see the module doc). `gts` are the boxes to learn,
/// `dont_care` boxes whose anchors are neither positive nor negative.
pub fn assign(anchors: &Anchors, cfg: &AnchorConfig, gts: &[RawBox], dont_care: &[RawBox]) -> Targets {
    let na = ROTATIONS.len();
    let total = anchors.len();
    let mut best_iou = vec![0f32; total];
    let mut best_gt = vec![u32::MAX; total];
    let mut dont_care_iou = vec![0f32; total];
    let anchor_rects: [[f32; 2]; 2] = std::array::from_fn(|k| {
        let r = nearest_bev_rect(&[0.0, 0.0, 0.0, cfg.size_lwh[0], cfg.size_lwh[1], 0.0, ROTATIONS[k]]);
        [r[2], r[3]]
    });
    let mut forced: Vec<(usize, usize)> = Vec::new();
    let visit = |b: &RawBox, f: &mut dyn FnMut(usize, f32)| {
        let r = nearest_bev_rect(b);
        let reach = 0.5 * (cfg.size_lwh[0] + cfg.size_lwh[1]);
        let lo = |v: f32| (((v - reach - anchors.xy_min) / anchors.cell).floor().max(0.0)) as usize;
        let hi = |v: f32| {
            let c = ((v + reach - anchors.xy_min) / anchors.cell).ceil();
            (c.max(0.0) as usize).min(anchors.n)
        };
        for iy in lo(r[1])..hi(r[3]) {
            for ix in lo(r[0])..hi(r[2]) {
                for (k, half) in anchor_rects.iter().enumerate() {
                    let idx = (iy * anchors.n + ix) * na + k;
                    let a = &anchors.boxes[idx];
                    let ar = [a[0] - half[0], a[1] - half[1], a[0] + half[0], a[1] + half[1]];
                    let iou = rect_iou(&ar, &r);
                    if iou > 0.0 {
                        f(idx, iou);
                    }
                }
            }
        }
    };
    for (g, b) in gts.iter().enumerate() {
        let mut best: Option<(usize, f32)> = None;
        visit(b, &mut |idx, iou| {
            if iou > best_iou[idx] {
                best_iou[idx] = iou;
                best_gt[idx] = g as u32;
            }
            if best.is_none_or(|(_, v)| iou > v) {
                best = Some((idx, iou));
            }
        });
        if let Some((idx, _)) = best {
            forced.push((idx, g));
        }
    }
    for b in dont_care {
        visit(b, &mut |idx, iou| {
            dont_care_iou[idx] = dont_care_iou[idx].max(iou)
        });
    }
    let mut t = Targets {
        labels: vec![0.0; total],
        cls_weights: vec![1.0; total],
        ..Default::default()
    };
    let mut gt_of = vec![u32::MAX; total];
    for i in 0..total {
        if best_iou[i] >= cfg.pos_iou {
            gt_of[i] = best_gt[i];
        } else if best_iou[i] >= cfg.neg_iou || dont_care_iou[i] >= cfg.neg_iou {
            t.cls_weights[i] = 0.0;
        }
    }
    for (idx, g) in forced {
        gt_of[idx] = g as u32;
        t.cls_weights[idx] = 1.0;
    }
    for (i, g) in gt_of.iter().enumerate() {
        let Some(gt) = gts.get(*g as usize) else { continue };
        t.labels[i] = 1.0;
        t.positives.push(i as u32);
        t.reg.extend_from_slice(&encode(gt, &anchors.boxes[i]));
        t.dir.push(dir_class(gt[6]));
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_decode_round_trip() {
        let a = [10.4, -3.2, -0.95, 4.7, 1.9, 1.7, FRAC_PI_2];
        for gt in [
            [11.0, -3.0, -1.1, 4.2, 1.8, 1.5, 1.7],
            [-20.0, 7.0, 0.3, 12.0, 2.9, 3.5, -3.0],
            [10.4, -3.2, -0.95, 4.7, 1.9, 1.7, FRAC_PI_2],
        ] {
            let back = decode(&encode(&gt, &a), &a);
            for k in 0..7 {
                assert!((back[k] - gt[k]).abs() < 1e-4, "{k}: {back:?} vs {gt:?}");
            }
        }
    }

    #[test]
    fn direction_class_recovers_heading() {
        for i in -40..40 {
            let yaw = i as f32 * 0.0785;
            // Within the noise of the class boundary the half-turn is ambiguous by design.
            let m = (yaw - DIR_OFFSET).rem_euclid(PI);
            if !(0.02..=PI - 0.02).contains(&m) {
                continue;
            }
            // The regression only knows the heading modulo π.
            let noisy = yaw + if i % 2 == 0 { PI } else { 0.0 } + 0.01;
            let back = apply_direction(noisy, dir_class(yaw));
            let d = (back - yaw - 0.01).rem_euclid(2.0 * PI);
            assert!(!(1e-4..=2.0 * PI - 1e-4).contains(&d), "{yaw} -> {back}");
        }
    }

    #[test]
    fn assignment_gives_each_box_positives() {
        let grid = GridConfig::default();
        let cfg = AnchorConfig::default();
        let anchors = Anchors::new(&grid, &cfg);
        assert_eq!(anchors.len(), 128 * 128 * 2);
        // One box on an anchor centre, one between cells at 30°, one don't-care.
        let gts = [
            [0.4, 0.4, -0.9, 4.5, 1.9, 1.6, 0.0],
            [20.0, 10.0, -1.0, 4.0, 1.7, 1.5, 0.52],
        ];
        let dc = [[-30.0, -30.0, -1.0, 4.5, 1.9, 1.6, FRAC_PI_2]];
        let t = assign(&anchors, &cfg, &gts, &dc);
        assert!(t.positives.len() >= 3, "{}", t.positives.len());
        assert_eq!(t.reg.len(), 7 * t.positives.len());
        // The anchor under box 0 (cell 64, 64, orientation 0) is positive with ~zero residuals.
        let idx = (64 * 128 + 64) * 2;
        assert_eq!(t.labels[idx], 1.0);
        let p = t.positives.iter().position(|&i| i as usize == idx).unwrap();
        assert!(t.reg[7 * p..7 * p + 3].iter().all(|v| v.abs() < 0.05));
        // Both boxes have a positive; the don't-care box has ignored anchors and no positive.
        let near = |x: f32, y: f32| {
            t.positives.iter().any(|&i| {
                let a = anchors.boxes[i as usize];
                (a[0] - x).abs() < 2.0 && (a[1] - y).abs() < 2.0
            })
        };
        assert!(near(0.4, 0.4) && near(20.0, 10.0) && !near(-30.0, -30.0));
        let dc_idx = ((((-30.0 + 51.2) / 0.8) as usize) * 128 + ((-30.0 + 51.2) / 0.8) as usize) * 2 + 1;
        assert_eq!(t.cls_weights[dc_idx], 0.0);
        assert_eq!(t.labels.iter().filter(|v| **v == 1.0).count(), t.positives.len());
    }
}
