//! Each visit's dense surface, for the change map: made from the visit's own images at a
//! model's poses (`revisit_colmap::dense`), kept in a folder beside a record of what it was
//! made from, and reused while the model's poses of that visit, its cameras, the image folder
//! and the options stay the same (a second map of the same model, or a run stopped and started
//! again, makes no visit's surface twice).

use std::path::Path;

use nalgebra::Point3;
use revisit_colmap::dense::{read_surface, surface_fingerprint, surface_path};
use revisit_colmap::{run_dense, DenseError, DenseOptions, DenseRun, DenseVisit};
use revisit_core::Reconstruction;
use serde::{Deserialize, Serialize};

use crate::{Cancel, PipelineError};

/// `<folder>/<visit>.json`: what a stored surface was made from, and what was made.
#[derive(Serialize, Deserialize)]
struct Record {
    fingerprint: String,
    made: DenseVisit,
}

/// One visit's surface and how it was made.
pub struct Surface {
    pub points: Vec<Point3<f64>>,
    pub made: DenseVisit,
    /// Read from `folder`, made by an earlier run.
    pub reused: bool,
}

/// The surfaces of `visits` of `model` (read from `model_dir`; image names relative to
/// `image_root`), in the order given, from `folder` when stored there, else made and stored.
pub fn dense_surfaces(
    python: &Path,
    (model_dir, model): (&Path, &Reconstruction),
    image_root: &Path,
    visits: &[&str],
    folder: &Path,
    options: &DenseOptions,
    cancel: &Cancel,
) -> Result<Vec<Surface>, PipelineError> {
    let record_path = |visit: &str| folder.join(format!("{visit}.json"));
    let stored = |visit: &str, fingerprint: &str| -> Option<DenseVisit> {
        let text = std::fs::read_to_string(record_path(visit)).ok()?;
        let record: Record = serde_json::from_str(&text).ok()?;
        (record.fingerprint == fingerprint && surface_path(folder, visit).is_file()).then_some(record.made)
    };
    let fingerprints: Vec<String> =
        visits.iter().map(|visit| surface_fingerprint(model, visit, image_root, options)).collect();
    let missing: Vec<&str> = visits
        .iter()
        .zip(&fingerprints)
        .filter(|(visit, fingerprint)| stored(visit, fingerprint).is_none())
        .map(|(visit, _)| *visit)
        .collect();
    // One visit at a time, its record written as soon as it is made: a run stopped during the
    // second visit keeps the first.
    for (visit, fingerprint) in visits.iter().zip(&fingerprints).filter(|(visit, _)| missing.contains(visit)) {
        let run = DenseRun { python, model: model_dir, image_root, output: folder, visits: &[visit] };
        for made in run_dense(&run, options, cancel.flag())? {
            let path = record_path(&made.visit);
            let record = Record { fingerprint: fingerprint.clone(), made };
            let text = serde_json::to_string_pretty(&record).map_err(|e| DenseError::BadSummary(e.to_string()))?;
            std::fs::write(&path, text + "\n").map_err(|source| PipelineError::Io { path, source })?;
        }
    }
    visits
        .iter()
        .zip(&fingerprints)
        .map(|(visit, fingerprint)| {
            let made = stored(visit, fingerprint)
                .ok_or_else(|| DenseError::Failed(format!("visit {visit}: no surface was made")))?;
            let points = read_surface(&surface_path(folder, visit))?;
            Ok(Surface { points, made, reused: !missing.contains(visit) })
        })
        .collect()
}
