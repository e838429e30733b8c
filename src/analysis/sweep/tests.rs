use std::path::PathBuf;
use std::sync::OnceLock;

use crate::analysis::sweep::*;
use crate::detect::weights::default_models_dir;

fn dataset() -> &'static Dataset {
    static DS: OnceLock<Dataset> = OnceLock::new();
    DS.get_or_init(|| Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap())
}

fn config() -> SweepConfig {
    let all: Vec<String> = dataset().sample_tokens().iter().map(|s| s.to_string()).collect();
    SweepConfig {
        cases: vec![
            Case::Top,
            Case::Input,
            Case::MlodI,
            Case::InputOc,
            Case::InputDrop,
            Case::MlodU,
            Case::MlodIrDrop,
        ],
        alphas: vec![0.1],
        trials: 2,
        seed: 3,
        draw: Draw::OneCar,
        oc_prior: OcPrior::Icp,
        samples: spread_samples(&all, Some(2)),
        assumed_alpha: None,
        drop_trace: Some(0.1),
        detectors: Default::default(),
    }
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlod-sweep-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Runs the sweep into `dir` on `threads` threads (stopping after `stop` units if given) and, once
/// complete, writes its outputs.
fn sweep(dir: &std::path::Path, threads: usize, shard: Shard, stop: Option<usize>) -> usize {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let n = run(
            dataset(),
            &default_models_dir(),
            &config(),
            dir,
            shard,
            stop,
            &|_, _| {},
        )
        .unwrap();
        if let Ok(rows) = collect(dir, &config()) {
            write_outputs(dir, &config(), &rows).unwrap();
        }
        n
    })
}

/// The uninterrupted one-thread sweep every other is compared with.
fn reference() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = tmp("reference");
        assert_eq!(
            sweep(&d, 1, Shard::default(), None),
            13,
            "top once, six cases twice"
        );
        d
    })
}

fn files(dir: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in ["", UNITS_DIR] {
        let mut names: Vec<_> = std::fs::read_dir(dir.join(sub))
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_file())
            .map(|e| e.path())
            .collect();
        names.sort();
        for p in names {
            out.push((
                p.strip_prefix(dir).unwrap().display().to_string(),
                std::fs::read(&p).unwrap(),
            ));
        }
    }
    out
}

