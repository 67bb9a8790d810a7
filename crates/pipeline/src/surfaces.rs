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
    // One visit at a time, its record written as soon as it is made: a run stopped during the
    // second visit keeps the first.
    let mut surfaces = Vec::with_capacity(visits.len());
    for visit in visits {
        let fingerprint = surface_fingerprint(model, visit, image_root, options);
        let record_path = folder.join(format!("{visit}.json"));
        let stored = std::fs::read_to_string(&record_path)
            .ok()
            .and_then(|text| serde_json::from_str::<Record>(&text).ok())
            .filter(|record| record.fingerprint == fingerprint && surface_path(folder, visit).is_file());
        let (made, reused) = match stored {
            Some(record) => (record.made, true),
            None => {
                let run = DenseRun { python, model: model_dir, image_root, output: folder, visits: &[visit] };
                let made = run_dense(&run, options, cancel.flag())?
                    .into_iter()
                    .find(|made| made.visit == *visit)
                    .ok_or_else(|| DenseError::Failed(format!("visit {visit}: no surface was made")))?;
                let record = Record { fingerprint, made };
                let text = serde_json::to_string_pretty(&record).map_err(|e| DenseError::BadSummary(e.to_string()))?;
                std::fs::write(&record_path, text + "\n")
                    .map_err(|source| PipelineError::Io { path: record_path, source })?;
                (record.made, false)
            }
        };
        let points = read_surface(&surface_path(folder, visit))?;
        surfaces.push(Surface { points, made, reused });
    }
    Ok(surfaces)
}
