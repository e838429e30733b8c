//! `sample_data/` is exactly what its documented command writes (the walled world of issue 29 the
//! shipped models were trained on): `mlod synth --out sample_data --scenes 1 --samples-per-scene
//! 10 --seed 0 --roof-sensors pandar40 --roof-height-jitter 0.2 --car-sizes mixed --intensity lyft
//! --glass see-through-no-ground --curb-walls 0.5`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn files(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.file_name().and_then(|n| n.to_str()) != Some("README.md") {
                out.insert(
                    p.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn sample_data_is_regenerated_byte_identically() {
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data");
    let fresh = std::env::temp_dir().join(format!("mlod-sample-data-{}", std::process::id()));
    let cfg = mlod::synth::SynthConfig {
        seed: 0,
        scenes: 1,
        samples_per_scene: 10,
        roof: mlod::synth::RoofRandomisation {
            presets: vec![mlod::synth::SensorPreset::Pandar40],
            height_jitter_m: 0.2,
        },
        car_sizes: mlod::synth::CarSizes::Mixed,
        lidar: mlod::synth::LidarModel {
            constant_intensity: Some(100.0),
            // `--glass see-through-no-ground`: 80 % of the beams pass a vehicle's side glass.
            glass_pass: 0.8,
            glass_ground: false,
            ..Default::default()
        },
        curb_walls: 0.5,
        ..Default::default()
    };
    mlod::synth::generate(&cfg, &fresh, |_, _| {}).unwrap();
    let a = files(&committed);
    let b = files(&fresh);
    let _ = std::fs::remove_dir_all(&fresh);
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "same file names"
    );
    for (name, bytes) in &a {
        assert!(
            bytes == &b[name],
            "{} differs from a fresh generation",
            name.display()
        );
    }
    let total: usize = a.values().map(|v| v.len()).sum();
    assert!(total < 30_000_000, "sample_data is {total} bytes (limit ~30 MB)");
}
