//! Background work for the GUI: opening a dataset and loading a frame run on worker threads and
//! report back through a channel that the UI drains once per frame, so the window never blocks on
//! disk. Results carry the request they answer; stale ones (the user already moved on) are
//! dropped by the app. Detector runs give stage 1's boxes and, for an MLOD case, their
//! refinements (`Mlod::run`). `synchronous` mode runs jobs inline (tests, headless screenshots).

use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;

use crate::calib::{Calibration, IcpConfig, OcPrior};
use crate::cases::ground_gate::GateChoice;
use crate::cases::{load_mlod, Mlod};
use crate::dataset::{Dataset, Frame, SampleSummary};
use crate::detect::model::Voting;
use crate::detect::{Case, Detection, Detector};
use crate::pipeline::FuseParams;
use crate::refine::Refined;

/// A loaded detector: a stage-1 case, or an MLOD case (stage 1 and the refiner).
#[derive(Clone)]
pub enum LoadedDetector {
    Stage1(Arc<dyn Detector>),
    Mlod(Arc<Mlod>),
}

impl LoadedDetector {
    /// Loads the shipped detector of `case` from a models folder (box voting as its manifest says).
    /// An (OC) case loads the detector it wraps: the calibration comes with the request's
    /// fuse parameters.
    fn load(models: &std::path::Path, case: Case, gate: GateChoice) -> Result<Self, String> {
        let case = case.without_oc();
        if case.is_mlod() {
            let m = load_mlod(models, case, Voting::Manifest).map_err(|e| e.to_string())?;
            return Ok(Self::Mlod(Arc::new(m)));
        }
        // Behind the models folder's ground gate (`mlod train tune-gate`) unless switched off, as
        // `mlod detect` applies it.
        let d = crate::cases::load_gated(models, case, gate).map_err(|e| e.to_string())?;
        Ok(Self::Stage1(Arc::from(d)))
    }

    /// The categories it outputs.
    pub fn categories(&self) -> Vec<String> {
        match self {
            Self::Stage1(d) => d.categories(),
            Self::Mlod(m) => m.categories(),
        }
    }
}

/// A detector run: the shipped model of `case` on one frame fused with `params`.
pub struct DetectRequest {
    pub frame: Arc<Frame>,
    pub params: FuseParams,
    /// The app's fuse generation the request was made at (a later one makes the result stale).
    pub generation: u64,
    pub case: Case,
    /// The already-loaded detector of this case, if any.
    pub cached: Option<LoadedDetector>,
    pub models: PathBuf,
    /// The ground gate of its stage-1 cases (the models folder's, or off).
    pub gate: GateChoice,
    /// For the compare half (the session's second case) rather than the main view.
    pub compare: bool,
}

/// What a detector run gives back.
pub struct DetectOutput {
    pub detector: LoadedDetector,
    /// The models folder it was loaded from (a run from a folder the window has since left is
    /// dropped).
    pub models: PathBuf,
    /// The gate it was loaded with.
    pub gate: GateChoice,
    /// Stage 1's boxes (an MLOD case's proposals), highest score first.
    pub detections: Vec<Detection>,
    /// An MLOD case's refinements of `detections`.
    pub refined: Option<Vec<Refined>>,
}

/// Samples summarised for the out-of-depth notes (as `mlod detect` does: cheap).
const DEPTH_NOTE_SAMPLES: usize = 5;

/// A finished job.
pub enum JobResult {
    Dataset {
        path: PathBuf,
        result: Result<(Arc<Dataset>, Vec<SampleSummary>), String>,
    },
    /// A dataset's statistics summary (a few samples) against the models' training data.
    DepthNotes { path: PathBuf, notes: Vec<String> },
    Frame {
        token: String,
        result: Result<Arc<Frame>, String>,
        millis: f64,
    },
    Detect {
        token: String,
        generation: u64,
        case: Case,
        /// The compare half's run.
        compare: bool,
        result: Result<DetectOutput, String>,
        millis: f64,
    },
    /// A failure scan (its id: a cancelled or superseded one is dropped).
    Scan {
        id: u64,
        result: Result<Vec<crate::analysis::failures::SampleFailures>, String>,
        millis: f64,
    },
    /// An exported clip: frames written, bytes.
    Clip {
        path: PathBuf,
        result: Result<(usize, u64), String>,
        millis: f64,
    },
    Calibrate {
        /// The request's id (a cancelled or superseded one is dropped by the app).
        id: u64,
        token: String,
        result: Result<Calibration, String>,
        millis: f64,
    },
}

/// Spawns jobs and collects their results.
pub struct Jobs {
    tx: Sender<JobResult>,
    rx: Receiver<JobResult>,
    repaint: Option<egui::Context>,
    synchronous: bool,
    running: usize,
}

impl Jobs {
    pub fn new(repaint: Option<egui::Context>, synchronous: bool) -> Self {
        let (tx, rx) = channel();
        Self {
            tx,
            rx,
            repaint,
            synchronous,
            running: 0,
        }
    }

    /// Jobs started and not yet collected.
    pub fn running(&self) -> usize {
        self.running
    }

    fn spawn(&mut self, work: impl FnOnce() -> JobResult + Send + 'static) {
        self.running += 1;
        if self.synchronous {
            let _ = self.tx.send(work());
            return;
        }
        let tx = self.tx.clone();
        let ctx = self.repaint.clone();
        std::thread::spawn(move || {
            let _ = tx.send(work());
            if let Some(ctx) = ctx {
                ctx.request_repaint();
            }
        });
    }

