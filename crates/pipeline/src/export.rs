//! What a reconstruction hands to users: which model counts, poses as CSV,
//! and the parts of the report that describe the result.

use std::collections::BTreeMap;

use revisit_colmap::ModelSummary;
use revisit_core::{session_of, ImageName, PairKind, Reconstruction};
use revisit_store::PairRecord;

use crate::report::{PairReport, SessionReport};
use crate::Session;

/// The rule by which `registered` is counted, as written into reports.
pub const REGISTERED_RULE: &str = "registered = images of the session in the chosen model: the model with the most \
    registered images among those that hold images of every session, or the largest model if none does";

/// Index of the model that counts (see [`REGISTERED_RULE`]) among `models`
/// (largest first), or `None` if there is none.
pub fn chosen_model(models: &[ModelSummary], sessions: &[Session]) -> Option<usize> {
    let holds_all =
        |m: &ModelSummary| sessions.iter().all(|s| m.registered_images.iter().any(|n| session_of(n) == s.name));
    let all: Vec<usize> = (0..models.len()).filter(|&k| models.get(k).is_some_and(holds_all)).collect();
    let pick = |ks: &mut dyn Iterator<Item = usize>| {
        ks.max_by_key(|&k| (models.get(k).map_or(0, |m| m.registered_images.len()), std::cmp::Reverse(k)))
    };
    pick(&mut all.into_iter()).or_else(|| pick(&mut (0..models.len())))
}

/// `poses.csv`: `session,image,qw,qx,qy,qz,tx,ty,tz` (cam_from_world), one row
/// per registered image, sorted by session then image; quoted as RFC 4180
/// asks, so names holding commas or quotes read back intact.
pub fn poses_csv(model: &Reconstruction) -> Result<String, csv::Error> {
    let mut rows: Vec<(String, String, [f64; 4], [f64; 3])> = model
        .images
        .values()
        .map(|image| {
            let (session, file) = match ImageName::parse(&image.name) {
                Ok(name) => (name.session().to_owned(), name.file().to_owned()),
                Err(_) => (String::new(), image.name.clone()),
            };
            let t = image.cam_from_world.translation;
            (session, file, image.cam_from_world.wxyz(), [t.x, t.y, t.z])
        })
        .collect();
    rows.sort_by(|a, b| (&a.0, &a.1).cmp(&(&b.0, &b.1)));
    let mut writer = csv::Writer::from_writer(Vec::new());
    writer.write_record(["session", "image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"])?;
    for (session, file, q, t) in rows {
        let numbers = q.iter().chain(&t).map(f64::to_string);
        writer.write_record([session, file].into_iter().chain(numbers))?;
    }
    let bytes = writer.into_inner().map_err(|e| csv::Error::from(e.into_error()))?;
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// Registered images per session in the chosen model (cameras and visit
/// order from `sessions`).
pub fn session_reports(
    sessions: &[Session],
    models: &[ModelSummary],
    chosen: Option<usize>,
) -> BTreeMap<String, SessionReport> {
    let registered = chosen.and_then(|k| models.get(k)).map(|m| m.registered_images.as_slice()).unwrap_or(&[]);
    sessions
        .iter()
        .map(|s| {
            let count = registered.iter().filter(|n| session_of(n) == s.name).count();
            let report = SessionReport {
                visit: s.visit,
                images: s.images.len(),
                registered: count,
                navigation: 0,
                cameras: s.camera_reports(),
            };
            (s.name.clone(), report)
        })
        .collect()
}

/// Whether a model links a visit of `images` images, `registered` of them in
/// it: at least half of them are.
pub fn is_linked(registered: usize, images: usize) -> bool {
    2 * registered >= images
}

/// Sessions (of several) with fewer than half their images in the chosen
/// model: they could not be linked to the others.
pub fn unlinked_sessions(sessions: &BTreeMap<String, SessionReport>) -> Vec<String> {
    if sessions.len() < 2 {
        return Vec::new();
    }
    sessions.iter().filter(|(_, s)| !is_linked(s.registered, s.images)).map(|(name, _)| name.clone()).collect()
}

/// Pairs tried, and verified (geometric verification kept inliers), per kind.
pub fn pair_reports(records: &[PairRecord]) -> BTreeMap<PairKind, PairReport> {
    let mut reports: BTreeMap<PairKind, PairReport> = BTreeMap::new();
    for record in records {
        let entry = reports.entry(record.kind).or_default();
        entry.tried += 1;
        if record.num_inliers > 0 {
            entry.verified += 1;
        }
    }
    reports
}

/// Verified cross-session pairs by the roll of their second image, degrees.
pub fn roll_histogram(records: &[PairRecord]) -> BTreeMap<u32, usize> {
    let mut histogram = BTreeMap::new();
    for record in records.iter().filter(|r| r.kind == PairKind::Cross && r.num_inliers > 0) {
        *histogram.entry(record.roll_deg.unsigned_abs()).or_default() += 1;
    }
    histogram
}

#[cfg(test)]
mod tests {
    use revisit_core::{Image, Rigid3};

    use super::*;

    #[test]
    fn names_with_commas_quotes_and_accents_round_trip_through_poses_csv() {
        let mut model = Reconstruction::default();
        let names = ["2019, \"north\"/a.png", "été/b,c.png"];
        for (k, name) in names.iter().enumerate() {
            let image = Image {
                image_id: k as u32 + 1,
                camera_id: 1,
                name: (*name).to_owned(),
                cam_from_world: Rigid3::identity(),
                points2d: Vec::new(),
            };
            model.images.insert(image.image_id, image);
        }
        let text = poses_csv(&model).unwrap();
        let mut reader = csv::Reader::from_reader(text.as_bytes());
        let rows: Vec<(String, String)> =
            reader.records().map(|r| r.unwrap()).map(|r| (r[0].to_owned(), r[1].to_owned())).collect();
        assert_eq!(
            rows,
            [("2019, \"north\"".to_owned(), "a.png".to_owned()), ("été".to_owned(), "b,c.png".to_owned())]
        );
    }
}
