//! The mapper stage: one joint COLMAP run over a Revisit store, driven through
//! pycolmap from the project's virtual environment.
//!
//! The entry point is embedded in the binary and written next to the output
//! before each run, so an installed `revisit` needs nothing but a Python with
//! pycolmap. (The post-hoc baselines, `revisit-posthoc`, start Python the same
//! way, through [`run_until_cancelled`].)

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use serde::{Deserialize, Serialize};

const ENTRY_POINT: &str = include_str!("../python/revisit_mapper.py");
/// The change-aware joint solve, a module the entry point imports (written beside it).
const CHANGE_AWARE: &str = include_str!("../python/revisit_change_aware.py");

/// Environment variable naming the Python interpreter to use.
pub const PYTHON_ENV: &str = "REVISIT_PYTHON";

#[derive(Debug, thiserror::Error)]
pub enum MapperError {
    #[error(
        "no Python environment with pycolmap found (looked for {looked}); run scripts/setup.sh, \
         or pass --python / set {PYTHON_ENV}"
    )]
    NoPython { looked: String },
    #[error("Python {python} cannot import pycolmap: {stderr}")]
    NoPycolmap { python: PathBuf, stderr: String },
    #[error("could not start {python}: {source}")]
    Spawn { python: PathBuf, source: std::io::Error },
    #[error("writing {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("COLMAP mapping failed (exit {code:?}): {stderr_tail}")]
    Failed { code: Option<i32>, stderr_tail: String },
    #[error("COLMAP mapping printed no summary: {0}")]
    BadSummary(String),
    #[error("COLMAP mapping was stopped on request")]
    Cancelled,
}

/// Runs `command` to the end and returns its output, or kills it and returns
/// `None` once `cancelled` is set. Its output is read on threads, so that a
/// chatty child never blocks on a full pipe.
pub fn run_until_cancelled(mut command: Command, cancelled: &AtomicBool) -> std::io::Result<Option<Output>> {
    let mut child = command.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn()?;
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(child.stdout.take().map(|p| Box::new(p) as Box<dyn Read + Send>));
    let stderr = drain(child.stderr.take().map(|p| Box::new(p) as Box<dyn Read + Send>));
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if cancelled.load(Ordering::SeqCst) {
            child.kill()?;
            child.wait()?;
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let stdout = stdout.join().unwrap_or_default();
    let stderr = stderr.join().unwrap_or_default();
    Ok(Some(Output { status, stdout, stderr }))
}

/// The last JSON line a script printed on stdout (its summary; logs go to stderr).
pub(crate) fn summary_line<T: serde::de::DeserializeOwned>(stdout: &[u8]) -> serde_json::Result<T> {
    let stdout = String::from_utf8_lossy(stdout);
    serde_json::from_str(stdout.lines().rev().find(|l| l.starts_with('{')).unwrap_or(""))
}

/// Which COLMAP mapper runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// Incremental SfM (COLMAP's default); can extend an existing model.
    #[default]
    Incremental,
    /// Global SfM (GLOMAP).
    Global,
}

/// Options of the mapper stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapperOptions {
    /// Default incremental.
    pub engine: Engine,
    /// Seed of COLMAP's random choices. Default 0.
    pub seed: u64,
    /// Threads; -1 = all cores. Default 1: with more, COLMAP's bundle
    /// adjustment sums in a varying order, so the same inputs give poses that
    /// differ in their last digits from run to run.
    pub threads: i32,
    /// Smallest model COLMAP keeps, in images. Default 10 (COLMAP's).
    pub min_model_size: usize,
    /// Fewest 2D-3D inliers with which an image joins a model. Default 30
    /// (COLMAP's). Fewer registers more, and more wrongly: at 20 an image
    /// of the strong-change reef with 184 and 211 verified inliers to its
    /// registered neighbours (26 of them triangulated) joined, and 8 images of
    /// a visit matched without roll search joined 730 px off.
    pub min_pose_inliers: usize,
    /// Change-aware mapping (incremental engine): each visit mapped alone,
    /// the visits placed by the similarity most of their cross-visit matches
    /// agree with (and their navigation, when given), then every match
    /// triangulated at those placements and bundle-adjusted jointly, so that
    /// matches on structure that changed between visits (a coral that grew)
    /// are left out instead of bending whole visits. Maps afresh every time
    /// (never extends). Default off: on every survey measured it was as
    /// accurate as the plain solve or more, but its placement costs grow
    /// with the cross-visit matches: 57 s against 8 s of mapping on an
    /// unchanged 3 x 16 survey (74k matches; README).
    pub change_aware: bool,
}

