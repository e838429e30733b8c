//! Integration tests of the ray-cast multi-LiDAR simulator (`mlod::synth`): determinism, points on
//! the surfaces they were cast on, the LiDARs' fields of view and beam angles, the written tables
//! and their links, the map raster, and the round trip through the Lyft loader.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use mlod::dataset::{Dataset, LidarChannel};
use mlod::geometry::Pose;
use mlod::synth::{
    generate, pandar40_elevations_deg, scan_sample, Hit, SampleScan, SynthConfig, SynthSummary, Town,
    LYFT_MOUNTS,
};
use nalgebra::Point3;
use serde_json::Value;

mod sensors;

/// A fresh, empty folder under cargo's per-target temporary directory.
fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("synth-tests")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Every file under `dir`, by path relative to it, with its bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let rel = path.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// One default town and the scan of its first key frame, shared by the geometry tests.
fn shared_scan() -> &'static (SynthConfig, Town, SampleScan) {
    static SCAN: OnceLock<(SynthConfig, Town, SampleScan)> = OnceLock::new();
    SCAN.get_or_init(|| {
        let cfg = SynthConfig {
            seed: 3,
            samples_per_scene: 2,
            ..SynthConfig::default()
        };
        let town = Town::generate(&cfg);
        let scan = scan_sample(&town, &town.scenes[0], 0, &cfg.lidar, cfg.seed);
        (cfg, town, scan)
    })
}

