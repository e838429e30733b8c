//! The native refiner trainer against candle's autograd on the same network, batch and optimiser.

use std::collections::HashMap;

use candle_core::{DType, Device, Tensor, D};
use candle_nn::{VarBuilder, VarMap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::detect::net::{sigmoid_focal_loss, smooth_l1 as smooth_l1_t};
use crate::detect::weights::varmap_tensors;
use crate::nn::testutil::{diff, rel};
use crate::refine::net::RefinerNet;
use crate::train::checkpoint::restore_varmap;
use crate::train::refiner_loss::loss;
use crate::train::refiner_native::*;
use crate::train::stage1::native::testutil::{grads_by_name, values};

/// A batch as the trainer gets it.
struct TestBatch {
    points: Vec<f32>,
    props: Vec<f32>,
    targets: Vec<Target>,
    max_trace: Vec<f32>,
}

fn small() -> RefinerConfig {
    let mut cfg = RefinerConfig::default();
    cfg.gather.points = 48;
    cfg.point_mlp = vec![16, 24, 32];
    cfg.head = vec![32, 16];
    cfg.proposal_width = 8;
    cfg
}

/// `b` proposals of random points (a few rows repeated, as the point draw repeats rows when a
/// proposal has fewer points: ties at the max), every kind of target.
fn batch(cfg: &RefinerConfig, b: usize, seed: u64, positives: bool) -> TestBatch {
    let (n, ch) = (cfg.gather.points, cfg.gather.features.channels());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points: Vec<f32> = (0..b * n * ch).map(|_| rng.random_range(-1f32..1.0)).collect();
    for j in 0..b {
        for i in 0..4 {
            let (src, dst) = ((j * n + i) * ch, (j * n + n - 1 - i) * ch);
            points.copy_within(src..src + ch, dst);
        }
    }
    let props = (0..b * PROPOSAL_FEATURES)
        .map(|_| rng.random_range(-1f32..1.0))
        .collect();
    let targets = (0..b)
        .map(|i| match i % 3 {
            0 if positives => Target::Positive {
                residuals: std::array::from_fn(|_| rng.random_range(-0.3..0.3)),
                iou: 0.7,
            },
            1 => Target::Ignored { iou: 0.5 },
            _ => Target::Negative { iou: 0.1 },
        })
        .collect();
    let max_trace = (0..b).map(|_| rng.random_range(0f32..0.6)).collect();
    TestBatch {
        points,
        props,
        targets,
        max_trace,
    }
}

/// candle's graph and eq. 17 in f64 on `varmap`'s weights: the reference both f32 paths are
/// measured against. Returns (total, reg, cls, uct) and every gradient.
fn reference_f64(
    cfg: &RefinerConfig,
    varmap: &VarMap,
    t: &TestBatch,
) -> ([f64; 4], HashMap<String, Vec<f32>>) {
    let dev = Device::Cpu;
    let f64s = |t: Tensor| t.to_dtype(DType::F64).unwrap();
    let vm = VarMap::new();
    let net = RefinerNet::new(cfg, VarBuilder::from_varmap(&vm, DType::F64, &dev)).unwrap();
    let src = varmap.data().lock().unwrap();
    for (name, var) in vm.data().lock().unwrap().iter() {
        var.set(&f64s(src[name].as_tensor().clone())).unwrap();
    }
    let b = t.targets.len();
    let (n, ch) = (cfg.gather.points, cfg.gather.features.channels());
    let points = f64s(Tensor::from_slice(&t.points, (b * n, ch), &dev).unwrap());
    let props = f64s(Tensor::from_slice(&t.props, (b, PROPOSAL_FEATURES), &dev).unwrap());
    let out = net.forward_t(&points, b, n, &props, true).unwrap();
    let (mut cls_t, mut cls_w, mut pos_w, mut uct_w) =
        (vec![0f64; b], vec![0f64; b], vec![0f64; b], vec![0f64; b]);
    let mut reg_t = vec![0f64; b * RESIDUALS];
    let mut positives = 0;
    for (i, tg) in t.targets.iter().enumerate() {
        match tg {
            Target::Positive { residuals, .. } => {
                positives += 1;
                (cls_t[i], cls_w[i], pos_w[i]) = (1.0, 1.0, 1.0);
                uct_w[i] = uct_weight(t.max_trace[i]) as f64;
                for k in 0..RESIDUALS {
                    reg_t[i * RESIDUALS + k] = residuals[k] as f32 as f64;
                }
            }
            Target::Negative { .. } => cls_w[i] = 1.0,
            Target::Ignored { .. } => {}
        }
    }
    let norm = 1.0 / positives.max(1) as f64;
    let v = |x: Vec<f64>, s: &[usize]| Tensor::from_vec(x, s, &dev).unwrap();
    let cls = (sigmoid_focal_loss(&out.cls, &v(cls_t, &[b]), 0.25, 2.0).unwrap() * v(cls_w, &[b]))
        .unwrap()
        .sum_all()
        .unwrap()
        .affine(norm, 0.0)
        .unwrap();
    let reg = smooth_l1_t(&(&out.reg - v(reg_t, &[b, RESIDUALS])).unwrap(), 1.0 / 9.0)
        .unwrap()
        .broadcast_mul(&v(pos_w, &[b, 1]))
        .unwrap()
        .sum_all()
        .unwrap()
        .affine(norm, 0.0)
        .unwrap();
    let u = out.reg.narrow(D::Minus1, 0, RESIDUALS - 1).unwrap();
    let unorm = (u.sqr().unwrap().sum(D::Minus1).unwrap() + 1e-12)
        .unwrap()
        .sqrt()
        .unwrap();
    let uct = (unorm * v(uct_w, &[b]))
        .unwrap()
        .sum_all()
        .unwrap()
        .affine(norm, 0.0)
        .unwrap();
    let total = ((&reg + cls.affine(ETA, 0.0).unwrap()).unwrap() + uct.affine(LAMBDA, 0.0).unwrap()).unwrap();
    let terms = [&total, &reg, &cls, &uct].map(|t| t.to_scalar::<f64>().unwrap());
    let grads = total.backward().unwrap();
    (terms, grads_by_name(&vm, &grads))
}

/// candle's f32 path (the trainer's `--slow-autograd` step) on `varmap`: loss and gradients.
fn candle_f32(
    cfg: &RefinerConfig,
    net: &RefinerNet,
    varmap: &VarMap,
    t: &TestBatch,
) -> (f32, HashMap<String, Vec<f32>>) {
    let dev = Device::Cpu;
    let b = t.targets.len();
    let (n, ch) = (cfg.gather.points, cfg.gather.features.channels());
    let points = Tensor::from_slice(&t.points, (b * n, ch), &dev).unwrap();
    let props = Tensor::from_slice(&t.props, (b, PROPOSAL_FEATURES), &dev).unwrap();
    let out = net.forward_t(&points, b, n, &props, true).unwrap();
    let l = loss(&out, &t.targets, &t.max_trace).unwrap();
    let grads = l.total.backward().unwrap();
    let g = varmap
        .data()
        .lock()
        .unwrap()
        .iter()
        .filter_map(|(name, var)| Some((name.clone(), values(grads.get(var.as_tensor())?))))
        .collect();
    (l.total.to_scalar().unwrap(), g)
}

/// The worst relative error over every gradient of `got` against `want`. The point layers'
/// Linear biases feed a BatchNorm, which removes them: their exact gradient is 0 and what either
/// f32 path computes is rounding, so it is measured against the scale of the layer's weight
/// gradient instead of its own.
fn worst(got: &dyn Fn(&str) -> Option<Vec<f32>>, want: &HashMap<String, Vec<f32>>) -> (f32, String) {
    let mut worst = (0f32, String::new());
    for (name, e) in want {
        let g = got(name).unwrap_or_else(|| panic!("{name}: no gradient"));
        let r = if name.contains(".lin.bias") {
            let w = &want[&name.replace(".bias", ".weight")];
            diff(&g, e) / w.iter().fold(0f32, |m, v| m.max(v.abs()))
        } else {
            rel(&g, e)
        };
        if r > worst.0 {
            worst = (r, name.clone());
        }
    }
    worst
}

fn gradients_match(cfg: &RefinerConfig, b: usize, positives: bool) {
    let (net, varmap) = RefinerNet::trainable(cfg, 5).unwrap();
    let opt = AdamW::for_varmap(&varmap, 0.01).unwrap();
    let t = batch(cfg, b, 11, positives);
    let (exact, exact_grads) = reference_f64(cfg, &varmap, &t);
    let mut native = NativeRefiner::new(cfg, &varmap, &opt).unwrap();
    let terms = native
        .forward_backward(&t.points, &t.props, &t.targets, &t.max_trace)
        .unwrap();
    for (a, e, what) in [
        (terms.total, exact[0], "total"),
        (terms.reg, exact[1], "reg"),
        (terms.cls, exact[2], "cls"),
        (terms.uct, exact[3], "uct"),
    ] {
        assert!(
            (a as f64 - e).abs() <= 1e-5 * e.abs().max(1e-3),
            "{what}: {a} vs {e}"
        );
    }
    // Every tensor has a gradient in both, the regression head's too without positives.
    assert_eq!(exact_grads.len(), opt.params.len());
    let (_, candle_grads) = candle_f32(cfg, &net, &varmap, &t);
    let w = worst(&|n| native.gradient(n).map(<[f32]>::to_vec), &exact_grads);
    let wc = worst(&|n| candle_grads.get(n).cloned(), &exact_grads);
    eprintln!(
        "refiner b={b} n={} positives={positives}: worst relative gradient error against f64: native {w:?}, candle f32 {wc:?}",
        cfg.gather.points
    );
    assert!(w.0 < 1e-4, "worst gradient {w:?}");
    // The forward pass moved the running statistics as candle's did.
    for (name, var) in varmap.data().lock().unwrap().iter() {
        if name.contains("running") {
            let r = rel(native.value(name).unwrap(), &values(var.as_tensor()));
            assert!(r < 1e-4, "{name}: {r}");
        }
    }
}

#[test]
fn gradients_equal_the_f64_reference() {
    gradients_match(&small(), 9, true);
}

#[test]
fn gradients_equal_the_f64_reference_without_positives() {
    gradients_match(&small(), 5, false);
}

#[test]
fn gradients_equal_the_f64_reference_shipped_shape() {
    // The shipped configuration (1024 points, 32·64·128 point MLP, head 128·64) on 8 proposals.
    gradients_match(&RefinerConfig::default(), 8, true);
}

#[test]
fn training_follows_candle_and_stores_loadable_weights() {
    let cfg = small();
    let steps = 5;
    let (lr, clip) = (2e-3, 10.0);
    let batches: Vec<TestBatch> = (0..steps)
        .map(|s| batch(&cfg, 6 + s % 3, 20 + s as u64, s != 2))
        .collect();
    // Reference: candle's graph and AdamW.
    let (net, ref_vm) = RefinerNet::trainable(&cfg, 9).unwrap();
    let mut ref_opt = AdamW::for_varmap(&ref_vm, 0.01).unwrap();
    let mut ref_curve = Vec::new();
    for t in &batches {
        let b = t.targets.len();
        let dev = Device::Cpu;
        let points = Tensor::from_slice(
            &t.points,
            (b * cfg.gather.points, cfg.gather.features.channels()),
            &dev,
        )
        .unwrap();
        let props = Tensor::from_slice(&t.props, (b, PROPOSAL_FEATURES), &dev).unwrap();
        let out = net
            .forward_t(&points, b, cfg.gather.points, &props, true)
            .unwrap();
        let l = loss(&out, &t.targets, &t.max_trace).unwrap();
        ref_curve.push(l.total.to_scalar::<f32>().unwrap());
        ref_opt.update(&l.total.backward().unwrap(), lr, clip).unwrap();
    }
    // Native, twice from the same seed: candle's curve, and bit-identical runs.
    let mut runs = Vec::new();
    for _ in 0..2 {
        let (_, vm) = RefinerNet::trainable(&cfg, 9).unwrap();
        let mut opt = AdamW::for_varmap(&vm, 0.01).unwrap();
        let mut native = NativeRefiner::new(&cfg, &vm, &opt).unwrap();
        let curve: Vec<f32> = batches
            .iter()
            .map(|t| {
                native
                    .step(&t.points, &t.props, &t.targets, &t.max_trace, lr, clip)
                    .unwrap()
                    .loss
                    .total
            })
            .collect();
        native.store(&vm, &mut opt).unwrap();
        runs.push((curve, vm, opt, native));
    }
    let (curve, vm, opt, native) = &runs[0];
    for (n, r) in curve.iter().zip(&ref_curve) {
        assert!((n - r).abs() <= 1e-3 * r.abs(), "{curve:?} vs {ref_curve:?}");
    }
    assert_eq!(curve, &runs[1].0, "two native runs differ");
    let ref_values = varmap_tensors(&ref_vm).unwrap();
    for (name, t) in varmap_tensors(vm).unwrap() {
        let a = values(&t);
        assert_eq!(a, runs[1].3.value(&name).unwrap(), "{name}: runs differ");
        // Weights after the same steps as candle's, within float drift. Not the point layers'
        // Linear biases: BatchNorm removes them, their gradient is rounding noise that AdamW
        // normalises into steps of either sign, and they change nothing the network computes
        // (the running means, which carry them, differ by the same amount).
        if !(name.contains(".lin.bias") || name.contains("running_mean")) {
            let r = rel(&a, &values(&ref_values[&name]));
            assert!(r < 1e-2, "{name}: {r:e}");
        }
    }
    // What was stored is what a new trainer reads back (the checkpoint round trip, through a
    // fresh variable map as a resume restores it), and a candle network runs on it.
    let saved = varmap_tensors(vm).unwrap();
    let (fresh_net, fresh) = RefinerNet::trainable(&cfg, 1).unwrap();
    restore_varmap(&fresh, |n| saved.get(n).cloned()).unwrap();
    let mut fresh_opt = AdamW::for_varmap(&fresh, 0.01).unwrap();
    fresh_opt
        .restore(|n| opt.state_tensors().get(n).cloned(), opt.step)
        .unwrap();
    let again = NativeRefiner::new(&cfg, &fresh, &fresh_opt).unwrap();
    for p in native.params.iter().chain(&native.stats) {
        assert_eq!(again.value(&p.name).unwrap(), p.value.as_slice(), "{}", p.name);
    }
    assert_eq!(again.adam.step, native.adam.step);
    assert_eq!(again.adam.m, native.adam.m);
    assert_eq!(again.adam.v, native.adam.v);
    let t = &batches[0];
    let b = t.targets.len();
    let dev = Device::Cpu;
    let points = Tensor::from_slice(
        &t.points,
        (b * cfg.gather.points, cfg.gather.features.channels()),
        &dev,
    )
    .unwrap();
    let props = Tensor::from_slice(&t.props, (b, PROPOSAL_FEATURES), &dev).unwrap();
    let out = fresh_net
        .forward_t(&points, b, cfg.gather.points, &props, false)
        .unwrap();
    assert!(values(&out.reg).iter().all(|v| v.is_finite()));
}

#[test]
fn bad_batches_are_errors() {
    let cfg = small();
    let (_, vm) = RefinerNet::trainable(&cfg, 1).unwrap();
    let opt = AdamW::for_varmap(&vm, 0.01).unwrap();
    let mut native = NativeRefiner::new(&cfg, &vm, &opt).unwrap();
    let t = batch(&cfg, 3, 1, true);
    let e = native
        .forward_backward(&t.points[1..], &t.props, &t.targets, &t.max_trace)
        .unwrap_err();
    assert!(matches!(e, RefineError::Shape(_)), "{e}");
    let e = native.forward_backward(&[], &[], &[], &[]).unwrap_err();
    assert!(e.to_string().contains("empty"), "{e}");
    let mut other = cfg.clone();
    other.point_mlp = vec![16, 24, 64];
    let e = NativeRefiner::new(&other, &vm, &opt).unwrap_err();
    assert!(e.to_string().contains("point.2.lin"), "{e}");
}

#[test]
fn the_iou_quality_target_and_its_cross_entropy() {
    assert_eq!(iou_quality(0.1), 0.0);
    assert_eq!(iou_quality(0.25), 0.0);
    assert!((iou_quality(0.5) - 0.5).abs() < 1e-6);
    assert_eq!(iou_quality(0.8), 1.0);
    for &y in &[0.0f32, 0.3, 1.0] {
        for &x in &[-30.0f32, -2.0, -0.1, 0.0, 0.7, 3.0, 30.0] {
            let (l, g) = bce(x, y);
            let s = 1.0 / (1.0 + (-f64::from(x)).exp());
            let naive =
                -(f64::from(y) * s.max(1e-300).ln() + (1.0 - f64::from(y)) * (1.0 - s).max(1e-300).ln());
            assert!(
                l.is_finite() && (f64::from(l) - naive).abs() < 1e-4 * naive.max(1.0),
                "{x} {y}: {l} vs {naive}"
            );
            let h = 1e-2f32;
            let fd = (f64::from(bce(x + h, y).0) - f64::from(bce(x - h, y).0)) / (2.0 * f64::from(h));
            assert!((f64::from(g) - fd).abs() < 1e-3, "{x} {y}: {g} vs {fd}");
        }
    }
    // The loss is smallest where σ(x) equals the soft label.
    let at = |x: f32| bce(x, 0.3).0;
    let best = (0.3f32 / 0.7).ln();
    assert!(at(best) < at(best - 0.5) && at(best) < at(best + 0.5));
}
