//! `revisit change`: where the reef changed between two visits of one joint model.

use std::path::{Path, PathBuf};

use anyhow::Context;
use revisit_change::truth::{parse_changes_csv, score, ChangeScores};
use revisit_change::{
    check_visits, detect, encode_ply, map_png, regions_csv, sparse_surfaces, ChangeMap, ChangeOptions, Surfaces,
};
use revisit_colmap::{DenseOptions, DenseVisit};
use revisit_core::Reconstruction;
use revisit_eval::{parse_truth_poses_csv, score_truth, Alignment, TruthOptions};
use revisit_pipeline::locate::Tools;
use revisit_pipeline::report::{ModelFrame, Report};
use revisit_pipeline::surfaces::{dense_surfaces, Surface};
use serde::Serialize;

/// `revisit change`'s arguments (the command's text is on `Command::Change`).
#[derive(clap::Args)]
pub struct Args {
    /// A `reconstruct` work folder (its chosen model, and its report for the unit) or a COLMAP
    /// model folder (the largest model in it).
    #[arg(long, value_name = "DIR")]
    model: PathBuf,
    /// The earlier visit (session name).
    #[arg(long, value_name = "A")]
    from: String,
    /// The later visit.
    #[arg(long, value_name = "B")]
    to: String,
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Score the map against a synthetic survey's truth folder (poses.csv and
    /// changes_A-B.csv, as `revisit synth` writes them): precision and recall of the regions
    /// on moved and removed corals, and the growth measured on grown ones.
    #[arg(long, value_name = "DIR")]
    truth: Option<PathBuf>,
    /// Spacing of the core points, model units [default: 2.5% of the altitude with dense
    /// surfaces, 4% with sparse ones].
    #[arg(long, value_name = "SIZE")]
    cell: Option<f64>,
    /// Radius of the measuring cylinder, model units [default: 4% of the altitude with dense
    /// surfaces (under the smallest colonies' reach), 8% with sparse ones].
    #[arg(long, value_name = "SIZE")]
    radius: Option<f64>,
    /// Radius of the neighbourhood a normal is fitted to, model units [default: 50% of the
    /// altitude].
    #[arg(long, value_name = "SIZE")]
    normal_radius: Option<f64>,
    /// Largest change measured (the cylinder's half length), model units [default: 50% of the
    /// altitude].
    #[arg(long, value_name = "SIZE")]
    max_depth: Option<f64>,
    /// Fewest points of each visit in a cylinder for a measurement.
    #[arg(long, default_value_t = 4, value_name = "N")]
    min_points: usize,
    /// Fewest points of each visit within half the cylinder's radius of its axis (a cylinder
    /// one visit sees only at its rim, as the sand beyond a coral table's plate, is not
    /// measured) [default: 3 with dense surfaces, 0 with sparse ones, too thin for it].
    #[arg(long, value_name = "N")]
    min_inner_points: Option<usize>,
    /// Largest share of the higher visit's points in a cylinder at the lower visit's level for
    /// a change to be measured (where the earlier visit also saw, through a branching coral's
    /// gaps, the sand the later one shows, the later one may just not have resolved the
    /// branches).
    #[arg(long, default_value_t = 0.3, value_name = "F")]
    max_seen_through: f64,
    /// Fewest cells of a reported region.
    #[arg(long, default_value_t = 3, value_name = "N")]
    min_cells: usize,
    /// A region of nine cells is reported when its mean change is at least this many times its
    /// cells' mean LoD95, one of n cells when it is this times sqrt(9 / n) times it (a guard
    /// against chance clusters: one cell in twenty passes its LoD95 by chance; the mean over
    /// more cells is surer).
    #[arg(long, default_value_t = 2.5, value_name = "F")]
    region_lod_factor: f64,
    /// The same factor for a region on level ground, asked of its median cell: where the lower
    /// visit's surface over the region and two cells around it rises less than half the
    /// region's mean change, the change is a structure that came or left on open ground, not the
    /// rim of one both visits saw (where dense surfaces err); small colonies need this less
    /// strict test to be found.
    #[arg(long, default_value_t = 1.25, value_name = "F")]
    level_lod_factor: f64,
    /// Fewest images observing a point for it to count, with `--surface sparse` (a point seen
    /// twice has the least certain depth).
    #[arg(long, default_value_t = 3, value_name = "N")]
    min_track: usize,
    /// Where each visit's surface comes from.
    #[arg(long, value_enum, default_value_t = SurfaceArg::Dense)]
    surface: SurfaceArg,
    /// The folder the model's image names (session/file) are relative to, for dense surfaces
    /// [default: the work folder's images/].
    #[arg(long, value_name = "DIR")]
    images: Option<PathBuf>,
    /// Dense surfaces: one point per block of this many pixels a side.
    #[arg(long, default_value_t = 4, value_name = "PX")]
    dense_step: u32,
    /// Python with pycolmap and OpenCV, for dense surfaces (default: $REVISIT_PYTHON, else
    /// .venv/bin/python).
    #[arg(long, value_name = "PATH")]
    python: Option<PathBuf>,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
enum SurfaceArg {
    /// Each visit's surface made densely from its own images at the model's poses.
    Dense,
    /// The model's points that only the visit observes (fast; thin on smooth structure, such
    /// as a coral table, that shows little texture).
    Sparse,
}

/// change_A-B.json.
#[derive(Serialize)]
struct Summary<'a> {
    model: String,
    unit: &'a str,
    options: &'a ChangeOptions,
    scales: &'a revisit_change::Scales,
    frame: &'a revisit_change::MapFrame,
    grid: &'a revisit_change::Grid,
    surface: SurfaceArg,
    /// How each dense surface was made (empty for sparse).
    dense: &'a [DenseVisit],
    points_from: usize,
    points_to: usize,
    points_shared: usize,
    cells_measured: usize,
    cells_significant: usize,
    registration: f64,
    median_change: f64,
    regions: &'a [revisit_change::Region],
    #[serde(skip_serializing_if = "Option::is_none")]
    truth: Option<&'a ChangeScores>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let defaults = match args.surface {
        SurfaceArg::Dense => ChangeOptions::default(),
        SurfaceArg::Sparse => ChangeOptions::sparse(),
    };
    let options = ChangeOptions {
        cell: args.cell,
        radius: args.radius,
        normal_radius: args.normal_radius,
        max_depth: args.max_depth,
        min_points: args.min_points,
        min_inner_points: args.min_inner_points.unwrap_or(defaults.min_inner_points),
        max_seen_through: args.max_seen_through,
        min_cells: args.min_cells,
        region_lod_factor: args.region_lod_factor,
        level_lod_factor: args.level_lod_factor,
        min_track: args.min_track,
        ..defaults
    };
    options.check()?;
    let (path, model, frame) = read_model(&args.model).with_context(|| format!("--model {}", args.model.display()))?;
    let unit = match frame {
        ModelFrame::Navigation => "m",
        ModelFrame::Arbitrary => "units",
    };
    let (surfaces, dense) = match args.surface {
        SurfaceArg::Sparse => (sparse_surfaces(&model, &args.from, &args.to, &options)?, Vec::new()),
        SurfaceArg::Dense => made_densely(&args, &path, &model)?,
    };
    let map = detect(&model, &args.from, &args.to, &surfaces, &options)?;
    let truth = match &args.truth {
        Some(dir) => Some(score_on_truth(&map, &model, dir).with_context(|| format!("--truth {}", dir.display()))?),
        None => None,
    };

    std::fs::create_dir_all(&args.out).with_context(|| format!("creating --out {}", args.out.display()))?;
    let stem = format!("{}-{}", file_safe(&args.from), file_safe(&args.to));
    let write = |name: String, bytes: &[u8]| {
        let path = args.out.join(name);
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))
    };
    write(format!("change_{stem}.ply"), &encode_ply(&map))?;
    write(format!("regions_{stem}.csv"), regions_csv(&map)?.as_bytes())?;
    let png = args.out.join(format!("change_{stem}.png"));
    map_png(&map, unit).save(&png).with_context(|| format!("writing {}", png.display()))?;
    let summary = Summary {
        model: path.display().to_string(),
        unit,
        options: &options,
        surface: args.surface,
        dense: &dense,
        scales: &map.scales,
        frame: &map.frame,
        grid: &map.grid,
        points_from: map.points_from,
        points_to: map.points_to,
        points_shared: map.points_shared,
        cells_measured: map.cells.len(),
        cells_significant: map.significant_cells(),
        registration: map.registration,
        median_change: map.median_change,
        regions: &map.regions,
        truth: truth.as_ref(),
    };
    write(format!("change_{stem}.json"), (serde_json::to_string_pretty(&summary)? + "\n").as_bytes())?;
    print!("{}", table(&map, args.surface, unit, truth.as_ref()));
    println!(
        "wrote {}",
        args.out
            .join(format!("{{change_{stem}.ply,change_{stem}.png,regions_{stem}.csv,change_{stem}.json}}"))
            .display()
    );
    Ok(())
}

