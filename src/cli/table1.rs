//! `mlod table1`: the paper's Table I — every stage-1 case over a split, car AP_3D.

use std::path::PathBuf;

use anyhow::{bail, Result};

use super::args::parse_unit;
use super::detect::DetectorRun;
use super::eval::{detect_case, evaluated_tokens};

#[derive(clap::Args)]
pub struct Table1Args {
    /// A Lyft-format dataset (the held-out test split).
    #[arg(long)]
    dataset: PathBuf,
    /// Only these cases (comma separated; default: the six stage-1 cases, and MLOD-I/F/R when the
    /// models folder has a refiner).
    #[arg(long, value_delimiter = ',')]
    cases: Vec<mlod::detect::Case>,
    /// Evaluate only the first N samples.
    #[arg(long)]
    samples: Option<usize>,
    /// Only the validation scenes of a training dataset (every 10th scene: the split training
    /// holds out), for tuning a setting without touching the test split.
    #[arg(long)]
    validation: bool,
    #[command(flatten)]
    run: DetectorRun,
    /// Write every case's whole evaluation report here as JSON (atomically).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Record each trained model's figures as `test_ap` in the models' manifest.json.
    #[arg(long)]
    update_manifest: bool,
    /// Also print each case's car recall per BEV range band: the bands' upper edges in m,
    /// increasing (e.g. 10,20,30 for 0–10, 10–20, 20–30 m).
    #[arg(long, value_delimiter = ',')]
    recall_bands: Vec<f64>,
    /// 3D IoU at which a car counts as found in the recall table.
    #[arg(long, default_value_t = 0.7, value_parser = parse_unit)]
    recall_iou: f64,
    /// Also print car moderate AP_3D@0.7 with parts of the boxes matched at 3D IoU ≥ 0.5 within
    /// 30 m (size, yaw, z/h, x/y, the whole box) taken from the truth (as `eval --attribution`).
    #[arg(long)]
    attribution: bool,
}

