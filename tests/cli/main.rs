//! The CLI contract of the foundation issue: names and JSON shapes later checks rely on, and
//! bad input that must fail cleanly (non-zero exit, a message, never a panic).

use std::process::Command;

mod av2;
mod chain;
mod cluster;
#[path = "../common/mod.rs"]
mod common;
mod external;
mod transfer;

fn mlod(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mlod"))
        .args(args)
        .output()
        .expect("run mlod")
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = mlod(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

fn matrix(v: &serde_json::Value) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| v[i][j].as_f64().unwrap()))
}

/// A fresh `$TMP/mlod-cli-TAG-PID` holding `data/`, ten one-sample scenes made by `mlod synth`
/// (the tenth is the validation split), and `models/`, a copy of the shipped models (manifest and
/// weights): what the validation-tuning commands work on. Returns (dir, data, models).
fn tuning_fixture(tag: &str) -> (std::path::PathBuf, String, String) {
    let dir = std::env::temp_dir().join(format!("mlod-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (data, models) = (dir.join("data"), dir.join("models"));
    std::fs::create_dir_all(&models).expect("tmp");
    let (d, m) = (
        data.to_str().expect("utf-8").to_string(),
        models.to_str().expect("utf-8").to_string(),
    );
    let synth = mlod(&[
        "synth",
        "--out",
        &d,
        "--scenes",
        "10",
        "--samples-per-scene",
        "1",
        "--seed",
        "7",
    ]);
    assert!(
        synth.status.success(),
        "{}",
        String::from_utf8_lossy(&synth.stderr)
    );
    common::copy_shipped_models(&models, &[]);
    (dir, d, m)
}

/// `mlod sweep` arguments with the given cases, α list and trials.
fn sweep<'a>(
    sample: &'a str,
    cases: &'a str,
    alphas: &'a str,
    trials: &'a str,
    out: &'a str,
) -> Vec<&'a str> {
    vec![
        "sweep",
        "--dataset",
        sample,
        "--cases",
        cases,
        "--alphas",
        alphas,
        "--trials",
        trials,
        "--out",
        out,
    ]
}

/// A folder for one test's files, removed on drop.
struct Scratch(std::path::PathBuf);

impl Scratch {
    fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("mlod-cli-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch");
        Self(d)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// sample_data's tables as JSON values, by table name.
fn sample_tables() -> std::collections::BTreeMap<String, serde_json::Value> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data/v1.01-train");
    mlod::dataset::tables::TABLE_NAMES
        .iter()
        .map(|t| {
            let bytes = std::fs::read(dir.join(format!("{t}.json"))).expect("table");
            (t.to_string(), serde_json::from_slice(&bytes).expect("JSON"))
        })
        .collect()
}

fn write_tables(root: &std::path::Path, tables: &std::collections::BTreeMap<String, serde_json::Value>) {
    let v = root.join("v1.01-train");
    std::fs::create_dir_all(&v).expect("version folder");
    for (t, rows) in tables {
        std::fs::write(
            v.join(format!("{t}.json")),
            serde_json::to_vec(rows).expect("JSON"),
        )
        .expect("table");
    }
}
mod kill;

mod evaluation;
mod inputs;
mod robustness;
mod training;
