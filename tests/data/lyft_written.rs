use super::*;

#[test]
fn synthetic_three_lidar_frame_loads_points_and_consistent_extrinsics() {
    let tmp = TempDir::new("three");
    // Three sweeps with slightly different ego poses (the car moved between them).
    let egos = [EGO, ([100.3, 200.2, -18.0], 0.71), ([100.6, 200.4, -18.01], 0.72)];
    let root = write_dataset(tmp.path(), &[vec![three_lidar_sample("s0", egos)]]);
    let ds = Dataset::open(&root).unwrap();
    let f = ds.frame("s0").unwrap();
    assert!(!f.is_single_lidar());
    assert_eq!(f.num_points(), 100);
    assert_eq!(f.primary.points.len(), 50);
    assert_eq!(f.lidar(LidarChannel::FrontLeft).unwrap().points.len(), 30);
    assert_eq!(f.lidar(LidarChannel::FrontRight).unwrap().points.len(), 20);
    assert!(f
        .lidars()
        .all(|l| l.points.dropped == 0 && l.points.is_consistent()));
    assert_eq!(f.primary.points.x[1], some_points(2, 0.0)[1][0]);

    // A global point seen by each LiDAR maps to the same base-frame point through T^b_{l_i}.
    let pg = Point3::new(120.0, 190.0, -17.0);
    let to_sensor =
        |l: &mlod::dataset::LidarInfo| (l.ego_to_global * l.sensor_to_ego).inverse_transform_point(&pg);
    let p_base = to_sensor(&f.primary.info);
    for l in f.lidars() {
        let p = l.info.extrinsic.transform_point(&to_sensor(&l.info));
        assert!((p - p_base).norm() < 1e-9, "{}", l.info.channel);
    }
    // With one shared ego pose the extrinsic is just T_ego<-top^-1 · T_ego<-i.
    let tmp2 = TempDir::new("three-same-ego");
    let root2 = write_dataset(tmp2.path(), &[vec![three_lidar_sample("s0", [EGO; 3])]]);
    let f2 = Dataset::open(&root2).unwrap().frame("s0").unwrap();
    let left = f2.lidar(LidarChannel::FrontLeft).unwrap();
    let want = f2.primary.info.sensor_to_ego.inverse() * left.info.sensor_to_ego;
    assert!((left.info.extrinsic.translation.vector - want.translation.vector).norm() < 1e-9);
    assert!(left.info.extrinsic.rotation.angle_to(&want.rotation) < 1e-9);
}

#[test]
fn synthetic_boxes_are_moved_into_the_base_frame_like_the_devkit() {
    let tmp = TempDir::new("boxes");
    let mut s = three_lidar_sample("s0", [EGO; 3]);
    s.boxes = vec![
        SynBox {
            center: [110.0, 205.0, -17.0],
            size_wlh: [1.9, 4.6, 1.6],
            yaw: 0.3,
            category: "car",
        },
        SynBox {
            center: [95.0, 190.0, -17.5],
            size_wlh: [0.6, 0.7, 1.8],
            yaw: -2.9,
            category: "pedestrian",
        },
    ];
    let root = write_dataset(tmp.path(), &[vec![s]]);
    let ds = Dataset::open(&root).unwrap();
    let f = ds.frame("s0").unwrap();
    assert_eq!(f.boxes.len(), 2);
    // Reference with plain matrices: c_b = R_cs^T (R_e^T (c - t_e) - t_cs).
    let r_e = rpy_to_matrix(0.0, 0.0, EGO.1);
    let r_cs = rpy_to_matrix(TOP_MOUNT.1[0], TOP_MOUNT.1[1], TOP_MOUNT.1[2]);
    let t_e = Vector3::from(EGO.0);
    let t_cs = Vector3::from(TOP_MOUNT.0);
    for (b, (cat, c, yaw, wlh)) in f.boxes.iter().zip([
        ("car", [110.0, 205.0, -17.0], 0.3, [1.9, 4.6, 1.6]),
        ("pedestrian", [95.0, 190.0, -17.5], -2.9, [0.6, 0.7, 1.8]),
    ]) {
        assert_eq!(b.category, cat);
        assert_eq!(b.num_lidar_pts, 7);
        let want = r_cs.transpose() * (r_e.transpose() * (Vector3::from(c) - t_e) - t_cs);
        for k in 0..3 {
            assert!((b.box3d.center[k] - want[k]).abs() < 1e-9);
        }
        let r: Matrix3<f64> = r_cs.transpose() * r_e.transpose() * rpy_to_matrix(0.0, 0.0, yaw);
        assert!((b.box3d.yaw - yaw_of(&r)).abs() < 1e-9);
        assert!((b.rotation.to_rotation_matrix().matrix() - r).abs().max() < 1e-9);
        assert_eq!(b.box3d.size_lwh, [wlh[1], wlh[0], wlh[2]]);
    }
    // inspect gives the same numbers, and complete point counts.
    let report = inspect(&ds, Some("s0")).unwrap();
    assert!(report.is_complete(), "{:?}", report.errors);
    assert_eq!(
        report.lidars.iter().map(|l| l.num_points).collect::<Vec<_>>(),
        [Some(50), Some(30), Some(20)]
    );
    assert_eq!(report.boxes[0].center, f.boxes[0].box3d.center);
    assert_eq!(report.boxes[1].yaw, f.boxes[1].box3d.yaw);
    assert!(report.lidars.iter().all(|l| l.extrinsic.rotation_wxyz[0] >= 0.0));
    let q = &report.lidars[1].extrinsic.rotation_wxyz;
    let q = quat_from_wxyz(*q).unwrap();
    assert!(q.angle_to(&f.auxiliaries[0].info.extrinsic.rotation) < 1e-12);
}

