//! Frame + perturbation -> fused cloud with tr(Ξ): the path the GUI and CLI share.

use mlod::dataset::{Frame, LidarChannel, LidarScan, PointCloud};
use mlod::geometry::{pose_from_rt, rpy_to_matrix};
use mlod::pipeline::{fuse, FuseParams};
use mlod::uncertainty::propagate::trace;
use mlod::uncertainty::{ExtrinsicNoise, Perturbation, Prior};
use nalgebra::{Point3, Vector3};

fn cloud(n: usize, offset: f32) -> PointCloud {
    let mut c = PointCloud::with_capacity(n);
    for i in 0..n {
        let a = i as f32 * 0.37 + offset;
        c.push(
            a.cos() * (4.0 + (i % 50) as f32),
            a.sin() * (4.0 + (i % 50) as f32),
            (i % 9) as f32 * 0.2 - 1.0,
            7.0,
            (i % 40) as f32,
        );
    }
    c
}

fn frame(with_left: bool) -> Frame {
    let top = LidarScan::in_memory(
        LidarChannel::Top,
        pose_from_rt(&rpy_to_matrix(0.0, 0.0, 0.0), &Vector3::zeros()),
        cloud(3000, 0.0),
    );
    let left_pose = pose_from_rt(
        &rpy_to_matrix(3.1, -0.03, -1.5),
        &Vector3::new(-2.23, -0.97, -1.34),
    );
    let right_pose = pose_from_rt(
        &rpy_to_matrix(3.13, 0.005, 1.6),
        &Vector3::new(-2.28, 0.92, -1.33),
    );
    let mut aux = Vec::new();
    if with_left {
        aux.push(LidarScan::in_memory(
            LidarChannel::FrontLeft,
            left_pose,
            cloud(2000, 1.0),
        ));
    }
    aux.push(LidarScan::in_memory(
        LidarChannel::FrontRight,
        right_pose,
        cloud(20_000, 2.0),
    ));
    Frame::in_memory("s", top, aux, Vec::new())
}

fn params(alpha: f64, seed: u64) -> FuseParams {
    FuseParams {
        perturbation: Perturbation::new(alpha, seed).unwrap(),
        ..Default::default()
    }
}

#[test]
fn alpha_zero_is_the_nominal_fusion() {
    let f = frame(true);
    let fused = fuse(&f, &params(0.0, 1)).unwrap();
    assert_eq!(fused.len(), 25_000);
    assert_eq!(fused.lidars.len(), 3);
    for (li, scan) in f.lidars().enumerate() {
        let part = &fused.lidars[li];
        assert_eq!(part.noise, ExtrinsicNoise::ZERO);
        for i in [0, 17, scan.points.len() - 1] {
            let p = Point3::new(
                scan.points.x[i] as f64,
                scan.points.y[i] as f64,
                scan.points.z[i] as f64,
            );
            let y = scan.info.extrinsic.transform_point(&p);
            let k = part.range.start + i;
            assert!(
                (fused.x[k] as f64 - y.x).abs() < 1e-4
                    && (fused.y[k] as f64 - y.y).abs() < 1e-4
                    && (fused.z[k] as f64 - y.z).abs() < 1e-4
            );
            assert_eq!(fused.source[k], li as u8);
            // α = 0: only the measurement noise remains, tr Z = 3 · 0.02².
            assert!((fused.trace[k] - 0.0012).abs() < 1e-6);
        }
    }
}

#[test]
fn perturbation_moves_only_auxiliaries_and_trace_matches_eq_8() {
    let f = frame(true);
    let p = params(0.04, 9);
    let base = fuse(&f, &params(0.0, 9)).unwrap();
    let fused = fuse(&f, &p).unwrap();
    let top = fused.lidars[0].range.clone();
    assert_eq!(
        &fused.x[top.clone()],
        &base.x[top.clone()],
        "the primary LiDAR is never perturbed"
    );
    assert!(fused.trace[top].iter().all(|t| (t - 0.0012).abs() < 1e-6));
    let right = &fused.lidars[2];
    assert_ne!(right.noise, ExtrinsicNoise::ZERO);
    let moved = right
        .range
        .clone()
        .filter(|&k| (fused.x[k] - base.x[k]).abs() > 1e-3)
        .count();
    assert!(moved > right.range.len() / 2);
    // tr(Ξ) of an auxiliary point = eq. 8 at the applied extrinsic with Θ(α).
    let scan = &f.auxiliaries[1];
    let r = right.applied.rotation.to_rotation_matrix().into_inner();
    let t = right.applied.translation.vector;
    let prior = Prior::paper().scaled(0.04).unwrap();
    for i in [0, 999, 19_999] {
        let q = Vector3::new(
            scan.points.x[i] as f64,
            scan.points.y[i] as f64,
            scan.points.z[i] as f64,
        );
        let expect = trace(&r, &t, &q, &prior, p.linearization);
        let got = fused.trace[right.range.start + i] as f64;
        assert!((got - expect).abs() < 1e-5 * expect, "{got} vs {expect}");
    }
    assert!(fused.uncertain_fraction(0.05) > 0.0);
    let (lo, hi) = fused.trace_range().unwrap();
    assert!(lo >= 0.0012 - 1e-6 && hi > lo);
}

