//! `revisit`: the command line over Revisit's stage libraries.
//!
//! Thin by design: each subcommand parses its arguments, calls the stage
//! libraries in order, shows progress and writes the artifacts. Errors are
//! reported once, here, as one line naming what is at fault.

mod commands;
mod progress;
mod signals;

use clap::{Parser, Subcommand};

/// Fuse camera surveys of one site, taken months or years apart, into one
/// coherent 3D reconstruction.
#[derive(Parser)]
#[command(name = "revisit", version, about, long_about = None)]
struct Cli {
    /// Log verbosity: -v for debug, -vv for trace (or set RUST_LOG).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Reconstruct one or more sessions (visits) jointly into one COLMAP model.
    Reconstruct(Box<commands::reconstruct::Args>),
    /// Render a synthetic multi-visit reef survey with exact ground truth.
    Synth(commands::synth::Args),
    /// Score a reconstruction with the published cross-visit reprojection protocol.
    Eval(commands::eval::Args),
    /// Map where the reef changed between two visits of one joint model (M3C2-style distances,
    /// each with its level of detection): a PLY, a top-down PNG and a CSV of changed regions.
    ///
    /// Visit B's surface against visit A's, M3C2-style. Each visit's surface is by default made
    /// densely from its own images at the model's poses (OpenCV's semi-global matching between
    /// each image and up to four of its visit's neighbours, kept where two agree; stored in OUT/dense
    /// and reused while the model stays the same), or with `--surface sparse` taken from the
    /// model's points only that visit observes. On a grid of core points over the site, the
    /// distance from A's surface to B's along A's normal, each with its 95% level of detection
    /// (LoD95, from the bootstrapped spread of each visit's median in the cylinder and the
    /// registration error between the visits, estimated from the change over the whole overlap:
    /// its median's size plus its robust spread); a cylinder one visit sees only at its rim, or
    /// where the higher visit also saw the lower one's level (through a branching coral), is not
    /// measured. Cells beyond their LoD95 are grouped into raised and lowered regions; a region
    /// of nine cells is kept when its mean change is at least 2.5 times its LoD95 (a smaller one
    /// needs more, a larger one less).
    ///
    /// Writes to OUT: change_A-B.ply (the core points coloured by signed change, with `change`,
    /// `lod95` and `significant` per point: Open3D, CloudCompare), change_A-B.png (a top-down map,
    /// north of the map frame up, with a scale bar), regions_A-B.csv (id, sign, cells, area,
    /// centre, mean and peak change), change_A-B.json (every figure) and, when dense,
    /// `dense/<visit>.ply` (each visit's surface, model frame). Sizes are in the model's
    /// unit: metres when it was mapped with navigation priors (`reconstruct --nav`), COLMAP's
    /// arbitrary unit otherwise; the defaults scale with the survey's altitude.
    Change(commands::change::Args),
    /// Match two images (learned or SIFT, with roll search) and show the verified matches.
    Match(commands::match_pair::Args),
    /// ROS 2 bags (mcap or sqlite3): info, export an image topic, pack image folders.
    #[command(subcommand)]
    Bag(commands::bag::Command),
    /// Start the ROS 2 node graph a launch file describes (launch-scripts/survey.yaml).
    Launch(commands::launch::Args),
    /// Run one ROS 2 node (ingest) in this process until Ctrl-C or SIGTERM.
    Node(commands::launch::NodeArgs),
    /// Call the mapper node's services: save the map to a folder, or map now.
    #[command(subcommand)]
    Service(commands::service::Command),
    /// Benchmarks that print Revisit's figures beside a reference implementation.
    #[command(subcommand)]
    Bench(commands::bench::Bench),
    /// Check what Revisit runs on (Python with pycolmap, ONNX Runtime, each
    /// learned model against its contract) and say what is ready.
    Doctor(commands::doctor::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    progress::init_logging(cli.verbose);
    let result = match cli.command {
        Command::Reconstruct(args) => commands::reconstruct::run(*args),
        Command::Synth(args) => commands::synth::run(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::Change(args) => commands::change::run(args),
        Command::Match(args) => commands::match_pair::run(args),
        Command::Bag(command) => commands::bag::run(command),
        Command::Launch(args) => commands::launch::run(args),
        Command::Node(args) => commands::launch::run_node(args),
        Command::Service(command) => commands::service::run(command),
        Command::Bench(bench) => commands::bench::run(bench),
        Command::Doctor(args) => commands::doctor::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) if is_cancelled(&err) => {
            eprintln!("stopped by {}: finished work is stored; run the same command again to resume", signals::name());
            std::process::ExitCode::from(signals::exit_code().unwrap_or(130))
        }
        Err(err) => {
            // One line: the outermost context first, then its causes (a cause
            // that its error's own message already ends with is said once).
            let mut chain: Vec<String> = Vec::new();
            for cause in err.chain().map(ToString::to_string) {
                if !chain.last().is_some_and(|last| last.ends_with(&cause)) {
                    chain.push(cause);
                }
            }
            eprintln!("error: {}", chain.join(": "));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Whether the command stopped because a signal asked it to.
fn is_cancelled(err: &anyhow::Error) -> bool {
    err.chain().any(|cause| matches!(cause.downcast_ref(), Some(revisit_pipeline::PipelineError::Cancelled)))
}
