//! `sample_data/` is exactly what the command printed in `mlod synth --help` writes: `mlod synth
//! --out sample_data --seed 0 --roof-sensors pandar40` (one scene of ten samples of the walled
//! world, the default and the world the shipped models were trained in, with Lyft's Pandar40 as
//! the only roof LiDAR).

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
fn sample_data_is_regenerated_byte_identically_by_the_command_in_the_help() {
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data");
    let fresh = std::env::temp_dir().join(format!("mlod-sample-data-{}", std::process::id()));
    let help = std::process::Command::new(env!("CARGO_BIN_EXE_mlod"))
        .args(["synth", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8(help.stdout).unwrap();
    let line = help
        .lines()
        .map(str::trim)
        .find(|l| l.starts_with("mlod synth --out sample_data "))
        .expect("the help prints the command that regenerates sample_data/");
    let args: Vec<String> = line
        .split_whitespace()
        .skip(2)
        .map(|a| match a {
            "sample_data" => fresh.to_string_lossy().into_owned(),
            a => a.to_string(),
        })
        .collect();
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mlod"))
        .arg("synth")
        .args(&args)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{line}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
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
