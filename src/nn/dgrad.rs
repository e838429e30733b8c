//! The input gradient of a stride-1 "same" convolution (the 3×3 layers, issue 28) without the
//! column gradient: `dX[ci][y][x] = Σ_co Σ_ky,kx W[co][ci][ky][kx] · dY[co][y+pad−ky][x+pad−kx]`
//! (zero outside the image), the convolution of `dY` with the transposed, flipped weights.
//!
//! It runs on [`kernel::tiles`](crate::nn::kernel::tiles): `a` is the weights rearranged to
//! `ci × (co, ky, kx)`, and each block's strips of `b` are copied straight from `dY`'s shifted
//! rows (an implicit im2col of `dY`, zeros at the borders: [`Shifted`], shared with the forward
//! and weight gradient of [`crate::nn::implicit`]), so neither the `K × P` column gradient
//! `Wᵀ · dY` (14 MB for a 24-channel 128 × 128 layer) nor col2im's pass over it exist. Each output
//! is one fused multiply-add chain over `(co, ky, kx)` in order, in one task: the result does not
//! depend on the thread count.

use candle_core::{Error, Result};

use crate::nn::gemm::Geom;
pub(crate) use crate::nn::implicit::applies;
use crate::nn::implicit::Shifted;
use crate::nn::kernel::{pack_a, tiles};

/// `dx (+)= ∂L/∂x` of the convolution `g` with weights `w [cout, cin, k, k]` from `dy [cout, h, w]`
/// (added to `dx` when `accumulate`). Only where [`applies`] holds.
pub(crate) fn input_grad(
    g: &Geom,
    cout: usize,
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    accumulate: bool,
) -> Result<()> {
    if !applies(g) {
        return Err(Error::Msg(format!(
            "input_grad: a {}×{} conv with stride {}, pad {} is not a stride-1 same conv on AVX-512",
            g.k, g.k, g.stride, g.pad
        )));
    }
    let (cin, p, kk2) = (g.cin, g.h * g.w, g.k * g.k);
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
    let sdy = Shifted::of(g, dy, true);
    tiles(dx, p, cin, p, k, &pa, accumulate, |n0, n1, pb| {
        sdy.pack(k, n0, n1, pb)
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gemm::{gemm_into, Mat};
    use crate::nn::kernel::avx512;
    use crate::nn::testutil::{data, rel};

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
