use nalgebra::{Matrix6, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::*;
use crate::calib::PoseError;
use crate::geometry::rpy_to_matrix;
use crate::uncertainty::ExtrinsicNoise;

/// A rectangle: origin + a·u + b·v for a, b in [0, 1].
struct Patch {
    origin: [f64; 3],
    u: [f64; 3],
    v: [f64; 3],
}

fn patch(origin: [f64; 3], u: [f64; 3], v: [f64; 3]) -> Patch {
    Patch { origin, u, v }
}

fn ground() -> Patch {
    patch([-30.0, -30.0, -1.8], [60.0, 0.0, 0.0], [0.0, 60.0, 0.0])
}

/// Two parallel walls along x on a ground plane: nothing observes a translation along x.
fn corridor() -> Vec<Patch> {
    vec![
        ground(),
        patch([-30.0, -7.0, -1.8], [60.0, 0.0, 0.0], [0.0, 0.0, 8.0]),
        patch([-30.0, 7.0, -1.8], [60.0, 0.0, 0.0], [0.0, 0.0, 8.0]),
    ]
}

/// A corridor closed by a cross wall and some boxes: every direction is observed.
fn street() -> Vec<Patch> {
    let mut s = corridor();
    s.push(patch([25.0, -7.0, -1.8], [0.0, 14.0, 0.0], [0.0, 0.0, 8.0]));
    s.push(patch([8.0, -3.0, -1.8], [0.0, 0.0, 1.5], [2.0, 1.5, 0.0]));
    s.push(patch([-12.0, 2.0, -1.8], [0.0, 0.0, 1.5], [1.0, -2.0, 0.0]));
    s
}

/// More structure on top of [`street`]: a second cross wall and more boxes.
fn busy_street() -> Vec<Patch> {
    let mut s = street();
    s.push(patch([-25.0, -7.0, -1.8], [0.0, 14.0, 0.0], [0.0, 0.0, 8.0]));
    s.push(patch([3.0, 4.0, -1.8], [0.0, 0.0, 1.6], [2.5, -1.0, 0.0]));
    s.push(patch([-5.0, -5.0, -1.8], [0.0, 0.0, 1.6], [1.5, 2.0, 0.0]));
    s.push(patch([15.0, 1.0, -1.8], [0.0, 0.0, 1.6], [-1.0, 2.5, 0.0]));
    s
}

/// `n` points per patch with 1 cm noise, in the base frame.
fn sample(patches: &[Patch], n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    for p in patches {
        for _ in 0..n {
            let (a, b): (f64, f64) = (rng.random(), rng.random());
            let noise: [f64; 3] = std::array::from_fn(|_| 0.01 * rng.sample::<f64, _>(StandardNormal));
            out.push(std::array::from_fn(|k| {
                p.origin[k] + a * p.u[k] + b * p.v[k] + noise[k]
            }));
        }
    }
    out
}

fn to_f32(points: &[[f64; 3]]) -> Vec<[f32; 3]> {
    points.iter().map(|p| p.map(|v| v as f32)).collect()
}

/// The auxiliary LiDAR's true mount (the paper's front-left one, roughly).
fn truth() -> Pose {
    pose_from_rt(&rpy_to_matrix(0.02, -0.01, 1.2), &Vector3::new(1.5, 0.9, -0.3))
}

/// Source points in the sensor frame of the true extrinsic.
fn source_in_sensor(patches: &[Patch], seed: u64) -> Vec<[f32; 3]> {
    let inv = truth().inverse();
    let base = sample(patches, 1500, seed);
    let sensor: Vec<[f64; 3]> = base
        .iter()
        .map(|p| {
            let q = inv.transform_point(&nalgebra::Point3::from(*p));
            [q.x, q.y, q.z]
        })
        .collect();
    to_f32(&sensor)
}

fn drift() -> ExtrinsicNoise {
    ExtrinsicNoise {
        rho: [0.05, -0.03, 0.02],
        phi: [0.01, -0.015, 0.02],
    }
}

fn prior() -> Matrix6<f64> {
    let mut p = Matrix6::zeros();
    for i in 0..3 {
        p[(i, i)] = 0.1 * (1.0f64 / 20.0).powi(2);
        p[(i + 3, i + 3)] = 0.1 * (1.0f64 / 10.0).powi(2);
    }
    p
}

fn run(patches: &[Patch]) -> (IcpOutcome, Pose) {
    let cfg = IcpConfig::default();
    let target = Target::new(to_f32(&sample(patches, 3000, 1)), &cfg).unwrap();
    let start = drift().apply(&truth());
    let out = align(&source_in_sensor(patches, 2), &start, &target, &prior(), &cfg).unwrap();
    (out, start)
}

#[test]
fn recovers_a_known_perturbation() {
    let (out, start) = run(&street());
    let before = PoseError::between(&start, &truth());
    let after = PoseError::between(&out.extrinsic, &truth());
    assert!(before.rot_deg > 1.0 && before.trans_m > 0.05, "{before:?}");
    assert!(out.converged, "{out:?}");
    assert!(out.degenerate.is_empty(), "{:?}", out.degenerate);
    assert!(after.rot_deg < 0.02 && after.trans_m < 0.005, "after {after:?}");
    // The test target is sparse (~1 m spacing on the ground): a third of the source has no
    // neighbour within the final 25 cm.
    assert!(
        out.fitness > 0.5 && out.rmse < 0.02,
        "{} {}",
        out.fitness,
        out.rmse
    );
}

#[test]
fn a_plane_is_degenerate_in_tx_ty_yaw_and_they_do_not_move() {
    let (out, start) = run(&[ground()]);
    let mut axes: Vec<&str> = out.degenerate.iter().map(|d| d.axis.as_str()).collect();
    axes.sort();
    assert_eq!(axes, ["tx", "ty", "yaw"], "{:?}", out.eigenvalues);
    let (t0, t1) = (start.translation.vector, out.extrinsic.translation.vector);
    // The start's drift along x and y stays (to the lever-arm coupling of the fitted roll/pitch).
    assert!(
        (t1.x - t0.x).abs() < 2e-3 && (t1.y - t0.y).abs() < 2e-3,
        "{t0} -> {t1}"
    );
    // What a plane observes is recovered: z, roll and pitch.
    assert!((t1.z - truth().translation.vector.z).abs() < 0.01, "z {}", t1.z);
    // The degenerate directions keep the prior's variance in the covariance.
    assert!(
        out.covariance[(0, 0)] > 0.5 * prior()[(0, 0)],
        "{}",
        out.covariance
    );
    assert!(
        out.covariance[(2, 2)] < 0.05 * prior()[(2, 2)],
        "{}",
        out.covariance
    );
}

#[test]
fn a_corridor_is_degenerate_along_it_only() {
    let (out, start) = run(&corridor());
    let axes: Vec<&str> = out.degenerate.iter().map(|d| d.axis.as_str()).collect();
    assert_eq!(axes, ["tx"], "{:?}", out.eigenvalues);
    let (t0, t1) = (start.translation.vector, out.extrinsic.translation.vector);
    assert!(
        (t1.x - t0.x).abs() < 2e-3,
        "moved along the corridor: {t0} -> {t1}"
    );
    let rot = PoseError::between(&out.extrinsic, &truth()).rot_deg;
    assert!(rot < 0.05, "rotation is observed in a corridor: {rot}°");
    assert!((t1.y - truth().translation.vector.y).abs() < 0.005);
}

#[test]
fn covariance_shrinks_with_more_structure() {
    let (a, _) = run(&street());
    let (b, _) = run(&busy_street());
    assert!(a.degenerate.is_empty() && b.degenerate.is_empty());
    for i in 0..6 {
        assert!(
            b.covariance[(i, i)] < a.covariance[(i, i)],
            "axis {i}: {} vs {}",
            b.covariance[(i, i)],
            a.covariance[(i, i)]
        );
    }
}

#[test]
fn bad_clouds_are_errors() {
    let cfg = IcpConfig::default();
    assert!(matches!(
        Target::new(Vec::new(), &cfg),
        Err(CalibError::BadCloud { .. })
    ));
    assert!(matches!(
        Target::new(vec![[0.0, 0.0, 0.0]; 5], &cfg),
        Err(CalibError::BadCloud { .. })
    ));
    let mut nan = to_f32(&sample(&street(), 100, 3));
    nan[17] = [f32::NAN, 0.0, 0.0];
    let err = Target::new(nan.clone(), &cfg).unwrap_err().to_string();
    assert!(err.contains("point 17"), "{err}");
    let target = Target::new(to_f32(&sample(&street(), 300, 1)), &cfg).unwrap();
    for source in [Vec::new(), vec![[1.0f32, 2.0, 3.0]; 3], nan] {
        let r = align(&source, &truth(), &target, &prior(), &cfg);
        assert!(
            matches!(r, Err(CalibError::BadCloud { cloud: "source", .. })),
            "{r:?}"
        );
    }
    let bad = IcpConfig { shrink: 0.0, ..cfg };
    assert!(align(&source_in_sensor(&street(), 2), &truth(), &target, &prior(), &bad).is_err());
    let nan_prior = Matrix6::from_element(f64::NAN);
    assert!(align(
        &source_in_sensor(&street(), 2),
        &truth(),
        &target,
        &nan_prior,
        &cfg
    )
    .is_err());
}

#[test]
fn no_overlap_is_not_converged_and_stays_put() {
    let cfg = IcpConfig::default();
    let target = Target::new(to_f32(&sample(&street(), 500, 1)), &cfg).unwrap();
    // A source 500 m away: no correspondence at all.
    let far: Vec<[f32; 3]> = to_f32(&sample(&street(), 200, 2))
        .iter()
        .map(|p| [p[0] + 500.0, p[1], p[2]])
        .collect();
    let out = align(&far, &truth(), &target, &prior(), &cfg).unwrap();
    assert!(!out.converged && out.iterations == 0);
    let moved = PoseError::between(&out.extrinsic, &truth());
    assert!(moved.rot_deg < 1e-9 && moved.trans_m < 1e-12, "{moved:?}");
}

#[test]
fn bit_identical_across_thread_counts() {
    let results: Vec<(Pose, Matrix6<f64>, Vec<[f32; 3]>)> = [1, 2, 3]
        .map(|threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let pts = to_f32(&sample(&busy_street(), 3000, 1));
                let (x, y, z): (Vec<f32>, Vec<f32>, Vec<f32>) = (
                    pts.iter().map(|p| p[0]).collect(),
                    pts.iter().map(|p| p[1]).collect(),
                    pts.iter().map(|p| p[2]).collect(),
                );
                let down = voxel_downsample(&x, &y, &z, 0.3, 100.0);
                let (out, _) = run(&busy_street());
                (out.extrinsic, out.covariance, down)
            })
        })
        .into_iter()
        .collect();
    for r in &results[1..] {
        assert_eq!(r.0, results[0].0);
        assert_eq!(r.1, results[0].1);
        assert_eq!(r.2, results[0].2);
    }
}

