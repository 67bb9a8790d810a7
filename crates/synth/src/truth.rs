//! Derived truth: which cross-session image pairs overlap and by how much, and
//! evaluation points in the published protocol's form (a pixel clicked in img0
//! and where the same seabed point lies in img1).

use std::collections::HashMap;

use nalgebra::{Point2, Point3};
use rayon::prelude::*;
use serde::Serialize;

use crate::noise::SplitMix64;
use crate::render::NO_OBJECT;
use crate::scene::{surface_heights_m, ObjectKind, ObjectState};
use crate::survey::Survey;
use crate::SynthError;

/// What became of one structure between two visits, the most telling first:
/// a moved coral may also have grown and bleached.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ChangeKind {
    Removed,
    New,
    Moved,
    Grown,
    Bleached,
    Unchanged,
}

impl ChangeKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Removed => "removed",
            Self::New => "new",
            Self::Moved => "moved",
            Self::Grown => "grown",
            Self::Bleached => "bleached",
            Self::Unchanged => "unchanged",
        }
    }
}

/// One structure's change between two visits, for scoring a change map.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StructureChange {
    pub id: u32,
    pub kind: ObjectKind,
    pub change: ChangeKind,
    /// Centre in the earlier visit (`None` when new), world metres.
    pub centre_before_m: Option<[f64; 2]>,
    /// Centre in the later visit (`None` when removed), world metres.
    pub centre_after_m: Option<[f64; 2]>,
    /// Largest horizontal reach from its centre in either visit, metres.
    pub reach_m: f64,
    /// Horizontal displacement of the centre, metres (0 when removed or new).
    pub moved_m: f64,
    /// Turn about the vertical, degrees (0 when removed or new).
    pub turned_deg: f64,
    /// Radial (and vertical) growth: the later size over the earlier, minus 1.
    pub growth: f64,
    /// Change of the height of its top above its base, metres.
    pub height_change_m: f64,
    /// For a grown structure (0 otherwise), the change of the median height of its surface
    /// within a quarter of its reach of its centre, metres: what a surface map measures on its
    /// top (a branching coral's canopy rises less than its tips).
    pub top_change_m: f64,
    /// Change of bleaching (0 healthy, 1 white).
    pub bleach_change: f64,
    /// For a removed, new or moved structure (0 otherwise), the largest change of the visible
    /// surface's height (the seabed's or any structure's, whichever stands highest) within half
    /// its reach of where it was or is, metres: near 0 where it lay inside a larger structure's
    /// outline, beneath its surface, so that no camera saw it go or come.
    pub surface_change_m: f64,
}

impl StructureChange {
    fn between(before: Option<&ObjectState>, after: Option<&ObjectState>) -> Option<Self> {
        let either = after.or(before)?;
        let reach_m = before.map_or(0.0, ObjectState::reach_m).max(after.map_or(0.0, ObjectState::reach_m));
        let mut change = Self {
            id: either.id,
            kind: either.kind,
            change: ChangeKind::Unchanged,
            centre_before_m: before.map(|o| o.centre_m),
            centre_after_m: after.map(|o| o.centre_m),
            reach_m,
            moved_m: 0.0,
            turned_deg: 0.0,
            growth: 0.0,
            height_change_m: 0.0,
            top_change_m: 0.0,
            bleach_change: 0.0,
            surface_change_m: 0.0,
        };
        let (Some(a), Some(b)) = (before, after) else {
            change.change = if after.is_some() { ChangeKind::New } else { ChangeKind::Removed };
            return Some(change);
        };
        change.moved_m = (b.centre_m[0] - a.centre_m[0]).hypot(b.centre_m[1] - a.centre_m[1]);
        change.turned_deg = (b.angle_rad - a.angle_rad).to_degrees();
        change.growth = b.growth / a.growth - 1.0;
        change.height_change_m = b.height_m * b.growth - a.height_m * a.growth;
        change.bleach_change = b.bleach - a.bleach;
        change.change = if change.moved_m > 0.0 || change.turned_deg != 0.0 {
            ChangeKind::Moved
        } else if change.growth != 0.0 {
            ChangeKind::Grown
        } else if change.bleach_change != 0.0 {
            ChangeKind::Bleached
        } else {
            ChangeKind::Unchanged
        };
        if change.change == ChangeKind::Grown {
            let top = |state: &ObjectState| state.median_height_over_m(b.centre_m, 0.25 * reach_m);
            if let (Some(top_a), Some(top_b)) = (top(a), top(b)) {
                change.top_change_m = top_b - top_a;
            }
        }
        Some(change)
    }
}

