//! `mlod detect`: run a shipped stage-1 detector on one sample and print its boxes; the
//! `DetectorRun` options that `eval --case` and `table1` share.

use std::path::PathBuf;

use anyhow::Result;

use mlod::cases::run::{detections_json, RunOptions};
use mlod::detect::model::Voting;
use mlod::detect::Case;
use mlod::pipeline::FuseParams;

use super::args::{parse_alpha, sample_token};

/// Which shipped detector weights to run, on which perturbation: shared by `mlod detect`,
/// `mlod eval --case` and `mlod table1`.
#[derive(clap::Args)]
pub struct DetectorRun {
    /// α of the perturbation injected into the auxiliary LiDARs (one draw, the same
    /// mis-calibration for every sample, as on one car).
    #[arg(long, default_value_t = 0.0, value_parser = parse_alpha)]
    pub alpha: f64,
    /// Seed of the perturbation draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Models folder with manifest.json (default: assets/models).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Box voting after NMS: each detection becomes the score-weighted mean of the candidates
    /// overlapping it by at least this IoU (BEV; 3D in Result Fusion's merge). `manifest`: as
    /// the models' manifest.json says (`mlod train tune-vote`), `off`: plain NMS, or an IoU.
    #[arg(long, default_value = "manifest")]
    pub vote_iou: Voting,
    /// (OC) cases: the uncertainty the calibrated LiDARs' points carry into the refiner. `icp`:
    /// the covariance ICP estimated; `alpha`: the prior Θ(α), as without calibration.
    #[arg(long, default_value = "icp")]
    pub oc_prior: mlod::calib::OcPrior,
    /// `input-drop`, `mlod-ir-drop`: points with tr(Ξ) above this (m²) are removed before the
    /// stage-1 networks (default: the threshold chosen on the validation scenes).
    #[arg(long, default_value_t = mlod::cases::drop::DROP_TRACE, value_parser = super::args::parse_trace_threshold)]
    pub drop_trace: f32,
    /// Set every point's intensity to this value before the detector runs (real Lyft data holds
    /// 100 everywhere): how much a model leans on intensity.
    #[arg(long, value_parser = parse_intensity)]
    pub set_intensity: Option<f32>,
    /// Drop detections whose bottom floats more than this many metres above the ground around
    /// them (the 10th percentile of the lowest points of the 1 m cells within 6 m): boxes a
    /// simulator-trained detector puts on hedges and walls of real streets. `manifest`: the
    /// models folder's gate for the stage-1 cases (`mlod train tune-gate`; none if it has
    /// none), `off`, or a height in metres (any case).
    #[arg(long, default_value = "manifest")]
    pub ground_gate: mlod::cases::ground_gate::GateChoice,
    #[command(flatten)]
    pub external: super::external::ExternalArgs,
}

fn parse_intensity(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if !v.is_finite() || !(0.0..=65535.0).contains(&v) {
        return Err(format!("{s}: an intensity is finite and within 0..=65535"));
    }
    Ok(v)
}

impl DetectorRun {
    /// The detectors of `models` as their manifest decodes them, on the dataset's own extrinsics
    /// (α = 0): what the trainers' validation runs.
    pub fn of_models(
        models: PathBuf,
        vote_iou: Voting,
        ground_gate: mlod::cases::ground_gate::GateChoice,
    ) -> Self {
        Self {
            alpha: 0.0,
            seed: 0,
            models: Some(models),
            vote_iou,
            oc_prior: Default::default(),
            drop_trace: mlod::cases::drop::DROP_TRACE,
            set_intensity: None,
            ground_gate,
            external: Default::default(),
        }
    }

    /// The library's run options these flags say (the Python package builds the same).
    pub fn options(&self) -> RunOptions {
        RunOptions {
            alpha: self.alpha,
            seed: self.seed,
            models: self.models.clone(),
            vote_iou: self.vote_iou,
            oc_prior: self.oc_prior,
            drop_trace: self.drop_trace,
            set_intensity: self.set_intensity,
            ground_gate: self.ground_gate,
        }
    }

    /// `--set-intensity`: every LiDAR's intensities replaced.
    pub fn apply_intensity(&self, frame: &mut mlod::dataset::Frame) {
        self.options().apply_intensity(frame);
    }

    /// The detector of `case` from the models folder, with the decoding asked for (external
    /// detectors defined first).
    pub fn load(&self, case: Case) -> Result<Box<dyn mlod::detect::Detector>> {
        self.external.define_for(&[case])?;
        Ok(self.options().load(case)?)
    }

    /// The models folder asked for, or the shipped one.
    pub fn models_dir(&self) -> PathBuf {
        self.options().models_dir()
    }

    /// Fuse parameters with the perturbation asked for.
    pub fn fuse_params(&self) -> Result<FuseParams> {
        Ok(self.options().fuse_params()?)
    }
}

#[derive(clap::Args)]
pub struct DetectArgs {
    #[arg(long)]
    dataset: PathBuf,
    /// Sample token (default: the first sample in scene order).
    #[arg(long)]
    sample: Option<String>,
    /// The case: one of the cases listed below, or an external detector ext:NAME /
    /// mlod-ext:NAME (with --detector or --detectors; docs/external.md).
    #[arg(long)]
    case: Case,
    #[command(flatten)]
    run: DetectorRun,
    /// Print JSON.
    #[arg(long)]
    json: bool,
    /// base: base-frame boxes; lyft: the devkit's prediction format (global frame).
    #[arg(long, default_value = "base")]
    format: DetectFormat,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DetectFormat {
    Base,
    Lyft,
}

pub fn detect(a: DetectArgs) -> Result<()> {
    let dataset = super::open_dataset(&a.dataset)?;
    let token = sample_token(&dataset, a.sample.as_deref())?;
    let mut frame = dataset.frame(&token)?;
    a.run.apply_intensity(&mut frame);
    let params = a.run.fuse_params()?;
    let detector = a.run.load(a.case)?;
    super::stats::print_training_notes(&dataset, &a.run.models_dir());
    if let Some(note) = a.case.missing_lidars_note(&frame) {
        eprintln!("note: {note}");
    }
    let t0 = std::time::Instant::now();
    let dets = detector.detect(&frame, &params)?;
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    match a.format {
        DetectFormat::Base => {
            if a.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&detections_json(&token, a.case, &dets))?
                );
            } else {
                println!(
                    "{} on {token}: {} boxes in {ms:.1} ms (base frame)",
                    a.case.paper_name(),
                    dets.len()
                );
                for d in &dets {
                    let b = &d.box3d;
                    println!(
                        "  {:<6} score {:.3}  center [{:8.3}, {:8.3}, {:7.3}]  lwh [{:.2}, {:.2}, {:.2}]  yaw {:7.4}",
                        d.category, d.score, b.center[0], b.center[1], b.center[2], b.size_lwh[0], b.size_lwh[1],
                        b.size_lwh[2], b.yaw
                    );
                }
            }
        }
        DetectFormat::Lyft => {
            let to_global = frame.primary.info.ego_to_global * frame.primary.info.sensor_to_ego;
            let rows: Vec<mlod::eval::LyftBox> = dets
                .iter()
                .map(|d| {
                    mlod::eval::LyftBox::from_base(
                        &token,
                        &d.box3d,
                        &to_global,
                        &d.category,
                        Some(f64::from(d.score)),
                    )
                })
                .collect();
            println!("{}", serde_json::to_string_pretty(&rows)?);
        }
    }
    Ok(())
}
