//! One training step of each trained network, the network part only (forward, loss, backward,
//! AdamW with clipping), data prepared outside the timed loop (issue 28):
//! - `stage1/native` and `stage1/slow_autograd`: the shipped LiDAR-Top stage-1 network (33 input
//!   channels, 256×256 grid, 32 768 anchors) on a sample_data frame, on the native trainer
//!   (`src/train/stage1/native/`, the default of `mlod train stage1`) and on candle's autograd
//!   (`--slow-autograd`);
//! - `refiner/native` and `refiner/candle`: the stage-2 PointNet (default configuration) on 32
//!   proposals × 1024 seeded random points (the trainer's batch), on the native trainer
//!   (`src/train/refiner_native.rs`, the default of `mlod train refiner`) and on candle's autograd
//!   (`--slow-autograd`).
use candle_core::{Device, Tensor};
use criterion::{criterion_group, criterion_main, Criterion};
use mlod::dataset::Dataset;
use mlod::detect::{Case, ModelConfig, Stage1Model};
use mlod::train::stage1::native::NativeTrainer;
use mlod::train::stage1::{compute_loss, prepare_sample, AdamW};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn bench_stage1(c: &mut Criterion) {
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).expect("sample_data");
    let token = ds.first_sample_token().expect("a sample").to_string();
    let frame = ds.frame(&token).expect("frame");
    let mut g = c.benchmark_group("train_step_stage1");
    g.sample_size(10);
    {
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 1).expect("model");
        let sample = prepare_sample(&model, &frame, None, &[]).expect("sample");
        let opt = AdamW::new(&model, 0.01).expect("optimiser");
        let mut native = NativeTrainer::new(&model, &opt).expect("trainer");
        g.bench_function("native", |b| {
            b.iter(|| native.step(&sample, 1.0, 1e-4, 10.0).expect("step"))
        });
    }
    {
        let model = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 1).expect("model");
        let sample = prepare_sample(&model, &frame, None, &[]).expect("sample");
        let mut opt = AdamW::new(&model, 0.01).expect("optimiser");
        g.bench_function("slow_autograd", |b| {
            b.iter(|| {
                let l = compute_loss(&model, &sample).expect("loss");
                let grads = l.total.backward().expect("backward");
                opt.update(&grads, 1e-4, 10.0).expect("update")
            })
        });
    }
    g.finish();
}

fn bench_refiner(c: &mut Criterion) {
    use mlod::refine::net::{RefinerConfig, RefinerNet, PROPOSAL_FEATURES};
    use mlod::train::refiner_loss::{loss, Target};
    let cfg = RefinerConfig::default();
    let (b, n, ch) = (32usize, cfg.gather.points, cfg.gather.features.channels());
    let (net, varmap) = RefinerNet::trainable(&cfg, 1).expect("network");
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut rand = |k: usize| (0..k).map(|_| rng.random_range(-1f32..1.0)).collect::<Vec<f32>>();
    let points = Tensor::from_vec(rand(b * n * ch), (b * n, ch), &Device::Cpu).expect("points");
    let props =
        Tensor::from_vec(rand(b * PROPOSAL_FEATURES), (b, PROPOSAL_FEATURES), &Device::Cpu).expect("props");
    let targets: Vec<Target> = (0..b)
        .map(|i| {
            if i % 4 == 0 {
                Target::Positive {
                    residuals: [0.1, -0.1, 0.05, 0.02, -0.03, 0.01, 0.1, 0.99],
                    iou: 0.7,
                }
            } else {
                Target::Negative { iou: 0.1 }
            }
        })
        .collect();
    let max_trace = vec![0.01f32; b];
    let mut opt = AdamW::for_varmap(&varmap, 0.01).expect("optimiser");
    let mut g = c.benchmark_group("train_step_refiner");
    g.sample_size(10);
    {
        let (_, vm) = RefinerNet::trainable(&cfg, 1).expect("network");
        let nopt = AdamW::for_varmap(&vm, 0.01).expect("optimiser");
        let mut native = mlod::train::refiner_native::NativeRefiner::new(&cfg, &vm, &nopt).expect("trainer");
        let pts: Vec<f32> = points.flatten_all().expect("points").to_vec1().expect("points");
        let prs: Vec<f32> = props.flatten_all().expect("props").to_vec1().expect("props");
        g.bench_function("native", |bch| {
            bch.iter(|| {
                native
                    .step(&pts, &prs, &targets, &max_trace, 1e-4, 10.0)
                    .expect("step")
            })
        });
    }
    g.bench_function("candle", |bch| {
        bch.iter(|| {
            let out = net.forward_t(&points, b, n, &props, true).expect("forward");
            let l = loss(&out, &targets, &max_trace).expect("loss");
            let grads = l.total.backward().expect("backward");
            opt.update(&grads, 1e-4, 10.0).expect("update")
        })
    });
    g.finish();
}

criterion_group!(benches, bench_stage1, bench_refiner);
criterion_main!(benches);
