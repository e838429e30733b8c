//! The fast training path of the stage-1 network's convolutions: candle [`CustomOp2`]s whose
//! forward and backward are im2col + `gemm` (the crate candle itself uses), in candle's NCHW
//! layout, so they drop into the candle graph in place of `conv2d` / `conv_transpose2d`.
//!
//! Why: candle's CPU conv2d gathers its im2col matrix element by element, and its backward
//! computes the weight gradient as a convolution and the input gradient with a naive
//! `conv_transpose2d`; in one stage-1 training step these were most of the time
//! (`docs/stage1.md`, "Where a training step's time goes"). Here:
//! - forward: `col[K, P]` (K = C_in·k·k rows, P = output pixels; a stride-1 row is a shifted
//!   copy of an input row), then `out[C_out, P] = W[C_out, K] · col`;
//! - input gradient: `dcol = Wᵀ · dY`, then col2im (each input channel sums its own k·k rows, in
//!   a fixed order, one channel per task), skipped when the input needs no gradient;
//! - weight gradient: `dW = dY · colᵀ` (col recomputed from the input).
//! - the transposed conv with kernel = stride (the neck's upsampling, no overlap) is one gemm
//!   `Z[C_out·s·s, P] = Wᵀ · X` and a scatter; its backward is the gather and two gemms.
//!
//! Determinism: gemm splits its output between threads, never a sum, and every other loop
//! writes disjoint outputs in a fixed order, so a result depends on nothing but the inputs and
//! the thread count (the kill/resume tests need this).

use candle_core::{CpuStorage, CustomOp2, Error, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

fn err(what: impl Into<String>) -> Error {
    Error::Msg(format!("fast conv: {}", what.into()))
}

/// The f32 data of a contiguous CPU tensor.
fn data<'a>(s: &'a CpuStorage, l: &Layout) -> Result<&'a [f32]> {
    let CpuStorage::F32(v) = s else {
        return Err(err("f32 tensors only"));
    };
    let (a, b) = l
        .contiguous_offsets()
        .ok_or_else(|| err("non-contiguous operand"))?;
    v.get(a..b).ok_or_else(|| err("layout outside its storage"))
}

