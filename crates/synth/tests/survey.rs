//! Boundary tests of the synthetic survey: determinism, truth consistency,
//! change grades and evaluation points. Small images keep them fast.

use std::sync::OnceLock;

use nalgebra::Point2;
use revisit_synth::{
    plan, ChangeGrade, ChangeKind, EvaluationOptions, Growth, ObjectKind, Survey, SynthError, SynthOptions, NO_DEPTH,
};

fn small(change: ChangeGrade, sessions: usize, seed: u64) -> SynthOptions {
    SynthOptions { sessions, images_per_session: 6, seed, change, width: 160, height: 120, ..Default::default() }
}

#[allow(clippy::unwrap_used)] // test fixture
fn mild() -> &'static Survey {
    static SURVEY: OnceLock<Survey> = OnceLock::new();
    SURVEY.get_or_init(|| plan(&small(ChangeGrade::Mild, 2, 7)).unwrap())
}

#[allow(clippy::unwrap_used)] // test fixture
fn none() -> &'static Survey {
    static SURVEY: OnceLock<Survey> = OnceLock::new();
    SURVEY.get_or_init(|| plan(&small(ChangeGrade::None, 2, 3)).unwrap())
}

#[test]
fn same_seed_gives_identical_bytes_and_another_seed_does_not() {
    let a = mild().render(3).unwrap();
    let again = plan(&small(ChangeGrade::Mild, 2, 7)).unwrap().render(3).unwrap();
    assert_eq!(a.rgb.as_raw(), again.rgb.as_raw());
    assert_eq!(a.depth_m, again.depth_m);
    let other = plan(&small(ChangeGrade::Mild, 2, 8)).unwrap().render(3).unwrap();
    let differing = a.rgb.as_raw().iter().zip(other.rgb.as_raw()).filter(|(x, y)| x != y).count();
    assert!(differing > a.rgb.as_raw().len() / 2, "only {differing} bytes differ");
}

#[test]
fn renders_look_like_a_textured_seabed() {
    let r = mild().render(0).unwrap();
    assert!(r.depth_m.iter().all(|d| d.is_finite() && *d > 0.5 && *d < 4.0), "every pixel sees the seabed");
    let gray: Vec<f64> = r.rgb.pixels().map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])).collect();
    let mean = gray.iter().sum::<f64>() / gray.len() as f64 / 3.0;
    let var = gray.iter().map(|g| (g / 3.0 - mean).powi(2)).sum::<f64>() / gray.len() as f64;
    assert!(mean > 60.0 && mean < 220.0, "mean {mean}");
    assert!(var.sqrt() > 8.0, "contrast {}", var.sqrt());
    // Blue-green water: red is the weakest channel on average.
    let (red, green): (f64, f64) =
        r.rgb.pixels().fold((0.0, 0.0), |acc, p| (acc.0 + f64::from(p[0]), acc.1 + f64::from(p[1])));
    assert!(red < green);
}

#[test]
fn truth_poses_project_rendered_points_onto_the_same_surface_in_other_images() {
    let survey = none();
    let model = survey.truth_model();
    assert_eq!(model.images.len(), survey.num_images());
    assert_eq!(model.cameras.len(), 2);
    let overlaps = survey.overlaps(0.3).unwrap();
    assert!(!overlaps.is_empty(), "sessions overlap");
    let mut checked = 0;
    let mut agreed = 0;
    for o in overlaps.iter().take(4) {
        let i = model.image_by_name(&o.img0).unwrap().image_id as usize - 1;
        let j = model.image_by_name(&o.img1).unwrap().image_id as usize - 1;
        let (ri, rj) = (survey.render(i).unwrap(), survey.render(j).unwrap());
        let image_j = model.images.get(&(j as u32 + 1)).unwrap();
        for row in (4..120).step_by(9) {
            for col in (4..160).step_by(9) {
                let z = ri.depth_m[row * 160 + col];
                let world =
                    survey.world_point(i, Point2::new(col as f64 + 0.5, row as f64 + 0.5), f64::from(z)).unwrap();
                let Some(uv) = model.project(image_j, &world) else { continue };
                if uv.x < 0.0 || uv.y < 0.0 || uv.x >= 160.0 || uv.y >= 120.0 {
                    continue;
                }
                let z_j = (image_j.cam_from_world * world).z;
                let found = f64::from(rj.depth_m[uv.y as usize * 160 + uv.x as usize]);
                checked += 1;
                if (found - z_j).abs() < 0.01 * z_j + 0.01 {
                    agreed += 1;
                }
            }
        }
    }
    assert!(checked > 50, "checked {checked}");
    // Disagreement only at occlusions and depth edges.
    assert!(agreed as f64 > 0.9 * checked as f64, "{agreed} of {checked} agree");
}

