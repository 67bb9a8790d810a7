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
//! Two rules on the turn of the pair's inlier matches, and two on where they
//! put the other image:
//! 1. **The roll agrees**: a learned pair matched at roll `r` must turn by
//!    `-r` within 45 degrees (else another roll was the nearer one, and the
//!    matches do not show what the roll search chose).
//! 2. **The offset agrees**: between two connected parts of two visits, the
//!    offsets implied by their pairs are voted (weighted by inliers; a pair
//!    matched at a predicted roll agrees by construction and does not vote);
//!    when one offset holds more than half of the weight and at least two
//!    pairs, a pair more than `tolerance_deg` away from it is off the
//!    consensus. Around a cycle of visits the offsets must add up: the clear
//!    ones (three pairs or more, twice the weight for as against) are chained
//!    through the surest, and a pair of visits whose own offset disagrees with
//!    the chain, or that has none, is held to the chain's.
//! 3. **The navigation agrees** (when both images have a navigated position):
//!    a downward camera's centre sits above the ground its image centre shows,
//!    so the pair's matches say where each image sees the other's centre
//!    ([`Motion`]). Each visit's pairs calibrate how navigation maps to its
//!    pixels (metres per pixel, each image's heading in the navigation frame,
//!    and the frame's handedness: ENU and NED are mirror images), and a
//!    cross-visit pair whose matches put the other camera farther from where
//!    navigation puts it than 3 standard deviations of the two positions (at
//!    least 64 pixels' worth) is off the navigation. Wrong pairs of a
//!    planar seabed pass rules 1 and 2 when they happen to turn right; they
//!    rarely also move right. When most of two visits' pairs are off, and by
//!    about the same distance, it is the navigation that is (a visit's
//!    position fix): none of them is.
//! 4. **The loops close** (no navigation needed): a cross-visit pair, another
//!    one near it, and the two visits' own pairs between their images make a
//!    loop of [`Similarity`]s that must come back to where it started. Right
//!    pairs close their loops with each other; wrong pairs, each wrong in its
//!    own way, miss them. A pair whose loops through trusted pairs (pairs
//!    whose loops mostly close) mostly miss is off its loops.
//!
//! Pure: pairs in, verdicts out; the pipeline sets the rejected pairs aside
//! in the store.

use std::collections::BTreeMap;

use revisit_core::{ImageId, PairKind, Reconstruction, Roll};

/// How far (degrees) a pair's implied offset may be from its visits' consensus, by default.
pub const DEFAULT_CONSISTENCY_TOLERANCE_DEG: f64 = 30.0;

/// How far a pair may put the other camera from its navigated position, by
/// default, in standard deviations of the two positions.
pub const DEFAULT_NAVIGATION_TOLERANCE_SIGMAS: f64 = 3.0;

/// How far a loop of pairs may miss, by default, as a share of the image
/// diagonal (100 pixels in a VGA image).
pub const DEFAULT_LOOP_TOLERANCE: f64 = 0.125;

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

/// The similarity a pair's matches show from image 1's pixels to image 2's:
/// `p2 = scale * turned(p1) + move_px`, turned by `turn_deg` (as [`Turn::deg`]).
/// A downward camera over a near-flat seabed sees the ground move so between
/// two images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub turn_deg: f64,
    pub move_px: [f64; 2],
}

impl Similarity {
    pub const IDENTITY: Similarity = Similarity { scale: 1.0, turn_deg: 0.0, move_px: [0.0, 0.0] };

    /// Where image 2 sees image 1's pixel `p`.
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        let q = self.turned(p);
        [q[0] + self.move_px[0], q[1] + self.move_px[1]]
    }

    fn turned(&self, p: [f64; 2]) -> [f64; 2] {
        let (sin, cos) = self.turn_deg.to_radians().sin_cos();
        [self.scale * (cos * p[0] - sin * p[1]), self.scale * (sin * p[0] + cos * p[1])]
    }

    /// From image 2's pixels back to image 1's.
    pub fn inverse(&self) -> Similarity {
        let back = Similarity { scale: 1.0 / self.scale, turn_deg: wrap(-self.turn_deg), move_px: [0.0, 0.0] };
        let m = back.turned(self.move_px);
        Similarity { move_px: [-m[0], -m[1]], ..back }
    }

    /// This similarity, then `next` (from image 2 on to a third image).
    pub fn then(&self, next: &Similarity) -> Similarity {
        let m = next.apply(self.move_px);
        Similarity { scale: self.scale * next.scale, turn_deg: wrap(self.turn_deg + next.turn_deg), move_px: m }
    }
}

/// The [`Similarity`] of matched points turned by `turn_deg` (as [`turn`]
/// finds it): its scale the median length ratio of the point pairs that agree
/// with the turn, its move the per-axis median of the matches' residual moves
/// (robust to the wrong matches a verified pair carries). `None` with fewer
/// than 8 agreeing point pairs.
pub fn similarity(points1: &[[f64; 2]], points2: &[[f64; 2]], turn_deg: f64) -> Option<Similarity> {
    let n = points1.len().min(points2.len());
    let mut ratios = Vec::new();
    for k in 0..n {
        for step in [1, 3, 7] {
            let j = (k + step) % n;
            let d1 = [points1[j][0] - points1[k][0], points1[j][1] - points1[k][1]];
            let d2 = [points2[j][0] - points2[k][0], points2[j][1] - points2[k][1]];
            let (l1, l2) = (d1[0].hypot(d1[1]), d2[0].hypot(d2[1]));
            if j == k || l1 < MIN_SPAN_PX || l2 < MIN_SPAN_PX {
                continue;
            }
            let change = d2[1].atan2(d2[0]).to_degrees() - d1[1].atan2(d1[0]).to_degrees();
            if angle_between(change, turn_deg) <= AGREEMENT_DEG {
                ratios.push(l2 / l1);
            }
        }
    }
    if ratios.len() < 8 {
        return None;
    }
    let turned = Similarity { scale: median(ratios), turn_deg, move_px: [0.0, 0.0] };
    let moved: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let q = turned.apply(points1[k]);
            [points2[k][0] - q[0], points2[k][1] - q[1]]
        })
        .collect();
    let move_px = [median(moved.iter().map(|m| m[0]).collect()), median(moved.iter().map(|m| m[1]).collect())];
    Some(Similarity { move_px, ..turned })
}

/// How a pair's matches move image 1 onto image 2, with the images' centres
/// (pixels), which say where each image sees the other.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    pub similarity: Similarity,
    pub centre1: [f64; 2],
    pub centre2: [f64; 2],
}

impl Motion {
    /// Where image 1 sees image 2's centre, pixels from its own centre.
    pub fn other_in_1(&self) -> [f64; 2] {
        let p = self.similarity.inverse().apply(self.centre2);
        [p[0] - self.centre1[0], p[1] - self.centre1[1]]
    }

    /// Where image 2 sees image 1's centre, pixels from its own centre.
    pub fn other_in_2(&self) -> [f64; 2] {
        let p = self.similarity.apply(self.centre1);
        [p[0] - self.centre2[0], p[1] - self.centre2[1]]
    }

