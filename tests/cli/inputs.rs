use super::*;

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
    // An independent numpy conversion of label_2/000001.txt's car (see tests/data/).
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
