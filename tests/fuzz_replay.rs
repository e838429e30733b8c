//! Replays the fuzz corpus (`fuzz/corpus/<target>/`) and every input a fuzzer once crashed on
//! (`fuzz/regressions/<target>/`) through the same harness the libFuzzer targets run
//! (`fuzz/harness.rs`), so CI checks them without a nightly toolchain. Fuzzing itself:
//! docs/hardening.md.

use std::path::Path;

#[path = "../fuzz/harness.rs"]
mod harness;

/// Every file of the target's corpus and regressions, through `run`; returns how many.
fn replay(target: &str, run: fn(&[u8])) -> usize {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let mut n = 0;
    for dir in ["corpus", "regressions"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir).join(target)) else {
            continue;
        };
        let mut files: Vec<_> = entries.filter_map(|e| e.ok()).map(|e| e.path()).collect();
        files.sort();
        for f in files {
            let bytes = std::fs::read(&f).expect("corpus file");
            let r = std::panic::catch_unwind(|| run(&bytes));
            assert!(r.is_ok(), "{target}: {} panics", f.display());
            n += 1;
        }
    }
    n
}

macro_rules! replay_test {
    ($($name:ident),* $(,)?) => {$(
        #[test]
        fn $name() {
            let n = replay(stringify!($name), harness::$name);
            assert!(n > 0, "no corpus for {}", stringify!($name));
        }
    )*};
}

replay_test!(
    lyft_tables,
    point_cloud,
    session,
    manifest,
    weights,
    predictions,
    sweep_folder,
    kitti,
    av2
);
