//! `mlod`: the headless core of the MLOD debugger — multi-LiDAR 3D object detection under
//! extrinsic perturbation (Jiao, Yun, Tai, Liu: "MLOD: Awareness of Extrinsic Perturbation in
//! Multi-LiDAR 3D Object Detection for Autonomous Driving").
//!
//! Dependencies point one way: `gui` → `pipeline` → {`uncertainty`, …} → {`lyft`, `geometry`}.
//! Nothing outside `gui` depends on egui, eframe or wgpu.

pub mod calib;
pub mod color;
pub mod detect;
pub mod eval;
pub mod export;
pub mod failures;
pub mod geometry;
pub mod inspect;
pub mod io;
pub mod lyft;
pub mod pipeline;
pub mod plot;
pub mod refine;
pub mod session;
pub mod sweep;
pub mod synth;
pub mod uncertainty;

#[cfg(feature = "gui")]
pub mod gui;
