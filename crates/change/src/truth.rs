//! A change map scored against the synthetic reef's truth (`truth/changes_A-B.csv`).

use nalgebra::Point3;
use revisit_core::Similarity;
use serde::{Deserialize, Serialize};

use crate::{ChangeMap, Region};

/// How regions and truth structures are matched, as the scores state it.
pub const MATCHING_RULE: &str = "a region covers a structure when one of its cells lies within half the structure's \
    reach (at least one cell) of where the structure was (removed, moved), is (new, moved) or stands (grown); a \
    region is true when at least half its cells lie within one cell beyond the reach of such places of structures \
    whose shape or place changed (removed, new, moved or grown; bleaching alone is not; pebbles, 1-4 cm tall, are \
    below what a map measures and count for nothing), false otherwise; the targets are the corals the truth \
    moved or removed whose changed place has a measured cell within half its reach and whose going changed the \
    visible surface there by more than 4 cm (not one that lay beneath a larger structure's surface); a target is \
    found when a region covers it";

/// Largest change of the visible surface a structure's going or coming may make and still be
/// no target: a pebble's height (1-4 cm), below what a map measures.
pub const HIDDEN_CHANGE_M: f64 = 0.04;

/// One structure's change between the two visits, as the truth lists it.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct TruthChange {
    pub id: u32,
    pub kind: String,
    pub change: String,
    x0: Option<f64>,
    y0: Option<f64>,
    x1: Option<f64>,
    y1: Option<f64>,
    pub reach_m: f64,
    pub growth: f64,
    pub height_change_m: f64,
    /// Change of the median height of its top (`revisit synth` writes it since growth is
    /// scored there; older truths lack it, and their height change is used).
    #[serde(default)]
    top_change_m: Option<f64>,
    /// For a removed, new or moved structure, the largest change of the visible surface's
    /// height within half its reach of its places (older truths lack it: every such structure
    /// counts).
    #[serde(default)]
    surface_change_m: Option<f64>,
}

impl TruthChange {
    pub fn before_m(&self) -> Option<[f64; 2]> {
        Some([self.x0?, self.y0?])
    }

    pub fn after_m(&self) -> Option<[f64; 2]> {
        Some([self.x1?, self.y1?])
    }

    /// Tall enough to explain a region: every structure but pebbles.
    fn is_measurable(&self) -> bool {
        self.kind != "pebble"
    }

    /// Whether its going, coming or moving changed what a camera sees by more than a pebble's
    /// height: not so for one that lay inside a larger structure's outline, beneath its surface.
    fn changed_the_surface(&self) -> bool {
        self.surface_change_m.is_none_or(|m| m > HIDDEN_CHANGE_M)
    }

    fn is_coral(&self) -> bool {
        matches!(self.kind.as_str(), "coral_head" | "coral_table" | "branching_coral")
    }