    /// The same motion seen from image 2.
    fn reversed(&self) -> Motion {
        Motion { similarity: self.similarity.inverse(), centre1: self.centre2, centre2: self.centre1 }
    }
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n % 2 {
        1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// A verified pair as the check sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckedPair {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub kind: PairKind,
    /// From image 1 to image 2.
    pub turn: Turn,
    /// How the matches move image 1 onto image 2.
    pub motion: Option<Motion>,
    /// Verified inliers: the pair's weight in the vote.
    pub inliers: usize,
    /// For a learned cross-visit pair: the roll at which the later visit's image was matched.
    pub roll: Option<Roll>,
    /// Matched at the roll its visits' consensus predicted, and kept because it turns as
    /// predicted: it agrees with that consensus by construction, so it does not vote on it.
    pub predicted: bool,
}

/// What the check says of a cross-visit pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Agrees with its roll and with its visits' consensus (or there is no consensus to check).
    Consistent,
    /// Consistent, and confirmed by its loops (rule 4): `closed` of them close, and more close
    /// than miss. A confirmed pair is evidence of where its two images sit, against which a
    /// model can be checked ([`placement_error_px`]).
    Confirmed { closed: usize },
    /// Its matches turn the later image by `turn_deg`, not by about `-roll`.
    RollDisagrees { turn_deg: f64, roll: Roll },
    /// Its offset between the two visits is `offset_deg`; the other pairs agree on `consensus_deg`.
    OffConsensus { offset_deg: f64, consensus_deg: f64 },
    /// Its matches put the other camera `miss_m` from where navigation puts it; `tolerance_m` allowed.
    OffNavigation { miss_m: f64, tolerance_m: f64 },
    /// Of the loops it closes with the trusted cross-visit pairs near it (or,
    /// with none near it, with any), `missed` miss and `closed` close.
    OffLoops { missed: usize, closed: usize },
    /// Rule 5: searched, its two visits' pairs show no clear heading offset (not even through
    /// other visits), no loop confirms it, and it holds `inliers`, fewer than
    /// [`UNLINKED_MIN_INLIERS`] (whatever rules 1 to 4 said of it), or more but rules 1 to 4
    /// find it `inconsistent`.
    Unlinked { inliers: usize, inconsistent: bool },
}

impl Verdict {
    pub fn is_consistent(&self) -> bool {
        matches!(self, Verdict::Consistent | Verdict::Confirmed { .. })
    }
}

/// The heading offset between two visits that one cross-visit pair implies.
struct Offset {
    /// Into the pairs checked.
    index: usize,
    deg: f64,
    /// The pair's inliers; 0 for a pair that does not vote ([`CheckedPair::predicted`]).
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
        let weight = if pair.predicted { 0.0 } else { pair.inliers as f64 };
        groups.entry((root_e, root_l)).or_default().push(Offset { index, deg: offset, weight });
        verdicts.push((index, Verdict::Consistent));
    }
    Votes { headings, verdicts, groups }
}

/// The offset most of the voting `members`' weight agrees on (within
/// `tolerance_deg`), if it holds more than half of the weight and at least
/// two voters.
fn consensus(members: &[Offset], tolerance_deg: f64) -> Option<Consensus> {
    let voters: Vec<&Offset> = members.iter().filter(|m| m.weight > 0.0).collect();
    let offsets: Vec<f64> = voters.iter().map(|m| m.deg).collect();
    let weights: Vec<f64> = voters.iter().map(|m| m.weight).collect();
    let (deg, support) = mode(&offsets, &weights, tolerance_deg);
    let supporters = offsets.iter().filter(|o| angle_between(**o, deg) <= tolerance_deg).count();
    let against = weights.iter().sum::<f64>() - support;
    (supporters >= 2 && support > against).then_some(Consensus { deg, support, against, supporters })
}

/// An offset most of the votes between two parts agree on, with the weight for and against it.
#[derive(Clone, Copy, Debug)]
struct Consensus {
    deg: f64,
    support: f64,
    against: f64,
    /// The voting pairs that agree with it.
    supporters: usize,
}

impl Consensus {
    /// Clear enough to predict pairs from: at least [`MIN_CLEAR_SUPPORTERS`] pairs agree, with at
    /// least twice the weight for as against. A narrower one (two wrong pairs that happen to
    /// agree, one right and one wrong) waits for more votes.
    fn is_clear(&self) -> bool {
        self.supporters >= MIN_CLEAR_SUPPORTERS && self.support >= 2.0 * self.against
    }
}

/// Pairs that must agree on an offset before it predicts. Two are not enough: on the scaling
/// study's 3 x 64 survey two wrong pairs of the first and third visits (274 and 441 px off their
/// true epipolar lines) agreed on a roll with nothing against them; chained with the first and
/// second visits' offset, they predicted every pair of the second and third at a wrong roll, and
/// the third visit was left out.
const MIN_CLEAR_SUPPORTERS: usize = 3;

/// The heading offsets between connected parts of visits that their clear
/// consensuses ([`Consensus::is_clear`]) imply together. Each measures one
/// offset between two parts; around a cycle of parts (three visits, or two
/// parts of a visit and a part of another) the offsets must add up, and where
/// they do not, the surer ones win: the offsets are chained through a maximum
/// spanning forest of the consensuses by their margins (weight for less
/// weight against), as the headings within a visit are through its strongest
/// pairs. So two parts linked through a third have an offset before their
/// own pairs agree on one (visits 1 and 2 through visit 3), and a consensus
/// that disagrees with two clearer ones around a cycle gives way to them.
#[derive(Clone, Debug, Default)]
struct PartFrames {
    /// Each part (by its root image) in the frame of its group of linked parts: `(group root, heading)`.
    frames: BTreeMap<ImageId, (ImageId, f64)>,
}

impl PartFrames {
    fn new(groups: &BTreeMap<(ImageId, ImageId), Vec<Offset>>, tolerance_deg: f64) -> PartFrames {
        let links: Vec<Link> = groups
            .iter()
            .filter_map(|(&(earlier, later), members)| {
                let consensus = consensus(members, tolerance_deg).filter(Consensus::is_clear)?;
                Some(Link {
                    from: earlier,
                    to: later,
                    deg: consensus.deg,
                    weight: consensus.support - consensus.against,
                })
            })
            .collect();
        PartFrames { frames: chain_spanning_forest([], links) }
    }

    /// The heading offset from part `earlier` to part `later` (as [`Offset::deg`]), if they are linked.
    fn offset(&self, earlier: ImageId, later: ImageId) -> Option<f64> {
        let ((group_e, heading_e), (group_l, heading_l)) = (self.frames.get(&earlier)?, self.frames.get(&later)?);
        (group_e == group_l).then(|| wrap(heading_l - heading_e))
    }
}

/// Rule 5: the fewest inliers of a pair kept between two visits whose pairs show no clear
/// heading offset. Such visits were searched pair by pair and no three pairs agreed: on the
/// surveys measured they could not be linked (a storm's first visit; a visit of another site),
/// and every pair verified between them but one held 30 to 44 inliers and showed another place
/// (8 of 8 at `--change storm`, seed 5; 5 of 5 for another site). Right pairs of linked visits
/// hold from 30 up, most of them over 60; a visit with little overlap keeps its strong pairs,
/// unless another rule finds them inconsistent: with each image's colours stretched, 3 of the 12
/// pairs verified between two sites held 45 to 57 inliers, and every loop they made missed.
pub const UNLINKED_MIN_INLIERS: usize = 45;

