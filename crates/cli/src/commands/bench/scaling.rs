//! `revisit bench matching --scale 16,32,64,128`: the scaling study. For each
//! size, a synthetic survey of 3 visits x N images at strong change; each
//! cross-visit strategy run on it through the pipeline's `Workspace` (the
//! figures `bench matching` prints for one dataset), or, when its learned
//! matching would take longer than the budget, estimated from a random
//! sample of its pairs (marked as an estimate). The published figure beside
//! it: VPR-guided learned matching took 4.4% of exhaustive learned matching's
//! time at 2.5k images.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use image::{Rgb, RgbImage};
use revisit_core::Roll;
use revisit_eval::{log_log, Series};
use revisit_matching::{CrossOptions, RollSearch};
use revisit_pipeline::CrossStrategy;
use revisit_synth::{ChangeGrade, SynthOptions};
use serde::{Deserialize, Serialize};

use super::matching::{run_strategy, session_images, Args, StrategyFigures};

/// Visits of every survey of the study.
const VISITS: usize = 3;
/// The study's surveys: strong change (new sand, other light, visits flown at
/// other headings), one seed for all sizes.
const SEED: u64 = 0;

/// One strategy at one size: measured by a whole run, or estimated.
#[derive(Clone, Serialize, Deserialize)]
struct Row {
    images_per_visit: usize,
    images: usize,
    strategy: String,
    /// Estimated from `sampled_pairs` pairs instead of run.
    estimated: bool,
    /// SIFT matching + place recognition + learned matching (measured), or the
    /// learned matching of every pair the strategy sends (estimated).
    matching_secs: f64,
    learned_features_secs: f64,
    /// Pairs matched (SIFT and learned), or, estimated, learned pairs sent.
    pairs: usize,
    /// Only for measured rows: what the run gave.
    cross_pairs_verified: Option<usize>,
    sessions_in_chosen_model: Option<usize>,
    median_cross_error_px: Option<f64>,
    /// The pairs timed to estimate, or to decide the strategy fits the budget.
    sampled_pairs: usize,
    secs_per_sampled_pair: Option<f64>,
}

#[derive(Serialize, Deserialize)]
struct Study {
    visits: usize,
    change: String,
    seed: u64,
    budget_minutes: f64,
    /// The options a measured row was made with (a row made with others is not kept).
    #[serde(default)]
    max_features: usize,
    #[serde(default)]
    vpr_top_k: usize,
    rows: Vec<Row>,
}

pub fn run(args: &Args) -> Result<()> {
    ensure!(args.scale.iter().all(|&n| n >= 2), "--scale: every size needs at least 2 images a visit");
    ensure!(args.budget_minutes > 0.0, "--budget-minutes must be positive");
    ensure!(args.sample_pairs >= 1, "--sample-pairs must be at least 1");
    let work = args.work.clone().unwrap_or_else(|| PathBuf::from("bench-scaling"));
    let cancel = crate::signals::cancel_on_signals()?;
    let mut study = Study {
        visits: VISITS,
        change: "strong".to_owned(),
        seed: SEED,
        budget_minutes: args.budget_minutes,
        max_features: args.max_features,
        vpr_top_k: args.vpr_top_k,
        rows: Vec::new(),
    };
    // A study run again keeps the rows it measured (a resumed run would time only what was left).
    let measured_before = measured_rows(&work.join("scaling.json"), &study)?;
    for &n in &args.scale {
        let dataset = survey(&work.join(n.to_string()), n)?;
        let mut sample = Sample::open(args, &dataset)?;
        for &strategy in &args.strategies {
            let name = strategy.name();
            if let Some(row) = measured_before.iter().find(|r| r.images_per_visit == n && r.strategy == name) {
                println!("== {name} at {VISITS} x {n}: measured before");
                print_row(row);
                study.rows.push(row.clone());
                continue;
            }
            let learned_pairs = learned_pairs(strategy, n, args.vpr_top_k);
            let per_pair = if learned_pairs > 0 { Some(sample.secs_per_pair(strategy)?) } else { None };
            let projected_secs = per_pair.map_or(0.0, |secs| secs * learned_pairs as f64);
            let row = if projected_secs > 60.0 * args.budget_minutes {
                println!(
                    "== {name} at {VISITS} x {n}: estimated ({learned_pairs} learned pairs x {:.2} s = {:.0} min)",
                    per_pair.unwrap_or(0.0),
                    projected_secs / 60.0
                );
                Row {
                    images_per_visit: n,
                    images: VISITS * n,
                    strategy: name.to_owned(),
                    estimated: true,
                    matching_secs: projected_secs,
                    learned_features_secs: sample.secs_per_extraction()? * extractions(n) as f64,
                    pairs: learned_pairs,
                    cross_pairs_verified: None,
                    sessions_in_chosen_model: None,
                    median_cross_error_px: None,
                    sampled_pairs: sample.pairs(strategy).len(),
                    secs_per_sampled_pair: per_pair,
                }
            } else {
                // Timed whole: what an interrupted run left is not reused.
                let out = work.join(n.to_string()).join(name);
                if out.exists() {
                    std::fs::remove_dir_all(&out).with_context(|| format!("removing {}", out.display()))?;
                }
                let (_, figures) = run_strategy(args, strategy, &dataset, &out, &cancel)?;
                measured_row(n, &figures, per_pair.map(|secs| (sample.pairs(strategy).len(), secs)))
            };
            print_row(&row);
            study.rows.push(row);
        }
        // The figures so far, so that a study stopped at a larger size keeps them.
        write(&work, &study)?;
    }
    println!();
    print_summary(&study);
    println!("wrote {} and {}", work.join("scaling.json").display(), work.join("scaling.png").display());
    Ok(())
}

