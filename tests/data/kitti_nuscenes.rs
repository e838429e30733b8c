use super::*;

#[test]
fn kitti_folder_opens_with_boxes_in_the_lidar_frame_and_our_names() {
    // The folder above training/, and training/ itself, open the same dataset.
    for path in [kitti_root(), kitti_root().join("training")] {
        let ds = Dataset::open(&path).unwrap();
        assert_eq!(ds.format(), mlod::dataset::DatasetFormat::Kitti);
        assert_eq!(ds.sample_tokens(), ["000000", "000001"]);
        let mut got = Vec::new();
        for tok in ds.sample_tokens() {
            let f = ds.frame(tok).unwrap();
            assert!(f.is_single_lidar());
            assert_eq!(f.primary.info.channel, LidarChannel::Top);
            assert_eq!(f.primary.info.extrinsic, mlod::geometry::Pose::identity());
            // Reflectance 0–1 read as 0–255; 64 rings recovered from the scan order.
            let max_i = f.primary.points.intensity.iter().copied().fold(0.0f32, f32::max);
            assert!(max_i > 200.0 && max_i <= 255.0, "{max_i}");
            let rings = f.primary.points.ring.iter().copied().fold(0.0f32, f32::max);
            assert_eq!(rings, 63.0);
            assert!(f.eval_region.is_some());
            for b in &f.boxes {
                got.push((
                    tok.to_owned(),
                    b.category.clone(),
                    b.source_category.clone(),
                    b.box3d,
                ));
            }
        }
        assert_eq!(got.len(), KITTI_EXPECTED.len());
        for ((tok, cat, _, b), (etok, ecat, c, lwh, yaw)) in got.iter().zip(KITTI_EXPECTED) {
            assert_eq!((tok.as_str(), cat.as_str()), (etok, ecat));
            for k in 0..3 {
                assert!(
                    (b.center[k] - c[k]).abs() < 1e-3,
                    "{tok} {cat}: {:?} vs {c:?}",
                    b.center
                );
                assert!((b.size_lwh[k] - lwh[k]).abs() < 1e-9);
            }
            assert!((b.yaw - yaw).abs() < 1e-3, "{tok} {cat}: yaw {} vs {yaw}", b.yaw);
        }
        assert_eq!(got[2].2, "Car");
        assert!(ds.unmapped_categories().is_empty());
    }
}

#[test]
fn kitti_evaluation_ignores_what_the_camera_does_not_see_and_dontcare_regions() {
    let ds = Dataset::open(kitti_root()).unwrap();
    let f = ds.frame("000001").unwrap();
    let region = f.eval_region.clone().unwrap();
    let car = f.boxes.iter().find(|b| b.category == "car").unwrap();
    assert!(f.evaluates(&car.box3d));
    // Behind the car (outside the camera's view): ignored.
    let mut behind = car.box3d;
    behind.center = [-20.0, 3.0, -0.8];
    assert_eq!(region.verdict(&behind), mlod::dataset::RegionVerdict::OutsideView);
    // Frame 000001's DontCare regions lie around pixels 503–591 × 170–190: a box projecting into
    // them is ignored.
    let dc = region.dont_care.first().copied().unwrap();
    assert!((dc[0] - 503.89).abs() < 1e-9);
    let mut in_dc = None;
    'search: for xi in 40..120 {
        for yi in -40..40 {
            let b = mlod::geometry::Box3d::new([xi as f64, yi as f64 * 0.25, -0.8], [3.9, 1.6, 1.5], 0.0);
            if region.verdict(&b) == mlod::dataset::RegionVerdict::DontCare {
                in_dc = Some(b);
                break 'search;
            }
        }
    }
    let in_dc = in_dc.expect("some box projects into a DontCare region");
    // Scored: the truths as predictions, plus one behind and one in a DontCare region. Neither
    // extra is a false positive: AP stays 100 where it is defined and the two are counted apart.
    let mut dets = std::collections::HashMap::new();
    for tok in ds.sample_tokens() {
        let fr = ds.frame(tok).unwrap();
        let mut d: Vec<_> = fr.boxes.iter().map(|b| b.as_detection()).collect();
        if tok == "000001" {
            for b in [behind, in_dc] {
                d.push(mlod::geometry::Detection {
                    box3d: b,
                    score: 0.9,
                    category: "bicycle".into(),
                });
            }
        }
        dets.insert(tok.to_owned(), d);
    }
    let opts = mlod::eval::EvalOptions {
        kitti: mlod::eval::KittiConfig {
            difficulties: vec![("all".into(), 100.0)],
            ..Default::default()
        },
        ..Default::default()
    };
    let report = mlod::eval::evaluate_detections(&ds, &dets, &opts).unwrap();
    assert_eq!(report.predictions.outside_region, 2);
    for class in ["car", "bicycle", "pedestrian", "truck"] {
        let ap = mlod::eval::kitti::ap_cell(&report.kitti, class, "iou_0.7", "all").unwrap();
        assert!((ap - 100.0).abs() < 1e-9, "{class}: {ap}");
    }
}

