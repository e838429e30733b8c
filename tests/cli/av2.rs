//! `mlod calibrate` on the real Argoverse 2 sweep of tests/fixtures/av2: the estimate in the
//! JSON, repeatability against ICP's fixed point (--draws), the residual tables (--alignment) and
//! the χ² check of Ξ (--xi-check).

use super::*;

fn av2() -> String {
    format!("{}/tests/fixtures/av2", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn calibrate_on_a_real_rig_reports_the_estimate_and_returns_to_its_fixed_point() {
    let data = av2();
    // α = 0 starts from the factory calibration: its estimate is the fixed point.
    let fixed = json(&["calibrate", "--dataset", &data, "--alpha", "0", "--json"]);
    let run = &fixed["runs"][0];
    assert_eq!(run["channel"], "LIDAR_FRONT_LEFT");
    let q: Vec<f64> = (0..4)
        .map(|k| run["estimate"]["rotation"][k].as_f64().unwrap())
        .collect();
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!((norm - 1.0).abs() < 1e-9, "{q:?}");
    let tz = run["estimate"]["translation"][2].as_f64().unwrap();
    assert!((-0.25..-0.05).contains(&tz), "down_lidar below up_lidar: {tz}");
    // Three draws at α = 0.1 land on it within 0.01° and 1 mm.
    let r = json(&[
        "calibrate",
        "--dataset",
        &data,
        "--alpha",
        "0.1",
        "--draws",
        "3",
        "--json",
    ]);
    assert_eq!(r["runs"].as_array().unwrap().len(), 3);
    let fp = &r["repeatability"]["fixed_points"][0]["estimate"];
    assert_eq!(fp, &run["estimate"], "the same fixed point as the α = 0 run");
    assert_eq!(r["repeatability"]["within_001deg_1mm"], 3);
    assert_eq!(r["repeatability"]["off_unflagged"], 0);
    for (k, run) in r["runs"].as_array().unwrap().iter().enumerate() {
        assert_eq!(run["seed"], k as u64);
        assert!(
            run["error_before"]["rot_deg"].as_f64().unwrap() > 0.5,
            "a real start"
        );
    }
}

#[test]
fn alignment_and_the_xi_check_run_on_a_real_rig() {
    let data = av2();
    let a = json(&["calibrate", "--dataset", &data, "--alignment", "--json"]);
    let al = &a["alignment"][0];
    let rows = al["dataset"].as_array().unwrap();
    assert_eq!(rows.len(), 8, "2 surfaces × 4 range bins");
    let points: u64 = rows.iter().map(|r| r["points"].as_u64().unwrap()).sum();
    assert!(points > 5_000, "{points}");
    assert!(al["fixed_point_offset"]["rot_deg"].as_f64().unwrap() < 0.5);
    let x = json(&[
        "calibrate",
        "--dataset",
        &data,
        "--alpha",
        "0.02",
        "--draws",
        "4",
        "--xi-check",
        "--json",
    ]);
    let c = &x["xi_check"][0];
    assert!(c["pairs"].as_u64().unwrap() > 10_000);
    // Ξ along the surface normals: z² near χ²₁'s median at a small α.
    let m = c["median_z2"].as_f64().unwrap();
    assert!((0.25..0.7).contains(&m), "{m}");
}
