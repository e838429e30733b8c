//! Studies over many frames: Table II sweeps ([`sweep`]), failure scans ([`failures`]), the
//! refiner's active points (§V-C, [`active`]), per-box inspection ([`inspect`]), the auxiliary
//! LiDARs' alignment on the primary's surfaces and the χ² check of Ξ ([`alignment`]) and the PNG
//! plots they write ([`plot`]).

pub mod active;
pub mod alignment;
pub mod failures;
pub mod inspect;
pub mod plot;
pub mod sweep;
