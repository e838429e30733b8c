//! The trainers' matrix product (issue 28): `dst (+)= a · b` where `b` and `dst` are row-major
//! and `a` is small (a layer's weights), with an AVX-512 kernel of our own where the CPU has one
//! and the `gemm` crate ([`gemm_into`]) otherwise or for other layouts.
//!
//! The `gemm` crate (0.19, as candle builds it) runs its AVX2 kernel on AVX-512 machines; its
//! AVX-512 kernels need the crate feature `x86-v4`, which would also change candle's and the
//! inference network's arithmetic (features unify), so the trainers use this kernel instead.
//! Two forms:
//! - row-major `b` (a forward product `W · col`, an input gradient `Wᵀ · dY`): `a` is packed once
//!   per call into panels of [`MR`] rows (zero-padded); the columns are split into blocks of
//!   [`NB`], one rayon task each, whose part of `b` is copied row by row into contiguous
//!   `k × NR` strips that the `MR × NR` tiles (24 zmm accumulators) read from L1/L2; each output
//!   is one fused multiply-add chain over `k` in order. The body is [`tiles`], which takes the
//!   block packing as a closure: the stride-1 convolutions ([`crate::nn::implicit`], [`crate::nn::dgrad`])
//!   fill the strips straight from `x` or `dY` instead of a materialised `b`;
//! - `b` given transposed, rows contiguous along a long `k` (a weight gradient `dY · colᵀ`):
//!   dot products in 16 lanes ([`abt`]; its rows read from memory, [`gemm_abt`], or generated
//!   per k-pass by the stride-1 convolutions' weight gradient).
//!
//! Neither splits a sum between threads, so the result does not depend on the thread count.

use candle_core::{Error, Result};
use rayon::prelude::*;

use crate::nn::gemm::{check_operands, gemm_into, Mat};

/// Rows of `a` per tile (12 × 2 zmm accumulators).
const MR: usize = 12;
/// Columns per tile: two zmm registers.
pub(crate) const NR: usize = 32;
/// Columns per rayon task.
pub(crate) const NB: usize = 256;