#[test]
fn single_lidar_sample_and_missing_lidar_top() {
    let tmp = TempDir::new("single");
    let single = SynSample {
        token: "only-top".into(),
        lidars: vec![lidar("LIDAR_TOP", &some_points(12, 0.0), EGO)],
        boxes: vec![SynBox {
            center: [101.0, 201.0, -17.0],
            size_wlh: [2.0, 4.5, 1.5],
            yaw: 0.0,
            category: "truck",
        }],
    };
    let no_top = SynSample {
        token: "no-top".into(),
        lidars: vec![lidar("LIDAR_FRONT_LEFT", &some_points(12, 0.0), EGO)],
        boxes: vec![],
    };
    let root = write_dataset(tmp.path(), &[vec![single, no_top]]);
    let ds = Dataset::open(&root).unwrap();
    let f = ds.frame("only-top").unwrap();
    assert!(f.is_single_lidar());
    assert_eq!(f.num_points(), 12);
    assert_eq!(f.primary.info.extrinsic, mlod::geometry::Pose::identity());
    assert_eq!(f.boxes[0].category, "truck");
    let r = inspect(&ds, Some("only-top")).unwrap();
    assert_eq!(r.lidars.len(), 1);

    let err = ds.frame("no-top").unwrap_err();
    assert!(matches!(err, DatasetError::NoLidarTop { .. }), "{err}");
    assert!(err.to_string().contains("no-top") && err.to_string().contains("LIDAR_TOP"));
    let err = ds.frame("nope").unwrap_err();
    assert!(matches!(err, DatasetError::UnknownSample { .. }), "{err}");

    let l = list(&ds);
    assert_eq!(l[0].lidar_channels, ["LIDAR_TOP"]);
    assert_eq!(l[1].lidar_channels, ["LIDAR_FRONT_LEFT"]);
    assert_eq!((l[0].num_boxes, l[1].num_boxes), (1, 0));
}

#[test]
fn nan_points_are_dropped_and_counted() {
    let tmp = TempDir::new("nan");
    let mut pts = some_points(10, 0.0);
    pts[2][0] = f32::NAN;
    pts[5][2] = f32::INFINITY;
    pts[9][3] = f32::NAN;
    let s = SynSample {
        token: "s".into(),
        lidars: vec![lidar("LIDAR_TOP", &pts, EGO)],
        boxes: vec![],
    };
    let root = write_dataset(tmp.path(), &[vec![s]]);
    let ds = Dataset::open(&root).unwrap();
    let f = ds.frame("s").unwrap();
    assert_eq!(f.primary.points.len(), 7);
    assert_eq!(f.primary.points.dropped, 3);
    assert!(f
        .primary
        .points
        .x
        .iter()
        .chain(&f.primary.points.z)
        .all(|v| v.is_finite()));
    let r = inspect(&ds, None).unwrap();
    assert_eq!(
        (r.lidars[0].num_points, r.lidars[0].dropped_points),
        (Some(7), Some(3))
    );
}

#[test]
fn truncated_bin_is_an_error_and_lenient_trims() {
    let tmp = TempDir::new("trunc");
    let mut bin = bin_of(&some_points(4, 0.0));
    bin.extend_from_slice(&[1, 2, 3]);
    let mut l = lidar("LIDAR_TOP", &[], EGO);
    l.bin = Some(bin);
    let root = write_dataset(
        tmp.path(),
        &[vec![SynSample {
            token: "s".into(),
            lidars: vec![l],
            boxes: vec![],
        }]],
    );
    let ds = Dataset::open(&root).unwrap();
    let err = ds.frame("s").unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(err, DatasetError::TruncatedPointCloud { size: 83, .. }),
        "{msg}"
    );
    assert!(
        msg.contains("lidar/s_LIDAR_TOP.bin") && msg.contains("83"),
        "{msg}"
    );
    let f = ds.frame_with("s", LoadOptions { lenient: true }).unwrap();
    assert_eq!(f.primary.points.len(), 4);
    assert_eq!(f.primary.points.trimmed_bytes, 3);
    assert_eq!(f.warnings.len(), 1);
    assert!(f.warnings[0].contains("s_LIDAR_TOP.bin"), "{:?}", f.warnings);
    let r = inspect(&ds, None).unwrap();
    assert_eq!(r.errors.len(), 1);
    assert_eq!(r.lidars[0].num_points, None);
}

