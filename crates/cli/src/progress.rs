//! Logging and progress bars, shared by every subcommand.

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tracing_subscriber::EnvFilter;

/// Logs go to stderr; `RUST_LOG` overrides the verbosity flag.
pub fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new(format!("{default},{}", revisit_node::QUIET_DDS)));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false).init();
}

/// A progress bar for a stage of `len` steps, drawn on stderr (indicatif hides
/// it when stderr is not a terminal).
pub fn bar(len: u64, stage: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} {per_sec} eta {eta} {msg}") {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(stage.to_owned());
    bar
}

/// A counter of items with no known end, drawn on stderr.
pub fn spinner(stage: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("{prefix:>12} {spinner} {pos} {per_sec} {msg}") {
        bar.set_style(style);
    }
    bar.set_prefix(stage.to_owned());
    bar
}

/// The pipeline's progress as bars, one per stage.
#[derive(Default)]
pub struct Bars {
    current: Mutex<Option<ProgressBar>>,
}

impl revisit_pipeline::Progress for Bars {
    fn start(&self, stage: &str, len: u64) {
        if let Ok(mut current) = self.current.lock() {
            *current = Some(bar(len, stage));
        }
    }

    fn advance(&self) {
        if let Ok(current) = self.current.lock() {
            if let Some(bar) = current.as_ref() {
                bar.inc(1);
            }
        }
    }

    fn finish(&self) {
        if let Ok(mut current) = self.current.lock() {
            if let Some(bar) = current.take() {
                bar.finish_and_clear();
            }
        }
    }
}
