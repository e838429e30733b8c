use super::*;

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
