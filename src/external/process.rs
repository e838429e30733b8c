//! One external detector process: started at the first frame, kept for the run, reaped always.
//!
//! How it works: the child's stdin, stdout and stderr are pipes. A reader thread turns stdout
//! into lines on a channel, so an answer is awaited with a timeout (`recv_timeout`); another
//! forwards stderr, line by line and prefixed with the case, to mlod's stderr. Any failure (it
//! does not start, exits, writes something that is not an answer, answers an error or for
//! another sample, or is late) kills the child, waits for it, and leaves the detector failed:
//! every later frame gets the same error without starting it again. Dropping the detector closes
//! the child's stdin (its signal to end), gives it a moment, then kills and reaps it, and
//! removes the points file's folder.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::dataset::Frame;
use crate::detect::{Case, DetectError, Detection, Detector};
use crate::external::protocol::{points_bytes, Answer, Request};
use crate::external::{ExternalError, ExternalSpec};
use crate::pipeline::FusedCloud;

/// How long a closing detector may take to exit by itself before it is killed.
const EXIT_GRACE: Duration = Duration::from_secs(2);
/// The longest line of an answer (64 MiB) before it counts as garbage.
const MAX_LINE: usize = 64 << 20;

/// Processes started, per command line (tests check that nothing ran behind the user's back).
fn spawns() -> std::sync::MutexGuard<'static, std::collections::BTreeMap<String, usize>> {
    static SPAWNS: Mutex<std::collections::BTreeMap<String, usize>> =
        Mutex::new(std::collections::BTreeMap::new());
    match SPAWNS.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

/// How many processes this process has started for `command_line` ([`ExternalSpec::command_line`]).
pub fn spawn_count(command_line: &str) -> usize {
    spawns().get(command_line).copied().unwrap_or(0)
}

/// A running child and its pipes.
struct Running {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<std::io::Result<String>>,
    points: PathBuf,
    folder: PathBuf,
}

