//! `mlod synth` and `mlod inspect`: make a Lyft-format dataset with the simulator, look into one.

use std::path::PathBuf;

use anyhow::{bail, Result};

#[derive(clap::Args)]
pub struct SynthArgs {
    /// Output folder (the dataset root: v1.01-train/, lidar/, maps/).
    #[arg(long)]
    out: PathBuf,
    /// Number of scenes.
    #[arg(long, default_value_t = 1)]
    scenes: usize,
    /// Key frames per scene (0.2 s apart).
    #[arg(long, default_value_t = 10)]
    samples_per_scene: usize,
    /// Seed of everything generated (layout, motion, noise, tokens).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The world: `walled` (the default: the world the shipped models were trained in), `v4` or
    /// `v2` (see `mlod::synth::World`). The options below override the world's values.
    #[arg(long, default_value = "walled", value_parser = mlod::synth::World::parse)]
    world: mlod::synth::World,
    /// Sensor randomisation: each scene's roof LiDAR is one of these (comma separated:
    /// pandar40, pandar64, hdl64e, hdl32e, vls128; `all` for every one). v2: Lyft's Pandar40;
    /// v4, walled: all.
    #[arg(long, value_delimiter = ',', value_parser = parse_preset)]
    roof_sensors: Vec<Vec<mlod::synth::SensorPreset>>,
    /// Sensor randomisation: each scene's roof LiDAR mount raised or lowered by up to this (m;
    /// v2: 0, v4 and walled: 0.2).
    #[arg(long)]
    roof_height_jitter: Option<f64>,
    /// Car sizes: `uniform` (4.2–5.0 m long, one body shape; v2) or `mixed` (compacts, sedans,
    /// SUVs and pickups; mean near real Lyft's 4.75 × 1.92 × 1.71 m; v4, walled).
    #[arg(long, value_parser = ["uniform", "mixed"])]
    car_sizes: Option<String>,
    /// Intensity: `reflectance` (from the material and incidence, 0–255; v2) or `lyft` (100 for
    /// every point, as the real Lyft Level 5 files hold; v4, walled).
    #[arg(long, value_parser = ["reflectance", "lyft"])]
    intensity: Option<String>,
    /// Vehicle side glass: `opaque` (a dark surface; v2, v4), `see-through` (80 % of the beams
    /// pass it and return from the cabin's lower body, what stands behind the car or the ground)
    /// or `see-through-no-ground` (the same, but a beam through the glass that meets nothing else
    /// returns nothing; walled).
    #[arg(long, value_parser = ["opaque", "see-through", "see-through-no-ground"])]
    glass: Option<String>,
    /// Share (0–1) of the stretches between driveways lined by a wall or hedge right behind the
    /// curb, as on narrow streets where a car parks half a metre from a garden wall (v2, v4: 0;
    /// walled: 0.5).
    #[arg(long)]
    curb_walls: Option<f64>,
    /// Show a progress bar.
    #[arg(long)]
    progress: bool,
}

fn parse_preset(s: &str) -> Result<Vec<mlod::synth::SensorPreset>, String> {
    use mlod::synth::SensorPreset;
    if s.trim() == "all" {
        return Ok(SensorPreset::ALL.to_vec());
    }
    SensorPreset::parse(s).map(|p| vec![p]).ok_or_else(|| {
        let names: Vec<&str> = SensorPreset::ALL.iter().map(|p| p.name()).collect();
        format!("{s}: not a roof LiDAR (one of {}, or all)", names.join(", "))
    })
}

