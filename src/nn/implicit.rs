//! Stride-1 "same" convolutions (the 3×3 layers, issue 28) without im2col: the forward product
//! `Y = W · col(x)` and the weight gradient `dW = dY · col(x)ᵀ` read `col`'s entries straight from
//! `x`'s shifted rows, `col[(ci, ky, kx)][(y, x)] = x[ci][y+ky−pad][x+kx−pad]` (zero outside the
//! image), so the `K × P` column matrix (14 MB for a 24-channel 128 × 128 layer) is neither
//! written nor read back. The input gradient ([`crate::nn::dgrad`]) packs the same way from `dY`,
//! flipped; the helpers here are shared.
//!
//! - forward: [`kernel::tiles`](crate::nn::kernel::tiles), each block's `k × 32` strips of `b` filled
//!   from `x`'s shifted rows by [`Shifted::pack`] (masked 16-lane loads);
//! - weight gradient: [`kernel::abt`](crate::nn::kernel::abt), each task's [`DN`](crate::nn::kernel)
//!   rows of `colᵀ` generated one k-pass (512 pixels) at a time into a small L1-resident buffer
//!   right before the dot-product tiles read it.
//!
//! Each output is one fused multiply-add chain (forward) or one 16-lane dot product (weight
//! gradient) in a fixed order, in one task: the result does not depend on the thread count.

use candle_core::{Error, Result};

use crate::nn::gemm::Geom;
use crate::nn::kernel::{abt, avx512, pack_a, tiles, NR};

/// Whether this convolution runs implicitly: stride 1, odd kernel > 1, padding k/2 (the output
/// is the input's size), on a CPU with AVX-512.
pub(crate) fn applies(g: &Geom) -> bool {
    g.stride == 1 && g.k % 2 == 1 && g.pad == g.k / 2 && g.k > 1 && g.ho == g.h && g.wo == g.w && avx512()
}

fn not_applicable(what: &str, g: &Geom) -> Error {
    Error::Msg(format!(
        "{what}: a {}×{} conv with stride {}, pad {} is not a stride-1 same conv on AVX-512",
        g.k, g.k, g.stride, g.pad
    ))
}

/// `y = W · col(x)`: the convolution `g` of `x [cin, h, w]` with `w [cout, cin, k, k]` into
/// `y [cout, h, w]`. Only where [`applies`] holds.
pub(crate) fn forward(g: &Geom, cout: usize, w: &[f32], x: &[f32], y: &mut [f32]) -> Result<()> {
    if !applies(g) {
        return Err(not_applicable("implicit forward", g));
    }
    let (p, kdim) = (g.p(), g.kk());
    if w.len() < cout * kdim || x.len() < g.cin * p || y.len() < cout * p {
        return Err(Error::Msg(
            "implicit forward: an operand is shorter than its shape".into(),
        ));
    }
    if cout == 0 || p == 0 || kdim == 0 {
        y[..cout * p].fill(0.0);
        return Ok(());
    }
    let pa = pack_a(cout, kdim, |co, r| w[co * kdim + r]);
    let sx = Shifted::of(g, x, false);
    tiles(y, p, cout, p, kdim, &pa, false, |n0, n1, pb| {
        sx.pack(kdim, n0, n1, pb)
    });
    Ok(())
}

/// `dw = dY · col(x)ᵀ` (`[cout, cin·k·k]`, written over) of the convolution `g`, from
/// `dy [cout, h, w]` and the forward input `x [cin, h, w]`. Only where [`applies`] holds.
pub(crate) fn weight_grad(g: &Geom, cout: usize, dy: &[f32], x: &[f32], dw: &mut [f32]) -> Result<()> {
    if !applies(g) {
        return Err(not_applicable("implicit weight gradient", g));
    }
    let (p, kdim) = (g.p(), g.kk());
    if dy.len() < cout * p || x.len() < g.cin * p || dw.len() < cout * kdim {
        return Err(Error::Msg(
            "implicit weight gradient: an operand is shorter than its shape".into(),
        ));
    }
    if cout == 0 || kdim == 0 {
        return Ok(());
    }
    if p == 0 {
        dw[..cout * kdim].fill(0.0);
        return Ok(());
    }
    let sx = Shifted::of(g, x, false);
    // Row j of colᵀ's pixels k0..: row j = (ci, ky, kx) of col.
    abt(
        dw,
        kdim,
        cout,
        kdim,
        p,
        dy,
        p,
        false,
        &[],
        0,
        Some(|j, k0, row: &mut [f32]| sx.fill(j, k0, row)),
    )
}