/// Each visit's dense surface, made from its images at the model's poses (or read from
/// OUT/dense when made before from the same poses).
fn made_densely(args: &Args, model_dir: &Path, model: &Reconstruction) -> anyhow::Result<(Surfaces, Vec<DenseVisit>)> {
    // The visits are checked first: a wrong name costs a line, not a dense run.
    check_visits(model, &args.from, &args.to)?;
    if args.dense_step == 0 {
        anyhow::bail!("--dense-step must be at least 1 pixel");
    }
    let images = match &args.images {
        Some(dir) => dir.clone(),
        None if args.model.join("report.json").is_file() => args.model.join("images"),
        None => anyhow::bail!("--images is needed for dense surfaces when --model is not a work folder"),
    };
    if !images.is_dir() {
        anyhow::bail!("--images {}: not a folder", images.display());
    }
    let python = Tools { python: args.python.clone(), ..Tools::default() }.python().context("--python")?;
    let options = DenseOptions { step_px: args.dense_step, ..DenseOptions::default() };
    let folder = args.out.join("dense");
    let cancel = crate::signals::cancel_on_signals()?;
    let visits = [args.from.as_str(), args.to.as_str()];
    println!("making the dense surfaces of {} and {} (a second or two an image) ...", args.from, args.to);
    let made = dense_surfaces(&python, (model_dir, model), &images, &visits, &folder, &options, &cancel)?;
    for Surface { made, reused, .. } in &made {
        println!(
            "dense surface of {}: {} points from {} of its {} images ({}, {})",
            made.visit,
            made.points,
            made.fused,
            made.images,
            if *reused { "made before" } else { "made" },
            revisit_colmap::dense::surface_path(&folder, &made.visit).display()
        );
    }
    let records = made.iter().map(|surface| surface.made.clone()).collect();
    let [from, to] = <[Surface; 2]>::try_from(made).map_err(|_| anyhow::anyhow!("two surfaces were asked for"))?;
    Ok((Surfaces { from: from.points, to: to.points, shared: 0 }, records))
}

