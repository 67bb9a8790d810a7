//! Consistency of the verified cross-visit pairs with each other, checked
//! before mapping.
//!
//! A wrong cross-visit pair can pass verification: a learned matcher run at
//! a wrong roll, or on two images of different places, returns matches that
//! are coherent enough for a fundamental (even an essential) matrix to find
//! 30 to 50 inliers among them. One such pair bends the joint model or merges
//! a visit at a wrong pose. What verification cannot see, the other pairs can:
//! downward cameras see the seabed nearly as a plane, so the matches of a pair
//! turn image 1 into image 2 by one in-plane angle (its *turn*). Within a
//! visit the turns chain (the verified pairs of a visit give every image a
//! heading relative to the visit), so each cross-visit pair between two visits
//! implies one heading offset between them, and the true pairs agree on it.
//!
//! Two rules, both on the turn of the pair's inlier matches:
//! 1. **The roll agrees**: a learned pair matched at roll `r` must turn by
//!    `-r` within 45 degrees (else another roll was the nearer one, and the
//!    matches do not show what the roll search chose).
//! 2. **The offset agrees**: between two connected parts of two visits, the
//!    offsets implied by their pairs are voted (weighted by inliers); when one
//!    offset holds more than half of the weight and at least two pairs, a pair
//!    more than `tolerance_deg` away from it is off the consensus.
//!
//! Pure: pairs in, verdicts out; the pipeline sets the rejected pairs aside
//! in the store.

use std::collections::BTreeMap;

use revisit_core::{ImageId, PairKind, Roll};

/// How far (degrees) a pair's implied offset may be from its visits' consensus, by default.
pub const DEFAULT_CONSISTENCY_TOLERANCE_DEG: f64 = 30.0;

/// The largest turn (degrees) away from the matched roll: half the spacing of the rolls.
const ROLL_TOLERANCE_DEG: f64 = 45.0;

/// Point pairs closer than this (pixels) in either image give no direction.
const MIN_SPAN_PX: f64 = 20.0;

/// Directions within this many degrees of the turn agree with it.
const AGREEMENT_DEG: f64 = 10.0;

/// The in-plane turn of a pair: directions in image 1 turned by `deg`
/// (degrees in [0, 360), counter-clockwise in pixel coordinates, x right and
/// y down) are the directions in image 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turn {
    pub deg: f64,
    /// The share of the point pairs' directions within 10 degrees of `deg`.
    pub agreement: f64,
}

/// The turn between matched points (`points1[k]` matches `points2[k]`): the
/// mode of the direction changes of point pairs `(k, k + 1)`, `(k, k + 3)`,
/// `(k, k + 7)`, refined to the mean of the directions that agree with it.
/// Robust to a share of wrong matches as large as the verified pairs carry.
/// `None` with fewer than 8 usable directions.
pub fn turn(points1: &[[f64; 2]], points2: &[[f64; 2]]) -> Option<Turn> {
    let n = points1.len().min(points2.len());
    let mut changes = Vec::with_capacity(3 * n);
    for k in 0..n {
        for step in [1, 3, 7] {
            let j = (k + step) % n;
            if j == k {
                continue;
            }
            let d1 = [points1[j][0] - points1[k][0], points1[j][1] - points1[k][1]];
            let d2 = [points2[j][0] - points2[k][0], points2[j][1] - points2[k][1]];
            if d1[0].hypot(d1[1]) < MIN_SPAN_PX || d2[0].hypot(d2[1]) < MIN_SPAN_PX {
                continue;
            }
            changes.push(wrap(d2[1].atan2(d2[0]).to_degrees() - d1[1].atan2(d1[0]).to_degrees()));
        }
    }
    if changes.len() < 8 {
        return None;
    }
    let (deg, agreeing) = mode(&changes, &vec![1.0; changes.len()], AGREEMENT_DEG);
    Some(Turn { deg, agreement: agreeing / changes.len() as f64 })
}

/// A verified pair as the check sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckedPair {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub kind: PairKind,
    /// From image 1 to image 2.
    pub turn: Turn,
    /// Verified inliers: the pair's weight in the vote.
    pub inliers: usize,
    /// For a learned cross-visit pair: the roll at which the later visit's image was matched.
    pub roll: Option<Roll>,
}

/// What the check says of a cross-visit pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Agrees with its roll and with its visits' consensus (or there is no consensus to check).
    Consistent,
    /// Its matches turn the later image by `turn_deg`, not by about `-roll`.
    RollDisagrees { turn_deg: f64, roll: Roll },
    /// Its offset between the two visits is `offset_deg`; the other pairs agree on `consensus_deg`.
    OffConsensus { offset_deg: f64, consensus_deg: f64 },
}

