//! AdamW with decoupled weight decay and global gradient-norm clipping, whose moments can be
//! checkpointed and restored (the stage-1 trainer's, shared with any other candle model).

use candle_core::{Tensor, Var};
use candle_nn::VarMap;

use crate::detect::model::Stage1Model;
use crate::detect::DetectError;

/// AdamW (decoupled weight decay) whose moments can be saved and restored.
#[derive(Debug)]
pub struct AdamW {
    pub params: Vec<(String, Var)>,
    pub m: Vec<Tensor>,
    pub v: Vec<Tensor>,
    pub step: u64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub weight_decay: f64,
}

impl AdamW {
    /// The optimiser of a stage-1 model's trainable variables.
    pub fn new(model: &Stage1Model, weight_decay: f64) -> Result<Self, DetectError> {
        let varmap = model
            .varmap
            .as_ref()
            .ok_or_else(|| DetectError::BadParameter("model is not trainable".into()))?;
        Self::for_varmap(varmap, weight_decay)
    }

    /// The optimiser of every variable of `varmap` except BatchNorm's running statistics (any
    /// name containing "running"), in name order.
    pub fn for_varmap(varmap: &VarMap, weight_decay: f64) -> Result<Self, DetectError> {
        let data = varmap
            .data()
            .lock()
            .map_err(|_| DetectError::BadParameter("variable map lock poisoned".into()))?;
        let mut params: Vec<(String, Var)> = data
            .iter()
            .filter(|(k, _)| !k.contains("running"))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let zeros = |p: &Var| p.as_tensor().zeros_like();
        let m = params
            .iter()
            .map(|(_, p)| zeros(p))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let v = params
            .iter()
            .map(|(_, p)| zeros(p))
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self {
            params,
            m,
            v,
            step: 0,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay,
        })
    }

    /// One update with learning rate `lr`; gradients are scaled so their global norm is at most
    /// `clip`. Returns the gradient norm before clipping.
    pub fn update(
        &mut self,
        grads: &candle_core::backprop::GradStore,
        lr: f64,
        clip: f64,
    ) -> Result<f64, DetectError> {
        let mut sq = 0f64;
        for (_, p) in &self.params {
            if let Some(g) = grads.get(p.as_tensor()) {
                sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
            }
        }
        let norm = sq.sqrt();
        let scale = if norm.is_finite() && norm > clip {
            clip / norm
        } else {
            1.0
        };
        if !norm.is_finite() {
            return Err(DetectError::BadParameter(format!("gradient norm is {norm}")));
        }
        self.step += 1;
        let t = self.step as i32;
        let bc1 = 1.0 - self.beta1.powi(t);
        let bc2 = 1.0 - self.beta2.powi(t);
        for (k, (_, p)) in self.params.iter().enumerate() {
            let Some(g) = grads.get(p.as_tensor()) else {
                continue;
            };
            // Detached: the moments must not keep this step's graph alive into the next step.
            let g = g.detach().affine(scale, 0.0)?;
            let m = ((&self.m[k] * self.beta1)? + (&g * (1.0 - self.beta1))?)?;
            let v = ((&self.v[k] * self.beta2)? + (g.sqr()? * (1.0 - self.beta2))?)?;
            let upd = ((&m / bc1)? / ((&v / bc2)?.sqrt()? + self.eps)?)?;
            let next = ((p.as_tensor() * (1.0 - lr * self.weight_decay))? - (upd * lr)?)?;
            p.set(&next.detach())?;
            self.m[k] = m.detach();
            self.v[k] = v.detach();
        }
        Ok(norm)
    }
}

impl AdamW {
    /// The moments as checkpoint tensors (`optim.m.<name>`, `optim.v.<name>`).
    pub fn state_tensors(&self) -> std::collections::BTreeMap<String, Tensor> {
        let mut out = std::collections::BTreeMap::new();
        for (k, (name, _)) in self.params.iter().enumerate() {
            out.insert(format!("optim.m.{name}"), self.m[k].clone());
            out.insert(format!("optim.v.{name}"), self.v[k].clone());
        }
        out
    }

    /// Restores the moments saved by [`Self::state_tensors`] and the step count; the name of the
    /// first missing tensor on failure.
    pub fn restore(&mut self, get: impl Fn(&str) -> Option<Tensor>, step: u64) -> Result<(), String> {
        for (k, (name, _)) in self.params.iter().enumerate() {
            for (moments, key) in [(&mut self.m, "m"), (&mut self.v, "v")] {
                let n = format!("optim.{key}.{name}");
                moments[k] = get(&n).ok_or_else(|| format!("tensor {n} missing"))?;
            }
        }
        self.step = step;
        Ok(())
    }
}