pub fn table1_cmd(args: Table1Args) -> Result<()> {
    use mlod::detect::Case;
    let bands = &args.recall_bands;
    if bands.iter().any(|b| !b.is_finite() || *b <= 0.0) || bands.windows(2).any(|w| w[1] <= w[0]) {
        bail!("--recall-bands must be positive and increasing, got {bands:?}");
    }
    let dataset = super::open_dataset(&args.dataset)?;
    let opts = mlod::eval::EvalOptions {
        samples: args.samples,
        validation_only: args.validation,
        per_box: bands.last().map(|&max_range| mlod::eval::MatchRule {
            iou_threshold: args.recall_iou,
            kind: mlod::geometry::IouKind::ThreeD,
            max_range,
        }),
        ..Default::default()
    };
    let tokens = evaluated_tokens(&dataset, &args.dataset, &opts)?;
    let models = args.run.models_dir();
    args.run.fuse_params()?; // an absurd α is refused before any sample runs
    let cases = if args.cases.is_empty() {
        // The MLOD rows join when the models folder has a refiner.
        let refiner = mlod::detect::Manifest::load(&models).is_ok_and(|m| m.refiner.is_some());
        if refiner {
            Case::EVERY.to_vec()
        } else {
            Case::ALL.to_vec()
        }
    } else {
        args.cases.clone()
    };
    let mut reports = serde_json::Map::new();
    let mut rows = Vec::new();
    let mut recalls = Vec::new();
    let mut attributions = Vec::new();
    for case in cases {
        let start = std::time::Instant::now();
        let dets = detect_case(&dataset, &tokens, &args.run, case)?;
        let mut report = mlod::eval::evaluate_detections(&dataset, &dets, &opts)?;
        if args.attribution {
            let att_opts = mlod::eval::EvalOptions {
                per_box: Some(mlod::eval::MatchRule {
                    iou_threshold: 0.5,
                    kind: mlod::geometry::IouKind::ThreeD,
                    max_range: 30.0,
                }),
                attribution: true,
                ..opts.clone()
            };
            let att = mlod::eval::evaluate_detections(&dataset, &dets, &att_opts)?.attribution;
            attributions.push((
                case,
                att.iter()
                    .flatten()
                    .map(|a| (a.fixed, mlod::eval::kitti::car_moderate_07(&a.kitti)))
                    .collect::<Vec<_>>(),
            ));
            report.attribution = att;
        }
        let cell = |t: &str, d: &str| mlod::eval::kitti::ap_cell(&report.kitti, "car", t, d);
        let figures: Vec<(String, Option<f64>)> = ["iou_0.7", "iou_0.5"]
            .iter()
            .flat_map(|t| ["easy", "moderate", "hard"].map(|d| (format!("{d}_ap3d_{}", &t[4..]), cell(t, d))))
            .collect();
        eprintln!(
            "{}: {} samples in {:.0} s",
            case.paper_name(),
            report.samples,
            start.elapsed().as_secs_f64()
        );
        let recall = report
            .per_box
            .as_deref()
            .map(|pb| mlod::eval::recall_by_range(pb, "car", bands))
            .unwrap_or_default();
        recalls.push((case, recall));
        rows.push((case, figures));
        reports.insert(case.as_str().to_string(), serde_json::to_value(&report)?);
    }
    println!(
        "Car AP_3D (%), R40, {} samples of {}, α = {}",
        tokens.len(),
        args.dataset.display(),
        args.run.alpha
    );
    println!();
    println!("| Method | Easy@0.7 | Mod.@0.7 | Hard@0.7 | Easy@0.5 | Mod.@0.5 | Hard@0.5 |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for (case, figures) in &rows {
        let cells: Vec<String> = figures
            .iter()
            .map(|(_, v)| v.map_or_else(|| "–".to_string(), |x| format!("{x:.2}")))
            .collect();
        println!("| {} | {} |", case.paper_name(), cells.join(" | "));
    }
    if !bands.is_empty() {
        println!();
        println!(
            "Cars found at 3D IoU ≥ {} (any score), by BEV range",
            args.recall_iou
        );
        println!();
        let heads: Vec<String> = std::iter::once(0.0)
            .chain(bands.iter().copied())
            .collect::<Vec<f64>>()
            .windows(2)
            .map(|w| format!("{}–{} m", w[0], w[1]))
            .collect();
        println!("| Method | {} |", heads.join(" | "));
        println!("|---|{}", "---:|".repeat(heads.len()));
        for (case, recall) in &recalls {
            let cells: Vec<String> = recall
                .iter()
                .map(|&(n, found)| match n {
                    0 => "–".to_string(),
                    n => format!("{:.1} % ({found}/{n})", 100.0 * found as f64 / n as f64),
                })
                .collect();
            println!("| {} | {} |", case.paper_name(), cells.join(" | "));
        }
    }
    if let Some((_, first)) = attributions.first() {
        println!();
        println!(
            "Car AP_3D mod.@0.7 with the boxes matched at 3D IoU ≥ 0.5 (< 30 m) given part of the truth"
        );
        println!();
        let heads: Vec<&str> = first.iter().map(|(f, _)| f.label()).collect();
        println!("| Method | {} |", heads.join(" | "));
        println!("|---|{}", "---:|".repeat(heads.len()));
        for (case, row) in &attributions {
            let cells: Vec<String> = row
                .iter()
                .map(|(_, v)| v.map_or_else(|| "–".to_string(), |x| format!("{x:.2}")))
                .collect();
            println!("| {} | {} |", case.paper_name(), cells.join(" | "));
        }
    }
    if let Some(out) = &args.out {
        let doc = serde_json::json!({
            "dataset": args.dataset,
            "samples": tokens.len(),
            "alpha": args.run.alpha,
            "seed": args.run.seed,
            "reports": reports,
        });
        mlod::io::write_atomic(
            out,
            format!("{}\n", serde_json::to_string_pretty(&doc)?).as_bytes(),
        )?;
    }
    if args.update_manifest {
        let mut manifest = mlod::detect::Manifest::load(&models)?;
        for (case, figures) in &rows {
            if case.is_mlod() {
                let entry = if case.refiner_sees_trace() {
                    manifest.refiner.as_mut()
                } else {
                    manifest.refiner_notrace.as_mut()
                };
                if let Some(entry) = entry {
                    for (k, v) in figures {
                        match v {
                            Some(v) => entry.test_ap.insert(format!("{case}/{k}"), *v),
                            None => entry.test_ap.remove(&format!("{case}/{k}")),
                        };
                    }
                }
                continue;
            }
            if let Some(entry) = manifest.models.get_mut(case) {
                entry.test_ap = figures
                    .iter()
                    .filter_map(|(k, v)| v.map(|v| (k.clone(), v)))
                    .collect();
            }
        }
        manifest.save(&models)?;
        eprintln!("test_ap recorded in {}", models.join("manifest.json").display());
    }
    Ok(())
}