#[test]
fn normals_are_the_plane_normals_and_lines_have_none() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for _ in 0..50 {
        let n = Vector3::new(
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
        )
        .normalize();
        let u = n.cross(&Vector3::x()).normalize();
        let v = n.cross(&u);
        let pts: Vec<[f32; 3]> = (0..12)
            .map(|_| {
                let (a, b): (f64, f64) = (rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
                let p = u * a + v * b + n * 0.002 * rng.sample::<f64, _>(StandardNormal);
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect();
        let got = plane_normal(&pts, 0.05, 0.02).expect("a plane");
        let dot = (got[0] as f64 * n.x + got[1] as f64 * n.y + got[2] as f64 * n.z).abs();
        assert!(dot > 0.999, "normal {got:?} vs {n}");
    }
    // Points on a line (a far scan ring): no normal.
    let line: Vec<[f32; 3]> = (0..10)
        .map(|i| [i as f32 * 0.1, 0.001 * (i % 3) as f32, 0.0])
        .collect();
    assert!(plane_normal(&line, 0.05, 0.02).is_none());
}

#[test]
fn voxel_downsample_takes_centroids_and_drops_bad_points() {
    let x = [0.01, 0.09, 0.5, f32::NAN, 200.0];
    let y = [0.0, 0.0, 0.0, 0.0, 0.0];
    let z = [0.0, 0.0, 0.0, 0.0, 0.0];
    let d = voxel_downsample(&x, &y, &z, 0.1, 100.0);
    assert_eq!(d.len(), 2);
    assert!(
        (d[0][0] - 0.05).abs() < 1e-6 && (d[1][0] - 0.5).abs() < 1e-6,
        "{d:?}"
    );
}