fn dims4(l: &Layout) -> Result<[usize; 4]> {
    match l.dims() {
        &[a, b, c, d] => Ok([a, b, c, d]),
        d => Err(err(format!("expected a 4-d tensor, got {d:?}"))),
    }
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

    /// col2im: `dx[cin, h, w] = Σ` of `dcol[K, P]`'s entries over the patches each input pixel
    /// is in; one input channel per task, its k·k rows in order.
    pub(crate) fn col2im(&self, dcol: &[f32], dx: &mut [f32]) {
        self.col2im_into(dcol, dx, false)
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

/// `conv2d(x, w)` without bias: `x [N, C_in, H, W]`, `w [C_out, C_in, k, k]` (candle's and
/// PyTorch's layout), square kernel, equal stride and padding on both axes.
#[derive(Debug, Clone, Copy)]
pub struct Conv2dOp {
    pub stride: usize,
    pub padding: usize,
}

impl Conv2dOp {
    fn geom(&self, x: [usize; 4], w: [usize; 4]) -> Result<Geom> {
        if w[1] != x[1] || w[2] != w[3] {
            return Err(err(format!("weight {w:?} does not fit input {x:?}")));
        }
        Geom::new(x[1], x[2], x[3], w[2], self.stride, self.padding)
    }
}

impl CustomOp2 for Conv2dOp {
    fn name(&self) -> &'static str {
        "mlod-conv2d"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (xd, wd) = (dims4(l1)?, dims4(l2)?);
        let g = self.geom(xd, wd)?;
        let (x, w) = (data(s1, l1)?, data(s2, l2)?);
        let (n, cout, kk, p) = (xd[0], wd[0], g.kk(), g.p());
        let mut out = vec![0f32; n * cout * p];
        let mut col = vec![0f32; kk * p];
        let img = g.cin * g.h * g.w;
        for b in 0..n {
            g.im2col(&x[b * img..(b + 1) * img], &mut col);
            let o = &mut out[b * cout * p..(b + 1) * cout * p];
            gemm_into(
                o,
                Mat::rm(cout, p),
                w,
                Mat::rm(cout, kk),
                &col,
                Mat::rm(kk, p),
                false,
            )?;
        }
        Ok((CpuStorage::F32(out), Shape::from((n, cout, g.ho, g.wo))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        let dx = if x.track_op() {
            let op = Conv2dInputGrad {
                op: *self,
                h: x.dim(2)?,
                w: x.dim(3)?,
            };
            Some(grad.apply_op2_no_bwd(w, &op)?)
        } else {
            None
        };
        let dw = if w.track_op() {
            let op = Conv2dWeightGrad {
                op: *self,
                k: w.dim(2)?,
            };
            Some(grad.apply_op2_no_bwd(&x.contiguous()?, &op)?)
        } else {
            None
        };
        Ok((dx, dw))
    }
}

/// The input gradient of [`Conv2dOp`]: `(dY, w) → dX`.
struct Conv2dInputGrad {
    op: Conv2dOp,
    h: usize,
    w: usize,
}

impl CustomOp2 for Conv2dInputGrad {
    fn name(&self) -> &'static str {
        "mlod-conv2d-dx"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (gd, wd) = (dims4(l1)?, dims4(l2)?);
        let g = self.op.geom([gd[0], wd[1], self.h, self.w], wd)?;
        if gd[1] != wd[0] || gd[2] != g.ho || gd[3] != g.wo {
            return Err(err("output gradient does not fit the conv"));
        }
        let (dy, w) = (data(s1, l1)?, data(s2, l2)?);
        let (n, cout, kk, p) = (gd[0], wd[0], g.kk(), g.p());
        let img = g.cin * g.h * g.w;
        let mut dx = vec![0f32; n * img];
        let mut dcol = vec![0f32; kk * p];
        for b in 0..n {
            let dyb = &dy[b * cout * p..(b + 1) * cout * p];
            gemm_into(
                &mut dcol,
                Mat::rm(kk, p),
                w,
                Mat::tr(cout, kk),
                dyb,
                Mat::rm(cout, p),
                false,
            )?;
            g.col2im(&dcol, &mut dx[b * img..(b + 1) * img]);
        }
        Ok((CpuStorage::F32(dx), Shape::from((n, g.cin, g.h, g.w))))
    }
}

/// The weight gradient of [`Conv2dOp`]: `(dY, x) → dW`.
struct Conv2dWeightGrad {
    op: Conv2dOp,
    k: usize,
}

impl CustomOp2 for Conv2dWeightGrad {
    fn name(&self) -> &'static str {
        "mlod-conv2d-dw"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (gd, xd) = (dims4(l1)?, dims4(l2)?);
        let cout = gd[1];
        let g = self.op.geom(xd, [cout, xd[1], self.k, self.k])?;
        if gd[0] != xd[0] || gd[2] != g.ho || gd[3] != g.wo {
            return Err(err("output gradient does not fit the conv"));
        }
        let (dy, x) = (data(s1, l1)?, data(s2, l2)?);
        let (n, kk, p) = (xd[0], g.kk(), g.p());
        let img = g.cin * g.h * g.w;
        let mut dw = vec![0f32; cout * kk];
        let mut col = vec![0f32; kk * p];
        for b in 0..n {
            g.im2col(&x[b * img..(b + 1) * img], &mut col);
            let dyb = &dy[b * cout * p..(b + 1) * cout * p];
            gemm_into(
                &mut dw,
                Mat::rm(cout, kk),
                dyb,
                Mat::rm(cout, p),
                &col,
                Mat::tr(kk, p),
                b > 0,
            )?;
        }
        Ok((CpuStorage::F32(dw), Shape::from((cout, g.cin, self.k, self.k))))
    }
}

/// `conv_transpose2d(x, w)` without bias, with kernel = stride and no padding (each input pixel
/// owns an s×s output block): `x [N, C_in, H, W]`, `w [C_in, C_out, s, s]` (candle's layout),
/// output `[N, C_out, s·H, s·W]`.
#[derive(Debug, Clone, Copy)]
pub struct DeconvOp {
    pub stride: usize,
}

/// `[N, C_in, H, W]`, `[C_in, C_out, s, s]` → (n, cin, h, w, cout, s) checked.
fn deconv_shape(stride: usize, x: [usize; 4], w: [usize; 4]) -> Result<(usize, usize, usize, usize, usize)> {
    if w[0] != x[1] || w[2] != stride || w[3] != stride || stride == 0 {
        return Err(err(format!(
            "deconv weight {w:?} does not fit input {x:?} at stride {stride}"
        )));
    }
    Ok((x[0], x[1], x[2], x[3], w[1]))
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

impl CustomOp2 for DeconvOp {
    fn name(&self) -> &'static str {
        "mlod-deconv"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (xd, wd) = (dims4(l1)?, dims4(l2)?);
        let (n, cin, h, wi, cout) = deconv_shape(self.stride, xd, wd)?;
        let (x, w) = (data(s1, l1)?, data(s2, l2)?);
        let (s, p) = (self.stride, h * wi);
        let j = cout * s * s;
        let mut out = vec![0f32; n * j * p];
        let mut z = vec![0f32; j * p];
        for b in 0..n {
            let xb = &x[b * cin * p..(b + 1) * cin * p];
            gemm_into(
                &mut z,
                Mat::rm(j, p),
                w,
                Mat::tr(cin, j),
                xb,
                Mat::rm(cin, p),
                false,
            )?;
            deconv_permute(&mut z, &mut out[b * j * p..(b + 1) * j * p], s, h, wi, false);
        }
        Ok((CpuStorage::F32(out), Shape::from((n, cout, h * s, wi * s))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        // dZ once, shared by both gradients: [N, C_out·s·s, H, W].
        let dz = grad.apply_op1_no_bwd(&DeconvGather { stride: self.stride })?;
        let dx = if x.track_op() {
            Some(dz.apply_op2_no_bwd(w, &DeconvInputGrad)?)
        } else {
            None
        };
        let dw = if w.track_op() {
            let op = DeconvWeightGrad { stride: self.stride };
            Some(dz.apply_op2_no_bwd(&x.contiguous()?, &op)?)
        } else {
            None
        };
        Ok((dx, dw))
    }
}

/// `dOut [N, C_out, s·H, s·W]` → `dZ [N, C_out·s·s, H, W]`.
struct DeconvGather {
    stride: usize,
}

impl candle_core::CustomOp1 for DeconvGather {
    fn name(&self) -> &'static str {
        "mlod-deconv-gather"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let d = dims4(l)?;
        let st = self.stride;
        if st == 0 || d[2] % st != 0 || d[3] % st != 0 {
            return Err(err("deconv gradient is not a multiple of the stride"));
        }
        let (n, cout, h, w) = (d[0], d[1], d[2] / st, d[3] / st);
        let g = data(s, l)?;
        let per = cout * st * st * h * w;
        let mut z = vec![0f32; n * per];
        let mut scratch = vec![0f32; per];
        for b in 0..n {
            scratch.copy_from_slice(&g[b * per..(b + 1) * per]);
            deconv_permute(&mut z[b * per..(b + 1) * per], &mut scratch, st, h, w, true);
        }
        Ok((CpuStorage::F32(z), Shape::from((n, cout * st * st, h, w))))
    }
}

/// `(dZ, w) → dX`: `dX[C_in, P] = W[C_in, J] · dZ[J, P]`.
struct DeconvInputGrad;

impl CustomOp2 for DeconvInputGrad {
    fn name(&self) -> &'static str {
        "mlod-deconv-dx"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (zd, wd) = (dims4(l1)?, dims4(l2)?);
        let (n, j, h, w, cin) = (zd[0], zd[1], zd[2], zd[3], wd[0]);
        if wd[1] * wd[2] * wd[3] != j {
            return Err(err("deconv weight does not fit its gradient"));
        }
        let (dz, wt) = (data(s1, l1)?, data(s2, l2)?);
        let p = h * w;
        let mut dx = vec![0f32; n * cin * p];
        for b in 0..n {
            let o = &mut dx[b * cin * p..(b + 1) * cin * p];
            gemm_into(
                o,
                Mat::rm(cin, p),
                wt,
                Mat::rm(cin, j),
                &dz[b * j * p..(b + 1) * j * p],
                Mat::rm(j, p),
                false,
            )?;
        }
        Ok((CpuStorage::F32(dx), Shape::from((n, cin, h, w))))
    }
}

/// `(dZ, x) → dW`: `dW[C_in, J] = X[C_in, P] · dZᵀ`.
struct DeconvWeightGrad {
    stride: usize,
}

impl CustomOp2 for DeconvWeightGrad {
    fn name(&self) -> &'static str {
        "mlod-deconv-dw"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (zd, xd) = (dims4(l1)?, dims4(l2)?);
        let (n, j, cin, p) = (zd[0], zd[1], xd[1], xd[2] * xd[3]);
        let s = self.stride;
        if xd[0] != n || zd[2] * zd[3] != p || s == 0 || j % (s * s) != 0 {
            return Err(err("deconv gradient does not fit its input"));
        }
        let (dz, x) = (data(s1, l1)?, data(s2, l2)?);
        let mut dw = vec![0f32; cin * j];
        for b in 0..n {
            let (xb, zb) = (
                &x[b * cin * p..(b + 1) * cin * p],
                &dz[b * j * p..(b + 1) * j * p],
            );
            gemm_into(
                &mut dw,
                Mat::rm(cin, j),
                xb,
                Mat::rm(cin, p),
                zb,
                Mat::tr(j, p),
                b > 0,
            )?;
        }
        Ok((CpuStorage::F32(dw), Shape::from((cin, j / (s * s), s, s))))
    }
}

