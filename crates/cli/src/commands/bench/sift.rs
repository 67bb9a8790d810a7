//! `revisit bench sift`: Revisit's SIFT beside OpenCV's on the same real images.
//!
//! Both extractors see the same pixels (Revisit decodes every image once and
//! hands OpenCV a grayscale PNG of it), keep the same number of features and
//! run on one thread each: Revisit's extraction runs image after image on this
//! thread, OpenCV's with `cv2.setNumThreads(1)`. Only extraction is timed.
//! Consecutive images (sorted by name) are then matched and verified with both
//! feature sets through the same `revisit-matching` calls.

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, ensure, Context};
use revisit_core::{Features, Keypoint};
use revisit_features::{extract_sift, SiftOptions};
use revisit_matching::{match_descriptors, verify, MatchOptions, VerifyOptions};
use serde::Serialize;

/// Images used when `--images` is not given.
const DEFAULT_IMAGES: &str = "../shared/data/subvo/images";
/// The time target: Revisit at most this many times OpenCV's time per image.
const MAX_TIME_RATIO: f64 = 1.5;
/// The quality target: Revisit at least this fraction of OpenCV's inliers.
const MIN_INLIER_RATIO: f64 = 0.9;

#[derive(clap::Args)]
pub struct Args {
    /// Folder of images (JPEG/PNG); consecutive images by name must overlap.
    /// Default ../shared/data/subvo/images when it exists.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Use the first N images.
    #[arg(long, default_value_t = 40)]
    limit: usize,
    /// Features kept per image by both extractors.
    #[arg(long, default_value_t = 2048)]
    max_features: usize,
    /// Python interpreter with opencv-python.
    #[arg(long, default_value = ".venv/bin/python")]
    python: PathBuf,
    /// The OpenCV side's script.
    #[arg(long, default_value = "python/opencv_sift.py")]
    script: PathBuf,
    /// Revisit's SIFT options as JSON (fields of `SiftOptions`); the feature
    /// cap is always `--max-features`.
    #[arg(long)]
    options: Option<String>,
    /// Write the figures as JSON here too.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// The figures of one extractor.
#[derive(Serialize)]
struct Side {
    name: &'static str,
    seconds_per_image_median: f64,
    seconds_per_image_mean: f64,
    keypoints_per_image_mean: f64,
    matches_per_pair_median: f64,
    inliers_sum: usize,
    inliers_per_pair_median: f64,
    inliers_per_pair: Vec<usize>,
}

#[derive(Serialize)]
struct Report {
    images: usize,
    pairs: usize,
    max_features: usize,
    threads_per_extractor: usize,
    revisit: Side,
    opencv: Side,
    /// Revisit's median time per image over OpenCV's (target <= 1.5).
    time_ratio: f64,
    /// Revisit's verified inliers over OpenCV's, summed over pairs (target >= 0.9).
    inlier_ratio: f64,
    time_target_met: bool,
    inlier_target_met: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let folder = match &args.images {
        Some(folder) => folder.clone(),
        None if Path::new(DEFAULT_IMAGES).is_dir() => PathBuf::from(DEFAULT_IMAGES),
        None => bail!("--images is required ({DEFAULT_IMAGES} does not exist)"),
    };
    let paths = list_images(&folder, args.limit)?;
    ensure!(paths.len() >= 2, "need at least 2 images in {}, found {}", folder.display(), paths.len());
    let mut options: SiftOptions = match &args.options {
        Some(json) => serde_json::from_str(json).context("parsing --options as SIFT options")?,
        None => SiftOptions::default(),
    };
    options.max_num_features = args.max_features;
    options.check().context("--options")?;

    let images: Vec<image::GrayImage> = paths
        .iter()
        .map(|p| image::open(p).map(|i| i.to_luma8()).with_context(|| format!("reading image {}", p.display())))
        .collect::<anyhow::Result<_>>()?;

    // OpenCV reads exactly the pixels Revisit sees.
    let scratch = std::env::temp_dir().join(format!("revisit-bench-sift-{}", std::process::id()));
    fs::create_dir_all(&scratch).with_context(|| format!("creating {}", scratch.display()))?;
    let result = run_in(&args, &options, &paths, &images, &scratch);
    let _ = fs::remove_dir_all(&scratch);
    let report = result?;

