//! The `mlod` subcommands, one file per subcommand or group; `main.rs` parses and dispatches.
//! Every command takes its data from the library and only formats it (text, JSON, CSV, PNG).

pub mod adapt;
pub mod alignment;
pub mod analyze;
pub mod args;
pub mod calibrate;
pub mod chain;
pub mod data;
pub mod detect;
pub mod eval;
pub mod export;
pub mod external;
pub mod failures;
pub mod refine;
pub mod stats;
pub mod sweep;
pub mod table1;
pub mod train;
pub mod uncertainty;
pub mod window;

pub const MAIN_EXAMPLES: &str = "\
Examples:
  mlod                                                   open the debugger on sample_data/
  mlod gui --dataset ~/lyft/v1.01-train                  open your Lyft Level 5 copy
  mlod fuse --dataset sample_data --alpha 0.04 --seed 0  the numbers of the window's panels
  mlod export --dataset sample_data --alpha 0.04 --out cloud.ply
  mlod detect --dataset sample_data --case input --json
  mlod table1 --dataset data/test                        the paper's Table I

Every subcommand has examples under `mlod <subcommand> --help`.";

pub const CALIBRATE_EXAMPLES: &str = "\
Examples:
  mlod calibrate --dataset sample_data --alpha 0.1                     the first sample, one drift
  mlod calibrate --dataset data/test --alpha 0.1 --samples 20 --spread --per-sample
                                                                       accuracy over 20 samples
  mlod calibrate --dataset data/test --alpha 0.1 --samples 20 --spread --per-sample --json
  mlod calibrate --dataset sample_data --alpha 0.1 --dump icp-dump     the clouds, for Open3D
  mlod calibrate --dataset av2/sensor/val --samples 2 --alpha 0.1 --draws 20
                                                                       repeatability against ICP's fixed point
  mlod calibrate --dataset av2/sensor/val --samples 2 --alignment     residuals: dataset's extrinsic vs ICP's
  mlod calibrate --dataset av2/sensor/val --samples 2 --alpha 0.04 --xi-check   the χ² check of Ξ
  mlod eval --dataset data/test --case input-oc --alpha 0.1            detection after calibration";

pub const SWEEP_EXAMPLES: &str = "\
Examples:
  mlod sweep --dataset data/test --samples 300 --trials 10 --out sweep-t2 \\
      --cases top,input,feature,result,mlod-i,mlod-f,mlod-r,input-oc,feature-oc,result-oc,mlod-i-oc,mlod-f-oc,mlod-r-oc
                                                   Table II (rerun the same command to resume)
  mlod sweep --dataset data/test --samples 20 --trials 2 --cases top,input,mlod-i --alphas 0,0.1 --out /tmp/quick
  mlod sweep --dataset data/test --samples 300 --trials 10 --out s0 --shard 0/2     one machine
  mlod sweep --dataset data/test --samples 300 --trials 10 --out s1 --shard 1/2     another
  mlod sweep merge --out sweep-t2 s0 s1            the same files as one run";

pub const GUI_EXAMPLES: &str = "\
Examples:
  mlod gui                                               the embedded sample_data/
  mlod gui --dataset ~/lyft/v1.01-train                  a Lyft Level 5 copy (root or version folder)
  mlod gui --session screenshots/bev.session.json        reproduce a saved view";

pub const SCREENSHOT_EXAMPLES: &str = "\
Examples:
  mlod screenshot --session screenshots/bev.session.json --out bev.png --size 1280x800";

pub const FAILURES_EXAMPLES: &str = "\
Examples:
  mlod failures --dataset sample_data --case mlod-i --alpha 0.04               worst samples first
  mlod failures --dataset data/test --case input --alpha 0.1 --samples 100 --json --out f.json";

pub const CLIP_EXAMPLES: &str = "\
Examples:
  mlod clip --session screenshots/compare.session.json --alpha-to 0.1 --frames 40 --out clip.gif
  mlod clip --alpha-to 0.04 --frames 20 --size 480x300 --fps 8 --out drift.gif   (first sight)";

pub const PROPAGATE_EXAMPLES: &str = "\
Examples:
  mlod propagate --example --linearization se3-left      the worked example of §III-B
  mlod propagate --point 10,0,0 --rpy-deg 0,0,90 --translation 1,0.5,0 --alpha 0.04 --json";

pub const SYNTH_EXAMPLES: &str = "\
Examples:
  mlod synth --out sample_data --seed 0 --roof-sensors pandar40
                                                  regenerates sample_data/ (1 scene of 10 samples)
  mlod synth --out data/train --scenes 80 --samples-per-scene 20 --seed 101 --progress
                                                  the training split of the shipped models
  mlod synth --out data/v4 --world v4 --seed 101  an earlier world (v2, v4, walled)";

pub const FUSE_EXAMPLES: &str = "\
Examples:
  mlod fuse --dataset sample_data --alpha 0.04 --seed 0
  mlod fuse --dataset sample_data --alpha 0.1 --prior-alpha 0.02 --json   a mis-specified prior";

