//! A native trainer's tensors as flat buffers (shared by stage 1's [`crate::train::stage1::native::NativeTrainer`] and
//! the refiner's [`crate::train::refiner_native::NativeRefiner`]): read from, and written back to, a
//! candle [`VarMap`] and its [`AdamW`], and AdamW itself over the buffers — the update of
//! [`AdamW::update`], so checkpoints and weight files are the same on either path.

use std::collections::HashMap;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;

use crate::detect::DetectError;
use crate::nn::layers::Param;
use crate::train::optim::AdamW;

fn tensor_values(t: &Tensor) -> candle_core::Result<(Vec<usize>, Vec<f32>)> {
    Ok((t.dims().to_vec(), t.flatten_all()?.to_vec1::<f32>()?))
}

fn poisoned() -> DetectError {
    DetectError::BadParameter("variable map lock poisoned".into())
}

/// The trainable tensors of `opt`, in its order (name order), without gradients yet.
pub(crate) fn params_of(opt: &AdamW) -> Result<Vec<Param>, DetectError> {
    let mut params = Vec::with_capacity(opt.params.len());
    for (name, var) in &opt.params {
        let (shape, value) = tensor_values(var.as_tensor())?;
        params.push(Param {
            name: name.clone(),
            shape,
            grad: vec![0.0; value.len()],
            value,
            has_grad: false,
        });
    }
    Ok(params)
}

/// BatchNorm's running statistics of `varmap` (names containing "running"), in name order.
pub(crate) fn stats_of(varmap: &VarMap) -> Result<Vec<Param>, DetectError> {
    let data = varmap.data().lock().map_err(|_| poisoned())?;
    let mut names: Vec<&String> = data.keys().filter(|k| k.contains("running")).collect();
    names.sort();
    let mut stats = Vec::new();
    for name in names {
        if let Some(var) = data.get(name) {
            let (shape, value) = tensor_values(var.as_tensor())?;
            stats.push(Param {
                name: name.clone(),
                shape,
                value,
                grad: Vec::new(),
                has_grad: false,
            });
        }
    }
    Ok(stats)
}

/// The index of a trainer's tensors by name: where each layer finds its weights.
pub(crate) struct TensorIndex<'a> {
    params: HashMap<&'a str, usize>,
    stats: HashMap<&'a str, usize>,
    all: &'a [Param],
}

impl<'a> TensorIndex<'a> {
    /// Indexes trainable tensors `params` and running statistics `stats`.
    pub fn new(params: &'a [Param], stats: &'a [Param]) -> Self {
        let index = |ps: &'a [Param]| ps.iter().enumerate().map(|(i, p)| (p.name.as_str(), i)).collect();
        Self {
            params: index(params),
            stats: index(stats),
            all: params,
        }
    }

    /// The position of trainable tensor `name`.
    pub fn param(&self, name: &str) -> Result<usize, DetectError> {
        self.params
            .get(name)
            .copied()
            .ok_or_else(|| DetectError::BadParameter(format!("native trainer: no tensor {name}")))
    }

    /// The position of running statistic `name`.
    pub fn stat(&self, name: &str) -> Result<usize, DetectError> {
        self.stats
            .get(name)
            .copied()
            .ok_or_else(|| DetectError::BadParameter(format!("native trainer: no tensor {name}")))
    }

    /// The shape of trainable tensor `name`.
    pub fn shape(&self, name: &str) -> Result<&'a [usize], DetectError> {
        let all = self.all;
        Ok(&all[self.param(name)?].shape)
    }

    /// γ, β, running mean, running var of the BatchNorm under `prefix`.
    pub fn bn(&self, prefix: &str) -> Result<[usize; 4], DetectError> {
        Ok([
            self.param(&format!("{prefix}.bn.weight"))?,
            self.param(&format!("{prefix}.bn.bias"))?,
            self.stat(&format!("{prefix}.bn.running_mean"))?,
            self.stat(&format!("{prefix}.bn.running_var"))?,
        ])
    }
}

/// Writes running statistics back into `varmap`'s variables.
pub(crate) fn store_stats(varmap: &VarMap, stats: &[Param]) -> Result<(), DetectError> {
    let data = varmap.data().lock().map_err(|_| poisoned())?;
    for s in stats {
        if let Some(var) = data.get(&s.name) {
            var.set(&Tensor::from_slice(&s.value, s.shape.as_slice(), &Device::Cpu)?)?;
        }
    }
    Ok(())
}

