//! What a reconstruction hands to users: which model counts, poses as CSV,
//! and the report.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use revisit_colmap::ModelSummary;
use revisit_core::{split_image_name, Reconstruction};
use serde::Serialize;

use crate::ingest::SessionImages;

/// The rule by which `registered` is counted, as written into reports.
pub const REGISTERED_RULE: &str = "registered = images of the session in the chosen model: the model with the most \
    registered images among those that hold images of every session, or the largest model if none does";

/// Index of the model that counts (see [`REGISTERED_RULE`]) among `models`
/// (largest first), or `None` if there is none.
pub fn chosen_model(models: &[ModelSummary], sessions: &[SessionImages]) -> Option<usize> {
    let holds_all = |m: &ModelSummary| {
        sessions.iter().all(|s| m.registered_images.iter().any(|n| split_image_name(n).map(|p| p.0) == Some(&s.name)))
    };
    let all: Vec<usize> = (0..models.len()).filter(|&k| models.get(k).is_some_and(holds_all)).collect();
    let pick = |ks: &mut dyn Iterator<Item = usize>| {
        ks.max_by_key(|&k| (models.get(k).map_or(0, |m| m.registered_images.len()), std::cmp::Reverse(k)))
    };
    pick(&mut all.into_iter()).or_else(|| pick(&mut (0..models.len())))
}

/// `poses.csv`: `session,image,qw,qx,qy,qz,tx,ty,tz` (cam_from_world), one row
/// per registered image, sorted by session then image.
pub fn poses_csv(model: &Reconstruction) -> String {
    let mut rows: Vec<(String, String, [f64; 4], [f64; 3])> = model
        .images
        .values()
        .map(|image| {
            let (session, file) = split_image_name(&image.name).unwrap_or(("", &image.name));
            let t = image.cam_from_world.translation;
            (session.to_owned(), file.to_owned(), image.cam_from_world.wxyz(), [t.x, t.y, t.z])
        })
        .collect();
    rows.sort_by(|a, b| (&a.0, &a.1).cmp(&(&b.0, &b.1)));
    let mut csv = String::from("session,image,qw,qx,qy,qz,tx,ty,tz\n");
    for (session, file, q, t) in rows {
        let _ = writeln!(csv, "{session},{file},{},{},{},{},{},{},{}", q[0], q[1], q[2], q[3], t[0], t[1], t[2]);
    }
    csv
}

/// One session's line of the report.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct SessionReport {
    pub images: usize,
    pub registered: usize,
}

/// Pairs of one kind (`intra`, `cross`): tried and verified.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PairReport {
    pub tried: usize,
    pub verified: usize,
}

/// Registered images per session in the chosen model.
pub fn session_reports(
    sessions: &[SessionImages],
    models: &[ModelSummary],
    chosen: Option<usize>,
) -> BTreeMap<String, SessionReport> {
    let registered = chosen.and_then(|k| models.get(k)).map(|m| m.registered_images.as_slice()).unwrap_or(&[]);
    sessions
        .iter()
        .map(|s| {
            let count = registered.iter().filter(|n| split_image_name(n).map(|p| p.0) == Some(&s.name)).count();
            (s.name.clone(), SessionReport { images: s.files.len(), registered: count })
        })
        .collect()
}

/// Pairs tried, and verified (geometric verification kept inliers), per kind.
pub fn pair_reports(records: &[revisit_store::PairRecord]) -> BTreeMap<String, PairReport> {
    let mut reports: BTreeMap<String, PairReport> = BTreeMap::new();
    for record in records {
        let entry = reports.entry(record.kind.clone()).or_default();
        entry.tried += 1;
        if record.num_inliers > 0 {
            entry.verified += 1;
        }
    }
    reports
}

/// Verified cross-session pairs by the roll of their second image, degrees.
pub fn roll_histogram(records: &[revisit_store::PairRecord]) -> BTreeMap<u32, usize> {
    let mut histogram = BTreeMap::new();
    for record in records.iter().filter(|r| r.kind == "cross" && r.num_inliers > 0) {
        *histogram.entry(record.roll_deg.unsigned_abs()).or_default() += 1;
    }
    histogram
}
