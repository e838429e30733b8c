//! The simulator's sensor randomisation (issue 29): roof LiDAR presets with
//! their beam tables, the mount height written to calibrated_sensor, mixed car sizes and Lyft's
//! constant intensity, and that a configuration without randomisation is unchanged by it.

use std::collections::BTreeSet;

use mlod::synth::{scan_sample, CarSizes, RoofRandomisation, SensorPreset, SynthConfig, Town, LYFT_MOUNTS};

fn config(presets: Vec<SensorPreset>, jitter: f64) -> SynthConfig {
    SynthConfig {
        seed: 11,
        scenes: 6,
        samples_per_scene: 1,
        roof: RoofRandomisation {
            presets,
            height_jitter_m: jitter,
        },
        car_sizes: CarSizes::Mixed,
        ..SynthConfig::default()
    }
}

#[test]
fn each_scene_scans_with_its_drawn_roof_lidar() {
    let cfg = config(vec![SensorPreset::Hdl64e, SensorPreset::Hdl32e], 0.2);
    let town = Town::generate(&cfg);
    let mut seen = BTreeSet::new();
    for scene in town.scenes.iter().take(4) {
        let preset = scene.roof.preset.expect("a preset is drawn");
        seen.insert(preset.name());
        assert!(scene.roof.dz.abs() <= 0.2);
        let mount = town.mount_of(scene, 0);
        assert!((mount.translation[2] - LYFT_MOUNTS[0].translation[2] - scene.roof.dz).abs() < 1e-12);
        let scan = scan_sample(&town, scene, 0, &cfg.lidar, cfg.seed);
        let elev = preset.elevations_deg();
        let top = &scan.lidars[0];
        let mut rings = BTreeSet::new();
        for p in &top.points {
            let ring = p[4] as usize;
            assert!(
                (1..=elev.len()).contains(&ring),
                "ring {ring} of {}",
                preset.name()
            );
            rings.insert(ring);
            let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            let e = z.atan2(x.hypot(y)).to_degrees();
            assert!(
                (e - elev[ring - 1]).abs() < 1e-3,
                "{} ring {ring}: {e}",
                preset.name()
            );
        }
        // On a mast above the roof, nearly every beam returns somewhere (the top ones may see
        // only sky).
        assert!(
            rings.len() + 4 >= elev.len(),
            "{}: {} rings",
            preset.name(),
            rings.len()
        );
        // The bumper LiDARs keep the Pandar40.
        assert!(scan.lidars[1].points.iter().all(|p| (1.0..=40.0).contains(&p[4])));
    }
    assert_eq!(seen.len(), 2, "both presets drawn over four scenes: {seen:?}");
}

#[test]
fn more_beams_give_more_points_on_the_same_street() {
    // One scene, the same layout (the roof draw does not touch the layout's generators).
    let count = |p: SensorPreset| {
        let cfg = config(vec![p], 0.0);
        let town = Town::generate(&cfg);
        scan_sample(&town, &town.scenes[0], 0, &cfg.lidar, cfg.seed).lidars[0]
            .points
            .len()
    };
    let (n32, n64, n128) = (
        count(SensorPreset::Hdl32e),
        count(SensorPreset::Hdl64e),
        count(SensorPreset::Vls128),
    );
    assert!(n32 < n64 && n64 < n128, "{n32} {n64} {n128}");
}

#[test]
fn mixed_cars_span_compacts_to_pickups_and_no_randomisation_changes_nothing() {
    let cfg = config(Vec::new(), 0.0);
    let town = Town::generate(&cfg);
    let lengths: Vec<f64> = town
        .scenes
        .iter()
        .flat_map(|s| s.actors.iter())
        .filter(|a| a.category.name() == "car")
        .map(|a| a.shape.size_lwh[0])
        .collect();
    assert!(lengths.len() > 100, "{} cars", lengths.len());
    assert!(lengths.iter().any(|&l| l < 4.2), "a compact");
    assert!(lengths.iter().any(|&l| l > 5.3), "a pickup");
    let mean = lengths.iter().sum::<f64>() / lengths.len() as f64;
    assert!((4.5..5.0).contains(&mean), "mean length {mean}");
    // Without presets and jitter every scene keeps the configured model and the real mount.
    for s in &town.scenes {
        assert_eq!(s.roof.preset, None);
        assert_eq!(town.mount_of(s, 0), LYFT_MOUNTS[0]);
    }
    // Uniform sizes (the default) draw the same layout as before the option existed.
    let uniform = Town::generate(&SynthConfig {
        car_sizes: CarSizes::Uniform,
        ..cfg
    });
    for a in uniform.scenes.iter().flat_map(|s| s.actors.iter()) {
        if a.category.name() == "car" {
            assert!((4.2..=5.0).contains(&a.shape.size_lwh[0]));
        }
    }
}

#[test]
fn lyft_intensity_is_constant_and_bad_jitter_is_refused() {
    let mut cfg = config(vec![SensorPreset::Pandar64], 0.0);
    cfg.lidar.constant_intensity = Some(100.0);
    let town = Town::generate(&cfg);
    let scan = scan_sample(&town, &town.scenes[0], 0, &cfg.lidar, cfg.seed);
    assert!(scan.lidars.iter().flat_map(|l| &l.points).all(|p| p[3] == 100.0));
    for bad in [-0.1, 1.5, f64::NAN] {
        let mut c = config(Vec::new(), 0.0);
        c.roof.height_jitter_m = bad;
        let err = c.validate().expect_err("refused").to_string();
        assert!(err.contains("roof height jitter"), "{err}");
    }
}

#[test]
fn curb_walls_line_the_planting_strip_and_leave_streets_and_actors_alone() {
    let plain = config(Vec::new(), 0.0);
    let walled_cfg = SynthConfig {
        curb_walls: 1.0,
        ..plain.clone()
    };
    let (a, b) = (Town::generate(&plain), Town::generate(&walled_cfg));
    let mut walls = 0;
    for (sa, sb) in a.streets.iter().zip(&b.streets) {
        let n = sa.statics.len();
        assert!(sb.statics.len() > n, "street {}: no walls", sa.index);
        // The street's own structures come first and are those without the walls.
        for (pa, pb) in sa.statics.iter().zip(&sb.statics[..n]) {
            assert_eq!(pa.center, pb.center);
        }
        let l = &sa.ground.layout;
        for w in &sb.statics[n..] {
            let y = w.center[1].abs();
            assert!(y > l.curb() + 0.25 && y < l.strip_outer(), "wall at |y| {y}");
            walls += 1;
        }
    }
    assert!(walls >= 20, "{walls} walls");
    // Parked cars, pedestrians and the drive are unchanged.
    for (sa, sb) in a.scenes.iter().zip(&b.scenes) {
        assert_eq!(sa.actors, sb.actors);
    }
    // The default draws none; a share outside 0..=1 is refused by name.
    assert_eq!(SynthConfig::default().curb_walls, 0.0);
    for bad in [-0.1, 1.5, f64::NAN] {
        let c = SynthConfig {
            curb_walls: bad,
            ..plain.clone()
        };
        let err = c.validate().expect_err("refused").to_string();
        assert!(err.contains("curb wall share"), "{err}");
    }
}