/// The model to compare and its frame: a work folder's chosen model, or the largest model of
/// a COLMAP folder (frame unknown: arbitrary).
fn read_model(dir: &Path) -> anyhow::Result<(PathBuf, Reconstruction, ModelFrame)> {
    let report_path = dir.join("report.json");
    if report_path.is_file() {
        let report = Report::read(&report_path)?;
        let chosen =
            report.chosen_model.context("report.json names no model: the reconstruction registered nothing")?;
        // The report names it as the reconstruction saw it (relative to where it ran): the
        // work folder may have moved since, so find its tail (model/...) under `dir`.
        let chosen = std::iter::successors(Some(chosen.as_path()), |p| {
            let mut parts = p.components();
            parts.next().map(|_| parts.as_path()).filter(|rest| !rest.as_os_str().is_empty())
        })
        .map(|tail| dir.join(tail))
        .find(|candidate| candidate.is_dir())
        .with_context(|| format!("its chosen model {} is not in it", chosen.display()))?;
        let model = revisit_colmap::read_model(&chosen).with_context(|| format!("reading {}", chosen.display()))?;
        return Ok((chosen, model, report.mapping.frame));
    }
    let models = revisit_colmap::read_models(dir)?;
    let count = models.len();
    let (path, model) = models
        .into_iter()
        .max_by_key(|(_, model)| model.images.len())
        .context("no COLMAP model in it (cameras, images and points3D as .bin or .txt)")?;
    if count > 1 {
        tracing::info!("{count} models in {}: comparing the largest, {}", dir.display(), path.display());
    }
    Ok((path, model, ModelFrame::Arbitrary))
}

