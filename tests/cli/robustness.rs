use super::*;

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