impl Verdict {
    pub fn is_consistent(&self) -> bool {
        matches!(self, Verdict::Consistent)
    }
}

/// The heading offset between two visits that one cross-visit pair implies.
struct Offset {
    /// Into the pairs checked.
    index: usize,
    deg: f64,
    /// The pair's inliers.
    weight: f64,
}

/// What the pairs say together: each image's heading within its visit, the
/// cross-visit pairs' roll verdicts, and the heading offsets their pairs imply
/// between two connected parts of two visits, `(earlier part, later part)`.
struct Votes {
    headings: BTreeMap<ImageId, (ImageId, f64)>,
    verdicts: Vec<(usize, Verdict)>,
    groups: BTreeMap<(ImageId, ImageId), Vec<Offset>>,
}

fn votes(pairs: &[CheckedPair], visit_of: &BTreeMap<ImageId, usize>) -> Votes {
    let headings = headings(pairs, visit_of);
    let mut groups: BTreeMap<(ImageId, ImageId), Vec<Offset>> = BTreeMap::new();
    let mut verdicts = Vec::new();
    for (index, pair) in pairs.iter().enumerate() {
        if pair.kind != PairKind::Cross {
            continue;
        }
        let (Some(v1), Some(v2)) = (visit_of.get(&pair.image_id1), visit_of.get(&pair.image_id2)) else { continue };
        // The turn from the earlier visit's image to the later one's.
        let (earlier, later, turn_deg) = match v1 <= v2 {
            true => (pair.image_id1, pair.image_id2, pair.turn.deg),
            false => (pair.image_id2, pair.image_id1, wrap(-pair.turn.deg)),
        };
        if let Some(roll) = pair.roll {
            if angle_between(turn_deg, -f64::from(roll.degrees())) > ROLL_TOLERANCE_DEG {
                verdicts.push((index, Verdict::RollDisagrees { turn_deg, roll }));
                continue;
            }
        }
        let (Some(&(root_e, heading_e)), Some(&(root_l, heading_l))) = (headings.get(&earlier), headings.get(&later))
        else {
            continue;
        };
        let offset = wrap(turn_deg - (heading_l - heading_e));
        groups.entry((root_e, root_l)).or_default().push(Offset { index, deg: offset, weight: pair.inliers as f64 });
        verdicts.push((index, Verdict::Consistent));
    }
    Votes { headings, verdicts, groups }
}

/// The offset most of `members`' weight agrees on (within `tolerance_deg`),
/// if it holds more than half of the weight and at least two pairs.
fn consensus(members: &[Offset], tolerance_deg: f64) -> Option<f64> {
    let offsets: Vec<f64> = members.iter().map(|m| m.deg).collect();
    let weights: Vec<f64> = members.iter().map(|m| m.weight).collect();
    let (consensus, support) = mode(&offsets, &weights, tolerance_deg);
    let supporters = offsets.iter().filter(|o| angle_between(**o, consensus) <= tolerance_deg).count();
    (supporters >= 2 && support > 0.5 * weights.iter().sum::<f64>()).then_some(consensus)
}

/// The verdict on every cross-visit pair of `pairs` (in their order; pairs
/// within a visit are the chains). `visit_of` gives each image's visit (its
/// place in the order of visits); an image without one is not checked.
pub fn check_cross_pairs(
    pairs: &[CheckedPair],
    visit_of: &BTreeMap<ImageId, usize>,
    tolerance_deg: f64,
) -> Vec<(usize, Verdict)> {
    let Votes { mut verdicts, groups, .. } = votes(pairs, visit_of);
    for members in groups.values() {
        let Some(consensus) = consensus(members, tolerance_deg) else { continue };
        for member in members.iter().filter(|m| angle_between(m.deg, consensus) > tolerance_deg) {
            if let Some(v) = verdicts.iter_mut().find(|(i, _)| *i == member.index) {
                v.1 = Verdict::OffConsensus { offset_deg: member.deg, consensus_deg: consensus };
            }
        }
    }
    verdicts.sort_by_key(|v| v.0);
    verdicts
}

/// The turns that the verified pairs predict for pairs not matched yet: each
/// image's heading within its visit, and the heading offset that the
/// cross-visit pairs between two parts of two visits agree on (the
/// consensus [`check_cross_pairs`] holds pairs to).
#[derive(Clone, Debug, Default)]
pub struct Predictor {
    headings: BTreeMap<ImageId, (ImageId, f64)>,
    offsets: BTreeMap<(ImageId, ImageId), f64>,
}