/// The verdict on every cross-visit pair of `pairs` (in their order; pairs
/// within a visit are the chains). `visit_of` gives each image's visit (its
/// place in the order of visits); an image without one is not checked.
/// `navigation` holds the images with a navigated position (rule 3; none:
/// not checked). A pair off the navigation is said so whatever the other rules
/// say: navigation is evidence from outside the images; unless most of its two
/// visits' checked pairs are off too, by about the same distance, which is the
/// navigation off (a visit's position fix), not the pairs. The pairs all three
/// rules pass then close loops with each other (rule 4;
/// `loop_tolerance` 0: not checked). Of the searched pairs no loop
/// confirms, those between visits with no clear offset and with fewer than
/// [`UNLINKED_MIN_INLIERS`], or inconsistent by rules 1 to 4, are
/// [`Verdict::Unlinked`] (rule 5).
pub fn check_cross_pairs(
    pairs: &[CheckedPair],
    visit_of: &BTreeMap<ImageId, usize>,
    tolerance_deg: f64,
    navigation: &Navigation,
    loop_tolerance: f64,
) -> Vec<(usize, Verdict)> {
    let Votes { mut verdicts, groups, headings } = votes(pairs, visit_of);
    let frames = PartFrames::new(&groups, tolerance_deg);
    for (&(earlier, later), members) in &groups {
        // The clear consensuses' offset, or the pairs' own narrow one.
        let own = || consensus(members, tolerance_deg).map(|c| c.deg);
        let Some(consensus) = frames.offset(earlier, later).or_else(own) else { continue };
        for member in members.iter().filter(|m| angle_between(m.deg, consensus) > tolerance_deg) {
            if let Some(v) = verdicts.iter_mut().find(|(i, _)| *i == member.index) {
                v.1 = Verdict::OffConsensus { offset_deg: member.deg, consensus_deg: consensus };
            }
        }
    }
    let footings = footings(pairs, visit_of, &navigation.positions);
    // Each checked cross-visit pair's miss, by the two visits it joins.
    let mut misses: BTreeMap<(usize, usize), Vec<Miss>> = BTreeMap::new();
    for (index, pair) in pairs.iter().enumerate().filter(|(_, p)| p.kind == PairKind::Cross) {
        let Some((miss_m, tolerance_m)) = navigation_miss(pair, &footings, visit_of, navigation) else { continue };
        let (Some(&v1), Some(&v2)) = (visit_of.get(&pair.image_id1), visit_of.get(&pair.image_id2)) else { continue };
        misses.entry((v1.min(v2), v1.max(v2))).or_default().push(Miss { index, miss_m, tolerance_m });
    }
    for checked in misses.values() {
        let off: Vec<&Miss> = checked.iter().filter(|m| m.miss_m > m.tolerance_m).collect();
        if navigation_is_off(checked, &off) {
            continue;
        }
        for &&Miss { index, miss_m, tolerance_m } in &off {
            let verdict = Verdict::OffNavigation { miss_m, tolerance_m };
            match verdicts.iter_mut().find(|(i, _)| *i == index) {
                Some(v) => v.1 = verdict,
                None => verdicts.push((index, verdict)),
            }
        }
    }
    verdicts.sort_by_key(|v| v.0);
    if loop_tolerance > 0.0 {
        let voters: Vec<usize> = verdicts.iter().filter(|v| v.1.is_consistent()).map(|v| v.0).collect();
        for (index, verdict) in loop_verdicts(pairs, visit_of, &voters, loop_tolerance) {
            if let Ok(at) = verdicts.binary_search_by_key(&index, |v| v.0) {
                verdicts[at].1 = verdict;
            }
        }
    }
    for (index, verdict) in &mut verdicts {
        let pair = &pairs[*index];
        let (Some((part1, _)), Some((part2, _))) = (headings.get(&pair.image_id1), headings.get(&pair.image_id2))
        else {
            continue;
        };
        let linked = frames.offset(*part1, *part2).is_some();
        let (confirmed, inconsistent) = (matches!(verdict, Verdict::Confirmed { .. }), !verdict.is_consistent());
        if !linked && !confirmed && !pair.predicted && (pair.inliers < UNLINKED_MIN_INLIERS || inconsistent) {
            *verdict = Verdict::Unlinked { inliers: pair.inliers, inconsistent };
        }
    }
    verdicts
}

/// A pair whose loops close this many times or more, and more often than
/// they miss, is trusted by rule 4; a pair with no trusted pair near it must
/// miss this many loops (and close none) to be off them: one miss between two
/// pairs does not say which of them is wrong.
const TRUSTED_LOOPS: usize = 2;

/// Rule 4: the loops the cross-visit pairs `voters` (indices into `pairs`)
/// close with each other. A cross-visit pair from image `a` to image `b`, and
/// another from `a'` to `b'`, where `a'` is `a` or an image of `a`'s visit
/// verified with it (and `b'` likewise), make a loop: `a` to `a'` to `b'` to
/// `b` must land where the pair itself takes `a`'s centre, within
/// `tolerance` of `b`'s diagonal. Wrong pairs rarely agree with each other,
/// so a pair is trusted when at least [`TRUSTED_LOOPS`] of its loops close
/// and more close than miss; a pair whose loops through trusted pairs miss
/// more than close, or, with no trusted pair near it, which closes no loop
/// and misses at least [`TRUSTED_LOOPS`], is [`Verdict::OffLoops`]. A pair
/// with no loop is not judged.
fn loop_verdicts(
    pairs: &[CheckedPair],
    visit_of: &BTreeMap<ImageId, usize>,
    voters: &[usize],
    tolerance: f64,
) -> Vec<(usize, Verdict)> {
    // Each visit's own pairs, both ways.
    let mut within: BTreeMap<(ImageId, ImageId), Similarity> = BTreeMap::new();
    for pair in pairs.iter().filter(|p| p.kind == PairKind::Intra) {
        let Some(motion) = pair.motion else { continue };
        if visit_of.get(&pair.image_id1).is_some_and(|v| visit_of.get(&pair.image_id2) == Some(v)) {
            within.insert((pair.image_id1, pair.image_id2), motion.similarity);
            within.insert((pair.image_id2, pair.image_id1), motion.similarity.inverse());
        }
    }
    let mut near: BTreeMap<ImageId, Vec<ImageId>> = BTreeMap::new();
    for &(a, b) in within.keys() {
        near.entry(a).or_default().push(b);
    }
    let step = |from: ImageId, to: ImageId| -> Option<Similarity> {
        match from == to {
            true => Some(Similarity::IDENTITY),
            false => within.get(&(from, to)).copied(),
        }
    };
    // The voters from each of their images: (voter, other image, motion from this image).
    let mut from_image: BTreeMap<ImageId, Vec<(usize, ImageId, Motion)>> = BTreeMap::new();
    for &index in voters {
        let pair = &pairs[index];
        let Some(motion) = pair.motion else { continue };
        from_image.entry(pair.image_id1).or_default().push((index, pair.image_id2, motion));
        from_image.entry(pair.image_id2).or_default().push((index, pair.image_id1, motion.reversed()));
    }
    // Each voter's loops: (the other voter, whether the loop closes).
    let mut loops: BTreeMap<usize, Vec<(usize, bool)>> = BTreeMap::new();
    for &index in voters {
        let pair = &pairs[index];
        let (Some(motion), Some(visit_b)) = (pair.motion, visit_of.get(&pair.image_id2)) else { continue };
        let (a, b) = (pair.image_id1, pair.image_id2);
        let seen = motion.similarity.apply(motion.centre1);
        let allowed_px = tolerance * 2.0 * length(motion.centre2);
        let mut closes = Vec::new();
        for a2 in std::iter::once(a).chain(near.get(&a).into_iter().flatten().copied()) {
            let Some(to_a2) = step(a, a2) else { continue };
            for &(other, b2, other_motion) in from_image.get(&a2).into_iter().flatten() {
                if other == index || visit_of.get(&b2) != Some(visit_b) {
                    continue;
                }
                let Some(to_b) = step(b2, b) else { continue };
                let around = to_a2.then(&other_motion.similarity).then(&to_b).apply(motion.centre1);
                closes.push((other, length([around[0] - seen[0], around[1] - seen[1]]) <= allowed_px));
            }
        }
        loops.insert(index, closes);
    }
    let count = |index: usize, among: &dyn Fn(usize) -> bool| -> (usize, usize) {
        let through: Vec<bool> = loops[&index].iter().filter(|(o, _)| among(*o)).map(|(_, c)| *c).collect();
        let closed = through.iter().filter(|c| **c).count();
        (closed, through.len() - closed)
    };
    // (closed, missed) over all of each voter's loops.
    let all: BTreeMap<usize, (usize, usize)> = loops.keys().map(|&i| (i, count(i, &|_| true))).collect();
    let trusted: std::collections::BTreeSet<usize> = all
        .iter()
        .filter(|(_, &(closed, missed))| closed >= TRUSTED_LOOPS && closed > missed)
        .map(|(&i, _)| i)
        .collect();
    let mut verdicts = Vec::new();
    for (&index, &(closed_any, missed_any)) in &all {
        if trusted.contains(&index) {
            verdicts.push((index, Verdict::Confirmed { closed: closed_any }));
            continue;
        }
        let (closed, missed) = count(index, &|o| trusted.contains(&o));
        if missed > closed || (closed + missed == 0 && closed_any == 0 && missed_any >= TRUSTED_LOOPS) {
            let (closed, missed) = if closed + missed > 0 { (closed, missed) } else { (closed_any, missed_any) };
            verdicts.push((index, Verdict::OffLoops { missed, closed }));
        }
    }
    verdicts
}