#[test]
fn killed_and_resumed_on_two_threads_equals_one_uninterrupted_run() {
    let d = tmp("resumed");
    assert_eq!(sweep(&d, 2, Shard::default(), Some(3)), 3);
    assert!(collect(&d, &config()).is_err(), "stopped early");
    assert_eq!(
        sweep(&d, 2, Shard::default(), None),
        10,
        "only the missing units run again"
    );
    let (a, b) = (files(reference()), files(&d));
    assert_eq!(
        a.iter().map(|f| &f.0).collect::<Vec<_>>(),
        b.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for (x, y) in a.iter().zip(&b) {
        assert!(x.1 == y.1, "{} differs", x.0);
    }
    assert!(a.iter().any(|f| f.0 == "table.md") && a.iter().any(|f| f.0 == "ap_vs_alpha.png"));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn progress_reads_a_partial_and_a_finished_sweep() {
    let d = tmp("progress");
    assert_eq!(sweep(&d, 2, Shard::default(), Some(2)), 2);
    let p = progress(&d).unwrap();
    assert_eq!((p.rows.len(), p.total), (2, config().units().len()));
    assert_eq!(p.config, config());
    let points: usize = p.curves.iter().map(|c| c.1.len()).sum();
    assert!((1..=2).contains(&points), "{points} points from 2 units");
    // Finished: the curves are the plot's, one point per case at α = 0.1, averaging its trials.
    let full = progress(reference()).unwrap();
    assert_eq!(full.rows.len(), full.total);
    assert!(full.curves.iter().all(|c| c.1.len() == 1 && c.1[0].0 == 0.1));
    assert_eq!(full.trials(Case::Input, 0.1), 2);
    assert_eq!(full.trials(Case::Top, 0.1), 1, "LiDAR-Top needs one trial");
    let m = |c: Case| {
        full.rows
            .iter()
            .filter(|r| r.case == c)
            .filter_map(|r| r.moderate)
            .collect::<Vec<_>>()
    };
    let input = m(Case::Input);
    let want = (input[0] + input[1]) / 2.0;
    let got = full.curves.iter().find(|c| c.0 == "Input Fusion").unwrap().1[0].1;
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    // Not a sweep folder: an error naming the file.
    let e = progress(&d.join("nothing")).unwrap_err().to_string();
    assert!(e.contains("config.json"), "{e}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn two_shards_merged_equal_one_run_and_a_missing_shard_is_refused() {
    let (s0, s1, m) = (tmp("shard0"), tmp("shard1"), tmp("merged"));
    sweep(&s0, 2, Shard { index: 0, count: 2 }, None);
    sweep(&s1, 2, Shard { index: 1, count: 2 }, None);
    let err = merge(&tmp("half"), std::slice::from_ref(&s0))
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing"), "{err}");
    merge(&m, &[s0.clone(), s1.clone()]).unwrap();
    assert!(files(reference()) == files(&m), "the merge differs from one run");
    for d in [s0, s1, m] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn another_configuration_in_the_same_folder_is_refused() {
    let dir = reference();
    let other = SweepConfig {
        trials: 3,
        ..config()
    };
    let err = run(
        dataset(),
        &default_models_dir(),
        &other,
        dir,
        Shard::default(),
        None,
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("another trials"), "{err}");
    let bad = SweepConfig {
        alphas: vec![f64::NAN],
        ..config()
    };
    assert!(bad.validate().is_err());
    assert!("2/2".parse::<Shard>().is_err() && "1/0".parse::<Shard>().is_err());
    assert_eq!("1/3".parse::<Shard>(), Ok(Shard { index: 1, count: 3 }));
}

#[test]
fn a_cell_is_what_eval_gives_for_that_case_alpha_and_seed() {
    let rows = collect(reference(), &config()).unwrap();
    let params = FuseParams {
        perturbation: Perturbation::new(0.1, 4).unwrap(),
        ..Default::default()
    };
    let opts = EvalOptions {
        only: Some(config().samples),
        ..Default::default()
    };
    // `mlod eval --case CASE --alpha 0.1 --seed 4` on the same samples (the drop cases with
    // `--drop-trace 0.1`), against the sweep's trial-1 cell.
    for case in [Case::MlodI, Case::InputDrop, Case::MlodU, Case::MlodIrDrop] {
        let det = crate::cases::load_detector(&default_models_dir(), case, Voting::Manifest).unwrap();
        let dets: HashMap<String, Vec<Detection>> = config()
            .samples
            .iter()
            .map(|t| {
                (
                    t.clone(),
                    det.detect(&dataset().frame(t).unwrap(), &params).unwrap(),
                )
            })
            .collect();
        let report = evaluate_detections(dataset(), &dets, &opts).unwrap();
        let cell = rows.iter().find(|r| r.case == case && r.trial == 1).unwrap();
        assert_eq!(
            cell.moderate,
            crate::eval::kitti::car_moderate_07(&report.kitti),
            "{case}"
        );
    }
    // LiDAR-Top ran once per α.
    assert_eq!(rows.iter().filter(|r| r.case == Case::Top).count(), 1);
}

#[test]
fn an_assumed_alpha_reaches_the_prior_and_leaves_old_configurations_readable() {
    let cfg = config();
    let json = serde_json::to_value(&cfg).unwrap();
    assert!(
        json.get("assumed_alpha").is_none(),
        "a sweep without it keeps its old config.json"
    );
    assert_eq!(cfg.fuse_params(0.1, 1, 0).unwrap().effective_prior_alpha(), 0.1);
    let mis = SweepConfig {
        assumed_alpha: Some(0.02),
        ..config()
    };
    let p = mis.fuse_params(0.1, 1, 0).unwrap();
    assert_eq!((p.perturbation.alpha, p.effective_prior_alpha()), (0.1, 0.02));
    assert_ne!(serde_json::to_value(&mis).unwrap(), json);
    let per_sample = SweepConfig {
        draw: Draw::PerSample,
        ..config()
    };
    let seeds: Vec<u64> = (0..3)
        .map(|j| per_sample.perturbation(0.1, 1, j).unwrap().seed)
        .collect();
    assert!(seeds[0] != seeds[1] && seeds[1] != seeds[2]);
    assert_eq!(
        config().perturbation(0.1, 1, 7).unwrap().seed,
        4,
        "one car: seed S + k"
    );
}