thread_local! {
    /// A thread's buffer of `b`'s strips for [`tiles`], reused by every block it runs.
    static STRIPS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Whether this CPU runs the AVX-512 kernel (checked once).
pub(crate) fn avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *HAS.get_or_init(|| std::arch::is_x86_feature_detected!("avx512f"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `dst (+)= a · b`, as [`gemm_into`] computes it (same checks, same result to float rounding).
pub(crate) fn gemm(
    dst: &mut [f32],
    d: Mat,
    a: &[f32],
    am: Mat,
    b: &[f32],
    bm: Mat,
    accumulate: bool,
) -> Result<()> {
    // The dot-product form pays only over long rows (a weight gradient's k = pixels).
    let bt = am.cs == 1 && bm.rs == 1 && am.cols >= 256;
    // Row-major `b`: worth it from a few column strips on (not for a k × 4 `b`).
    let rm = bm.cs == 1 && bm.cols >= 2 * NR;
    if !(avx512() && d.cs == 1 && (rm || bt)) {
        return gemm_into(dst, d, a, am, b, bm, accumulate);
    }
    check_operands(dst.len(), d, a.len(), am, b.len(), bm)?;
    let (m, n, k) = (d.rows, d.cols, am.cols);
    if m == 0 || n == 0 || k == 0 {
        return gemm_into(dst, d, a, am, b, bm, accumulate);
    }
    if bm.cs != 1 {
        return gemm_abt(dst, d, a, am, b, bm, accumulate);
    }
    let pa = pack_a(m, k, |i, kk| a[i * am.rs + kk * am.cs]);
    let brs = bm.rs;
    tiles(dst, d.rs, m, n, k, &pa, accumulate, |n0, n1, pb| {
        for kk in 0..k {
            put_row(pb, k, kk, &b[kk * brs + n0..kk * brs + n1]);
        }
    });
    Ok(())
}

/// `a` (`m × k`, element (i, kk) given by `at`) packed into panels of [`MR`] rows: panel t,
/// step kk, row r at (t·k + kk)·MR + r; rows past `m` zero.
pub(crate) fn pack_a(m: usize, k: usize, at: impl Fn(usize, usize) -> f32) -> Vec<f32> {
    let mut pa = vec![0f32; m.div_ceil(MR) * k * MR];
    for (t, panel) in pa.chunks_mut(k * MR).enumerate() {
        for (kk, col) in panel.chunks_mut(MR).enumerate() {
            for (r, v) in col.iter_mut().enumerate().take(m - t * MR) {
                *v = at(t * MR + r, kk);
            }
        }
    }
    pa
}

/// Row `kk` of a block's part of `b` (`row`, at most [`NB`] columns) into the block's strips:
/// strip s, step kk at (s·k + kk)·NR. Only inside [`tiles`] (AVX-512 present).
fn put_row(pb: &mut [f32], k: usize, kk: usize, row: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `tiles`, whose packing calls this, runs only where AVX-512 was detected.
    unsafe {
        put_row_avx512(pb, k, kk, row)
    };
    #[cfg(not(target_arch = "x86_64"))]
    for (s, part) in row.chunks(NR).enumerate() {
        let o = (s * k + kk) * NR;
        pb[o..o + part.len()].copy_from_slice(part);
    }
}

/// [`put_row`] in zmm loads and stores: a plain copy (`*to = *part` or `copy_from_slice`) became
/// one `memcpy` call per 128-byte strip row (the two branches merged), 10 % of a step.
///
/// # Safety
/// AVX-512F available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn put_row_avx512(pb: &mut [f32], k: usize, kk: usize, row: &[f32]) {
    use std::arch::x86_64::*;
    for (s, part) in row.chunks(NR).enumerate() {
        let o = (s * k + kk) * NR;
        let to = &mut pb[o..o + part.len()];
        let mut off = 0;
        while off < part.len() {
            let n = (part.len() - off).min(16);
            let mask = ((1u32 << n) - 1) as u16;
            // SAFETY: n lanes from `off`, inside `part` and `to` (the same length).
            unsafe {
                let v = _mm512_maskz_loadu_ps(mask, part.as_ptr().add(off));
                _mm512_mask_storeu_ps(to.as_mut_ptr().add(off), mask, v);
            }
            off += 16;
        }
    }
}

/// The row-major-`b` product's body, with `b` given by `pack`: `dst (+)= a · b` where `pa` is
/// `a` packed by [`pack_a`] (`m × k`), `dst` is `m × n` with row stride `crs`, and
/// `pack(n0, n1, pb)` writes columns `n0..n1` of `b` (`k` rows, `n1 − n0 ≤ NB`) into `pb`'s
/// `k × NR` strips, every row of those columns (`pb` holds stale values: a thread's buffer is
/// reused). Columns in blocks of [`NB`], one rayon
/// task each; callers have checked that AVX-512 is present and that `dst` holds the product.
#[allow(clippy::too_many_arguments)]
pub(crate) fn tiles<F>(
    dst: &mut [f32],
    crs: usize,
    m: usize,
    n: usize,
    k: usize,
    pa: &[f32],
    accumulate: bool,
    pack: F,
) where
    F: Fn(usize, usize, &mut [f32]) + Sync,
{
    debug_assert!(avx512() && pa.len() >= m.div_ceil(MR) * k * MR);
    debug_assert!(m == 0 || n == 0 || (m - 1) * crs + n <= dst.len());
    let mt = m.div_ceil(MR);
    let out = Out(dst.as_mut_ptr());
    (0..n.div_ceil(NB)).into_par_iter().for_each(|blk| {
        let out = &out;
        let (n0, n1) = (blk * NB, ((blk + 1) * NB).min(n));
        // The block's columns of b, strip by strip. Each row's part is written in one
        // sequential run (a copy per 32-column strip read k rows 64 KiB apart per strip and
        // waited on memory: 15 % of a step). The strips live in a buffer per thread, reused
        // (a fresh zeroed one per block cost a 221 KB memset per block).
        let strips = (n1 - n0).div_ceil(NR);
        let need = strips * k * NR;
        let run = |buf: &mut Vec<f32>| {
            if buf.len() < need {
                buf.resize(need, 0.0);
            }
            let pb = &mut buf[..need];
            if (n1 - n0) % NR != 0 {
                // The last strip's columns past n1 are never stored, but keep them finite.
                pb[(strips - 1) * k * NR..].fill(0.0);
            }
            pack(n0, n1, pb);
            for s in 0..strips {
                let j = n0 + s * NR;
                let w = (n1 - j).min(NR);
                for t in 0..mt {
                    let rows = (m - t * MR).min(MR);
                    // SAFETY: AVX-512 was detected (the callers' check); the tile writes rows
                    // t·MR.. t·MR+rows < m and columns j..j+w ≤ n of dst (inside it, the callers'
                    // check), columns no other task writes; pa and pb hold the tile's k steps.
                    #[cfg(target_arch = "x86_64")]
                    unsafe {
                        tile(
                            k,
                            pa.as_ptr().add(t * k * MR),
                            pb.as_ptr().add(s * k * NR),
                            out.0.add(t * MR * crs + j),
                            crs,
                            rows,
                            w,
                            accumulate,
                        )
                    };
                }
            }
        };
        // `pack` and `tile` start no rayon work, so a thread never re-enters here while its
        // buffer is borrowed; should it, it gets a buffer of its own.
        STRIPS.with(|cell| match cell.try_borrow_mut() {
            Ok(mut buf) => run(&mut buf),
            Err(_) => run(&mut Vec::new()),
        });
    });
}

/// Rows of `a` and of `bᵀ` per tile of [`gemm_abt`] (4 × 6 zmm accumulators).
const DM: usize = 4;
const DN: usize = 6;
/// Steps of `k` per pass over a tile's accumulators.
const KB: usize = 512;

/// `dst (+)= a · b` where `a`'s and `bᵀ`'s rows are contiguous along `k` (a weight gradient
/// `dY · colᵀ`): [`abt`] with `bᵀ` given.
fn gemm_abt(dst: &mut [f32], d: Mat, a: &[f32], am: Mat, b: &[f32], bm: Mat, accumulate: bool) -> Result<()> {
    abt(
        dst,
        d.rs,
        d.rows,
        d.cols,
        am.cols,
        a,
        am.rs,
        accumulate,
        b,
        bm.cs,
        None::<fn(usize, usize, &mut [f32])>,
    )
}

/// `dst (+)= a · b` (`m × n`, row stride `crs`) where `a`'s rows (stride `ars`) and `bᵀ`'s rows
/// run along `k`: every output is a dot product of two rows, summed in 16 lanes in `k` order and
/// the lanes added at the end. `bᵀ`'s rows are `b`'s (stride `brs`), or, with `fill`, generated:
/// `fill(j, k0, row)` writes row j's values `k0..k0 + row.len()` (then `b` is not read). One
/// rayon task per [`DN`] rows of `bᵀ`; `k` in passes of [`KB`] with the tile's accumulators kept
/// in memory between passes (the rows' chunks stay in L1; generated ones go to a `DN × KB`
/// buffer of the task's, right before the tiles read them). Callers have checked that AVX-512
/// is present.
#[allow(clippy::too_many_arguments)]
pub(crate) fn abt<F>(
    dst: &mut [f32],
    crs: usize,
    m: usize,
    n: usize,
    k: usize,
    a: &[f32],
    ars: usize,
    accumulate: bool,
    b: &[f32],
    brs: usize,
    fill: Option<F>,
) -> Result<()>
where
    F: Fn(usize, usize, &mut [f32]) + Sync,
{
    if m == 0 || n == 0 || k == 0 {
        return Err(Error::Msg("abt: an empty product".into()));
    }
    let short = |len: usize, rows: usize, rs: usize, cols: usize| (rows - 1) * rs + cols > len;
    if short(dst.len(), m, crs, n)
        || short(a.len(), m, ars, k)
        || (fill.is_none() && short(b.len(), n, brs, k))
    {
        return Err(Error::Msg("abt: an operand is shorter than its shape".into()));
    }
    let mt = m.div_ceil(DM);
    let out = Out(dst.as_mut_ptr());
    (0..n.div_ceil(DN)).into_par_iter().for_each(|jt| {
        let out = &out;
        // Rows past the end repeat the last one; their sums are not stored.
        let rows: [usize; DN] = std::array::from_fn(|q| (jt * DN + q).min(n - 1));
        let mut acc = vec![0f32; mt * DM * DN * 16];
        let mut buf = vec![0f32; if fill.is_some() { DN * KB } else { 0 }];
        let mut k0 = 0;
        while k0 < k {
            let kl = (k - k0).min(KB);
            let (bp, brow) = match &fill {
                Some(f) => {
                    for (q, &j) in rows.iter().enumerate() {
                        f(j, k0, &mut buf[q * KB..q * KB + kl]);
                    }
                    (buf.as_ptr(), std::array::from_fn(|q| q * KB))
                }
                None => (b.as_ptr(), rows.map(|j| j * brs + k0)),
            };
            for (it, acc) in acc.chunks_mut(DM * DN * 16).enumerate() {
                let arow: [usize; DM] = std::array::from_fn(|q| (it * DM + q).min(m - 1) * ars + k0);
                // SAFETY: AVX-512 was detected (the callers' check); every row offset + kl is
                // inside its slice (`b` and `a` checked above, `buf` holds DN rows of KB ≥ kl),
                // and `acc` holds DM·DN·16 values.
                #[cfg(target_arch = "x86_64")]
                unsafe {
                    dot_tile(kl, a.as_ptr(), &arow, bp, &brow, acc.as_mut_ptr())
                };
            }
            k0 += kl;
        }
        for (it, acc) in acc.chunks(DM * DN * 16).enumerate() {
            for p in 0..DM {
                let i = it * DM + p;
                for q in 0..DN {
                    let j = jt * DN + q;
                    if i < m && j < n {
                        let v: f32 = acc[(p * DN + q) * 16..(p * DN + q + 1) * 16].iter().sum();
                        // SAFETY: (i, j) is inside dst (checked above); this task alone writes
                        // column j.
                        unsafe {
                            let c = out.0.add(i * crs + j);
                            *c = if accumulate { *c + v } else { v };
                        }
                    }
                }
            }
        }
    });
    Ok(())
}

/// `acc[p·DN + q] += a[arow[p] + 0..kl] ⊙ b[brow[q] + 0..kl]` in 16 lanes.
///
/// # Safety
/// AVX-512F available; `a`/`b` valid for `kl` values from each row offset; `acc` holds
/// `DM·DN·16` values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn dot_tile(
    kl: usize,
    a: *const f32,
    arow: &[usize; DM],
    b: *const f32,
    brow: &[usize; DN],
    acc: *mut f32,
) {
    use std::arch::x86_64::*;
    let mut v = [[_mm512_setzero_ps(); DN]; DM];
    for (p, row) in v.iter_mut().enumerate() {
        for (q, x) in row.iter_mut().enumerate() {
            *x = _mm512_loadu_ps(acc.add((p * DN + q) * 16));
        }
    }
    let mut s = 0;
    while s < kl {
        let mk: u16 = ((1u32 << (kl - s).min(16)) - 1) as u16;
        let mut av = [_mm512_setzero_ps(); DM];
        for (x, &o) in av.iter_mut().zip(arow) {
            *x = _mm512_maskz_loadu_ps(mk, a.add(o + s));
        }
        for (q, &o) in brow.iter().enumerate() {
            let bv = _mm512_maskz_loadu_ps(mk, b.add(o + s));
            for (row, &x) in v.iter_mut().zip(&av) {
                row[q] = _mm512_fmadd_ps(x, bv, row[q]);
            }
        }
        s += 16;
    }
    for (p, row) in v.iter().enumerate() {
        for (q, x) in row.iter().enumerate() {
            _mm512_storeu_ps(acc.add((p * DN + q) * 16), *x);
        }
    }
}

/// The output pointer, shared by the tasks (each writes its own columns).
struct Out(*mut f32);
// SAFETY: the tasks write disjoint elements (see `gemm`).
unsafe impl Sync for Out {}

/// `c[r, 0..w] (+)= Σ_kk pa[kk·MR + r] · pb[kk·NR + 0..w]` for `r < rows`.
///
/// # Safety
/// AVX-512F available; `pa` holds `k·MR`, `pb` `k·NR` values; `c` row `r < rows` has `w ≤ NR`
/// writable values at `c + r·crs`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn tile(
    k: usize,
    pa: *const f32,
    pb: *const f32,
    c: *mut f32,
    crs: usize,
    rows: usize,
    w: usize,
    accumulate: bool,
) {
    use std::arch::x86_64::*;
    let mask = |w: usize| -> u16 { ((1u32 << w.min(16)) - 1) as u16 };
    let (m0, m1) = (mask(w), mask(w.saturating_sub(16)));
    let mut acc = [[_mm512_setzero_ps(); 2]; MR];
    for kk in 0..k {
        let bp = pb.add(kk * NR);
        let b0 = _mm512_loadu_ps(bp);
        let b1 = _mm512_loadu_ps(bp.add(16));
        let ap = pa.add(kk * MR);
        for (r, acc) in acc.iter_mut().enumerate() {
            let av = _mm512_set1_ps(*ap.add(r));
            acc[0] = _mm512_fmadd_ps(av, b0, acc[0]);
            acc[1] = _mm512_fmadd_ps(av, b1, acc[1]);
        }
    }
    for (r, acc) in acc.iter().enumerate().take(rows) {
        let cp = c.add(r * crs);
        let (mut v0, mut v1) = (acc[0], acc[1]);
        if accumulate {
            v0 = _mm512_add_ps(v0, _mm512_maskz_loadu_ps(m0, cp));
            v1 = _mm512_add_ps(v1, _mm512_maskz_loadu_ps(m1, cp.add(16)));
        }
        _mm512_mask_storeu_ps(cp, m0, v0);
        _mm512_mask_storeu_ps(cp.add(16), m1, v1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::testutil::data;

    /// max |x − y| / max(1, max |y|).
    fn rel(x: &[f32], y: &[f32]) -> f32 {
        let d = x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
        d / y.iter().fold(1f32, |m, v| m.max(v.abs()))
    }

    #[test]
    fn equals_the_gemm_crate_on_every_layout_it_takes() {
        // Odd sizes: row tiles and column strips with remainders; a transposed (strided) `a`.
        for &(m, n, k, tr, acc) in &[
            (5, 37, 3, false, false),
            (24, 300, 216, false, true),
            (22, 77, 48, true, false),
            (13, 33, 0, false, true),
            (9, 14, 1500, false, false),
        ] {
            let a = data(m * k, 1);
            let b = data(k * n, 2);
            let am = if tr { Mat::tr(k, m) } else { Mat::rm(m, k) };
            let (mut x, mut y) = (data(m * n, 3), data(m * n, 3));
            gemm(&mut x, Mat::rm(m, n), &a, am, &b, Mat::rm(k, n), acc).unwrap();
            gemm_into(&mut y, Mat::rm(m, n), &a, am, &b, Mat::rm(k, n), acc).unwrap();
            let d = rel(&x, &y);
            assert!(d < 1e-5, "{m}×{n}×{k}: {d}");
            // The weight-gradient form: b given as the transpose of a row-major n × k.
            if !tr {
                let bt = data(n * k, 4);
                let (mut x, mut y) = (data(m * n, 5), data(m * n, 5));
                gemm(&mut x, Mat::rm(m, n), &a, am, &bt, Mat::tr(n, k), acc).unwrap();
                gemm_into(&mut y, Mat::rm(m, n), &a, am, &bt, Mat::tr(n, k), acc).unwrap();
                let d = rel(&x, &y);
                assert!(d < 1e-5, "aᵀ {m}×{n}×{k}: {d}");
            }
        }
    }
}
