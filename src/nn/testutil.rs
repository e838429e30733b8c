//! Helpers of the kernels' and trainers' tests: deterministic data and error measures.

/// A deterministic pattern of `n` values in [−0.5, 0.5), different per `seed` (the kernels' tests).
pub(crate) fn data(n: usize, seed: usize) -> Vec<f32> {
    (0..n)
        .map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 1000.0 - 0.5)
        .collect()
}

/// max |a − b|.
pub(crate) fn diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()))
}

/// max |a − b| / max |b|.
pub(crate) fn rel(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    diff(a, b) / scale
}

/// ‖a − b‖₂ / ‖b‖₂: the whole tensor's error, which a few entries near 0 do not dominate.
pub(crate) fn rel_l2(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let d: f32 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let n: f32 = b.iter().map(|y| y * y).sum();
    d.sqrt() / n.sqrt().max(1e-12)
}