/// The measured rows of the study in `path`, if there is one made with the
/// options of `this`.
fn measured_rows(path: &Path, this: &Study) -> Result<Vec<Row>> {
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let before: Study =
        serde_json::from_str(&text).with_context(|| format!("{}: not a scaling study", path.display()))?;
    if (before.max_features, before.vpr_top_k) != (this.max_features, this.vpr_top_k) {
        return Ok(Vec::new());
    }
    Ok(before.rows.into_iter().filter(|r| !r.estimated).collect())
}

/// The survey of `n` images a visit in `dir/reef`, rendered unless a whole
/// one is there (rendered into a side folder, then renamed).
fn survey(dir: &Path, n: usize) -> Result<PathBuf> {
    let reef = dir.join("reef");
    if reef.join("truth").is_dir() {
        return Ok(reef);
    }
    let partial = dir.join("reef.partial");
    if partial.exists() {
        std::fs::remove_dir_all(&partial).with_context(|| format!("removing {}", partial.display()))?;
    }
    let options = SynthOptions {
        sessions: VISITS,
        images_per_session: n,
        seed: SEED,
        change: ChangeGrade::Strong,
        ..SynthOptions::default()
    };
    println!("== survey {VISITS} x {n} (strong change, seed {SEED})");
    crate::commands::synth::write_survey(&options, &partial, 30)?;
    std::fs::rename(&partial, &reef)
        .with_context(|| format!("renaming {} to {}", partial.display(), reef.display()))?;
    Ok(reef)
}

/// The learned pairs a strategy sends at `n` images a visit (`vpr`: at most
/// `top_k` candidates for each image of a later visit).
fn learned_pairs(strategy: CrossStrategy, n: usize, top_k: usize) -> usize {
    let images = VISITS * n;
    match strategy {
        CrossStrategy::None | CrossStrategy::Sift => 0,
        CrossStrategy::LearnedAll => images * (images - 1) / 2,
        CrossStrategy::LearnedCross => n * n * VISITS * (VISITS - 1) / 2,
        CrossStrategy::Vpr => (VISITS - 1) * n * top_k.min(n * VISITS),
    }
}

/// Learned extractions of every strategy that matches learned features:
/// the first visit at roll 0, every later one at the four rolls.
fn extractions(n: usize) -> usize {
    n + (VISITS - 1) * n * Roll::ALL.len()
}

