pub mod bench;
pub mod eval;
pub mod match_pair;
pub mod models;
pub mod reconstruct;
pub mod synth;