/// An image's navigated position across the ground: the navigation frame's
/// x and y (metres; z is the vertical in ENU and NED alike), with its
/// standard deviation (metres, both axes together).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Navigated {
    pub xy_m: [f64; 2],
    pub sigma_m: f64,
}

/// The navigation rule 3 holds pairs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Navigation {
    /// The images with a navigated position.
    pub positions: BTreeMap<ImageId, Navigated>,
    /// How far a pair may put the other camera from its navigated position,
    /// in standard deviations of the two positions; 0 turns the rule off.
    pub tolerance_sigmas: f64,
}

/// Shifts shorter than this (pixels) give no reliable direction or scale.
const MIN_SHIFT_PX: f64 = 50.0;

/// The smallest tolerance of rule 3, pixels (a tenth of a VGA image): the
/// shift is a downward camera's, and cameras tilt.
const MIN_NAVIGATION_TOLERANCE_PX: f64 = 64.0;

/// How one visit's navigation maps to its images' pixels: a move of `w`
/// metres shows as `heading`-turned (and, `mirrored`, reflected) `w /
/// metres_per_px` pixels in an image.
struct Footing {
    metres_per_px: f64,
    mirrored: bool,
    /// Radians, per image with a pair to fix it.
    headings: BTreeMap<ImageId, f64>,
}

impl Footing {
    /// Where `image` should see a point `w_m` metres away from its own centre's ground.
    fn predicted_px(&self, image: ImageId, w_m: [f64; 2]) -> Option<[f64; 2]> {
        let (sin, cos) = self.headings.get(&image)?.sin_cos();
        let [x, y] = [w_m[0] / self.metres_per_px, w_m[1] / self.metres_per_px];
        Some(match self.mirrored {
            true => [cos * x + sin * y, sin * x - cos * y],
            false => [cos * x - sin * y, sin * x + cos * y],
        })
    }
}

/// One image of a verified pair within a visit: where it sees the other
/// image's centre (pixels from its own) and where navigation puts the other
/// camera (metres from its own).
struct Sample {
    image: ImageId,
    seen_px: [f64; 2],
    away_m: [f64; 2],
}

/// A handedness clearly fits better when its headings cohere by this factor more.
const HANDEDNESS_MARGIN: f64 = 1.02;

/// Each visit's [`Footing`] (by visit), from its own verified pairs with
/// navigation on both images (at least 3 with a long enough shift; else the
/// visit has none), for each handedness of the navigation frame the pairs
/// cannot tell apart: one when a handedness fits clearly better over all
/// visits, both when every track is one straight line.
fn footings(
    pairs: &[CheckedPair],
    visit_of: &BTreeMap<ImageId, usize>,
    navigation: &BTreeMap<ImageId, Navigated>,
) -> Vec<BTreeMap<usize, Footing>> {
    let mut samples: BTreeMap<usize, Vec<Sample>> = BTreeMap::new();
    for pair in pairs.iter().filter(|p| p.kind == PairKind::Intra) {
        let (Some(motion), Some(n1), Some(n2)) =
            (pair.motion, navigation.get(&pair.image_id1), navigation.get(&pair.image_id2))
        else {
            continue;
        };
        let Some(&visit) = visit_of.get(&pair.image_id1).filter(|v| visit_of.get(&pair.image_id2) == Some(v)) else {
            continue;
        };
        let w = [n2.xy_m[0] - n1.xy_m[0], n2.xy_m[1] - n1.xy_m[1]];
        let (seen_in_1, seen_in_2) = (motion.other_in_1(), motion.other_in_2());
        if length(seen_in_1) >= MIN_SHIFT_PX && length(seen_in_2) >= MIN_SHIFT_PX {
            let list = samples.entry(visit).or_default();
            list.push(Sample { image: pair.image_id1, seen_px: seen_in_1, away_m: w });
            list.push(Sample { image: pair.image_id2, seen_px: seen_in_2, away_m: [-w[0], -w[1]] });
        }
    }
    samples.retain(|_, samples| samples.len() >= 6);
    // Mirrored, a heading is the sum of the pixel and the navigation angles; turned, their
    // difference. The coherence of each image's headings tells the handedness.
    let fit = |mirrored: bool| -> (BTreeMap<usize, Footing>, f64) {
        let mut coherence = 0.0;
        let mut footings = BTreeMap::new();
        for (visit, samples) in &samples {
            let metres_per_px = median(samples.iter().map(|s| length(s.away_m) / length(s.seen_px)).collect());
            let mut sums: BTreeMap<ImageId, [f64; 2]> = BTreeMap::new();
            for Sample { image, seen_px: p, away_m: w } in samples {
                let (a, b) = (p[1].atan2(p[0]), w[1].atan2(w[0]));
                let heading = if mirrored { a + b } else { a - b };
                let sum = sums.entry(*image).or_default();
                (sum[0], sum[1]) = (sum[0] + heading.cos(), sum[1] + heading.sin());
            }
            coherence += sums.values().map(|s| length(*s)).sum::<f64>();
            let headings = sums.into_iter().map(|(image, s)| (image, s[1].atan2(s[0]))).collect();
            footings.insert(*visit, Footing { metres_per_px, mirrored, headings });
        }
        (footings, coherence)
    };
    let ((mirrored, mirrored_fit), (turned, turned_fit)) = (fit(true), fit(false));
    if mirrored_fit > HANDEDNESS_MARGIN * turned_fit {
        vec![mirrored]
    } else if turned_fit > HANDEDNESS_MARGIN * mirrored_fit {
        vec![turned]
    } else {
        vec![mirrored, turned]
    }
}

/// How far (metres) a cross-visit pair's matches put the other camera from
/// where navigation puts it (the worse of the two images that can tell; the
/// better of the handednesses still open), and the tolerance; `None` when
/// neither image can tell.
fn navigation_miss(
    pair: &CheckedPair,
    footings: &[BTreeMap<usize, Footing>],
    visit_of: &BTreeMap<ImageId, usize>,
    navigation: &Navigation,
) -> Option<(f64, f64)> {
    if navigation.tolerance_sigmas <= 0.0 {
        return None;
    }
    let positions = &navigation.positions;
    let (motion, n1, n2) = (pair.motion?, positions.get(&pair.image_id1)?, positions.get(&pair.image_id2)?);
    let w = [n2.xy_m[0] - n1.xy_m[0], n2.xy_m[1] - n1.xy_m[1]];
    let sides = [(pair.image_id1, motion.other_in_1(), w), (pair.image_id2, motion.other_in_2(), [-w[0], -w[1]])];
    let worst = |footings: &BTreeMap<usize, Footing>| -> Option<(f64, f64)> {
        let mut worst: Option<(f64, f64)> = None;
        for (image, seen_px, w_m) in sides {
            let Some(footing) = visit_of.get(&image).and_then(|v| footings.get(v)) else { continue };
            let Some(predicted) = footing.predicted_px(image, w_m) else { continue };
            let miss_m = length([predicted[0] - seen_px[0], predicted[1] - seen_px[1]]) * footing.metres_per_px;
            let floor_m = MIN_NAVIGATION_TOLERANCE_PX * footing.metres_per_px;
            let (m, f) = worst.unwrap_or((0.0, 0.0));
            worst = Some((m.max(miss_m), f.max(floor_m)));
        }
        worst
    };
    let (miss_m, floor_m) = footings.iter().filter_map(worst).min_by(|a, b| a.0.total_cmp(&b.0))?;
    Some((miss_m, (navigation.tolerance_sigmas * n1.sigma_m.hypot(n2.sigma_m)).max(floor_m)))
}

