//! Times descriptor matching on random descriptors: `cargo run --release --example match_speed -p revisit-matching`.
use revisit_core::{Features, Keypoint};

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(4096);
    let mut state = 1u64;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
        (state >> 56) as u8
    };
    let mut make = || Features {
        keypoints: vec![Keypoint { x: 0.0, y: 0.0, scale: 1.0, orientation: 0.0 }; n],
        descriptors: (0..n * 128).map(|_| next()).collect(),
        descriptor_dim: 128,
    };
    let (a, b) = (make(), make());
    let start = std::time::Instant::now();
    let m = revisit_matching::match_descriptors(&a, &b, &Default::default());
    println!("{n} x {n}: {} matches in {:.3} s", m.len(), start.elapsed().as_secs_f64());
}
