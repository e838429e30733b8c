//! Detector cost on this CPU: stage-1 inference per sample for each case — fuse, voxelise,
//! network, decoding and NMS — on a sample_data frame (target ≤ 150 ms on 2 cores), and one
//! training step (data, forward, backward, AdamW) of Input Fusion; the network alone, candle's
//! graph against the folded inference network; and stage 2 (issue 17): refining 50 proposals of
//! the frame — index, gather, sample, network, decode — (target ≤ 30 ms), and whole MLOD-I and
//! MLOD-U runs (issue 32's proposal union; target ≤ 150 ms). Uses the shipped weights when
//! `assets/models/manifest.json` lists them, else seeded random weights (same cost, but random
//! weights give few boxes, so decoding/NMS is cheaper than with trained ones).
use criterion::{criterion_group, criterion_main, Criterion};
use mlod::dataset::Dataset;
use mlod::detect::model::load_detector;
use mlod::detect::weights::default_models_dir;
use mlod::detect::{Case, Detector, ModelConfig, Stage1Model};
use mlod::pipeline::{fuse, FuseParams};
use mlod::train::stage1::{compute_loss, prepare_sample, AdamW};
use std::hint::black_box;

fn detector(case: Case) -> Box<dyn Detector> {
    load_detector(&default_models_dir(), case).expect("the shipped models")
}

fn bench(c: &mut Criterion) {
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).expect("sample_data");
    let token = ds.first_sample_token().expect("a sample").to_string();
    let frame = ds.frame(&token).expect("frame");
    let params = FuseParams::default();
    let mut g = c.benchmark_group("detect");
    g.sample_size(10);
    for case in Case::ALL {
        let d = detector(case);
        g.bench_function(case.as_str(), |b| {
            b.iter(|| black_box(d.detect(&frame, &params).expect("detect")))
        });
    }
    g.finish();
    // The network alone on one BEV: candle's graph (what training runs) against the folded
    // inference network (what detection runs).
    let mut g = c.benchmark_group("network");
    g.sample_size(10);
    let top = Stage1Model::load_shipped(&default_models_dir(), Case::Top).expect("the shipped LiDAR-Top");
    let cloud = fuse(&frame, &params).expect("fuse");
    let bevs = top.voxelize(&cloud);
    let folded = top.fast_net().expect("folded network");
    g.bench_function("top_candle", |b| {
        b.iter(|| black_box(top.forward(&bevs, false).expect("forward")))
    });
    g.bench_function("top_folded", |b| {
        b.iter(|| black_box(folded.forward(&bevs).expect("forward")))
    });
    g.finish();
    let mut g = c.benchmark_group("train_step");
    g.sample_size(10);
    let model = Stage1Model::new_trainable(ModelConfig::new(Case::Input), 1).expect("model");
    let mut opt = AdamW::new(&model, 0.01).expect("optimiser");
    g.bench_function("input", |b| {
        b.iter(|| {
            let s = prepare_sample(&model, &frame, None, &[]).expect("sample");
            let l = compute_loss(&model, &s).expect("loss");
            let grads = l.total.backward().expect("backward");
            opt.update(&grads, 1e-4, 10.0).expect("update")
        })
    });
    g.finish();
}

fn bench_refine(c: &mut Criterion) {
    use mlod::refine::net::{RefinerConfig, RefinerNet};
    use mlod::refine::{Decoding, Refiner};
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).expect("sample_data");
    let token = ds.first_sample_token().expect("a sample").to_string();
    let frame = ds.frame(&token).expect("frame");
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(0.04, 0).expect("perturbation"),
        ..Default::default()
    };
    let cloud = fuse(&frame, &params).expect("fuse");
    let refiner = Refiner::load_shipped(&default_models_dir()).unwrap_or_else(|_| {
        let cfg = RefinerConfig::default();
        let (_, varmap) = RefinerNet::trainable(&cfg, 1).expect("network");
        let tensors = mlod::detect::weights::varmap_tensors(&varmap).expect("tensors");
        Refiner::from_tensors(cfg, &|n| tensors.get(n).cloned(), Decoding::default()).expect("refiner")
    });
    // 50 proposals: Input Fusion's, topped up with shifted copies when it gives fewer.
    let mut proposals = detector(Case::Input).detect(&frame, &params).expect("detect");
    let base = proposals.clone();
    let mut k = 0;
    while proposals.len() < 50 && !base.is_empty() {
        let mut p = base[k % base.len()].clone();
        p.box3d.center[0] += 0.3 * (1 + k / base.len()) as f64;
        proposals.push(p);
        k += 1;
    }
    proposals.truncate(50);
    let mut g = c.benchmark_group("refine");
    g.sample_size(20);
    g.bench_function("50_proposals", |b| {
        b.iter(|| black_box(refiner.refine(&cloud, &proposals).expect("refine")))
    });
    // MLOD-I and the two cases beyond the paper: the proposal union mlod-u (two stage-1
    // networks, the refiner on both proposal lists, NMS and voting after it) and mlod-ir-drop
    // (Result and Input Fusion on the certain points, four networks, their proposals refined
    // together): whole runs, fuse included.
    for case in [Case::MlodI, Case::MlodU, Case::MlodIrDrop] {
        let m = mlod::cases::load_mlod(&default_models_dir(), case, Default::default())
            .expect("the shipped models");
        g.bench_function(case.as_str(), |b| {
            b.iter(|| black_box(m.run(&frame, &params).expect("run")))
        });
    }
    g.finish();
}

/// The protocol's cost per frame on mlod's side with an external detector that answers at once
/// (`tests/fixtures/detectors/fake.py instant`, python3): 150k points written, the request sent,
/// the answer read.
fn bench_external(c: &mut Criterion) {
    use mlod::dataset::LidarChannel;
    use mlod::pipeline::{FusedCloud, FusedLidar};
    const N: usize = 150_000;
    let lidar = |channel, range| FusedLidar {
        channel,
        range,
        nominal: mlod::geometry::Pose::identity(),
        noise: mlod::uncertainty::ExtrinsicNoise::ZERO,
        applied: mlod::geometry::Pose::identity(),
        calibrated: false,
    };
    let f = |k: usize| {
        (0..N)
            .map(|i| ((i * k) % 1000) as f32 * 0.01)
            .collect::<Vec<f32>>()
    };
    let cloud = FusedCloud {
        x: f(7),
        y: f(11),
        z: f(13),
        intensity: f(17),
        source: (0..N).map(|i| (i % 3) as u8).collect(),
        trace: f(19),
        lidars: vec![
            lidar(LidarChannel::Top, 0..N / 3),
            lidar(LidarChannel::FrontLeft, N / 3..2 * N / 3),
            lidar(LidarChannel::FrontRight, 2 * N / 3..N),
        ],
    };
    let spec = mlod::external::ExternalSpec::new(
        "instant",
        vec![
            "python3".into(),
            concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/detectors/fake.py").into(),
            "instant".into(),
        ],
    )
    .expect("spec");
    let det = mlod::external::ExternalDetector::new(spec);
    det.detect_cloud("warm", &cloud)
        .expect("the fake detector answers");
    let mut g = c.benchmark_group("external_protocol");
    g.sample_size(20);
    let mut i = 0u64;
    g.bench_function("150k_points", |b| {
        b.iter(|| {
            i += 1;
            det.detect_cloud(&format!("s{i}"), &cloud).expect("answer")
        })
    });
    g.finish();
}

criterion_group!(benches, bench, bench_refine, bench_external);
criterion_main!(benches);