impl Running {
    /// Waits up to `grace` for the child to exit by itself, then kills it; returns how it ended.
    fn end(&mut self, grace: Duration) -> String {
        self.stdin = None;
        let until = Instant::now() + grace;
        loop {
            match self.child.try_wait() {
                Ok(Some(status)) => return describe(status),
                Ok(None) if Instant::now() < until => std::thread::sleep(Duration::from_millis(10)),
                _ => break,
            }
        }
        let _ = self.child.kill();
        match self.child.wait() {
            Ok(s) => describe(s),
            Err(e) => format!("could not be reaped ({e})"),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.end(EXIT_GRACE);
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

/// Rewrites the points file over its old bytes (no truncation first: a file of about the same
/// size every frame keeps its pages), then cuts it to the new length.
fn write_in_place(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)?;
    f.write_all(bytes)?;
    f.set_len(bytes.len() as u64)
}

fn describe(status: std::process::ExitStatus) -> String {
    match status.code() {
        Some(c) => format!("exit status {c}"),
        None => format!("{status}"),
    }
}

enum State {
    Idle,
    Running(Box<Running>),
    Failed(String),
}

/// An `ext:NAME` detector: the process of its [`ExternalSpec`], over `mlod-detector/1`.
pub struct ExternalDetector {
    spec: ExternalSpec,
    case: Case,
    state: Mutex<State>,
}

impl ExternalDetector {
    /// The detector of `spec`; its process starts at the first frame.
    pub fn new(spec: ExternalSpec) -> Self {
        let case = crate::external::ext_case(&spec.name);
        Self {
            spec,
            case,
            state: Mutex::new(State::Idle),
        }
    }

    pub fn spec(&self) -> &ExternalSpec {
        &self.spec
    }

    fn error(&self, what: String) -> ExternalError {
        ExternalError::Detector {
            name: self.spec.name.clone(),
            command: self.spec.command_line(),
            what,
        }
    }

    fn start(&self) -> Result<Running, String> {
        static FOLDERS: AtomicU64 = AtomicU64::new(0);
        let program = self.spec.command.first().ok_or("the command is empty")?;
        let mut cmd = Command::new(program);
        cmd.args(self.spec.command.iter().skip(1))
            .envs(&self.spec.env)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if let Some(dir) = &self.spec.dir {
            cmd.current_dir(dir);
        }
        let folder = std::env::temp_dir().join(format!(
            "mlod-ext-{}-{}",
            std::process::id(),
            FOLDERS.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&folder).map_err(|e| format!("cannot create {}: {e}", folder.display()))?;
        let folder = std::path::absolute(&folder).unwrap_or(folder);
        let mut child = match cmd.spawn() {
            Ok(c) => {
                *spawns().entry(self.spec.command_line()).or_default() += 1;
                c
            }
            Err(e) => {
                let _ = std::fs::remove_dir_all(&folder);
                let dir = self.spec.dir.as_ref().map(|d| format!(" in {}", d.display()));
                return Err(format!("did not start{}: {e}", dir.unwrap_or_default()));
            }
        };
        let (stdin, stdout, stderr) = (child.stdin.take(), child.stdout.take(), child.stderr.take());
        let (Some(stdin), Some(stdout)) = (stdin, stdout) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err("its pipes could not be opened".into());
        };
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut r = BufReader::new(stdout);
            loop {
                let mut line = String::new();
                match std::io::Read::take(&mut r, MAX_LINE as u64).read_line(&mut line) {
                    Ok(0) => break,
                    Ok(_) => {
                        if tx.send(Ok(line)).is_err() {
                            break;
                        }
                    }
                    Err(e) => {
                        let _ = tx.send(Err(e));
                        break;
                    }
                }
            }
        });
        if let Some(stderr) = stderr {
            let case = self.case;
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    eprintln!("[{case}] {line}");
                }
            });
        }
        Ok(Running {
            child,
            stdin: Some(stdin),
            lines,
            points: folder.join("points.f32"),
            folder,
        })
    }

    /// Sends one frame and reads its answer; `Err` says what the detector did.
    fn exchange(&self, run: &mut Running, token: &str, cloud: &FusedCloud) -> Result<Vec<Detection>, String> {
        let bytes = points_bytes(cloud)?;
        write_in_place(&run.points, &bytes)
            .map_err(|e| format!("cannot write {}: {e}", run.points.display()))?;
        let request = Request::new(token, &run.points, cloud.len());
        let mut line = serde_json::to_string(&request).map_err(|e| e.to_string())?;
        line.push('\n');
        let sent = match run.stdin.as_mut() {
            Some(stdin) => stdin.write_all(line.as_bytes()).and_then(|()| stdin.flush()),
            None => Err(std::io::ErrorKind::BrokenPipe.into()),
        };
        if sent.is_err() {
            let how = run.end(EXIT_GRACE);
            return Err(format!("exited ({how}) before it was sent sample {token}"));
        }
        let timeout = self.spec.timeout();
        let text = match run.lines.recv_timeout(timeout) {
            Ok(Ok(text)) => text,
            Ok(Err(e)) => return Err(format!("its stdout could not be read ({e}) for sample {token}")),
            Err(RecvTimeoutError::Timeout) => {
                let how = run.end(Duration::ZERO);
                return Err(format!(
                    "did not answer sample {token} within {:.0} s (--detector-timeout); it was stopped ({how})",
                    timeout.as_secs_f64()
                ));
            }
            Err(RecvTimeoutError::Disconnected) => {
                let how = run.end(EXIT_GRACE);
                return Err(format!("exited ({how}) without answering sample {token}"));
            }
        };
        let answer: Answer = serde_json::from_str(text.trim()).map_err(|e| {
            let shown: String = text.trim().chars().take(120).collect();
            format!("answered sample {token} with something that is not a mlod-detector/1 answer ({e}): {shown:?}")
        })?;
        if answer.sample_token != token {
            return Err(format!(
                "answered for sample {:?} when asked for {token}",
                answer.sample_token
            ));
        }
        if let Some(e) = answer.error {
            return Err(format!("answered an error for sample {token}: {e}"));
        }
        let boxes = answer
            .boxes
            .ok_or_else(|| format!("its answer for sample {token} has neither boxes nor error"))?;
        let mut dets = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| {
                b.to_detection()
                    .map_err(|e| format!("box {i} of sample {token}: {e}"))
            })
            .collect::<Result<Vec<_>, _>>()?;
        dets.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(dets)
    }

    /// Detects on `cloud` (the frame `token`, fused by the caller).
    pub fn detect_cloud(&self, token: &str, cloud: &FusedCloud) -> Result<Vec<Detection>, ExternalError> {
        let mut state = match self.state.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        };
        if let State::Failed(why) = &*state {
            return Err(self.error(format!("failed earlier in this run: {why}")));
        }
        if matches!(*state, State::Idle) {
            match self.start() {
                Ok(r) => *state = State::Running(Box::new(r)),
                Err(why) => {
                    *state = State::Failed(why.clone());
                    return Err(self.error(why));
                }
            }
        }
        let State::Running(run) = &mut *state else {
            return Err(self.error("is not running".into()));
        };
        match self.exchange(run, token, cloud) {
            Ok(d) => Ok(d),
            Err(why) => {
                // Dropping the running child kills and reaps it.
                *state = State::Failed(why.clone());
                Err(self.error(why))
            }
        }
    }
}

impl Detector for ExternalDetector {
    fn case(&self) -> Case {
        self.case
    }

    fn categories(&self) -> Vec<String> {
        self.spec.classes.clone()
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        Ok(self.detect_cloud(&frame.sample_token, cloud)?)
    }
}
