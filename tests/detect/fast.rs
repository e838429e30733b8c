//! The folded inference network (`detect::infer`) computes what candle's forward computes: on
//! seeded random weights and on the shipped weights, for single-branch and Feature Fusion models,
//! with and without absent LiDARs; and its result does not depend on the number of threads.

use mlod::dataset::Dataset;
use mlod::detect::infer::RawHeads;
use mlod::detect::weights::default_models_dir;
use mlod::detect::{Case, ModelConfig, Stage1Model};
use mlod::pipeline::{fuse, FuseParams, FusedCloud};

fn cloud() -> FusedCloud {
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
    let token = ds.first_sample_token().unwrap().to_string();
    fuse(&ds.frame(&token).unwrap(), &FuseParams::default()).unwrap()
}

/// Largest |a − b| relative to the largest |a| (1 if the lengths differ).
fn rel_diff(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() || a.is_empty() {
        return 1.0;
    }
    let scale = a.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max) / scale
}

fn assert_same_heads(m: &Stage1Model, cloud: &FusedCloud, drop_branches: &[usize]) {
    let mut bevs = m.voxelize(cloud);
    for &i in drop_branches {
        bevs[i] = None;
    }
    let candle = RawHeads::from_candle(&m.forward(&bevs, false).unwrap()).unwrap();
    let fast = m.fast_net().unwrap().forward(&bevs).unwrap();
    let case = m.config.case;
    for (name, a, b) in [
        ("cls", &candle.cls, &fast.cls),
        ("reg", &candle.reg, &fast.reg),
        ("dir", &candle.dir, &fast.dir),
    ] {
        let d = rel_diff(a, b);
        assert!(d < 1e-4, "{case} {name}: relative difference {d}");
    }
    // And the decoded boxes agree.
    let (da, db) = (m.decode(&candle, 1.0).unwrap(), m.decode(&fast, 1.0).unwrap());
    assert_eq!(da.len(), db.len(), "{case}");
    for ((a, _), (b, _)) in da.iter().zip(&db) {
        let d = (0..3)
            .map(|k| (a.box3d.center[k] - b.box3d.center[k]).abs())
            .fold((a.score - b.score).abs() as f64, f64::max);
        assert!(d < 1e-3, "{case}: {a:?} vs {b:?}");
    }
}

#[test]
fn folded_network_matches_candle_on_random_weights() {
    let cloud = cloud();
    for case in [Case::Top, Case::Feature] {
        let m = Stage1Model::new_trainable(ModelConfig::new(case), 4).unwrap();
        assert_same_heads(&m, &cloud, &[]);
    }
}

#[test]
fn folded_network_matches_candle_on_shipped_weights() {
    let cloud = cloud();
    let dir = default_models_dir();
    for case in [Case::Top, Case::Input, Case::Feature] {
        let m = Stage1Model::load_shipped(&dir, case).unwrap();
        assert!(m.fast.is_some(), "loaded models infer with the folded network");
        assert_same_heads(&m, &cloud, &[]);
        if case == Case::Feature {
            // Left and right absent: only the top branch feeds the RPN.
            assert_same_heads(&m, &cloud, &[1, 2]);
        }
    }
}

#[test]
fn folded_network_does_not_depend_on_the_thread_count() {
    let cloud = cloud();
    let m = Stage1Model::load_shipped(&default_models_dir(), Case::Feature).unwrap();
    let bevs = m.voxelize(&cloud);
    let many = m.heads(&bevs).unwrap();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let one = pool.install(|| m.heads(&bevs).unwrap());
    assert!(
        many == one,
        "bit-identical on 1 and on the default number of threads"
    );
    let pool3 = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
    assert!(pool3.install(|| m.heads(&bevs).unwrap()) == one);
}
