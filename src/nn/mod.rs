//! The numeric kernels both stages' trainers share, knowing nothing of datasets or detectors:
//! [`gemm`] (matrix shapes and the gemm call every layer goes through), [`kernel`] (AVX-512 tiles
//! and packing), the direct and implicit convolutions' gradients ([`dgrad`], [`implicit`]) and
//! the layers built on them ([`layers`]: conv + BatchNorm + ReLU, deconvolution, heads, with
//! their backward passes).

pub(crate) mod dgrad;
pub mod gemm;
pub(crate) mod implicit;
pub(crate) mod kernel;
pub(crate) mod layers;
#[cfg(test)]
pub(crate) mod testutil;
