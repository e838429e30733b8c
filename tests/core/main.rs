//! The geometry and uncertainty core, one test binary: rotated 3D IoU properties
//! ([`iou_props`]), Ξ against a Monte Carlo estimate ([`monte_carlo`]), the fused cloud and its
//! tr(Ξ) ([`pipeline`]) and the plane-fitting experiment of §III-C ([`plane_fit`]).

mod iou_props;
mod monte_carlo;
mod pipeline;
mod plane_fit;
