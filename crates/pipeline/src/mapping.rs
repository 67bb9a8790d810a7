//! The mapping stage over a work folder: runs COLMAP once over the store, puts
//! the models where users look for them, and skips or extends work already done.

use std::path::{Path, PathBuf};

use revisit_colmap::{
    run_mapper, ChangeAware, Engine, MapperError, MapperOptions, MapperRun, ModelSummary, MIN_POSE_PRIORS,
};
use revisit_core::CameraId;
use revisit_store::PosePrior;
use serde::{Deserialize, Serialize};

use crate::{Cancel, PipelineError};

/// What the mapping stage produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MappingOutcome {
    /// Every model, largest first, with its final folder.
    pub models: Vec<ModelSummary>,
    /// The store had not changed since the last mapping: its models were kept.
    pub reused: bool,
    /// The previous model was extended rather than rebuilt.
    pub extended: bool,
    /// A fingerprint of the store's content that the models were built from.
    pub inputs: String,
    /// The pairs set aside (kept out of COLMAP's sight) when the models were built.
    #[serde(default)]
    pub set_aside: Vec<u64>,
    /// A fingerprint of the navigation priors the models were built with ("" for none).
    #[serde(default)]
    pub priors: String,
    /// The models were placed on the navigation priors (metres, in the navigation frame).
    #[serde(default)]
    pub on_navigation: bool,
    /// COLMAP's peak resident memory, MiB (`None` when the models were kept).
    #[serde(default)]
    pub peak_rss_mib: Option<f64>,
    /// What change-aware mapping did, when it ran.
    #[serde(default)]
    pub change_aware: Option<ChangeAware>,
}

/// Where the models of a work folder live: `WORK/model` for one model,
/// `WORK/model/1`, `WORK/model/2`, ... (largest first) for several.
pub fn model_root(work: &Path) -> PathBuf {
    work.join("model")
}

/// The folder of the `k`-th of `count` models (largest first) of the work folder `work`.
fn model_path(work: &Path, k: usize, count: usize) -> PathBuf {
    match count {
        1 => model_root(work),
        _ => model_root(work).join((k + 1).to_string()),
    }
}

fn record_path(work: &Path) -> PathBuf {
    work.join("mapping.json")
}

/// An I/O error on `path`, as the pipeline reports it.
pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io { path: path.to_path_buf(), source }
}

fn previous(work: &Path) -> Option<MappingOutcome> {
    let text = std::fs::read_to_string(record_path(work)).ok()?;
    let mut outcome: MappingOutcome = serde_json::from_str(&text).ok()?;
    // Where the models are now: the work folder may have been moved or copied since.
    let count = outcome.models.len();
    for (k, model) in outcome.models.iter_mut().enumerate() {
        model.path = model_path(work, k, count);
    }
    outcome.models.iter().all(|m| m.path.join("images.bin").is_file()).then_some(outcome)
}

/// Whether every image of the model at `model` still has the keypoints it was mapped with: a
/// visit added later registers learned keypoints in the earlier visits' images (their keypoint
/// lists grow), and COLMAP cannot extend a model whose images changed; it maps afresh then.
fn keypoints_unchanged(model: &Path, database: &Path) -> bool {
    let (Ok(model), Ok(store)) = (revisit_colmap::read_model(model), revisit_store::Store::open_read_only(database))
    else {
        return false;
    };
    let unchanged = model.images.values().all(|image| {
        store.read_keypoints(image.image_id).is_ok_and(|keypoints| keypoints.len() == image.points2d.len())
    });
    if !unchanged {
        tracing::info!("mapping afresh: keypoints were added to images of the previous model");
    }
    unchanged
}

/// Whether every pair set aside now was already set aside when the previous model was built.
fn none_withdrawn(before: &[u64], now: &[u64]) -> bool {
    let withdrawn = now.iter().filter(|pair| !before.contains(pair)).count();
    if withdrawn > 0 {
        tracing::info!(withdrawn, "mapping afresh: pairs of the previous model were set aside");
    }
    withdrawn == 0
}

/// What a mapping is built from, besides the store's matches.
pub struct MappingInputs<'a> {
    /// A fingerprint of everything the store holds that mapping reads.
    pub fingerprint: &'a str,
    /// The pairs set aside (kept out of COLMAP's sight).
    pub set_aside: &'a [u64],
    /// A fingerprint of the navigation priors, "" for none.
    pub priors: &'a str,
    /// How many images have a navigation prior.
    pub pose_priors: usize,
    /// Cameras whose intrinsics are held fixed.
    pub constant_cameras: &'a [CameraId],
}

/// A fingerprint of navigation priors: "" for none, else their count and a hash of every
/// value (FNV-1a over the bits, stable across builds).
pub fn priors_fingerprint(priors: &[PosePrior]) -> String {
    if priors.is_empty() {
        return String::new();
    }
    let mut hash = revisit_core::Fingerprint::default();
    for prior in priors {
        hash.u64(u64::from(prior.image_id));
        for value in prior.position_m.iter().chain(prior.covariance_m2.iter().flatten()) {
            hash.f64(*value);
        }
    }
    format!("{} priors {}", priors.len(), hash.hex())
}

/// Whether the navigation priors are those the previous model was built with.
fn same_priors(before: &str, now: &str) -> bool {
    if before != now {
        tracing::info!("mapping afresh: the navigation priors changed");
    }
    before == now
}