/// A cross-session image pair that truly overlaps.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Overlap {
    /// `session/file` of the first image (the earlier session).
    pub img0: String,
    /// `session/file` of the second image (a later session).
    pub img1: String,
    /// Fraction of img0's pixels whose seabed point is visible, unchanged in
    /// depth, in img1.
    pub overlap: f64,
}

/// One image pair of the evaluation protocol: pixels clicked in img0 and their
/// true positions in img1 (COLMAP pixel convention).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvaluationPair {
    pub img0: String,
    pub img1: String,
    pub uv_clicked: Vec<[f64; 2]>,
    pub uv_groundtruth: Vec<[f64; 2]>,
}

/// How evaluation points are picked.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvaluationOptions {
    /// Image pairs per session pair. Default 30.
    pub pairs: usize,
    /// Fewest points for a pair to be kept. Default 4.
    pub min_points: usize,
    /// Most points per pair. Default 8.
    pub max_points: usize,
    /// Smallest overlap of a candidate pair. Default 0.3.
    pub min_overlap: f64,
    /// Distance of points from the image border, pixels. Default 12.
    pub border_px: f64,
    /// Smallest distance between two points of a pair, in img0 pixels. Default 40.
    pub min_separation_px: f64,
}

impl Default for EvaluationOptions {
    fn default() -> Self {
        Self { pairs: 30, min_points: 4, max_points: 8, min_overlap: 0.3, border_px: 12.0, min_separation_px: 40.0 }
    }
}

/// Downscaled geometry of one image for overlap estimates.
struct Coarse {
    session: usize,
    points: Vec<(Point3<f64>, u32)>,
    depth: Vec<f32>,
    width: usize,
    height: usize,
    centre_xy: [f64; 2],
}

fn depth_agrees(expected: f64, found: f32, relative: f64, absolute: f64) -> bool {
    found.is_finite() && (f64::from(found) - expected).abs() <= relative * expected + absolute
}

impl Survey {
    /// Every structure of visits `a` and `b` (either order) and what became of it
    /// from `a` to `b`, sorted by id.
    pub fn changes(&self, a: usize, b: usize) -> Result<Vec<StructureChange>, SynthError> {
        let (before, after) = (self.objects(a)?, self.objects(b)?);
        let mut ids: Vec<u32> = before.iter().chain(after).map(|o| o.id).collect();
        ids.sort_unstable();
        ids.dedup();
        let mut changes: Vec<StructureChange> =
            ids.into_iter().filter_map(|id| StructureChange::between(self.object(a, id), self.object(b, id))).collect();
        for change in &mut changes {
            if matches!(change.change, ChangeKind::Removed | ChangeKind::New | ChangeKind::Moved) {
                change.surface_change_m = self.surface_change_m(change, a, b)?;
            }
        }
        Ok(changes)
    }

    /// The largest change of the visible surface's height from visit `a` to `b` within half
    /// `change`'s reach of its places, sampled every centimetre.
    fn surface_change_m(&self, change: &StructureChange, a: usize, b: usize) -> Result<f64, SynthError> {
        let places: Vec<[f64; 2]> = [change.centre_before_m, change.centre_after_m].into_iter().flatten().collect();
        let radius_m = 0.5 * change.reach_m;
        let within = |p: &[f64; 2], radius_m: f64| places.iter().any(|c| (p[0] - c[0]).hypot(p[1] - c[1]) <= radius_m);
        let steps = (radius_m / 0.01).ceil() as i32;
        let points_m: Vec<[f64; 2]> = places
            .iter()
            .flat_map(|&[x, y]| {
                (-steps..=steps).flat_map(move |i| {
                    (-steps..=steps).map(move |j| [x + 0.01 * f64::from(i), y + 0.01 * f64::from(j)])
                })
            })
            .filter(|p| within(p, radius_m))
            .collect();
        let surface = |session: usize| -> Result<Vec<f64>, SynthError> {
            let near = self.objects(session)?.iter().filter(|o| within(&o.centre_m, radius_m + o.reach_m()));
            Ok(surface_heights_m(self.site(), near, &points_m))
        };
        let (before, after) = (surface(a)?, surface(b)?);
        Ok(before.iter().zip(&after).map(|(h0, h1)| (h1 - h0).abs()).fold(0.0, f64::max))
    }

