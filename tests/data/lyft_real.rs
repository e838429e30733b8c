use super::*;

// ---------------------------------------------------------------------------------------------
// The real Lyft excerpt
// ---------------------------------------------------------------------------------------------

#[test]
fn real_tables_parse_with_every_field() {
    let ds = Dataset::open(real_root()).unwrap();
    let t = ds.tables();
    let counts = [
        ("scene", t.scene.len(), 1),
        ("sample", t.sample.len(), 1),
        ("sample_data", t.sample_data.len(), 10),
        ("calibrated_sensor", t.calibrated_sensor.len(), 10),
        ("sensor", t.sensor.len(), 10),
        ("ego_pose", t.ego_pose.len(), 7),
        ("sample_annotation", t.sample_annotation.len(), 4),
        ("instance", t.instance.len(), 4),
        ("category", t.category.len(), 9),
        ("attribute", t.attribute.len(), 18),
        ("visibility", t.visibility.len(), 4),
        ("log", t.log.len(), 1),
        ("map", t.map.len(), 1),
    ];
    for (name, got, want) in counts {
        assert_eq!(got, want, "{name}");
    }
    let s = t.sample.get(REAL_SAMPLE).unwrap();
    assert_eq!(s.timestamp, 1556675185903083.2);
    assert_eq!(
        s.scene_token,
        "9d0166ccd4af9c089738587f6e3d21cd9c8b6102787427da8c3b4f64161160c5"
    );

    let top = t
        .sample_data
        .get("694595c9da7827c3e3cf849c8d30585ab6fa5b51af97e94d56801c344dd7112b")
        .unwrap();
    assert_eq!(top.filename, "lidar/host-a101_lidar1_1240710385903083166.bin");
    assert_eq!(top.fileformat, "bin");
    assert!(top.is_key_frame);
    assert_eq!((top.width, top.height), (None, None));
    let cs = t.calibrated_sensor.get(&top.calibrated_sensor_token).unwrap();
    assert!(cs.camera_intrinsic.is_empty());
    assert_eq!(t.sensor.get(&cs.sensor_token).unwrap().channel, "LIDAR_TOP");
    assert!((cs.translation[0] - 1.1970962545449502).abs() < 1e-15);

    let cam = t
        .sample_data
        .get("ff8dc9f62a36f159eb30e9c62eae7bdf4726cf9c91587ceb0314400e74e89438")
        .unwrap();
    assert_eq!((cam.width, cam.height), (Some(1920), Some(1080)));
    assert_eq!(cam.fileformat, "jpeg");
    let cam_cs = t.calibrated_sensor.get(&cam.calibrated_sensor_token).unwrap();
    assert_eq!(cam_cs.camera_intrinsic.len(), 3);
    assert!(cam_cs.camera_intrinsic.iter().all(|r| r.len() == 3));

    let ann = t
        .sample_annotation
        .get("c18679b6bd6c643cddec8b6c0d8cedf1ee92d10ce6861faaf3db8b30f541f5e7")
        .unwrap();
    assert_eq!(ann.num_lidar_pts, -1);
    assert_eq!(ann.size, [2.046, 4.495, 1.849]);
    assert_eq!(ann.visibility_token, "");
    assert_eq!(ann.attribute_tokens.len(), 1);
    assert_eq!(t.map.rows()[0].filename, "maps/map_raster_palo_alto.png");
    assert_eq!(t.log.rows()[0].vehicle, "a101");
    assert_eq!(t.visibility.get("4").unwrap().level, "v80-100");
    assert_eq!(t.instance.rows()[0].nbr_annotations, 103);
}

#[test]
fn open_accepts_the_root_or_the_version_folder() {
    let a = Dataset::open(real_root()).unwrap();
    let b = Dataset::open(real_root().join("v1.01-train")).unwrap();
    assert_eq!(a.root(), real_root());
    assert_eq!(b.root(), real_root());
    assert_eq!(b.version_dir(), real_root().join("v1.01-train"));
}

#[test]
fn real_sample_list() {
    let ds = Dataset::open(real_root()).unwrap();
    let l = list(&ds);
    assert_eq!(l.len(), 1);
    assert_eq!(l[0].sample_token, REAL_SAMPLE);
    assert_eq!(
        l[0].scene_name,
        "host-a101-lidar0-1240710366399037786-1240710391298976894"
    );
    assert_eq!(
        l[0].lidar_channels,
        ["LIDAR_TOP", "LIDAR_FRONT_LEFT", "LIDAR_FRONT_RIGHT"]
    );
    assert_eq!(l[0].num_boxes, 4);
    let json = serde_json::to_value(&l).unwrap();
    assert_eq!(json[0]["num_boxes"], 4);
    assert_eq!(ds.first_sample_token(), Some(REAL_SAMPLE));
}

