//! `revisit reconstruct`: the command line over `revisit_pipeline::Workspace`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use revisit_core::PairKind;
use revisit_pipeline::bags::{self, IngestOptions};
use revisit_pipeline::ingest::{self, SessionSpec};
use revisit_pipeline::keyframes::{self, KeyframeOptions};
use revisit_pipeline::navigation::read_navigation_csv;
use revisit_pipeline::report::ModelFrame;
use revisit_pipeline::{Report, Workspace};

use crate::commands::models::ToolArgs;
use crate::commands::options::OptionArgs;
use crate::progress::Bars;

/// Reconstruct one or more sessions (visits of one site) jointly: SIFT within
/// visits, learned matching across them, and ONE COLMAP mapping run.
///
/// Outputs in WORK: database.db (the store, a COLMAP database), model/ (COLMAP
/// binary model; model/1, model/2, ... largest first if COLMAP made several),
/// points.ply, poses.csv (cam_from_world of the chosen model's images) and
/// report.json. Re-running the same command resumes: finished features, pairs
/// and an up-to-date model are reused, never recomputed. Ctrl-C (or SIGTERM)
/// stops after the image or pair in flight; running again resumes.
#[derive(clap::Args)]
pub struct Args {
    /// A session (one visit) as NAME=DIR. DIR holds its images (.png, .jpg),
    /// whose sorted file names give the time order: directly (one camera per
    /// image size) or in one sub-folder per camera (e.g. left/, right/).
    /// Repeat for every visit; a new visit comes after those already stored.
    #[arg(long = "session", value_name = "NAME=DIR", required_unless_present = "bags")]
    sessions: Vec<SessionSpec>,
    /// A visit recorded as a ROS 2 bag, as NAME=BAG (a bag folder with metadata.yaml, or one .mcap
    /// or .db3 file). Its keyframes (see --keyframe-overlap) are written to WORK/frames/NAME/ and
    /// reconstructed like a folder. Repeat for every visit; bags come after --session folders.
    #[arg(long = "bag", value_name = "NAME=BAG")]
    bags: Vec<SessionSpec>,
    #[command(flatten)]
    bag_options: BagArgs,
    /// A visit's navigation as NAME=CSV: per image, the camera's position from the vehicle (a
    /// DVL-aided INS with a position fix, as `revisit synth` writes DIR/nav/NAME.csv). Columns,
    /// found by their header: image (the file within the visit), x, y, z (metres, in one
    /// Cartesian frame for every visit, e.g. ENU or NED) and optionally sigma_x, sigma_y, sigma_z
    /// (standard deviations, metres; 1 m when absent); other columns (attitude) are ignored:
    /// COLMAP's prior holds a position. Stored as COLMAP pose priors: mapping pulls each camera
    /// towards its position, weighted by its uncertainty, which fixes every visit's scale and
    /// placement, and the model comes out in the navigation frame. A visit without --nav joins
    /// through its images alone. Rows naming images the visit does not hold are skipped.
    #[arg(long = "nav", value_name = "NAME=CSV")]
    navigation: Vec<SessionSpec>,
    /// Work folder for the store and every output (created if missing).
    #[arg(long, value_name = "WORK")]
    out: PathBuf,
    #[command(flatten)]
    options: OptionArgs,
    #[command(flatten)]
    tools: ToolArgs,
}

/// How bags become visits.
#[derive(clap::Args)]
struct BagArgs {
    /// The image topic of every --bag (sensor_msgs/Image or CompressedImage); default: the bag's
    /// only image topic.
    #[arg(long)]
    topic: Option<String>,
    /// Split each --bag into visits where frames are more than SECONDS apart (named NAME-1, NAME-2, ...).
    #[arg(long, value_name = "SECONDS")]
    split_gap: Option<f64>,
    /// Keep a frame as a keyframe when its tracked overlap with the last keyframe (the fraction of
    /// the image still in view) falls below this.
    #[arg(long, value_name = "FRACTION", default_value_t = keyframes::DEFAULT_MIN_OVERLAP)]
    keyframe_overlap: f64,
    /// Also keep a frame SECONDS after the last keyframe.
    #[arg(long, value_name = "SECONDS")]
    keyframe_every: Option<f64>,
    /// Also keep a frame METRES (by nav_msgs/Odometry in the bag) from the last keyframe.
    #[arg(long, value_name = "METRES")]
    keyframe_distance: Option<f64>,
    /// Keep every frame (no keyframe selection).
    #[arg(long, conflicts_with_all = ["keyframe_every", "keyframe_distance"])]
    all_frames: bool,
    /// Each --bag's navigation topic (geometry_msgs/PoseWithCovarianceStamped or
    /// nav_msgs/Odometry; positions in metres, in one Cartesian frame for every visit, as a
    /// DVL-aided INS with a position fix gives them, not a visit's own odom frame). Each keyframe
    /// takes the position at its stamp (interpolated) and the deviations its covariance gives,
    /// written to WORK/frames/NAME.nav.csv and used as --nav NAME=that file; a --nav given for the
    /// visit is used instead.
    #[arg(long, value_name = "TOPIC")]
    nav_topic: Option<String>,
}