#[test]
fn change_none_renders_the_same_pose_identically_in_every_session() {
    let survey = none();
    let pose = survey.image(2).unwrap().cam_from_world;
    let a = survey.render_pose(0, &pose, 1.0, 5).unwrap();
    let b = survey.render_pose(1, &pose, 1.0, 5).unwrap();
    assert_eq!(a.rgb.as_raw(), b.rgb.as_raw());
    assert_eq!(survey.objects(0).unwrap(), survey.objects(1).unwrap());
    // Headings differ by about 90 degrees between sessions 1 and 2.
    let d = (survey.sessions()[1].heading_deg - survey.sessions()[0].heading_deg).rem_euclid(360.0);
    assert!((d - 90.0).abs() < 10.0, "{d}");
}

#[test]
fn mild_change_differs_in_water_and_a_few_structures() {
    let survey = mild();
    let pose = survey.image(2).unwrap().cam_from_world;
    let a = survey.render_pose(0, &pose, 1.0, 5).unwrap();
    let b = survey.render_pose(1, &pose, 1.0, 5).unwrap();
    assert_ne!(a.rgb.as_raw(), b.rgb.as_raw());
    let objects = survey.objects(0).unwrap();
    let unchanged = objects.iter().filter(|o| survey.object_unchanged(o.id, 0, 1)).count();
    let share = unchanged as f64 / objects.len() as f64;
    assert!(share > 0.8 && share < 1.0, "unchanged share {share}");
}

#[test]
fn storm_moves_or_removes_a_large_share_of_corals() {
    let survey = plan(&small(ChangeGrade::Storm, 2, 11)).unwrap();
    let before = survey.objects(0).unwrap();
    let after = survey.objects(1).unwrap();
    let corals: Vec<_> = before.iter().filter(|o| o.kind.is_coral()).collect();
    let moved_or_gone =
        corals.iter().filter(|o| after.iter().find(|p| p.id == o.id).is_none_or(|p| p.centre_m != o.centre_m)).count();
    let share = moved_or_gone as f64 / corals.len() as f64;
    assert!((0.3..=0.55).contains(&share), "moved or removed {share}");
}

/// The truth says how much each removal changed what a camera sees: most corals leave a visible
/// hole; one that changed the surface by no more than a pebble's height lay inside a larger
/// structure's outline, beneath its surface (the scene lets structures overlap).
#[test]
fn a_removal_beneath_a_larger_structure_is_told_apart_in_the_truth() {
    let (mut removed, mut hidden) = (0, 0);
    for seed in 0..10 {
        let survey = plan(&small(ChangeGrade::Storm, 2, seed)).unwrap();
        let before = survey.objects(0).unwrap();
        let changes = survey.changes(0, 1).unwrap();
        for gone in changes.iter().filter(|c| c.kind.is_coral() && c.change == ChangeKind::Removed) {
            removed += 1;
            if gone.surface_change_m > 0.04 {
                continue;
            }
            hidden += 1;
            let [x, y] = gone.centre_before_m.unwrap();
            let under = before.iter().any(|o| {
                o.id != gone.id
                    && o.reach_m() > gone.reach_m
                    && (o.centre_m[0] - x).hypot(o.centre_m[1] - y) < o.reach_m()
            });
            assert!(under, "seed {seed}: {gone:?} changed the surface by {} m in the open", gone.surface_change_m);
        }
        assert!(changes.iter().filter(|c| c.change == ChangeKind::Grown).all(|c| c.surface_change_m == 0.0));
    }
    assert!(hidden > 0 && hidden * 10 <= removed, "{hidden} of {removed} removals hidden");
}

#[test]
fn growth_grows_every_living_coral_and_changes_nothing_else() {
    let plain = plan(&small(ChangeGrade::Strong, 3, 5)).unwrap();
    let grown = plan(&SynthOptions { growth: Some(Growth::YEARLY), ..small(ChangeGrade::Strong, 3, 5) }).unwrap();
    for s in 1..3 {
        let (a, b) = (plain.objects(s).unwrap(), grown.objects(s).unwrap());
        assert_eq!(a.len(), b.len(), "the same structures survive in visit {s}");
        for (x, y) in a.iter().zip(b) {
            assert_eq!((x.id, x.centre_m, x.angle_rad, x.bleach), (y.id, y.centre_m, y.angle_rad, y.bleach));
        }
    }
    // Visit 1 to 2: each surviving coral grew by 0.5-1.5 times its type's yearly fraction.
    let changes = grown.changes(0, 1).unwrap();
    let mut grown_corals = 0;
    for c in changes.iter().filter(|c| c.kind.is_coral() && c.centre_before_m.is_some() && c.centre_after_m.is_some()) {
        let f = Growth::YEARLY.fraction(c.kind);
        assert!(c.growth >= 0.5 * f - 1e-12 && c.growth <= 1.5 * f + 1e-12, "{c:?}");
        assert!(c.height_change_m > 0.0);
        assert!(matches!(c.change, ChangeKind::Grown | ChangeKind::Moved), "{c:?}");
        grown_corals += 1;
    }
    assert!(grown_corals > 10, "{grown_corals} corals grew");
    let rocks = changes.iter().filter(|c| c.kind == ObjectKind::Rock && c.change == ChangeKind::Grown).count();
    assert_eq!(rocks, 0, "rocks do not grow");
    let removed = changes.iter().filter(|c| c.change == ChangeKind::Removed).count();
    let plain_removed = plain.changes(0, 1).unwrap().iter().filter(|c| c.change == ChangeKind::Removed).count();
    assert_eq!(removed, plain_removed);
    // Growth compounds over visits, and a visit compared with itself has no change.
    let over_two = grown.changes(0, 2).unwrap();
    let one = changes.iter().find(|c| c.change == ChangeKind::Grown).unwrap();
    let later = over_two.iter().find(|c| c.id == one.id).unwrap();
    assert!(later.change != ChangeKind::Grown || later.growth > one.growth);
    assert!(grown.changes(1, 1).unwrap().iter().all(|c| c.change == ChangeKind::Unchanged));
}