fn score_on_truth(map: &ChangeMap, model: &Reconstruction, dir: &Path) -> anyhow::Result<ChangeScores> {
    let poses_path = dir.join("poses.csv");
    let text = std::fs::read_to_string(&poses_path).with_context(|| format!("reading {}", poses_path.display()))?;
    let poses = parse_truth_poses_csv(&text, &poses_path.display().to_string())?;
    let aligned = score_truth(std::slice::from_ref(model), &poses, &TruthOptions { alignment: Alignment::Union });
    let truth_from_model = aligned
        .similarities
        .first()
        .copied()
        .flatten()
        .context("the model's cameras could not be aligned to the truth's (fewer than 3 images in common)")?;
    let changes_path = dir.join(format!("changes_{}-{}.csv", map.from, map.to));
    let text = std::fs::read_to_string(&changes_path).with_context(|| format!("reading {}", changes_path.display()))?;
    let changes = parse_changes_csv(&text, &changes_path.display().to_string())?;
    Ok(score(map, &changes, &truth_from_model))
}

fn file_safe(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect()
}

fn table(map: &ChangeMap, surface: SurfaceArg, unit: &str, truth: Option<&ChangeScores>) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let s = &map.scales;
    let _ = match surface {
        SurfaceArg::Dense => writeln!(
            out,
            "change from {} to {}: dense surfaces of {} and {} points",
            map.from, map.to, map.points_from, map.points_to
        ),
        SurfaceArg::Sparse => writeln!(
            out,
            "change from {} to {}: points seen by {} only {}, by {} only {}, by both {} (not compared)",
            map.from, map.to, map.from, map.points_from, map.to, map.points_to, map.points_shared
        ),
    };
    let _ = writeln!(
        out,
        "altitude {:.3} {unit}; cell {:.3}, cylinder radius {:.3}, normal radius {:.3}, max depth {:.3}",
        s.altitude, s.cell, s.radius, s.normal_radius, s.max_depth
    );
    let _ = writeln!(
        out,
        "{} cells measured, {} beyond their LoD95; registration term {:.4} {unit}, median change {:+.4} {unit}",
        map.cells.len(),
        map.significant_cells(),
        map.registration,
        map.median_change
    );
    let _ = writeln!(out, "{} regions{}", map.regions.len(), if map.regions.is_empty() { "" } else { ":" });
    if !map.regions.is_empty() {
        let _ = writeln!(
            out,
            "{:>4} {:<8} {:>6} {:>10} {:>12} {:>12} {:>10}",
            "id", "sign", "cells", "area", "mean change", "peak change", "LoD95"
        );
        for r in &map.regions {
            let _ = writeln!(
                out,
                "{:>4} {:<8} {:>6} {:>10.4} {:>+12.4} {:>+12.4} {:>10.4}",
                r.id,
                r.sign.name(),
                r.cells.len(),
                r.area,
                r.mean_change,
                r.peak_change,
                r.mean_lod95
            );
        }
    }
    if let Some(t) = truth {
        let pct = |v: Option<f64>| v.map_or_else(|| "-".to_owned(), |v| format!("{:.0}%", 100.0 * v));
        let _ = writeln!(
            out,
            "against the truth: precision {} ({} of {} regions), recall {} ({} of {} moved or removed corals measured)",
            pct(t.precision),
            t.true_regions,
            t.regions,
            pct(t.recall),
            t.found,
            t.targets
        );
        let detectable = t.grown.iter().filter(|g| g.detectable).count();
        let _ = writeln!(
            out,
            "grown corals measured: {} ({} above the LoD95), median |growth error| {}",
            t.grown.len(),
            detectable,
            pct(t.growth_median_abs_error)
        );
    }
    out
}
