//! `mlod`: the headless core of the MLOD debugger — multi-LiDAR 3D object detection under
//! extrinsic perturbation (Jiao, Yun, Tai, Liu: "MLOD: Awareness of Extrinsic Perturbation in
//! Multi-LiDAR 3D Object Detection for Autonomous Driving").
//!
//! Dependencies point one way: `gui` → `pipeline` → {`uncertainty`, …} → {`dataset`, `geometry`}.
//! Nothing outside `gui` depends on egui, eframe or wgpu.
//!
//! No panic on data: the library denies `unwrap`, `expect` and `panic!` outside tests; each site
//! that remains states with `#[allow]` and a comment why it cannot fail (an invariant the code
//! itself established, never a property of a file or an argument). Indexing is not denied
//! crate-wide (the per-point kernels index slices whose lengths they checked once up front); the
//! parsers of outside data index only through `get`, and `fuzz/` searches them for panics.

#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

pub mod analysis;
pub mod calib;
pub mod cases;
pub mod color;
pub mod dataset;
pub mod detect;
pub mod eval;
pub mod export;
pub mod external;
pub mod geometry;
pub mod io;
pub mod nn;
pub mod pipeline;
pub mod refine;
pub mod session;
pub mod synth;
pub mod train;
pub mod uncertainty;

#[cfg(feature = "gui")]
pub mod gui;
#[cfg(feature = "gui")]
pub mod render;