    fn prepare_all(&self) -> Result<(), SynthError> {
        for s in 0..self.sessions().len() {
            self.prepare(s)?;
        }
        Ok(())
    }

    /// Overlapping cross-session pairs (img0 in an earlier session than img1)
    /// with an overlap above `min_overlap`, sorted by img0 then img1. Overlap is
    /// estimated on a grid of about 80 x 60 samples per image.
    pub fn overlaps(&self, min_overlap: f64) -> Result<Vec<Overlap>, SynthError> {
        self.prepare_all()?;
        let downscale = ((self.options().width / 80).max(1)) as usize;
        let coarse: Vec<Coarse> = (0..self.num_images())
            .into_par_iter()
            .map(|index| {
                let image = self.image(index)?;
                let (depth, ids, width, height) = self.render_geometry(index, downscale)?;
                let scale = downscale as f64;
                let mut points = Vec::new();
                for row in 0..height {
                    for col in 0..width {
                        let Some(&z) = depth.get(row * width + col) else { continue };
                        if !z.is_finite() {
                            continue;
                        }
                        let pixel = Point2::new((col as f64 + 0.5) * scale, (row as f64 + 0.5) * scale);
                        let p = self.world_point(index, pixel, f64::from(z))?;
                        points.push((p, ids.get(row * width + col).copied().unwrap_or(NO_OBJECT)));
                    }
                }
                let centre = image.cam_from_world.origin_of_target();
                Ok(Coarse { session: image.session, points, depth, width, height, centre_xy: [centre.x, centre.y] })
            })
            .collect::<Result<_, SynthError>>()?;
        let reach_m = self.sessions().iter().map(|s| s.altitude_m).fold(0.0, f64::max) * 2.0 + 0.5;
        let pairs: Vec<(usize, usize)> = (0..coarse.len())
            .flat_map(|i| (0..coarse.len()).map(move |j| (i, j)))
            .filter(|&(i, j)| match (coarse.get(i), coarse.get(j)) {
                (Some(a), Some(b)) => {
                    a.session < b.session
                        && (a.centre_xy[0] - b.centre_xy[0]).hypot(a.centre_xy[1] - b.centre_xy[1]) < reach_m
                }
                _ => false,
            })
            .collect();
        let results: Vec<Option<Overlap>> = pairs
            .par_iter()
            .map(|&(i, j)| {
                let (Some(a), Some(b), Ok(ia), Ok(ib)) = (coarse.get(i), coarse.get(j), self.image(i), self.image(j))
                else {
                    return Ok(None);
                };
                let view = self.view(b.session, &ib.cam_from_world)?.scaled(downscale);
                let visible = a
                    .points
                    .iter()
                    .filter(|(p, _)| {
                        let pc = ib.cam_from_world * *p;
                        if pc.z <= 0.05 {
                            return false;
                        }
                        let u = view.fx * pc.x / pc.z + view.cx;
                        let v = view.fy * pc.y / pc.z + view.cy;
                        if u < 0.0 || v < 0.0 || u >= b.width as f64 || v >= b.height as f64 {
                            return false;
                        }
                        let found = b.depth.get(v as usize * b.width + u as usize).copied().unwrap_or(f32::INFINITY);
                        depth_agrees(pc.z, found, 0.03, 0.03)
                    })
                    .count();
                let total = (a.width * a.height).max(1);
                let overlap = visible as f64 / total as f64;
                Ok((overlap > min_overlap).then(|| Overlap { img0: ia.name.clone(), img1: ib.name.clone(), overlap }))
            })
            .collect::<Result<_, SynthError>>()?;
        Ok(results.into_iter().flatten().collect())
    }

