//! The refiner folded for inference: every BatchNorm folded into the Linear before it, each layer
//! one `gemm` over a proposal's points (the kernels candle itself uses), the max-pool computed with
//! its arg-max (the active points of §V-C), proposals in parallel with rayon. It computes what
//! [`super::net::RefinerNet`] computes in evaluation mode, to float rounding (tested).

use candle_core::Tensor;

use super::coding::RESIDUALS;
use super::net::{RefinerConfig, PROPOSAL_FEATURES};
use super::RefineError;
use crate::nn::gemm::gemm_rm;

/// BatchNorm's ε in candle-nn's default configuration.
const BN_EPS: f32 = 1e-5;

/// y = x·W + b with W stored `cin × cout` row-major (the transpose of candle's Linear weight).
#[derive(Debug, Clone)]
struct Dense {
    w: Vec<f32>,
    b: Vec<f32>,
    cin: usize,
    cout: usize,
}

impl Dense {
    fn load(get: &dyn Fn(&str) -> Option<Tensor>, name: &str, bn: Option<&str>) -> Result<Self, RefineError> {
        let t = |n: String| -> Result<Vec<f32>, RefineError> {
            let v = get(&n).ok_or_else(|| RefineError::Weights(format!("tensor {n} missing")))?;
            Ok(v.flatten_all()?.to_vec1::<f32>()?)
        };
        let wt = get(&format!("{name}.weight"))
            .ok_or_else(|| RefineError::Weights(format!("tensor {name}.weight missing")))?;
        let dims = wt.dims().to_vec();
        let [cout, cin] = dims[..] else {
            return Err(RefineError::Weights(format!(
                "{name}.weight has shape {dims:?}, not (out, in)"
            )));
        };
        let w0 = wt.flatten_all()?.to_vec1::<f32>()?;
        let mut b = t(format!("{name}.bias"))?;
        if b.len() != cout {
            return Err(RefineError::Weights(format!(
                "{name}.bias has {} values, not {cout}",
                b.len()
            )));
        }
        let mut scale = vec![1.0f32; cout];
        if let Some(bn) = bn {
            let (g, beta, mean, var) = (
                t(format!("{bn}.weight"))?,
                t(format!("{bn}.bias"))?,
                t(format!("{bn}.running_mean"))?,
                t(format!("{bn}.running_var"))?,
            );
            if [g.len(), beta.len(), mean.len(), var.len()]
                .iter()
                .any(|&n| n != cout)
            {
                return Err(RefineError::Weights(format!(
                    "{bn}: BatchNorm of another width than {cout}"
                )));
            }
            for j in 0..cout {
                scale[j] = g[j] / (var[j] + BN_EPS).sqrt();
                b[j] = (b[j] - mean[j]) * scale[j] + beta[j];
            }
        }
        let mut w = vec![0.0f32; cin * cout];
        for j in 0..cout {
            for i in 0..cin {
                w[i * cout + j] = w0[j * cin + i] * scale[j];
            }
        }
        Ok(Self { w, b, cin, cout })
    }

    /// `rows × cin` → `rows × cout`, with the bias and optionally ReLU.
    fn apply(&self, x: &[f32], rows: usize, relu: bool) -> Result<Vec<f32>, RefineError> {
        let mut y = Vec::with_capacity(rows * self.cout);
        for _ in 0..rows {
            y.extend_from_slice(&self.b);
        }
        if !gemm_rm(
            rows, self.cout, self.cin, x, self.cin, &self.w, self.cout, &mut y, self.cout, true,
        ) {
            return Err(RefineError::Shape(format!(
                "{} values for {rows} rows of {}",
                x.len(),
                self.cin
            )));
        }
        if relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        Ok(y)
    }
}

/// What the network says of one proposal.
#[derive(Debug, Clone, PartialEq)]
pub struct RefinerRun {
    pub logit: f32,
    pub residuals: [f32; RESIDUALS],
    /// Per global-feature channel, the row (sampled point) that won its max.
    pub argmax: Vec<u32>,
}

