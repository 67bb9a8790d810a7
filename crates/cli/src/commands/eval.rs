//! `revisit eval`: the published cross-visit reprojection protocol, and pose
//! errors when ground truth is at hand.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use revisit_core::Reconstruction;
use revisit_eval::{
    histogram, parse_points_csv, parse_truth_poses_csv, score, score_truth, session_of, Alignment, HistogramOptions,
    MalformedRow, ScoreOptions, Scores, SkipReason, Summary, TruthOptions, TruthScores,
};
use serde::Serialize;

#[derive(clap::Args)]
pub struct Args {
    /// A COLMAP model folder (cameras/images/points3D as .bin or .txt) or a
    /// folder of numbered sub-models (model/0, model/1, ...). Repeat for
    /// separately built models that share one frame (post-hoc alignment).
    #[arg(long = "model", required = true, value_name = "DIR")]
    models: Vec<PathBuf>,
    /// Click files: img0,img1,uv_clicked,uv_groundtruth (JSON lists of [u, v]).
    #[arg(long, required = true, num_args = 1.., value_name = "CSV")]
    points: Vec<PathBuf>,
    /// Ground truth folder holding poses.csv (session,image,qw,qx,qy,qz,tx,ty,tz,
    /// cam_from_world), or the poses.csv file itself.
    #[arg(long, value_name = "DIR")]
    truth: Option<PathBuf>,
    /// How several models are aligned to the truth: one similarity for all
    /// (they should share a frame) or one per model.
    #[arg(long, value_enum, default_value_t = AlignArg::Union)]
    align: AlignArg,
    /// Write every figure (and every click) as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write an error histogram PNG per session pair, and one over all.
    #[arg(long, value_name = "DIR")]
    plots: Option<PathBuf>,
    /// A click takes the 3D point of the nearest triangulated keypoint within
    /// this many pixels.
    #[arg(long, default_value_t = 3.0, value_name = "R")]
    radius_px: f64,
    /// Take the point on the clicked pixel's ray at the depth of that nearest
    /// 3D point, so the keypoint-to-click offset does not count as error
    /// (for exact synthetic clicks; the published rule is without it).
    #[arg(long)]
    at_click_depth: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum AlignArg {
    Union,
    Each,
}

/// The JSON report: the scores' keys at top level, then the inputs.
#[derive(Serialize)]
struct Report<'a> {
    #[serde(flatten)]
    scores: &'a Scores,
    malformed: &'a [MalformedRow],
    model_paths: Vec<String>,
    points_files: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    truth: Option<&'a TruthScores>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let options =
        ScoreOptions { radius_px: args.radius_px, at_click_depth: args.at_click_depth, ..ScoreOptions::default() };
    options.check().context("--radius-px")?;

    let mut model_paths = Vec::new();
    let mut models: Vec<Reconstruction> = Vec::new();
    for dir in &args.models {
        let found = revisit_colmap::read_models(dir).with_context(|| format!("--model {}", dir.display()))?;
        for (path, model) in found {
            tracing::info!("model {}: {} images, {} points", path.display(), model.images.len(), model.points3d.len());
            model_paths.push(path);
            models.push(model);
        }
    }

    let mut pairs = Vec::new();
    let mut malformed = Vec::new();
    for path in &args.points {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading --points {}", path.display()))?;
        let parsed = parse_points_csv(&text, &path.display().to_string())?;
        pairs.extend(parsed.pairs);
        malformed.extend(parsed.malformed);
    }

    let mut scores = score(&models, &pairs, &options);
    scores.malformed_rows = malformed.len();

    let truth = match &args.truth {
        Some(path) => {
            let poses_path = if path.is_dir() { path.join("poses.csv") } else { path.clone() };
            let text = std::fs::read_to_string(&poses_path)
                .with_context(|| format!("reading --truth {}", poses_path.display()))?;
            let poses = parse_truth_poses_csv(&text, &poses_path.display().to_string())?;
            let alignment = match args.align {
                AlignArg::Union => Alignment::Union,
                AlignArg::Each => Alignment::EachModel,
            };
            Some(score_truth(&models, &poses, &TruthOptions { alignment }))
        }
        None => None,
    };

    print!("{}", table(&scores, &models, &model_paths, truth.as_ref()));

    if let Some(path) = &args.json {
        let report = Report {
            scores: &scores,
            malformed: &malformed,
            model_paths: model_paths.iter().map(|p| p.display().to_string()).collect(),
            points_files: args.points.iter().map(|p| p.display().to_string()).collect(),
            truth: truth.as_ref(),
        };
        let json = serde_json::to_string_pretty(&report).context("encoding the JSON report")?;
        write_file(path, json.as_bytes()).with_context(|| format!("writing --json {}", path.display()))?;
    }
    if let Some(dir) = &args.plots {
        write_plots(dir, &scores).with_context(|| format!("writing --plots {}", dir.display()))?;
    }
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    std::fs::write(path, bytes)
}

