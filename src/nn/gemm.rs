//! Every call of the `gemm` crate (the one candle itself uses) goes through this module:
//! [`gemm_rm`] (row-major, one thread: the inference networks, each band on its own task),
//! [`Mat`] (a strided row- or column-major view) and [`gemm_into`] (`dst (+)= a · b` over rayon's
//! threads: the trainers; `kernel.rs` packs its own AVX-512 tiles and falls back to it),
//! [`Geom`] (one convolution's shape, im2col and col2im) and the neck's deconvolution permute.
//!
//! Determinism: gemm splits its output between threads, never a sum, and every other loop
//! writes disjoint outputs in a fixed order, so a result depends on nothing but the inputs and
//! the thread count (the kill/resume tests need this).

use candle_core::{Error, Result};
use rayon::prelude::*;

fn err(what: impl Into<String>) -> Error {
    Error::Msg(format!("gemm: {}", what.into()))
}

/// A row-major view: element (i, j) at `off + i·rs + j·cs`.
#[derive(Clone, Copy)]
pub(crate) struct Mat {
    pub(crate) rows: usize,
    pub(crate) cols: usize,
    pub(crate) rs: usize,
    pub(crate) cs: usize,
}

impl Mat {
    pub(crate) fn rm(rows: usize, cols: usize) -> Self {
        Self {
            rows,
            cols,
            rs: cols,
            cs: 1,
        }
    }

    /// The transpose of a row-major `rows × cols` matrix (a view, no copy).
    pub(crate) fn tr(rows: usize, cols: usize) -> Self {
        Self {
            rows: cols,
            cols: rows,
            rs: 1,
            cs: cols,
        }
    }

    /// A strided view: element (i, j) at `i·rs + j·cs`.
    pub(crate) fn strided(rows: usize, cols: usize, rs: usize, cs: usize) -> Self {
        Self { rows, cols, rs, cs }
    }

    pub(crate) fn fits(&self, len: usize) -> bool {
        self.rows == 0 || self.cols == 0 || (self.rows - 1) * self.rs + (self.cols - 1) * self.cs < len
    }
}

/// The checks of every `dst (+)= a · b` (this module's and the native trainers' kernel): the
/// shapes agree and each operand holds its shape.
pub(crate) fn check_operands(dst: usize, d: Mat, a: usize, am: Mat, b: usize, bm: Mat) -> Result<()> {
    if am.rows != d.rows || bm.cols != d.cols || am.cols != bm.rows {
        return Err(err("gemm shapes do not match"));
    }
    if !(d.fits(dst) && am.fits(a) && bm.fits(b)) {
        return Err(err("a gemm operand is shorter than its shape"));
    }
    Ok(())
}

/// `dst (+)= a · b` with gemm over rayon's threads.
pub(crate) fn gemm_into(
    dst: &mut [f32],
    d: Mat,
    a: &[f32],
    am: Mat,
    b: &[f32],
    bm: Mat,
    accumulate: bool,
) -> Result<()> {
    check_operands(dst.len(), d, a.len(), am, b.len(), bm)?;
    if d.rows == 0 || d.cols == 0 {
        return Ok(());
    }
    if am.cols == 0 {
        if !accumulate {
            dst.fill(0.0);
        }
        return Ok(());
    }
    // SAFETY: `fits` above keeps every element the strides reach inside its slice; dst is the
    // only one written and cannot alias a or b (a unique borrow).
    unsafe {
        gemm::gemm(
            d.rows,
            d.cols,
            am.cols,
            dst.as_mut_ptr(),
            d.cs as isize,
            d.rs as isize,
            accumulate,
            a.as_ptr(),
            am.cs as isize,
            am.rs as isize,
            b.as_ptr(),
            bm.cs as isize,
            bm.rs as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::Rayon(rayon::current_num_threads().max(1)),
        );
    }
    Ok(())
}

/// `c[i·ldc + j] (+)= Σ_p a[i·lda + p] · b[p·ldb + j]` for `i < m`, `j < n`, `p < k`, on one
/// thread, row-major (the inference networks' bands, each already on its own rayon task).
/// Returns false (and computes nothing) when a slice is too short for the shape.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_rm(
    m: usize,
    n: usize,
    k: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) -> bool {
    if m == 0 || n == 0 {
        return true;
    }
    let fits = |len: usize, rows: usize, ld: usize, cols: usize| rows == 0 || len >= (rows - 1) * ld + cols;
    if !fits(c.len(), m, ldc, n) || !(k == 0 || fits(a.len(), m, lda, k) && fits(b.len(), k, ldb, n)) {
        return false;
    }
    if k == 0 {
        if !accumulate {
            for i in 0..m {
                c[i * ldc..i * ldc + n].fill(0.0);
            }
        }
        return true;
    }
    // SAFETY: the checks above keep every element the strides reach inside its slice:
    // a: (m−1)·lda + k, b: (k−1)·ldb + n, c: (m−1)·ldc + n; c is the only one written and does
    // not alias a or b (distinct borrows).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            ldc as isize,
            accumulate,
            a.as_ptr(),
            1,
            lda as isize,
            b.as_ptr(),
            1,
            ldb as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
    true
}

/// The shape of one convolution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Geom {
    pub(crate) cin: usize,
    pub(crate) h: usize,
    pub(crate) w: usize,
    pub(crate) k: usize,
    pub(crate) stride: usize,
    pub(crate) pad: usize,
    pub(crate) ho: usize,
    pub(crate) wo: usize,
}

