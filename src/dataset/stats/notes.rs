//! [`out_of_depth_notes`]: what differs between a model's training data and the data it is
//! given, in words, from two [`StatsSummary`]s.

use super::StatsSummary;

/// Tolerances of [`out_of_depth_notes`].
const SIZE_TOLERANCE_M: f64 = 0.3;
const GROUND_TOLERANCE_M: f64 = 0.3;
const POINTS_RATIO: f64 = 2.0;

/// What differs between the data a model was trained on and the data it is given, beyond sensible
/// tolerances, in words: rings, constant or shifted intensity, car size (≥ 0.3 m in length, width
/// or height), the sensor's height above the ground (≥ 0.3 m), points per sweep (≥ 2×), LiDARs
/// the model saw that the data lacks. Empty when nothing does.
pub fn out_of_depth_notes(trained_on: &StatsSummary, data: &StatsSummary) -> Vec<String> {
    let mut notes = Vec::new();
    let t = trained_on;
    // The data's rings per sweep (its most), against what the model saw: one count, or the span of
    // several sensors' counts when its training data mixed them.
    let saw = match (t.rings_per_sweep, t.rings) {
        (Some([lo, hi]), _) if lo < hi => Some((lo, hi)),
        (_, Some(a)) => Some((a, a)),
        _ => None,
    };
    let saw_words = |(lo, hi): (u32, u32)| {
        if lo < hi {
            format!("{lo}–{hi}")
        } else {
            lo.to_string()
        }
    };
    let data_rings = match saw {
        Some((lo, hi)) if lo < hi => data.rings_per_sweep.map(|[_, most]| most).or(data.rings),
        _ => data.rings,
    };
    match (saw, data_rings) {
        (Some((lo, hi)), Some(b)) if !(lo..=hi).contains(&b) => {
            notes.push(format!("{b} rings: the model saw {}", saw_words((lo, hi))))
        }
        (Some(span), None) => notes.push(format!(
            "the ring index is unknown: the model saw {} rings",
            saw_words(span)
        )),
        _ => {}
    }
    let trained_range = format!(
        "{:.0}–{:.0} (5th–95th percentile)",
        t.intensity_p05, t.intensity_p95
    );
    match (t.intensity_constant, data.intensity_constant) {
        (None, Some(v)) => notes.push(format!(
            "intensity is constant {}: the model was trained on {trained_range}",
            num(v)
        )),
        (Some(a), Some(b)) if (a - b).abs() > 1e-6 => notes.push(format!(
            "intensity is constant {}: the model was trained on a constant {}",
            num(b),
            num(a)
        )),
        (Some(a), None) => notes.push(format!(
            "intensity varies ({:.0}–{:.0}, 5th–95th percentile): the model was trained on a constant {}",
            data.intensity_p05,
            data.intensity_p95,
            num(a)
        )),
        (None, None) => {
            let outside = data.intensity_median < t.intensity_p05 || data.intensity_median > t.intensity_p95;
            let spread = |s: &StatsSummary| (s.intensity_p95 - s.intensity_p05).max(1.0);
            let ratio = spread(data) / spread(t);
            if outside || !(1.0 / POINTS_RATIO..=POINTS_RATIO).contains(&ratio) {
                notes.push(format!(
                    "intensity median {:.0} ({:.0}–{:.0}, 5th–95th percentile): the model was trained on median {:.0} ({trained_range})",
                    data.intensity_median, data.intensity_p05, data.intensity_p95, t.intensity_median
                ));
            }
        }
        _ => {}
    }
    if let (Some(a), Some(b)) = (t.car_size_mean_lwh, data.car_size_mean_lwh) {
        let words = [
            ("shorter", "longer", "length"),
            ("narrower", "wider", "width"),
            ("lower", "taller", "height"),
        ];
        for ((ta, da), (less, more, what)) in a.iter().zip(b.iter()).zip(words) {
            let d = da - ta;
            if d.abs() >= SIZE_TOLERANCE_M {
                notes.push(format!(
                    "cars are {:.1} m {} (mean {what} {da:.2} m): the model saw {ta:.2} m",
                    d.abs(),
                    if d < 0.0 { less } else { more }
                ));
            }
        }
    }
    if let (Some(a), Some(b)) = (t.ground_height_m, data.ground_height_m) {
        if (a - b).abs() >= GROUND_TOLERANCE_M {
            notes.push(format!(
                "LIDAR_TOP is {b:.2} m above the ground: the model's was {a:.2} m"
            ));
        }
    }
    // Against the training sweeps' span when the training data mixed sensors (a sweep within it
    // is one the model has seen the like of), else against their median.
    let (a, b) = (t.points_per_sweep_median, data.points_per_sweep_median);
    let (lo, hi) = match t.points_per_sweep_range {
        Some([lo, hi]) if lo > 0.0 && hi / lo >= POINTS_RATIO => (lo, hi),
        _ => (a, a),
    };
    if lo > 0.0 && b > 0.0 {
        let saw = if lo < hi {
            format!("{lo:.0}–{hi:.0}")
        } else {
            format!("{a:.0}")
        };
        let note = if b / hi >= POINTS_RATIO {
            Some((b / hi, "more"))
        } else if lo / b >= POINTS_RATIO {
            Some((lo / b, "fewer"))
        } else {
            None
        };
        if let Some((k, word)) = note {
            notes.push(format!(
                "{b:.0} points per LIDAR_TOP sweep: the model saw {saw} ({k:.1}× {word})"
            ));
        }
    }
    let missing: Vec<&str> = t
        .lidars
        .iter()
        .filter(|c| !data.lidars.contains(c))
        .map(String::as_str)
        .collect();
    if !missing.is_empty() {
        notes.push(format!(
            "no {}: the model saw {} (fusion cases run on what there is)",
            missing.join(", "),
            if missing.len() == 1 { "it" } else { "them" }
        ));
    }
    notes
}

