//! `mlod sweep --shard auto` under a faked Slurm job array and Kubernetes Indexed Job
//! (docs/cluster.md): each task runs its shard, and the merge equals the unsharded sweep.

use std::process::Command;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");

/// `mlod sweep` of one shard into `out` under the scheduler variables `env` (and no others).
fn sweep_output(out: &std::path::Path, shard: &str, env: &[(&str, String)]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mlod"))
        .args([
            "sweep",
            "--dataset",
            DATA,
            "--samples",
            "1",
            "--trials",
            "2",
            "--alphas",
            "0.1",
        ])
        .args(["--cases", "top,input", "--shard", shard, "--out"])
        .arg(out)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX")
        .envs(env.iter().map(|(k, v)| (k, v)))
        .output()
        .expect("run mlod")
}

/// [`sweep_output`], which must succeed: its stderr.
fn sweep(out: &std::path::Path, shard: &str, env: &[(&str, String)]) -> String {
    let o = sweep_output(out, shard, env);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{shard} {env:?}: {err}");
    err
}

fn merge(out: &std::path::Path, shards: &[std::path::PathBuf]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_mlod"))
        .args(["sweep", "merge", "--out"])
        .arg(out)
        .args(shards)
        .output()
        .expect("run mlod");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read_to_string(out.join("results.csv")).unwrap()
}

#[test]
fn sweep_shard_auto_under_slurm_and_kubernetes() {
    let dir = std::env::temp_dir().join(format!("mlod-cluster-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let whole = dir.join("whole");
    sweep(&whole, "0/1", &[]);
    let want = std::fs::read_to_string(whole.join("results.csv")).unwrap();
    // sbatch --array=4-5: tasks 4 and 5, of 2.
    let slurm: Vec<_> = (4..6).map(|id| dir.join(format!("slurm-{id}"))).collect();
    for (id, out) in (4..6).zip(&slurm) {
        let env = [
            ("SLURM_ARRAY_TASK_ID", id.to_string()),
            ("SLURM_ARRAY_TASK_MIN", "4".into()),
            ("SLURM_ARRAY_TASK_MAX", "5".into()),
            ("SLURM_ARRAY_TASK_COUNT", "2".into()),
        ];
        let err = sweep(out, "auto", &env);
        assert!(err.contains(&format!("shard {}/2", id - 4)), "{err}");
    }
    assert_eq!(merge(&dir.join("slurm-all"), &slurm), want);
    // An Indexed Job with completions: 2.
    let k8s: Vec<_> = (0..2).map(|i| dir.join(format!("k8s-{i}"))).collect();
    for (i, out) in k8s.iter().enumerate() {
        let err = sweep(out, "auto/2", &[("JOB_COMPLETION_INDEX", i.to_string())]);
        assert!(err.contains("Indexed Job"), "{err}");
    }
    assert_eq!(merge(&dir.join("k8s-all"), &k8s), want);
    // Without a scheduler, or without the count of an Indexed Job: a clear error.
    for (shard, env) in [
        ("auto", vec![]),
        ("auto", vec![("JOB_COMPLETION_INDEX", "0".to_string())]),
    ] {
        let o = sweep_output(&dir.join("never"), shard, &env);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--shard"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
