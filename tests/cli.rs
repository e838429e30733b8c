//! The CLI contract of the foundation issue: names and JSON shapes later checks rely on, and
//! bad input that must fail cleanly (non-zero exit, a message, never a panic).

use std::process::Command;

#[path = "cli/cluster.rs"]
mod cluster;
#[path = "cli/external.rs"]
mod external;
#[path = "cli/transfer.rs"]
mod transfer;

fn mlod(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mlod"))
        .args(args)
        .output()
        .expect("run mlod")
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = mlod(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

fn matrix(v: &serde_json::Value) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| v[i][j].as_f64().unwrap()))
}

#[test]
fn propagate_example_reproduces_the_paper_with_se3_left() {
    let v = json(&[
        "propagate",
        "--example",
        "--linearization",
        "se3-left",
        "--alpha",
        "0.02",
        "--json",
    ]);
    assert_eq!(v["linearization"], "se3-left");
    assert_eq!(v["alpha"], 0.02);
    let m = matrix(&v["extrinsic_per_alpha"]);
    let paper = [[2.36, -1.24, -1.20], [-1.24, 2.41, -1.18], [-1.20, -1.18, 2.49]];
    for i in 0..3 {
        for j in 0..3 {
            assert!(
                (m[i][j] - paper[i][j]).abs() <= 0.01,
                "({i},{j}) {} vs {}",
                m[i][j],
                paper[i][j]
            );
        }
    }
    // xi = α·extrinsic + Z, and std = sqrt(diag(xi)) ≈ 0.22 m as the paper says.
    let xi = matrix(&v["xi"]);
    assert!((xi[0][0] - (0.02 * m[0][0] + 0.0004)).abs() < 1e-12);
    let std = v["std_m"].as_array().unwrap();
    assert!((std[0].as_f64().unwrap() - 0.218).abs() < 0.002);
}

#[test]
fn propagate_example_separate_differs() {
    let v = json(&["propagate", "--example", "--json"]);
    assert_eq!(v["linearization"], "separate");
    let m = matrix(&v["extrinsic_per_alpha"]);
    assert!((m[0][0] - 1.95).abs() < 0.01 && (m[0][1] - -1.03).abs() < 0.01);
}

#[test]
fn propagate_point_gives_xi_and_trace() {
    let v = json(&[
        "propagate",
        "--point",
        "10,10,10",
        "--rpy-deg",
        "10,10,10",
        "--translation",
        "1,1,1",
        "--alpha",
        "0.1",
        "--linearization",
        "se3-left",
        "--json",
    ]);
    let xi = matrix(&v["xi"]);
    let tr = v["trace"].as_f64().unwrap();
    assert!((tr - (xi[0][0] + xi[1][1] + xi[2][2])).abs() < 1e-12);
    assert!((tr - (0.1 * (2.36 + 2.41 + 2.49) + 0.0012)).abs() < 0.01 * 0.1 * 3.0);
    // Negative numbers in a point parse (not taken for flags).
    json(&[
        "propagate",
        "--point",
        "-10,5,-1",
        "--rpy-deg",
        "0,0,-90",
        "--translation",
        "-1,0,0",
        "--alpha",
        "0",
        "--json",
    ]);
}

