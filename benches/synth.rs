//! Simulator benchmarks (issue 3: "one sample in about a second or less"): ray-cast one key frame
//! of the three LiDARs (3 × 40 × 1800 = 216 000 rays, town generated once in the setup), and
//! generate a complete one-sample dataset (town, rays, 3 `.bin` files, 13 tables, map raster)
//! into a temporary folder that is removed at the end.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mlod::synth::{generate, scan_sample, SynthConfig, Town};

fn bench_synth(c: &mut Criterion) {
    let cfg = SynthConfig {
        seed: 1,
        samples_per_scene: 1,
        ..SynthConfig::default()
    };
    let town = Town::generate(&cfg);
    let scene = &town.scenes[0];
    let rays = (3 * cfg.lidar.elevations_deg.len() * cfg.lidar.azimuth_steps) as u64;

    let mut group = c.benchmark_group("synth");
    group.sample_size(10);
    group.throughput(Throughput::Elements(rays));
    group.bench_function("scan_sample_3_lidars", |b| {
        b.iter(|| black_box(scan_sample(&town, scene, 0, &cfg.lidar, cfg.seed)))
    });

    let dir: PathBuf = std::env::temp_dir().join(format!("mlod-synth-bench-{}", std::process::id()));
    group.bench_function("generate_1_sample_dataset", |b| {
        b.iter(|| black_box(generate(&cfg, &dir, |_, _| {}).map(|s| s.points)))
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench_synth);
criterion_main!(benches);
