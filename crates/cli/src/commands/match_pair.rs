//! `revisit match`: the verified matches between two images, to debug a pair.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use image::{Rgb, RgbImage};
use revisit_core::{CrossKey, PairKind, Roll};
use revisit_matching::{match_descriptors, match_learned_pair, verify, CrossOptions, MatchOptions, RollSearch};
use revisit_pipeline::learned::LearnedMethod;
use revisit_pipeline::options::FeatureOptions;
use serde::Serialize;

use crate::commands::models::ToolArgs;

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum MethodArg {
    /// ALIKED + LightGlue (default of cross-visit matching).
    AlikedLightglue,
    /// XFeat + LighterGlue.
    XfeatLighterglue,
    /// SIFT + ratio test (rotation-invariant: no roll search needed).
    Sift,
}

impl MethodArg {
    pub fn learned(self) -> Option<LearnedMethod> {
        match self {
            MethodArg::AlikedLightglue => Some(LearnedMethod::AlikedLightglue),
            MethodArg::XfeatLighterglue => Some(LearnedMethod::XfeatLighterglue),
            MethodArg::Sift => None,
        }
    }
}

/// Match two images and print the verified matches: which roll of the second
/// image won, how many inliers, and optionally every match as JSON and a
/// drawing. A learned pair is judged by the same rule as in `reconstruct`
/// (the roll must stand out, and at least 30 inliers must verify). Coordinates are pixels in each image's own, unrotated frame, with
/// (0, 0) at the top-left corner of the top-left pixel (COLMAP's convention).
#[derive(clap::Args)]
pub struct Args {
    /// The first image.
    image_a: PathBuf,
    /// The second image (the one that is rolled).
    image_b: PathBuf,
    /// The matcher.
    #[arg(long, value_enum, default_value = "aliked-lightglue")]
    method: MethodArg,
    /// Try the second image at rolls of 0, 90, 180 and 270 degrees and keep the
    /// roll with the most verified inliers.
    #[arg(long)]
    roll_search: bool,
    /// Decide the roll by matching every roll in full (4 matches) instead of a
    /// 256-keypoint probe per roll followed by one full match.
    #[arg(long, requires = "roll_search")]
    full_search: bool,
    /// Write {"roll_deg", "inliers", "matches": [[xa, ya, xb, yb], ...]} here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Draw the two images side by side with the verified matches to this PNG.
    #[arg(long, value_name = "PNG")]
    draw: Option<PathBuf>,
    /// Seed of RANSAC.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[command(flatten)]
    tools: ToolArgs,
}

#[derive(Serialize)]
struct Output {
    roll_deg: u32,
    inliers: usize,
    matches: Vec<[f32; 4]>,
}

fn load(path: &Path) -> Result<RgbImage> {
    Ok(revisit_pipeline::images::read(path)?.to_rgb8())
}