impl Predictor {
    pub fn new(pairs: &[CheckedPair], visit_of: &BTreeMap<ImageId, usize>, tolerance_deg: f64) -> Predictor {
        let Votes { headings, groups, .. } = votes(pairs, visit_of);
        let offsets = groups.iter().filter_map(|(parts, m)| Some((*parts, consensus(m, tolerance_deg)?))).collect();
        Predictor { headings, offsets }
    }

    /// The two connected parts a pair from `earlier` (an image of the earlier
    /// visit) to `later` joins: the pairs whose offsets are voted together.
    pub fn parts(&self, earlier: ImageId, later: ImageId) -> Option<(ImageId, ImageId)> {
        Some((self.headings.get(&earlier)?.0, self.headings.get(&later)?.0))
    }

    /// The turn (degrees, as [`Turn::deg`]) from `earlier` to `later` that
    /// the consensus of their parts implies; `None` without a consensus.
    pub fn turn(&self, earlier: ImageId, later: ImageId) -> Option<f64> {
        let (&(root_e, heading_e), &(root_l, heading_l)) = (self.headings.get(&earlier)?, self.headings.get(&later)?);
        let offset = self.offsets.get(&(root_e, root_l))?;
        Some(wrap(offset + heading_l - heading_e))
    }
}

/// Each image's heading (degrees) within its visit, relative to the root of
/// its connected part (the part's smallest image id): the turns of the
/// strongest pairs within the visit (a maximum spanning forest by inliers),
/// chained from the root.
fn headings(pairs: &[CheckedPair], visit_of: &BTreeMap<ImageId, usize>) -> BTreeMap<ImageId, (ImageId, f64)> {
    let mut intra: Vec<&CheckedPair> = pairs
        .iter()
        .filter(|p| p.kind == PairKind::Intra)
        .filter(|p| visit_of.get(&p.image_id1).is_some_and(|v| visit_of.get(&p.image_id2) == Some(v)))
        .collect();
    intra.sort_by(|a, b| b.inliers.cmp(&a.inliers).then((a.image_id1, a.image_id2).cmp(&(b.image_id1, b.image_id2))));
    // Kruskal: the strongest pairs that join two parts.
    let mut parent: BTreeMap<ImageId, ImageId> = visit_of.keys().map(|id| (*id, *id)).collect();
    fn find(parent: &mut BTreeMap<ImageId, ImageId>, id: ImageId) -> ImageId {
        let mut root = id;
        while let Some(&p) = parent.get(&root).filter(|p| **p != root) {
            root = p;
        }
        parent.insert(id, root);
        root
    }
    let mut edges: BTreeMap<ImageId, Vec<(ImageId, f64)>> = BTreeMap::new();
    for pair in intra {
        let (a, b) = (find(&mut parent, pair.image_id1), find(&mut parent, pair.image_id2));
        if a != b {
            parent.insert(a.max(b), a.min(b));
            edges.entry(pair.image_id1).or_default().push((pair.image_id2, pair.turn.deg));
            edges.entry(pair.image_id2).or_default().push((pair.image_id1, -pair.turn.deg));
        }
    }
    let mut headings = BTreeMap::new();
    for &root in visit_of.keys() {
        if headings.contains_key(&root) {
            continue;
        }
        headings.insert(root, (root, 0.0));
        let mut stack = vec![root];
        while let Some(at) = stack.pop() {
            let heading = headings[&at].1;
            for &(next, turn_deg) in edges.get(&at).into_iter().flatten() {
                if let std::collections::btree_map::Entry::Vacant(entry) = headings.entry(next) {
                    entry.insert((root, wrap(heading + turn_deg)));
                    stack.push(next);
                }
            }
        }
    }
    headings
}

/// The weighted circular mode of `angles` (degrees): the angle whose window
/// of `window_deg` either side holds the most weight (candidates: the angles
/// themselves, the first on ties), refined to the weighted circular mean of
/// that window; with the weight within `window_deg` of the refined angle.
fn mode(angles: &[f64], weights: &[f64], window_deg: f64) -> (f64, f64) {
    let support = |centre: f64| -> f64 {
        angles.iter().zip(weights).filter(|(a, _)| angle_between(**a, centre) <= window_deg).map(|(_, w)| w).sum()
    };
    let mut best = (0.0, f64::NEG_INFINITY);
    for &candidate in angles {
        let s = support(candidate);
        if s > best.1 {
            best = (candidate, s);
        }
    }
    let (mut x, mut y) = (0.0, 0.0);
    for (a, w) in angles.iter().zip(weights) {
        if angle_between(*a, best.0) <= window_deg {
            x += w * a.to_radians().cos();
            y += w * a.to_radians().sin();
        }
    }
    let refined = if x == 0.0 && y == 0.0 { best.0 } else { wrap(y.atan2(x).to_degrees()) };
    (refined, support(refined))
}