impl Geom {
    pub(crate) fn new(cin: usize, h: usize, w: usize, k: usize, stride: usize, pad: usize) -> Result<Self> {
        if k == 0 || stride == 0 || h + 2 * pad < k || w + 2 * pad < k {
            return Err(err(format!(
                "bad conv geometry {h}×{w}, k {k}, stride {stride}, pad {pad}"
            )));
        }
        Ok(Self {
            cin,
            h,
            w,
            k,
            stride,
            pad,
            ho: (h + 2 * pad - k) / stride + 1,
            wo: (w + 2 * pad - k) / stride + 1,
        })
    }

    pub(crate) fn kk(&self) -> usize {
        self.cin * self.k * self.k
    }

    pub(crate) fn p(&self) -> usize {
        self.ho * self.wo
    }

    /// The input column of output column `ox` for kernel column `kx`, if inside the image.
    fn ix(&self, ox: usize, kx: usize) -> Option<usize> {
        (ox * self.stride + kx)
            .checked_sub(self.pad)
            .filter(|&i| i < self.w)
    }

    fn iy(&self, oy: usize, ky: usize) -> Option<usize> {
        (oy * self.stride + ky)
            .checked_sub(self.pad)
            .filter(|&i| i < self.h)
    }

    /// The output columns whose input column for `kx` is inside the image: `lo..hi`.
    fn ox_range(&self, kx: usize) -> (usize, usize) {
        let lo = (0..self.wo)
            .find(|&ox| self.ix(ox, kx).is_some())
            .unwrap_or(self.wo);
        let hi = (lo..self.wo)
            .find(|&ox| self.ix(ox, kx).is_none())
            .unwrap_or(self.wo);
        (lo, hi)
    }

    /// im2col of one image `x[cin, h, w]` into `col[K, P]`, one row per task.
    pub(crate) fn im2col(&self, x: &[f32], col: &mut [f32]) {
        let (p, k, s) = (self.p(), self.k, self.stride);
        col.par_chunks_mut(p).enumerate().for_each(|(r, row)| {
            let (c, ky, kx) = (r / (k * k), (r / k) % k, r % k);
            let plane = &x[c * self.h * self.w..(c + 1) * self.h * self.w];
            let (lo, hi) = self.ox_range(kx);
            for oy in 0..self.ho {
                let out = &mut row[oy * self.wo..(oy + 1) * self.wo];
                let Some(iy) = self.iy(oy, ky) else {
                    out.fill(0.0);
                    continue;
                };
                out[..lo].fill(0.0);
                out[hi..].fill(0.0);
                let src = &plane[iy * self.w..(iy + 1) * self.w];
                let ix0 = lo * s + kx - self.pad;
                if s == 1 {
                    out[lo..hi].copy_from_slice(&src[ix0..ix0 + (hi - lo)]);
                } else {
                    for (j, o) in out[lo..hi].iter_mut().enumerate() {
                        *o = src[ix0 + j * s];
                    }
                }
            }
        });
    }

    /// [`Self::col2im`] added to `dx` when `accumulate`.
    pub(crate) fn col2im_into(&self, dcol: &[f32], dx: &mut [f32], accumulate: bool) {
        let (p, k, s) = (self.p(), self.k, self.stride);
        dx.par_chunks_mut(self.h * self.w)
            .enumerate()
            .for_each(|(c, plane)| {
                if !accumulate {
                    plane.fill(0.0);
                }
                for ky in 0..k {
                    for kx in 0..k {
                        let r = (c * k + ky) * k + kx;
                        let row = &dcol[r * p..(r + 1) * p];
                        let (lo, hi) = self.ox_range(kx);
                        for oy in 0..self.ho {
                            let Some(iy) = self.iy(oy, ky) else { continue };
                            let src = &row[oy * self.wo + lo..oy * self.wo + hi];
                            let dst = &mut plane[iy * self.w..(iy + 1) * self.w];
                            let ix0 = lo * s + kx - self.pad;
                            for (j, v) in src.iter().enumerate() {
                                dst[ix0 + j * s] += v;
                            }
                        }
                    }
                }
            });
    }
}

/// Scatters `z[C_out·s·s, H·W]` into `out[C_out, s·H, s·W]` (or gathers back when `gather`).
pub(crate) fn deconv_permute(z: &mut [f32], out: &mut [f32], s: usize, h: usize, w: usize, gather: bool) {
    let (p, ow) = (h * w, w * s);
    if gather {
        z.par_chunks_mut(s * s * p).enumerate().for_each(|(co, zc)| {
            let plane = &out[co * p * s * s..(co + 1) * p * s * s];
            for d in 0..s * s {
                let (dy, dx) = (d / s, d % s);
                for y in 0..h {
                    for x in 0..w {
                        zc[d * p + y * w + x] = plane[(y * s + dy) * ow + x * s + dx];
                    }
                }
            }
        });
    } else {
        out.par_chunks_mut(p * s * s).enumerate().for_each(|(co, plane)| {
            let zc = &z[co * s * s * p..(co + 1) * s * s * p];
            for d in 0..s * s {
                let (dy, dx) = (d / s, d % s);
                for y in 0..h {
                    for x in 0..w {
                        plane[(y * s + dy) * ow + x * s + dx] = zc[d * p + y * w + x];
                    }
                }
            }
        });
    }
}