#[test]
fn path_traversal_is_rejected_and_other_samples_still_load() {
    let tmp = TempDir::new("traversal");
    let data = tmp.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    // A file outside the root that a "../" filename would reach.
    std::fs::write(tmp.path().join("x.bin"), bin_of(&some_points(3, 0.0))).unwrap();
    let mut a = lidar("LIDAR_TOP", &[], EGO);
    a.filename = Some("../x.bin".into());
    a.bin = None;
    let mut b = lidar("LIDAR_TOP", &[], EGO);
    b.filename = Some("/etc/passwd".into());
    b.bin = None;
    let mut c = lidar("LIDAR_TOP", &some_points(3, 0.0), EGO);
    c.filename = Some("lidar/../../x.bin".into());
    c.bin = None;
    let good = lidar("LIDAR_TOP", &some_points(5, 0.0), EGO);
    let samples = vec![
        SynSample {
            token: "dotdot".into(),
            lidars: vec![a],
            boxes: vec![],
        },
        SynSample {
            token: "absolute".into(),
            lidars: vec![b],
            boxes: vec![],
        },
        SynSample {
            token: "nested".into(),
            lidars: vec![c],
            boxes: vec![],
        },
        SynSample {
            token: "good".into(),
            lidars: vec![good],
            boxes: vec![],
        },
    ];
    let root = write_dataset(&data, &[samples]);
    let ds = Dataset::open(&root).unwrap();
    for (token, filename) in [
        ("dotdot", "../x.bin"),
        ("absolute", "/etc/passwd"),
        ("nested", "lidar/../../x.bin"),
    ] {
        let err = ds.frame(token).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, DatasetError::UnsafePath { .. }), "{msg}");
        assert!(
            msg.contains(&format!("sd-{token}-LIDAR_TOP")) && msg.contains(filename),
            "{msg}"
        );
    }
    assert_eq!(ds.frame("good").unwrap().num_points(), 5);
}

#[test]
fn missing_bin_names_file_and_token_and_other_samples_load() {
    let tmp = TempDir::new("missing-bin");
    let mut gone = three_lidar_sample("gone", [EGO; 3]);
    gone.lidars[2].bin = None;
    let root = write_dataset(tmp.path(), &[vec![three_lidar_sample("ok", [EGO; 3]), gone]]);
    let ds = Dataset::open(&root).unwrap();
    let err = ds.frame("gone").unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, DatasetError::MissingPointCloud { .. }), "{msg}");
    assert!(
        msg.contains("lidar/gone_LIDAR_FRONT_RIGHT.bin") && msg.contains("sd-gone-LIDAR_FRONT_RIGHT"),
        "{msg}"
    );
    assert_eq!(ds.frame("ok").unwrap().num_points(), 100);
    let r = inspect(&ds, Some("gone")).unwrap();
    assert_eq!(r.errors.len(), 1);
    assert_eq!(r.lidars[2].num_points, None);
    assert_eq!(r.lidars[0].num_points, Some(50));
}

#[test]
fn samples_are_listed_in_scene_order() {
    let tmp = TempDir::new("order");
    let scene = |names: &[&str]| -> Vec<SynSample> {
        names
            .iter()
            .map(|n| SynSample {
                token: (*n).into(),
                lidars: vec![lidar("LIDAR_TOP", &some_points(1, 0.0), EGO)],
                boxes: vec![],
            })
            .collect()
    };
    // sample.json holds them reversed; the chains give the order back.
    let root = write_dataset(tmp.path(), &[scene(&["a3", "a1", "a2"]), scene(&["b2", "b1"])]);
    let ds = Dataset::open(&root).unwrap();
    assert_eq!(ds.sample_tokens(), ["a3", "a1", "a2", "b2", "b1"]);
    let l = list(&ds);
    assert_eq!(
        l.iter().map(|s| s.scene_name.as_str()).collect::<Vec<_>>(),
        [
            "synthetic-0",
            "synthetic-0",
            "synthetic-0",
            "synthetic-1",
            "synthetic-1"
        ]
    );
    assert_eq!(inspect(&ds, None).unwrap().sample_token, "a3");
}

#[test]
fn write_bin_and_read_bin_round_trip() {
    let tmp = TempDir::new("bin");
    let mut c = PointCloud::with_capacity(3);
    c.push(1.0, 2.0, 3.0, 4.0, 5.0);
    c.push(-1.5, 0.25, 1e-3, 0.0, 39.0);
    let p = tmp.path().join("lidar/a.bin");
    write_bin(&p, &c).unwrap();
    assert_eq!(std::fs::metadata(&p).unwrap().len(), 40);
    assert_eq!(read_bin(&p, LoadOptions::default()).unwrap(), c);
    let err = read_bin(&tmp.path().join("lidar/none.bin"), LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("none.bin"));
}