/// `deg` in [0, 360).
fn wrap(deg: f64) -> f64 {
    deg.rem_euclid(360.0)
}

/// The smallest angle (degrees, [0, 180]) between two directions.
pub(crate) fn angle_between(a: f64, b: f64) -> f64 {
    let d = wrap(a - b);
    d.min(360.0 - d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of points and the same points turned by `deg` about (320, 240)
    /// and moved, with every `wrong_every`-th match replaced by a far point.
    fn turned(deg: f64, wrong_every: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let (s, c) = deg.to_radians().sin_cos();
        let mut a = Vec::new();
        let mut b = Vec::new();
        for k in 0..60 {
            let p = [40.0 + 97.0 * (k % 6) as f64, 30.0 + 43.0 * (k / 6) as f64];
            let q = [p[0] - 320.0, p[1] - 240.0];
            let mut t = [c * q[0] - s * q[1] + 330.0, s * q[0] + c * q[1] + 230.0];
            if k % wrong_every == 0 {
                t = [((k * 7919) % 640) as f64, ((k * 104_729) % 480) as f64];
            }
            a.push(p);
            b.push(t);
        }
        (a, b)
    }

    #[test]
    fn turn_is_found_among_wrong_matches() {
        for deg in [0.0, 37.0, 95.0, 183.0, 271.0] {
            let (a, b) = turned(deg, 3);
            let found = turn(&a, &b).unwrap();
            assert!(angle_between(found.deg, deg) < 2.0, "{deg}: {found:?}");
            assert!(found.agreement > 0.3, "{deg}: {found:?}");
        }
        assert_eq!(turn(&[[0.0, 0.0]; 3], &[[1.0, 1.0]; 3]), None);
    }

    fn pair(image_id1: ImageId, image_id2: ImageId, kind: PairKind, deg: f64, roll: Option<Roll>) -> CheckedPair {
        CheckedPair { image_id1, image_id2, kind, turn: Turn { deg, agreement: 1.0 }, inliers: 50, roll }
    }

    #[test]
    fn a_pair_off_its_visits_consensus_or_its_roll_is_caught() {
        // Visit 0: images 1-3 (image 2 turned by 180 from image 1, a lawnmower's return line);
        // visit 1: images 11-13, headed 95 degrees from visit 0.
        let visit_of: BTreeMap<ImageId, usize> = [(1, 0), (2, 0), (3, 0), (11, 1), (12, 1), (13, 1)].into();
        let mut pairs = vec![
            pair(1, 2, PairKind::Intra, 180.0, None),
            pair(2, 3, PairKind::Intra, 180.0, None),
            pair(11, 12, PairKind::Intra, 0.0, None),
            pair(12, 13, PairKind::Intra, 2.0, None),
            pair(1, 11, PairKind::Cross, 95.0, Some(Roll::R270)),
            pair(2, 12, PairKind::Cross, 275.0, Some(Roll::R90)),
            pair(3, 13, PairKind::Cross, 97.0, Some(Roll::R270)),
            // Matched at roll 90 but turned by 202: the roll's matches do not show the place.
            pair(1, 13, PairKind::Cross, 202.0, Some(Roll::R90)),
            // Agrees with its roll, not with the visits: image 2 is turned by 180 from image 1.
            pair(2, 11, PairKind::Cross, 90.0, Some(Roll::R270)),
            // Stored the other way round (image 1 of the pair in the later visit).
            pair(13, 2, PairKind::Cross, wrap(-277.0), Some(Roll::R90)),
        ];
        let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG);
        let consistent: Vec<usize> = verdicts.iter().filter(|v| v.1.is_consistent()).map(|v| v.0).collect();
        assert_eq!(consistent, vec![4, 5, 6, 9]);
        assert!(matches!(verdicts[3].1, Verdict::RollDisagrees { roll: Roll::R90, .. }), "{verdicts:?}");
        assert!(matches!(verdicts[4].1, Verdict::OffConsensus { .. }), "{verdicts:?}");
        // Without the chains within the visits, each image is its own part: nothing to vote on.
        pairs.retain(|p| p.kind == PairKind::Cross);
        let alone = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG);
        assert_eq!(alone.iter().filter(|v| v.1.is_consistent()).count(), 5);
    }
}