impl Default for MapperOptions {
    fn default() -> Self {
        Self {
            engine: Engine::Incremental,
            seed: 0,
            threads: 1,
            min_model_size: 10,
            min_pose_inliers: 30,
            change_aware: false,
        }
    }
}

/// One model the mapper produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelSummary {
    /// Folder holding the binary model.
    pub path: PathBuf,
    /// Names (`session/file`) of the registered images, sorted.
    pub registered_images: Vec<String>,
    pub points: usize,
    pub mean_reprojection_error_px: f64,
    /// RMS distance between the registered cameras and their navigation
    /// priors, metres (`None` when the model was not placed on priors).
    #[serde(default)]
    pub navigation_rms_m: Option<f64>,
    /// Per visit, how far its navigation sat from where the images put it
    /// (the offset taken out of its priors); empty when not placed on priors.
    #[serde(default)]
    pub navigation_offsets: BTreeMap<String, NavigationOffset>,
}

/// A visit's navigation against the images: the mean offset of its
/// positions from its cameras in the model placed on the navigation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NavigationOffset {
    pub offset_m: f64,
    /// The offset in standard deviations of the error common to the visit's
    /// positions (its smallest covariance: the position fix); `None` when
    /// the navigation gives no uncertainty.
    pub offset_sigmas: Option<f64>,
}

impl NavigationOffset {
    /// Beyond this many standard deviations a visit's placement by the images
    /// and by its navigation disagree (a 3D offset: 99% of honest fixes lie within).
    pub const DISAGREES_SIGMAS: f64 = 3.5;

    /// Whether the images put the visit where its navigation cannot have been.
    pub fn disagrees(&self) -> bool {
        self.offset_sigmas.is_some_and(|s| s > Self::DISAGREES_SIGMAS)
    }
}

/// What change-aware mapping did: which visits it placed, and per visit
/// pair what became of their cross-visit matches.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChangeAware {
    /// Per visit pair (`A-B`, names sorted), its verified cross-visit matches.
    pub pairs: BTreeMap<String, CrossMatchFate>,
    /// Visits placed by their matches' consensus (the first is the reference).
    pub placed: Vec<String>,
    /// Visits that could not be mapped alone or placed (they joined, if at
    /// all, as COLMAP's incremental mapper let them).
    pub unplaced: Vec<String>,
    pub seconds: f64,
}

/// What became of one visit pair's verified cross-visit matches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CrossMatchFate {
    pub matches: usize,
    /// Matches whose two visits' points agree (4 px) under the visits'
    /// placements (0 when either visit was not placed).
    pub agreeing: usize,
    /// Matches the joint model holds (both keypoints in one track).
    pub kept: usize,
    /// The others: on structure that changed, wrong, or not triangulated.
    pub dropped: usize,
}

/// What one mapper run produced.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct Mapped {
    /// Every model, largest first.
    pub models: Vec<ModelSummary>,
    /// The models were placed on the pose priors (metres, their frame).
    #[serde(default)]
    pub on_priors: bool,
    /// What change-aware mapping did (`None` when it was off or could not
    /// place two visits and the store was mapped as it is).
    #[serde(default)]
    pub change_aware: Option<ChangeAware>,
    /// The mapper process's peak resident memory, MiB.
    pub peak_rss_mib: Option<f64>,
}

/// Checks that `python` runs and imports pycolmap; returns it.
pub fn check_python(python: &Path) -> Result<PathBuf, MapperError> {
    let output = Command::new(python)
        .args(["-c", "import pycolmap"])
        .output()
        .map_err(|source| MapperError::Spawn { python: python.to_path_buf(), source })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let last = stderr.lines().last().unwrap_or("").to_owned();
        return Err(MapperError::NoPycolmap { python: python.to_path_buf(), stderr: last });
    }
    Ok(python.to_path_buf())
}