#[test]
fn real_extrinsics_match_notice_and_devkit() {
    let ds = Dataset::open(real_root()).unwrap();
    let info = ds.frame_info(REAL_SAMPLE).unwrap();
    assert_eq!(info.primary.channel, LidarChannel::Top);
    assert_eq!(info.primary.extrinsic, mlod::geometry::Pose::identity());
    let chans: Vec<_> = info.auxiliaries.iter().map(|l| l.channel).collect();
    assert_eq!(chans, [LidarChannel::FrontLeft, LidarChannel::FrontRight]);

    // NOTICE.md, to 1e-3 m.
    let notice = [[-2.234, -0.970, -1.336], [-2.283, 0.920, -1.333]];
    for (l, want) in info.auxiliaries.iter().zip(notice) {
        let t = l.extrinsic.translation.vector;
        for k in 0..3 {
            assert!((t[k] - want[k]).abs() < 1e-3, "{} t = {t:?}", l.channel);
        }
        // The bumper LiDARs are upside down relative to LIDAR_TOP: their z axis points down.
        let r = l.extrinsic.rotation.to_rotation_matrix();
        assert!(r[(2, 2)] < -0.99, "{}", l.channel);
    }

    // The devkit's numbers, to 1e-9.
    let exp = devkit_expected();
    for l in &info.auxiliaries {
        let e = &exp["extrinsics"][l.channel.as_str()];
        let t = f64s(&e["translation"]);
        let got = l.extrinsic.translation.vector;
        for k in 0..3 {
            assert!((got[k] - t[k]).abs() < 1e-9, "{} {got:?} vs {t:?}", l.channel);
        }
        assert!(
            quat_close(&l.extrinsic.rotation, &f64s(&e["rotation_wxyz"]), 1e-9),
            "{}",
            l.channel
        );
    }
}

#[test]
fn real_boxes_match_the_devkit() {
    let ds = Dataset::open(real_root()).unwrap();
    let info = ds.frame_info(REAL_SAMPLE).unwrap();
    assert_eq!(info.boxes.len(), 4);
    assert!(info
        .boxes
        .iter()
        .all(|b| b.category == "car" && b.num_lidar_pts == -1));
    let exp = devkit_expected();
    assert_eq!(exp["sample_token"], REAL_SAMPLE);
    let eb = exp["boxes"].as_array().unwrap();
    assert_eq!(eb.len(), info.boxes.len());
    for (b, e) in info.boxes.iter().zip(eb) {
        assert_eq!(e["annotation_token"], b.annotation_token.as_str());
        assert_eq!(e["category"], b.category.as_str());
        let c = f64s(&e["center"]);
        for k in 0..3 {
            assert!(
                (b.box3d.center[k] - c[k]).abs() < 1e-4,
                "centre {:?} vs {c:?}",
                b.box3d.center
            );
            assert!(
                (b.box3d.center[k] - c[k]).abs() < 1e-9,
                "centre {:?} vs {c:?}",
                b.box3d.center
            );
        }
        let wlh = f64s(&e["wlh"]);
        assert_eq!(b.box3d.size_lwh, [wlh[1], wlh[0], wlh[2]]);
        assert_eq!(b.box3d.size_wlh().to_vec(), wlh);
        // Our yaw is the heading yaw atan2(R10, R00) = the devkit's `yaw_zyx`.
        let yaw_zyx = e["yaw_zyx"].as_f64().unwrap();
        assert!(
            (b.box3d.yaw - yaw_zyx).abs() < 1e-4,
            "{} vs {yaw_zyx}",
            b.box3d.yaw
        );
        assert!(
            (b.box3d.yaw - yaw_zyx).abs() < 1e-9,
            "{} vs {yaw_zyx}",
            b.box3d.yaw
        );
        // The full orientation and pyquaternion's yaw are kept too.
        assert!(quat_close(&b.rotation, &f64s(&e["orientation_wxyz"]), 1e-9));
        let yaw_pyq = e["yaw"].as_f64().unwrap();
        assert!((pyquaternion_yaw(&b.rotation) - yaw_pyq).abs() < 1e-9);
    }
}