/// A random (seeded) sample of a survey's pairs, each matched once by the
/// learned matcher at roll 0 (one match and its verification: what a pair
/// whose roll is predicted costs; the searched pairs cost more, so an
/// estimate from it is a lower bound).
struct Sample {
    images: Vec<PathBuf>,
    n: usize,
    count: usize,
    learned: revisit_pipeline::learned::Learned,
    _runtime: revisit_onnx::Runtime,
    features: BTreeMap<usize, revisit_core::LearnedFeatures>,
    extraction_secs: f64,
    secs: BTreeMap<&'static str, f64>,
}

impl Sample {
    fn open(args: &Args, dataset: &Path) -> Result<Sample> {
        let mut images = Vec::new();
        for session in super::session_names(dataset)? {
            images.extend(session_images(&dataset.join("sessions").join(&session))?);
        }
        ensure!(images.len() % VISITS == 0, "{}: not {VISITS} visits of equal size", dataset.display());
        let (runtime, learned) = args.tools.open(revisit_pipeline::learned::LearnedMethod::default())?;
        Ok(Sample {
            n: images.len() / VISITS,
            images,
            count: args.sample_pairs,
            learned,
            _runtime: runtime,
            features: BTreeMap::new(),
            extraction_secs: 0.0,
            secs: BTreeMap::new(),
        })
    }

    /// The sampled pairs of `strategy` (image indices, visit-major).
    fn pairs(&self, strategy: CrossStrategy) -> Vec<(usize, usize)> {
        let visit = |i: usize| i / self.n;
        let mut all: Vec<(usize, usize)> = (0..self.images.len())
            .flat_map(|i| (i + 1..self.images.len()).map(move |j| (i, j)))
            .filter(|&(i, j)| strategy == CrossStrategy::LearnedAll || visit(i) != visit(j))
            .collect();
        all.sort_by_key(|&(i, j)| splitmix64(((i as u64) << 32) ^ j as u64 ^ SEED));
        all.truncate(self.count);
        all
    }

    fn features(&mut self, index: usize) -> Result<&revisit_core::LearnedFeatures> {
        if !self.features.contains_key(&index) {
            let path = &self.images[index];
            let image = image::open(path).with_context(|| path.display().to_string())?.to_rgb8();
            let start = Instant::now();
            let features = self.learned.extract(&image, Roll::R0)?;
            self.extraction_secs += start.elapsed().as_secs_f64();
            self.features.insert(index, features);
        }
        Ok(&self.features[&index])
    }

    /// Mean seconds of one learned match (and its verification) over the sample.
    fn secs_per_pair(&mut self, strategy: CrossStrategy) -> Result<f64> {
        if let Some(secs) = self.secs.get(strategy.name()) {
            return Ok(*secs);
        }
        let pairs = self.pairs(strategy);
        // Every image extracted first: the extractor's threads would otherwise still be
        // spinning while a match is timed.
        for &(i, j) in &pairs {
            self.features(i)?;
            self.features(j)?;
        }
        let options = CrossOptions::default();
        // ONNX Runtime plans its kernels on the first call: one match untimed.
        if let Some(&(i, j)) = pairs.first() {
            let (a, b) = (self.features(i)?.clone(), self.features(j)?.clone());
            self.learned.match_rolls(&a, &[(Roll::R0, b)], (RollSearch::Off, None), &options)?;
        }
        let mut total = 0.0;
        for &(i, j) in &pairs {
            let (a, b) = (self.features(i)?.clone(), self.features(j)?.clone());
            let start = Instant::now();
            self.learned.match_rolls(&a, &[(Roll::R0, b)], (RollSearch::Off, None), &options)?;
            total += start.elapsed().as_secs_f64();
        }
        let secs = total / pairs.len().max(1) as f64;
        self.secs.insert(strategy.name(), secs);
        Ok(secs)
    }

    /// Mean seconds of one learned extraction over the images sampled (the
    /// first included: it also plans ONNX Runtime's kernels, a small share).
    fn secs_per_extraction(&mut self) -> Result<f64> {
        if self.features.is_empty() {
            self.features(0)?;
        }
        Ok(self.extraction_secs / self.features.len() as f64)
    }
}

/// A 64-bit mix (SplitMix64's finaliser): the sample's order.
fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