pub const EXPORT_EXAMPLES: &str = "\
Fields: x y z (m, base frame = LIDAR_TOP), intensity, lidar (0 LIDAR_TOP, 1 LIDAR_FRONT_LEFT,
2 LIDAR_FRONT_RIGHT), trace = tr(Xi) (m^2); with --covariance also xi_xx xi_xy xi_xz xi_yy xi_yz
xi_zz. CloudCompare and Open3D open the PLY with these as scalar fields; PCL opens the PCD.

Examples:
  mlod export --dataset sample_data --alpha 0.04 --seed 0 --out cloud.ply        CloudCompare, Open3D
  mlod export --dataset sample_data --alpha 0.04 --seed 0 --out cloud.pcd        PCL
  mlod export --dataset sample_data --alpha 0.1 --covariance --out cloud.ply     with the six entries of Ξ";

pub const INSPECT_EXAMPLES: &str = "\
Examples:
  mlod inspect --dataset sample_data --list
  mlod inspect --dataset ~/lyft/v1.01-train --sample TOKEN --json";

pub const PLANE_FIT_EXAMPLES: &str = "\
Examples:
  mlod plane-fit --out docs --trials 100 --seed 0        Fig. 2 of the paper";

pub const TRAIN_EXAMPLES: &str = "\
Examples:
  mlod train proposals --dataset data/train --out data/proposals --draws 2 --seed 0
  mlod train refiner --dataset data/train --proposals data/proposals --out assets/models/refiner.safetensors --steps 3000 --seed 0
  mlod train stage1 --case top --dataset data/train --out M/top.safetensors --steps 4000 --seed 1
  mlod train stage1 --case top --dataset data/train --out M/top.safetensors --steps 4000 --seed 1 --resume
  mlod train calibrate-temperature --dataset data/train --models M
  mlod train tune-vote --dataset data/train --models M
  mlod train chain --world walled --out models-new          the shipped recipe, data included (resumable)
  mlod train chain --dataset data/v6w/train --world walled --out models-new
  mlod train adapt --dataset ../shared/real-lidar/kitti --out models-kitti   your sensor's labelled frames";

pub const DETECT_EXAMPLES: &str = "\
Examples:
  mlod detect --dataset sample_data --case input --json
  mlod detect --dataset sample_data --case result --alpha 0.04 --seed 0 --format lyft";

/// `mlod detect --help`'s epilogue: every case with its one-line description, then the examples.
pub fn detect_help() -> String {
    let mut s = String::from("Cases:\n");
    for c in mlod::detect::Case::LISTED {
        s.push_str(&format!(
            "  {:<15} {}: {}\n",
            c.as_str(),
            c.paper_name(),
            c.description()
        ));
    }
    s.push_str("  ext:NAME        an external detector over mlod-detector/1 (docs/external.md)\n");
    s.push_str("  mlod-ext:NAME   the refiner on an external detector's proposals\n\n");
    s.push_str(
        "On a rig with fewer LiDARs the cases read the slots that are there: Argoverse 2's up_lidar\n\
         plays LiDAR-Top and down_lidar LiDAR-Left; LiDAR-Right has no points there, and the fusion\n\
         cases (and MLOD) fuse the two LiDARs (docs/av2.md). A LIDAR_TOP-only sample (KITTI,\n\
         nuScenes, most real Lyft scenes) runs every fusion case on LIDAR_TOP alone.\n\n",
    );
    s.push_str(DETECT_EXAMPLES);
    s
}

pub const EVAL_EXAMPLES: &str = "\
Examples:
  mlod eval --dataset data/test --pred predictions.json  a Lyft-format prediction file
  mlod eval --dataset data/test --case input --alpha 0.04 --seed 3
  mlod eval --dataset sample_data --case top --samples 1 --per-box --json";

pub const STATS_EXAMPLES: &str = "\
Examples:
  mlod stats --dataset data/test --samples 40                  text summary
  mlod stats --dataset data/test --samples 40 --json           the same as JSON
  mlod stats --dataset data/test --compare /data/kitti --out out/realism   JSON and PNG plots of both
  mlod stats --dataset data/train --samples 200 --summary --update-manifest assets/models
                                                               the training data's summary, which
                                                               detect and eval compare datasets with";

pub const TABLE1_EXAMPLES: &str = "\
Examples:
  mlod table1 --dataset data/test                        all six cases, α = 0
  mlod table1 --dataset data/test --cases top,input --attribution --recall-bands 10,20,30,50
  mlod table1 --dataset data/train --validation --vote-iou off";

pub const ANALYZE_EXAMPLES: &str = "\
Examples:
  mlod analyze active-points --dataset data/test --case mlod-i --alpha 0.1 --seed 0 --out out/active";

/// Opens a dataset in any format the folder holds and prints what the user should know about it
/// on stderr (`note: …`: the split opened, categories not among ours, samples that will not load).
pub fn open_dataset(path: &std::path::Path) -> anyhow::Result<mlod::dataset::Dataset> {
    use anyhow::Context;
    let dataset =
        mlod::dataset::Dataset::open(path).with_context(|| format!("opening dataset {}", path.display()))?;
    for note in dataset.notes() {
        eprintln!("note: {note}");
    }
    Ok(dataset)
}
