//! `mlod train chain`: the whole training chain of a models folder as one resumable command.
//!
//! The chain is a list of phases, each one `mlod` command as a user would type it (the data in a
//! named world, the five stage-1 cases, Result Fusion's temperatures, box voting, the ground
//! gate, the refiner's proposals, both refiners, the refiner's and the union cases' decoding,
//! the training data's statistics). Each phase runs as a child process of this binary, so what it
//! writes into the manifest records its own command, as a user would type it alone; the child dies
//! with the chain (Linux: `PR_SET_PDEATHSIG`), so a killed chain never leaves a phase writing
//! behind it. After each
//! phase `OUT/chain.json` is rewritten atomically with the phases and their wall times, so a run
//! killed part-way skips the finished phases when the same command is run again, and the
//! interrupted one continues from its checkpoint (stage 1, the refiners) or its shards
//! (proposals). The manifest gets the chain's command and per-phase wall times last.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use mlod::detect::weights::{ChainPhase, ChainRecord, Manifest};

use super::args::command_line;

#[derive(clap::Args)]
pub struct ChainArgs {
    /// The training data: a folder any reader opens (every 10th scene is the validation split).
    /// Without it, `--world` simulates it into OUT/data/train.
    #[arg(long, required_unless_present = "world")]
    dataset: Option<PathBuf>,
    /// The simulator world (`walled`, `v4`, `v2`): simulate the training data in it first
    /// (`mlod synth`), or, with `--dataset`, the world that data was made in (for the manifest).
    #[arg(long, value_parser = mlod::synth::World::parse)]
    world: Option<mlod::synth::World>,
    /// The models folder to write (weights, loss curves, checkpoints, logs, chain.json).
    #[arg(long)]
    out: PathBuf,
    /// With --world alone: scenes, samples per scene and seed of the simulated data.
    #[arg(long, default_value_t = 80)]
    scenes: usize,
    #[arg(long, default_value_t = 20)]
    samples_per_scene: usize,
    #[arg(long, default_value_t = 101)]
    data_seed: u64,
    /// Steps of each stage-1 case and its seed.
    #[arg(long, default_value_t = 10000)]
    steps: u64,
    #[arg(long, default_value_t = 5)]
    seed: u64,
    /// Steps of each refiner.
    #[arg(long, default_value_t = 12000)]
    refiner_steps: u64,
    /// Start every stage-1 case from this models folder's weights (warm start) instead of random
    /// ones.
    #[arg(long)]
    init: Option<PathBuf>,
    /// At most this many validation samples for the temperatures and the tuning phases.
    #[arg(long)]
    val_samples: Option<usize>,
    /// Training samples the proposal database is built from (0: all).
    #[arg(long, default_value_t = 0)]
    proposal_samples: usize,
    /// Samples of the training data's statistics.
    #[arg(long, default_value_t = 200)]
    stats_samples: u64,
}

/// One phase: its name, its command's words after `mlod`, and the checkpoint whose presence
/// makes a rerun add `--resume`.
struct Phase {
    name: String,
    words: Vec<String>,
    checkpoint: Option<PathBuf>,
    /// The folder a killed run leaves half written and the phase starts afresh (simulated data).
    scratch: Option<PathBuf>,
}

/// `OUT/chain.json`: the phases and how long each took.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct ChainState {
    command: String,
    phases: Vec<PhaseState>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PhaseState {
    name: String,
    command: String,
    wall_time_s: Option<f64>,
}

const STATE_FILE: &str = "chain.json";
const STAGE1: [&str; 5] = ["top", "input", "left", "right", "feature"];

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn words(list: &[&str]) -> Vec<String> {
    list.iter().map(|w| w.to_string()).collect()
}

