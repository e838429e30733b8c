//! Properties of the rotated IoU (geometry::iou), checked on random boxes with proptest, and the
//! clipping checked against an independent grid count of the overlap area.

use std::f64::consts::PI;

use mlod::geometry::iou::{iou, iou_bev, Footprint, IouKind};
use mlod::geometry::{Box3d, Pose};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn arb_box() -> impl Strategy<Value = Box3d> {
    (
        -6.0..6.0f64,
        -6.0..6.0f64,
        -1.0..1.0f64,
        0.3..6.0f64,
        0.3..3.0f64,
        0.3..3.0f64,
        -PI..PI,
    )
        .prop_map(|(x, y, z, l, w, h, yaw)| Box3d::new([x, y, z], [l, w, h], yaw))
}

fn kinds() -> [IouKind; 2] {
    [IouKind::Bev, IouKind::ThreeD]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn symmetric_and_bounded(a in arb_box(), b in arb_box()) {
        for k in kinds() {
            let ab = iou(&a, &b, k);
            let ba = iou(&b, &a, k);
            prop_assert!((ab - ba).abs() < 1e-9, "{k:?}: {ab} vs {ba}");
            prop_assert!((0.0..=1.0).contains(&ab));
        }
        // With equal heights and centres the height term is 1: 3D IoU equals BEV IoU.
        let mut b2 = b;
        b2.center[2] = a.center[2];
        b2.size_lwh[2] = a.size_lwh[2];
        prop_assert!((iou(&a, &b2, IouKind::ThreeD) - iou_bev(&a, &b2)).abs() < 1e-9);
    }

    #[test]
    fn a_box_with_itself_is_one(a in arb_box()) {
        for k in kinds() {
            prop_assert!((iou(&a, &a, k) - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn invariant_under_a_common_motion_about_z(
        a in arb_box(), b in arb_box(), yaw in -PI..PI, tx in -50.0..50.0f64, ty in -50.0..50.0f64, tz in -2.0..2.0f64
    ) {
        let pose: Pose = Isometry3::from_parts(
            Translation3::new(tx, ty, tz),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        );
        for k in kinds() {
            let before = iou(&a, &b, k);
            let after = iou(&a.transformed(&pose), &b.transformed(&pose), k);
            prop_assert!((before - after).abs() < 1e-9, "{k:?}: {before} vs {after}");
        }
    }

    #[test]
    fn yaw_plus_pi_is_the_same_box(a in arb_box(), b in arb_box()) {
        let mut flipped = b;
        flipped.yaw += if b.yaw > 0.0 { -PI } else { PI };
        for k in kinds() {
            prop_assert!((iou(&a, &b, k) - iou(&a, &flipped, k)).abs() < 1e-9);
        }
    }
}

/// The clipped intersection area against a dense grid count of points inside both rectangles.
#[test]
fn clipping_matches_a_grid_count() {
    let cases = [
        (
            Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.0], 0.3),
            Box3d::new([1.0, 0.5, 0.0], [3.0, 1.5, 1.0], 1.2),
        ),
        (
            Box3d::new([0.0, 0.0, 0.0], [5.0, 1.0, 1.0], 0.0),
            Box3d::new([0.0, 0.0, 0.0], [5.0, 1.0, 1.0], std::f64::consts::FRAC_PI_2),
        ),
        (
            Box3d::new([0.2, -0.3, 0.0], [2.0, 2.0, 1.0], 0.7),
            Box3d::new([-0.4, 0.1, 0.0], [1.0, 4.0, 1.0], -0.4),
        ),
    ];
    for (a, b) in cases {
        let exact = Footprint::of_box(&a).intersection_area(&Footprint::of_box(&b));
        let n = 999; // odd: no cell centre falls exactly on an axis-aligned edge
        let (lo, hi) = (-4.0, 4.0);
        let cell = (hi - lo) / n as f64;
        let mut count = 0usize;
        for i in 0..n {
            for j in 0..n {
                let p = [lo + (i as f64 + 0.5) * cell, lo + (j as f64 + 0.5) * cell, 0.0];
                if a.contains(p, 0.0) && b.contains(p, 0.0) {
                    count += 1;
                }
            }
        }
        let grid = count as f64 * cell * cell;
        assert!(
            (exact - grid).abs() < 0.01 * exact.max(0.1),
            "exact {exact} vs grid {grid}"
        );
    }
}