/// An implicit im2col of `planes [c, h, wd]` with a `ks × ks` kernel and padding `pad`: row
/// `r = (c, ky, kx)`, column `(y, x)` is `planes[c][y+oy][x+ox]`, zero outside the image, with
/// `(oy, ox) = (ky−pad, kx−pad)`, or `(pad−ky, pad−kx)` when `flip` (the input gradient's
/// transposed convolution, of `dY`). Its methods run only where AVX-512 was detected.
#[derive(Clone, Copy)]
pub(crate) struct Shifted<'a> {
    pub planes: &'a [f32],
    pub h: usize,
    pub wd: usize,
    pub ks: usize,
    pub pad: usize,
    pub flip: bool,
}

impl<'a> Shifted<'a> {
    /// The implicit im2col of `planes` (`g.cin` planes for the forward, `cout` for the input
    /// gradient) for the convolution `g`.
    pub fn of(g: &Geom, planes: &'a [f32], flip: bool) -> Self {
        Self {
            planes,
            h: g.h,
            wd: g.w,
            ks: g.k,
            pad: g.pad,
            flip,
        }
    }

    /// Row `r`'s plane and shift.
    fn row(&self, r: usize) -> (&[f32], isize, isize) {
        let (ks, pad, p) = (self.ks, self.pad as isize, self.h * self.wd);
        let (c, ky, kx) = (r / (ks * ks), ((r / ks) % ks) as isize, (r % ks) as isize);
        let (oy, ox) = if self.flip {
            (pad - ky, pad - kx)
        } else {
            (ky - pad, kx - pad)
        };
        (&self.planes[c * p..(c + 1) * p], oy, ox)
    }

    /// Row `y + oy` of `plane`, or `None` outside the image.
    fn src<'p>(&self, plane: &'p [f32], y: usize, oy: isize) -> Option<&'p [f32]> {
        let yy = y as isize + oy;
        (0..self.h as isize)
            .contains(&yy)
            .then(|| &plane[yy as usize * self.wd..(yy as usize + 1) * self.wd])
    }

    /// Rows `0..k`, columns `n0..n1` into [`tiles`]' `k × NR` strips `pb` (strip s, row r at
    /// `(s·k + r)·NR`).
    pub fn pack(&self, k: usize, n0: usize, n1: usize, pb: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512 was detected (this type's contract).
        unsafe {
            self.pack_avx512(k, n0, n1, pb)
        };
    }

    /// Row `r`, columns `j0..j0 + dst.len()` into `dst`.
    pub fn fill(&self, r: usize, j0: usize, dst: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512 was detected (this type's contract).
        unsafe {
            self.fill_avx512(r, j0, dst)
        };
    }

    /// [`Self::pack`], compiled for AVX-512 so that [`shifted`] is inlined (a call per 32-column
    /// strip row otherwise).
    ///
    /// # Safety
    /// AVX-512F available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn pack_avx512(&self, k: usize, n0: usize, n1: usize, pb: &mut [f32]) {
        // The block's columns cut at strip and image-row ends, once: (offset in the strip's
        // row, strip, y, x, length).
        let wd = self.wd;
        let mut segs = Vec::with_capacity(2 * (n1 - n0).div_ceil(NR) + (n1 - n0) / wd.max(1) + 1);
        let mut j = n0;
        while j < n1 {
            let (y, c) = (j / wd, j - n0);
            let jb = n1.min((y + 1) * wd).min(n0 + (c / NR + 1) * NR);
            segs.push((c % NR, c / NR, y, j - y * wd, jb - j));
            j = jb;
        }
        for r in 0..k {
            let (plane, oy, ox) = self.row(r);
            for &(cc, s, y, x, len) in &segs {
                let o = (s * k + r) * NR + cc;
                // SAFETY: AVX-512F available (this function's contract).
                unsafe { shifted(&mut pb[o..o + len], self.src(plane, y, oy), x as isize + ox) };
            }
        }
    }

    /// [`Self::fill`], compiled for AVX-512 ([`shifted`] inlined).
    ///
    /// # Safety
    /// AVX-512F available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn fill_avx512(&self, r: usize, j0: usize, dst: &mut [f32]) {
        let (plane, oy, ox) = self.row(r);
        let (wd, end) = (self.wd, j0 + dst.len());
        let mut j = j0;
        while j < end {
            let y = j / wd;
            let jb = end.min((y + 1) * wd);
            // SAFETY: AVX-512F available (this function's contract).
            unsafe {
                shifted(
                    &mut dst[j - j0..jb - j0],
                    self.src(plane, y, oy),
                    (j - y * wd) as isize + ox,
                )
            };
            j = jb;
        }
    }
}