pub fn run(args: Args) -> Result<()> {
    let a = load(&args.image_a)?;
    let b = load(&args.image_b)?;
    let (roll, matches) = match args.method.learned() {
        None => {
            let options = FeatureOptions::default();
            let extract = |image: &RgbImage, path: &Path| {
                revisit_pipeline::stages::sift_features(&options, &image::DynamicImage::ImageRgb8(image.clone()))
                    .map_err(anyhow::Error::msg)
                    .with_context(|| path.display().to_string())
            };
            let (fa, fb) = (extract(&a, &args.image_a)?, extract(&b, &args.image_b)?);
            let matches = match_descriptors(&fa, &fb, &MatchOptions::default());
            let verify_options = revisit_matching::VerifyOptions { seed: args.seed, ..Default::default() };
            let geometry = verify(&fa.keypoints, &fb.keypoints, &matches, &verify_options);
            let points = geometry
                .inlier_matches
                .iter()
                .filter_map(|&[i, j]| {
                    let (p, q) = (fa.keypoints.get(i as usize)?, fb.keypoints.get(j as usize)?);
                    Some([p.x, p.y, q.x, q.y])
                })
                .collect::<Vec<_>>();
            (Roll::R0, points)
        }
        Some(method) => {
            let (_, mut learned) = args.tools.open(method)?;
            let mut options = CrossOptions {
                roll_search: match (args.roll_search, args.full_search) {
                    (false, _) => RollSearch::Off,
                    (true, false) => RollSearch::PROBE,
                    (true, true) => RollSearch::Full,
                },
                ..CrossOptions::default()
            };
            options.verify.seed = args.seed;
            let fa = learned.extract(&a, Roll::R0).with_context(|| args.image_a.display().to_string())?;
            let fb: Vec<(Roll, _)> = options
                .roll_search
                .rolls()
                .iter()
                .map(|&roll| Ok((roll, learned.extract(&b, roll).with_context(|| args.image_b.display().to_string())?)))
                .collect::<Result<_>>()?;
            let pair = match_learned_pair(
                &mut learned.matcher,
                (&fa, &[]),
                (&fb, &[]),
                PairKind::Cross,
                (None, None),
                &options,
            )?;
            for (roll, inliers) in &pair.inliers_by_roll {
                tracing::info!("roll {:>3}: {inliers} inliers", roll.degrees());
            }
            let p = options.confident_probability;
            match (pair.accepted(), &pair.confident) {
                (false, _) => println!(
                    "rejected: the roll does not stand out, or fewer than {} inliers",
                    options.verify.min_inliers
                ),
                (true, Some((sure, _))) => {
                    println!("confident: {} inliers above probability {p} verify alone", sure.len())
                }
                (true, None) => println!("weak: its matches above probability {p} do not verify alone"),
            }
            let at = |side: usize, key: CrossKey| match key {
                CrossKey::Learned(l) => pair.positions[side].get(l as usize).copied(),
                CrossKey::Own(_) => None,
            };
            let points = pair
                .inliers
                .iter()
                .filter_map(|&[ka, kb]| {
                    let (p, q) = (at(0, ka)?, at(1, kb)?);
                    Some([p[0], p[1], q[0], q[1]])
                })
                .collect::<Vec<_>>();
            (pair.roll, points)
        }
    };
    println!("roll: {} degrees", roll.degrees());
    println!("inliers: {}", matches.len());
    if let Some(path) = &args.json {
        let output = Output { roll_deg: roll.degrees(), inliers: matches.len(), matches: matches.clone() };
        std::fs::write(path, serde_json::to_string(&output)?).with_context(|| format!("--json {}", path.display()))?;
        println!("wrote:   {}", path.display());
    }
    if let Some(path) = &args.draw {
        draw(&a, &b, &matches).save(path).with_context(|| format!("--draw {}", path.display()))?;
        println!("wrote:   {}", path.display());
    }
    Ok(())
}

/// The two images side by side with a line per match, coloured along a hue ramp.
fn draw(a: &RgbImage, b: &RgbImage, matches: &[[f32; 4]]) -> RgbImage {
    let mut canvas = RgbImage::new(a.width() + b.width(), a.height().max(b.height()));
    image::imageops::replace(&mut canvas, a, 0, 0);
    image::imageops::replace(&mut canvas, b, i64::from(a.width()), 0);
    let offset = a.width() as f32;
    for (k, m) in matches.iter().enumerate() {
        let hue = k as f32 / matches.len().max(1) as f32;
        let color =
            Rgb([(255.0 * (1.0 - hue)) as u8, (255.0 * (1.0 - (2.0 * hue - 1.0).abs())) as u8, (255.0 * hue) as u8]);
        line(&mut canvas, [m[0], m[1]], [m[2] + offset, m[3]], color);
    }
    canvas
}

fn line(canvas: &mut RgbImage, from: [f32; 2], to: [f32; 2], color: Rgb<u8>) {
    let steps = (to[0] - from[0]).abs().max((to[1] - from[1]).abs()).ceil().max(1.0) as usize;
    for s in 0..=steps {
        let t = s as f32 / steps as f32;
        let (x, y) = (from[0] + t * (to[0] - from[0]), from[1] + t * (to[1] - from[1]));
        if x >= 0.0 && y >= 0.0 && (x as u32) < canvas.width() && (y as u32) < canvas.height() {
            canvas.put_pixel(x as u32, y as u32, color);
        }
    }
}
