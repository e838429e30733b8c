//! The two per-sweep estimates of the sensor's statistics that need more than counting: the
//! ground height below the sensor and the share of emitted rays that returned (methods in the
//! module doc of `super`).

use super::{median, LidarScan, GROUND_BIN_M, GROUND_RANGE_M, MIN_RING_POINTS};

/// Ground height below the sensor of one sweep (see the module doc); `None` without points at
/// 3–20 m.
pub(super) fn ground_height(scan: &LidarScan) -> Option<f64> {
    const HALF_SPAN_M: f64 = 10.0;
    let bins = (2.0 * HALF_SPAN_M / GROUND_BIN_M).round() as usize;
    let r = scan.info.extrinsic.rotation;
    let p = &scan.points;
    let mut zs = Vec::new();
    let mut counts = vec![0u32; bins];
    for ((&x, &y), &z) in p.x.iter().zip(&p.y).zip(&p.z) {
        let q = r * nalgebra::Vector3::new(f64::from(x), f64::from(y), f64::from(z));
        let h = q.x.hypot(q.y);
        if !(GROUND_RANGE_M.0..=GROUND_RANGE_M.1).contains(&h) || q.z.abs() >= HALF_SPAN_M {
            continue;
        }
        let k = ((q.z + HALF_SPAN_M) / GROUND_BIN_M).floor() as usize;
        if let Some(c) = counts.get_mut(k) {
            *c += 1;
            zs.push((k, q.z));
        }
    }
    let (best, _) = counts
        .iter()
        .enumerate()
        .max_by_key(|(k, c)| (**c, std::cmp::Reverse(*k)))?;
    let mut near: Vec<f64> = zs
        .into_iter()
        .filter(|(k, _)| k.abs_diff(best) <= 1)
        .map(|(_, z)| z)
        .collect();
    median(&mut near).map(|z| -z)
}

/// Returned and emitted rays of one sweep (see the module doc); `None` when rings are unknown.
pub(super) fn returns(x: &[f32], y: &[f32], ring: &[f32]) -> Option<(u64, u64)> {
    let mut per_ring: Vec<Vec<f64>> = Vec::new();
    for ((&px, &py), &r) in x.iter().zip(y).zip(ring) {
        if !(0.0..4096.0).contains(&r) {
            continue;
        }
        let k = r.round() as usize;
        if per_ring.len() <= k {
            per_ring.resize_with(k + 1, Vec::new);
        }
        if let Some(v) = per_ring.get_mut(k) {
            v.push(f64::from(py).atan2(f64::from(px)));
        }
    }
    if per_ring.is_empty() {
        return None;
    }
    let steps: Vec<Option<f64>> = per_ring
        .iter_mut()
        .map(|az| {
            az.sort_by(f64::total_cmp);
            if az.len() < MIN_RING_POINTS {
                return None;
            }
            let mut d: Vec<f64> = az
                .windows(2)
                .filter_map(|w| match w {
                    [a, b] if b - a > 1e-9 => Some(b - a),
                    _ => None,
                })
                .collect();
            median(&mut d)
        })
        .collect();
    let mut known: Vec<f64> = steps.iter().flatten().copied().collect();
    let sweep_step = median(&mut known)?;
    let (mut returned, mut emitted) = (0u64, 0u64);
    for (az, step) in per_ring.iter().zip(&steps) {
        let step = step.unwrap_or(sweep_step);
        let cells = (std::f64::consts::TAU / step).round().max(1.0) as u64;
        let mut n = 0u64;
        let mut last = f64::NEG_INFINITY;
        for &a in az {
            if a - last > 0.5 * step {
                n += 1;
                last = a;
            }
        }
        returned += n.min(cells);
        emitted += cells;
    }
    Some((returned, emitted))
}