    /// Evaluation points between sessions `a` and `b` (a < b): image pairs
    /// chosen among `overlaps` to spread over the site, and in each, pixels of
    /// img0 on textured, unoccluded structure unchanged between the sessions,
    /// with their exact positions in img1. Sorted as chosen (spread order).
    pub fn evaluation_points(
        &self,
        a: usize,
        b: usize,
        overlaps: &[Overlap],
        options: &EvaluationOptions,
    ) -> Result<Vec<EvaluationPair>, SynthError> {
        self.prepare_all()?;
        let names: HashMap<&str, usize> =
            (0..self.num_images()).filter_map(|i| self.image(i).ok().map(|im| (im.name.as_str(), i))).collect();
        let mut candidates: Vec<(usize, usize, f64, [f64; 2])> = Vec::new();
        for o in overlaps.iter().filter(|o| o.overlap >= options.min_overlap) {
            let (Some(&i), Some(&j)) = (names.get(o.img0.as_str()), names.get(o.img1.as_str())) else { continue };
            let (ii, ij) = (self.image(i)?, self.image(j)?);
            if ii.session != a || ij.session != b {
                continue;
            }
            let (ca, cb) = (ii.cam_from_world.origin_of_target(), ij.cam_from_world.origin_of_target());
            candidates.push((i, j, o.overlap, [0.5 * (ca.x + cb.x), 0.5 * (ca.y + cb.y)]));
        }
        // Spread: start at the best overlap, then farthest-point sampling.
        let mut chosen: Vec<(usize, usize)> = Vec::new();
        let mut chosen_xy: Vec<[f64; 2]> = Vec::new();
        let mut min_dist: Vec<f64> = vec![f64::INFINITY; candidates.len()];
        let target = (options.pairs * 3 / 2).max(options.pairs);
        while chosen.len() < target.min(candidates.len()) {
            let mut best: Option<(usize, f64)> = None;
            for (k, c) in candidates.iter().enumerate() {
                let d = min_dist.get(k).copied().unwrap_or(0.0);
                if d <= 1e-9 {
                    continue;
                }
                let score = if chosen.is_empty() { c.2 } else { d + 0.05 * c.2 };
                if best.is_none_or(|(_, s)| score > s) {
                    best = Some((k, score));
                }
            }
            let Some((k, _)) = best else { break };
            let Some(&(i, j, _, xy)) = candidates.get(k) else { break };
            chosen.push((i, j));
            chosen_xy.push(xy);
            for (m, c) in candidates.iter().enumerate() {
                if let Some(d) = min_dist.get_mut(m) {
                    *d = d.min((c.3[0] - xy[0]).hypot(c.3[1] - xy[1]));
                }
            }
        }
        let found: Vec<Option<EvaluationPair>> =
            chosen.par_iter().map(|&(i, j)| self.pick_points(i, j, options)).collect::<Result<_, SynthError>>()?;
        Ok(found.into_iter().flatten().take(options.pairs).collect())
    }