#[derive(clap::Args)]
pub struct InspectArgs {
    /// Dataset root or its version folder (e.g. v1.01-train).
    #[arg(long)]
    dataset: PathBuf,
    /// Sample token (default: the first sample in scene order).
    #[arg(long, conflicts_with = "list")]
    sample: Option<String>,
    /// List all samples with their LiDAR channels and box counts.
    #[arg(long)]
    list: bool,
    /// Trim .bin files whose size is not a multiple of 20 bytes (with a warning) instead of failing.
    #[arg(long)]
    lenient: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

pub fn synth(args: SynthArgs) -> Result<()> {
    // The world's configuration, then each option given on the command line over it.
    let mut cfg = args.world.config();
    cfg.seed = args.seed;
    cfg.scenes = args.scenes;
    cfg.samples_per_scene = args.samples_per_scene;
    if !args.roof_sensors.is_empty() {
        cfg.roof.presets = args.roof_sensors.iter().flatten().copied().collect();
    }
    if let Some(j) = args.roof_height_jitter {
        cfg.roof.height_jitter_m = j;
    }
    if let Some(c) = &args.car_sizes {
        cfg.car_sizes = if c == "mixed" {
            mlod::synth::CarSizes::Mixed
        } else {
            mlod::synth::CarSizes::Uniform
        };
    }
    if let Some(i) = &args.intensity {
        cfg.lidar.constant_intensity = (i == "lyft").then_some(100.0);
    }
    if let Some(g) = &args.glass {
        cfg.lidar.glass_pass = if g.starts_with("see-through") {
            mlod::synth::world::GLASS_PASS
        } else {
            0.0
        };
        cfg.lidar.glass_ground = g != "see-through-no-ground";
    }
    if let Some(w) = args.curb_walls {
        cfg.curb_walls = w;
    }
    let bar = args.progress.then(|| {
        let bar = indicatif::ProgressBar::new((args.scenes * args.samples_per_scene) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40.cyan/blue} {pos}/{len} samples  {elapsed_precise} (eta {eta})",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let start = std::time::Instant::now();
    let summary = mlod::synth::generate(&cfg, &args.out, |done, total| {
        if let Some(bar) = &bar {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    })?;
    if let Some(bar) = bar {
        bar.finish();
    }
    eprintln!(
        "wrote {} samples ({} scenes, {} annotations, {} points, {:.1} MB) to {} in {:.1} s",
        summary.samples,
        summary.scenes,
        summary.annotations,
        summary.points,
        summary.bytes as f64 / 1e6,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn inspect(args: InspectArgs) -> Result<()> {
    let dataset = super::open_dataset(&args.dataset)?;
    if args.list {
        let samples = mlod::dataset::list(&dataset);
        if args.json {
            println!("{}", serde_json::to_string_pretty(&samples)?);
        } else {
            for s in &samples {
                println!(
                    "{}  {}  {:>3} boxes  {}",
                    s.sample_token,
                    s.scene_name,
                    s.num_boxes,
                    s.lidar_channels.join(",")
                );
            }
        }
        return Ok(());
    }
    let opts = mlod::dataset::LoadOptions {
        lenient: args.lenient,
    };
    let report = mlod::dataset::inspect_with(&dataset, args.sample.as_deref(), opts)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("sample {}", report.sample_token);
        let format = dataset.format();
        if let Some(rig) = format.rig() {
            println!("  {rig}");
        }
        for l in &report.lidars {
            let n = l.num_points.map_or("-".to_string(), |n| n.to_string());
            let t = l.extrinsic.translation;
            let name = match mlod::dataset::LidarChannel::from_channel(&l.channel) {
                Some(ch) if format.rig().is_some() => format!("{} ({})", l.channel, format.lidar_name(ch)),
                _ => l.channel.clone(),
            };
            println!(
                "  {:<29} {:>7} points  t = ({:.3}, {:.3}, {:.3})  {}",
                name, n, t[0], t[1], t[2], l.file
            );
        }
        for b in &report.boxes {
            let c = b.center;
            println!(
                "  {:<12} centre ({:.2}, {:.2}, {:.2})  yaw {:.3}",
                b.category, c[0], c[1], c[2], b.yaw
            );
        }
    }
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if !report.is_complete() {
        for e in &report.errors {
            eprintln!("error: {e}");
        }
        bail!(
            "{} of the sample's LiDAR files could not be read",
            report.errors.len()
        );
    }
    Ok(())
}
