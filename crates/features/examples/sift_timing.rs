//! Times `extract_sift` on a few images: `cargo run --release -p revisit-features
//! --example sift_timing -- IMAGE...` (environment: FIRST_OCTAVE, MAX_FEATURES).
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let first_octave: i32 = std::env::var("FIRST_OCTAVE").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let max_num_features: usize = std::env::var("MAX_FEATURES").ok().and_then(|v| v.parse().ok()).unwrap_or(2048);
    let options = revisit_features::SiftOptions { first_octave, max_num_features, ..Default::default() };
    let mut total = 0.0;
    let paths: Vec<String> = std::env::args().skip(1).collect();
    for path in &paths {
        let image = image::open(path)?.to_luma8();
        let start = Instant::now();
        let features = revisit_features::extract_sift(&options, &image)?;
        let secs = start.elapsed().as_secs_f64();
        total += secs;
        println!("{path}: {} keypoints in {secs:.3} s", features.len());
    }
    println!("mean {:.3} s", total / paths.len().max(1) as f64);
    Ok(())
}