    fn pick_points(
        &self,
        i: usize,
        j: usize,
        options: &EvaluationOptions,
    ) -> Result<Option<EvaluationPair>, SynthError> {
        let (im0, im1) = (self.image(i)?, self.image(j)?);
        let r0 = self.render(i)?;
        let (depth1, ids1, w1, h1) = self.render_geometry(j, 1)?;
        let view1 = self.view(im1.session, &im1.cam_from_world)?;
        let (w, h) = (r0.rgb.width() as usize, r0.rgb.height() as usize);
        let gray: Vec<f32> = r0
            .rgb
            .pixels()
            .map(|p| 0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2]))
            .collect();
        let g = |x: usize, y: usize| gray.get(y * w + x).copied().unwrap_or(0.0);
        let border = options.border_px.max(6.0) as usize;
        if w <= 2 * border || h <= 2 * border {
            return Ok(None);
        }
        // Smooth, single-object neighbourhood in a depth/id buffer.
        let stable = |depth: &[f32], ids: &[u32], width: usize, x: usize, y: usize, id: u32| -> bool {
            let Some(&d0) = depth.get(y * width + x) else { return false };
            for yy in y - 2..=y + 2 {
                for xx in x - 2..=x + 2 {
                    let k = yy * width + xx;
                    if ids.get(k) != Some(&id)
                        || !depth_agrees(f64::from(d0), depth.get(k).copied().unwrap_or(f32::INFINITY), 0.015, 0.004)
                    {
                        return false;
                    }
                }
            }
            true
        };
        let mut rng = SplitMix64::stream(self.options().seed, 0xE7A1_0000 ^ ((i as u64) << 20) ^ j as u64);
        let mut scored: Vec<(f64, usize, usize, [f64; 2])> = Vec::new();
        for _ in 0..800 {
            let x = border + rng.below(w - 2 * border);
            let y = border + rng.below(h - 2 * border);
            let Some(&id0) = r0.object_id.get(y * w + x) else { continue };
            if id0 == NO_OBJECT || !self.object_unchanged(id0, im0.session, im1.session) {
                continue;
            }
            if !stable(&r0.depth_m, &r0.object_id, w, x, y, id0) {
                continue;
            }
            // Texture: the smaller eigenvalue of the structure tensor over 7x7.
            let (mut sxx, mut syy, mut sxy) = (0.0f64, 0.0f64, 0.0f64);
            for yy in y - 3..=y + 3 {
                for xx in x - 3..=x + 3 {
                    let gx = f64::from(g(xx + 1, yy) - g(xx - 1, yy)) * 0.5;
                    let gy = f64::from(g(xx, yy + 1) - g(xx, yy - 1)) * 0.5;
                    sxx += gx * gx;
                    syy += gy * gy;
                    sxy += gx * gy;
                }
            }
            let half_trace = 0.5 * (sxx + syy);
            let lambda_min = (half_trace - ((0.5 * (sxx - syy)).powi(2) + sxy * sxy).sqrt()) / 49.0;
            if lambda_min < 4.0 {
                continue;
            }
            let clicked = Point2::new(x as f64 + 0.5, y as f64 + 0.5);
            let Some(&z0) = r0.depth_m.get(y * w + x) else { continue };
            let p = self.world_point(i, clicked, f64::from(z0))?;
            let pc = im1.cam_from_world * p;
            if pc.z <= 0.05 {
                continue;
            }
            let u = view1.fx * pc.x / pc.z + view1.cx;
            let v = view1.fy * pc.y / pc.z + view1.cy;
            let b = options.border_px;
            if u < b || v < b || u >= w1 as f64 - b || v >= h1 as f64 - b {
                continue;
            }
            let (x1, y1) = (u as usize, v as usize);
            if x1 < 2 || y1 < 2 || x1 + 2 >= w1 || y1 + 2 >= h1 {
                continue;
            }
            let found = depth1.get(y1 * w1 + x1).copied().unwrap_or(f32::INFINITY);
            if !depth_agrees(pc.z, found, 0.01, 0.01) || !stable(&depth1, &ids1, w1, x1, y1, id0) {
                continue;
            }
            scored.push((lambda_min, x, y, [u, v]));
        }
        scored.sort_by(|p, q| q.0.total_cmp(&p.0).then(p.2.cmp(&q.2)).then(p.1.cmp(&q.1)));
        let mut uv_clicked: Vec<[f64; 2]> = Vec::new();
        let mut uv_groundtruth = Vec::new();
        for (_, x, y, uv) in scored {
            if uv_clicked.len() >= options.max_points {
                break;
            }
            let c = [x as f64 + 0.5, y as f64 + 0.5];
            if uv_clicked.iter().any(|q| (q[0] - c[0]).hypot(q[1] - c[1]) < options.min_separation_px) {
                continue;
            }
            uv_clicked.push(c);
            uv_groundtruth.push(uv);
        }
        if uv_clicked.len() < options.min_points {
            return Ok(None);
        }
        Ok(Some(EvaluationPair { img0: im0.name.clone(), img1: im1.name.clone(), uv_clicked, uv_groundtruth }))
    }
}