#[test]
fn coral_cover_follows_the_option_and_the_plan_keeps_its_kinds() {
    let cover = |c: Option<f64>| {
        let survey = plan(&SynthOptions { cover: c, ..small(ChangeGrade::None, 1, 4) }).unwrap();
        let kinds = |kind: ObjectKind| survey.objects(0).unwrap().iter().filter(|o| o.kind == kind).count();
        let counts = [ObjectKind::CoralHead, ObjectKind::CoralTable, ObjectKind::BranchingCoral].map(kinds);
        (survey.coral_cover(0).unwrap(), counts)
    };
    let (default, _) = cover(None);
    assert!((0.12..0.3).contains(&default), "the reef's own cover {default}");
    for target in [0.08, 0.45] {
        let (seen, counts) = cover(Some(target));
        assert!((seen - target).abs() < 0.05, "asked {target}, seen {seen}");
        assert!(counts.iter().all(|&n| n > 0), "{counts:?} heads, tables, branching at {target}");
    }
    let message = plan(&SynthOptions { cover: Some(0.95), ..Default::default() }).unwrap_err().to_string();
    assert!(message.contains("cover 0.95"), "{message}");
}

#[test]
fn growth_is_read_as_a_preset_a_fraction_or_per_type() {
    assert_eq!("yearly".parse::<Growth>().unwrap(), Growth::YEARLY);
    assert_eq!("none".parse::<Growth>().unwrap(), Growth::NONE);
    assert_eq!("0.1".parse::<Growth>().unwrap(), Growth { head: 0.1, table: 0.1, branching: 0.1 });
    assert_eq!("branching=0.3".parse::<Growth>().unwrap(), Growth { branching: 0.3, ..Growth::YEARLY });
    for bad in ["fast", "head=x", "trunk=0.1", "1.5", "-0.1"] {
        let message = bad.parse::<Growth>().unwrap_err().to_string();
        assert!(message.contains(bad), "{message}");
    }
}

#[test]
fn evaluation_points_land_in_img1_on_the_same_unchanged_structure() {
    let survey = mild();
    let overlaps = survey.overlaps(0.1).unwrap();
    let options = EvaluationOptions { pairs: 4, min_separation_px: 15.0, border_px: 6.0, ..Default::default() };
    let pairs = survey.evaluation_points(0, 1, &overlaps, &options).unwrap();
    assert!(!pairs.is_empty());
    let model = survey.truth_model();
    for pair in &pairs {
        assert!(pair.img0.starts_with("s1/") && pair.img1.starts_with("s2/"));
        assert!(pair.uv_clicked.len() >= 4 && pair.uv_clicked.len() == pair.uv_groundtruth.len());
        let i = model.image_by_name(&pair.img0).unwrap().image_id as usize - 1;
        let j = model.image_by_name(&pair.img1).unwrap().image_id as usize - 1;
        let (r0, r1) = (survey.render(i).unwrap(), survey.render(j).unwrap());
        for (c, g) in pair.uv_clicked.iter().zip(&pair.uv_groundtruth) {
            assert!(g[0] > 0.0 && g[1] > 0.0 && g[0] < 160.0 && g[1] < 120.0, "{g:?} outside img1");
            let id0 = r0.object_id[c[1] as usize * 160 + c[0] as usize];
            let id1 = r1.object_id[g[1] as usize * 160 + g[0] as usize];
            assert_eq!(id0, id1);
            assert!(survey.object_unchanged(id0, 0, 1));
            assert_ne!(r1.depth_m[g[1] as usize * 160 + g[0] as usize], NO_DEPTH);
        }
    }
}

#[test]
fn bad_options_are_rejected_with_the_option_named() {
    let bad = |o: SynthOptions| plan(&o).unwrap_err().to_string();
    assert!(bad(SynthOptions { sessions: 0, ..Default::default() }).contains("sessions"));
    assert!(bad(SynthOptions { images_per_session: 1, ..Default::default() }).contains("images per session"));
    assert!(bad(SynthOptions { width: 32, ..Default::default() }).contains("image size"));
    assert!(matches!("hurricane".parse::<ChangeGrade>(), Err(SynthError::UnknownChange(_))));
    assert_eq!("Storm".parse::<ChangeGrade>().unwrap(), ChangeGrade::Storm);
}
