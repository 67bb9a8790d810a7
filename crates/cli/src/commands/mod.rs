pub mod bench;
pub mod doctor;
pub mod eval;
pub mod match_pair;
pub mod models;
pub mod options;
pub mod reconstruct;
pub mod synth;
