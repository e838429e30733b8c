//! Helpers of the native trainers' tests (stage 1's and the refiner's): error measures and the
//! gradients of a candle graph by variable name.

use std::collections::HashMap;

use candle_core::{DType, Tensor};
use candle_nn::VarMap;

/// A deterministic pattern of `n` values in [−0.5, 0.5), different per `seed` (the kernels' tests).
pub(crate) fn data(n: usize, seed: usize) -> Vec<f32> {
    (0..n)
        .map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 1000.0 - 0.5)
        .collect()
}

/// max |a − b|.
pub(crate) fn diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()))
}

/// max |a − b| / max |b|.
pub(crate) fn rel(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    diff(a, b) / scale
}

/// ‖a − b‖₂ / ‖b‖₂: the whole tensor's error, which a few entries near 0 do not dominate.
pub(crate) fn rel_l2(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let d: f32 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let n: f32 = b.iter().map(|y| y * y).sum();
    d.sqrt() / n.sqrt().max(1e-12)
}

/// LiDAR-Top without intensity, as the shipped v4 models are trained (sample_data/ holds the
/// constant 100 of real Lyft files, which the v4 models do not read): the training-path tests'
/// model.
pub(crate) fn top_without_intensity() -> crate::detect::ModelConfig {
    let mut c = crate::detect::ModelConfig::new(crate::detect::Case::Top);
    c.grid.intensity = false;
    c
}

pub(crate) fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

/// The gradients `grads` holds for `vm`'s variables, by name, as f32.
pub(crate) fn grads_by_name(
    vm: &VarMap,
    grads: &candle_core::backprop::GradStore,
) -> HashMap<String, Vec<f32>> {
    vm.data()
        .lock()
        .unwrap()
        .iter()
        .filter_map(|(name, var)| {
            let g = grads.get(var.as_tensor())?;
            Some((name.clone(), values(&g.to_dtype(DType::F32).unwrap())))
        })
        .collect()
}