/// AdamW's state over flat buffers, one moment pair per trainable tensor.
#[derive(Debug, Clone)]
pub(crate) struct FlatAdamW {
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
    pub step: u64,
    beta1: f64,
    beta2: f64,
    eps: f64,
    weight_decay: f64,
}

impl FlatAdamW {
    /// The state of `opt` (its moments and step count).
    pub fn of(opt: &AdamW) -> Result<Self, DetectError> {
        let moments = |ts: &[Tensor]| -> candle_core::Result<Vec<Vec<f32>>> {
            ts.iter().map(|t| t.flatten_all()?.to_vec1::<f32>()).collect()
        };
        Ok(Self {
            m: moments(&opt.m)?,
            v: moments(&opt.v)?,
            step: opt.step,
            beta1: opt.beta1,
            beta2: opt.beta2,
            eps: opt.eps,
            weight_decay: opt.weight_decay,
        })
    }

    /// AdamW over the tensors the last step reached (`has_grad`), as [`AdamW::update`] computes
    /// it, the gradients scaled to a global norm of at most `clip`; the norm before clipping.
    pub fn update(&mut self, params: &mut [Param], lr: f64, clip: f64) -> Result<f64, DetectError> {
        if params.len() != self.m.len() || params.len() != self.v.len() {
            return Err(DetectError::BadParameter(
                "the optimiser's moments do not fit the tensors".into(),
            ));
        }
        let sq: f64 = params
            .iter()
            .filter(|p| p.has_grad)
            .map(|p| p.grad.iter().map(|&g| (g as f64) * (g as f64)).sum::<f64>())
            .sum();
        let norm = sq.sqrt();
        if !norm.is_finite() {
            return Err(DetectError::BadParameter(format!("gradient norm is {norm}")));
        }
        let scale = if norm > clip { (clip / norm) as f32 } else { 1.0 };
        self.step += 1;
        let t = self.step as i32;
        let (b1, b2) = (self.beta1 as f32, self.beta2 as f32);
        let (c1, c2) = ((1.0 - self.beta1) as f32, (1.0 - self.beta2) as f32);
        let inv_bc1 = (1.0 / (1.0 - self.beta1.powi(t))) as f32;
        let inv_bc2 = (1.0 / (1.0 - self.beta2.powi(t))) as f32;
        let (eps, decay, lr32) = (self.eps as f32, (1.0 - lr * self.weight_decay) as f32, lr as f32);
        for ((p, m), v) in params.iter_mut().zip(&mut self.m).zip(&mut self.v) {
            if !p.has_grad {
                continue;
            }
            for (((w, &g), m), v) in p
                .value
                .iter_mut()
                .zip(&p.grad)
                .zip(m.iter_mut())
                .zip(v.iter_mut())
            {
                let g = g * scale;
                *m = *m * b1 + g * c1;
                *v = *v * b2 + g * g * c2;
                let upd = (*m * inv_bc1) / ((*v * inv_bc2).sqrt() + eps);
                *w = *w * decay - upd * lr32;
            }
        }
        Ok(norm)
    }

    /// Writes `params`' values into `opt`'s variables and this state's moments and step count
    /// into `opt`.
    pub fn store(&self, params: &[Param], opt: &mut AdamW) -> Result<(), DetectError> {
        let dev = Device::Cpu;
        if opt.params.len() != params.len() || self.m.len() != params.len() {
            return Err(DetectError::BadParameter(
                "the optimiser does not fit the trainer".into(),
            ));
        }
        for (k, (p, (_, var))) in params.iter().zip(&opt.params).enumerate() {
            var.set(&Tensor::from_slice(&p.value, p.shape.as_slice(), &dev)?)?;
            opt.m[k] = Tensor::from_slice(&self.m[k], p.shape.as_slice(), &dev)?;
            opt.v[k] = Tensor::from_slice(&self.v[k], p.shape.as_slice(), &dev)?;
        }
        opt.step = self.step;
        Ok(())
    }
}

/// The gradient of tensor `name` among `params` from the last step, if the step reached it.
pub fn gradient_of<'a>(params: &'a [Param], name: &str) -> Option<&'a [f32]> {
    params
        .iter()
        .find(|p| p.name == name && p.has_grad)
        .map(|p| p.grad.as_slice())
}

/// Tensor `name`'s current value among `params` and the running statistics `stats`.
pub fn value_of<'a>(params: &'a [Param], stats: &'a [Param], name: &str) -> Option<&'a [f32]> {
    params
        .iter()
        .chain(stats)
        .find(|p| p.name == name)
        .map(|p| p.value.as_slice())
}