/// How far a cross-visit pair (by its index) puts the other camera from its
/// navigated position, and how far it may.
#[derive(Clone, Copy, Debug)]
struct Miss {
    index: usize,
    miss_m: f64,
    tolerance_m: f64,
}

/// Whether the pairs of two visits that are off their navigation (`off`, of
/// all the pairs `checked`) show the navigation off rather than themselves:
/// most of them are off, and by about the same distance (the middle half of
/// their misses within one tolerance), as when one visit's position fix is
/// off. Wrong pairs miss each by its own distance.
fn navigation_is_off(checked: &[Miss], off: &[&Miss]) -> bool {
    if 2 * off.len() <= checked.len() {
        return false;
    }
    let mut misses: Vec<f64> = off.iter().map(|o| o.miss_m).collect();
    misses.sort_by(f64::total_cmp);
    let quartile = |q: usize| misses[(q * (misses.len() - 1)) / 4];
    let tolerance = median(off.iter().map(|o| o.tolerance_m).collect());
    quartile(3) - quartile(1) < tolerance
}

/// Matches a model triangulated on fewer than this many points of a pair do
/// not say where the model puts the pair's images.
const MIN_PLACEMENT_POINTS: usize = 5;

/// How far a model puts a pair's matches from each other (pixels): for each
/// match (`[keypoint of image 1, keypoint of image 2]`) whose keypoint in one
/// image the model triangulated, the distance from that point, projected into
/// the other image, to the match's keypoint there; the median over both
/// directions. A model that placed the two images where their matches say
/// gives about the matches' own error; one that placed them at odds with
/// them, far more. `None` when an image is not in the model or fewer than 5
/// matches were triangulated.
pub fn placement_error_px(
    model: &Reconstruction,
    image1: ImageId,
    image2: ImageId,
    matches: &[[u32; 2]],
) -> Option<f64> {
    let (one, two) = (model.images.get(&image1)?, model.images.get(&image2)?);
    let mut errors = Vec::new();
    for m in matches {
        let (Some(o1), Some(o2)) = (one.points2d.get(m[0] as usize), two.points2d.get(m[1] as usize)) else {
            continue;
        };
        for (seen, other, other_image) in [(o1, o2, two), (o2, o1, one)] {
            let Some(point) = seen.point3d_id.and_then(|id| model.points3d.get(&id)) else { continue };
            if let Some(projected) = model.project(other_image, &point.xyz) {
                errors.push((projected - other.xy).norm());
            }
        }
    }
    (errors.len() >= MIN_PLACEMENT_POINTS).then(|| median(errors))
}

/// A confirmed pair's matches may lie this share of the image diagonal apart
/// in a model (40 pixels in a VGA image) and the model still agrees with it.
pub const PLACEMENT_TOLERANCE: f64 = 0.05;

/// How a model holds the confirmed cross-visit pairs between two of its visits.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// Verified cross-visit pairs between the two visits that were mapped, both images in the model.
    #[serde(default)]
    pub joining: usize,
    /// Confirmed pairs with both images in the model and enough of their matches triangulated.
    pub measured: usize,
    /// Of those, the pairs whose matches the model puts within their tolerance of each other.
    pub agreeing: usize,
    /// The median over the measured pairs of how far apart the model puts their matches, pixels.
    pub median_px: f64,
}

impl Placement {
    /// From each measured pair's [`placement_error_px`] and its tolerance (pixels).
    pub fn of(errors: &[(f64, f64)]) -> Placement {
        Placement {
            joining: 0,
            measured: errors.len(),
            agreeing: errors.iter().filter(|(e, tolerance)| e <= tolerance).count(),
            median_px: if errors.is_empty() { 0.0 } else { median(errors.iter().map(|e| e.0).collect()) },
        }
    }

    /// Most of the pairs that confirm the two visits' link disagree with where the model put them.
    pub fn is_suspect(&self) -> bool {
        self.measured >= 2 && 2 * self.agreeing < self.measured
    }

    /// The model joins the two visits by verified pairs, none of which the loops confirm: nothing
    /// checks where it put them (a join made by wrong pairs alone looks the same).
    pub fn is_unchecked(&self) -> bool {
        self.joining > 0 && self.measured == 0
    }
}

fn length(v: [f64; 2]) -> f64 {
    v[0].hypot(v[1])
}

/// The turns that the verified pairs predict for pairs not matched yet: each
/// image's heading within its visit, and the heading offset between two parts
/// of two visits that the clear consensuses imply, directly or through other
/// visits (the offset [`check_cross_pairs`] holds pairs to).
#[derive(Clone, Debug, Default)]
pub struct Predictor {
    headings: BTreeMap<ImageId, (ImageId, f64)>,
    frames: PartFrames,
}

impl Predictor {
    pub fn new(pairs: &[CheckedPair], visit_of: &BTreeMap<ImageId, usize>, tolerance_deg: f64) -> Predictor {
        let Votes { headings, groups, .. } = votes(pairs, visit_of);
        Predictor { headings, frames: PartFrames::new(&groups, tolerance_deg) }
    }

    /// The two connected parts a pair from `earlier` (an image of the earlier
    /// visit) to `later` joins: the pairs whose offsets are voted together.
    pub fn parts(&self, earlier: ImageId, later: ImageId) -> Option<(ImageId, ImageId)> {
        Some((self.headings.get(&earlier)?.0, self.headings.get(&later)?.0))
    }

    /// The turn (degrees, as [`Turn::deg`]) from `earlier` to `later` that
    /// the clear consensuses imply; `None` when no chain of them links their parts.
    pub fn turn(&self, earlier: ImageId, later: ImageId) -> Option<f64> {
        let (&(root_e, heading_e), &(root_l, heading_l)) = (self.headings.get(&earlier)?, self.headings.get(&later)?);
        let offset = self.frames.offset(root_e, root_l)?;
        Some(wrap(offset + heading_l - heading_e))
    }

    /// Whether `pair` is to be matched again at the turn [`Predictor::turn`]
    /// gives it: a learned cross-visit pair that was searched (matched at a
    /// roll of its own choosing, before its visits' offset was settled) and
    /// whose matches turn further than `tolerance_deg` from what the clear
    /// consensuses now imply. Such a pair won at a roll its visits do not
    /// have: two images of different places, or the right two at a wrong
    /// roll, and verification alone cannot tell which. Not a pair that
    /// agrees, that was matched at a prediction, or that no consensus reaches.
    pub fn needs_settling(&self, pair: &CheckedPair, tolerance_deg: f64) -> bool {
        if pair.kind != PairKind::Cross || pair.roll.is_none() || pair.predicted {
            return false;
        }
        self.turn(pair.image_id1, pair.image_id2).is_some_and(|t| angle_between(pair.turn.deg, t) > tolerance_deg)
    }
}

/// Each image's heading (degrees) within its visit, relative to the root of
/// its connected part (the part's smallest image id): the turns of the
/// strongest pairs within the visit (a maximum spanning forest by inliers),
/// chained from the root.
fn headings(pairs: &[CheckedPair], visit_of: &BTreeMap<ImageId, usize>) -> BTreeMap<ImageId, (ImageId, f64)> {
    let links = pairs
        .iter()
        .filter(|p| p.kind == PairKind::Intra)
        .filter(|p| visit_of.get(&p.image_id1).is_some_and(|v| visit_of.get(&p.image_id2) == Some(v)))
        .map(|p| Link { from: p.image_id1, to: p.image_id2, deg: p.turn.deg, weight: p.inliers as f64 })
        .collect();
    chain_spanning_forest(visit_of.keys().copied(), links)
}