#[test]
fn real_sample_reports_its_missing_bin_files() {
    let ds = Dataset::open(real_root()).unwrap();
    let err = ds.frame(REAL_SAMPLE).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, DatasetError::MissingPointCloud { .. }), "{msg}");
    assert!(
        msg.contains("lidar/host-a101_lidar1_1240710385903083166.bin"),
        "{msg}"
    );
    assert!(
        msg.contains("694595c9da7827c3e3cf849c8d30585ab6fa5b51af97e94d56801c344dd7112b"),
        "{msg}"
    );

    // inspect still gives the boxes, plus one error per missing file.
    let report = inspect(&ds, None).unwrap();
    assert_eq!(report.sample_token, REAL_SAMPLE);
    assert_eq!(report.boxes.len(), 4);
    assert!(!report.is_complete());
    assert_eq!(report.errors.len(), 3);
    for (e, lidar) in report.errors.iter().zip(["lidar1", "lidar0", "lidar2"]) {
        let m = e.to_string();
        assert!(
            m.contains(&format!("host-a101_{lidar}_1240710385903083166.bin")) && m.contains("missing"),
            "{m}"
        );
    }
    let json = serde_json::to_value(&report).unwrap();
    let keys: Vec<_> = json.as_object().unwrap().keys().cloned().collect();
    assert_eq!(keys.len(), 4);
    assert_eq!(json["format"], "lyft");
    for k in ["sample_token", "format", "lidars", "boxes"] {
        assert!(json.get(k).is_some(), "{k}");
    }
    let l0 = &json["lidars"][0];
    assert_eq!(l0["channel"], "LIDAR_TOP");
    assert!(l0["num_points"].is_null() && l0["dropped_points"].is_null());
    assert!(l0["file"]
        .as_str()
        .unwrap()
        .ends_with("lidar/host-a101_lidar1_1240710385903083166.bin"));
    assert_eq!(f64s(&l0["extrinsic"]["translation"]), [0.0, 0.0, 0.0]);
    assert_eq!(f64s(&l0["extrinsic"]["rotation_wxyz"]), [1.0, 0.0, 0.0, 0.0]);
    let t1 = f64s(&json["lidars"][1]["extrinsic"]["translation"]);
    assert!((t1[0] + 2.234).abs() < 1e-3);
    assert_eq!(
        json["lidars"][1]["extrinsic"]["rotation_wxyz"]
            .as_array()
            .unwrap()
            .len(),
        4
    );
    let b0 = &json["boxes"][0];
    for k in ["category", "source_category", "center", "size_lwh", "yaw"] {
        assert!(b0.get(k).is_some(), "{k}");
    }
    assert_eq!(b0.as_object().unwrap().len(), 5);
    assert_eq!(b0["category"], b0["source_category"], "Lyft's names are ours");
    let exp = devkit_expected();
    for (b, e) in json["boxes"]
        .as_array()
        .unwrap()
        .iter()
        .zip(exp["boxes"].as_array().unwrap())
    {
        assert!((b["yaw"].as_f64().unwrap() - e["yaw_zyx"].as_f64().unwrap()).abs() < 1e-4);
        let (c, ce) = (f64s(&b["center"]), f64s(&e["center"]));
        assert!(c.iter().zip(&ce).all(|(a, b)| (a - b).abs() < 1e-4));
    }
}

#[test]
fn real_truncated_host_a017_bin_has_five_points() {
    let path = real_root().join("lidar/host-a017_lidar1_1236118886501000046.bin");
    let c = read_bin(&path, LoadOptions::default()).unwrap();
    assert_eq!(c.len(), 5);
    assert_eq!(c.dropped, 0);
    assert!((c.x[0] - 50.651905).abs() < 1e-5 && (c.y[0] - 4.1775036).abs() < 1e-6);
    assert!(c.intensity.iter().all(|&i| i == 100.0));
    assert!(c.ring.iter().all(|&r| r == 1.0));
}

