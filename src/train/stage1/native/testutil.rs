//! Helpers of the native trainers' tests (stage 1's and the refiner's): the gradients of a candle
//! graph by variable name (error measures: `crate::nn::testutil`).

use std::collections::HashMap;

use candle_core::{DType, Tensor};
use candle_nn::VarMap;

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