    print_report(&report);
    super::write_json(args.json.as_deref(), &report)
}

fn run_in(
    args: &Args,
    options: &SiftOptions,
    paths: &[PathBuf],
    images: &[image::GrayImage],
    scratch: &Path,
) -> anyhow::Result<Report> {
    let mut list = String::new();
    for (i, image) in images.iter().enumerate() {
        let png = scratch.join(format!("{i:05}.png"));
        image.save(&png).with_context(|| format!("writing {}", png.display()))?;
        list.push_str(&format!("{}\n", png.display()));
    }
    let list_path = scratch.join("images.txt");
    fs::write(&list_path, list).with_context(|| format!("writing {}", list_path.display()))?;

    let bar = crate::progress::bar(images.len() as u64, "revisit sift");
    let mut revisit = Vec::with_capacity(images.len());
    for (image, path) in images.iter().zip(paths) {
        let start = Instant::now();
        let features = extract_sift(options, image).with_context(|| format!("SIFT on {}", path.display()))?;
        revisit.push((features, start.elapsed().as_secs_f64()));
        bar.inc(1);
    }
    bar.finish_and_clear();

    let output = scratch.join("opencv.bin");
    tracing::info!("running OpenCV SIFT on {} images", images.len());
    let status = Command::new(&args.python)
        .arg(&args.script)
        .arg(&list_path)
        .arg("--max-features")
        .arg(args.max_features.to_string())
        .arg("--threads")
        .arg("1")
        .arg("--out")
        .arg(&output)
        .status()
        .with_context(|| format!("starting {} {}", args.python.display(), args.script.display()))?;
    ensure!(status.success(), "{} {} failed: {status}", args.python.display(), args.script.display());
    let opencv = read_opencv(&output)?;
    ensure!(
        opencv.len() == images.len(),
        "{} holds {} images, expected {}",
        output.display(),
        opencv.len(),
        images.len()
    );

    let pairs = images.len() - 1;
    let bar = crate::progress::bar(2 * pairs as u64, "matching");
    let revisit_side = side("revisit", &revisit, &bar);
    let opencv_side = side("opencv", &opencv, &bar);
    bar.finish_and_clear();
    let time_ratio = revisit_side.seconds_per_image_median / opencv_side.seconds_per_image_median.max(1e-12);
    let inlier_ratio = revisit_side.inliers_sum as f64 / (opencv_side.inliers_sum as f64).max(1.0);
    Ok(Report {
        images: images.len(),
        pairs,
        max_features: args.max_features,
        threads_per_extractor: 1,
        time_target_met: time_ratio <= MAX_TIME_RATIO,
        inlier_target_met: inlier_ratio >= MIN_INLIER_RATIO,
        revisit: revisit_side,
        opencv: opencv_side,
        time_ratio,
        inlier_ratio,
    })
}

/// Image files (.jpg, .jpeg, .png) of `folder`, sorted by name, at most `limit`.
fn list_images(folder: &Path, limit: usize) -> anyhow::Result<Vec<PathBuf>> {
    let mut paths: Vec<PathBuf> = fs::read_dir(folder)
        .with_context(|| format!("listing images in {}", folder.display()))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
            matches!(ext.as_str(), "jpg" | "jpeg" | "png")
        })
        .collect();
    paths.sort();
    paths.truncate(limit);
    Ok(paths)
}

