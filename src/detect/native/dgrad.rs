//! The input gradient of a stride-1 "same" convolution (the 3×3 layers, issue 28) without the
//! column gradient: `dX[ci][y][x] = Σ_co Σ_ky,kx W[co][ci][ky][kx] · dY[co][y+pad−ky][x+pad−kx]`
//! (zero outside the image), the convolution of `dY` with the transposed, flipped weights.
//!
//! It runs on [`kernel::tiles`](super::kernel::tiles): `a` is the weights rearranged to
//! `ci × (co, ky, kx)`, and each block's strips of `b` are copied straight from `dY`'s shifted
//! rows (an implicit im2col of `dY`, zeros at the borders), so neither the `K × P` column gradient
//! `Wᵀ · dY` (14 MB for a 24-channel 128 × 128 layer) nor col2im's pass over it exist. Each output
//! is one fused multiply-add chain over `(co, ky, kx)` in order, in one task: the result does not
//! depend on the thread count.

use candle_core::{Error, Result};

use super::kernel::{avx512, pack_a, tiles, NR};
use crate::detect::fastconv::Geom;

/// Whether [`input_grad`] computes this convolution's input gradient: stride 1, odd kernel,
/// padding k/2 (the output is the input's size), on a CPU with AVX-512.
pub(super) fn applies(g: &Geom) -> bool {
    g.stride == 1 && g.k % 2 == 1 && g.pad == g.k / 2 && g.k > 1 && avx512()
}

/// `dx (+)= ∂L/∂x` of the convolution `g` with weights `w [cout, cin, k, k]` from `dy [cout, h, w]`
/// (added to `dx` when `accumulate`). Only where [`applies`] holds.
pub(super) fn input_grad(
    g: &Geom,
    cout: usize,
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    accumulate: bool,
) -> Result<()> {
    if !applies(g) || g.ho != g.h || g.wo != g.w {
        return Err(Error::Msg(format!(
            "input_grad: a {}×{} conv with stride {}, pad {} is not a stride-1 same conv on AVX-512",
            g.k, g.k, g.stride, g.pad
        )));
    }
    let (cin, h, wd, ks, pad) = (g.cin, g.h, g.w, g.k, g.pad);
    let (p, kk2) = (h * wd, ks * ks);
    let k = cout * kk2;
    if w.len() < cout * cin * kk2 || dy.len() < cout * p || dx.len() < cin * p {
        return Err(Error::Msg(
            "input_grad: an operand is shorter than its shape".into(),
        ));
    }
    if cin == 0 || p == 0 || k == 0 {
        if !accumulate {
            dx[..cin * p].fill(0.0);
        }
        return Ok(());
    }
    // a[ci][(co·k + ky)·k + kx] = W[co][ci][ky][kx].
    let pa = pack_a(cin, k, |ci, r| w[((r / kk2) * cin + ci) * kk2 + r % kk2]);
    tiles(dx, p, cin, p, k, &pa, accumulate, |n0, n1, pb| {
        for r in 0..k {
            let (co, ky, kx) = (r / kk2, (r / ks) % ks, r % ks);
            let plane = &dy[co * p..(co + 1) * p];
            let mut j = n0;
            while j < n1 {
                // Output row y, up to the row's or the strip's end: b's entries
                // dY[co][y+pad−ky][x+pad−kx], zero outside the image.
                let (y, c) = (j / wd, j - n0);
                let jb = n1.min((y + 1) * wd).min(n0 + (c / NR + 1) * NR);
                let o = ((c / NR) * k + r) * NR + c % NR;
                let src = (y + pad)
                    .checked_sub(ky)
                    .filter(|&yy| yy < h)
                    .map(|yy| &plane[yy * wd..(yy + 1) * wd]);
                let xs = (j - y * wd + pad) as isize - kx as isize;
                // SAFETY: AVX-512 was detected (`applies`).
                #[cfg(target_arch = "x86_64")]
                unsafe {
                    shifted(&mut pb[o..o + (jb - j)], src, xs)
                };
                j = jb;
            }
        }
    });
    Ok(())
}

/// `dst[i] = src[xs + i]`, zero where `xs + i` is outside `src` (everywhere when `src` is
/// `None`), in masked 16-lane loads: no copy call, no branch per border.
///
/// # Safety
/// AVX-512F available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn shifted(dst: &mut [f32], src: Option<&[f32]>, xs: isize) {
    use std::arch::x86_64::*;
    let len = dst.len();
    let mut off = 0;
    while off < len {
        let n = (len - off).min(16);
        let x = xs + off as isize;
        let v = match src {
            Some(row) => {
                // Lanes lo..hi read row[x + lane], inside the row; the others load nothing.
                let lo = (-x).clamp(0, n as isize) as u32;
                let hi = (row.len() as isize - x).clamp(lo as isize, n as isize) as u32;
                let mask = (((1u32 << hi) - 1) & !((1u32 << lo) - 1)) as u16;
                // SAFETY: only lanes in lo..hi are read, at row[x + lo..x + hi], inside `row`;
                // masked-off lanes are not accessed (the address is only formed, with wrapping).
                unsafe { _mm512_maskz_loadu_ps(mask, row.as_ptr().wrapping_offset(x)) }
            }
            None => _mm512_setzero_ps(),
        };
        // SAFETY: n lanes from dst[off], inside `dst`.
        unsafe { _mm512_mask_storeu_ps(dst.as_mut_ptr().add(off), ((1u32 << n) - 1) as u16, v) };
        off += 16;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::fastconv::{gemm_into, Mat};
    use crate::detect::native::testutil::rel;

    fn data(n: usize, seed: usize) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 1000.0 - 0.5)
            .collect()
    }

    #[test]
    fn equals_the_column_gradient_and_col2im() {
        if !avx512() {
            eprintln!("no AVX-512: the implicit input gradient is not used on this CPU");
            return;
        }
        // Odd sizes: a row tile with a remainder (cin 5, 13), blocks across image rows (w 37),
        // a last strip and a last block cut short, a 5×5 kernel.
        for &(cin, cout, h, w, k) in &[
            (5, 7, 9, 37, 3),
            (13, 4, 6, 70, 3),
            (3, 2, 11, 8, 5),
            (24, 24, 16, 64, 3),
        ] {
            let g = Geom::new(cin, h, w, k, 1, k / 2).unwrap();
            assert!(applies(&g));
            let (p, kk) = (g.p(), g.kk());
            let wt = data(cout * kk, 1);
            let dy = data(cout * p, 2);
            for accumulate in [false, true] {
                let mut x = data(cin * p, 3);
                input_grad(&g, cout, &wt, &dy, &mut x, accumulate).unwrap();
                let mut col = vec![0f32; kk * p];
                gemm_into(
                    &mut col,
                    Mat::rm(kk, p),
                    &wt,
                    Mat::tr(cout, kk),
                    &dy,
                    Mat::rm(cout, p),
                    false,
                )
                .unwrap();
                let mut y = data(cin * p, 3);
                g.col2im_into(&col, &mut y, accumulate);
                let d = rel(&x, &y);
                assert!(
                    d < 1e-5,
                    "cin {cin} cout {cout} {h}×{w} k {k} acc {accumulate}: {d}"
                );
            }
        }
        // Not a stride-1 same convolution: an error, not a wrong answer.
        let g = Geom::new(4, 8, 8, 3, 2, 1).unwrap();
        assert!(!applies(&g));
        let mut dx = vec![0f32; 4 * 64];
        assert!(input_grad(&g, 2, &[0.0; 72], &[0.0; 32], &mut dx, false).is_err());
    }
}
