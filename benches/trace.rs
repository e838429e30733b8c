//! tr(Ξ) (and the six entries of Ξ) for one three-LiDAR frame: 150 000 points.
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mlod::uncertainty::propagate::{covariance_cloud, trace_cloud, worked_example, TraceKernel};
use mlod::uncertainty::{Linearization, Prior};
use std::hint::black_box;

fn cloud(n: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    // A deterministic ring-like cloud out to ~60 m.
    let x = (0..n)
        .map(|i| ((i as f32) * 0.618).sin() * (5.0 + (i % 550) as f32 * 0.1))
        .collect();
    let y = (0..n)
        .map(|i| ((i as f32) * 0.618).cos() * (5.0 + (i % 550) as f32 * 0.1))
        .collect();
    let z = (0..n).map(|i| (i % 40) as f32 * 0.1 - 2.0).collect();
    (x, y, z)
}

fn bench(c: &mut Criterion) {
    let n = 150_000;
    let (x, y, z) = cloud(n);
    let (r, t, _) = worked_example();
    let k = TraceKernel::new(
        &r,
        &t,
        &Prior::paper().scaled(0.04).unwrap(),
        Linearization::Separate,
    );
    let mut g = c.benchmark_group("xi_150k");
    g.throughput(Throughput::Elements(n as u64));
    let mut out = vec![0.0f32; n];
    g.bench_function("trace", |b| {
        b.iter(|| trace_cloud(black_box(&k), &x, &y, &z, &mut out))
    });
    let mut out6 = vec![[0.0f32; 6]; n];
    g.bench_function("covariance6", |b| {
        b.iter(|| covariance_cloud(black_box(&k), &x, &y, &z, &mut out6))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