/// `dst[i] = src[xs + i]`, zero where `xs + i` is outside `src` (everywhere when `src` is
/// `None`), in masked 16-lane loads: no copy call, no branch per border.
///
/// # Safety
/// AVX-512F available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn shifted(dst: &mut [f32], src: Option<&[f32]>, xs: isize) {
    use std::arch::x86_64::*;
    let (len, d) = (dst.len(), dst.as_mut_ptr());
    let mut off = 0;
    let Some(row) = src else {
        while off < len {
            let n = (len - off).min(16);
            // SAFETY: n lanes from dst[off], inside `dst`.
            unsafe { _mm512_mask_storeu_ps(d.add(off), ((1u32 << n) - 1) as u16, _mm512_setzero_ps()) };
            off += 16;
        }
        return;
    };
    let rl = row.len() as isize;
    while off < len {
        let n = (len - off).min(16);
        let x = xs + off as isize;
        if n == 16 && x >= 0 && x + 16 <= rl {
            // Inside the row (most chunks): plain loads and stores.
            // SAFETY: row[x..x + 16] and dst[off..off + 16] are inside their slices.
            unsafe { _mm512_storeu_ps(d.add(off), _mm512_loadu_ps(row.as_ptr().offset(x))) };
        } else {
            // Lanes lo..hi read row[x + lane], inside the row; the others load nothing.
            let lo = (-x).clamp(0, n as isize) as u32;
            let hi = (rl - x).clamp(lo as isize, n as isize) as u32;
            let mask = (((1u32 << hi) - 1) & !((1u32 << lo) - 1)) as u16;
            // SAFETY: only lanes in lo..hi are read, at row[x + lo..x + hi], inside `row`
            // (masked-off lanes are not accessed; the address is only formed, with wrapping);
            // n lanes are stored from dst[off], inside `dst`.
            unsafe {
                let v = _mm512_maskz_loadu_ps(mask, row.as_ptr().wrapping_offset(x));
                _mm512_mask_storeu_ps(d.add(off), ((1u32 << n) - 1) as u16, v)
            };
        }
        off += 16;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gemm::{gemm_into, Mat};
    use crate::nn::testutil::{data, rel};

    #[test]
    fn forward_and_weight_gradient_equal_im2col_and_gemm() {
        if !avx512() {
            eprintln!("no AVX-512: the implicit convolution is not used on this CPU");
            return;
        }
        // Odd sizes: row tiles with remainders (cout 7, 13), blocks across image rows (w 37),
        // k-passes across image rows and a short last pass (p 333, 1024 + 320), a 5×5 kernel,
        // rows of col past a multiple of 6 (K = 45, 75).
        for &(cin, cout, h, w, k) in &[
            (5, 7, 9, 37, 3),
            (13, 4, 6, 70, 3),
            (3, 2, 11, 8, 5),
            (24, 24, 16, 64, 3),
            (5, 13, 21, 64, 3),
        ] {
            let g = Geom::new(cin, h, w, k, 1, k / 2).unwrap();
            assert!(applies(&g));
            let (p, kk) = (g.p(), g.kk());
            let wt = data(cout * kk, 1);
            let x = data(cin * p, 2);
            let dy = data(cout * p, 3);
            let mut col = vec![0f32; kk * p];
            g.im2col(&x, &mut col);

            let mut y = data(cout * p, 4);
            forward(&g, cout, &wt, &x, &mut y).unwrap();
            let mut want = vec![0f32; cout * p];
            gemm_into(
                &mut want,
                Mat::rm(cout, p),
                &wt,
                Mat::rm(cout, kk),
                &col,
                Mat::rm(kk, p),
                false,
            )
            .unwrap();
            let d = rel(&y, &want);
            assert!(d < 1e-5, "forward cin {cin} cout {cout} {h}×{w} k {k}: {d}");

            let mut dw = data(cout * kk, 5);
            weight_grad(&g, cout, &dy, &x, &mut dw).unwrap();
            let mut want = vec![0f32; cout * kk];
            gemm_into(
                &mut want,
                Mat::rm(cout, kk),
                &dy,
                Mat::rm(cout, p),
                &col,
                Mat::tr(kk, p),
                false,
            )
            .unwrap();
            let d = rel(&dw, &want);
            assert!(d < 1e-5, "dW cin {cin} cout {cout} {h}×{w} k {k}: {d}");
        }
        // Not a stride-1 same convolution: an error, not a wrong answer.
        let g = Geom::new(4, 8, 8, 3, 2, 1).unwrap();
        assert!(!applies(&g));
        let mut out = vec![0f32; 64];
        assert!(forward(&g, 2, &[0.0; 72], &[0.0; 256], &mut out).is_err());
        assert!(weight_grad(&g, 2, &[0.0; 32], &[0.0; 256], &mut out).is_err());
    }
}