/// The folded refiner.
#[derive(Debug, Clone)]
pub struct FastRefiner {
    point: Vec<Dense>,
    prop: Dense,
    head: Vec<Dense>,
    cls: Dense,
    reg: Dense,
    channels: usize,
}

impl FastRefiner {
    /// Folds the weights `get` returns (the names of [`super::net::RefinerNet`]).
    pub fn build(cfg: &RefinerConfig, get: &dyn Fn(&str) -> Option<Tensor>) -> Result<Self, RefineError> {
        let point = (0..cfg.point_mlp.len())
            .map(|k| Dense::load(get, &format!("point.{k}.lin"), Some(&format!("point.{k}.bn"))))
            .collect::<Result<Vec<_>, _>>()?;
        let prop = Dense::load(get, "prop", None)?;
        let head = (0..cfg.head.len())
            .map(|k| Dense::load(get, &format!("head.{k}"), None))
            .collect::<Result<Vec<_>, _>>()?;
        let channels = cfg.gather.features.channels();
        let s = Self {
            point,
            prop,
            head,
            cls: Dense::load(get, "cls", None)?,
            reg: Dense::load(get, "reg", None)?,
            channels,
        };
        // The widths must chain.
        let width = s.point.last().map_or(channels, |l| l.cout);
        let mut c = channels;
        for l in &s.point {
            if l.cin != c {
                return Err(RefineError::Weights(format!(
                    "point layer of input {} after width {c}",
                    l.cin
                )));
            }
            c = l.cout;
        }
        let mut c = width + s.prop.cout;
        if s.prop.cin != PROPOSAL_FEATURES {
            return Err(RefineError::Weights(format!(
                "prop takes {} inputs, not {PROPOSAL_FEATURES}",
                s.prop.cin
            )));
        }
        for l in &s.head {
            if l.cin != c {
                return Err(RefineError::Weights(format!(
                    "head layer of input {} after width {c}",
                    l.cin
                )));
            }
            c = l.cout;
        }
        if s.cls.cin != c || s.reg.cin != c {
            return Err(RefineError::Weights(format!(
                "heads take {} / {} inputs, not {c}",
                s.cls.cin, s.reg.cin
            )));
        }
        if s.cls.cout != 1 || s.reg.cout != RESIDUALS {
            return Err(RefineError::Weights("heads of the wrong width".into()));
        }
        Ok(s)
    }

    /// One proposal: `rows` holds `n × channels` values.
    pub fn run(
        &self,
        rows: &[f32],
        n: usize,
        props: &[f32; PROPOSAL_FEATURES],
    ) -> Result<RefinerRun, RefineError> {
        if rows.len() != n * self.channels || n == 0 {
            return Err(RefineError::Shape(format!(
                "{} values for {n} points of {} channels",
                rows.len(),
                self.channels
            )));
        }
        let mut x = rows.to_vec();
        for l in &self.point {
            x = l.apply(&x, n, true)?;
        }
        let width = self.point.last().map_or(self.channels, |l| l.cout);
        let mut global = vec![f32::NEG_INFINITY; width];
        let mut argmax = vec![0u32; width];
        for (r, row) in x.chunks_exact(width).enumerate() {
            for (j, &v) in row.iter().enumerate() {
                if v > global[j] {
                    global[j] = v;
                    argmax[j] = r as u32;
                }
            }
        }
        let p = self.prop.apply(props, 1, true)?;
        let mut h = global;
        h.extend(p);
        for l in &self.head {
            h = l.apply(&h, 1, true)?;
        }
        let logit = self.cls.apply(&h, 1, false)?[0];
        let reg = self.reg.apply(&h, 1, false)?;
        let mut residuals = [0.0f32; RESIDUALS];
        residuals.copy_from_slice(&reg);
        Ok(RefinerRun {
            logit,
            residuals,
            argmax,
        })
    }
}
