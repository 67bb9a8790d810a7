pub mod bench;
pub mod eval;
pub mod reconstruct;
pub mod synth;
