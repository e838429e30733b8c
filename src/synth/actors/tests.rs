//! Unit tests of the actors' shapes.
use super::*;
use crate::synth::noise::layout_rng;

#[test]
fn every_shape_fills_its_annotation_box_exactly() {
    let mut rng = layout_rng(&[1, 2, 3]);
    for cat in Category::ALL {
        for _ in 0..50 {
            let s = build(cat, &mut rng);
            let (lo, hi) = s.bounds();
            for k in 0..3 {
                let half = 0.5 * s.size_lwh[k];
                assert!(
                    (lo[k] + half).abs() < 1e-9,
                    "{cat:?} axis {k}: {} vs {}",
                    lo[k],
                    -half
                );
                assert!(
                    (hi[k] - half).abs() < 1e-9,
                    "{cat:?} axis {k}: {} vs {}",
                    hi[k],
                    half
                );
            }
        }
    }
}

#[test]
fn car_sizes_are_lyft_like_and_not_cuboids() {
    let mut rng = layout_rng(&[4]);
    for _ in 0..100 {
        let s = build(Category::Car, &mut rng);
        let [l, w, h] = s.size_lwh;
        assert!((4.2..=5.0).contains(&l) && (1.8..=2.1).contains(&w) && (1.4..=1.9).contains(&h));
        // The top front corner of the box is empty (hood below the roof line).
        assert!(!s.contains(&[0.45 * l, 0.0, 0.45 * h], 0.0));
        // The plan-view corners are rounded off.
        assert!(!s.contains(&[0.49 * l, 0.49 * w, -0.1 * h], 0.0));
        // The centre of the cabin and of the lower body are solid.
        assert!(s.contains(&[0.0, 0.0, 0.3 * h], 0.0) && s.contains(&[0.3 * l, 0.0, -0.2 * h], 0.0));
    }
}

#[test]
fn detailed_cars_fill_their_box_with_arches_clearance_and_mirrors() {
    let mut rng = layout_rng(&[5]);
    for _ in 0..100 {
        let s = build_with(Category::Car, CarSizes::Detailed, &mut rng);
        let [l, w, h] = s.size_lwh;
        let (lo, hi) = s.bounds();
        for k in 0..3 {
            assert!((lo[k] + 0.5 * s.size_lwh[k]).abs() < 1e-9, "axis {k}: {lo:?}");
            assert!((hi[k] - 0.5 * s.size_lwh[k]).abs() < 1e-9, "axis {k}: {hi:?}");
        }
        let z0 = -0.5 * h;
        let rw = (0.3 + 0.12 * (h - 1.4)).clamp(0.3, 0.4);
        let xf = 0.5 * l - 0.95;
        // Above the front wheel, inside its arch, at the body's side: empty.
        assert!(!s.contains(&[xf, 0.5 * w - 0.1, z0 + 2.0 * rw + 0.02], 0.0));
        // Under the middle of the car, 10 cm above the road: empty (clearance ≥ 14 cm).
        assert!(!s.contains(&[0.0, 0.0, z0 + 0.1], 0.0));
        // The wheel itself and the door below the belt line: solid.
        assert!(s.contains(&[xf, 0.5 * w - 0.15, z0 + rw], 0.0));
        assert!(s.contains(&[0.0, 0.5 * w - 0.1, z0 + 0.45 * h], 0.0));
        // Beside the door the box is empty (the body is 9 cm narrower than the mirrors).
        assert!(!s.contains(&[0.0, 0.5 * w - 0.03, z0 + 0.45 * h], 0.0));
    }
}