fn measured_row(n: usize, f: &StrategyFigures, sample: Option<(usize, f64)>) -> Row {
    Row {
        images_per_visit: n,
        images: VISITS * n,
        strategy: f.strategy.clone(),
        estimated: false,
        matching_secs: f.matching_secs,
        learned_features_secs: f.learned_features_secs,
        pairs: f.pairs_matched,
        cross_pairs_verified: Some(f.cross_pairs_verified),
        sessions_in_chosen_model: Some(f.sessions_in_chosen_model),
        median_cross_error_px: f.median_cross_error_px,
        sampled_pairs: sample.map_or(0, |s| s.0),
        secs_per_sampled_pair: sample.map(|s| s.1),
    }
}

fn print_row(r: &Row) {
    let or_dash = |v: Option<String>| v.unwrap_or_else(|| "-".to_owned());
    println!(
        "{:<14} {:>7} {:>10} {:>12.1} {:>12.1} {:>9} {:>9} {:>10} {:>10}",
        r.strategy,
        r.images,
        if r.estimated { "estimated" } else { "measured" },
        r.matching_secs,
        r.learned_features_secs,
        r.pairs,
        or_dash(r.cross_pairs_verified.map(|v| v.to_string())),
        or_dash(r.sessions_in_chosen_model.map(|v| format!("{v}/{VISITS}"))),
        or_dash(r.median_cross_error_px.map(|v| format!("{v:.2}"))),
    );
}

fn print_summary(study: &Study) {
    println!(
        "{:<14} {:>7} {:>10} {:>12} {:>12} {:>9} {:>9} {:>10} {:>10}",
        "strategy", "images", "", "match s", "features s", "pairs", "verified", "one model", "median px"
    );
    for row in &study.rows {
        print_row(row);
    }
    let mut sizes: Vec<usize> = study.rows.iter().map(|r| r.images_per_visit).collect();
    sizes.dedup();
    for n in sizes {
        let secs = |name: &str| {
            study.rows.iter().find(|r| r.images_per_visit == n && r.strategy == name).map(|r| r.matching_secs)
        };
        if let (Some(vpr), Some(all)) = (secs("vpr"), secs("learned-all")) {
            println!(
                "{VISITS} x {n}: vpr / learned-all matching time {:.1}% (goal <= 10% at 3 x 128; published 4.4% at 2.5k images)",
                100.0 * vpr / all.max(1e-9)
            );
        }
    }
    println!("estimated: the strategy's learned pairs x the mean time of one match over a random sample of them");
}

/// `scaling.json` and `scaling.png` in `work`.
fn write(work: &Path, study: &Study) -> Result<()> {
    super::write_json(Some(&work.join("scaling.json")), study)?;
    let colors =
        [Rgb([31, 119, 180]), Rgb([255, 127, 14]), Rgb([44, 160, 44]), Rgb([214, 39, 40]), Rgb([148, 103, 189])];
    let mut names: Vec<&str> = study.rows.iter().map(|r| r.strategy.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    let series: Vec<Series> = names
        .iter()
        .enumerate()
        .map(|(k, name)| Series {
            name,
            color: colors[k % colors.len()],
            points: study
                .rows
                .iter()
                .filter(|r| r.strategy == *name)
                .map(|r| (r.images as f64, r.matching_secs, r.estimated))
                .collect(),
        })
        .collect();
    let plot: RgbImage =
        log_log(&series, "matching time against survey size (3 visits, strong change)", "images", "seconds", 900, 600);
    let path = work.join("scaling.png");
    plot.save(&path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_sent_by_each_strategy() {
        assert_eq!(learned_pairs(CrossStrategy::LearnedAll, 16, 5), 48 * 47 / 2);
        assert_eq!(learned_pairs(CrossStrategy::LearnedCross, 16, 5), 3 * 16 * 16);
        assert_eq!(learned_pairs(CrossStrategy::Vpr, 16, 5), 2 * 16 * 5);
        assert_eq!(learned_pairs(CrossStrategy::Sift, 16, 5), 0);
        assert_eq!(extractions(16), 16 + 2 * 16 * 4);
    }
}