impl BagArgs {
    fn options(&self) -> IngestOptions {
        let keyframes = if self.all_frames {
            KeyframeOptions::ALL
        } else {
            KeyframeOptions {
                min_overlap: Some(self.keyframe_overlap),
                every_s: self.keyframe_every,
                distance_m: self.keyframe_distance,
            }
        };
        let (topic, navigation_topic) = (self.topic.clone(), self.nav_topic.clone());
        IngestOptions { topic, split_gap_s: self.split_gap, keyframes, navigation_topic }
    }
}

/// Runs a reconstruction with progress bars; `cancel` stops it between items.
fn reconstruct(args: &Args, cancel: &revisit_pipeline::Cancel) -> Result<Report> {
    let mut specs = args.sessions.clone();
    let mut navigation = args.navigation.clone();
    let frames = args.out.join("frames");
    for bag in &args.bags {
        ingest::check_specs(std::slice::from_ref(bag)).context("--bag")?;
        let ingested = bags::ingest(bag, &args.bag_options.options(), &frames, &Bars::default(), cancel)
            .with_context(|| format!("--bag {}", bag.name))?;
        for visit in &ingested.visits {
            tracing::info!("{}: {} of {} frames of {} kept", visit.name, visit.keyframes, visit.frames, ingested.topic);
        }
        if !ingested.skipped.is_empty() {
            tracing::warn!(
                "--bag {}: {} messages skipped, first: {}",
                bag.name,
                ingested.skipped.len(),
                ingested.skipped[0]
            );
        }
        specs.extend(ingested.sessions());
        if let Some(topic) = &args.bag_options.nav_topic {
            for visit in ingested.visits.iter().filter(|v| v.navigation.is_none()) {
                tracing::warn!("--nav-topic {topic}: no position near any keyframe of {}", visit.name);
            }
            let given = |visit: &SessionSpec| args.navigation.iter().any(|n| n.name == visit.name);
            navigation.extend(ingested.navigation().into_iter().filter(|visit| !given(visit)));
        }
    }
    ingest::check_specs(&specs).context("--session")?;
    let sessions = specs
        .iter()
        .map(|spec| ingest::scan_session(spec).with_context(|| format!("--session {}", spec.name)))
        .collect::<Result<Vec<_>>>()?;
    let mut workspace = Workspace::open(&args.out, args.options.options(), args.tools.tools())
        .with_context(|| format!("--out {}", args.out.display()))?;
    for session in sessions {
        let name = session.name.clone();
        workspace.add_session(session).with_context(|| format!("--session {name}"))?;
    }
    for nav in &navigation {
        let context = || format!("--nav {}={}", nav.name, nav.dir.display());
        let fixes = read_navigation_csv(&nav.dir, &nav.name).with_context(context)?;
        let count = workspace.add_navigation(&nav.name, &fixes).with_context(context)?;
        tracing::info!("{}: {count} images with a navigation prior", nav.name);
    }
    Ok(workspace.run(&Bars::default(), cancel)?)
}

pub fn run(args: Args) -> Result<()> {
    let cancel = crate::signals::cancel_on_signals()?;
    let report = reconstruct(&args, &cancel)?;
    print_summary(&report, &args.out);
    Ok(())
}