fn point(p: &[f32; 5]) -> Point3<f64> {
    Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

#[test]
fn same_seed_gives_identical_bytes_whatever_the_thread_count() {
    let cfg = SynthConfig {
        seed: 11,
        samples_per_scene: 2,
        ..SynthConfig::default()
    };
    let (a, b, c) = (fresh_dir("det-a"), fresh_dir("det-b"), fresh_dir("det-c"));
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let mut calls = Vec::new();
    let sa = pool(1)
        .install(|| generate(&cfg, &a, |done, total| calls.push((done, total))))
        .unwrap();
    let sb = pool(4).install(|| generate(&cfg, &b, |_, _| {})).unwrap();
    assert_eq!(calls, vec![(0, 2), (1, 2), (2, 2)]);
    assert_eq!(
        sb,
        SynthSummary {
            version_dir: sb.version_dir.clone(),
            map_file: sb.map_file.clone(),
            ..sa.clone()
        }
    );
    let (fa, fb) = (files(&a), files(&b));
    // 13 tables, one map, 3 LiDARs × 2 samples.
    assert_eq!(fa.len(), 13 + 1 + 6, "{:?}", fa.keys().collect::<Vec<_>>());
    assert_eq!(fa, fb, "same seed, different bytes");
    assert_eq!(sa.bytes, fa.values().map(|v| v.len() as u64).sum::<u64>());

    let other = SynthConfig { seed: 12, ..cfg };
    generate(&other, &c, |_, _| {}).unwrap();
    let fc = files(&c);
    assert_ne!(
        fa.get("v1.01-train/sample_annotation.json"),
        fc.get("v1.01-train/sample_annotation.json")
    );
    let bins = |f: &BTreeMap<String, Vec<u8>>| {
        f.iter()
            .filter(|(k, _)| k.ends_with(".bin"))
            .map(|(_, v)| v.clone())
            .collect::<Vec<_>>()
    };
    assert_ne!(
        bins(&fa),
        bins(&fc),
        "a different seed must give different clouds"
    );
}

#[test]
fn every_point_lies_on_the_surface_it_was_cast_on() {
    let (_, town, scan) = shared_scan();
    let scene = &town.scenes[0];
    let street = town.street_of(scene);
    let mut per_kind = HashMap::new();
    for (mount, lidar) in LYFT_MOUNTS.iter().zip(&scan.lidars) {
        let pose: Pose = town.lidar_pose(scene, 0, mount);
        assert_eq!(lidar.points.len(), lidar.hits.len());
        for (p, hit) in lidar.points.iter().zip(&lidar.hits) {
            let w = pose.transform_point(&point(p));
            let w = [w.x, w.y, w.z];
            match *hit {
                Hit::Actor(a) => {
                    let actor = &scene.actors[a as usize];
                    let b = town.actor_box(scene, a as usize, 0).unwrap();
                    assert!(
                        b.contains(w, 0.1),
                        "{:?} point {w:?} outside its box {b:?}",
                        actor.category
                    );
                    // On the shape's surface: inside it grown by 10 cm, outside it shrunk by 10 cm.
                    let local = b.to_local(w);
                    assert!(
                        actor.shape.contains(&local, 0.1),
                        "{:?}: {local:?} off the shape",
                        actor.category
                    );
                    assert!(
                        !actor.shape.contains(&local, -0.1),
                        "{:?}: {local:?} deep inside",
                        actor.category
                    );
                }
                Hit::Ground => {
                    let base = street.ground.base_height(w[0], w[1]);
                    let top = street
                        .ground
                        .height(w[0], w[1])
                        .max(base + street.ground.layout.curb_height);
                    assert!(
                        w[2] > base - 0.1 && w[2] < top + 0.1,
                        "ground point {w:?} at base {base}"
                    );
                }
                Hit::Static => {}
            }
            *per_kind.entry(std::mem::discriminant(hit)).or_insert(0usize) += 1;
        }
    }
    // All three kinds of surface are seen, and many actors.
    assert_eq!(per_kind.len(), 3);
    let counts = scan.actor_point_counts(scene.actors.len());
    assert!(counts.iter().filter(|&&c| c > 0).count() >= 15, "{counts:?}");
}

#[test]
fn top_lidar_sees_all_around_and_bumper_lidars_about_225_degrees() {
    let (_, _, scan) = shared_scan();
    let mut covered = Vec::new();
    for (mount, lidar) in LYFT_MOUNTS.iter().zip(&scan.lidars) {
        // Azimuth about the sensor, in the ego frame (x forward, y left), in 1° bins.
        let pose = mount.pose();
        let mut bins = [false; 360];
        for p in &lidar.points {
            let e = pose.transform_point(&point(p));
            let az = (e.y - mount.translation[1])
                .atan2(e.x - mount.translation[0])
                .to_degrees();
            bins[(az.rem_euclid(360.0) as usize).min(359)] = true;
        }
        let deg = bins.iter().filter(|&&b| b).count();
        eprintln!("{}: {deg}° covered", mount.channel);
        covered.push((mount.channel, deg, bins));
    }
    let (_, top, _) = covered[0];
    assert!(top >= 358, "LIDAR_TOP covers {top}°");
    for &(channel, deg, bins) in &covered[1..] {
        assert!((210..=240).contains(&deg), "{channel} covers {deg}°");
        // Forward is always seen; the own side is seen, the far side is hidden by the car.
        let (own, far) = if channel == "LIDAR_FRONT_LEFT" {
            (90, 270)
        } else {
            (270, 90)
        };
        assert!(bins[0] && bins[own] && !bins[far], "{channel}");
        // What the car hides is one arc: from just behind the sensor, across the car, to the
        // front corner on the far side.
        let hidden: Vec<usize> = (0..360).filter(|&b| !bins[(own + b) % 360]).collect();
        let arc = hidden.last().unwrap() - hidden.first().unwrap() + 1;
        assert!(
            arc <= hidden.len() + 3,
            "{channel}: hidden bins {hidden:?} are not one arc"
        );
    }
    // The roof hides the top LiDAR's lowest beams: many rays blocked, none of the bumpers' forward ones.
    assert!(scan.lidars[0].blocked_by_ego > 1800);
}

#[test]
fn beams_have_the_pandar40_elevations_and_rings() {
    let (cfg, _, scan) = shared_scan();
    let elev = pandar40_elevations_deg();
    for lidar in &scan.lidars {
        let mut rings = BTreeSet::new();
        for p in &lidar.points {
            let ring = p[4] as usize;
            assert!((1..=40).contains(&ring) && p[4].fract() == 0.0, "ring {}", p[4]);
            rings.insert(ring);
            let q = point(p);
            let e = q.z.atan2(q.x.hypot(q.y)).to_degrees();
            assert!((e - elev[ring - 1]).abs() < 1e-3, "ring {ring}: elevation {e}");
            let r = q.coords.norm();
            assert!(
                r >= cfg.lidar.min_range_m - 0.1 && r <= cfg.lidar.max_range_m + 0.1,
                "range {r}"
            );
            assert!(
                (0.0..=255.0).contains(&p[3]) && p[3].fract() == 0.0,
                "intensity {}",
                p[3]
            );
        }
        assert!(rings.len() >= 30, "only {} rings return", rings.len());
    }
    // Points reach far (objects out to 80 m) and the top LiDAR returns most of its rays.
    let top = &scan.lidars[0];
    let far = top
        .points
        .iter()
        .filter(|p| point(p).coords.xy().norm() > 60.0)
        .count();
    assert!(far > 100, "{far} points beyond 60 m");
    assert!(top.points.len() > 30_000, "{} points", top.points.len());
    // Lane paint is brighter than asphalt.
    let ground: Vec<f32> = top
        .points
        .iter()
        .zip(&top.hits)
        .filter(|(_, h)| **h == Hit::Ground)
        .map(|(p, _)| p[3])
        .collect();
    let bright = ground.iter().filter(|&&i| i > 60.0).count();
    assert!(
        bright > 0 && bright < ground.len() / 4,
        "{bright} of {}",
        ground.len()
    );
}

fn table(dir: &Path, name: &str) -> Vec<Value> {
    let bytes = std::fs::read(dir.join("v1.01-train").join(format!("{name}.json"))).unwrap();
    // Written like Python's json.dump: one line, ", " and ": " separators, trailing newline.
    assert!(bytes.starts_with(b"[") && bytes.ends_with(b"]\n"), "{name}");
    assert_eq!(bytes.iter().filter(|&&b| b == b'\n').count(), 1, "{name}");
    serde_json::from_slice::<Vec<Value>>(&bytes).unwrap()
}

fn by_token(rows: &[Value]) -> HashMap<String, &Value> {
    let map: HashMap<String, &Value> = rows
        .iter()
        .map(|r| (r["token"].as_str().unwrap().to_owned(), r))
        .collect();
    assert_eq!(map.len(), rows.len(), "duplicate tokens");
    map
}

/// Follows a prev/next chain from `first`; checks the back links and returns the tokens.
fn chain(rows: &HashMap<String, &Value>, first: &str) -> Vec<String> {
    let mut out = vec![first.to_owned()];
    assert_eq!(rows[first]["prev"], "");
    loop {
        let cur = out.last().unwrap().clone();
        let next = rows[&cur]["next"].as_str().unwrap();
        if next.is_empty() {
            return out;
        }
        assert_eq!(rows[next]["prev"], cur.as_str());
        out.push(next.to_owned());
    }
}

#[test]
fn tables_are_complete_and_linked_and_the_loader_reads_them_back() {
    let cfg = SynthConfig {
        seed: 5,
        scenes: 2,
        samples_per_scene: 2,
        ..SynthConfig::default()
    };
    let dir = fresh_dir("tables");
    let summary = generate(&cfg, &dir, |_, _| {}).unwrap();
    assert_eq!((summary.scenes, summary.samples, summary.sample_data), (2, 4, 12));

    let scenes = table(&dir, "scene");
    let samples = table(&dir, "sample");
    let sample_data = table(&dir, "sample_data");
    let annotations = table(&dir, "sample_annotation");
    let instances = table(&dir, "instance");
    let logs = table(&dir, "log");
    let maps = table(&dir, "map");
    let (ego_poses, calibrated) = (table(&dir, "ego_pose"), table(&dir, "calibrated_sensor"));
    let (sensors, categories, attributes) = (
        table(&dir, "sensor"),
        table(&dir, "category"),
        table(&dir, "attribute"),
    );
    let (s_idx, sd_idx, a_idx) = (by_token(&samples), by_token(&sample_data), by_token(&annotations));
    let (ep_idx, cs_idx) = (by_token(&ego_poses), by_token(&calibrated));
    let (sensor_idx, cat_idx, log_idx) = (by_token(&sensors), by_token(&categories), by_token(&logs));
    let attr_idx = by_token(&attributes);
    assert_eq!(table(&dir, "visibility").len(), 4);
    assert_eq!(cat_idx.len(), 9);
    for t in scenes
        .iter()
        .chain(&samples)
        .chain(&sample_data)
        .chain(&annotations)
        .chain(&instances)
    {
        let token = t["token"].as_str().unwrap();
        assert!(
            token.len() == 64 && token.chars().all(|c| c.is_ascii_hexdigit()),
            "{token}"
        );
    }

    for scene in &scenes {
        let tokens = chain(&s_idx, scene["first_sample_token"].as_str().unwrap());
        assert_eq!(tokens.len() as u64, scene["nbr_samples"].as_u64().unwrap());
        assert_eq!(
            tokens.last().unwrap(),
            scene["last_sample_token"].as_str().unwrap()
        );
        assert!(log_idx.contains_key(scene["log_token"].as_str().unwrap()));
        assert!(scene["name"].as_str().unwrap().starts_with("host-a101-lidar0-"));
    }
    // Each sample has one key-frame sweep per LiDAR; per channel the sweeps form a chain.
    let mut channel_of = HashMap::new();
    for sd in &sample_data {
        assert!(s_idx.contains_key(sd["sample_token"].as_str().unwrap()));
        assert!(ep_idx.contains_key(sd["ego_pose_token"].as_str().unwrap()));
        assert_eq!(sd["is_key_frame"], true);
        assert_eq!(sd["fileformat"], "bin");
        assert!(sd.get("width").is_none(), "LiDAR rows have no width");
        let cs = cs_idx[sd["calibrated_sensor_token"].as_str().unwrap()];
        let sensor = sensor_idx[cs["sensor_token"].as_str().unwrap()];
        let channel = sensor["channel"].as_str().unwrap();
        let file_index = match channel {
            "LIDAR_TOP" => 1,
            "LIDAR_FRONT_LEFT" => 0,
            _ => 2,
        };
        let name = sd["filename"].as_str().unwrap();
        let prefix = format!("lidar/host-a101_lidar{file_index}_");
        assert!(name.starts_with(&prefix) && name.ends_with(".bin"), "{name}");
        assert_eq!(name[prefix.len()..name.len() - 4].len(), 19, "{name}");
        let size = std::fs::metadata(dir.join(name)).unwrap().len();
        assert!(size > 0 && size.is_multiple_of(20));
        channel_of.insert(sd["token"].as_str().unwrap().to_owned(), channel.to_owned());
    }
    for sd in sample_data.iter().filter(|sd| sd["prev"] == "") {
        let tokens = chain(&sd_idx, sd["token"].as_str().unwrap());
        assert_eq!(tokens.len(), 2);
        assert!(tokens.iter().all(|t| channel_of[t] == channel_of[&tokens[0]]));
    }
    // Instances chain their annotations; every annotation is reachable from one instance.
    let mut reached = 0;
    for inst in &instances {
        assert!(cat_idx.contains_key(inst["category_token"].as_str().unwrap()));
        let tokens = chain(&a_idx, inst["first_annotation_token"].as_str().unwrap());
        assert_eq!(tokens.len() as u64, inst["nbr_annotations"].as_u64().unwrap());
        assert_eq!(
            tokens.last().unwrap(),
            inst["last_annotation_token"].as_str().unwrap()
        );
        assert!(tokens.iter().all(|t| a_idx[t]["instance_token"] == inst["token"]));
        reached += tokens.len();
    }
    assert_eq!(reached, annotations.len());
    for a in &annotations {
        assert!(a["num_lidar_pts"].as_i64().unwrap() >= 1);
        let q: Vec<f64> = a["rotation"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert!(q[1] == 0.0 && q[2] == 0.0 && (q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(attr_idx.contains_key(a["attribute_tokens"][0].as_str().unwrap()));
    }
    assert_eq!(maps.len(), 1);
    let map_logs: BTreeSet<&str> = maps[0]["log_tokens"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(
        map_logs,
        logs.iter().map(|l| l["token"].as_str().unwrap()).collect()
    );

    // The map raster: grayscale as the devkit's MapMask wants it, and every ego pose on a
    // drivable (255) pixel at px = x / 0.1, py = height − y / 0.1.
    let img = image::open(dir.join(maps[0]["filename"].as_str().unwrap())).unwrap();
    assert_eq!(img.color(), image::ColorType::L8);
    let img = img.to_luma8();
    for ep in ep_idx.values() {
        let t: Vec<f64> = ep["translation"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let px = (t[0] / 0.1).round() as u32;
        let py = (f64::from(img.height()) - t[1] / 0.1).round() as u32;
        assert_eq!(
            img.get_pixel(px, py).0,
            [255],
            "ego at {t:?} is off the drivable surface"
        );
    }

    // The loader reads it back: extrinsics are the real mounts, all boxes and points are there.
    let ds = Dataset::open(&dir).unwrap();
    let top_inv = LYFT_MOUNTS[0].pose().inverse();
    let town = Town::generate(&cfg);
    for (k, sample) in samples.iter().enumerate().take(2) {
        let token = sample["token"].as_str().unwrap();
        let frame = ds.frame(token).unwrap();
        assert_eq!(frame.auxiliaries.len(), 2);
        let n_boxes = annotations.iter().filter(|a| a["sample_token"] == token).count();
        assert_eq!(frame.boxes.len(), n_boxes);
        let scan = scan_sample(&town, &town.scenes[0], k, &cfg.lidar, cfg.seed);
        let mut base_points = Vec::new();
        for (mount, written) in LYFT_MOUNTS.iter().zip(&scan.lidars) {
            let channel = LidarChannel::from_channel(mount.channel).unwrap();
            let lidar = frame.lidar(channel).unwrap();
            let expected = top_inv * mount.pose();
            let d = lidar.info.extrinsic.inverse() * expected;
            assert!(
                d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-9,
                "{}",
                mount.channel
            );
            assert_eq!(lidar.points.len(), written.points.len());
            for (i, p) in written.points.iter().enumerate() {
                let q = [
                    lidar.points.x[i],
                    lidar.points.y[i],
                    lidar.points.z[i],
                    lidar.points.intensity[i],
                    lidar.points.ring[i],
                ];
                assert_eq!(&q, p);
                base_points.push(lidar.info.extrinsic.transform_point(&point(p)));
            }
        }
        // Every annotated box holds at least its num_lidar_pts points of the base-frame cloud.
        for b in &frame.boxes {
            let inside = base_points
                .iter()
                .filter(|p| b.box3d.contains([p.x, p.y, p.z], 0.1))
                .count();
            assert!(
                inside as i64 >= b.num_lidar_pts,
                "{} holds {inside} < {}",
                b.category,
                b.num_lidar_pts
            );
        }
        let cats: BTreeSet<&str> = frame.boxes.iter().map(|b| b.category.as_str()).collect();
        assert!(cats.contains("car") && cats.contains("pedestrian"), "{cats:?}");
    }
}

#[test]
fn car_boxes_have_lyft_sizes() {
    let (_, town, _) = shared_scan();
    for scene in &town.scenes {
        for a in scene.actors.iter().filter(|a| a.category.name() == "car") {
            let [l, w, h] = a.shape.size_lwh;
            assert!((4.2..=5.0).contains(&l) && (1.8..=2.1).contains(&w) && (1.4..=1.9).contains(&h));
        }
        assert!(scene.actors.iter().any(|a| a.category.name() == "truck"
            || a.category.name() == "other_vehicle"
            || a.category.name() == "bus"));
    }
}

#[test]
fn invalid_configurations_are_refused_before_writing() {
    let dir = fresh_dir("invalid");
    for cfg in [
        SynthConfig {
            scenes: 0,
            ..SynthConfig::default()
        },
        SynthConfig {
            samples_per_scene: 100_000,
            ..SynthConfig::default()
        },
        SynthConfig {
            annotation_range_m: f64::NAN,
            ..SynthConfig::default()
        },
    ] {
        let err = generate(&cfg, &dir, |_, _| {}).unwrap_err();
        assert!(
            err.to_string().starts_with("invalid synth configuration"),
            "{err}"
        );
    }
    assert!(files(&dir).is_empty());
}
