//! Training tests on sample_data's first samples with the shipped Input Fusion: the database,
//! a loss that falls, a resume that is bit-identical, and the folded network against candle's.

use crate::detect::Case;
use crate::refine::infer::FastRefiner;
use crate::refine::Refiner;
use crate::train::proposals::{build, DatabaseConfig};
use crate::train::refiner::*;

fn sample_data() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data"))
}

fn models() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/models"))
}

fn small(cfg: &mut RefineTrainConfig) {
    cfg.batch = 8;
    cfg.positives = 4;
    cfg.model.gather.points = 128;
    cfg.model.point_mlp = vec![16, 32];
    cfg.model.head = vec![32];
    cfg.model.proposal_width = 8;
    cfg.warmup = 1;
    cfg.lr = 3e-3;
    cfg.checkpoint_every_s = 1e9;
}

fn database(dir: &std::path::Path) -> PathBuf {
    let db = dir.join("db");
    let n = build(
        &DatabaseConfig {
            dataset: sample_data(),
            models: models(),
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
    assert_eq!(n, 2, "one entry per sample and case");
    db
}

fn weights(path: &std::path::Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}

#[test]
fn a_few_steps_lower_the_loss_and_a_resume_is_bit_identical() {
    let dir = std::env::temp_dir().join(format!("mlod-refine-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let db = database(&dir);
    let entries = load(&db).unwrap();
    assert!(entries
        .iter()
        .all(|e| !e.boxes.is_empty() && e.case == Case::Input));
    // Rebuilding finds every shard present and changes nothing.
    let before = std::fs::read(db.join("shard-00000.json")).unwrap();
    database(&dir);
    assert_eq!(std::fs::read(db.join("shard-00000.json")).unwrap(), before);

    let mut cfg = RefineTrainConfig::new(sample_data(), db.clone(), dir.join("a/refiner.safetensors"));
    small(&mut cfg);
    cfg.steps = 12;
    cfg.seed = 5;
    // The loss of one fixed batch before and after training.
    let dataset = Dataset::open(sample_data()).unwrap();
    let batch = make_batch(&cfg, &dataset, &entries[0], 0)
        .unwrap()
        .expect("a labelled proposal");
    let fixed_loss = |net: &RefinerNet| -> f32 {
        let out = net
            .forward_t(&batch.points, batch.targets.len(), 128, &batch.props, false)
            .unwrap();
        loss(&out, &batch.targets, &batch.max_trace)
            .unwrap()
            .total
            .to_scalar()
            .unwrap()
    };
    let (fresh, _) = RefinerNet::trainable(&cfg.model, cfg.seed).unwrap();
    let first = fixed_loss(&fresh);
    let straight = train_refiner(&cfg, |_| {}).unwrap();
    assert_eq!(straight.steps, 12);
    let w = read_weights(&cfg.out, None).unwrap();
    let trained = Refiner::from_tensors(
        cfg.model.clone(),
        &|n| w.tensors.get(n).cloned(),
        Default::default(),
    )
    .unwrap();
    let vb = candle_nn::VarBuilder::from_tensors(w.tensors.clone(), candle_core::DType::F32, &Device::Cpu);
    let net = RefinerNet::new(&cfg.model, vb).unwrap();
    let last = fixed_loss(&net);
    assert!(last < first, "loss on a fixed batch {first} -> {last}");
    // The manifest beside the weights records the refiner with its command and seed.
    let m = Manifest::load(cfg.out.parent().unwrap()).unwrap();
    let e = m.refiner.expect("refiner entry");
    assert_eq!(
        (e.seed, e.steps, e.sha256.as_str()),
        (5, 12, straight.sha256.as_str())
    );

    // Killed after 5 steps, resumed: the same bytes.
    let mut cut = cfg.clone();
    cut.out = dir.join("b/refiner.safetensors");
    cut.checkpoint = dir.join("b/refiner.ckpt.safetensors");
    cut.loss_csv = dir.join("b/refiner.loss.csv");
    cut.stop_after = Some(5);
    assert!(train_refiner(&cut, |_| {}).is_err());
    assert!(!cut.out.exists() && cut.checkpoint.exists());
    cut.stop_after = None;
    cut.resume = true;
    let resumed = train_refiner(&cut, |_| {}).unwrap();
    assert_eq!(resumed.sha256, straight.sha256);
    assert_eq!(weights(&cut.out), weights(&cfg.out));
    let rows = |p: &std::path::Path| -> Vec<String> {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .map(|l| l.rsplit_once(',').unwrap().0.to_string())
            .collect()
    };
    assert_eq!(
        rows(&cut.loss_csv),
        rows(&cfg.loss_csv),
        "the loss curve without the time column"
    );

    // The folded network computes what candle's computes (evaluation mode).
    let props = batch.props.clone();
    let b = batch.targets.len();
    let out = net.forward_t(&batch.points, b, 128, &props, false).unwrap();
    let cls: Vec<f32> = out.cls.to_vec1().unwrap();
    let reg: Vec<Vec<f32>> = out.reg.to_vec2().unwrap();
    let fast = FastRefiner::build(&cfg.model, &|n| w.tensors.get(n).cloned()).unwrap();
    let rows_all: Vec<f32> = batch.points.flatten_all().unwrap().to_vec1().unwrap();
    let props_all: Vec<f32> = props.flatten_all().unwrap().to_vec1().unwrap();
    let ch = cfg.model.gather.features.channels();
    for i in 0..b {
        let mut p = [0f32; PROPOSAL_FEATURES];
        p.copy_from_slice(&props_all[i * PROPOSAL_FEATURES..(i + 1) * PROPOSAL_FEATURES]);
        let r = fast
            .run(&rows_all[i * 128 * ch..(i + 1) * 128 * ch], 128, &p)
            .unwrap();
        assert!(
            (r.logit - cls[i]).abs() < 1e-4 * (1.0 + cls[i].abs()),
            "{} vs {}",
            r.logit,
            cls[i]
        );
        for (a, b) in r.residuals.iter().zip(&reg[i]) {
            assert!((a - b).abs() < 1e-4 * (1.0 + b.abs()), "{a} vs {b}");
        }
        assert_eq!(r.argmax.len(), 32);
    }
    // A refiner on a real frame: every car proposal refined, active points among its gathered ones.
    let frame = dataset.frame(&entries[0].sample).unwrap();
    let cloud = fuse(&frame, &entries[0].fuse_params().unwrap()).unwrap();
    let proposals = entries[0].detections();
    let refined = trained.refine(&cloud, &proposals).unwrap();
    assert_eq!(refined.len(), proposals.len());
    assert!(refined.iter().any(|r| !r.unrefined && !r.active.is_empty()));
    for r in &refined {
        assert!(r.detection.box3d.is_valid() && (0.0..=1.0).contains(&r.detection.score));
        assert!(r.active.len() <= 32 && r.active.iter().all(|&k| (k as usize) < cloud.len()));
    }

    // The ablation's refiner (`--no-trace`) goes to the manifest's `refiner_notrace`, beside the
    // traced one, and only mlod-i-notrace loads it.
    let mut nt = cfg.clone();
    nt.steps = 2;
    nt.out = dir.join("a/refiner-notrace.safetensors");
    nt.checkpoint = dir.join("a/refiner-notrace.ckpt.safetensors");
    nt.loss_csv = dir.join("a/refiner-notrace.loss.csv");
    nt.model.gather.features.trace = false;
    let nts = train_refiner(&nt, |_| {}).unwrap();
    let folder = nt.out.parent().unwrap();
    let m = Manifest::load(folder).unwrap();
    assert_eq!(
        m.refiner.as_ref().map(|e| e.sha256.as_str()),
        Some(straight.sha256.as_str())
    );
    assert_eq!(
        m.refiner_notrace.as_ref().map(|e| e.sha256.as_str()),
        Some(nts.sha256.as_str())
    );
    let plain = Refiner::load_shipped_for(folder, Case::MlodI).unwrap();
    let blind = Refiner::load_shipped_for(folder, Case::MlodINoTrace).unwrap();
    assert!(plain.config.gather.features.trace && !blind.config.gather.features.trace);
    assert_eq!(blind.config.gather.features.channels(), 3);
    assert_eq!(blind.refine(&cloud, &proposals).unwrap().len(), proposals.len());
    // Entries swapped by hand: each case refuses a refiner of the other kind, naming the file.
    let mut swapped = m.clone();
    std::mem::swap(&mut swapped.refiner, &mut swapped.refiner_notrace);
    swapped.save(folder).unwrap();
    let e = Refiner::load_shipped_for(folder, Case::MlodINoTrace)
        .unwrap_err()
        .to_string();
    assert!(e.contains("refiner.safetensors") && e.contains("tr(Ξ)"), "{e}");
    assert!(Refiner::load_shipped_for(folder, Case::MlodI).is_err());
    // No ablation refiner: the error says how to train one.
    let mut none = m;
    none.refiner_notrace = None;
    none.save(folder).unwrap();
    let e = Refiner::load_shipped_for(folder, Case::MlodINoTrace)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--no-trace"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_settings_and_a_missing_database_are_errors() {
    let dir = std::env::temp_dir().join(format!("mlod-refine-bad-{}", std::process::id()));
    let mut cfg = RefineTrainConfig::new(sample_data(), dir.join("nothing"), dir.join("r.safetensors"));
    let e = train_refiner(&cfg, |_| {}).unwrap_err().to_string();
    assert!(e.contains("nothing") && e.contains("mlod train proposals"), "{e}");
    cfg.batch = 0;
    assert!(train_refiner(&cfg, |_| {}).is_err());
    // A corrupt shard names its file.
    std::fs::create_dir_all(dir.join("db")).unwrap();
    std::fs::write(dir.join("db/shard-00000.json"), br#"[{"sample": 3}]"#).unwrap();
    let e = load(&dir.join("db")).unwrap_err().to_string();
    assert!(e.contains("shard-00000.json"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_database_takes_the_certain_points_cases_and_refuses_refined_ones() {
    let dir = std::env::temp_dir().join(format!("mlod-refine-db-drop-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = |cases: Vec<Case>| DatabaseConfig {
        dataset: sample_data(),
        models: models(),
        out: dir.join("db"),
        cases,
        draws: 1,
        seed: 3,
        zero_share: 0.0,
        max_samples: 1,
    };
    assert_eq!(
        build(&cfg(vec![Case::InputDrop, Case::ResultDrop]), |_, _| {}).unwrap(),
        2
    );
    let entries = load(&dir.join("db")).unwrap();
    assert_eq!(
        entries.iter().map(|e| e.case).collect::<Vec<_>>(),
        [Case::InputDrop, Case::ResultDrop]
    );
    assert!(entries.iter().all(|e| e.alpha > 0.0));
    let err = build(&cfg(vec![Case::MlodIrDrop]), |_, _| {}).unwrap_err();
    assert!(err.to_string().contains("stage-1"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_iou_score_is_refused_on_the_slow_autograd_path_before_any_work() {
    let mut cfg = RefineTrainConfig::new(
        PathBuf::from("/nonexistent/dataset"),
        PathBuf::from("/nonexistent/db"),
        PathBuf::from("/nonexistent/refiner.safetensors"),
    );
    cfg.model.iou_score = true;
    cfg.slow_autograd = true;
    let err = train_refiner(&cfg, |_| {}).unwrap_err();
    assert!(err.to_string().contains("native trainer only"), "{err}");
    // On the native path the same configuration gets as far as the missing dataset.
    cfg.slow_autograd = false;
    let err = train_refiner(&cfg, |_| {}).unwrap_err();
    assert!(!err.to_string().contains("native trainer only"), "{err}");
}