    /// Where its shape changed: its old place and its new one (one of them for removed,
    /// new and grown), world metres.
    fn changed_at(&self) -> Vec<[f64; 2]> {
        match self.change.as_str() {
            "removed" => self.before_m().into_iter().collect(),
            "new" => self.after_m().into_iter().collect(),
            "moved" => self.before_m().into_iter().chain(self.after_m()).collect(),
            "grown" => self.after_m().into_iter().collect(),
            _ => Vec::new(),
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TruthError {
    #[error("{source_name}: row {row}: {reason}")]
    BadRow { source_name: String, row: usize, reason: String },
}

/// Reads `changes_A-B.csv` (`id,kind,change,x0,y0,x1,y1,reach_m,...`, as `revisit synth`
/// writes it).
pub fn parse_changes_csv(text: &str, source_name: &str) -> Result<Vec<TruthChange>, TruthError> {
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    reader
        .deserialize()
        .enumerate()
        .map(|(k, row)| {
            row.map_err(|e| TruthError::BadRow {
                source_name: source_name.to_owned(),
                row: k + 2,
                reason: e.to_string(),
            })
        })
        .collect()
}

/// A grown coral: the true change of its top's height against the map's.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GrowthScore {
    pub id: u32,
    /// The truth's change of the median height of its top (within a quarter of its reach).
    pub truth_m: f64,
    /// The median change of the cells on its top (within a quarter of its reach of its centre,
    /// at least one cell), metres: the largest change stands on a flank (a grown dome's flank
    /// moves out and so rises more than its top), and the median over half the reach mixes the
    /// flanks in.
    pub measured_m: f64,
    /// `measured_m / truth_m - 1`.
    pub relative_error: f64,
    /// The truth's change exceeds the median LoD95 of those cells.
    pub detectable: bool,
}

/// One region against the truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RegionTruth {
    pub id: usize,
    /// Its centre in the truth's world, metres.
    pub centre_m: [f64; 2],
    /// Ids of the changed structures it covers.
    pub covers: Vec<u32>,
    /// Share of its cells within a changed structure's reach plus one cell.
    pub on_changed: f64,
    /// The structure (not a pebble) whose place, then or now, is nearest: id, change and
    /// distance beyond its reach, metres.
    pub nearest: Option<(u32, String, f64)>,
}

/// Precision and recall of a change map's regions, and the growth it measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChangeScores {
    pub rule: &'static str,
    /// The similarity that put the model on the truth (its cameras on the true ones).
    pub truth_from_model: Similarity,
    pub regions: usize,
    /// Regions mostly on structures whose shape or place changed.
    pub true_regions: usize,
    pub precision: Option<f64>,
    /// Ids of the regions that are not true.
    pub false_regions: Vec<usize>,
    pub by_region: Vec<RegionTruth>,
    /// Corals moved or removed where the map measured.
    pub targets: usize,
    pub found: usize,
    pub recall: Option<f64>,
    /// Ids of targets no region covers.
    pub missed: Vec<u32>,
    /// Grown corals measured on their top; those under or over a structure that was removed,
    /// moved or new are left out (their change is the other's).
    pub grown: Vec<GrowthScore>,
    /// Median |relative error| over the detectable grown corals.
    pub growth_median_abs_error: Option<f64>,
}