/// One mapping run: what COLMAP reads and where it writes.
#[derive(Clone, Copy, Debug)]
pub struct MapperRun<'a> {
    /// Python with pycolmap.
    pub python: &'a Path,
    /// The store (a COLMAP database).
    pub database: &'a Path,
    /// The folder image names are relative to.
    pub image_root: &'a Path,
    /// Models go to `output/<k>`.
    pub output: &'a Path,
    /// An existing model to continue (incremental engine only).
    pub extend: Option<&'a Path>,
    /// Calibrated cameras, whose intrinsics are held fixed. The global
    /// engine can hold all cameras fixed or none: it refines them all
    /// unless every camera is listed.
    pub constant_cameras: &'a [u32],
    /// Place the models on the store's pose priors (navigation) after
    /// mapping from the images: a similarity onto the priors (metres, their
    /// frame), then, for the largest model, COLMAP's pose-prior bundle
    /// adjustment with each visit's priors de-biased by the visit's common
    /// offset and weighted by their drift (see the script). Needs at least
    /// [`MIN_POSE_PRIORS`] registered images with a prior.
    pub pose_priors: bool,
}

/// The fewest registered images with a pose prior with which a model is
/// placed on the priors.
pub const MIN_POSE_PRIORS: usize = 3;

/// Maps the store into `run.output/<k>`, k = 0, 1, ... by decreasing size,
/// and returns every model produced. Setting `cancelled` stops COLMAP (within
/// a tenth of a second) and returns [`MapperError::Cancelled`].
pub fn run_mapper(run: &MapperRun<'_>, options: &MapperOptions, cancelled: &AtomicBool) -> Result<Mapped, MapperError> {
    let MapperRun { python, database, image_root, output, extend, constant_cameras, pose_priors } = *run;
    let parent = output.parent().unwrap_or(Path::new("."));
    let script = parent.join("revisit_mapper.py");
    for (name, text) in [("revisit_mapper.py", ENTRY_POINT), ("revisit_change_aware.py", CHANGE_AWARE)] {
        let path = parent.join(name);
        std::fs::write(&path, text).map_err(|source| MapperError::Io { path: path.clone(), source })?;
    }
    let mut command = Command::new(python);
    command
        .arg(&script)
        .arg("--database")
        .arg(database)
        .arg("--image-path")
        .arg(image_root)
        .arg("--output")
        .arg(output)
        .arg("--engine")
        .arg(match options.engine {
            Engine::Incremental => "incremental",
            Engine::Global => "global",
        })
        .arg("--seed")
        .arg(options.seed.to_string())
        .arg("--threads")
        .arg(options.threads.to_string())
        .arg("--min-model-size")
        .arg(options.min_model_size.to_string())
        .arg("--min-pose-inliers")
        .arg(options.min_pose_inliers.to_string());
    if !constant_cameras.is_empty() {
        let ids: Vec<String> = constant_cameras.iter().map(u32::to_string).collect();
        command.arg("--constant-cameras").arg(ids.join(","));
    }
    if pose_priors {
        command.arg("--pose-priors");
    }
    if options.change_aware {
        command.arg("--change-aware");
    }
    if let (Some(input), Engine::Incremental) = (extend, options.engine) {
        command.arg("--input-path").arg(input);
    }
    tracing::debug!(?command, "starting COLMAP");
    let result = run_until_cancelled(command, cancelled)
        .map_err(|source| MapperError::Spawn { python: python.to_path_buf(), source })?
        .ok_or(MapperError::Cancelled)?;
    let stderr = String::from_utf8_lossy(&result.stderr);
    if !result.status.success() {
        let tail: Vec<&str> = stderr.lines().rev().take(3).collect();
        let stderr_tail = tail.into_iter().rev().collect::<Vec<_>>().join(" | ");
        return Err(MapperError::Failed { code: result.status.code(), stderr_tail });
    }
    summary_line(&result.stdout).map_err(|e| MapperError::BadSummary(e.to_string()))
}