/// The phases of the chain, in order.
fn phases(a: &ChainArgs, data: &Path) -> Vec<Phase> {
    let out = &a.out;
    let mut list = Vec::new();
    let phase = |name: &str, words: Vec<String>| Phase {
        name: name.to_string(),
        words,
        checkpoint: None,
        scratch: None,
    };
    if let (None, Some(world)) = (&a.dataset, &a.world) {
        let mut p = phase(
            "data",
            words(&["synth", "--world", world.name(), "--out", &s(data)]),
        );
        p.words.extend(words(&[
            "--scenes",
            &a.scenes.to_string(),
            "--samples-per-scene",
            &a.samples_per_scene.to_string(),
            "--seed",
            &a.data_seed.to_string(),
        ]));
        p.scratch = Some(data.to_path_buf());
        list.push(p);
    }
    let val = |mut w: Vec<String>| {
        if let Some(n) = a.val_samples {
            w.extend(["--samples".to_string(), n.to_string()]);
        }
        w
    };
    let (d, m) = (s(data), s(out));
    for case in STAGE1 {
        let weights = out.join(format!("{case}.safetensors"));
        let ckpt = out.join(format!("{case}.ckpt.safetensors"));
        let mut w = words(&[
            "train",
            "stage1",
            "--case",
            case,
            "--dataset",
            &d,
            "--out",
            &s(&weights),
        ]);
        w.extend(words(&[
            "--steps",
            &a.steps.to_string(),
            "--seed",
            &a.seed.to_string(),
        ]));
        w.extend(words(&[
            "--transfer-aug",
            "--no-intensity",
            "--checkpoint",
            &s(&ckpt),
        ]));
        // The car ray drop, adopted for LiDAR-Top, the one case it was measured on
        // (docs/notes/2026-12-07-lever-object-ray-drop-rule.md).
        if case == "top" {
            w.push("--car-drop".to_string());
        }
        if let Some(init) = &a.init {
            w.extend(words(&["--init", &s(&init.join(format!("{case}.safetensors")))]));
        }
        let mut p = phase(case, w);
        p.checkpoint = Some(ckpt);
        list.push(p);
    }
    let models = |sub: &str| words(&["train", sub, "--dataset", &d, "--models", &m]);
    list.push(phase("temperature", val(models("calibrate-temperature"))));
    list.push(phase("vote", val(models("tune-vote"))));
    list.push(phase("gate", val(models("tune-gate"))));
    let mut w = words(&["train", "proposals", "--dataset", &d, "--models", &m]);
    w.extend(words(&["--out", &s(&out.join("proposals"))]));
    if a.proposal_samples > 0 {
        w.extend(words(&["--max-samples", &a.proposal_samples.to_string()]));
    }
    list.push(phase("proposals", w));
    for (name, extra) in [("refiner", None), ("refiner-notrace", Some("--no-trace"))] {
        let mut w = words(&[
            "train",
            "refiner",
            "--dataset",
            &d,
            "--proposals",
            &s(&out.join("proposals")),
        ]);
        let weights = out.join(format!("{name}.safetensors"));
        w.extend(words(&["--out", &s(&weights)]));
        w.extend(words(&[
            "--steps",
            &a.refiner_steps.to_string(),
            "--seed",
            "0",
            "--log-every",
            "100",
        ]));
        w.extend(extra.map(String::from));
        let mut p = phase(name, w);
        p.checkpoint = Some(weights.with_extension("ckpt.safetensors"));
        list.push(p);
    }
    list.push(phase("tune-refiner", val(models("tune-refiner"))));
    let mut w = val(models("tune-refiner"));
    w.extend(words(&["--union-only", "--union-cases", "mlod-u,mlod-ir-drop"]));
    w.extend(words(&[
        "--union-nms",
        "0.3,0.5,0.7",
        "--union-vote",
        "0.5,0.6,0.7",
    ]));
    list.push(phase("tune-union", w));
    let n = a.stats_samples.to_string();
    list.push(phase(
        "stats",
        words(&[
            "stats",
            "--dataset",
            &d,
            "--samples",
            &n,
            "--summary",
            "--update-manifest",
            &m,
        ]),
    ));
    list
}

fn read_state(path: &Path) -> Result<Option<ChainState>> {
    match std::fs::read(path) {
        Ok(b) => {
            Ok(Some(serde_json::from_slice(&b).with_context(|| {
                format!("{}: not a chain state", path.display())
            })?))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| format!("cannot read {}", path.display())),
    }
}