fn print_summary(report: &Report, work: &Path) {
    println!("{:<16} {:>6} {:>8} {:>11}  cameras", "session", "visit", "images", "registered");
    for (name, s) in &report.sessions {
        let cameras: Vec<&str> = s.cameras.keys().map(String::as_str).collect();
        println!("{name:<16} {:>6} {:>8} {:>11}  {}", s.visit, s.images, s.registered, cameras.join(", "));
    }
    for kind in [PairKind::Intra, PairKind::Cross] {
        if let Some(p) = report.pairs.get(&kind) {
            println!("{kind} pairs: {} tried, {} verified", p.tried, p.verified);
        }
    }
    if !report.rolls.is_empty() {
        println!("cross pairs by roll: {:?}", report.rolls);
    }
    if let Some((m, per_pair)) = report.cross.learned_matching.and_then(|m| Some((m, m.runs_per_pair()?))) {
        let mut again = match m.rematched {
            0 => String::new(),
            n => format!(", {n} searched pairs matched again at their visits' settled roll"),
        };
        if m.unlinked > 0 {
            again += &format!(
                ", {} pairs left unmatched (their visits showed no common heading within the search budget)",
                m.unlinked
            );
        }
        println!(
            "learned matching: {} pairs matched, {} matcher runs ({per_pair:.2} a pair){again}",
            m.done, m.matcher_runs
        );
    }
    if let Some(c) = report.cross.consistency.filter(|c| c.confident + c.weak > 0) {
        println!(
            "confident cross pairs: {} (mapped on their matches above --confident-probability); weak pairs set aside: \
             {} (between visits with at least --confident-pairs confident ones)",
            c.confident, c.weak
        );
    }
    if let Some(c) = report.cross.consistency.filter(|c| c.inconsistent() > 0) {
        let fate = match c.set_aside {
            0 => "mapped all the same (--set-aside-inconsistent sets them aside)".to_owned(),
            n if n == c.inconsistent() => "set aside, not mapped".to_owned(),
            n => format!(
                "{n} set aside (unlinked, weak, or off the navigation when change-aware), the others mapped all the same"
            ),
        };
        println!(
            "inconsistent cross pairs: {} at odds with their roll, {} with their visits' other pairs, {} with the \
             navigation, {} with their loops, {} between visits that agree on no heading (weak, or at odds with a rule; of {} \
             checked; each is logged): {fate}",
            c.roll_disagrees, c.off_consensus, c.off_navigation, c.off_loops, c.unlinked, c.checked
        );
    }
    println!("models: {} (sizes {:?})", report.models, report.model_sizes);
    if let Some(change) = &report.mapping.change_aware {
        let fates: Vec<String> =
            change.pairs.iter().map(|(pair, fate)| format!("{pair} {} of {}", fate.kept, fate.matches)).collect();
        println!(
            "change-aware: visits placed {}; cross-visit matches kept: {}",
            change.placed.join(", "),
            fates.join(", ")
        );
        if !change.unplaced.is_empty() {
            println!(
                "warning: change-aware mapping could not place {} (mapped alone too small, or too few cross-visit \
                 matches agree): joined as COLMAP's incremental mapper let them",
                change.unplaced.join(", ")
            );
        }
    }
    if report.mapping.frame == ModelFrame::Navigation {
        let rms = report.mapping.navigation_rms_m.map_or("-".to_owned(), |m| format!("{m:.3} m"));
        println!("frame:  the navigation's (metres); cameras sit {rms} RMS from their navigation");
    }
    for (visit, offset) in report.mapping.navigation_offsets.iter().filter(|(_, o)| o.disagrees()) {
        println!(
            "warning: the images place visit {visit} {:.2} m from its navigation ({:.1} standard deviations of its \
             fix): its link to the other visits or its navigation is suspect",
            offset.offset_m,
            offset.offset_sigmas.unwrap_or_default()
        );
    }
    for (visits, p) in report.mapping.placement.iter().filter(|(_, p)| p.is_suspect()) {
        println!(
            "warning: visits {visits} sit at odds with {} of the {} cross-visit pairs whose loops confirm them \
             (their matches {:.0} px apart in the model, median): their placement is suspect",
            p.measured - p.agreeing,
            p.measured,
            p.median_px
        );
    }
    for (visits, p) in report.mapping.placement.iter().filter(|(_, p)| p.is_unchecked()) {
        println!(
            "warning: visits {visits} are joined by {} cross-visit pairs, none of which their loops confirm: \
             nothing checks their placement (wrong pairs alone would join them the same way)",
            p.joining
        );
    }
    for name in &report.unlinked_sessions {
        println!(
            "warning: session {name} could not be linked to the others: fewer than half its images are in \
             the chosen model (the rest are kept as their own model if COLMAP made one)"
        );
    }
    if let Some(model) = &report.chosen_model {
        println!("model:  {}", model.display());
    }
    for file in ["database.db", "points.ply", "poses.csv", "report.json"] {
        let path = work.join(file);
        if path.exists() {
            println!("wrote:  {}", path.display());
        }
    }
}
