//! Evaluation hot paths (evaluation issue): the rotated 3D IoU matrix of 200 × 200 boxes, and a
//! whole-dataset `mlod eval` on sample_data/ (10 samples, 363 GT, 379 predictions: KITTI AP_3D at
//! two thresholds × three difficulties for every class, plus the Lyft mAP at ten thresholds with
//! both footprints).
use std::collections::HashSet;
use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use mlod::eval::{self, EvalOptions};
use mlod::geometry::iou::{iou_matrix, IouKind};
use mlod::geometry::Box3d;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn boxes(n: usize, seed: u64) -> Vec<Box3d> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            Box3d::new(
                [
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-1.0..1.0),
                ],
                [
                    rng.random_range(3.5..5.5),
                    rng.random_range(1.6..2.2),
                    rng.random_range(1.4..2.0),
                ],
                rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
            )
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    // Dense case: 200 boxes in a 60 × 60 m area overlap often enough that clipping runs.
    let (a, b) = (boxes(200, 1), boxes(200, 2));
    c.bench_function("iou_matrix_3d_200x200", |bench| {
        bench.iter(|| black_box(iou_matrix(black_box(&a), black_box(&b), IouKind::ThreeD)))
    });
    // Worst case: all pairs overlap (every pair is clipped).
    let mut near = boxes(200, 3);
    for (k, bx) in near.iter_mut().enumerate() {
        bx.center = [0.01 * k as f64, 0.0, 0.0];
    }
    c.bench_function("iou_matrix_3d_200x200_all_overlapping", |bench| {
        bench.iter(|| black_box(iou_matrix(black_box(&near), black_box(&near), IouKind::ThreeD)))
    });

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ds = mlod::dataset::Dataset::open(root.join("sample_data")).expect("sample_data");
    let opts = EvalOptions::default();
    let tokens = eval::sample_tokens(&ds, &opts);
    let known: HashSet<&str> = tokens.iter().map(String::as_str).collect();
    let raw =
        eval::read_predictions(&root.join("tests/fixtures/devkit_expected/eval_sample_data/pred_all.json"))
            .expect("fixture");
    let preds = eval::parse_predictions(&raw, &known);
    c.bench_function("eval_sample_data_whole", |bench| {
        bench.iter(|| black_box(eval::evaluate(&ds, &preds, &opts).expect("eval")))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