/// Scores `map` against `truth`, the model mapped into the truth's world by `truth_from_model`.
pub fn score(map: &ChangeMap, truth: &[TruthChange], truth_from_model: &Similarity) -> ChangeScores {
    let world = |p: &Point3<f64>| {
        let w = truth_from_model.apply(p);
        [w.x, w.y]
    };
    let cell_m = map.grid.cell * truth_from_model.scale;
    let cells: Vec<[f64; 2]> = map.cells.iter().map(|c| world(&c.core)).collect();
    let near = |a: [f64; 2], b: [f64; 2], r: f64| (a[0] - b[0]).hypot(a[1] - b[1]) <= r;
    let changed: Vec<&TruthChange> = truth.iter().filter(|s| s.is_measurable() && !s.changed_at().is_empty()).collect();
    let core = |s: &TruthChange| (0.5 * s.reach_m).max(cell_m);
    let covers = |region: &Region, s: &TruthChange| {
        region.cells.iter().any(|&k| s.changed_at().iter().any(|&p| near(cells[k], p, core(s))))
    };
    let on_changed =
        |k: usize| changed.iter().any(|s| s.changed_at().iter().any(|&p| near(cells[k], p, s.reach_m + cell_m)));

    let by_region: Vec<RegionTruth> = map
        .regions
        .iter()
        .map(|region| {
            let centre = world(&region.centre);
            let measurable = || truth.iter().filter(|s| s.is_measurable());
            let places = |s: &TruthChange| s.before_m().into_iter().chain(s.after_m()).collect::<Vec<_>>();
            let beyond = |s: &TruthChange| {
                places(s)
                    .iter()
                    .map(|p| (centre[0] - p[0]).hypot(centre[1] - p[1]) - s.reach_m)
                    .fold(f64::INFINITY, f64::min)
            };
            let on = region.cells.iter().filter(|&&k| on_changed(k)).count();
            RegionTruth {
                id: region.id,
                centre_m: centre,
                covers: changed.iter().filter(|s| covers(region, s)).map(|s| s.id).collect(),
                on_changed: on as f64 / region.cells.len().max(1) as f64,
                nearest: measurable()
                    .map(|s| (s, beyond(s)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .map(|(s, d)| (s.id, s.change.clone(), d)),
            }
        })
        .collect();
    let false_regions: Vec<usize> = by_region.iter().filter(|r| r.on_changed < 0.5).map(|r| r.id).collect();
    let measured_at = |p: [f64; 2], r: f64| cells.iter().any(|&c| near(c, p, r));
    let targets: Vec<&TruthChange> = truth
        .iter()
        .filter(|s| s.is_coral() && matches!(s.change.as_str(), "removed" | "moved") && s.changed_the_surface())
        .filter(|s| s.changed_at().iter().any(|&p| measured_at(p, 0.5 * s.reach_m)))
        .collect();
    let missed: Vec<u32> = targets.iter().filter(|s| !map.regions.iter().any(|r| covers(r, s))).map(|s| s.id).collect();

    // A grown coral under or over one that left, came or moved (one stands within the other's
    // reach) is measured with it, not alone.
    let under_other = |s: &TruthChange, at: [f64; 2]| {
        changed.iter().any(|o| {
            o.id != s.id && o.change != "grown" && o.changed_at().iter().any(|&p| near(at, p, s.reach_m.max(o.reach_m)))
        })
    };
    let mut grown = Vec::new();
    for s in truth.iter().filter(|s| s.is_coral() && s.change == "grown" && s.height_change_m > 0.0) {
        let Some(centre) = s.after_m().filter(|&at| !under_other(s, at)) else { continue };
        let top: Vec<&crate::Cell> = map
            .cells
            .iter()
            .zip(&cells)
            .filter(|(_, &c)| near(c, centre, (0.25 * s.reach_m).max(cell_m)))
            .map(|(c, _)| c)
            .collect();
        if top.is_empty() {
            continue;
        }
        let median_of = |value: fn(&crate::Cell) -> f64| {
            crate::median(&top.iter().map(|&c| value(c)).collect::<Vec<_>>()) * truth_from_model.scale
        };
        let (measured_m, truth_m) = (median_of(|c| c.change), s.top_change_m.unwrap_or(s.height_change_m));
        grown.push(GrowthScore {
            id: s.id,
            truth_m,
            measured_m,
            relative_error: measured_m / truth_m - 1.0,
            detectable: truth_m > median_of(|c| c.lod95),
        });
    }
    let mut errors: Vec<f64> = grown.iter().filter(|g| g.detectable).map(|g| g.relative_error.abs()).collect();
    errors.sort_by(f64::total_cmp);
    let ratio = |a: usize, b: usize| (b > 0).then(|| a as f64 / b as f64);
    let regions = map.regions.len();
    ChangeScores {
        rule: MATCHING_RULE,
        truth_from_model: *truth_from_model,
        regions,
        true_regions: regions - false_regions.len(),
        precision: ratio(regions - false_regions.len(), regions),
        false_regions,
        by_region,
        targets: targets.len(),
        found: targets.len() - missed.len(),
        recall: ratio(targets.len() - missed.len(), targets.len()),
        missed,
        grown,
        growth_median_abs_error: errors.get(errors.len() / 2).copied(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{all_points, two_visits};

    const CHANGES: &str = "\
id,kind,change,x0,y0,x1,y1,reach_m,moved_m,turned_deg,growth,height_change_m,bleach_change
1,coral_head,removed,-1,-1,,,0.4,0,0,0,0,0
2,coral_head,new,,,1,1,0.4,0,0,0,0,0
3,coral_table,moved,-1,1,-0.6,1.2,0.4,0.45,10,0,0,0
4,branching_coral,bleached,1,-1,1,-1,0.3,0,0,0,0,0.8
5,pebble,moved,0,0,0.05,0,0.03,0.05,0,0,0,0
";

    #[test]
    fn regions_on_changed_corals_are_true_and_an_unseen_move_is_missed() {
        let truth = parse_changes_csv(CHANGES, "changes_a-b.csv").expect("csv");
        assert_eq!(truth.len(), 5);
        let map = crate::testing::sparse_map(&two_visits(true), "a", "b", &all_points()).expect("map");
        let scores = score(&map, &truth, &Similarity::identity());
        assert_eq!((scores.regions, scores.true_regions, scores.precision), (2, 2, Some(1.0)));
        // The removed head is found; the table the truth moved did not move in the model.
        assert_eq!((scores.targets, scores.found, scores.missed.clone()), (2, 1, vec![3]));
        let mut explained: Vec<Vec<u32>> = scores.by_region.iter().map(|r| r.covers.clone()).collect();
        explained.sort();
        assert_eq!(explained, [vec![1], vec![2]]);

        // A truth that says the table's move changed no surface a camera saw (it lay beneath a
        // larger structure's) leaves it out of the targets; the head's going is seen.
        let text: Vec<String> = CHANGES
            .lines()
            .enumerate()
            .map(|(k, line)| match k {
                0 => format!("{line},surface_change_m"),
                1 => format!("{line},0.3"),
                3 => format!("{line},0.02"),
                _ => format!("{line},0"),
            })
            .collect();
        let text = text.join("\n");
        let truth = parse_changes_csv(&text, "changes_a-b.csv").expect("csv");
        let scores = score(&map, &truth, &Similarity::identity());
        assert_eq!((scores.targets, scores.found, scores.missed), (1, 1, vec![]));
    }

    #[test]
    fn a_grown_coral_is_measured_on_its_top_not_its_flank() {
        // A dome 0.4 m across the foot and 0.3 m tall that grew by a quarter: its top rose
        // 7.5 cm, its flanks more (they moved out as well).
        fn grown_dome(visit: &str, x: f64, y: f64) -> f64 {
            let size = if visit == "b" { 1.25 } else { 1.0 };
            let t = (x - 1.0).hypot(y + 1.0) / (0.4 * size);
            0.3 * size * (1.0 - t * t).max(0.0)
        }
        let truth = parse_changes_csv(
            "id,kind,change,x0,y0,x1,y1,reach_m,moved_m,turned_deg,growth,height_change_m,bleach_change\n\
             1,coral_head,grown,1,-1,1,-1,0.5,0,0,0.25,0.075,0\n",
            "changes_a-b.csv",
        )
        .expect("csv");
        let map = crate::testing::sparse_map(&crate::testing::two_visits_of(grown_dome), "a", "b", &all_points())
            .expect("map");
        let scores = score(&map, &truth, &Similarity::identity());
        let [grown] = &scores.grown[..] else { panic!("{:?}", scores.grown) };
        assert!(grown.detectable, "{grown:?}");
        assert!(grown.relative_error.abs() < 0.2, "{grown:?}");
        let flank = map.cells.iter().map(|c| c.change).fold(f64::MIN, f64::max);
        assert!(flank > 1.5 * grown.truth_m, "the flank rose {flank} m");
    }

    #[test]
    fn a_bad_row_is_named() {
        let text = "id,kind,change,x0,y0,x1,y1,reach_m,moved_m,turned_deg,growth,height_change_m,bleach_change\n\
                    1,coral_head,removed,x,-1,,,0.4,0,0,0,0,0\n";
        let err = parse_changes_csv(text, "changes_a-b.csv").unwrap_err().to_string();
        assert!(err.starts_with("changes_a-b.csv: row 2: "), "{err}");
    }
}