/// A measured turn from one node to another (degrees), and how sure it is.
struct Link {
    from: ImageId,
    to: ImageId,
    deg: f64,
    weight: f64,
}

/// Each of `nodes` (and of the links' ends) with its heading relative to the
/// root of its tree (the tree's smallest node): the heaviest links that join
/// two trees (Kruskal, ties by the nodes), their turns chained from the root.
fn chain_spanning_forest(
    nodes: impl IntoIterator<Item = ImageId>,
    mut links: Vec<Link>,
) -> BTreeMap<ImageId, (ImageId, f64)> {
    links.sort_by(|a, b| b.weight.total_cmp(&a.weight).then((a.from, a.to).cmp(&(b.from, b.to))));
    let mut parent: BTreeMap<ImageId, ImageId> = nodes.into_iter().map(|id| (id, id)).collect();
    for link in &links {
        for id in [link.from, link.to] {
            parent.entry(id).or_insert(id);
        }
    }
    fn find(parent: &mut BTreeMap<ImageId, ImageId>, id: ImageId) -> ImageId {
        let mut root = id;
        while let Some(&p) = parent.get(&root).filter(|p| **p != root) {
            root = p;
        }
        parent.insert(id, root);
        root
    }
    let mut edges: BTreeMap<ImageId, Vec<(ImageId, f64)>> = BTreeMap::new();
    for link in &links {
        let (a, b) = (find(&mut parent, link.from), find(&mut parent, link.to));
        if a != b {
            parent.insert(a.max(b), a.min(b));
            edges.entry(link.from).or_default().push((link.to, link.deg));
            edges.entry(link.to).or_default().push((link.from, -link.deg));
        }
    }
    let mut headings = BTreeMap::new();
    for &root in parent.keys() {
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
        let turn = Turn { deg, agreement: 1.0 };
        CheckedPair { image_id1, image_id2, kind, turn, motion: None, inliers: 50, roll, predicted: false }
    }

    const LOOPS: f64 = DEFAULT_LOOP_TOLERANCE;

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
        let verdicts =
            check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &Navigation::default(), LOOPS);
        let consistent: Vec<usize> = verdicts.iter().filter(|v| v.1.is_consistent()).map(|v| v.0).collect();
        assert_eq!(consistent, vec![4, 5, 6, 9]);
        assert!(matches!(verdicts[3].1, Verdict::RollDisagrees { roll: Roll::R90, .. }), "{verdicts:?}");
        assert!(matches!(verdicts[4].1, Verdict::OffConsensus { .. }), "{verdicts:?}");
        // Without the chains within the visits, each image is its own part: nothing to vote on.
        pairs.retain(|p| p.kind == PairKind::Cross);
        let alone =
            check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &Navigation::default(), LOOPS);
        assert_eq!(alone.iter().filter(|v| v.1.is_consistent()).count(), 5);
    }

    #[test]
    fn the_offsets_between_visits_add_up_around_a_cycle() {
        // Three visits of three images each, headed 0, 90 and 180 degrees.
        let visit_of: BTreeMap<ImageId, usize> =
            [(1, 0), (2, 0), (3, 0), (11, 1), (12, 1), (13, 1), (21, 2), (22, 2), (23, 2)].into();
        let cross = |a, b, deg, roll, inliers| CheckedPair { inliers, ..pair(a, b, PairKind::Cross, deg, Some(roll)) };
        let chains = [(1, 2), (2, 3), (11, 12), (12, 13), (21, 22), (22, 23)]
            .map(|(a, b)| pair(a, b, PairKind::Intra, 0.0, None));
        let clear = [
            cross(1, 21, 180.0, Roll::R180, 80),
            cross(2, 22, 181.0, Roll::R180, 90),
            cross(3, 23, 179.0, Roll::R180, 85),
            cross(11, 21, 90.0, Roll::R270, 80),
            cross(12, 22, 89.0, Roll::R270, 70),
            cross(13, 23, 91.0, Roll::R270, 75),
        ];
        // Visits 0 and 1 by two wrong pairs that agree, narrowly, and two that do not.
        let narrow = [
            cross(1, 11, 270.0, Roll::R90, 33),
            cross(2, 12, 268.0, Roll::R90, 32),
            cross(1, 12, 0.0, Roll::R0, 34),
            cross(2, 11, 180.0, Roll::R180, 30),
        ];
        let predicted = |pairs: &[CheckedPair]| -> Option<f64> {
            let pairs: Vec<CheckedPair> = chains.iter().chain(pairs).copied().collect();
            Predictor::new(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG).turn(1, 12)
        };
        // Visits 0 and 1 without a pair of their own: predicted through visit 2.
        assert!(predicted(&clear).is_some_and(|deg| angle_between(deg, 90.0) < 2.0), "{:?}", predicted(&clear));
        // Two pairs that agree, with nothing against them, are not yet clear: two wrong pairs can.
        let two_each = [clear[0], clear[1], clear[3], clear[4]];
        assert_eq!(predicted(&two_each), None);
        // A narrow consensus predicts nothing, and the pairs matched at a roll predicted from it do not
        // make it clearer: they agree with it by construction.
        assert_eq!(predicted(&narrow), None);
        let echoes = [(1, 11), (2, 11), (1, 12), (2, 12)]
            .map(|(a, b)| CheckedPair { predicted: true, ..cross(a, b, 271.0, Roll::R90, 60) });
        assert_eq!(predicted(&[narrow.as_slice(), &echoes].concat()), None);
        // With the clear ones, the path through visit 2 wins over the narrow consensus.
        let all: Vec<CheckedPair> = chains.iter().chain(&clear).chain(&narrow).copied().collect();
        assert!(predicted(&all[chains.len()..]).is_some_and(|deg| angle_between(deg, 90.0) < 2.0));
        let verdicts =
            check_cross_pairs(&all, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &Navigation::default(), 0.0);
        let off: Vec<usize> =
            verdicts.iter().filter(|v| matches!(v.1, Verdict::OffConsensus { .. })).map(|v| v.0).collect();
        let narrow_at = chains.len() + clear.len();
        assert_eq!(off, (narrow_at..narrow_at + narrow.len()).collect::<Vec<_>>(), "{verdicts:?}");
        // Once settled, the searched pairs that turn otherwise are matched again at the settled
        // turn (90 degrees, from visit 0 to visit 1); the ones that agree, and any pair matched at
        // a prediction, are not.
        let predictor = Predictor::new(&all, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG);
        let settling = |p: &CheckedPair| predictor.needs_settling(p, DEFAULT_CONSISTENCY_TOLERANCE_DEG);
        assert!(narrow.iter().all(settling));
        assert!(predictor.turn(1, 12).is_some_and(|deg| angle_between(deg, 90.0) < 2.0));
        assert!(!settling(&clear[0]));
        assert!(!settling(&CheckedPair { predicted: true, ..narrow[0] }));
    }

    #[test]
    fn weak_pairs_of_visits_that_agree_on_no_offset_are_unlinked() {
        let visit_of: BTreeMap<ImageId, usize> = [(1, 0), (2, 0), (3, 0), (11, 1), (12, 1), (13, 1)].into();
        let cross = |a, b, deg, roll, inliers| CheckedPair { inliers, ..pair(a, b, PairKind::Cross, deg, Some(roll)) };
        let chains = [(1, 2), (2, 3), (11, 12), (12, 13)].map(|(a, b)| pair(a, b, PairKind::Intra, 0.0, None));
        // Searched pairs that agree on nothing: the weak ones are unlinked, the strong one stays
        // unless another rule finds it inconsistent.
        let searched = [
            cross(1, 11, 270.0, Roll::R90, 33),
            cross(2, 12, 0.0, Roll::R0, UNLINKED_MIN_INLIERS - 1),
            cross(3, 13, 180.0, Roll::R180, UNLINKED_MIN_INLIERS),
            // Matched at a roll its matches do not show, as well.
            cross(1, 13, 202.0, Roll::R90, 40),
            cross(2, 11, 130.0, Roll::R90, 60),
        ];
        let verdicts_of = |cross_pairs: &[CheckedPair]| {
            let pairs: Vec<CheckedPair> = chains.iter().chain(cross_pairs).copied().collect();
            let verdicts =
                check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &Navigation::default(), 0.0);
            verdicts.into_iter().map(|(index, verdict)| (index - chains.len(), verdict)).collect::<Vec<_>>()
        };
        assert_eq!(
            verdicts_of(&searched),
            [
                (0, Verdict::Unlinked { inliers: 33, inconsistent: false }),
                (1, Verdict::Unlinked { inliers: 44, inconsistent: false }),
                (2, Verdict::Consistent),
                (3, Verdict::Unlinked { inliers: 40, inconsistent: true }),
                (4, Verdict::Unlinked { inliers: 60, inconsistent: true })
            ]
        );
        // A pair matched at a prediction is not judged so (it agreed with an offset once clear).
        let echo = CheckedPair { predicted: true, ..searched[0] };
        assert_eq!(verdicts_of(&[echo]), [(0, Verdict::Consistent)]);
        // Once three pairs agree clearly, the pairs against them are off the consensus, not unlinked.
        let agreeing = [(1, 12), (2, 13), (3, 11)].map(|(a, b)| cross(a, b, 90.0, Roll::R270, 130));
        let verdicts = verdicts_of(&[searched.as_slice(), &agreeing].concat());
        assert!(verdicts.iter().all(|v| !matches!(v.1, Verdict::Unlinked { .. })), "{verdicts:?}");
        assert!(matches!(verdicts[0].1, Verdict::OffConsensus { .. }), "{verdicts:?}");
    }

    #[test]
    fn the_motion_finds_where_each_image_sees_the_other_centre() {
        // `turned` turns about (320, 240) and moves by (10, -10); a third of the matches are wrong.
        let near = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) < 1.0;
        for deg in [0.0, 37.0, 183.0] {
            let (a, b) = turned(deg, 3);
            let found = turn(&a, &b).unwrap();
            let similarity = similarity(&a, &b, found.deg).unwrap();
            let motion = Motion { similarity, centre1: [320.0, 240.0], centre2: [320.0, 240.0] };
            let (sin, cos) = f64::to_radians(deg).sin_cos();
            let back = [cos * -10.0 + sin * 10.0, -sin * -10.0 + cos * 10.0];
            assert!(near(motion.other_in_2(), [10.0, -10.0]), "{deg}: {motion:?}");
            assert!(near(motion.other_in_1(), back), "{deg}: {motion:?}");
            // There and back, or there and on, is one similarity.
            let p = [100.0, 50.0];
            assert!(near(similarity.then(&similarity.inverse()).apply(p), p), "{deg}");
            let twice = similarity.then(&similarity);
            assert!(near(twice.apply(p), similarity.apply(similarity.apply(p))), "{deg}");
        }
    }

    /// Two visits of four images each along a line (`bent`: turning at the
    /// third), seen by a downward camera at 4 mm a pixel; `mirrored` as an ENU
    /// frame is to the image's pixels (NED is not). Visit 0's images head 20
    /// degrees in the frame, visit 1's 115.
    fn navigated_visits(mirrored: bool, bent: bool) -> (Vec<CheckedPair>, BTreeMap<ImageId, usize>, Navigation) {
        let visit_of: BTreeMap<ImageId, usize> =
            [(1, 0), (2, 0), (3, 0), (4, 0), (11, 1), (12, 1), (13, 1), (14, 1)].into();
        let xy = |id: ImageId| -> [f64; 2] {
            let k = f64::from(id % 10);
            let across = if bent && k > 3.0 { 0.6 } else { 0.0 };
            match id < 10 {
                true => [0.5 * k.min(3.0), 0.1 * k + across],
                false => [0.5 * k.min(3.0) + 0.05, 0.12 * k - 0.04 + across],
            }
        };
        let heading_deg = |id: ImageId| if id < 10 { 20.0 } else { 115.0 };
        // Where `image` sees a point `w` metres away.
        let seen = |image: ImageId, w: [f64; 2]| -> [f64; 2] {
            let (sin, cos) = f64::to_radians(heading_deg(image)).sin_cos();
            let [x, y] = [w[0] / 0.004, w[1] / 0.004];
            match mirrored {
                true => [cos * x + sin * y, sin * x - cos * y],
                false => [cos * x - sin * y, sin * x + cos * y],
            }
        };
        // The motion from image `a` to image `b`, `w` metres apart.
        let sighted = |a: ImageId, b: ImageId, w: [f64; 2]| -> Motion {
            let centre = [320.0, 240.0];
            let turn_deg = wrap(heading_deg(b) - heading_deg(a));
            let turned = Similarity { turn_deg, ..Similarity::IDENTITY }.apply(centre);
            let seen_in_b = seen(b, [-w[0], -w[1]]);
            let move_px = [centre[0] + seen_in_b[0] - turned[0], centre[1] + seen_in_b[1] - turned[1]];
            Motion { similarity: Similarity { scale: 1.0, turn_deg, move_px }, centre1: centre, centre2: centre }
        };
        let pair = |a: ImageId, b: ImageId, kind: PairKind| -> CheckedPair {
            let w = [xy(b)[0] - xy(a)[0], xy(b)[1] - xy(a)[1]];
            let motion = sighted(a, b, w);
            let deg = wrap(heading_deg(b) - heading_deg(a));
            CheckedPair { motion: Some(motion), ..pair(a, b, kind, if mirrored { wrap(-deg) } else { deg }, None) }
        };
        let mut pairs = Vec::new();
        for base in [0, 10] {
            for (a, b) in [(1, 2), (2, 3), (3, 4), (1, 3), (2, 4)] {
                pairs.push(pair(base + a, base + b, PairKind::Intra));
            }
        }
        pairs.extend([pair(1, 11, PairKind::Cross), pair(2, 12, PairKind::Cross), pair(3, 12, PairKind::Cross)]);
        // Two places 1 m apart that matched coherently: the matches say 0.2 m, turned right.
        let mut wrong = pair(1, 13, PairKind::Cross);
        wrong.motion = Some(sighted(1, 13, [0.2, 0.0]));
        pairs.push(wrong);
        let positions = visit_of.keys().map(|&id| (id, Navigated { xy_m: xy(id), sigma_m: 0.1 })).collect();
        (pairs, visit_of, Navigation { positions, tolerance_sigmas: DEFAULT_NAVIGATION_TOLERANCE_SIGMAS })
    }

    #[test]
    fn a_pair_whose_matches_move_the_camera_off_its_navigation_is_caught() {
        for (mirrored, bent) in [(true, false), (false, false), (true, true), (false, true)] {
            let (pairs, visit_of, mut navigation) = navigated_visits(mirrored, bent);
            // A bent track tells ENU from NED; a straight one leaves both open.
            let open = footings(&pairs, &visit_of, &navigation.positions);
            assert_eq!(open.len(), if bent { 1 } else { 2 });
            assert!(open.iter().any(|f| f[&0].mirrored == mirrored && f[&1].mirrored == mirrored));
            let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, LOOPS);
            let off: Vec<usize> =
                verdicts.iter().filter(|v| matches!(v.1, Verdict::OffNavigation { .. })).map(|v| v.0).collect();
            assert_eq!(off, vec![13], "mirrored {mirrored}: {verdicts:?}");
            let Verdict::OffNavigation { miss_m, tolerance_m } = verdicts.last().unwrap().1 else { unreachable!() };
            // Navigated (1.05, 0.22) m apart, matched (0.2, 0) m apart; 3 x 0.14 m allowed.
            assert!((miss_m - 0.85f64.hypot(0.22)).abs() < 1e-6, "{miss_m}");
            assert!((tolerance_m - 3.0 * 0.1f64.hypot(0.1)).abs() < 1e-9, "{tolerance_m}");
            navigation.tolerance_sigmas = 0.0;
            let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, LOOPS);
            assert!(verdicts.iter().all(|v| !matches!(v.1, Verdict::OffNavigation { .. })), "{verdicts:?}");
        }
    }

    #[test]
    fn a_visit_whose_navigation_is_off_keeps_its_pairs() {
        let (pairs, visit_of, mut navigation) = navigated_visits(false, true);
        // The second visit's position fix 1 m off: every pair between the visits misses by about it.
        for (id, navigated) in navigation.positions.iter_mut() {
            if visit_of[id] == 1 {
                navigated.xy_m[1] += 1.0;
            }
        }
        let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, 0.0);
        assert!(verdicts.iter().all(|v| !matches!(v.1, Verdict::OffNavigation { .. })), "{verdicts:?}");
    }

    #[test]
    fn wrong_pairs_stay_off_the_navigation_even_when_they_are_most_pairs() {
        let (mut pairs, visit_of, navigation) = navigated_visits(false, true);
        // Three more wrong pairs, each matched a different distance off.
        let wrong = *pairs.last().unwrap();
        for k in 1..=3 {
            let mut more = wrong;
            more.image_id1 = 1 + k;
            if let Some(motion) = &mut more.motion {
                motion.similarity.move_px[0] += 150.0 * k as f64;
            }
            pairs.push(more);
        }
        let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, 0.0);
        let off: Vec<usize> =
            verdicts.iter().filter(|v| matches!(v.1, Verdict::OffNavigation { .. })).map(|v| v.0).collect();
        assert_eq!(off, vec![13, 14, 15, 16], "{verdicts:?}");
    }

    #[test]
    fn a_pair_whose_loops_miss_is_caught_without_navigation() {
        let (mut pairs, visit_of, mut navigation) = navigated_visits(false, true);
        navigation.tolerance_sigmas = 0.0;
        let off = |pairs: &[CheckedPair], loops: f64| -> Vec<(usize, Verdict)> {
            let verdicts = check_cross_pairs(pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, loops);
            verdicts.into_iter().filter(|v| !v.1.is_consistent()).collect()
        };
        // Pair 13 (images 1 and 13) misses its loops through the three right pairs, each of which
        // closes two loops with the others.
        assert_eq!(off(&pairs, LOOPS), vec![(13, Verdict::OffLoops { missed: 3, closed: 0 })]);
        let verdicts = check_cross_pairs(&pairs, &visit_of, DEFAULT_CONSISTENCY_TOLERANCE_DEG, &navigation, LOOPS);
        let confirmed: Vec<usize> =
            verdicts.iter().filter(|v| matches!(v.1, Verdict::Confirmed { closed: 2 })).map(|v| v.0).collect();
        assert_eq!(confirmed, vec![10, 11, 12]);
        assert_eq!(off(&pairs, 0.0), vec![]);
        // Alone with one right pair, the two miss their one loop: one miss does not say which is
        // wrong, and neither is judged.
        let two: Vec<CheckedPair> =
            pairs.iter().filter(|p| p.kind == PairKind::Intra).copied().chain([pairs[10], pairs[13]]).collect();
        assert_eq!(off(&two, LOOPS), vec![]);
        // Without the pairs within the visits, no loop closes, and nothing is judged.
        pairs.retain(|p| p.kind == PairKind::Cross);
        assert_eq!(off(&pairs, LOOPS), vec![]);
    }

    /// Two downward cameras 0.5 m apart over 40 ground points, the second
    /// placed `misplaced` (a turn about the vertical, degrees) away from where
    /// its matches put it; only image 1's keypoints are triangulated.
    fn two_cameras(misplaced_deg: f64) -> (Reconstruction, Vec<[u32; 2]>) {
        use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
        use revisit_core::{Camera, CameraModel, Image, Observation, Point3D, Rigid3};
        let camera = Camera::new(1, CameraModel::Pinhole, 640, 480, vec![500.0, 500.0, 320.0, 240.0]).unwrap();
        let ground: Vec<Point3<f64>> =
            (0..40).map(|k| Point3::new(-1.0 + 0.05 * f64::from(k), 0.4 * f64::from(k % 5) - 0.8, 2.0)).collect();
        let pose = |x: f64, deg: f64| {
            Rigid3::new(UnitQuaternion::from_euler_angles(0.0, 0.0, deg.to_radians()), Vector3::new(-x, 0.0, 0.0))
        };
        let (true_pose, placed) = (pose(0.5, 0.0), pose(0.5, misplaced_deg));
        let mut model = Reconstruction::default();
        model.cameras.insert(1, camera.clone());
        let seen = |pose: &Rigid3| -> Vec<Point2<f64>> {
            ground.iter().map(|p| camera.img_from_cam(&(*pose * *p)).unwrap()).collect()
        };
        let (in1, in2) = (seen(&Rigid3::identity()), seen(&true_pose));
        let observe = |xy: &[Point2<f64>], triangulated: bool| -> Vec<Observation> {
            let id = |k: usize| triangulated.then_some(k as u64 + 1);
            xy.iter().enumerate().map(|(k, xy)| Observation { xy: *xy, point3d_id: id(k) }).collect()
        };
        let image = |image_id, cam_from_world, points2d| Image {
            image_id,
            camera_id: 1,
            name: format!("s{image_id}/a.png"),
            cam_from_world,
            points2d,
        };
        model.images.insert(1, image(1, Rigid3::identity(), observe(&in1, true)));
        model.images.insert(2, image(2, placed, observe(&in2, false)));
        for (k, xyz) in ground.iter().enumerate() {
            model.points3d.insert(k as u64 + 1, Point3D { xyz: *xyz, rgb: [0; 3], error: 0.0, track: vec![] });
        }
        (model, (0..40).map(|k| [k, k]).collect())
    }

    #[test]
    fn a_model_that_placed_two_images_at_odds_with_their_matches_is_suspect() {
        let (model, matches) = two_cameras(0.0);
        let right = placement_error_px(&model, 1, 2, &matches).unwrap();
        assert!(right < 1e-6, "{right}");
        let (model, matches) = two_cameras(20.0);
        let turned = placement_error_px(&model, 1, 2, &matches).unwrap();
        assert!(turned > 50.0, "{turned}");
        // Too few triangulated matches, or an image not in the model: nothing to say.
        assert_eq!(placement_error_px(&model, 1, 2, &matches[..4]), None);
        assert_eq!(placement_error_px(&model, 1, 3, &matches), None);
        let tolerance = PLACEMENT_TOLERANCE * 800.0;
        let placement = Placement::of(&[(right, tolerance), (turned, tolerance), (turned, tolerance)]);
        assert_eq!((placement.measured, placement.agreeing, placement.median_px), (3, 1, turned));
        assert!(placement.is_suspect());
        assert!(!Placement::of(&[(right, tolerance), (turned, tolerance)]).is_suspect());
        assert!(!Placement::of(&[(turned, tolerance)]).is_suspect(), "one pair is not enough to say");
        // Joined without a confirmed pair: unchecked; not joined at all: nothing to check.
        assert!(Placement { joining: 4, ..Placement::of(&[]) }.is_unchecked());
        assert!(!Placement { joining: 4, ..placement }.is_unchecked());
        assert!(!Placement::of(&[]).is_unchecked());
    }
}
