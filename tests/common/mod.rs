//! Helpers shared by the integration tests: the repository's paths, fresh scratch folders and a
//! second models folder made from the shipped one. Each test binary that uses them says
//! `mod common;`; not every binary uses every helper.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The repository root.
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shipped models folder.
pub fn assets_models() -> PathBuf {
    root().join("assets/models")
}

/// The committed sample dataset.
pub fn sample_data() -> PathBuf {
    root().join("sample_data")
}

/// A fresh, empty folder under the temp dir, unique to this process and `tag`.
pub fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlod-test-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display()));
    d
}

/// A copy of the shipped models folder (every weights file and the manifest) whose manifest lacks
/// the top-level `keys` (e.g. `ground_gate`, `vote`): a second folder whose detectors differ
/// from the shipped ones in a known way.
pub fn shipped_without(tag: &str, keys: &[&str]) -> PathBuf {
    let dir = scratch(tag).join("models");
    copy_shipped_models(&dir, keys);
    dir
}

/// Copies the shipped models folder (every weights file and the manifest, without its top-level
/// `keys`) into `dir`.
pub fn copy_shipped_models(dir: &Path, keys: &[&str]) {
    std::fs::create_dir_all(dir).unwrap();
    for e in std::fs::read_dir(assets_models()).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "safetensors") {
            std::fs::copy(&p, dir.join(p.file_name().unwrap())).unwrap();
        }
    }
    let text = std::fs::read_to_string(assets_models().join("manifest.json")).unwrap();
    if keys.is_empty() {
        std::fs::write(dir.join("manifest.json"), text).unwrap();
        return;
    }
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    for k in keys {
        assert!(
            m.as_object_mut().unwrap().remove(*k).is_some(),
            "the shipped manifest has no {k}"
        );
    }
    std::fs::write(
        dir.join("manifest.json"),
        serde_json::to_string_pretty(&m).unwrap(),
    )
    .unwrap();
}
