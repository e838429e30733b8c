//! The shipped weights (`assets/models/`) reproduce the committed detections and refinements
//! (`tests/fixtures/detections/`) on two sample_data frames bit for bit, for every listed case
//! that runs on them, and their manifest records how they were made. `MLOD_BLESS=1 cargo test
//! --test detect shipped` rewrites the fixtures after a deliberate change of the weights.

use std::path::{Path, PathBuf};

use mlod::dataset::Dataset;
use mlod::detect::model::load_detector;
use mlod::detect::weights::{default_models_dir, Manifest};
use mlod::detect::Case;
use mlod::pipeline::FuseParams;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/detections")
}

fn blessing() -> bool {
    std::env::var("MLOD_BLESS").is_ok()
}

fn sample_data() -> (Dataset, Vec<String>) {
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
    let tokens = ds.sample_tokens().iter().take(2).map(|t| t.to_string()).collect();
    (ds, tokens)
}

/// `json` equals the committed fixture at `path` byte for byte (with `bless`: written there first).
fn check_fixture(path: &Path, json: &str, bless: bool, what: &str) {
    if bless {
        mlod::io::write_atomic(path, json.as_bytes()).unwrap();
    }
    let committed = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e} (run with MLOD_BLESS=1 to create it)", path.display()));
    assert!(committed == json, "{what} differ from {}", path.display());
}

/// `command` (a manifest's record of how weights were made) holds every one of `parts`.
fn assert_command_has(command: &str, parts: &[&str]) {
    for part in parts {
        assert!(command.contains(part), "{part:?} not in {command}");
    }
}

#[test]
fn shipped_weights_reproduce_committed_detections() {
    let (ds, tokens) = sample_data();
    let models = default_models_dir();
    for case in Case::ALL {
        let det = load_detector(&models, case).unwrap_or_else(|e| panic!("{case}: {e}"));
        for token in &tokens {
            let frame = ds.frame(token).unwrap();
            let dets = det.detect(&frame, &FuseParams::default()).unwrap();
            let json = serde_json::to_string_pretty(&dets).unwrap() + "\n";
            let path = fixtures().join(format!("{case}-{}.json", &token[..12]));
            check_fixture(
                &path,
                &json,
                blessing(),
                &format!("{case} on {token}: detections"),
            );
        }
    }
}

/// The shipped refiner reproduces the committed refinements of two sample_data frames under a
/// perturbation (α = 0.04, seed 0) bit for bit, for every MLOD case of the paper and beyond it:
/// every refined box, its score, the classification head's probability, the proposal it came from
/// and its active points.
#[test]
fn shipped_refiner_reproduces_committed_refinements() {
    let (ds, tokens) = sample_data();
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(0.04, 0).unwrap(),
        ..Default::default()
    };
    for case in Case::MLOD.into_iter().chain(Case::BEYOND) {
        check_refinements(
            &default_models_dir(),
            &fixtures(),
            case,
            &ds,
            &tokens,
            &params,
            blessing(),
        );
    }
}

/// `case` of the models folder on each of `tokens` under `params` reproduces the committed
/// refinements in `fixtures` (`{case}-a0.04-{token}.json`) byte for byte.
fn check_refinements(
    models: &Path,
    fixtures: &Path,
    case: Case,
    ds: &Dataset,
    tokens: &[String],
    params: &FuseParams,
    bless: bool,
) {
    let m = mlod::cases::load_mlod(models, case, Default::default()).unwrap();
    for token in tokens {
        let run = m.run(&ds.frame(token).unwrap(), params).unwrap();
        let rows: Vec<serde_json::Value> = run
            .refined
            .iter()
            .map(|r| {
                serde_json::json!({
                    "box": r.detection,
                    "refined_score": r.refined_score,
                    "proposal": r.proposal,
                    "proposal_box": run.proposals[r.proposal],
                    "active": r.active,
                    "unrefined": r.unrefined,
                })
            })
            .collect();
        let json = serde_json::to_string_pretty(&rows).unwrap() + "\n";
        let path = fixtures.join(format!("{case}-a0.04-{}.json", &token[..12]));
        check_fixture(&path, &json, bless, &format!("{case} on {token}: refinements"));
        // Every refinement points at a proposal of its run.
        assert!(run.refined.iter().all(|r| r.proposal < run.proposals.len()));
    }
}