#[test]
fn kitti_bad_or_missing_calib_and_labels_fail_their_frame_only() {
    let tmp = TempDir::new("kitti");
    let split = tmp.path().join("training");
    for sub in ["velodyne", "label_2", "calib"] {
        std::fs::create_dir_all(split.join(sub)).unwrap();
    }
    let src = kitti_root().join("training");
    for id in ["000000", "000001", "000002", "000003"] {
        std::fs::copy(
            src.join("velodyne/000000.bin"),
            split.join(format!("velodyne/{id}.bin")),
        )
        .unwrap();
        std::fs::copy(
            src.join("label_2/000000.txt"),
            split.join(format!("label_2/{id}.txt")),
        )
        .unwrap();
        std::fs::copy(
            src.join("calib/000000.txt"),
            split.join(format!("calib/{id}.txt")),
        )
        .unwrap();
    }
    std::fs::remove_file(split.join("calib/000001.txt")).unwrap();
    std::fs::write(
        split.join("label_2/000002.txt"),
        "Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57\nCar 0 0 0 1 2 3 4 oops\n",
    )
    .unwrap();
    std::fs::write(split.join("calib/000003.txt"), "P2: 1 2 3\n").unwrap();
    let ds = Dataset::open(tmp.path()).unwrap();
    assert_eq!(ds.sample_tokens().len(), 4);
    assert!(ds.frame("000000").is_ok());
    let e1 = ds.frame("000001").unwrap_err().to_string();
    assert!(e1.contains("calib/000001.txt") && e1.contains("missing"), "{e1}");
    let e2 = ds.frame("000002").unwrap_err().to_string();
    assert!(
        e2.contains("label_2/000002.txt:2") && e2.contains("fields"),
        "{e2}"
    );
    let e3 = ds.frame("000003").unwrap_err().to_string();
    assert!(e3.contains("calib/000003.txt:1") && e3.contains("P2"), "{e3}");
    let notes = ds.notes().join("\n");
    assert!(notes.contains("3 samples will not load"), "{notes}");
    // A truncated KITTI .bin names the 16-byte record.
    let bytes = std::fs::read(split.join("velodyne/000000.bin")).unwrap();
    std::fs::write(split.join("velodyne/000000.bin"), &bytes[..bytes.len() - 3]).unwrap();
    let e0 = ds.frame("000000").unwrap_err().to_string();
    assert!(e0.contains("multiple of 16") && e0.contains("KITTI"), "{e0}");
    // velodyne_reduced is read when velodyne is absent; an empty folder is not a dataset.
    std::fs::rename(split.join("velodyne"), split.join("velodyne_reduced")).unwrap();
    let ds = Dataset::open(&split).unwrap();
    assert!(ds.notes().join(" ").contains("velodyne_reduced"));
    assert_eq!(
        ds.frame_info("000000").unwrap().primary.filename,
        "velodyne_reduced/000000.bin"
    );
    let empty = TempDir::new("kitti-empty");
    let err = Dataset::open(empty.path()).unwrap_err().to_string();
    assert!(err.contains("KITTI") && err.contains("sample.json"), "{err}");
}

#[test]
fn nuscenes_copy_maps_category_names_and_lists_the_unmapped() {
    let tmp = TempDir::new("nuscenes");
    let mut s = three_lidar_sample("nu0", [([10.0, 5.0, 0.0], 0.3); 3]);
    s.lidars.truncate(1);
    s.lidars[0].filename = Some("samples/LIDAR_TOP/nu0.pcd.bin".into());
    s.boxes = vec![
        SynBox {
            center: [20.0, 5.0, 1.0],
            size_wlh: [1.9, 4.6, 1.7],
            yaw: 0.3,
            category: "vehicle.car",
        },
        SynBox {
            center: [14.0, 8.0, 1.0],
            size_wlh: [0.6, 0.7, 1.8],
            yaw: 0.0,
            category: "human.pedestrian.adult",
        },
        SynBox {
            center: [12.0, 2.0, 0.5],
            size_wlh: [0.5, 2.0, 1.0],
            yaw: 0.0,
            category: "movable_object.barrier",
        },
    ];
    let root = write_dataset_in(tmp.path(), &[vec![s]], "v1.0-mini");
    let ds = Dataset::open(&root).unwrap();
    assert_eq!(ds.format(), mlod::dataset::DatasetFormat::NuScenes);
    let f = ds.frame("nu0").unwrap();
    assert!(f.is_single_lidar() && !f.primary.points.is_empty());
    let names: Vec<(&str, &str)> = f
        .boxes
        .iter()
        .map(|b| (b.category.as_str(), b.source_category.as_str()))
        .collect();
    assert_eq!(
        names,
        [
            ("car", "vehicle.car"),
            ("pedestrian", "human.pedestrian.adult"),
            ("movable_object.barrier", "movable_object.barrier")
        ]
    );
    let unmapped = ds.unmapped_categories();
    assert_eq!(unmapped.len(), 1);
    assert_eq!(
        (unmapped[0].name.as_str(), unmapped[0].boxes),
        ("movable_object.barrier", 1)
    );
    assert!(ds
        .notes()
        .iter()
        .any(|n| n.contains("movable_object.barrier (1 box)")));
    // Scored as ours: the truths named `car` are a perfect car detector (it scored 0 before).
    let dets = std::collections::HashMap::from([(
        "nu0".to_owned(),
        f.boxes
            .iter()
            .filter(|b| b.category == "car")
            .map(|b| b.as_detection())
            .collect::<Vec<_>>(),
    )]);
    let report = mlod::eval::evaluate_detections(&ds, &dets, &Default::default()).unwrap();
    let ap = mlod::eval::kitti::ap_cell(&report.kitti, "car", "iou_0.7", "easy").unwrap();
    assert!((ap - 100.0).abs() < 1e-9, "{ap}");
    // The unmapped barrier is never scored: no class of its own, not a missed box.
    assert!(report.kitti.get("movable_object.barrier").is_none());
    assert!(report.kitti.get("pedestrian").is_some());
}