/// Maps the store at `database` into `work`'s model folder. If the last
/// mapping had the same `inputs.fingerprint`, its models are kept; if it
/// differs and the engine is incremental, the previous largest model is
/// extended with the new images (not with change-aware mapping, which maps
/// afresh), unless pairs it was built with are now set aside (a model holds
/// its pairs' tracks: it is rebuilt without them) or the navigation priors
/// changed (it was refined on the old ones).
/// A cancelled run leaves the previous models as they were.
pub fn map(
    python: &Path,
    database: &Path,
    image_root: &Path,
    work: &Path,
    inputs: &MappingInputs,
    options: &MapperOptions,
    cancel: &Cancel,
) -> Result<MappingOutcome, PipelineError> {
    let before = previous(work);
    if let Some(before) = &before {
        if before.inputs == inputs.fingerprint {
            tracing::info!("mapping: the store is unchanged since the last run; keeping its models");
            return Ok(MappingOutcome { reused: true, extended: false, peak_rss_mib: None, ..before.clone() });
        }
    }
    let staging = work.join(".mapping");
    let extend = before
        .as_ref()
        .and_then(|b| b.models.first())
        .filter(|_| options.engine == Engine::Incremental && !options.change_aware)
        .filter(|_| before.as_ref().is_none_or(|b| none_withdrawn(&b.set_aside, inputs.set_aside)))
        .filter(|_| before.as_ref().is_none_or(|b| same_priors(&b.priors, inputs.priors)))
        .filter(|m| keypoints_unchanged(&m.path, database))
        .map(|m| m.path.clone());
    // Extend from a copy: the models in place are replaced only on success.
    let extend_copy = match &extend {
        Some(model) => {
            let copy = work.join(".mapping-input");
            copy_dir(model, &copy)?;
            Some(copy)
        }
        None => None,
    };
    tracing::info!(extend = ?extend, "mapping with COLMAP");
    let run = MapperRun {
        python,
        database,
        image_root,
        output: &staging,
        extend: extend_copy.as_deref(),
        constant_cameras: inputs.constant_cameras,
        pose_priors: inputs.pose_priors >= MIN_POSE_PRIORS,
    };
    let produced = match run_mapper(&run, options, cancel.flag()) {
        Err(MapperError::Cancelled) => return Err(PipelineError::Cancelled),
        other => other?,
    };

    let root = model_root(work);
    if root.exists() {
        std::fs::remove_dir_all(&root).map_err(io(&root))?;
    }
    let count = produced.models.len();
    let mut models = Vec::with_capacity(count);
    for (k, model) in produced.models.into_iter().enumerate() {
        let target = model_path(work, k, count);
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        std::fs::rename(&model.path, &target).map_err(io(&model.path))?;
        models.push(ModelSummary { path: target, ..model });
    }
    std::fs::remove_dir_all(&staging).map_err(io(&staging))?;
    if let Some(copy) = &extend_copy {
        std::fs::remove_dir_all(copy).map_err(io(copy))?;
    }
    let outcome = MappingOutcome {
        models,
        reused: false,
        extended: extend.is_some(),
        inputs: inputs.fingerprint.to_owned(),
        set_aside: inputs.set_aside.to_vec(),
        priors: inputs.priors.to_owned(),
        on_navigation: produced.on_priors,
        peak_rss_mib: produced.peak_rss_mib,
        change_aware: produced.change_aware,
    };
    let record = record_path(work);
    let json = serde_json::to_string_pretty(&outcome).unwrap_or_default();
    std::fs::write(&record, json).map_err(io(&record))?;
    Ok(outcome)
}

fn copy_dir(from: &Path, to: &Path) -> Result<(), PipelineError> {
    if to.exists() {
        std::fs::remove_dir_all(to).map_err(io(to))?;
    }
    std::fs::create_dir_all(to).map_err(io(to))?;
    for entry in std::fs::read_dir(from).map_err(io(from))? {
        let entry = entry.map_err(io(from))?;
        if entry.path().is_file() {
            let target = to.join(entry.file_name());
            std::fs::copy(entry.path(), &target).map_err(io(&target))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_moved_work_folder_keeps_its_models_where_they_are_now() {
        let dir = tempfile::tempdir().unwrap();
        let (original, moved) = (dir.path().join("original"), dir.path().join("moved"));
        let summary = |path: PathBuf| ModelSummary {
            path,
            registered_images: vec!["s1/a.png".into()],
            points: 1,
            mean_reprojection_error_px: 0.5,
            navigation_rms_m: None,
            navigation_offsets: Default::default(),
        };
        let outcome = MappingOutcome {
            models: vec![summary(model_path(&original, 0, 2)), summary(model_path(&original, 1, 2))],
            reused: false,
            extended: false,
            inputs: "inputs".into(),
            set_aside: Vec::new(),
            priors: String::new(),
            on_navigation: false,
            peak_rss_mib: None,
            change_aware: None,
        };
        for model in &outcome.models {
            std::fs::create_dir_all(&model.path).unwrap();
            std::fs::write(model.path.join("images.bin"), b"").unwrap();
        }
        std::fs::write(record_path(&original), serde_json::to_string(&outcome).unwrap()).unwrap();
        std::fs::rename(&original, &moved).unwrap();
        let paths: Vec<PathBuf> = previous(&moved).unwrap().models.into_iter().map(|m| m.path).collect();
        assert_eq!(paths, [moved.join("model/1"), moved.join("model/2")]);
    }
}