/// Reads the output of `python/opencv_sift.py` (format in its docstring).
fn read_opencv(path: &Path) -> anyhow::Result<Vec<(Features, f64)>> {
    let mut bytes = Vec::new();
    fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .with_context(|| format!("reading {}", path.display()))?;
    let mut cursor = bytes.as_slice();
    let mut take = |n: usize| -> anyhow::Result<&[u8]> {
        ensure!(cursor.len() >= n, "{} is truncated", path.display());
        let (head, tail) = cursor.split_at(n);
        cursor = tail;
        Ok(head)
    };
    ensure!(take(8)? == b"RVSIFT01", "{} is not an opencv_sift.py output", path.display());
    let u32_at = |b: &[u8]| b.try_into().map(u32::from_le_bytes).unwrap_or(0);
    let count = u32_at(take(4)?);
    let mut out = Vec::with_capacity(count as usize);
    for _ in 0..count {
        let n = u32_at(take(4)?) as usize;
        let seconds = take(8)?.try_into().map(f64::from_le_bytes).unwrap_or(0.0);
        let floats: Vec<f32> =
            take(16 * n)?.chunks_exact(4).map(|c| c.try_into().map(f32::from_le_bytes).unwrap_or(0.0)).collect();
        let keypoints =
            floats.chunks_exact(4).map(|k| Keypoint { x: k[0], y: k[1], scale: k[2], orientation: k[3] }).collect();
        let descriptors = take(128 * n)?.to_vec();
        out.push((Features { keypoints, descriptors, descriptor_dim: 128 }, seconds));
    }
    Ok(out)
}

fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

/// Times, keypoint counts, and matches and verified inliers of consecutive pairs.
fn side(name: &'static str, features: &[(Features, f64)], bar: &indicatif::ProgressBar) -> Side {
    let seconds: Vec<f64> = features.iter().map(|(_, s)| *s).collect();
    let mut matches_per_pair = Vec::new();
    let mut inliers_per_pair = Vec::new();
    for pair in features.windows(2) {
        let [(a, _), (b, _)] = pair else { continue };
        let matches = match_descriptors(a, b, &MatchOptions::default());
        let geometry = verify(&a.keypoints, &b.keypoints, &matches, &VerifyOptions::default());
        matches_per_pair.push(matches.len() as f64);
        inliers_per_pair.push(geometry.inlier_matches.len());
        bar.inc(1);
    }
    let inliers: Vec<f64> = inliers_per_pair.iter().map(|&n| n as f64).collect();
    Side {
        name,
        seconds_per_image_median: median(&seconds),
        seconds_per_image_mean: seconds.iter().sum::<f64>() / seconds.len().max(1) as f64,
        keypoints_per_image_mean: features.iter().map(|(f, _)| f.len() as f64).sum::<f64>()
            / features.len().max(1) as f64,
        matches_per_pair_median: median(&matches_per_pair),
        inliers_sum: inliers_per_pair.iter().sum(),
        inliers_per_pair_median: median(&inliers),
        inliers_per_pair,
    }
}

fn print_report(report: &Report) {
    println!(
        "SIFT on {} images ({} consecutive pairs), {} features, 1 thread per extractor",
        report.images, report.pairs, report.max_features
    );
    println!("{:<28} {:>12} {:>12}", "", "revisit", "opencv");
    let (r, o) = (&report.revisit, &report.opencv);
    println!(
        "{:<28} {:>12.3} {:>12.3}",
        "seconds/image (median)", r.seconds_per_image_median, o.seconds_per_image_median
    );
    println!("{:<28} {:>12.3} {:>12.3}", "seconds/image (mean)", r.seconds_per_image_mean, o.seconds_per_image_mean);
    println!(
        "{:<28} {:>12.1} {:>12.1}",
        "keypoints/image (mean)", r.keypoints_per_image_mean, o.keypoints_per_image_mean
    );
    println!("{:<28} {:>12.1} {:>12.1}", "matches/pair (median)", r.matches_per_pair_median, o.matches_per_pair_median);
    println!("{:<28} {:>12} {:>12}", "verified inliers (sum)", r.inliers_sum, o.inliers_sum);
    println!(
        "{:<28} {:>12.1} {:>12.1}",
        "verified inliers (median)", r.inliers_per_pair_median, o.inliers_per_pair_median
    );
    let verdict = |met: bool| if met { "met" } else { "NOT met" };
    println!(
        "time ratio revisit/opencv {:.2} (target <= {MAX_TIME_RATIO}): {}",
        report.time_ratio,
        verdict(report.time_target_met)
    );
    println!(
        "inlier ratio revisit/opencv {:.2} (target >= {MIN_INLIER_RATIO}): {}",
        report.inlier_ratio,
        verdict(report.inlier_target_met)
    );
}