    /// A failure scan over `cfg.tokens`; `done` counts finished samples, `cancel` stops it.
    pub fn scan(
        &mut self,
        id: u64,
        dataset: Arc<Dataset>,
        (models, gate): (PathBuf, GateChoice),
        cfg: crate::analysis::failures::ScanConfig,
        done: Arc<std::sync::atomic::AtomicUsize>,
        cancel: Arc<std::sync::atomic::AtomicBool>,
    ) {
        let repaint = self.repaint.clone();
        self.spawn(move || {
            let start = std::time::Instant::now();
            let scan = || {
                crate::analysis::failures::scan(&dataset, &models, gate, &cfg, &cancel, &|d, _| {
                    done.store(d, std::sync::atomic::Ordering::Relaxed);
                    if let Some(ctx) = &repaint {
                        ctx.request_repaint();
                    }
                })
            };
            // A long scan leaves one core to the window (and its software rasteriser): its pool
            // has one thread fewer than the machine (at least one).
            let threads =
                std::thread::available_parallelism().map_or(1, |n| n.get().saturating_sub(1).max(1));
            let result = match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
                Ok(pool) => pool.install(scan),
                Err(_) => scan(),
            }
            .map_err(|e| e.to_string());
            JobResult::Scan {
                id,
                result,
                millis: start.elapsed().as_secs_f64() * 1e3,
            }
        });
    }

    /// Renders "play α" of `options` headlessly and writes it as a GIF to `path`.
    pub fn clip(&mut self, options: super::AppOptions, clip: super::clip::ClipOptions, path: PathBuf) {
        self.spawn(move || {
            let start = std::time::Instant::now();
            let result = super::clip::render_clip(options, &clip, &|_, _| {})
                .and_then(|frames| {
                    super::clip::write_gif(&path, &frames, clip.fps)?;
                    Ok(frames.len())
                })
                .map(|n| (n, std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0)))
                .map_err(|e| e.to_string());
            JobResult::Clip {
                path,
                result,
                millis: start.elapsed().as_secs_f64() * 1e3,
            }
        });
    }

    pub fn open_dataset(&mut self, path: PathBuf) {
        self.spawn(move || {
            let result = Dataset::open(&path)
                .map(|d| {
                    let samples = d.samples();
                    (Arc::new(d), samples)
                })
                .map_err(|e| e.to_string());
            JobResult::Dataset { path, result }
        });
    }

    /// What differs between `dataset` and the data the models in `models` were trained on
    /// (nothing when the manifest has no training statistics or the summary fails).
    pub fn depth_notes(&mut self, path: PathBuf, dataset: Arc<Dataset>, models: PathBuf) {
        self.spawn(move || {
            let notes = match crate::dataset::summarize(&dataset, DEPTH_NOTE_SAMPLES) {
                Ok(data) => crate::detect::weights::training_notes(&models, &data),
                Err(_) => Vec::new(),
            };
            JobResult::DepthNotes { path, notes }
        });
    }

    pub fn load_frame(&mut self, dataset: Arc<Dataset>, token: String) {
        self.spawn(move || {
            let start = std::time::Instant::now();
            let result = dataset.frame(&token).map(Arc::new).map_err(|e| e.to_string());
            JobResult::Frame {
                token,
                result,
                millis: start.elapsed().as_secs_f64() * 1e3,
            }
        });
    }

    /// Runs a detector (loading its weights first if needed) on a worker thread; an MLOD case
    /// gives its proposals and their refinements.
    pub fn detect(&mut self, req: DetectRequest) {
        self.spawn(move || {
            let start = std::time::Instant::now();
            let token = req.frame.sample_token.clone();
            let result = (|| {
                let detector = match req.cached {
                    Some(d) => d,
                    None => LoadedDetector::load(&req.models, req.case, req.gate)?,
                };
                let (detections, refined) = match &detector {
                    LoadedDetector::Stage1(d) => (d.detect(&req.frame, &req.params), None),
                    LoadedDetector::Mlod(m) => match m.run(&req.frame, &req.params) {
                        Ok(run) => (Ok(run.proposals), Some(run.refined)),
                        Err(e) => (Err(e), None),
                    },
                };
                let detections = detections.map_err(|e| e.to_string())?;
                Ok(DetectOutput {
                    detector,
                    models: req.models.clone(),
                    gate: req.gate,
                    detections,
                    refined,
                })
            })();
            JobResult::Detect {
                token,
                generation: req.generation,
                case: req.case,
                compare: req.compare,
                result,
                millis: start.elapsed().as_secs_f64() * 1e3,
            }
        });
    }

    /// Online calibration (ICP) of the auxiliary LiDARs of `frame`, drifted as `params` says.
    pub fn calibrate(&mut self, id: u64, frame: Arc<Frame>, params: FuseParams, prior: OcPrior) {
        self.spawn(move || {
            let start = std::time::Instant::now();
            let result = crate::pipeline::calibrate(&frame, &params, &IcpConfig::default(), prior)
                .map_err(|e| e.to_string());
            JobResult::Calibrate {
                id,
                token: frame.sample_token.clone(),
                result,
                millis: start.elapsed().as_secs_f64() * 1e3,
            }
        });
    }

    /// Results that arrived since the last call.
    pub fn poll(&mut self) -> Vec<JobResult> {
        let out: Vec<JobResult> = self.rx.try_iter().collect();
        self.running = self.running.saturating_sub(out.len());
        out
    }
}
