//! Warm starts: a model initialised from another model's weights file (`train stage1 --init`),
//! including a single-branch model into every Feature Fusion branch and a model trained before
//! the in-voxel x/y means.

use std::path::Path;

use candle_core::Tensor;

use crate::detect::model::Stage1Model;
use crate::detect::weights::read_weights;
use crate::detect::DetectError;

/// Copies weights from another model file into `model`: same names, or `middle.*` of a
/// single-branch model into each `middle_<lidar>.*` branch of Feature Fusion. A model trained
/// without the in-voxel x/y means has a narrower first layer: its weights fill the channels it
/// has and the new ones start at zero, so the warm-started model computes what it computed.
pub fn warm_start(model: &Stage1Model, path: &Path) -> Result<(), DetectError> {
    let w = read_weights(path, None)?;
    let varmap = model
        .varmap
        .as_ref()
        .ok_or_else(|| DetectError::BadParameter("model is not trainable".into()))?;
    let data = varmap
        .data()
        .lock()
        .map_err(|_| DetectError::BadParameter("variable map lock poisoned".into()))?;
    for (name, var) in data.iter() {
        let single = name
            .strip_prefix("middle_")
            .and_then(|rest| rest.split_once('.'))
            .map(|(_, tail)| format!("middle.{tail}"));
        let src = w
            .tensors
            .get(name)
            .or_else(|| single.as_ref().and_then(|n| w.tensors.get(n)))
            .ok_or_else(|| DetectError::Weights {
                path: path.to_path_buf(),
                what: format!("no tensor for {name}"),
            })?;
        let (s, v) = (src.dims(), var.dims());
        if s == v {
            var.set(src)?;
        } else if name.ends_with("conv1.conv.weight")
            && name.starts_with("middle")
            && s.len() == 4
            && v.len() == 4
            && s[0] == v[0]
            && s[1] < v[1]
            && s[2..] == v[2..]
        {
            // The init model's FLN has fewer input channels (trained before the in-voxel x/y
            // means): those it has keep their weights, the new ones start at zero, so the warm
            // start begins exactly where the init model was.
            let zeros = Tensor::zeros((v[0], v[1] - s[1], v[2], v[3]), src.dtype(), src.device())?;
            var.set(&Tensor::cat(&[src, &zeros], 1)?)?;
        } else {
            return Err(DetectError::Weights {
                path: path.to_path_buf(),
                what: format!("{name} has shape {s:?}, expected {v:?}"),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::dataset::Dataset;
    use crate::detect::{Case, ModelConfig};
    use crate::pipeline::{fuse, FuseParams};

    #[test]
    fn warm_start_from_a_model_without_xy_means_starts_where_it_was() {
        let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let token = ds.first_sample_token().unwrap().to_string();
        let cloud = fuse(&ds.frame(&token).unwrap(), &FuseParams::default()).unwrap();
        let mut old_cfg = ModelConfig::new(Case::Top);
        old_cfg.grid.xy_means = false;
        let old = Stage1Model::new_trainable(old_cfg, 5).unwrap();
        let dir = std::env::temp_dir().join(format!("mlod-warm-xy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("old.safetensors");
        std::fs::write(
            &path,
            old.to_safetensors(BTreeMap::new(), BTreeMap::new()).unwrap(),
        )
        .unwrap();
        let new = Stage1Model::new_trainable(ModelConfig::new(Case::Top), 9).unwrap();
        assert!(new.config.grid.xy_means);
        warm_start(&new, &path).unwrap();
        let heads = |m: &Stage1Model| -> Vec<f32> {
            m.forward(&m.voxelize(&cloud), false)
                .unwrap()
                .cls
                .to_vec1()
                .unwrap()
        };
        let (a, b) = (heads(&old), heads(&new));
        assert_eq!(a.len(), b.len());
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "class logits differ by {worst}");
        // Any other shape mismatch is still an error naming the tensor.
        let mut other = ModelConfig::new(Case::Top);
        other.net.mid_channels += 8;
        let wrong = Stage1Model::new_trainable(other, 1).unwrap();
        let e = warm_start(&wrong, &path).unwrap_err().to_string();
        assert!(e.contains("old.safetensors") && e.contains("has shape"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
