//! Place recognition: one global descriptor per image, and nearest neighbours
//! among the images of other visits.
//!
//! Two sources of global descriptors behind [`GlobalDescriptor`]:
//! - [`Vlad`], built in, needs no trained weights: VLAD (Jégou et al., 2010)
//!   over the image's learned local descriptors, with a vocabulary learned by
//!   k-means from the survey's own images ([`Vocabulary::train`]);
//! - [`OnnxPlaces`], any ONNX model with the contract RGB image in [0, 1] ->
//!   one L2-normalised vector (MegaLoc, NetVLAD, CosPlace... supplied by users).
//!
//! Descriptors are L2-normalised, so distances are in [0, 2]. Downward cameras
//! revisit a place at any heading, so a query is described at four rolls and
//! its distance to an image is the smallest over them ([`nearest`]).
//!
//! Invariant: pure. Images and descriptors in, descriptors and candidates
//! out; the pipeline keeps them in the store.

mod onnx;
mod vlad;

pub use onnx::OnnxPlaces;
pub use vlad::{Vlad, Vocabulary};

use revisit_core::Roll;

/// A way to describe a whole image by one L2-normalised vector.
pub trait GlobalDescriptor {
    /// The name under which descriptors are stored (a changed method or
    /// vocabulary must not mix with old descriptors).
    fn name(&self) -> String;
}

/// An image of the database that a query may show, with the query's roll
/// that came closest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Index into the database.
    pub index: usize,
    /// Smallest L2 distance over the query's rolls.
    pub distance: f32,
    pub roll: Roll,
}

/// How many candidates a query keeps.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CandidateOptions {
    /// The nearest `top_k` database images.
    pub top_k: usize,
    /// Only those closer than this (L2 on normalised descriptors); `None` keeps all `top_k`.
    pub max_distance: Option<f32>,
}

impl Default for CandidateOptions {
    fn default() -> Self {
        CandidateOptions { top_k: 5, max_distance: None }
    }
}

impl CandidateOptions {
    /// A query needs at least one candidate; a distance bound is in (0, 2].
    pub fn check(&self) -> Result<(), String> {
        if self.top_k == 0 {
            return Err("top_k must be at least 1".to_owned());
        }
        match self.max_distance {
            Some(d) if !(d > 0.0 && d <= 2.0) => Err(format!("max_distance {d} is not in (0, 2]")),
            _ => Ok(()),
        }
    }
}

/// The database images nearest to a query described at one or more rolls,
/// nearest first (ties by index).
pub fn nearest(query_by_roll: &[(Roll, &[f32])], database: &[&[f32]], options: &CandidateOptions) -> Vec<Candidate> {
    let mut candidates: Vec<Candidate> = database
        .iter()
        .enumerate()
        .filter_map(|(index, d)| {
            query_by_roll
                .iter()
                .map(|(roll, q)| Candidate { index, distance: l2(q, d), roll: *roll })
                .min_by(|a, b| a.distance.total_cmp(&b.distance))
        })
        .filter(|c| options.max_distance.is_none_or(|max| c.distance <= max))
        .collect();
    candidates.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.index.cmp(&b.index)));
    candidates.truncate(options.top_k);
    candidates
}

fn l2(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() {
        return f32::INFINITY;
    }
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>().sqrt()
}

/// Scales `v` to unit length (leaves a zero vector as it is).
pub fn l2_normalise(v: &mut [f32]) {
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if norm > 0.0 {
        v.iter_mut().for_each(|x| *x /= norm);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_takes_the_best_roll_and_respects_top_k_and_distance() {
        let database: Vec<Vec<f32>> = vec![vec![1.0, 0.0], vec![0.0, 1.0], vec![-1.0, 0.0]];
        let database: Vec<&[f32]> = database.iter().map(Vec::as_slice).collect();
        let at0 = [0.0, 1.0];
        let at90 = [-1.0, 0.0];
        let query = [(Roll::R0, &at0[..]), (Roll::R90, &at90[..])];
        let found = nearest(&query, &database, &CandidateOptions { top_k: 2, max_distance: None });
        assert_eq!(found.iter().map(|c| (c.index, c.roll)).collect::<Vec<_>>(), vec![(1, Roll::R0), (2, Roll::R90)]);
        let close = nearest(&query, &database, &CandidateOptions { top_k: 3, max_distance: Some(0.5) });
        assert_eq!(close.len(), 2);
    }
}