fn write_plots(dir: &Path, scores: &Scores) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let options = HistogramOptions::default();
    let mut plots: Vec<(String, &Summary)> = scores.pairs.iter().map(|(key, summary)| (key.clone(), summary)).collect();
    plots.push(("all".to_owned(), &scores.overall));
    for (key, summary) in plots {
        let file_key: String =
            key.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect();
        let path = dir.join(format!("errors_{file_key}.png"));
        histogram(&summary.errors_px, &format!("{key}  reprojection error"), &options)
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        tracing::info!("wrote {}", path.display());
    }
    Ok(())
}

fn fmt_opt(value: Option<f64>, decimals: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.decimals$}"))
}

/// The human-readable report on stdout.
fn table(scores: &Scores, models: &[Reconstruction], paths: &[PathBuf], truth: Option<&TruthScores>) -> String {
    let mut out = String::new();
    for (path, model) in paths.iter().zip(models) {
        let sessions: BTreeSet<&str> = model.images.values().map(|i| session_of(&i.name)).collect();
        let sessions: Vec<&str> = sessions.into_iter().collect();
        let _ = writeln!(
            out,
            "model {}: {} images, {} points, sessions {}",
            path.display(),
            model.images.len(),
            model.points3d.len(),
            sessions.join(", ")
        );
    }
    let _ = writeln!(
        out,
        "one model holds every session: {}   radius {} px   malformed rows skipped: {}",
        if scores.one_model { "yes" } else { "no" },
        scores.radius_px,
        scores.malformed_rows
    );
    let _ = writeln!(out);
    let _ =
        writeln!(out, "{:<24} {:>7} {:>7} {:>10} {:>10}", "session pair", "scored", "skipped", "median px", "mean px");
    let row = |out: &mut String, name: &str, s: &Summary| {
        let _ = writeln!(
            out,
            "{:<24} {:>7} {:>7} {:>10} {:>10}",
            name,
            s.scored,
            s.skipped,
            fmt_opt(s.median_px, 2),
            fmt_opt(s.mean_px, 2)
        );
    };
    for (key, summary) in &scores.pairs {
        row(&mut out, key, summary);
    }
    row(&mut out, "overall", &scores.overall);
    if scores.overall.skipped > 0 {
        let reasons: Vec<String> = SkipReason::ALL
            .iter()
            .filter_map(|r| scores.overall.skipped_by_reason.get(r).map(|n| format!("{} {n}", r.as_str())))
            .collect();
        let _ = writeln!(out, "skipped clicks: {}", reasons.join(", "));
    }
    if let Some(t) = truth {
        let alignment = match t.alignment {
            Alignment::Union => "one similarity for all models",
            Alignment::EachModel => "one similarity per model",
        };
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "truth: {} images, scene size {:.2} m, aligned with {alignment}",
            t.images_in_truth, t.scene_size_m
        );
        let _ = writeln!(
            out,
            "{:<16} {:>7} {:>10} {:>6} {:>14} {:>12} {:>12} {:>11}",
            "session", "truth", "registered", "rate", "centre med m", "centre rel", "rot med deg", "scale rel"
        );
        for (session, s) in &t.sessions {
            let _ = writeln!(
                out,
                "{:<16} {:>7} {:>10} {:>6.3} {:>14} {:>12} {:>12} {:>11}",
                session,
                s.images_in_truth,
                s.registered_in_largest,
                s.registration_rate,
                fmt_opt(s.pose.centre_median_m, 4),
                fmt_opt(s.pose.centre_median_rel, 5),
                fmt_opt(s.pose.rotation_median_deg, 3),
                fmt_opt(s.scale_rel_error, 4)
            );
        }
        let o = &t.overall;
        let registered: usize = t.sessions.values().map(|s| s.registered_in_largest).sum();
        let _ = writeln!(
            out,
            "{:<16} {:>7} {:>10} {:>6} {:>14} {:>12} {:>12}",
            "overall",
            t.images_in_truth,
            registered,
            "",
            fmt_opt(o.centre_median_m, 4),
            fmt_opt(o.centre_median_rel, 5),
            fmt_opt(o.rotation_median_deg, 3)
        );
        let _ = writeln!(
            out,
            "centre mean {} m ({} of scene), rotation mean {} deg",
            fmt_opt(o.centre_mean_m, 4),
            fmt_opt(o.centre_mean_rel, 5),
            fmt_opt(o.rotation_mean_deg, 3)
        );
        let _ = writeln!(out, "scale rel: a session's scale against its model's, minus 1 (its cameras fitted alone)");
        if t.similarities.iter().any(Option::is_none) {
            let _ =
                writeln!(out, "warning: some models could not be aligned (fewer than 3 truth images, or degenerate)");
        }
    }
    out
}
