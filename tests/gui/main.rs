//! The whole debugger driven headlessly (egui_kittest on wgpu; lavapipe with
//! `WGPU_BACKEND=vulkan` in CI): snapshots of the main states, the α slider moving the fused cloud
//! and the legend, a session round trip that reproduces identical pixels, stage-1 detection, and
//! MLOD-I (proposals, refinements and ground truth on screen, counted as `mlod eval` counts,
//! active points, a missing refiner).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use egui::accesskit::Role;
use egui_kittest::kittest::{NodeT, Queryable};
use egui_kittest::Harness;
use mlod::cases::load_mlod;
use mlod::color::ColorMode;
use mlod::dataset::Dataset;
use mlod::detect::model::Voting;
use mlod::detect::{Case, Detection, Manifest};
use mlod::eval::{evaluate_detections, EvalOptions, GtOutcome, MatchRule, PredOutcome};
use mlod::geometry::IouKind;
use mlod::gui::{
    default_dataset, AppOptions, MlodApp, ACTIVE_POINT_COLOR, FALSE_POSITIVE_COLOR, GT_COLOR, PROPOSAL_COLOR,
    REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR,
};
use mlod::render::View;
use mlod::session::Session;
use mlod::train::proposals::DatabaseConfig;
use mlod::train::refiner::{train_refiner, RefineTrainConfig};
use mlod::uncertainty::Perturbation;

#[path = "../common/mod.rs"]
mod common;
mod external;

fn harness(session: Option<Session>) -> Harness<'static, MlodApp> {
    harness_with(session, None)
}

fn harness_with(session: Option<Session>, models: Option<std::path::PathBuf>) -> Harness<'static, MlodApp> {
    harness_and_render_state(session, models).0
}

/// [`harness_with`], and the wgpu render state the app was created with (for the viewport's
/// GPU figures).
fn harness_and_render_state(
    session: Option<Session>,
    models: Option<std::path::PathBuf>,
) -> (Harness<'static, MlodApp>, egui_wgpu::RenderState) {
    harness_full(default_dataset(), session, models)
}

/// The window opened on `dataset` (or the session's), and its wgpu render state.
fn harness_full(
    dataset: PathBuf,
    session: Option<Session>,
    models: Option<std::path::PathBuf>,
) -> (Harness<'static, MlodApp>, egui_wgpu::RenderState) {
    let render_state = std::sync::Arc::new(std::sync::Mutex::new(None));
    let rs = render_state.clone();
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .wgpu()
        .build_eframe(move |cc| {
            *rs.lock().unwrap() = cc.wgpu_render_state.clone();
            MlodApp::new(
                cc,
                AppOptions {
                    dataset,
                    session,
                    synchronous: true,
                    measure_frames: None,
                    measure_run: false,
                    models,
                    session_file: None,
                },
            )
        });
    h.run_steps(3);
    let rs = render_state.lock().unwrap().clone().expect("a wgpu render state");
    (h, rs)
}

fn session_at(alpha: f64, mode: ColorMode) -> Session {
    let mut s = Session::new(default_dataset());
    s.fuse.perturbation = Perturbation::new(alpha, 0).unwrap();
    s.color.mode = mode;
    s
}

/// The models folder of the MLOD tests: `assets/models` once it ships a refiner; until then a
/// copy of the stage-1 weights with a tiny refiner trained on two samples (three steps), made once
/// per test run.
fn mlod_models() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let shipped = assets_models();
        if Manifest::load(&shipped).unwrap().refiner.is_some() {
            return shipped;
        }
        let dir = std::env::temp_dir().join(format!("mlod-gui-refiner-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let models = stage1_copy(&dir.join("models"));
        let db = dir.join("db");
        mlod::train::proposals::build(
            &DatabaseConfig {
                dataset: default_dataset(),
                models: shipped,
                out: db.clone(),
                cases: vec![Case::Input],
                draws: 1,
                seed: 3,
                zero_share: 0.5,
                max_samples: 2,
            },
            |_, _| {},
        )
        .unwrap();
        let mut cfg = RefineTrainConfig::new(default_dataset(), db, models.join("refiner.safetensors"));
        cfg.batch = 8;
        cfg.positives = 4;
        cfg.model.gather.points = 128;
        cfg.model.point_mlp = vec![16, 32];
        cfg.model.head = vec![32];
        cfg.model.proposal_width = 8;
        cfg.warmup = 1;
        cfg.lr = 3e-3;
        cfg.steps = 3;
        cfg.seed = 1;
        cfg.checkpoint_every_s = 1e9;
        train_refiner(&cfg, |_| {}).unwrap();
        assert!(Manifest::load(&models).unwrap().refiner.is_some());
        // The database and the checkpoint are not needed any more (the weights stay for the run).
        let _ = std::fs::remove_dir_all(&cfg.proposals);
        let _ = std::fs::remove_file(&cfg.checkpoint);
        models
    })
    .clone()
}