#[test]
fn real_tables_are_written_back_byte_identically() {
    // The writer emits Python json.dump's format. Tables whose real rows all share one key order
    // and store floats as floats come back byte for byte (sample_data has two row layouts, both
    // reproduced); the others (mixed key orders, integer 0 in float fields) round-trip by value.
    let src = real_root().join("v1.01-train");
    let tables = Tables::load(&src).unwrap();
    let tmp = TempDir::new("rewrite");
    tables.write(tmp.path()).unwrap();
    // serde_json parses floats exactly only with its `float_roundtrip` feature; without it a
    // value may come back 1 ulp off and is then printed with different digits.
    let exact_floats = serde_json::from_str::<f64>("-0.21496785091935613").unwrap() == -0.21496785091935613;
    for name in [
        "sample",
        "sample_data",
        "scene",
        "sensor",
        "ego_pose",
        "instance",
        "log",
        "map",
        "visibility",
    ] {
        let a = std::fs::read(src.join(format!("{name}.json"))).unwrap();
        let b = std::fs::read(tmp.path().join(format!("{name}.json"))).unwrap();
        if exact_floats {
            assert!(
                a == b,
                "{name}.json differs:\n{}\n{}",
                String::from_utf8_lossy(&a),
                String::from_utf8_lossy(&b)
            );
        } else {
            let (va, vb): (serde_json::Value, serde_json::Value) = (
                serde_json::from_slice(&a).unwrap(),
                serde_json::from_slice(&b).unwrap(),
            );
            assert!(json_close(&va, &vb), "{name}.json differs");
            // Same layout: identical once every number is blanked out.
            let blank = |s: &[u8]| -> String {
                let s = String::from_utf8_lossy(s);
                let mut out = String::new();
                let mut in_str = false;
                for ch in s.chars() {
                    if ch == '"' {
                        in_str = !in_str;
                    }
                    if in_str || !(ch.is_ascii_digit() || ch == '.' || ch == '-' || ch == 'e') {
                        out.push(ch);
                    }
                }
                out
            };
            assert_eq!(blank(&a), blank(&b), "{name}.json layout differs");
        }
    }
    let back = Tables::load(tmp.path()).unwrap();
    assert_eq!(back.sample_annotation.rows(), tables.sample_annotation.rows());
    assert_eq!(back.calibrated_sensor.rows(), tables.calibrated_sensor.rows());
    assert_eq!(back.attribute.rows(), tables.attribute.rows());
    assert_eq!(back.category.rows(), tables.category.rows());
}

#[test]
fn missing_or_corrupt_tables_are_named() {
    let src = real_root().join("v1.01-train");
    for victim in ["instance", "sample_data", "map"] {
        let tmp = TempDir::new("missing-table");
        let dir = tmp.path().join("v1.01-train");
        std::fs::create_dir_all(&dir).unwrap();
        for e in std::fs::read_dir(&src).unwrap() {
            let p = e.unwrap().path();
            if p.file_stem().unwrap() != victim {
                std::fs::copy(&p, dir.join(p.file_name().unwrap())).unwrap();
            }
        }
        let err = Dataset::open(tmp.path()).unwrap_err();
        assert!(matches!(err, DatasetError::MissingTable { .. }), "{err}");
        assert!(err.to_string().contains(&format!("{victim}.json")), "{err}");

        // Corrupt instead of missing: the message has the file, line and column.
        std::fs::write(
            dir.join(format!("{victim}.json")),
            "[{\"token\": \"a\",\n  oops}]",
        )
        .unwrap();
        let err = Dataset::open(tmp.path()).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, DatasetError::Json { line: 2, .. }), "{msg}");
        assert!(msg.contains(&format!("{victim}.json:2:")), "{msg}");

        // A row without a required field is named too.
        std::fs::write(dir.join(format!("{victim}.json")), "[{\"nothing\": 1}]").unwrap();
        let msg = Dataset::open(tmp.path()).unwrap_err().to_string();
        assert!(
            msg.contains(&format!("{victim}.json")) && msg.contains("missing field"),
            "{msg}"
        );
    }
}

#[test]
fn open_errors_name_the_folder() {
    let tmp = TempDir::new("empty");
    let err = Dataset::open(tmp.path()).unwrap_err();
    assert!(matches!(err, DatasetError::VersionFolderNotFound { .. }), "{err}");
    let err = Dataset::open(tmp.path().join("nope")).unwrap_err();
    assert!(err.to_string().contains("nope"), "{err}");
    // Two version folders: ambiguous.
    for v in ["v1.01-train", "v1.01-test"] {
        let d = tmp.path().join(v);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("sample.json"), "[]").unwrap();
    }
    let msg = Dataset::open(tmp.path()).unwrap_err().to_string();
    assert!(msg.contains("v1.01-test, v1.01-train"), "{msg}");
}
