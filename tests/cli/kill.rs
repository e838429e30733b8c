//! Kill -9 tests (issue 21): the `mlod` binary, or this test binary in a writer mode, is killed
//! with SIGKILL at seeded pseudo-random points while it writes a synthetic dataset, a training
//! checkpoint, sweep units, an eval `--out` and a session. Afterwards every file the program
//! names is absent, the old one or the complete new one (a killed writer may leave its hidden
//! `.NAME.tmp-PID`, never a half-written NAME), and a resumed job ends bit-identical to an
//! uninterrupted one.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const MLOD: &str = env!("CARGO_BIN_EXE_mlod");

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh folder under the temp dir.
fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlod-kill-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch");
    d
}

fn run<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Duration {
    let t = Instant::now();
    let out = Command::new(MLOD).args(args).output().expect("run mlod");
    let shown: Vec<_> = args.iter().map(|a| a.as_ref().to_string_lossy()).collect();
    assert!(
        out.status.success(),
        "mlod {shown:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    t.elapsed()
}

/// Owned arguments (the kill loop re-spawns the same command many times).
fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

/// Starts `cmd`, SIGKILLs it after `after` (if it is still running); true if it was killed.
fn kill_after(mut cmd: Command, after: Duration) -> bool {
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    let t = Instant::now();
    while t.elapsed() < after {
        if child.try_wait().expect("wait").is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().expect("SIGKILL");
    child.wait().expect("reap");
    true
}

/// Runs `mlod args` `n` times, each killed at one of `kill_points(total, n, seed)`, and calls
/// `check` after each; at least one run must have been killed.
fn kill_repeatedly(args: &[String], total: Duration, n: usize, seed: u64, check: impl Fn()) {
    let mut killed = 0;
    for at in kill_points(total, n, seed) {
        let mut cmd = Command::new(MLOD);
        cmd.args(args);
        killed += usize::from(kill_after(cmd, at));
        check();
    }
    assert!(
        killed > 0,
        "no run was killed (the machine is too fast for these kill points)"
    );
}

/// `n` kill points spread over `total`, each jittered by a seeded LCG (printed, so a failure can
/// be replayed).
fn kill_points(total: Duration, n: usize, seed: u64) -> Vec<Duration> {
    let mut s = seed;
    (0..n)
        .map(|i| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let jitter = ((s >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 0.1;
            let f = ((i as f64 + 0.5) / n as f64 + jitter).clamp(0.02, 0.98);
            total.mul_f64(f)
        })
        .inspect(|d| eprintln!("kill point: {d:?}"))
        .collect()
}

/// Every file under `dir` (relative path → bytes), hidden temp files of killed writers aside.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if p.is_dir() {
                walk(base, &p, out);
            } else if is_writer_temp(&name) {
                continue;
            } else {
                let rel = p.strip_prefix(base).expect("inside").to_path_buf();
                out.insert(rel, std::fs::read(&p).expect("read"));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// `.NAME.tmp-PID`, what `mlod::io::write_atomic` writes before its rename.
fn is_writer_temp(name: &str) -> bool {
    name.starts_with('.')
        && name
            .rsplit_once(".tmp-")
            .is_some_and(|(_, pid)| pid.parse::<u32>().is_ok())
}

/// Every file of `got` is byte-identical to the same file of `want` (a killed run wrote some of
/// them); names `what` on failure.
fn assert_prefix_of(got: &BTreeMap<PathBuf, Vec<u8>>, want: &BTreeMap<PathBuf, Vec<u8>>, what: &str) {
    for (p, bytes) in got {
        let w = want
            .get(p)
            .unwrap_or_else(|| panic!("{what}: unexpected file {}", p.display()));
        assert!(w == bytes, "{what}: {} is not the complete file", p.display());
    }
}

#[test]
fn a_killed_synth_leaves_only_complete_files_and_a_rerun_equals_an_uninterrupted_one() {
    let d = scratch("synth");
    let args = |out: &Path| {
        let out = out.to_str().expect("utf-8");
        strings(&[
            "synth",
            "--out",
            out,
            "--scenes",
            "1",
            "--samples-per-scene",
            "6",
            "--seed",
            "5",
        ])
    };
    let a = d.join("a");
    let total = run(&args(&a));
    let want = files(&a);
    let b = d.join("b");
    kill_repeatedly(&args(&b), total, 6, 21, || {
        assert_prefix_of(&files(&b), &want, "killed synth");
    });
    run(&args(&b));
    assert!(
        files(&b) == want,
        "a rerun after kills differs from an uninterrupted run"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_killed_training_resumes_bit_identical() {
    let d = scratch("train");
    let data = d.join("data");
    run(&[
        "synth",
        "--out",
        data.to_str().expect("utf-8"),
        "--scenes",
        "1",
        "--samples-per-scene",
        "3",
        "--seed",
        "4",
    ]);
    let args = |out: &Path, resume: bool| {
        let mut v = strings(&[
            "train",
            "stage1",
            "--case",
            "top",
            "--dataset",
            data.to_str().expect("utf-8"),
            "--out",
            out.join("top.safetensors").to_str().expect("utf-8"),
            "--steps",
            "5",
            "--seed",
            "2",
            "--checkpoint-every",
            "1",
        ]);
        if resume {
            v.push("--resume".into());
        }
        v
    };
    let a = d.join("a");
    let total = run(&args(&a, false));
    let want = std::fs::read(a.join("top.safetensors")).expect("weights");
    let b = d.join("b");
    kill_repeatedly(&args(&b, true), total, 4, 33, || {
        // The checkpoint, if there is one yet, is a complete safetensors file.
        let ck = b.join("top.ckpt.safetensors");
        if ck.exists() {
            mlod::detect::weights::read_weights(&ck, None).expect("a complete checkpoint");
        }
        if let Ok(w) = std::fs::read(b.join("top.safetensors")) {
            assert!(w == want, "final weights written by a killed run differ");
        }
    });
    run(&args(&b, true));
    let got = std::fs::read(b.join("top.safetensors")).expect("weights");
    assert!(got == want, "resumed training differs from an uninterrupted one");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_killed_sweep_resumes_to_the_same_results_and_an_eval_out_is_old_or_new() {
    let d = scratch("sweep");
    let sample = root().join("sample_data");
    let args = |out: &Path| {
        strings(&[
            "sweep",
            "--dataset",
            sample.to_str().expect("utf-8"),
            "--cases",
            "top,input",
            "--alphas",
            "0,0.1",
            "--samples",
            "2",
            "--trials",
            "2",
            "--out",
            out.to_str().expect("utf-8"),
        ])
    };
    let a = d.join("a");
    let total = run(&args(&a));
    let want = files(&a);
    let b = d.join("b");
    kill_repeatedly(&args(&b), total, 4, 47, || {
        assert_prefix_of(&files(&b), &want, "killed sweep");
    });
    run(&args(&b));
    assert!(
        files(&b) == want,
        "a resumed sweep differs from an uninterrupted one"
    );

    // eval --out over an existing report: killed at any point, the file is the old report or
    // the complete new one.
    let out = d.join("report.json");
    let eval = |limit: &str| {
        strings(&[
            "eval",
            "--dataset",
            sample.to_str().expect("utf-8"),
            "--case",
            "top",
            "--samples",
            limit,
            "--out",
            out.to_str().expect("utf-8"),
        ])
    };
    run(&eval("1"));
    let old = std::fs::read(&out).expect("old report");
    let total = run(&eval("2"));
    let new = std::fs::read(&out).expect("new report");
    assert!(old != new);
    let mut killed = 0;
    for at in kill_points(total, 8, 59) {
        std::fs::write(&out, &old).expect("restore the old report");
        let mut cmd = Command::new(MLOD);
        cmd.args(eval("2"));
        killed += usize::from(kill_after(cmd, at));
        let now = std::fs::read(&out).expect("a report");
        assert!(now == old || now == new, "eval --out left a torn report");
    }
    assert!(killed > 0, "no eval was killed");
    let _ = std::fs::remove_dir_all(&d);
}

/// Writer mode: saves two different sessions in turn, forever (the test below kills it).
#[test]
fn session_writer_child() {
    let Ok(path) = std::env::var("MLOD_KILL_SESSION") else {
        return;
    };
    let (a, b) = two_sessions();
    for i in 0.. {
        let s = if i % 2 == 0 { &a } else { &b };
        s.save(Path::new(&path)).expect("save");
    }
}

fn two_sessions() -> (mlod::session::Session, mlod::session::Session) {
    let a = mlod::session::Session::new(root().join("sample_data"));
    let mut b = a.clone();
    b.fuse.perturbation.alpha = 0.04;
    b.sample_token = Some("x".repeat(5000));
    (a, b)
}

#[test]
fn a_session_save_killed_mid_write_leaves_one_of_the_two_sessions() {
    let d = scratch("session");
    let path = d.join("s.session.json");
    let (a, b) = two_sessions();
    let exe = std::env::current_exe().expect("this test binary");
    for at in kill_points(Duration::from_millis(400), 20, 71) {
        let mut cmd = Command::new(&exe);
        cmd.args([
            "--exact",
            "kill::session_writer_child",
            "--nocapture",
            "--test-threads",
            "1",
        ])
        .env("MLOD_KILL_SESSION", &path);
        assert!(kill_after(cmd, at), "the writer stopped by itself");
        if path.exists() {
            let s = mlod::session::Session::load(&path).expect("a complete session file");
            assert!(s == a || s == b);
        }
    }
    assert!(path.exists(), "the writer never wrote a session");
    let _ = std::fs::remove_dir_all(&d);
}