fn write_state(path: &Path, state: &ChainState) -> Result<()> {
    let mut text = serde_json::to_string_pretty(state)?;
    text.push('\n');
    mlod::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// Runs one phase: this binary with `words`, its output shown as it comes.
fn run_phase(words: &[String]) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the mlod binary to run a phase")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.args(words);
    die_with_parent(&mut cmd);
    let status = cmd.status().context("cannot start the phase")?;
    if !status.success() {
        bail!("the phase failed ({status})");
    }
    Ok(())
}

/// The child gets SIGKILL when the chain dies (a killed chain must not leave a phase writing).
#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: prctl is async-signal-safe and touches only the child's own state.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn die_with_parent(_cmd: &mut std::process::Command) {}

pub fn chain(a: ChainArgs) -> Result<()> {
    let data = match &a.dataset {
        Some(d) => d.clone(),
        None => a.out.join("data").join("train"),
    };
    if a.steps == 0 || a.refiner_steps == 0 {
        bail!("--steps and --refiner-steps must be at least 1");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let cwd = std::env::current_dir().unwrap_or_default();
    let plan = phases(&a, &data);
    let state_path = a.out.join(STATE_FILE);
    let command = command_line();
    let fresh = ChainState {
        command: command.clone(),
        phases: plan
            .iter()
            .map(|p| PhaseState {
                name: p.name.clone(),
                command: super::args::portable_command(&p.words, &cwd),
                wall_time_s: None,
            })
            .collect(),
    };
    let mut state = match read_state(&state_path)? {
        None => fresh,
        Some(old) => {
            // A resumed run must be the same chain: same phases, same commands.
            let differs = fresh.phases.len() != old.phases.len()
                || fresh
                    .phases
                    .iter()
                    .zip(&old.phases)
                    .any(|(n, w)| n.command != w.command);
            if differs {
                let (was, now) = fresh
                    .phases
                    .iter()
                    .zip(&old.phases)
                    .find(|(n, w)| n.command != w.command)
                    .map_or(("(other phases)".to_string(), String::new()), |(n, w)| {
                        (format!("{}: `{}`", w.name, w.command), n.command.clone())
                    });
                bail!(
                    "{} holds another chain (phase {was}, now `{now}`): give another --out or the same options",
                    state_path.display()
                );
            }
            old
        }
    };
    write_state(&state_path, &state)?;
    let total = plan.len();
    let start = Instant::now();
    for (k, p) in plan.iter().enumerate() {
        if let Some(t) = state.phases[k].wall_time_s {
            eprintln!("[{}/{total}] {}: done ({t:.0} s)", k + 1, p.name);
            continue;
        }
        let mut words = p.words.clone();
        let resumed = p.checkpoint.as_ref().is_some_and(|c| c.is_file());
        if resumed {
            words.push("--resume".to_string());
        }
        if let Some(dir) = &p.scratch {
            if dir.exists() {
                std::fs::remove_dir_all(dir)
                    .with_context(|| format!("cannot clear the half-written {}", dir.display()))?;
            }
        }
        eprintln!(
            "[{}/{total}] {}{} (chain {:.0} s so far)",
            k + 1,
            p.name,
            if resumed { ": resuming" } else { "" },
            start.elapsed().as_secs_f64()
        );
        let t0 = Instant::now();
        run_phase(&words).with_context(|| format!("phase {} ({})", p.name, state.phases[k].command))?;
        state.phases[k].wall_time_s = Some(t0.elapsed().as_secs_f64());
        write_state(&state_path, &state)?;
    }
    let mut manifest = Manifest::load(&a.out)?;
    if let Some(w) = &a.world {
        manifest.world = Some(w.name().to_string());
    }
    manifest.chain = Some(ChainRecord {
        command,
        phases: state
            .phases
            .iter()
            .map(|p| ChainPhase {
                name: p.name.clone(),
                command: p.command.clone(),
                wall_time_s: p.wall_time_s.unwrap_or(0.0),
            })
            .collect(),
    });
    manifest.save(&a.out)?;
    println!("phase             wall time");
    for p in &state.phases {
        println!("{:<16} {:>8.0} s", p.name, p.wall_time_s.unwrap_or(0.0));
    }
    println!("chain done -> {}", a.out.display());
    Ok(())
}