fn assert_transfer_chain(dir: &Path, dataset: &str) -> Manifest {
    let m = Manifest::load(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let data = format!("--dataset {dataset}");
    for (case, entry) in &m.models {
        // Loading checks the file against the manifest's sha256.
        load_detector(dir, *case).unwrap_or_else(|e| panic!("{case}: {e}"));
        assert_command_has(
            &entry.command,
            &["mlod train stage1", &data, "--transfer-aug", "--no-intensity"],
        );
        assert_eq!(entry.steps, 10_000, "{case}");
        assert!(entry.init.is_none(), "{case}: trained from scratch");
        assert!(entry.test_ap.contains_key("moderate_ap3d_0.7"), "{case}");
    }
    // Trained without intensity, so the training-data notes leave intensity out.
    assert!(!mlod::detect::weights::models_read_intensity(dir));
    for r in [&m.refiner, &m.refiner_notrace] {
        let r = r.as_ref().expect("both refiners ship");
        assert!(r.command.contains(&data), "{}", r.command);
    }
    m
}

#[test]
fn shipped_models_are_the_walled_chain() {
    // The shipped chain (issue 29): every stage-1 model trained from scratch with seed 5 on the
    // walled world (`mlod synth --world walled`, recorded in the manifest) with the transfer
    // augmentation and without intensity; the temperatures, voting, refiner decoding and ground
    // gate chosen on its validation scenes.
    let dir = default_models_dir();
    let m = assert_transfer_chain(&dir, "data/v6w/train");
    assert_eq!(m.world.as_deref(), Some("walled"));
    assert_eq!(
        m.models.keys().copied().collect::<Vec<_>>(),
        [Case::Top, Case::Left, Case::Right, Case::Input, Case::Feature]
    );
    for case in [Case::Top, Case::Left, Case::Right, Case::Input, Case::Feature] {
        assert_command_has(&m.models[&case].command, &["--seed 5", "--steps 10000"]);
    }
    assert_eq!(m.temperatures.len(), 3);
    assert!(m
        .vote
        .as_ref()
        .expect("voting")
        .command
        .contains("data/v6w/train"));
    assert!(m.refine.is_some());
    let gate = m
        .ground_gate
        .as_ref()
        .expect("a ground gate chosen on validation");
    assert!(
        gate.command.contains("--dataset data/v6w/train"),
        "{}",
        gate.command
    );
    assert!(m.training_stats.is_some());
}

#[test]
fn voting_moves_the_boxes_but_keeps_the_detections() {
    use mlod::detect::model::{load_detector_with, Voting};
    let models = default_models_dir();
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
    let frame = ds.frame(ds.first_sample_token().unwrap()).unwrap();
    for case in [Case::Top, Case::Result] {
        let run = |v: Voting| {
            load_detector_with(&models, case, v)
                .unwrap()
                .detect(&frame, &FuseParams::default())
                .unwrap()
        };
        let (plain, voted) = (run(Voting::Off), run(Voting::Iou(0.5)));
        assert!(!plain.is_empty(), "{case}: no detections to vote on");
        assert_eq!(plain.len(), voted.len(), "{case}: voting keeps NMS's choice");
        let mut moved = 0;
        for (p, v) in plain.iter().zip(&voted) {
            assert_eq!((p.score, &p.category), (v.score, &v.category), "{case}");
            let d = (0..3)
                .map(|j| (p.box3d.center[j] - v.box3d.center[j]).powi(2))
                .sum::<f64>()
                .sqrt();
            // Only boxes overlapping the kept one by BEV IoU ≥ 0.5 vote: the mean stays well
            // inside the kept footprint.
            assert!(
                d < 0.5 * p.box3d.size_lwh[0],
                "{case}: a voted box moved {d} m: {p:?} -> {v:?}"
            );
            moved += usize::from(p.box3d != v.box3d);
        }
        assert!(moved > 0, "{case}: voting changed no box");
    }
}

#[test]
fn the_union_case_refines_both_views_proposals() {
    let models = default_models_dir();
    let manifest = Manifest::load(&models).unwrap();
    let ds = Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
    let frame = ds.frame(ds.first_sample_token().unwrap()).unwrap();
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(0.1, 2).unwrap(),
        ..Default::default()
    };
    let m = mlod::cases::load_mlod(&models, Case::MlodU, Default::default()).unwrap();
    let run = m.run(&frame, &params).unwrap();
    let top = load_detector(&models, Case::Top)
        .unwrap()
        .detect(&frame, &params)
        .unwrap();
    let input = load_detector(&models, Case::Input)
        .unwrap()
        .detect(&frame, &params)
        .unwrap();
    assert!(!top.is_empty() && !input.is_empty());
    let union = mlod::cases::union::union_of(&[&top, &input]);
    assert_eq!(run.proposals, union);
    assert!(!run.refined.is_empty() && run.refined.len() < union.len());
    // The union's NMS: the manifest's choice (`mlod train tune-refiner`), else the default.
    let iou = manifest
        .refine
        .as_ref()
        .and_then(|r| r.union_nms_iou)
        .unwrap_or(mlod::cases::union::UNION_NMS_IOU);
    for (i, a) in run.refined.iter().enumerate() {
        for b in &run.refined[i + 1..] {
            let o = mlod::geometry::iou_3d(&a.detection.box3d, &b.detection.box3d);
            assert!(o <= iou + 1e-9, "two refined boxes overlap by {o}");
        }
    }
    assert_eq!(m.refiner().decoding.nms_iou, Some(iou));
}
