//! `mlod eval`: score predictions (a file, or a shipped detector run over the samples) against a
//! dataset's ground truth.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use super::args::parse_unit;
use super::detect::DetectorRun;

#[derive(clap::Args)]
pub struct EvalArgs {
    /// A Lyft-format dataset (root or version folder).
    #[arg(long)]
    dataset: PathBuf,
    /// Predictions: a JSON list in the Lyft devkit format (sample_token, translation [global],
    /// size [w,l,h], rotation [w,x,y,z], name, score).
    #[arg(long, required_unless_present = "case", conflicts_with = "case")]
    pred: Option<PathBuf>,
    /// Instead of --pred: run this case over the samples (a shipped detector, or ext:NAME /
    /// mlod-ext:NAME with --detector; docs/external.md).
    #[arg(long)]
    case: Option<mlod::detect::Case>,
    // With --case: the perturbation and the models folder.
    #[command(flatten)]
    run: DetectorRun,
    /// Evaluate only the first N samples of the dataset.
    #[arg(long)]
    samples: Option<usize>,
    /// Only the validation scenes of a training dataset (every 10th scene: the split training
    /// holds out), for tuning a setting without touching the test split.
    #[arg(long)]
    validation: bool,
    /// KITTI recall points: r40 (default) or r11.
    #[arg(long, default_value = "r40", value_parser = ["r40", "r11"])]
    interpolation: String,
    /// Add every box's outcome (TP with its GT, IoU and residuals, FP, miss) to the JSON, and a
    /// localisation summary of the matches (mean |residual| and size correlation per class).
    #[arg(long)]
    per_box: bool,
    /// With --per-box: AP again with each part of the matched predictions (size, x/y, z/h, yaw,
    /// the whole box) taken from their ground truth: which residual costs how much AP.
    #[arg(long, requires = "per_box")]
    attribution: bool,
    /// IoU threshold of the per-box outcomes (3D IoU, ≥).
    #[arg(long, default_value_t = 0.7, value_parser = parse_unit)]
    match_iou: f64,
    /// Range of the per-box outcomes (m): boxes farther from the base origin are ignored.
    #[arg(long, default_value_t = 50.0)]
    match_range: f64,
    /// With --case: one perturbation trial per seed (instead of --seed), and car moderate
    /// AP_3D@0.7 per trial with its mean ± standard deviation (comma separated, e.g. 0,1,2,3,4).
    #[arg(long, value_delimiter = ',', requires = "case", conflicts_with_all = ["per_box", "pred"])]
    seeds: Vec<u64>,
    /// Also the transfer check of real frames (docs/realism.md): cars within 50 m found by a
    /// prediction scoring ≥ 0.3 with its BEV centre within 2 m, AP over such matches,
    /// confident false positives (nothing within 2 m) per frame, cars found at 3D IoU ≥ 0.5.
    #[arg(long)]
    transfer: bool,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
    /// Also write the JSON to this file (atomically).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// The samples `opts` evaluates; an error naming the dataset when it asks for the validation
/// scenes and there are none.
pub fn evaluated_tokens(
    dataset: &mlod::dataset::Dataset,
    path: &std::path::Path,
    opts: &mlod::eval::EvalOptions,
) -> Result<Vec<String>> {
    let tokens = mlod::eval::sample_tokens(dataset, opts);
    if opts.validation_only && tokens.is_empty() {
        bail!(
            "{}: no validation samples (the validation split is every 10th scene)",
            path.display()
        );
    }
    Ok(tokens)
}

/// Runs a shipped detector over `tokens` (samples in parallel) with a progress bar: its
/// detections per sample.
pub fn detect_case(
    dataset: &mlod::dataset::Dataset,
    tokens: &[String],
    run: &DetectorRun,
    case: mlod::detect::Case,
) -> Result<std::collections::HashMap<String, Vec<mlod::detect::Detection>>> {
    let detector = run.load(case)?;
    let bar = indicatif::ProgressBar::new(tokens.len() as u64);
    let (dets, notes) = run
        .options()
        .detect_samples(dataset, tokens, detector.as_ref(), case, &|| bar.inc(1))?;
    bar.finish_and_clear();
    if let Some(note) = notes.first {
        eprintln!(
            "note: {} of {} samples lack LiDARs the case reads; {note}",
            notes.lacking,
            tokens.len()
        );
    }
    Ok(dets)
}

/// Runs a shipped detector over `tokens` and evaluates it.
pub fn run_case(
    dataset: &mlod::dataset::Dataset,
    tokens: &[String],
    run: &DetectorRun,
    case: mlod::detect::Case,
    opts: &mlod::eval::EvalOptions,
) -> Result<mlod::eval::EvalReport> {
    let dets = detect_case(dataset, tokens, run, case)?;
    Ok(mlod::eval::evaluate_detections(dataset, &dets, opts)?)
}

pub fn eval_cmd(args: EvalArgs) -> Result<()> {
    use mlod::eval::{EvalOptions, Interpolation, MatchRule};
    if args.match_range.is_nan() || args.match_range <= 0.0 {
        bail!("--match-range must be positive, got {}", args.match_range);
    }
    let dataset = super::open_dataset(&args.dataset)?;
    let mut opts = EvalOptions {
        samples: args.samples,
        validation_only: args.validation,
        transfer: args.transfer.then(mlod::eval::TransferRule::default),
        ..Default::default()
    };
    if args.interpolation == "r11" {
        opts.kitti.interpolation = Interpolation::R11;
    }
    if args.per_box {
        opts.per_box = Some(MatchRule {
            iou_threshold: args.match_iou,
            max_range: args.match_range,
            ..Default::default()
        });
        opts.attribution = args.attribution;
    }
    let tokens = evaluated_tokens(&dataset, &args.dataset, &opts)?;
    let Some(pred_path) = &args.pred else {
        let case = args.case.context("give --pred FILE or --case CASE")?;
        super::stats::print_training_notes(&dataset, &args.run.models_dir());
        if !args.seeds.is_empty() {
            return trials(&args, &dataset, &tokens, case, &opts);
        }
        args.run.fuse_params()?; // an absurd α is refused before any sample runs
        let report = run_case(&dataset, &tokens, &args.run, case, &opts)?;
        return print_eval(&args, &report);
    };
    let known: std::collections::HashSet<&str> = tokens.iter().map(String::as_str).collect();
    let raw = mlod::eval::read_predictions(pred_path)?;
    let preds = mlod::eval::parse_predictions(&raw, &known);
    if !preds.rejected.is_empty() {
        eprintln!(
            "warning: {} of {} predictions in {} rejected and skipped; first:",
            preds.rejected.len(),
            preds.total,
            pred_path.display()
        );
        for r in preds.rejected.iter().take(5) {
            let tok = r.sample_token.as_deref().unwrap_or("?");
            eprintln!("  #{} (sample {tok}): {}", r.index, r.reason);
        }
    }
    let report = mlod::eval::evaluate(&dataset, &preds, &opts)?;
    print_eval(&args, &report)
}

pub fn print_eval(args: &EvalArgs, report: &mlod::eval::EvalReport) -> Result<()> {
    let json = serde_json::to_string_pretty(report)?;
    if let Some(out) = &args.out {
        mlod::io::write_atomic(out, format!("{json}\n").as_bytes())?;
    }
    if args.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "{} samples, {} predictions used ({} rejected)",
        report.samples, report.predictions.accepted, report.predictions.rejected
    );
    if report.predictions.outside_region > 0 {
        println!(
            "{} predictions outside the evaluated region (KITTI: camera 2's view, DontCare regions) ignored",
            report.predictions.outside_region
        );
    }
    println!("\nKITTI-style AP_3D (%), {} interpolation", args.interpolation);
    println!(
        "{:<20} {:>7} {:>7} {:>7}   {:>7} {:>7} {:>7}",
        "class", "easy", "mod.", "hard", "easy", "mod.", "hard"
    );
    println!("{:<20} {:^23}   {:^23}", "", "IoU >= 0.7", "IoU >= 0.5");
    let cell = |v: Option<&Option<f64>>| match v {
        Some(Some(x)) => format!("{x:>7.2}"),
        _ => format!("{:>7}", "-"),
    };
    // One class's easy / moderate / hard cells at threshold key `t`.
    let row = |per_t: &mlod::eval::kitti::Ordered<mlod::eval::kitti::Ordered<Option<f64>>>, t: &str| {
        let d = per_t.get(t);
        ["easy", "moderate", "hard"]
            .iter()
            .map(|k| cell(d.and_then(|d| d.get(k))))
            .collect::<Vec<_>>()
            .join(" ")
    };
    for (class, per_t) in &report.kitti.0 {
        println!(
            "{class:<20} {}   {}",
            row(per_t, "iou_0.7"),
            row(per_t, "iou_0.5")
        );
    }
    println!("\nLyft mAP (IoU > t)   devkit   exact footprint");
    for (t, m) in &report.lyft.per_threshold {
        let e = report
            .lyft_exact
            .per_threshold
            .get(t)
            .copied()
            .unwrap_or(f64::NAN);
        println!("  t = {t:<5}          {m:.4}   {e:.4}");
    }
    println!(
        "  mean                {:.4}   {:.4}",
        report.lyft.map, report.lyft_exact.map
    );
    if let Some(t) = &report.transfer {
        let p = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
        let r = &t.rule;
        println!(
            "\nTransfer check ({} within {} m; a match: BEV centre within {} m)",
            r.category, r.max_range, r.centre_dist
        );
        let iv = |i: Option<mlod::eval::transfer::Interval>, digits: usize| {
            i.map_or(String::new(), |i| {
                format!("  [{:.*}, {:.*}]", digits, i.lo, digits, i.hi)
            })
        };
        let ci = &t.intervals;
        println!(
            "  found with score >= {}        {} of {} ({} %){}",
            r.min_score,
            t.found,
            t.boxes,
            p(t.found_pct),
            iv(ci.found_pct, 1)
        );
        println!(
            "  AP over centre matches (R40)  {}{}",
            p(t.ap_centre),
            iv(ci.ap_centre, 1)
        );
        println!(
            "  confident false positives     {} in {} frames ({} per frame){}",
            t.confident_false_positives,
            t.frames,
            t.confident_false_positives_per_frame
                .map_or("-".to_string(), |v| format!("{v:.2}")),
            iv(ci.confident_false_positives_per_frame, 2)
        );
        println!(
            "  found at 3D IoU >= {}         {} of {} ({} %){}",
            r.iou,
            t.found_iou,
            t.boxes,
            p(t.found_iou_pct),
            iv(ci.found_iou_pct, 1)
        );
        println!(
            "  [90 % bootstrap intervals, {} resamples: shares over cars, AP and false positives over frames]",
            ci.resamples
        );
        println!(
            "\n  {:<28} {:>7} {:>7} {:>5} {:>6} {:>7} {:>6}  found",
            "frame", "range m", "points", "occl", "trunc", "best sc", "IoU"
        );
        let opt = |v: Option<String>| v.unwrap_or_else(|| "-".to_string());
        for c in &t.cars {
            let frame: String = c
                .frame
                .chars()
                .rev()
                .take(28)
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            println!(
                "  {:<28} {:>7.1} {:>7} {:>5} {:>6} {:>7} {:>6}  {}{}",
                frame,
                c.range_m,
                opt(c.info.points.map(|n| n.to_string())),
                opt(c.info.occlusion.map(|o| o.to_string())),
                opt(c.info.truncation.map(|v| format!("{v:.2}"))),
                opt(c.best_score.map(|v| format!("{v:.2}"))),
                opt(c.best_iou.map(|v| format!("{v:.2}"))),
                if c.found { "yes" } else { "no" },
                if c.found_iou { ", IoU" } else { "" }
            );
        }
    }
    if let Some(att) = &report.attribution {
        println!(
            "\nAP_3D (%) with the matched boxes (3D IoU >= {}, range < {} m) partly replaced by the truth",
            args.match_iou, args.match_range
        );
        println!(
            "{:<20} {:<14} {:>7} {:>7} {:>7}   {:>7} {:>7} {:>7}",
            "class", "boxes", "easy", "mod.", "hard", "easy", "mod.", "hard"
        );
        println!(
            "{:<20} {:<14} {:^23}   {:^23}",
            "", "", "IoU >= 0.7", "IoU >= 0.5"
        );
        let classes: Vec<&String> = att
            .first()
            .map(|a| a.kitti.0.iter().map(|(c, _)| c).collect())
            .unwrap_or_default();
        for class in classes {
            for a in att {
                let Some(per_t) = a.kitti.get(class) else { continue };
                println!(
                    "{class:<20} {:<14} {}   {}",
                    a.fixed.label(),
                    row(per_t, "iou_0.7"),
                    row(per_t, "iou_0.5")
                );
            }
        }
    }
    if let Some(loc) = &report.localization {
        println!(
            "\nLocalisation of the matches (3D IoU >= {}, range < {} m): mean |prediction - truth|",
            args.match_iou, args.match_range
        );
        println!(
            "{:<20} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}   size corr. l / w / h",
            "class", "matched", "along", "lateral", "z", "l", "w", "h", "yaw (°)"
        );
        let corr = |c: Option<f64>| c.map_or("-".to_string(), |c| format!("{c:.2}"));
        for l in loc {
            let e = &l.mean_abs;
            println!(
                "{:<20} {:>7} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.2}   {} / {} / {}",
                l.category,
                l.matched,
                e.along,
                e.lateral,
                e.dz,
                e.dl,
                e.dw,
                e.dh,
                e.dyaw.to_degrees(),
                corr(l.size_corr[0]),
                corr(l.size_corr[1]),
                corr(l.size_corr[2])
            );
        }
    }
    Ok(())
}