#[test]
fn deterministic_and_streams_independent_of_other_lidars() {
    let p = params(0.1, 3);
    let a = fuse(&frame(true), &p).unwrap();
    let b = fuse(&frame(true), &p).unwrap();
    assert_eq!(a, b);
    let without_left = fuse(&frame(false), &p).unwrap();
    assert_eq!(
        a.lidars[2].noise, without_left.lidars[1].noise,
        "FRONT_RIGHT's draw does not depend on FRONT_LEFT"
    );
    let other_seed = fuse(&frame(true), &params(0.1, 4)).unwrap();
    assert_ne!(a.lidars[2].noise, other_seed.lidars[2].noise);
}

#[test]
fn decoupled_prior_alpha_and_manual_offsets() {
    let f = frame(true);
    let mut p = params(0.0, 1);
    p.prior_alpha = Some(0.1);
    let fused = fuse(&f, &p).unwrap();
    let nominal = fuse(&f, &params(0.0, 1)).unwrap();
    assert_eq!(fused.x, nominal.x, "points are not perturbed at α = 0 ...");
    let r = fused.lidars[2].range.clone();
    assert!(
        fused.trace[r.clone()]
            .iter()
            .zip(&nominal.trace[r])
            .all(|(a, b)| a > b),
        "... but the prior says they are uncertain"
    );

    let mut p = params(0.0, 1);
    let offset = ExtrinsicNoise {
        rho: [0.1, 0.0, 0.0],
        phi: [0.0, 0.0, 0.0],
    };
    p.manual.insert(LidarChannel::FrontLeft, offset);
    let fused = fuse(&f, &p).unwrap();
    let left = fused.lidars[1].range.clone();
    for k in left {
        assert!((fused.x[k] - nominal.x[k] - 0.1).abs() < 1e-4);
    }
    p.manual.insert(
        LidarChannel::FrontLeft,
        ExtrinsicNoise {
            rho: [f64::NAN, 0.0, 0.0],
            phi: [0.0; 3],
        },
    );
    assert!(fuse(&f, &p).is_err());
}

#[test]
fn single_lidar_and_empty_clouds() {
    let top = LidarScan::in_memory(
        LidarChannel::Top,
        mlod::geometry::Pose::identity(),
        PointCloud::default(),
    );
    let f = Frame::in_memory("empty", top, Vec::new(), Vec::new());
    let fused = fuse(&f, &params(0.1, 0)).unwrap();
    assert!(fused.is_empty());
    assert_eq!(fused.uncertain_fraction(0.05), 0.0);
    assert!(fused.trace_range().is_none());
}

#[test]
fn box_stats_counts_points_inside() {
    use mlod::geometry::Box3d;
    use mlod::pipeline::box_stats;
    let mut pts = PointCloud::default();
    for i in 0..10 {
        pts.push(10.0 + i as f32 * 0.1, 0.0, 0.0, 1.0, 0.0); // inside the box below
    }
    pts.push(20.0, 0.0, 0.0, 1.0, 0.0); // outside
    let top = LidarScan::in_memory(LidarChannel::Top, mlod::geometry::Pose::identity(), pts);
    let f = Frame::in_memory("b", top, Vec::new(), Vec::new());
    let fused = fuse(&f, &params(0.0, 0)).unwrap();
    let b = Box3d::new([10.5, 0.0, 0.0], [2.0, 1.0, 1.0], 0.3);
    let s = box_stats(&fused, &b);
    assert_eq!(s.points, 10);
    assert!((s.mean_trace - 0.0012).abs() < 1e-6);
    assert_eq!(s.uncertain_fraction, 0.0);
    assert_eq!(
        box_stats(&fused, &Box3d::new([-5.0, 0.0, 0.0], [1.0; 3], 0.0)).points,
        0
    );
}