#[test]
fn bad_input_fails_cleanly() {
    let cases: &[&[&str]] = &[
        &["propagate", "--example", "--alpha", "-0.1"],
        &["propagate", "--example", "--alpha", "nan"],
        &["propagate", "--example", "--alpha", "inf"],
        &[
            "propagate",
            "--point",
            "1,2",
            "--rpy-deg",
            "0,0,0",
            "--translation",
            "0,0,0",
        ],
        &[
            "propagate",
            "--point",
            "1,x,2",
            "--rpy-deg",
            "0,0,0",
            "--translation",
            "0,0,0",
        ],
        &[
            "propagate",
            "--point",
            "1,2,3",
            "--rpy-deg",
            "0,0,NaN",
            "--translation",
            "0,0,0",
        ],
        &["propagate", "--point", "1,2,3"],
        &["propagate", "--example", "--linearization", "left"],
        &[
            "propagate",
            "--example",
            "--prior-std",
            "0.1,0.1,0.1;0.1,-1,0.1;0.1,0.1,0.1",
        ],
        &["propagate", "--example", "--prior-std", "0.1,0.1,0.1"],
        &[
            "plane-fit",
            "--out",
            "/dev/null/cannot-be-a-folder",
            "--trials",
            "1",
        ],
        &["plane-fit", "--out", "x", "--trials", "0"],
    ];
    for args in cases {
        let out = mlod(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(!err.trim().is_empty(), "{args:?} gave no message");
    }
}

#[test]
fn plane_fit_writes_csv_and_png() {
    let dir = std::env::temp_dir().join(format!("mlod-cli-plane-{}", std::process::id()));
    let out = mlod(&[
        "plane-fit",
        "--out",
        dir.to_str().unwrap(),
        "--trials",
        "2",
        "--seed",
        "3",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = std::fs::read_to_string(dir.join("plane_fit.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("case,alpha,weighted_error,unweighted_error"));
    assert_eq!(lines.count(), 22, "two cases × 11 α values");
    let png = std::fs::read(dir.join("plane_fit.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inspect_real_fixture_prints_devkit_boxes_and_names_missing_bins() {
    let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/lyft-real");
    let out = mlod(&["inspect", "--dataset", fixture, "--json"]);
    assert!(
        !out.status.success(),
        "the host-a101 .bin files are not in the fixture"
    );
    let err = String::from_utf8_lossy(&out.stderr);
    for lidar in ["lidar0", "lidar1", "lidar2"] {
        assert!(
            err.contains(&format!("host-a101_{lidar}_1240710385903083166.bin")),
            "{err}"
        );
    }
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("the report is printed before failing");
    let expected: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/devkit_expected/real_boxes.json"
        ))
        .unwrap(),
    )
    .unwrap();
    let boxes = v["boxes"].as_array().unwrap();
    let want = expected["boxes"].as_array().unwrap();
    assert_eq!(boxes.len(), want.len());
    for (b, w) in boxes.iter().zip(want) {
        for k in 0..3 {
            assert!((b["center"][k].as_f64().unwrap() - w["center"][k].as_f64().unwrap()).abs() < 1e-4);
        }
        // size_lwh = devkit wlh with w and l swapped.
        assert!((b["size_lwh"][0].as_f64().unwrap() - w["wlh"][1].as_f64().unwrap()).abs() < 1e-9);
        assert!((b["yaw"].as_f64().unwrap() - w["yaw_zyx"].as_f64().unwrap()).abs() < 1e-4);
    }
    let list = json(&["inspect", "--dataset", fixture, "--list", "--json"]);
    assert_eq!(list.as_array().unwrap().len(), 1);
    let out = mlod(&["inspect", "--dataset", "/nonexistent/dataset"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/dataset"));
}

#[test]
fn a_kitti_folder_opens_as_it_lies_and_fusion_names_the_missing_lidars() {
    let kitti = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/kitti");
    let v = json(&["inspect", "--dataset", kitti, "--sample", "000001", "--json"]);
    assert_eq!(v["format"], "kitti");
    let car = v["boxes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["category"] == "car")
        .expect("KITTI's Car is our car");
    assert_eq!(car["source_category"], "Car");
    // An independent numpy conversion of label_2/000001.txt's car (see tests/lyft_loader.rs).
    for (k, want) in [58.7721, 16.5508, -0.8412].into_iter().enumerate() {
        assert!((car["center"][k].as_f64().unwrap() - want).abs() < 1e-3, "{car}");
    }
    let out = mlod(&[
        "detect",
        "--dataset",
        kitti,
        "--sample",
        "000001",
        "--case",
        "input",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("note: Input Fusion: sample 000001 lacks LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT; it runs on what is there (LIDAR_TOP)"),
        "{err}"
    );
    // LiDAR-Top reads only LIDAR_TOP: no such note.
    let out = mlod(&[
        "detect",
        "--dataset",
        kitti,
        "--sample",
        "000001",
        "--case",
        "top",
    ]);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("lacks"));
    // eval counts the samples that lack LiDARs, and what it ignores outside camera 2's view.
    let out = mlod(&["eval", "--dataset", kitti, "--case", "input"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("note: 2 of 2 samples lack LiDARs the case reads"),
        "{err}"
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("outside the evaluated region"), "{text}");
}

#[test]
fn fuse_reports_what_the_gui_shows() {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let v = json(&[
        "fuse",
        "--dataset",
        data,
        "--alpha",
        "0.04",
        "--seed",
        "0",
        "--json",
    ]);
    let n = v["num_points"].as_u64().unwrap();
    assert!(n > 100_000);
    let counts: u64 = v["histogram"]["counts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .sum();
    assert_eq!(counts, n, "every point is in the histogram");
    let frac = v["uncertain_fraction"].as_f64().unwrap();
    assert!(frac > 0.05 && frac < 1.0, "{frac}");
    let lidars = v["lidars"].as_array().unwrap();
    assert_eq!(lidars[0]["channel"], "LIDAR_TOP");
    assert_eq!(
        lidars[0]["rho_m"],
        serde_json::json!([0.0, 0.0, 0.0]),
        "the primary is never perturbed"
    );
    // ±σ bound at α = 0.04: σ_ρ = sqrt(0.04)·0.05 = 0.01 m.
    for l in &lidars[1..] {
        for r in l["rho_m"].as_array().unwrap() {
            assert!(r.as_f64().unwrap().abs() <= 0.01 + 1e-12);
        }
    }
    assert!(!v["boxes"].as_array().unwrap().is_empty());
    // α = 0: nothing uncertain; the same seed reproduces the same numbers.
    let zero = json(&["fuse", "--dataset", data, "--json"]);
    assert_eq!(zero["uncertain_fraction"], 0.0);
    assert_eq!(json(&["fuse", "--dataset", data, "--alpha", "0.04", "--json"]), v);
    let out = mlod(&["fuse", "--dataset", data, "--sample", "no-such-token"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no-such-token"));
}

#[test]
fn eval_prints_the_issue_json_shape_and_rejects_bad_files() {
    let root = env!("CARGO_MANIFEST_DIR");
    // The predictions were made for sample_data/ before issue 29; its tables are kept beside them.
    let data = format!("{root}/tests/fixtures/devkit_expected/eval_sample_data/dataset");
    let pred = format!("{root}/tests/fixtures/devkit_expected/eval_sample_data/pred_all.json");
    let dir = std::env::temp_dir().join(format!("mlod-cli-eval-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let out_file = dir.join("eval.json");
    let v = json(&[
        "eval",
        "--dataset",
        &data,
        "--pred",
        &pred,
        "--json",
        "--per-box",
        "--out",
        out_file.to_str().expect("utf-8"),
    ]);
    assert_eq!(v["samples"], 10);
    // kitti -> class -> iou_0.7 / iou_0.5 -> easy / moderate / hard, car first.
    let kitti = v["kitti"].as_object().expect("kitti");
    assert_eq!(kitti.keys().next().map(String::as_str), Some("car"));
    for t in ["iou_0.7", "iou_0.5"] {
        for d in ["easy", "moderate", "hard"] {
            let ap = kitti["car"][t][d].as_f64().expect("car AP");
            assert!((0.0..=100.0).contains(&ap));
        }
    }
    for key in ["lyft", "lyft_exact"] {
        let per = v[key]["per_threshold"].as_object().expect("per_threshold");
        assert_eq!(per.len(), 10);
        assert!(per.contains_key("0.5") && per.contains_key("0.95"));
        assert!(v[key]["mAP"].as_f64().is_some());
    }
    assert_eq!(v["predictions"]["rejected"], 6);
    assert_eq!(v["per_box"].as_array().map(Vec::len), Some(10));
    // The localisation summary: per class, mean |residual| and the size correlations.
    let loc = v["localization"].as_array().expect("localization with --per-box");
    let car = loc.iter().find(|l| l["category"] == "car").expect("car");
    assert!(car["matched"].as_u64().is_some_and(|n| n > 0));
    for k in ["along", "lateral", "dz", "dl", "dw", "dh", "dyaw"] {
        assert!(car["mean_abs"][k].as_f64().is_some_and(|x| x >= 0.0), "{k}");
    }
    assert_eq!(car["size_corr"].as_array().map(Vec::len), Some(3));
    assert!(v.get("attribution").is_none(), "only with --attribution");
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out_file).expect("--out written")).expect("json");
    assert_eq!(written, v);

    // Bad inputs: a missing file, a file that is not JSON, JSON that is not a list.
    let not_json = dir.join("bad.json");
    std::fs::write(&not_json, "[{\"sample_token\": ").expect("write");
    let not_list = dir.join("obj.json");
    std::fs::write(&not_list, "{\"a\": 1}").expect("write");
    for (file, needle) in [
        (dir.join("missing.json"), "cannot read predictions"),
        (not_json, "not valid JSON"),
        (not_list, "expected a JSON list"),
    ] {
        let out = mlod(&[
            "eval",
            "--dataset",
            &data,
            "--pred",
            file.to_str().expect("utf-8"),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(
            err.contains(needle) && err.contains(file.to_str().expect("utf-8")),
            "{err}"
        );
    }
    let out = mlod(&["eval", "--dataset", &data, "--pred", &pred, "--match-iou", "1.5"]);
    assert!(!out.status.success());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn table1_agrees_with_eval_case_and_detect() {
    let root = env!("CARGO_MANIFEST_DIR");
    let data = format!("{root}/sample_data");
    let dir = std::env::temp_dir().join(format!("mlod-cli-table1-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let out_file = dir.join("table1.json");
    let out = mlod(&[
        "table1",
        "--dataset",
        &data,
        "--cases",
        "top",
        "--samples",
        "2",
        "--out",
        out_file.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("| LiDAR-Top |"), "{table}");
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&out_file).expect("--out written")).expect("JSON");
    let eval = json(&[
        "eval",
        "--dataset",
        &data,
        "--case",
        "top",
        "--samples",
        "2",
        "--json",
    ]);
    assert_eq!(written["reports"]["top"]["kitti"], eval["kitti"]);
    assert_eq!(written["samples"], 2);
    // The Markdown cell is the JSON figure, rounded.
    let m = eval["kitti"]["car"]["iou_0.7"]["moderate"]
        .as_f64()
        .expect("car AP");
    assert!(table.contains(&format!("{m:.2}")), "{table}");
    // An unknown case is a usage error, not a panic.
    let bad = mlod(&["table1", "--dataset", &data, "--cases", "lidar9"]);
    assert!(!bad.status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn table1_recall_bands_count_the_cars_eval_per_box_matches() {
    let root = env!("CARGO_MANIFEST_DIR");
    let data = format!("{root}/sample_data");
    let out = mlod(&[
        "table1",
        "--dataset",
        &data,
        "--cases",
        "top",
        "--samples",
        "2",
        "--recall-bands",
        "20,50",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("| Method | 0–20 m | 20–50 m |"), "{table}");
    // The same counts from eval's per-box outcomes at the same IoU and range.
    let eval = json(&[
        "eval",
        "--dataset",
        &data,
        "--case",
        "top",
        "--samples",
        "2",
        "--per-box",
        "--match-iou",
        "0.7",
        "--match-range",
        "50",
        "--json",
    ]);
    let mut counts = [(0, 0); 2];
    for s in eval["per_box"].as_array().expect("per_box") {
        for g in s["gts"].as_array().expect("gts") {
            let r = g["range"].as_f64().expect("range");
            if g["category"] != "car" || g["outcome"] == "ignored" || r >= 50.0 {
                continue;
            }
            let b = usize::from(r >= 20.0);
            counts[b].0 += 1;
            counts[b].1 += usize::from(g["outcome"] == "matched");
        }
    }
    assert!(counts[0].0 > 0 && counts[1].0 > 0, "{counts:?}");
    for (n, found) in counts {
        let cell = format!("{:.1} % ({found}/{n})", 100.0 * found as f64 / n as f64);
        assert!(table.contains(&cell), "{cell} not in {table}");
    }
    let bad = mlod(&["table1", "--dataset", &data, "--recall-bands", "30,20"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--recall-bands"));
}

#[test]
fn table1_attribution_agrees_with_eval_attribution() {
    let root = env!("CARGO_MANIFEST_DIR");
    let data = format!("{root}/sample_data");
    let out = mlod(&[
        "table1",
        "--dataset",
        &data,
        "--cases",
        "top",
        "--samples",
        "2",
        "--attribution",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains(
            "| Method | as predicted | true l, w, h | true x, y | true z, h | true yaw | true box |"
        ),
        "{table}"
    );
    let eval = json(&[
        "eval",
        "--dataset",
        &data,
        "--case",
        "top",
        "--samples",
        "2",
        "--per-box",
        "--attribution",
        "--match-iou",
        "0.5",
        "--match-range",
        "30",
        "--json",
    ]);
    let att = eval["attribution"].as_array().expect("attribution");
    assert_eq!(att.len(), 6);
    assert_eq!(att[0]["fixed"], "nothing");
    assert_eq!(att[5]["fixed"], "all");
    // The unedited row is eval's own AP; the table's row holds every figure, rounded.
    assert_eq!(att[0]["kitti"], eval["kitti"]);
    let cells: Vec<String> = att
        .iter()
        .map(|a| {
            a["kitti"]["car"]["iou_0.7"]["moderate"]
                .as_f64()
                .map_or("–".to_string(), |x| format!("{x:.2}"))
        })
        .collect();
    let row = format!("| LiDAR-Top | {} |", cells.join(" | "));
    assert!(table.contains(&row), "{row} not in {table}");
    // --attribution needs --per-box.
    let bad = mlod(&["eval", "--dataset", &data, "--case", "top", "--attribution"]);
    assert!(!bad.status.success());
}

/// A fresh `$TMP/mlod-cli-TAG-PID` holding `data/`, ten one-sample scenes made by `mlod synth`
/// (the tenth is the validation split), and `models/`, a copy of the shipped models (manifest and
/// weights): what the validation-tuning commands work on. Returns (dir, data, models).
fn tuning_fixture(tag: &str) -> (std::path::PathBuf, String, String) {
    let dir = std::env::temp_dir().join(format!("mlod-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (data, models) = (dir.join("data"), dir.join("models"));
    std::fs::create_dir_all(&models).expect("tmp");
    let (d, m) = (
        data.to_str().expect("utf-8").to_string(),
        models.to_str().expect("utf-8").to_string(),
    );
    let synth = mlod(&[
        "synth",
        "--out",
        &d,
        "--scenes",
        "10",
        "--samples-per-scene",
        "1",
        "--seed",
        "7",
    ]);
    assert!(
        synth.status.success(),
        "{}",
        String::from_utf8_lossy(&synth.stderr)
    );
    let source = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models");
    for e in std::fs::read_dir(&source).expect("models folder") {
        let p = e.expect("entry").path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if name == "manifest.json" || name.ends_with(".safetensors") {
            std::fs::copy(&p, models.join(name)).expect("copy the models");
        }
    }
    (dir, d, m)
}

#[test]
fn tune_vote_records_its_choice_in_the_manifest() {
    let (dir, d, m) = tuning_fixture("vote");
    let (d, m, models) = (d.as_str(), m.as_str(), std::path::Path::new(&m));
    let root = env!("CARGO_MANIFEST_DIR");
    let shipped = std::path::Path::new(root).join("assets/models");
    let out = mlod(&[
        "train",
        "tune-vote",
        "--dataset",
        d,
        "--models",
        m,
        "--cases",
        "top",
        "--candidates",
        "0.5",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(models.join("manifest.json")).expect("manifest"))
            .expect("JSON");
    let vote = &manifest["vote"];
    assert!(vote["command"].as_str().expect("command").contains("tune-vote"));
    let off = vote["validation"]["off"]["mean"]
        .as_f64()
        .expect("plain NMS scored");
    let half = vote["validation"]["0.5"]["mean"].as_f64().expect("0.5 scored");
    assert_eq!(
        vote["validation"]["0.5"]["top"].as_f64(),
        Some(half),
        "one case: its AP is the mean"
    );
    // The better candidate is chosen; plain NMS keeps a tie.
    if half > off {
        assert_eq!(vote["iou"].as_f64(), Some(0.5));
    } else {
        assert!(vote["iou"].is_null(), "{vote}");
    }
    // The models were not touched: the rest of the manifest is the shipped one.
    let before: serde_json::Value =
        serde_json::from_slice(&std::fs::read(shipped.join("manifest.json")).expect("manifest"))
            .expect("JSON");
    assert_eq!(manifest["models"], before["models"]);
    // The same validation scenes through table1 give the same figure for the chosen setting.
    let chosen = if half > off { "0.5" } else { "off" };
    let out = mlod(&[
        "table1",
        "--dataset",
        d,
        "--validation",
        "--cases",
        "top",
        "--models",
        m,
        "--vote-iou",
        chosen,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let best = if half > off { half } else { off };
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("{best:.2}")));

    // The union cases' decoding alone (issue 32): the MLOD-I/F/R choice and its command stay,
    // the union's NMS and box voting are chosen on the same validation scene.
    for f in ["input.safetensors", "refiner.safetensors"] {
        std::fs::copy(shipped.join(f), models.join(f)).expect("copy the shipped model");
    }
    let out = mlod(&[
        "train",
        "tune-refiner",
        "--dataset",
        d,
        "--models",
        m,
        "--union-only",
        "--union-cases",
        "mlod-u",
        "--alphas",
        "0",
        "--union-nms",
        "0.3",
        "--union-vote",
        "0.5",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let tuned: serde_json::Value =
        serde_json::from_slice(&std::fs::read(models.join("manifest.json")).expect("manifest"))
            .expect("JSON");
    let (r, r0) = (&tuned["refine"], &before["refine"]);
    assert_eq!((&r["score"], &r["nms_iou"]), (&r0["score"], &r0["nms_iou"]));
    let cmd = r["command"].as_str().expect("command");
    assert!(
        cmd.starts_with(
            r0["command"]
                .as_str()
                .expect("old command")
                .split(" && ")
                .next()
                .expect("one")
        ) && cmd.contains(" && ")
            && cmd.contains("--union-only"),
        "{cmd}"
    );
    let plain = r["validation"]["union+nms0.3"]["mlod-u@0"]
        .as_f64()
        .expect("plain NMS scored");
    let voted = r["validation"]["union+nms0.3+vote0.5"]["mlod-u@0"]
        .as_f64()
        .expect("voting scored");
    assert_eq!(r["union_nms_iou"].as_f64(), Some(0.3));
    if voted > plain {
        assert_eq!(r["union_vote_iou"].as_f64(), Some(0.5), "{r}");
    } else {
        assert!(r["union_vote_iou"].is_null(), "a tie keeps plain NMS: {r}");
    }
    // The MLOD-I/F/R candidates' scores are the shipped ones, the old union ones are gone.
    assert_eq!(r["validation"]["mean"], r0["validation"]["mean"]);
    assert!(r["validation"].get("union+nms0.7").is_none());

    // sample_data is one scene: no validation split, said clearly.
    let sample = format!("{root}/sample_data");
    for args in [
        vec!["train", "tune-vote", "--dataset", &sample, "--models", m],
        vec!["table1", "--dataset", &sample, "--validation", "--cases", "top"],
    ] {
        let out = mlod(&args);
        assert!(!out.status.success());
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("no validation samples"),
            "{args:?}"
        );
    }
    // A vote IoU outside (0, 1] is a usage error.
    let out = mlod(&[
        "detect",
        "--dataset",
        &sample,
        "--case",
        "top",
        "--vote-iou",
        "1.5",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("(0, 1]"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn export_writes_what_fuse_reports_and_refuses_bad_input() {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let dir = std::env::temp_dir().join(format!("mlod-cli-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fused = json(&[
        "fuse",
        "--dataset",
        data,
        "--alpha",
        "0.04",
        "--seed",
        "3",
        "--json",
    ]);
    let n = fused["num_points"].as_u64().unwrap() as usize;
    for (name, cov) in [("c.ply", false), ("c.pcd", true)] {
        let path = dir.join(name);
        let mut args = vec![
            "export",
            "--dataset",
            data,
            "--alpha",
            "0.04",
            "--seed",
            "3",
            "--out",
            path.to_str().unwrap(),
        ];
        if cov {
            args.push("--covariance");
        }
        let out = mlod(&args);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("{n} points")));
        let cloud = mlod::export::read_file(&path).unwrap();
        assert_eq!(cloud.len(), n, "{name}: the points fuse reports");
        let lo = cloud.trace.iter().copied().fold(f32::INFINITY, f32::min) as f64;
        let hi = cloud.trace.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
        assert_eq!(lo, fused["trace_min"].as_f64().unwrap(), "{name}");
        assert_eq!(hi, fused["trace_max"].as_f64().unwrap(), "{name}");
        let per_lidar: Vec<usize> = (0..3u8)
            .map(|l| cloud.lidar.iter().filter(|&&x| x == l).count())
            .collect();
        let expected: Vec<usize> = fused["lidars"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| l["num_points"].as_u64().unwrap() as usize)
            .collect();
        assert_eq!(per_lidar, expected, "{name}: points per LiDAR");
        assert_eq!(cloud.covariance.is_some(), cov, "{name}");
        if let Some(c) = &cloud.covariance {
            // The diagonal of Ξ sums to tr(Ξ).
            for (xi, t) in c.iter().zip(&cloud.trace).step_by(997) {
                let tr = xi[0] + xi[1] + xi[2]; // covariance6 order: xx, yy, zz, xy, xz, yz
                assert!((tr - t).abs() <= 1e-5 * t.max(1e-3), "{tr} vs {t}");
            }
        }
    }
    let bad = |args: &[&str], says: &str| {
        let out = mlod(args);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    };
    let txt = dir.join("c.txt");
    bad(
        &["export", "--dataset", data, "--out", txt.to_str().unwrap()],
        "c.txt",
    );
    bad(
        &["export", "--dataset", "/no/such/dataset", "--out", "x.ply"],
        "/no/such/dataset",
    );
    bad(
        &["export", "--dataset", data, "--sample", "nope", "--out", "x.ply"],
        "nope",
    );
    bad(
        &["export", "--dataset", data, "--alpha", "-1", "--out", "x.ply"],
        "alpha",
    );
    bad(
        &["export", "--dataset", data, "--format", "las", "--out", "x.las"],
        "las",
    );
    assert!(
        !txt.exists() && !std::path::Path::new("x.ply").exists(),
        "nothing written on error"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn mlod_cases_without_or_with_a_corrupt_refiner_fail_naming_the_file() {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models");
    let dir = std::env::temp_dir().join(format!("mlod-cli-refiner-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["input.safetensors", "manifest.json"] {
        std::fs::copy(shipped.join(f), dir.join(f)).unwrap();
    }
    // The manifest without a refiner: an error naming manifest.json and saying what to do.
    let mut m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    m.as_object_mut().unwrap().remove("refiner");
    m.as_object_mut().unwrap().remove("refine");
    std::fs::write(dir.join("manifest.json"), serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    let models = dir.to_str().unwrap();
    let out = mlod(&[
        "detect",
        "--dataset",
        data,
        "--case",
        "mlod-i",
        "--models",
        models,
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("manifest.json") && err.contains("mlod train refiner"),
        "{err}"
    );
    // A refiner entry whose file is garbage: an error naming the file.
    std::fs::write(dir.join("refiner.safetensors"), b"not a safetensors file").unwrap();
    m["refiner"] = serde_json::json!({
        "file": "refiner.safetensors", "sha256": mlod::detect::weights::sha256_hex(b"not a safetensors file"),
        "command": "mlod train refiner", "seed": 0, "steps": 1, "wall_time_s": 0.0
    });
    std::fs::write(dir.join("manifest.json"), serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    let out = mlod(&[
        "eval",
        "--dataset",
        data,
        "--case",
        "mlod-i",
        "--models",
        models,
        "--samples",
        "1",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("refiner.safetensors") && !err.contains("panicked"),
        "{err}"
    );
    // A stage-1 case still runs from that folder, and analyze refuses a stage-1 case.
    let out = mlod(&[
        "detect",
        "--dataset",
        data,
        "--case",
        "input",
        "--models",
        models,
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let analyze = |case: &str, extra: &[&str]| {
        let base = [
            "analyze",
            "active-points",
            "--dataset",
            data,
            "--case",
            case,
            "--out",
            models,
        ];
        mlod(&[&base[..], extra].concat())
    };
    let out = analyze("input", &[]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("MLOD case"));
    // Flags that cannot change active points are refused, not ignored.
    for (flag, value) in [("--ground-gate", "0.5"), ("--set-intensity", "0")] {
        let out = analyze("mlod-i", &[flag, value]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(flag) && !err.contains("panicked"),
            "{err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn calibrate_reports_errors_before_and_after_and_oc_cases_run() {
    let data = format!("{}/sample_data", env!("CARGO_MANIFEST_DIR"));
    let v = json(&[
        "calibrate",
        "--dataset",
        &data,
        "--alpha",
        "0.1",
        "--samples",
        "2",
        "--json",
    ]);
    let runs = v["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 4, "two samples, two auxiliary LiDARs");
    for r in runs {
        for key in [
            "sample_token",
            "channel",
            "converged",
            "degenerate",
            "fitness",
            "rmse",
            "iterations",
            "covariance",
            "ms",
        ] {
            assert!(!r[key].is_null(), "{key} missing: {r}");
        }
        let before = r["error_before"]["rot_deg"].as_f64().unwrap();
        let after = r["error_after"]["rot_deg"].as_f64().unwrap();
        // ICP's floor is about 0.01° (docs/calibration.md); 0.05° on the v4 sample_data's worst run.
        assert!(after < 0.1 && after < before / 10.0, "{before} -> {after}");
        assert!(r["error_after"]["trans_m"].as_f64().unwrap() < 0.01);
        assert_eq!(r["covariance"].as_array().unwrap().len(), 6);
    }
    assert_eq!(v["summary"]["runs"], 4);
    assert!(v["summary"]["rot_deg_after"]["median"].as_f64().unwrap() < 0.05);
    // The same drift as `mlod fuse`: the start error is the one of fuse's applied extrinsic.
    let single = json(&["calibrate", "--dataset", &data, "--alpha", "0.1", "--json"]);
    assert_eq!(single["runs"][0]["error_before"], runs[0]["error_before"]);
    // Bad settings and input fail cleanly, naming what is wrong.
    for (args, needle) in [
        (vec!["--icp", "voxel=1"], "unknown ICP setting 'voxel'"),
        (vec!["--icp", "shrink=2"], "shrink"),
        (vec!["--alpha", "-1"], "alpha"),
        (vec!["--samples", "0"], "--samples"),
        (vec!["--sample", "nope"], "nope"),
    ] {
        let mut a = vec!["calibrate", "--dataset", data.as_str()];
        a.extend(args.iter());
        let out = mlod(&a);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{a:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // `fuse --oc` gives the corrected cloud's numbers (what the window shows after calibrating):
    // far fewer uncertain points with ICP's covariance, the same as without OC with the prior's.
    let drifted_fuse = json(&["fuse", "--dataset", &data, "--alpha", "0.1", "--json"]);
    let oc_fuse = json(&["fuse", "--dataset", &data, "--alpha", "0.1", "--oc", "--json"]);
    let oc_alpha = json(&[
        "fuse",
        "--dataset",
        &data,
        "--alpha",
        "0.1",
        "--oc",
        "--oc-prior",
        "alpha",
        "--json",
    ]);
    assert_eq!(oc_fuse["lidars"][1]["calibrated"], true);
    assert_eq!(drifted_fuse["lidars"][1]["calibrated"], false);
    let frac = |v: &serde_json::Value| v["uncertain_fraction"].as_f64().unwrap();
    assert!(
        frac(&oc_fuse) < 0.2 * frac(&drifted_fuse),
        "{} vs {}",
        frac(&oc_fuse),
        frac(&drifted_fuse)
    );
    assert!((frac(&oc_alpha) - frac(&drifted_fuse)).abs() < 0.02);
    // An (OC) case runs from detect: ICP first, then Input Fusion on the corrected cloud.
    let oc = json(&[
        "detect",
        "--dataset",
        &data,
        "--case",
        "input-oc",
        "--alpha",
        "0.1",
        "--json",
    ]);
    let drifted = json(&[
        "detect",
        "--dataset",
        &data,
        "--case",
        "input",
        "--alpha",
        "0.1",
        "--json",
    ]);
    let clean = json(&["detect", "--dataset", &data, "--case", "input", "--json"]);
    assert_ne!(oc, drifted, "calibration changed nothing");
    assert!(oc.to_string().len() > 10 && clean.to_string().len() > 10);
}

/// `mlod sweep` arguments with the given cases, α list and trials.
fn sweep<'a>(
    sample: &'a str,
    cases: &'a str,
    alphas: &'a str,
    trials: &'a str,
    out: &'a str,
) -> Vec<&'a str> {
    vec![
        "sweep",
        "--dataset",
        sample,
        "--cases",
        cases,
        "--alphas",
        alphas,
        "--trials",
        trials,
        "--out",
        out,
    ]
}

#[test]
fn absurd_arguments_of_the_workflow_commands_fail_cleanly() {
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let out_gif = std::env::temp_dir().join(format!("mlod-absurd-{}.gif", std::process::id()));
    let gif = out_gif.to_str().unwrap();
    let cases: Vec<Vec<&str>> = vec![
        vec!["clip", "--alpha-to", "nan", "--out", gif],
        vec!["clip", "--alpha-to", "5", "--out", gif],
        vec!["clip", "--alpha-to", "-0.1", "--out", gif],
        vec!["clip", "--frames", "0", "--out", gif],
        vec!["clip", "--frames", "10000000", "--out", gif],
        vec!["clip", "--fps", "0", "--out", gif],
        vec!["clip", "--size", "100000x100000", "--out", gif],
        vec!["clip", "--size", "axb", "--out", gif],
        vec!["clip", "--session", "/nonexistent/session.json", "--out", gif],
        vec!["screenshot", "--size", "100000x100000", "--out", gif],
        vec![
            "failures",
            "--dataset",
            sample,
            "--case",
            "input",
            "--alpha",
            "-1",
        ],
        vec![
            "failures",
            "--dataset",
            sample,
            "--case",
            "input",
            "--alpha",
            "nan",
        ],
        vec!["failures", "--dataset", sample, "--case", "input", "--alpha", "2"],
        vec![
            "failures",
            "--dataset",
            sample,
            "--case",
            "input-oc",
            "--alpha",
            "0.1",
        ],
        vec![
            "failures",
            "--dataset",
            sample,
            "--case",
            "input",
            "--scene",
            "no-such-scene",
        ],
        vec![
            "failures",
            "--dataset",
            sample,
            "--case",
            "input",
            "--match-iou",
            "2",
        ],
        vec!["failures", "--dataset", "/nonexistent/dataset", "--case", "input"],
        vec!["failures", "--dataset", sample, "--case", "no-such-case"],
        sweep(sample, "input", "2", "1", gif),
        sweep(sample, "input", "nan", "1", gif),
        sweep(sample, "input", "0.1", "0", gif),
        sweep(sample, "input,input", "0.1", "1", gif),
        sweep(sample, "input", "0.1,0.1", "1", gif),
        vec!["eval", "--dataset", sample, "--case", "input", "--alpha", "1e9"],
        vec!["fuse", "--dataset", sample, "--alpha", "nan"],
        vec![
            "fuse",
            "--dataset",
            sample,
            "--alpha",
            "0.1",
            "--prior-alpha",
            "-3",
        ],
        vec!["export", "--dataset", sample, "--alpha", "-0.5", "--out", gif],
        vec!["calibrate", "--dataset", sample, "--alpha", "inf"],
        vec!["detect", "--dataset", sample, "--case", "top", "--alpha", "1.5"],
        vec![
            "detect",
            "--dataset",
            sample,
            "--case",
            "input",
            "--drop-trace",
            "nan",
        ],
        vec!["table1", "--dataset", sample, "--cases", "top", "--alpha", "-1"],
        vec!["propagate", "--example", "--alpha", "1e308"],
        vec![
            "sweep",
            "--dataset",
            sample,
            "--cases",
            "top",
            "--trials",
            "100000000",
            "--out",
            gif,
        ],
        vec!["stats", "--dataset", sample, "--samples", "0"],
        vec!["stats", "--dataset", sample, "--samples", "-3"],
        vec!["stats", "--dataset", sample, "--samples", "many"],
        vec!["stats", "--dataset", "/nonexistent/dataset"],
        vec![
            "stats",
            "--dataset",
            sample,
            "--compare",
            "/nonexistent/dataset",
            "--out",
            gif,
        ],
        vec![
            "stats",
            "--dataset",
            sample,
            "--samples",
            "1",
            "--out",
            "/dev/null/cannot-be-a-folder",
        ],
        vec!["stats", "--dataset", sample, "--summary", "--out", gif],
        vec![
            "stats",
            "--dataset",
            sample,
            "--update-manifest",
            "/nonexistent/models",
        ],
    ];
    for args in &cases {
        let out = mlod(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(!err.trim().is_empty(), "{args:?} gave no message");
    }
    assert!(!out_gif.exists(), "nothing written");
}

/// A folder for one test's files, removed on drop.
struct Scratch(std::path::PathBuf);

impl Scratch {
    fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("mlod-cli-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch");
        Self(d)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// sample_data's tables as JSON values, by table name.
fn sample_tables() -> std::collections::BTreeMap<String, serde_json::Value> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data/v1.01-train");
    mlod::dataset::tables::TABLE_NAMES
        .iter()
        .map(|t| {
            let bytes = std::fs::read(dir.join(format!("{t}.json"))).expect("table");
            (t.to_string(), serde_json::from_slice(&bytes).expect("JSON"))
        })
        .collect()
}

fn write_tables(root: &std::path::Path, tables: &std::collections::BTreeMap<String, serde_json::Value>) {
    let v = root.join("v1.01-train");
    std::fs::create_dir_all(&v).expect("version folder");
    for (t, rows) in tables {
        std::fs::write(
            v.join(format!("{t}.json")),
            serde_json::to_vec(rows).expect("JSON"),
        )
        .expect("table");
    }
}

/// What the program does with absurd data rather than absurd arguments: an empty dataset, LiDAR
/// files of 0 points, and a dataset of 10 000 samples of which one `.bin` is broken. Each either
/// succeeds (0 points is a LiDAR that saw nothing) or fails with a message; never a panic.
#[test]
fn absurd_datasets_fail_cleanly_or_work() {
    let s = Scratch::new("absurd-data");
    let ok_or_message = |args: &[&str], must_fail: bool, needle: &str| {
        let out = mlod(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        if must_fail {
            assert!(!out.status.success(), "{args:?} should fail");
            assert!(
                err.contains(needle),
                "{args:?}: the message does not name {needle}: {err}"
            );
        }
        out
    };

    // Empty: every table an empty list.
    let empty = s.0.join("empty");
    let mut tables = sample_tables();
    for rows in tables.values_mut() {
        *rows = serde_json::json!([]);
    }
    write_tables(&empty, &tables);
    let e = empty.to_str().expect("utf-8");
    for args in [
        vec!["fuse", "--dataset", e],
        vec!["detect", "--dataset", e, "--case", "top"],
        vec!["eval", "--dataset", e, "--case", "top"],
        vec!["table1", "--dataset", e, "--cases", "top"],
        vec!["failures", "--dataset", e, "--case", "input"],
        vec!["sweep", "--dataset", e, "--cases", "top", "--out", e],
    ] {
        ok_or_message(&args, true, "sample");
    }

    // Zero points: sample_data's tables over empty .bin files.
    let zero = s.0.join("zero");
    write_tables(&zero, &sample_tables());
    std::fs::create_dir_all(zero.join("lidar")).expect("lidar folder");
    let lidar = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data/lidar");
    for f in std::fs::read_dir(lidar).expect("lidar").flatten() {
        std::fs::write(zero.join("lidar").join(f.file_name()), b"").expect("empty bin");
    }
    let z = zero.to_str().expect("utf-8");
    for args in [
        vec!["fuse", "--dataset", z, "--alpha", "0.1"],
        vec!["detect", "--dataset", z, "--case", "mlod-i", "--alpha", "0.1"],
        vec!["calibrate", "--dataset", z, "--alpha", "0.1"],
        vec!["eval", "--dataset", z, "--case", "input", "--samples", "2"],
    ] {
        ok_or_message(&args, false, "");
    }

    // 10 000 samples, one of them with a truncated LIDAR_TOP file.
    let big = s.0.join("big");
    let mut tables = sample_tables();
    let first = tables["sample"][0].clone();
    let token = first["token"].as_str().expect("token").to_owned();
    let rows: Vec<serde_json::Value> = tables["sample_data"]
        .as_array()
        .expect("rows")
        .iter()
        .filter(|r| r["sample_token"] == token.as_str())
        .cloned()
        .collect();
    let mut samples = Vec::new();
    let mut data = Vec::new();
    for i in 0..10_000 {
        let t = format!("{i:064x}");
        let mut smp = first.clone();
        smp["token"] = t.clone().into();
        smp["prev"] = "".into();
        smp["next"] = "".into();
        samples.push(smp);
        for (k, r) in rows.iter().enumerate() {
            let mut r = r.clone();
            r["token"] = format!("{i:060x}{k:04x}").into();
            r["sample_token"] = t.clone().into();
            r["prev"] = "".into();
            r["next"] = "".into();
            if i == 7_777
                && r["filename"]
                    .as_str()
                    .is_some_and(|f| f.contains("lidar1") || f.contains("lidar0"))
            {
                r["filename"] = "lidar/broken.bin".into();
            }
            data.push(r);
        }
    }
    tables.insert("sample".into(), samples.into());
    tables.insert("sample_data".into(), data.into());
    tables.insert("sample_annotation".into(), serde_json::json!([]));
    write_tables(&big, &tables);
    std::fs::create_dir_all(big.join("lidar")).expect("lidar folder");
    for f in std::fs::read_dir(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data/lidar"))
        .expect("lidar")
        .flatten()
    {
        std::fs::copy(f.path(), big.join("lidar").join(f.file_name())).expect("copy bin");
    }
    std::fs::write(big.join("lidar/broken.bin"), [0u8; 33]).expect("broken bin");
    let b = big.to_str().expect("utf-8");
    let broken = format!("{:064x}", 7_777);
    let listed = ok_or_message(&["inspect", "--dataset", b, "--list"], false, "");
    assert!(
        listed.status.success(),
        "{}",
        String::from_utf8_lossy(&listed.stderr)
    );
    ok_or_message(&["fuse", "--dataset", b, "--sample", &broken], true, "broken.bin");
    ok_or_message(
        &["detect", "--dataset", b, "--sample", &broken, "--case", "top"],
        true,
        "broken.bin",
    );
    let fine = format!("{:064x}", 7_778);
    let out = ok_or_message(&["fuse", "--dataset", b, "--sample", &fine], false, "");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// The ablation's figures go to the manifest's `refiner_notrace` entry, not the shipped refiner's.
#[test]
fn table1_records_the_notrace_ablation_under_its_own_refiner() {
    let s = Scratch::new("notrace-manifest");
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models");
    for f in [
        "manifest.json",
        "input.safetensors",
        "refiner-notrace.safetensors",
    ] {
        std::fs::copy(shipped.join(f), s.0.join(f)).expect("copy a shipped file");
    }
    let read = || -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(s.0.join("manifest.json")).expect("manifest")).expect("JSON")
    };
    let before = read();
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let out = mlod(&[
        "table1",
        "--dataset",
        sample,
        "--cases",
        "mlod-i-notrace",
        "--samples",
        "3",
        "--models",
        s.0.to_str().expect("utf-8"),
        "--update-manifest",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let after = read();
    assert_eq!(
        after["refiner"], before["refiner"],
        "the shipped refiner's figures are untouched"
    );
    let ap = &after["refiner_notrace"]["test_ap"]["mlod-i-notrace/moderate_ap3d_0.7"];
    assert!(ap.as_f64().is_some_and(|v| (0.0..=100.0).contains(&v)), "{ap}");
}

#[test]
fn stats_prints_text_json_and_writes_plots() {
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let text = mlod(&["stats", "--dataset", sample, "--samples", "2"]);
    assert!(text.status.success(), "{}", String::from_utf8_lossy(&text.stderr));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("LIDAR_TOP") && text.contains("car"), "{text}");
    let v = json(&["stats", "--dataset", sample, "--samples", "2", "--json"]);
    assert_eq!(v["samples"], 2);
    assert_eq!(v["failed_samples"], 0);
    assert_eq!(v["format"], "lyft");
    assert_eq!(v["lidars"][0]["channel"], "LIDAR_TOP");
    assert!(v["lidars"][0]["points_per_sweep"]["median"].as_f64().unwrap() > 1000.0);
    assert!(v["objects"][0]["range_bins"][7]["to_m"].is_null());
    assert!(v.get("boxes").is_none(), "boxes only with --per-box");
    let s = json(&[
        "stats",
        "--dataset",
        sample,
        "--samples",
        "2",
        "--summary",
        "--json",
    ]);
    assert_eq!(s["samples"], 2);
    assert_eq!(s["lidars"].as_array().unwrap().len(), 3);

    let dir = Scratch::new("stats");
    let out = dir.0.to_str().unwrap();
    let kitti = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/kitti");
    let run = mlod(&[
        "stats",
        "--dataset",
        sample,
        "--compare",
        kitti,
        "--per-box",
        "--out",
        out,
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    for f in [
        "stats.json",
        "compare.json",
        "points_per_box.png",
        "intensity.png",
        "range.png",
    ] {
        assert!(dir.0.join(f).is_file(), "{f} missing");
    }
    let k: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.0.join("compare.json")).unwrap()).unwrap();
    assert_eq!(k["format"], "kitti");
    assert_eq!(k["lidars"][0]["rings"], 64);
    assert_eq!(k["lidars"].as_array().unwrap().len(), 1);
    assert!(!k["boxes"].as_array().unwrap().is_empty());
}

#[test]
fn stats_updates_a_manifest_and_detect_and_eval_name_what_differs() {
    let root = env!("CARGO_MANIFEST_DIR");
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let kitti = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/kitti");
    // The summary goes into a copy of the shipped manifest, under training_stats.
    let dir = Scratch::new("stats-manifest");
    let shipped = std::path::Path::new(root).join("assets/models");
    std::fs::copy(shipped.join("manifest.json"), dir.0.join("manifest.json")).unwrap();
    let m = dir.0.to_str().unwrap();
    let run = mlod(&[
        "stats",
        "--dataset",
        sample,
        "--samples",
        "3",
        "--summary",
        "--update-manifest",
        m,
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.0.join("manifest.json")).unwrap()).unwrap();
    let t = &manifest["training_stats"];
    assert!(t["command"]
        .as_str()
        .unwrap()
        .starts_with("mlod stats --dataset "));
    assert_eq!(t["summary"]["samples"], 3);
    assert!(
        manifest["models"]["top"].is_object(),
        "the rest of the manifest is kept"
    );

    // The shipped manifest holds the training data's summary: KITTI differs, sample_data does not.
    assert!(
        mlod::detect::weights::read_training_stats(&shipped)
            .unwrap()
            .is_some(),
        "assets/models/manifest.json has no training_stats"
    );
    let det = mlod(&["detect", "--dataset", kitti, "--case", "top", "--json"]);
    let err = String::from_utf8_lossy(&det.stderr);
    assert!(det.status.success(), "{err}");
    // The shipped (v4) models saw roof LiDARs of 32 to 128 rings: KITTI's 64 are among them.
    assert!(!err.contains("rings"), "{err}");
    assert!(
        err.contains("note: no LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT"),
        "{err}"
    );
    assert!(err.contains("m shorter"), "{err}");
    serde_json::from_slice::<serde_json::Value>(&det.stdout).expect("stdout stays JSON");
    let ev = mlod(&["eval", "--dataset", kitti, "--case", "top", "--json"]);
    let err = String::from_utf8_lossy(&ev.stderr);
    assert!(ev.status.success(), "{err}");
    assert!(err.contains("note: cars are 1.0 m shorter"), "{err}");
    let same = mlod(&["detect", "--dataset", sample, "--case", "top", "--json"]);
    assert!(same.status.success());
    let err = String::from_utf8_lossy(&same.stderr);
    assert!(
        !err.contains("note:"),
        "sample_data is like the training data: {err}"
    );
}

#[test]
fn synth_glass_see_through_changes_the_sweeps_and_refuses_unknown_values() {
    let dir = std::env::temp_dir().join(format!("mlod-cli-glass-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let make = |name: &str, glass: &str| {
        let out = dir.join(name);
        let run = mlod(&[
            "synth",
            "--out",
            out.to_str().expect("utf-8"),
            "--samples-per-scene",
            "1",
            "--seed",
            "5",
            "--glass",
            glass,
        ]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let lidar = out.join("lidar");
        let mut bins: Vec<_> = std::fs::read_dir(&lidar)
            .expect("lidar/")
            .map(|e| e.expect("entry").path())
            .collect();
        bins.sort();
        bins.iter()
            .map(|p| std::fs::read(p).expect("bin"))
            .collect::<Vec<_>>()
    };
    let (opaque, clear) = (make("opaque", "opaque"), make("clear", "see-through"));
    assert_eq!(opaque.len(), clear.len());
    assert_ne!(opaque, clear, "see-through glass changed no sweep");
    let bad = mlod(&[
        "synth",
        "--out",
        dir.join("bad").to_str().expect("utf-8"),
        "--glass",
        "foggy",
    ]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--glass"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_refiner_of_chosen_widths_trains_and_loads_and_bad_widths_are_refused() {
    // `mlod train refiner --point-mlp … --head …` (issue 32's capacity lever).
    let dir = std::env::temp_dir().join(format!("mlod-cli-widths-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let sd = concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data");
    let (props, out) = (dir.join("props"), dir.join("refiner.safetensors"));
    let (props_s, out_s) = (props.to_str().unwrap(), out.to_str().unwrap());
    let train = |widths: &[&str]| {
        let mut args = vec![
            "train",
            "refiner",
            "--dataset",
            sd,
            "--proposals",
            props_s,
            "--out",
            out_s,
        ];
        args.extend_from_slice(&[
            "--steps",
            "2",
            "--batch",
            "4",
            "--points",
            "64",
            "--log-every",
            "1",
        ]);
        args.extend_from_slice(widths);
        mlod(&args)
    };
    let bad = train(&["--point-mlp", "8,0", "--head", "16"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("--point-mlp"), "{err}");
    assert!(!out.exists());
    let db = mlod(&[
        "train",
        "proposals",
        "--dataset",
        sd,
        "--out",
        props_s,
        "--cases",
        "input",
        "--max-samples",
        "2",
    ]);
    assert!(db.status.success(), "{}", String::from_utf8_lossy(&db.stderr));
    let ok = train(&["--point-mlp", "8,16", "--head", "16"]);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let r = mlod::refine::Refiner::load(&out, None, Default::default()).expect("the trained refiner loads");
    assert_eq!(
        (r.config.point_mlp.as_slice(), r.config.head.as_slice()),
        ([8, 16].as_slice(), [16].as_slice())
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn analyze_takes_the_drop_threshold_of_a_drop_case() {
    // `mlod-ir-drop` at α = 0.1: its proposals come from Result and Input Fusion on the points
    // under the threshold, so another --drop-trace gives the refiner other proposals to look at.
    let dir = std::env::temp_dir().join(format!("mlod-analyze-drop-{}", std::process::id()));
    let csv = |trace: &str| {
        let out_dir = dir.join(trace);
        let out = out_dir.to_str().unwrap();
        let args = [
            "analyze",
            "active-points",
            "--dataset",
            "sample_data",
            "--case",
            "mlod-ir-drop",
            "--alpha",
            "0.1",
            "--samples",
            "1",
            "--drop-trace",
            trace,
            "--out",
            out,
        ];
        let o = mlod(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out_dir.join("active_points.csv")).unwrap()
    };
    assert_ne!(csv("0.1"), csv("0.005"));
    let _ = std::fs::remove_dir_all(&dir);
}