/// `eval --case C --alpha A --seeds …`: one perturbation trial per seed; car moderate AP_3D@0.7
/// per trial, its mean and (sample) standard deviation.
fn trials(
    args: &EvalArgs,
    dataset: &mlod::dataset::Dataset,
    tokens: &[String],
    case: mlod::detect::Case,
    opts: &mlod::eval::EvalOptions,
) -> Result<()> {
    let mut values = Vec::new();
    for &seed in &args.seeds {
        let run = DetectorRun {
            seed,
            models: args.run.models.clone(),
            external: args.run.external.clone(),
            ..args.run
        };
        let report = run_case(dataset, tokens, &run, case, opts)?;
        let ap =
            mlod::eval::kitti::car_moderate_07(&report.kitti).context("no car of moderate difficulty")?;
        eprintln!(
            "{} α {} seed {seed}: car moderate AP_3D@0.7 {ap:.2}",
            case.paper_name(),
            args.run.alpha
        );
        values.push(ap);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let std = if values.len() > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    let doc = serde_json::json!({
        "case": case.as_str(), "alpha": args.run.alpha, "seeds": args.seeds, "samples": tokens.len(),
        "car_moderate_ap3d_0.7": values, "mean": mean, "std": std,
    });
    if let Some(out) = &args.out {
        mlod::io::write_atomic(
            out,
            format!("{}\n", serde_json::to_string_pretty(&doc)?).as_bytes(),
        )?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        println!(
            "{}  α {}  {} trials  car moderate AP_3D@0.7 {mean:.2} ± {std:.2}",
            case.paper_name(),
            args.run.alpha,
            values.len()
        );
    }
    Ok(())
}