use common::assets_models;

/// `dir` with the shipped stage-1 weights and their manifest, without a refiner.
fn stage1_copy(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let mut m = Manifest::load(&assets_models()).unwrap();
    for e in m.models.values() {
        std::fs::copy(assets_models().join(&e.file), dir.join(&e.file)).unwrap();
    }
    m.refiner = None;
    m.refine = None;
    m.save(dir).unwrap();
    dir.to_path_buf()
}

/// Pixels of the viewport in any of `colors` (exactly: lines are opaque).
fn count_pixels(img: &image::RgbaImage, rect: egui::Rect, colors: &[[u8; 4]]) -> usize {
    let scale = img.width() as f32 / 1280.0;
    let (x0, y0) = ((rect.min.x * scale) as u32, (rect.min.y * scale) as u32);
    let (x1, y1) = (
        ((rect.max.x * scale) as u32).min(img.width()),
        ((rect.max.y * scale) as u32).min(img.height()),
    );
    let mut n = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            let p = img.get_pixel(x, y).0;
            n += colors.iter().any(|c| c[..3] == p[..3]) as usize;
        }
    }
    n
}

fn mlod_session(alpha: f64, mode: ColorMode) -> Session {
    let mut s = session_at(alpha, mode);
    s.detection.case = Case::MlodI;
    s
}

/// `mlod eval --per-box` of `drawn` on one sample (3D IoU at `match_iou`, no range limit).
fn per_box_sample(token: &str, drawn: Vec<Detection>, match_iou: f64) -> mlod::eval::dataset::SampleReport {
    let dataset = Dataset::open(default_dataset()).unwrap();
    let opts = EvalOptions {
        per_box: Some(MatchRule {
            iou_threshold: match_iou,
            kind: IouKind::ThreeD,
            max_range: f64::INFINITY,
        }),
        ..Default::default()
    };
    let report = evaluate_detections(&dataset, &HashMap::from([(token.to_string(), drawn)]), &opts).unwrap();
    report
        .per_box
        .unwrap()
        .into_iter()
        .find(|s| s.sample_token == token)
        .unwrap()
}

/// TP, FP and misses of `drawn` on one sample as `mlod eval --per-box` matches them (ground truth
/// of other categories left out).
fn eval_counts(
    token: &str,
    drawn: Vec<Detection>,
    match_iou: f64,
    categories: &[String],
) -> (usize, usize, usize) {
    let s = per_box_sample(token, drawn, match_iou);
    let tp = s
        .preds
        .iter()
        .filter(|p| matches!(p.outcome, PredOutcome::TruePositive { .. }))
        .count();
    let fp = s
        .preds
        .iter()
        .filter(|p| matches!(p.outcome, PredOutcome::FalsePositive { .. }))
        .count();
    let missed = s
        .gts
        .iter()
        .filter(|g| categories.contains(&g.category) && matches!(g.outcome, GtOutcome::Missed))
        .count();
    (tp, fp, missed)
}

/// Every file under `dir`, with its bytes (a folder's state before and after).
fn tree(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// Resident memory of this process (kB), from /proc.
fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

fn kitti_fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/kitti")
}

fn harness_on(dataset: PathBuf, session: Option<Session>) -> Harness<'static, MlodApp> {
    harness_full(dataset, session, None).0
}

mod models;
mod viewport;
mod visibility;

mod av2;
mod browse;
mod detection;
mod window;
mod workflow;