/// `conv2d` on the fast path (see the module doc); `x` and `w` as for candle's `conv2d`.
pub fn conv2d(x: &Tensor, w: &Tensor, stride: usize, padding: usize) -> Result<Tensor> {
    x.contiguous()?
        .apply_op2(&w.contiguous()?, Conv2dOp { stride, padding })
}

/// `conv_transpose2d` with kernel = stride and no padding on the fast path.
pub fn conv_transpose2d(x: &Tensor, w: &Tensor, stride: usize) -> Result<Tensor> {
    x.contiguous()?.apply_op2(&w.contiguous()?, DeconvOp { stride })
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn randn(shape: &[usize], seed: u64) -> Tensor {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n: usize = shape.iter().product();
        let d = Normal::new(0.0f32, 1.0).unwrap();
        let v: Vec<f32> = (0..n).map(|_| d.sample(&mut rng)).collect();
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    /// max |a − b| / max(max |b|, 1e-6) over all elements.
    fn rel(a: &Tensor, b: &Tensor) -> f32 {
        let a: Vec<f32> = a.flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f32> = b.flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
        a.iter().zip(&b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
    }

    /// Forward and both gradients of `fast` equal candle's `slow` (loss Σ r·y with random r).
    fn check(
        x_shape: &[usize],
        w_shape: &[usize],
        fast: impl Fn(&Tensor, &Tensor) -> Result<Tensor>,
        slow: impl Fn(&Tensor, &Tensor) -> Result<Tensor>,
        seed: u64,
    ) {
        let x = Var::from_tensor(&randn(x_shape, seed)).unwrap();
        let w = Var::from_tensor(&randn(w_shape, seed + 1)).unwrap();
        let yf = fast(x.as_tensor(), w.as_tensor()).unwrap();
        let ys = slow(x.as_tensor(), w.as_tensor()).unwrap();
        assert_eq!(yf.dims(), ys.dims());
        assert!(rel(&yf, &ys) < 1e-5, "forward {}", rel(&yf, &ys));
        let r = randn(ys.dims(), seed + 2);
        let gf = (yf * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let gs = (ys * &r).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in [("x", &x), ("w", &w)] {
            let (a, b) = (gf.get(v.as_tensor()).unwrap(), gs.get(v.as_tensor()).unwrap());
            assert!(rel(a, b) < 1e-4, "d{name}: {}", rel(a, b));
        }
    }

    #[test]
    fn conv_gradients_equal_candle() {
        // (input, weight, stride, padding): the network's 3×3 stride 1 and 2, the 1×1 neck and
        // heads, odd sizes, a batch of two.
        let cases: [(&[usize], &[usize], usize, usize); 6] = [
            (&[1, 5, 12, 12], &[7, 5, 3, 3], 1, 1),
            (&[1, 5, 12, 12], &[7, 5, 3, 3], 2, 1),
            (&[1, 4, 11, 9], &[6, 4, 3, 3], 2, 1),
            (&[1, 8, 10, 10], &[3, 8, 1, 1], 1, 0),
            (&[2, 3, 9, 10], &[4, 3, 3, 3], 1, 1),
            (&[1, 3, 9, 9], &[2, 3, 3, 3], 1, 0),
        ];
        for (i, (xs, ws, s, p)) in cases.into_iter().enumerate() {
            check(
                xs,
                ws,
                |x, w| conv2d(x, w, s, p),
                |x, w| x.conv2d(w, p, s, 1, 1),
                10 * i as u64,
            );
        }
    }

    #[test]
    fn deconv_gradients_equal_candle() {
        for (i, (xs, ws)) in [
            (&[1usize, 6, 5, 7][..], &[6usize, 4, 2, 2][..]),
            (&[2, 3, 4, 4], &[3, 5, 2, 2]),
            (&[1, 2, 3, 3], &[2, 3, 3, 3]),
        ]
        .into_iter()
        .enumerate()
        {
            let s = ws[2];
            check(
                xs,
                ws,
                |x, w| conv_transpose2d(x, w, s),
                |x, w| x.conv_transpose2d(w, 0, 0, s, 1),
                100 + 10 * i as u64,
            );
        }
    }

    #[test]
    fn conv_is_deterministic() {
        let x = randn(&[1, 6, 32, 32], 7);
        let w = randn(&[8, 6, 3, 3], 8);
        let a: Vec<f32> = conv2d(&x, &w, 1, 1)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        let b: Vec<f32> = conv2d(&x, &w, 1, 1)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert!(a.iter().zip(&b).all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}
