//! Stage-1 and MLOD detection, one test binary: the folded network against candle's graph
//! ([`fast`]), the shipped weights against the committed fixtures ([`shipped`]) and the
//! evaluation (matching, AP) on committed detections ([`eval`]).

mod eval;
mod fast;
mod shipped;
