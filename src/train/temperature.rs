//! Result Fusion's temperature calibration (eq. 11): each single-LiDAR generator's logits are
//! rescaled by a temperature T fitted on the validation scenes (Guo et al., temperature scaling),
//! so that the three generators' scores are comparable before the 3D-IoU merge.

use std::collections::BTreeMap;
use std::path::Path;

use crate::dataset::{train_validation_split as split, Dataset};
use crate::detect::model::Stage1Model;
use crate::detect::weights::Manifest;
use crate::detect::{Case, DetectError};
use crate::geometry::{iou_3d, Box3d};
use crate::pipeline::{fuse, FuseParams};

/// Fits the temperature T of sigmoid(logit / T) minimising the NLL of TP (1) / FP (0) labels, by
/// golden-section search on ln T ∈ [−4, 4] (the NLL is unimodal in T for these data).
pub fn fit_temperature(logits: &[f32], labels: &[bool]) -> f64 {
    let nll = |t: f64| -> f64 {
        logits
            .iter()
            .zip(labels)
            .map(|(&z, &y)| {
                let x = z as f64 / t;
                // −ln σ(x) = softplus(−x), −ln(1 − σ(x)) = softplus(x).
                let sp = |v: f64| v.max(0.0) + (-v.abs()).exp().ln_1p();
                if y {
                    sp(-x)
                } else {
                    sp(x)
                }
            })
            .sum()
    };
    if logits.is_empty() {
        return 1.0;
    }
    let (mut a, mut b) = (-4f64, 4f64);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (nll(c.exp()), nll(d.exp()));
    for _ in 0..80 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = nll(c.exp());
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = nll(d.exp());
        }
    }
    (0.5 * (a + b)).exp()
}

/// TP / FP labels of detections against ground-truth boxes of their class: greedy by score, a
/// detection is a TP when its 3D IoU with a not yet matched box is at least `iou`.
pub fn label_detections(dets: &[(crate::detect::Detection, f32)], gts: &[Box3d], iou: f64) -> Vec<bool> {
    let mut used = vec![false; gts.len()];
    let mut order: Vec<usize> = (0..dets.len()).collect();
    order.sort_by(|&a, &b| dets[b].0.score.total_cmp(&dets[a].0.score).then(a.cmp(&b)));
    let mut out = vec![false; dets.len()];
    for i in order {
        let mut best: Option<(usize, f64)> = None;
        for (j, g) in gts.iter().enumerate() {
            if used[j] {
                continue;
            }
            let v = iou_3d(&dets[i].0.box3d, g);
            if v >= iou && best.is_none_or(|(_, b)| v > b) {
                best = Some((j, v));
            }
        }
        if let Some((j, _)) = best {
            used[j] = true;
            out[i] = true;
        }
    }
    out
}

/// Fits Result Fusion's temperature for each single-LiDAR generator on the validation split of
/// `dataset` (at most `max_samples` samples) and writes them into the models folder's manifest.
pub fn calibrate_temperatures(
    dataset_dir: &Path,
    models_dir: &Path,
    max_samples: usize,
    iou: f64,
    command: &str,
    mut on_sample: impl FnMut(Case, usize, usize),
) -> Result<BTreeMap<Case, f64>, DetectError> {
    let dataset = Dataset::open(dataset_dir)?;
    let (_, mut val) = split(&dataset);
    if max_samples > 0 {
        val.truncate(max_samples);
    }
    let mut manifest = Manifest::load(models_dir)?;
    let mut temps = BTreeMap::new();
    for case in [Case::Top, Case::Left, Case::Right] {
        let model = Stage1Model::load_shipped(models_dir, case)?;
        let (mut logits, mut labels) = (Vec::new(), Vec::new());
        for (k, token) in val.iter().enumerate() {
            let frame = dataset.frame(token)?;
            let cloud = fuse(&frame, &FuseParams::default())?;
            if case.channel().is_some_and(|ch| frame.lidar(ch).is_none()) {
                continue;
            }
            let dets = model.detect_cloud_logits(&cloud)?;
            let gts: Vec<Box3d> = frame
                .boxes
                .iter()
                .filter(|b| b.category == model.config.anchor.category)
                .map(|b| b.box3d)
                .collect();
            labels.extend(label_detections(&dets, &gts, iou));
            logits.extend(dets.iter().map(|d| d.1));
            on_sample(case, k + 1, val.len());
        }
        temps.insert(case, fit_temperature(&logits, &labels));
    }
    manifest.temperatures = temps.clone();
    manifest.temperature_command = command.to_string();
    manifest.save(models_dir)?;
    Ok(temps)
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn temperature_fit_recovers_a_known_temperature() {
        // Labels drawn as Bernoulli(σ(z / 3)) ⇒ the fitted T is near 3.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut z, mut y) = (Vec::new(), Vec::new());
        for _ in 0..20000 {
            let l: f32 = rng.random_range(-12.0..12.0);
            let p = 1.0 / (1.0 + (-(l as f64) / 3.0).exp());
            z.push(l);
            y.push(rng.random::<f64>() < p);
        }
        let t = fit_temperature(&z, &y);
        assert!((t - 3.0).abs() < 0.2, "{t}");
    }
}