/// A number without a needless fraction (100, not 100.0; 0.25 stays).
fn num(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e12 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary() -> StatsSummary {
        StatsSummary {
            samples: 200,
            rings: Some(40),
            rings_per_sweep: Some([40, 40]),
            intensity_median: 12.0,
            intensity_p05: 2.0,
            intensity_p95: 60.0,
            intensity_constant: None,
            ground_height_m: Some(1.85),
            points_per_sweep_median: 45_000.0,
            points_per_sweep_range: Some([41_000.0, 48_000.0]),
            car_size_mean_lwh: Some([4.8, 1.95, 1.6]),
            lidars: vec![
                "LIDAR_TOP".into(),
                "LIDAR_FRONT_LEFT".into(),
                "LIDAR_FRONT_RIGHT".into(),
            ],
        }
    }

    #[test]
    fn the_same_data_gives_no_notes_and_small_differences_none_either() {
        let t = summary();
        assert!(out_of_depth_notes(&t, &t).is_empty());
        let near = StatsSummary {
            samples: 5,
            intensity_median: 15.0,
            ground_height_m: Some(1.7),
            points_per_sweep_median: 60_000.0,
            car_size_mean_lwh: Some([4.6, 1.8, 1.5]),
            ..t.clone()
        };
        assert_eq!(out_of_depth_notes(&t, &near), Vec::<String>::new());
    }

    #[test]
    fn each_difference_is_named() {
        let t = summary();
        let kitti = StatsSummary {
            samples: 6,
            rings: Some(64),
            rings_per_sweep: None,
            intensity_median: 74.0,
            intensity_p05: 0.0,
            intensity_p95: 150.0,
            intensity_constant: None,
            ground_height_m: Some(1.45),
            points_per_sweep_median: 120_000.0,
            points_per_sweep_range: Some([115_000.0, 124_000.0]),
            car_size_mean_lwh: Some([3.9, 1.6, 1.5]),
            lidars: vec!["LIDAR_TOP".into()],
        };
        let notes = out_of_depth_notes(&t, &kitti);
        assert_eq!(notes.len(), 7, "{notes:#?}");
        assert_eq!(notes[0], "64 rings: the model saw 40");
        assert!(notes[1].starts_with("intensity median 74"), "{}", notes[1]);
        assert!(notes[2].starts_with("cars are 0.9 m shorter"), "{}", notes[2]);
        assert!(
            notes[3].starts_with("cars are 0.3 m narrower")
                || notes[3].starts_with("cars are 0.4 m narrower"),
            "{}",
            notes[3]
        );
        assert!(
            notes[4].contains("1.45 m above the ground") && notes[4].contains("1.85"),
            "{}",
            notes[4]
        );
        assert!(
            notes[5].starts_with("120000 points per LIDAR_TOP sweep") && notes[5].contains("2.7× more"),
            "{}",
            notes[5]
        );
        assert_eq!(
            notes[6],
            "no LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT: the model saw them (fusion cases run on what there is)"
        );
        // The height differs by 0.1 m only: not named.
        assert!(!notes.iter().any(|n| n.contains("lower") || n.contains("taller")));
    }

    #[test]
    fn constant_intensity_and_unknown_rings_are_named() {
        let t = summary();
        let flat = StatsSummary {
            rings: None,
            intensity_median: 100.0,
            intensity_p05: 100.0,
            intensity_p95: 100.0,
            intensity_constant: Some(100.0),
            ..t.clone()
        };
        let notes = out_of_depth_notes(&t, &flat);
        assert_eq!(
            notes,
            [
                "the ring index is unknown: the model saw 40 rings",
                "intensity is constant 100: the model was trained on 2–60 (5th–95th percentile)",
            ]
        );
        // The other way round: a model trained on a constant intensity.
        let notes = out_of_depth_notes(&flat, &t);
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("trained on a constant 100"), "{}", notes[0]);
        // Fewer points by 2× or more, and a higher sensor.
        let sparse = StatsSummary {
            points_per_sweep_median: 15_000.0,
            ground_height_m: Some(2.2),
            ..t.clone()
        };
        let notes = out_of_depth_notes(&t, &sparse);
        assert_eq!(notes.len(), 2, "{notes:?}");
        assert!(notes[0].contains("2.20 m above"), "{}", notes[0]);
        assert!(notes[1].contains("3.0× fewer"), "{}", notes[1]);
    }

    #[test]
    fn a_model_trained_on_several_sensors_names_their_span() {
        // v4: roof LiDARs of 32 to 128 rings; the union of ring indices is 128.
        let t = StatsSummary {
            rings: Some(128),
            rings_per_sweep: Some([32, 128]),
            ..summary()
        };
        let with = |rings, per| StatsSummary {
            rings: Some(rings),
            rings_per_sweep: per,
            ..summary()
        };
        // KITTI's 64 and a 40-ring sweep (an old summary without the span) are within it.
        assert!(out_of_depth_notes(&t, &with(64, Some([64, 64]))).is_empty());
        assert!(out_of_depth_notes(&t, &with(40, None)).is_empty());
        // A 16-ring unit is not, and the span is named.
        assert_eq!(
            out_of_depth_notes(&t, &with(16, Some([16, 16]))),
            ["16 rings: the model saw 32–128"]
        );
        // Unknown rings name the span too.
        let unknown = StatsSummary {
            rings: None,
            rings_per_sweep: None,
            ..summary()
        };
        assert_eq!(
            out_of_depth_notes(&t, &unknown),
            ["the ring index is unknown: the model saw 32–128 rings"]
        );
    }
    #[test]
    fn a_model_trained_on_several_sensors_is_judged_by_its_span_of_points() {
        // v4: 27 k (HDL-32E) to 250 k (128 beams) points per sweep, median 108 k.
        let t = StatsSummary {
            points_per_sweep_median: 108_000.0,
            points_per_sweep_range: Some([27_000.0, 250_000.0]),
            ..summary()
        };
        let with = |n: f64| StatsSummary {
            points_per_sweep_median: n,
            points_per_sweep_range: Some([n, n]),
            ..summary()
        };
        // An HDL-32E's 27.5 k is a sweep the model has seen the like of (3.9× fewer than the median).
        assert!(out_of_depth_notes(&t, &with(27_500.0)).is_empty());
        // Half the sparsest, or twice the densest, is named against the span.
        assert_eq!(
            out_of_depth_notes(&t, &with(9_000.0)),
            ["9000 points per LIDAR_TOP sweep: the model saw 27000–250000 (3.0× fewer)"]
        );
        assert_eq!(
            out_of_depth_notes(&t, &with(600_000.0)),
            ["600000 points per LIDAR_TOP sweep: the model saw 27000–250000 (2.4× more)"]
        );
        // A summary written before the span existed: the median, as before.
        let old = StatsSummary {
            points_per_sweep_range: None,
            ..t
        };
        assert_eq!(
            out_of_depth_notes(&old, &with(27_500.0)),
            ["27500 points per LIDAR_TOP sweep: the model saw 108000 (3.9× fewer)"]
        );
    }
}
