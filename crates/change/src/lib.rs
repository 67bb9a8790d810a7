//! revisit-change: where the reef changed between two visits of one joint model.
//!
//! [`detect`] compares the surface visit B saw with visit A's, each a point cloud in the joint
//! model's frame: either each visit's dense surface from its own images at the model's poses
//! (revisit-colmap's `dense`, what `revisit change` uses by default: sparse points sample
//! texture, and a smooth coral table that a storm removed holds almost none), or
//! [`sparse_surfaces`]: the model's points tagged with the visits whose images observe them
//! ([`visits_of_points`]), a visit's surface being the points only it observes (a point
//! tracked across both is one sample of both surfaces: it would pull their difference to zero
//! and hide the registration error). The comparison is made in the manner of M3C2 (Lague,
//! Brodu and Leroux 2013, ISPRS J. 82): on a grid of core points over the site, a normal is
//! fitted to A's points around each, and the change is the distance between the medians of
//! A's and B's points along that normal, within a cylinder.
//! Each carries its 95% level of detection, `LoD95 = 1.96 (sqrt(vA + vB) + reg)`, M3C2's form
//! with two departures made for sparse points: `vA`, `vB` are the variances of each visit's
//! median by a seeded bootstrap, not `s^2/n` (at a colony's edge a cylinder's points sit on two
//! surfaces, the share on each differs between visits, and only the bootstrap sees that the
//! median may land on either), and `reg`, the registration error between the visits, is
//! estimated from the data as the median change's magnitude plus its robust spread (1.4826 x
//! MAD) over the whole overlap (most of a reef does not change between visits; registration
//! differs everywhere, and an offset common to the whole overlap looks like one).
//! Cells whose change exceeds their LoD95 are grouped into [`Region`]s of one sign.
//!
//! Outputs: [`encode_ply`] (core points coloured by signed change, with the change and its
//! LoD95 as properties), [`map_png`] (a top-down map with a scale bar and a colour bar) and
//! [`regions_csv`]; [`truth`] scores a map against the synthetic reef's truth.
//!
//! Units are the model's: metres when the model was placed on navigation, COLMAP's
//! arbitrary unit otherwise (the caller names it). Defaults scale with the survey's
//! altitude (the median camera-to-point depth), so they hold in either.
//!
//! Invariant: pure functions over a model; no file I/O (the CLI reads and writes).

mod output;
pub mod truth;

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use revisit_core::{session_of, Point3DId, Reconstruction};
use serde::Serialize;

pub use output::{encode_ply, map_png, regions_csv};

/// The region size `ChangeOptions::region_lod_factor` is stated for: a 3 x 3 patch.
const REGION_REFERENCE_CELLS: f64 = 9.0;

/// Largest relief of the lower visit's surface around a region, as a share of the region's mean
/// change, for the region to stand on level ground (`ChangeOptions::level_lod_factor`).
pub const LEVEL_RELIEF: f64 = 0.5;

/// Most grid cells a map may have.
pub const MAX_CELLS: usize = 16_000_000;

/// How the comparison is made. Sizes are in model units; `None` takes the default, a
/// fraction of the survey's altitude.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChangeOptions {
    /// Spacing of the core points (grid cell side). Default `cell_of_altitude` of the altitude.
    pub cell: Option<f64>,
    /// Radius of the cylinder the distance is measured in. Default `radius_of_altitude` of the
    /// altitude.
    pub radius: Option<f64>,
    /// The default cell as a fraction of the altitude: 2.5% for dense surfaces (5 cm at 2 m),
    /// 4% for sparse ones.
    pub cell_of_altitude: f64,
    /// The default radius as a fraction of the altitude: 4% for dense surfaces, under the
    /// smallest colonies' reach (12-20 cm at 2 m) so that the median in a cylinder on one stands
    /// on it; 8% for sparse ones, which hold few points in a smaller cylinder.
    pub radius_of_altitude: f64,
    /// Radius of the neighbourhood of visit A's points a normal is fitted to. Default 50% of
    /// the altitude: large against a coral, so normals follow the reef, not a colony's flank.
    pub normal_radius: Option<f64>,
    /// Half length of the cylinder along the normal: the largest change measured. Default
    /// 50% of the altitude.
    pub max_depth: Option<f64>,
    /// Fewest points of each visit in a cylinder for a measurement. Default 4.
    pub min_points: usize,
    /// Fewest points of each visit within half the cylinder's radius of its axis. Default 3: a
    /// cylinder one visit sees only at its rim (the sand beyond a coral table's plate, hidden
    /// from that visit's side) would compare two different surfaces.
    pub min_inner_points: usize,
    /// Largest share of the higher visit's points in a cylinder that lie at the lower visit's
    /// level (within a quarter of the cylinder's radius of its median) for a change beyond
    /// half the radius to be measured. Default 0.3: where the earlier visit also saw the sand
    /// the later one shows (through a branching coral's gaps), the later visit's missing
    /// branches may be branches it did not resolve; on the unchanged test reef such a coral
    /// made the one false region (README).
    pub max_seen_through: f64,
    /// Fewest cells of a reported region. Default 3.
    pub min_cells: usize,
    /// A region of nine cells (a 3 x 3 patch) is reported when its mean change is at least
    /// this many times its cells' mean LoD95; a region of n cells when it is at least this
    /// times sqrt(9 / n) times it (the mean over more cells is surer). Default 2.5: a guard
    /// against chance clusters, since one cell in twenty exceeds its LoD95 by chance and a
    /// map tests thousands (on seven storm surveys and three unchanged ones, 2 left a false
    /// region on an unchanged coral's rim and 2.5 none, finding the same corals).
    pub region_lod_factor: f64,
    /// The factor for a region on level ground: where the lower visit's surface over the region
    /// and two cells around it has a relief (10th to 90th percentile of its height) under
    /// [`LEVEL_RELIEF`] of the region's mean change, the change is a structure that came or left
    /// on open ground, not the rim of one both visits saw (where dense surfaces err). Default
    /// 1.25, and asked of the region's median cell (a colony changes its whole footprint; a
    /// dense surface's spike, one cell): on seven storm surveys it finds small colonies (reach
    /// 20 cm, 5-8 cm of relief) that 2.5 misses, with no false region there or on three
    /// unchanged surveys, dense or sparse (1.0 left one on the sparse map of one; README).
    pub level_lod_factor: f64,
    /// Fewest observations of a point for it to count. Default 3: a point seen in two
    /// images has the least certain depth.
    pub min_track: usize,
}

/// The defaults for dense surfaces ([`ChangeOptions::sparse`] for the model's points).
impl Default for ChangeOptions {
    fn default() -> Self {
        Self {
            cell: None,
            radius: None,
            cell_of_altitude: 0.025,
            radius_of_altitude: 0.04,
            normal_radius: None,
            max_depth: None,
            min_points: 4,
            min_inner_points: 3,
            max_seen_through: 0.3,
            min_cells: 3,
            region_lod_factor: 2.5,
            level_lod_factor: 1.25,
            min_track: 3,
        }
    }
}

impl ChangeOptions {
    /// The defaults for sparse surfaces (the model's points): a coarser grid and wider
    /// cylinders, and no inner points asked of a surface too thin for it.
    pub fn sparse() -> Self {
        Self { cell_of_altitude: 0.04, radius_of_altitude: 0.08, min_inner_points: 0, ..Self::default() }
    }

    /// Each option's value, checked (before any work is done), with the option named.
    pub fn check(&self) -> Result<(), ChangeError> {
        let sizes = [
            (self.cell, "--cell"),
            (self.radius, "--radius"),
            (self.normal_radius, "--normal-radius"),
            (self.max_depth, "--max-depth"),
        ];
        for (value, option) in sizes {
            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(ChangeError::BadOption { option, reason: format!("{v} is not a positive size") });
            }
        }
        for (fraction, name) in
            [(self.cell_of_altitude, "cell_of_altitude"), (self.radius_of_altitude, "radius_of_altitude")]
        {
            if !(fraction.is_finite() && fraction > 0.0) {
                return Err(ChangeError::BadOption {
                    option: name,
                    reason: format!("{fraction} is not a positive fraction"),
                });
            }
        }
        for (factor, option) in
            [(self.region_lod_factor, "--region-lod-factor"), (self.level_lod_factor, "--level-lod-factor")]
        {
            if !(factor.is_finite() && factor >= 0.0) {
                let reason = format!("{factor} is not a factor of 0 or more");
                return Err(ChangeError::BadOption { option, reason });
            }
        }
        if !(0.0..=1.0).contains(&self.max_seen_through) {
            let reason = format!("{} is not a share from 0 to 1", self.max_seen_through);
            return Err(ChangeError::BadOption { option: "--max-seen-through", reason });
        }
        if self.min_points < 1 {
            return Err(ChangeError::BadOption { option: "--min-points", reason: "must be at least 1".into() });
        }
        Ok(())
    }
}

/// The sizes a map was made with, model units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scales {
    /// Median depth of the visits' points in their images: the survey's altitude.
    pub altitude: f64,
    pub cell: f64,
    pub radius: f64,
    pub normal_radius: f64,
    pub max_depth: f64,
}

/// The map's frame: a plane fitted to the site, `up` towards the cameras; `east` is the
/// model's x axis laid on the plane (east in an ENU navigation frame), `north = up x east`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MapFrame {
    pub origin: Point3<f64>,
    pub east: Vector3<f64>,
    pub north: Vector3<f64>,
    pub up: Vector3<f64>,
}

impl MapFrame {
    /// Map coordinates (east, north) and height above the plane of a model point.
    pub fn to_map(&self, point: &Point3<f64>) -> [f64; 3] {
        let d = point - self.origin;
        [d.dot(&self.east), d.dot(&self.north), d.dot(&self.up)]
    }

    /// The model point at map coordinates and height.
    pub fn to_model(&self, east: f64, north: f64, height: f64) -> Point3<f64> {
        self.origin + self.direction_to_model(&Vector3::new(east, north, height))
    }

    /// A direction given in map axes (east, north, up), in the model frame.
    pub fn direction_to_model(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.east * v.x + self.north * v.y + self.up * v.z
    }
}

/// The grid of core points: `cols x rows` cells of side `cell`, the first cell's lower-left
/// corner at map coordinates `min`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Grid {
    pub cols: usize,
    pub rows: usize,
    pub cell: f64,
    pub min: [f64; 2],
}

impl Grid {
    /// Map coordinates of a cell's centre.
    pub fn centre(&self, col: usize, row: usize) -> [f64; 2] {
        [self.min[0] + (col as f64 + 0.5) * self.cell, self.min[1] + (row as f64 + 0.5) * self.cell]
    }

    fn index_of(&self, map: [f64; 2]) -> (i64, i64) {
        (((map[0] - self.min[0]) / self.cell).floor() as i64, ((map[1] - self.min[1]) / self.cell).floor() as i64)
    }
}

/// One core point where both visits had enough points to measure.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Cell {
    pub col: usize,
    pub row: usize,
    /// The core point, on visit A's surface, model frame.
    pub core: Point3<f64>,
    /// Unit normal of visit A's surface there, towards the cameras.
    pub normal: Vector3<f64>,
    /// Signed distance from A's surface to B's along the normal (positive: B stands higher,
    /// as a coral that grew or arrived; negative: lower, as one that broke or left).
    pub change: f64,
    /// 95% level of detection of `change`.
    pub lod95: f64,
    pub points_from: usize,
    pub points_to: usize,
    /// `|change| > lod95`.
    pub significant: bool,
}

/// Raised (B above A) or lowered.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Sign {
    Raised,
    Lowered,
}

impl Sign {
    pub fn name(self) -> &'static str {
        match self {
            Self::Raised => "raised",
            Self::Lowered => "lowered",
        }
    }

    fn of(change: f64) -> Self {
        if change >= 0.0 {
            Self::Raised
        } else {
            Self::Lowered
        }
    }
}

/// Significant cells of one sign, connected (8-neighbours).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Region {
    /// 1, 2, ... by decreasing area.
    pub id: usize,
    pub sign: Sign,
    /// Indices into [`ChangeMap::cells`].
    pub cells: Vec<usize>,
    /// Cells x cell side squared, model units squared.
    pub area: f64,
    /// Mean of the cells' core points, model frame.
    pub centre: Point3<f64>,
    /// Mean of the cells' centres, map coordinates.
    pub centre_map: [f64; 2],
    pub mean_change: f64,
    /// The cell change of largest magnitude.
    pub peak_change: f64,
    pub mean_lod95: f64,
}

/// Where visit `to` differs from visit `from`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChangeMap {
    pub from: String,
    pub to: String,
    pub scales: Scales,
    pub frame: MapFrame,
    pub grid: Grid,
    /// Points observed by `from` only, by `to` only, and by both (left out of the comparison).
    pub points_from: usize,
    pub points_to: usize,
    pub points_shared: usize,
    /// Measured cells, in grid order (row, then column).
    pub cells: Vec<Cell>,
    /// The registration term of the LoD95: the median change's magnitude plus 1.4826 x the
    /// MAD of the change over all cells.
    pub registration: f64,
    /// Median change over all cells: a vertical offset between the visits' surfaces.
    pub median_change: f64,
    pub regions: Vec<Region>,
}

impl ChangeMap {
    pub fn significant_cells(&self) -> usize {
        self.cells.iter().filter(|c| c.significant).count()
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ChangeError {
    #[error("visit {visit} has no image in the model (its visits: {present})")]
    NoVisit { visit: String, present: String },
    #[error("--from and --to name the same visit ({0})")]
    SameVisit(String),
    #[error("the surface of visit {visit} has {points} points (sparse: those only it observes, in --min-track images or more): too few to compare")]
    TooFewPoints { visit: String, points: usize },
    #[error("invalid option {option}: {reason}")]
    BadOption { option: &'static str, reason: String },
    #[error("the visits do not overlap: no core point has {0} points of each")]
    NoOverlap(usize),
}

/// The visits (sessions) observing each point of the model, by point id.
pub fn visits_of_points(model: &Reconstruction) -> BTreeMap<Point3DId, BTreeSet<&str>> {
    let session_of_image: BTreeMap<_, &str> =
        model.images.iter().map(|(id, image)| (*id, session_of(&image.name))).collect();
    model
        .points3d
        .iter()
        .map(|(id, point)| {
            let visits = point.track.iter().filter_map(|t| session_of_image.get(&t.image_id).copied()).collect();
            (*id, visits)
        })
        .collect()
}

/// Each visit's surface as two point clouds, model frame, and how many points were left out
/// as seen by both.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Surfaces {
    pub from: Vec<Point3<f64>>,
    pub to: Vec<Point3<f64>>,
    /// Points of the joint model observed by both visits (left out: see the crate's text); 0
    /// for surfaces made from each visit's images alone.
    pub shared: usize,
}

/// The visits' surfaces as the joint model's sparse points sample them: each visit's points
/// that only it observes, in `options.min_track` images or more.
pub fn sparse_surfaces(
    model: &Reconstruction,
    from: &str,
    to: &str,
    options: &ChangeOptions,
) -> Result<Surfaces, ChangeError> {
    check_visits(model, from, to)?;
    let visits = visits_of_points(model);
    let mut surfaces = Surfaces::default();
    for (id, point) in model.points3d.iter().filter(|(_, p)| p.track.len() >= options.min_track) {
        let seen = &visits[id];
        match (seen.contains(from), seen.contains(to)) {
            (true, true) => surfaces.shared += 1,
            (true, false) => surfaces.from.push(point.xyz),
            (false, true) => surfaces.to.push(point.xyz),
            (false, false) => {}
        }
    }
    Ok(surfaces)
}

/// Both visits have images in the model, and they differ.
pub fn check_visits(model: &Reconstruction, from: &str, to: &str) -> Result<(), ChangeError> {
    if from == to {
        return Err(ChangeError::SameVisit(from.to_owned()));
    }
    let present: BTreeSet<&str> = model.images.values().map(|image| session_of(&image.name)).collect();
    for visit in [from, to] {
        if !present.contains(visit) {
            let present = present.iter().copied().collect::<Vec<_>>().join(", ");
            return Err(ChangeError::NoVisit { visit: visit.to_owned(), present });
        }
    }
    Ok(())
}

/// Compares visit `to`'s surface with visit `from`'s (see the crate's text). `model` gives the
/// visits' cameras (where up is, and the altitude the default sizes scale with).
pub fn detect(
    model: &Reconstruction,
    from: &str,
    to: &str,
    surfaces: &Surfaces,
    options: &ChangeOptions,
) -> Result<ChangeMap, ChangeError> {
    check_visits(model, from, to)?;
    let Surfaces { from: cloud_from, to: cloud_to, shared } = surfaces;
    for (visit, cloud) in [(from, cloud_from), (to, cloud_to)] {
        if cloud.len() < 10 {
            return Err(ChangeError::TooFewPoints { visit: visit.to_owned(), points: cloud.len() });
        }
    }

    let scales = resolve_scales(model, [from, to], options)?;
    let frame = map_frame(model, [from, to], cloud_from.iter().chain(cloud_to));
    let map_from: Vec<[f64; 3]> = cloud_from.iter().map(|p| frame.to_map(p)).collect();
    let map_to: Vec<[f64; 3]> = cloud_to.iter().map(|p| frame.to_map(p)).collect();
    let grid = grid_over(map_from.iter().chain(&map_to), scales.cell)?;
    let index_from = Buckets::new(&grid, &map_from);
    let index_to = Buckets::new(&grid, &map_to);

    let mut cells = Vec::new();
    for row in 0..grid.rows {
        for col in 0..grid.cols {
            if let Some(cell) = measure(&grid, &frame, &scales, options, (col, row), [&index_from, &index_to]) {
                cells.push(cell);
            }
        }
    }
    if cells.is_empty() {
        return Err(ChangeError::NoOverlap(options.min_points));
    }
    let changes: Vec<f64> = cells.iter().map(|c| c.change).collect();
    let median_change = median(&changes);
    let deviations: Vec<f64> = changes.iter().map(|c| (c - median_change).abs()).collect();
    // A vertical offset common to the whole overlap cannot be told from a registration error.
    let registration = median_change.abs() + 1.4826 * median(&deviations);
    for cell in &mut cells {
        cell.lod95 += 1.96 * registration;
        cell.significant = cell.change.abs() > cell.lod95;
    }
    let regions = regions(&grid, &frame, &cells, options);
    Ok(ChangeMap {
        from: from.to_owned(),
        to: to.to_owned(),
        scales,
        frame,
        grid,
        points_from: cloud_from.len(),
        points_to: cloud_to.len(),
        points_shared: *shared,
        cells,
        registration,
        median_change,
        regions,
    })
}

fn resolve_scales(model: &Reconstruction, visits: [&str; 2], options: &ChangeOptions) -> Result<Scales, ChangeError> {
    let mut depths = Vec::new();
    for image in model.images.values().filter(|image| visits.contains(&session_of(&image.name))) {
        let mut own: Vec<f64> = image
            .points2d
            .iter()
            .filter_map(|o| o.point3d_id.and_then(|id| model.points3d.get(&id)))
            .map(|p| image.cam_from_world.transform_point(&p.xyz).z)
            .filter(|z| *z > 0.0)
            .collect();
        if !own.is_empty() {
            own.sort_by(f64::total_cmp);
            depths.push(own[own.len() / 2]);
        }
    }
    let altitude = median(&depths);
    if !(altitude.is_finite() && altitude > 0.0) {
        return Err(ChangeError::TooFewPoints { visit: visits.join(" and "), points: 0 });
    }
    options.check()?;
    let pick = |value: Option<f64>, fraction: f64| value.unwrap_or(fraction * altitude);
    Ok(Scales {
        altitude,
        cell: pick(options.cell, options.cell_of_altitude),
        radius: pick(options.radius, options.radius_of_altitude),
        normal_radius: pick(options.normal_radius, 0.5),
        max_depth: pick(options.max_depth, 0.5),
    })
}

/// The site's plane (least squares), `up` towards the visits' cameras.
fn map_frame<'a>(model: &Reconstruction, visits: [&str; 2], points: impl Iterator<Item = &'a Point3<f64>>) -> MapFrame {
    let points: Vec<&Point3<f64>> = points.collect();
    let centroid = Point3::from(points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64);
    let normal = smallest_axis(points.iter().map(|p| *p - centroid));
    let cameras: Vec<Vector3<f64>> = model
        .images
        .values()
        .filter(|image| visits.contains(&session_of(&image.name)))
        .map(|image| image.cam_from_world.origin_of_target().coords)
        .collect();
    let towards_cameras = cameras.iter().sum::<Vector3<f64>>() / cameras.len().max(1) as f64 - centroid.coords;
    let up = if normal.dot(&towards_cameras) < 0.0 { -normal } else { normal };
    let on_plane = |axis: Vector3<f64>| axis - up * axis.dot(&up);
    let x = on_plane(Vector3::x());
    let east = if x.norm() > 0.1 { x.normalize() } else { on_plane(Vector3::y()).normalize() };
    MapFrame { origin: centroid, east, north: up.cross(&east), up }
}

/// Unit eigenvector of the smallest eigenvalue of the scatter of `offsets`.
fn smallest_axis(offsets: impl Iterator<Item = Vector3<f64>>) -> Vector3<f64> {
    let scatter: Matrix3<f64> = offsets.map(|d| d * d.transpose()).sum();
    let eigen = SymmetricEigen::new(scatter);
    let smallest = eigen.eigenvalues.imin();
    eigen.eigenvectors.column(smallest).into_owned()
}

fn grid_over<'a>(points: impl Iterator<Item = &'a [f64; 3]>, cell: f64) -> Result<Grid, ChangeError> {
    let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        for k in 0..2 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let cols = ((max[0] - min[0]) / cell).floor() as usize + 1;
    let rows = ((max[1] - min[1]) / cell).floor() as usize + 1;
    if cols.saturating_mul(rows) > MAX_CELLS {
        return Err(ChangeError::BadOption {
            option: "--cell",
            reason: format!("{cell} makes a {cols} x {rows} grid, more than {MAX_CELLS} cells: choose a larger cell"),
        });
    }
    Ok(Grid { cols, rows, cell, min })
}

/// A visit's points in map coordinates, bucketed by grid cell.
struct Buckets<'a> {
    grid: Grid,
    points: &'a [[f64; 3]],
    /// Point indices by cell, `row * cols + col`.
    cells: Vec<Vec<u32>>,
}

impl<'a> Buckets<'a> {
    fn new(grid: &Grid, points: &'a [[f64; 3]]) -> Self {
        let mut cells = vec![Vec::new(); grid.cols * grid.rows];
        for (k, p) in points.iter().enumerate() {
            let (col, row) = grid.index_of([p[0], p[1]]);
            let index = row as usize * grid.cols + col as usize;
            cells[index].push(k as u32);
        }
        Self { grid: *grid, points, cells }
    }

    /// Points within `radius` (map distance) of `centre`.
    fn near(&self, centre: [f64; 2], radius: f64) -> Vec<[f64; 3]> {
        let reach = (radius / self.grid.cell).ceil() as i64;
        let (col, row) = self.grid.index_of(centre);
        let mut found = Vec::new();
        for r in (row - reach).max(0)..=(row + reach).min(self.grid.rows as i64 - 1) {
            for c in (col - reach).max(0)..=(col + reach).min(self.grid.cols as i64 - 1) {
                for &k in &self.cells[r as usize * self.grid.cols + c as usize] {
                    let p = self.points[k as usize];
                    if (p[0] - centre[0]).hypot(p[1] - centre[1]) <= radius {
                        found.push(p);
                    }
                }
            }
        }
        found
    }
}

/// The M3C2 measurement at one core point, or `None` where either visit has too few points.
/// `lod95` holds the sampling term only; the registration term is added once all cells are in.
fn measure(
    grid: &Grid,
    frame: &MapFrame,
    scales: &Scales,
    options: &ChangeOptions,
    (col, row): (usize, usize),
    [from, to]: [&Buckets; 2],
) -> Option<Cell> {
    let centre = grid.centre(col, row);
    let around = from.near(centre, scales.normal_radius);
    if around.len() < options.min_points.max(3) {
        return None;
    }
    let mean = around.iter().fold(Vector3::zeros(), |s, p| s + Vector3::from(*p)) / around.len() as f64;
    let normal = smallest_axis(around.iter().map(|p| Vector3::from(*p) - mean));
    let normal = if normal.z < 0.0 { -normal } else { normal };
    // Steeper than 60 degrees: a colony's flank, not a surface seen from above.
    if normal.z < 0.5 {
        return None;
    }
    let mut heights: Vec<f64> = from.near(centre, scales.radius).iter().map(|p| p[2]).collect();
    if heights.is_empty() {
        return None;
    }
    let core = Vector3::new(centre[0], centre[1], median_in_place(&mut heights));
    let tilt = (1.0 - normal.z * normal.z).max(0.0).sqrt();
    let search = scales.radius + scales.max_depth * tilt;
    let along = |buckets: &Buckets| -> (Vec<f64>, usize) {
        let mut inner = 0;
        let distances = buckets
            .near(centre, search)
            .iter()
            .filter_map(|p| {
                let d = Vector3::from(*p) - core;
                let distance = d.dot(&normal);
                let lateral = (d - normal * distance).norm();
                let inside = lateral <= scales.radius && distance.abs() <= scales.max_depth;
                inner += usize::from(inside && lateral <= scales.radius / 2.0);
                inside.then_some(distance)
            })
            .collect();
        (distances, inner)
    };
    let ((mut a, inner_a), (mut b, inner_b)) = (along(from), along(to));
    if a.len() < options.min_points || b.len() < options.min_points {
        return None;
    }
    // Seen only at its rim by one visit (a table's plate hiding the sand beyond it from one
    // side), the cylinder would compare two different surfaces.
    if inner_a < options.min_inner_points || inner_b < options.min_inner_points {
        return None;
    }
    let seed = 2 * (row * grid.cols + col) as u64;
    let sampling = (median_variance(&a, seed) + median_variance(&b, seed + 1)).sqrt();
    let (median_a, median_b) = (median_in_place(&mut a), median_in_place(&mut b));
    let change = median_b - median_a;
    // The lower visit's level, as seen by the higher one: a visit that also saw it (through a
    // branching coral's gaps) cannot tell a coral gone from one the other visit did not resolve.
    let level = scales.radius / 4.0;
    let share_at = |values: &[f64], at: f64| values.iter().filter(|v| (**v - at).abs() <= level).count() as f64;
    let seen_through =
        if change < 0.0 { share_at(&a, median_b) / a.len() as f64 } else { share_at(&b, median_a) / b.len() as f64 };
    if change.abs() > 2.0 * level && seen_through > options.max_seen_through {
        return None;
    }
    Some(Cell {
        col,
        row,
        core: frame.to_model(core.x, core.y, core.z),
        normal: frame.direction_to_model(&normal),
        change,
        lod95: 1.96 * sampling,
        points_from: a.len(),
        points_to: b.len(),
        significant: false,
    })
}

/// Significant cells grouped by sign into 8-connected regions of at least `min_cells` whose
/// change passes its level of detection (the mean at `region_lod_factor`, or on level ground the
/// median at `level_lod_factor`), largest first.
fn regions(grid: &Grid, frame: &MapFrame, cells: &[Cell], options: &ChangeOptions) -> Vec<Region> {
    let measured: BTreeMap<(usize, usize), usize> =
        cells.iter().enumerate().map(|(k, cell)| ((cell.col, cell.row), k)).collect();
    let mut at = measured.clone();
    at.retain(|_, k| cells[*k].significant);
    let mut taken = vec![false; cells.len()];
    let mut found = Vec::new();
    for (&(col, row), &start) in &at {
        if taken[start] {
            continue;
        }
        let sign = Sign::of(cells[start].change);
        let (mut members, mut queue) = (Vec::new(), vec![(col, row)]);
        taken[start] = true;
        while let Some((c, r)) = queue.pop() {
            members.push(at[&(c, r)]);
            for (dc, dr) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nc, nr) = (c as i64 + dc, r as i64 + dr);
                if nc < 0 || nr < 0 {
                    continue;
                }
                let key = (nc as usize, nr as usize);
                if let Some(&k) = at.get(&key) {
                    if !taken[k] && Sign::of(cells[k].change) == sign {
                        taken[k] = true;
                        queue.push(key);
                    }
                }
            }
        }
        if members.len() < options.min_cells.max(1) {
            continue;
        }
        members.sort_unstable();
        let n = members.len() as f64;
        let centre = members.iter().map(|&k| cells[k].core.coords).sum::<Vector3<f64>>() / n;
        let centre_map = members.iter().fold([0.0, 0.0], |s, &k| {
            let c = grid.centre(cells[k].col, cells[k].row);
            [s[0] + c[0] / n, s[1] + c[1] / n]
        });
        let peak_change = members.iter().map(|&k| cells[k].change).max_by(|a, b| a.abs().total_cmp(&b.abs()));
        found.push(Region {
            id: 0,
            sign,
            area: n * grid.cell * grid.cell,
            centre: Point3::from(centre),
            centre_map,
            mean_change: members.iter().map(|&k| cells[k].change).sum::<f64>() / n,
            peak_change: peak_change.unwrap_or(0.0),
            mean_lod95: members.iter().map(|&k| cells[k].lod95).sum::<f64>() / n,
            cells: members,
        });
        let needed =
            |r: &Region, factor: f64| factor * (REGION_REFERENCE_CELLS / r.cells.len() as f64).sqrt() * r.mean_lod95;
        // On level ground the median cell must pass: a colony changes its whole footprint, a
        // dense surface's spike one cell.
        let median_change = |r: &Region| median(&r.cells.iter().map(|&k| cells[k].change).collect::<Vec<_>>());
        let kept = |r: &Region| {
            r.mean_change.abs() >= needed(r, options.region_lod_factor)
                || median_change(r).abs() >= needed(r, options.level_lod_factor)
                    && on_level_ground(frame, cells, &measured, r)
        };
        if found.last().is_some_and(|r| !kept(r)) {
            found.pop();
        }
    }
    found.sort_by(|a, b| b.cells.len().cmp(&a.cells.len()).then(a.cells.cmp(&b.cells)));
    for (k, region) in found.iter_mut().enumerate() {
        region.id = k + 1;
    }
    found
}

/// Whether the lower visit's surface over `region` and two cells around it is level: its relief
/// (10th to 90th percentile of its height) under [`LEVEL_RELIEF`] of the region's mean change. A
/// coral that left or came from open ground shows so; a dense surface's error at the rim of a
/// structure both visits saw stands beside that structure.
fn on_level_ground(
    frame: &MapFrame,
    cells: &[Cell],
    measured: &BTreeMap<(usize, usize), usize>,
    region: &Region,
) -> bool {
    const RING: i64 = 2;
    let mut around: BTreeSet<usize> = BTreeSet::new();
    for &k in &region.cells {
        let (col, row) = (cells[k].col as i64, cells[k].row as i64);
        for (dc, dr) in (-RING..=RING).flat_map(|dc| (-RING..=RING).map(move |dr| (dc, dr))) {
            let (Ok(c), Ok(r)) = (usize::try_from(col + dc), usize::try_from(row + dr)) else { continue };
            if ((dc * dc + dr * dr) as f64).sqrt() <= RING as f64 + 0.5 {
                around.extend(measured.get(&(c, r)));
            }
        }
    }
    let mut lower: Vec<f64> =
        around.iter().map(|&k| frame.to_map(&cells[k].core)[2] + cells[k].change.min(0.0)).collect();
    lower.sort_by(f64::total_cmp);
    let at = |q: f64| lower[((lower.len() - 1) as f64 * q).round() as usize];
    !lower.is_empty() && at(0.9) - at(0.1) <= LEVEL_RELIEF * region.mean_change.abs()
}

/// Resamples of the bootstrap estimate of a median's variance.
const BOOTSTRAP: usize = 200;

/// The variance of the median of `values`, by a seeded bootstrap: large when the points
/// in a cylinder sit on two surfaces (a colony's edge), where the median may fall on either.
fn median_variance(values: &[f64], seed: u64) -> f64 {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1);
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut sample = vec![0.0; values.len()];
    let medians: Vec<f64> = (0..BOOTSTRAP)
        .map(|_| {
            for v in &mut sample {
                *v = values[(next() % values.len() as u64) as usize];
            }
            median_in_place(&mut sample)
        })
        .collect();
    variance(&medians)
}

fn variance(values: &[f64]) -> f64 {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)
}

fn median(values: &[f64]) -> f64 {
    median_in_place(&mut values.to_vec())
}

/// The median (the upper middle of an even count); NaN when empty.
fn median_in_place(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[cfg(test)]
pub(crate) mod testing {
    use super::*;
    use nalgebra::{Point2, UnitQuaternion};
    use revisit_core::{Image, Observation, Point3D, Rigid3, TrackElement};

    /// The defaults, with every point counted (each is seen by one image here).
    pub fn all_points() -> ChangeOptions {
        ChangeOptions { min_track: 1, ..ChangeOptions::sparse() }
    }

    /// The map of the model's sparse points.
    pub fn sparse_map(
        model: &Reconstruction,
        from: &str,
        to: &str,
        options: &ChangeOptions,
    ) -> Result<ChangeMap, ChangeError> {
        detect(model, from, to, &sparse_surfaces(model, from, to, options)?, options)
    }

    /// Seabed height of a visit at (x, y): flat, with a 0.3 m coral of radius 0.4 m at (-1, -1)
    /// that only visit A has, and a 0.2 m one at (1, 1) that only visit B has.
    fn seabed(visit: &str, x: f64, y: f64) -> f64 {
        let inside = |cx: f64, cy: f64| (x - cx).hypot(y - cy) < 0.4;
        match visit {
            "a" if inside(-1.0, -1.0) => 0.3,
            "b" if inside(1.0, 1.0) => 0.2,
            _ => 0.0,
        }
    }

    /// Two visits of a 4 m x 4 m site from 2 m up, each point seen by the one camera above it,
    /// heights with 1 cm of noise (seeded). `change` false: both visits see the flat seabed.
    pub fn two_visits(change: bool) -> Reconstruction {
        two_visits_of(if change { seabed } else { |_, _, _| 0.0 })
    }

    /// [`two_visits`] of the seabed `height(visit, x, y)`.
    pub fn two_visits_of(height: fn(&str, f64, f64) -> f64) -> Reconstruction {
        let mut model = Reconstruction::default();
        let mut state = 7u64;
        let mut noise = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.02
        };
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        for (v, visit) in ["a", "b"].into_iter().enumerate() {
            for (k, (cx, cy)) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)].into_iter().enumerate() {
                let image_id = (v * 4 + k + 1) as u32;
                let centre = Vector3::new(cx, cy, 2.0);
                let cam_from_world = Rigid3::new(down, -(down * centre));
                let name = format!("{visit}/{k}.png");
                model.images.insert(image_id, Image { image_id, camera_id: 1, name, cam_from_world, points2d: vec![] });
            }
            // Visits sample the seabed on offset grids, as two surveys would.
            let offset = 0.02 * v as f64;
            for i in 0..80 {
                for j in 0..80 {
                    let (x, y) = (-2.0 + 0.05 * i as f64 + offset, -2.0 + 0.05 * j as f64 + offset);
                    let z = height(visit, x, y) + noise();
                    let image_id = (v * 4 + usize::from(x > 0.0) + 2 * usize::from(y > 0.0) + 1) as u32;
                    let id = model.points3d.len() as u64 + 1;
                    let image = model.images.get_mut(&image_id).expect("image");
                    let point2d_idx = image.points2d.len() as u32;
                    image.points2d.push(Observation { xy: Point2::origin(), point3d_id: Some(id) });
                    let track = vec![TrackElement { image_id, point2d_idx }];
                    model.points3d.insert(id, Point3D { xyz: Point3::new(x, y, z), rgb: [0; 3], error: 0.5, track });
                }
            }
        }
        model
    }
}

#[cfg(test)]
mod tests {
    use super::testing::{all_points, sparse_map, two_visits};
    use super::*;

    #[test]
    fn a_coral_removed_and_one_arrived_are_the_only_regions() {
        let map = sparse_map(&two_visits(true), "a", "b", &all_points()).expect("map");
        assert!((map.scales.altitude - 2.0).abs() < 0.05, "altitude {}", map.scales.altitude);
        assert_eq!(map.regions.len(), 2, "{:?}", map.regions);
        let area = std::f64::consts::PI * 0.4 * 0.4;
        for (sign, at, height) in [(Sign::Lowered, [-1.0, -1.0], -0.3), (Sign::Raised, [1.0, 1.0], 0.2)] {
            let region = map.regions.iter().find(|r| r.sign == sign).expect("region of the sign");
            let [x, y] = [region.centre.x, region.centre.y];
            assert!((x - at[0]).hypot(y - at[1]) < 0.1, "{sign:?} region at ({x:.2}, {y:.2})");
            assert!((region.peak_change - height).abs() < 0.03, "{sign:?} peak {}", region.peak_change);
            assert!((region.area / area - 1.0).abs() < 0.35, "{sign:?} area {} against {area}", region.area);
        }
        // The registration term is the noise's level, not the corals'.
        assert!(map.registration < 0.02, "registration {}", map.registration);
    }

    #[test]
    fn an_unchanged_site_has_no_region() {
        let map = sparse_map(&two_visits(false), "a", "b", &all_points()).expect("map");
        assert!(map.cells.len() > 1000, "{} cells", map.cells.len());
        assert!(map.regions.is_empty(), "{:?}", map.regions);
        assert!(map.median_change.abs() < 0.005);
    }

    #[test]
    fn the_outputs_hold_every_cell_and_region() {
        let map = sparse_map(&two_visits(true), "a", "b", &all_points()).expect("map");
        let ply = encode_ply(&map);
        let header_end = ply.windows(11).position(|w| w == b"end_header\n").expect("header") + 11;
        assert_eq!(ply.len() - header_end, map.cells.len() * (3 * 8 + 3 + 4 + 4 + 1));
        let csv = regions_csv(&map).expect("csv");
        assert_eq!(csv.lines().count(), 1 + map.regions.len());
        assert!(csv.starts_with("id,sign,cells,area,x,y,z,east,north,mean_change,peak_change,mean_lod95\n"));
        let png = map_png(&map, "m");
        assert!(png.width() >= 520 && png.height() > 100);
    }

    /// A visit's surface on a 2.5 cm grid over the site, `height` giving its points at (x, y)
    /// (none, one or several layers), with 1 cm of noise (seeded).
    fn surface(offset: f64, height: impl Fn(f64, f64) -> Vec<f64>) -> Vec<Point3<f64>> {
        let mut state = 11u64;
        let mut noise = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.02
        };
        let mut points = Vec::new();
        for i in 0..160 {
            for j in 0..160 {
                let (x, y) = (-2.0 + 0.025 * i as f64 + offset, -2.0 + 0.025 * j as f64 + offset);
                points.extend(height(x, y).into_iter().map(|z| Point3::new(x, y, z + noise())));
            }
        }
        points
    }

    #[test]
    fn a_coral_one_visit_did_not_resolve_is_no_change() {
        let model = two_visits(false);
        let on_coral = |x: f64, y: f64| (x + 1.0).hypot(y + 1.0) < 0.4;
        // A branching coral both visits flew over: the first saw its branches (0.25 m) and the
        // sand through its gaps (every other point); the second resolved only the sand.
        let porous = Surfaces {
            from: surface(0.0, |x, y| match on_coral(x, y) {
                true if ((x * 40.0).round() as i64 + (y * 40.0).round() as i64) % 2 == 0 => vec![0.25],
                _ => vec![0.0],
            }),
            to: surface(0.01, |_, _| vec![0.0]),
            shared: 0,
        };
        // A solid coral gone: the first visit saw only its top, the second the sand.
        let removed =
            Surfaces { from: surface(0.0, |x, y| vec![if on_coral(x, y) { 0.25 } else { 0.0 }]), ..porous.clone() };
        // A solid coral still there, but the second visit saw the sand beyond one side of it only
        // (a hole where the rest of its surface should be).
        let hidden = Surfaces {
            from: removed.from.clone(),
            to: surface(0.01, |x, y| {
                if on_coral(x, y) || (x + 1.0).hypot(y + 1.0) < 0.55 && x < -1.0 {
                    vec![]
                } else {
                    vec![0.0]
                }
            }),
            shared: 0,
        };
        let options = ChangeOptions::default();
        let regions = |surfaces: &Surfaces, options: &ChangeOptions| {
            detect(&model, "a", "b", surfaces, options).expect("map").regions
        };
        // At the unchanged corals no region says anything of their height (a ring of a few
        // millimetres may remain where a cylinder's median moves with its share of branches).
        let largest = |regions: Vec<Region>| regions.iter().map(|r| r.peak_change.abs()).fold(0.0, f64::max);
        assert!(largest(regions(&porous, &options)) < 0.02, "{:?}", regions(&porous, &options));
        assert!(largest(regions(&hidden, &options)) < 0.02, "{:?}", regions(&hidden, &options));
        let gone = regions(&removed, &options);
        assert_eq!(gone.len(), 1, "{gone:?}");
        assert!((gone[0].peak_change + 0.25).abs() < 0.03, "{gone:?}");
        // Without the two rules, both unchanged corals read as a change of their height.
        let credulous = ChangeOptions { max_seen_through: 1.0, min_inner_points: 0, ..options };
        assert!(largest(regions(&porous, &credulous)) > 0.2);
        assert!(largest(regions(&hidden, &credulous)) > 0.2);
    }

    #[test]
    fn a_small_colony_removed_is_found_on_dense_surfaces() {
        let model = two_visits(false);
        // A dome 0.12 m tall with a 0.18 m reach (the smallest colonies of a reef) gone.
        let dome = |x: f64, y: f64| {
            let t = (x - 1.0).hypot(y + 1.0) / 0.18;
            vec![if t < 1.0 { 0.12 * (1.0 - t * t).sqrt() } else { 0.0 }]
        };
        let surfaces = Surfaces { from: surface(0.0, dome), to: surface(0.01, |_, _| vec![0.0]), shared: 0 };
        let regions = |options: &ChangeOptions| detect(&model, "a", "b", &surfaces, options).expect("map").regions;
        let found = regions(&ChangeOptions::default());
        assert_eq!(found.len(), 1, "{found:?}");
        let [x, y] = [found[0].centre.x, found[0].centre.y];
        assert!((x - 1.0).hypot(y + 1.0) < 0.05, "region at ({x:.2}, {y:.2})");
        // The sparse defaults' wider cylinders (8% of the altitude, 0.16 m here) reach past it
        // onto the sand: its measured height falls short of the finer cylinders'.
        let coarse = regions(&ChangeOptions::sparse());
        let peak = |regions: &[Region]| regions.iter().map(|r| r.peak_change).fold(0.0, f64::min);
        assert!((peak(&found) + 0.12).abs() < 0.015, "{found:?}");
        assert!(peak(&coarse) > peak(&found) + 0.015, "{coarse:?}");
    }

    #[test]
    fn a_low_colony_gone_from_open_ground_is_found_but_as_low_a_change_at_a_rim_is_not() {
        let model = two_visits(false);
        let dome = |x: f64, y: f64| {
            let t = (x - 1.0).hypot(y + 1.0) / 0.09;
            if t < 1.0 {
                0.045 * (1.0 - t * t).sqrt()
            } else {
                0.0
            }
        };
        let coral = |x: f64, y: f64| if (x + 1.0).hypot(y + 1.0) < 0.4 { 0.3 } else { 0.0 };
        // Beside the coral's rim, over a sixth of its circumference, the second visit's surface
        // stands 4.5 cm above the sand for 6 cm, as a dense surface errs beside a structure.
        let rim = |x: f64, y: f64| {
            let (r, angle) = ((x + 1.0).hypot(y + 1.0), (y + 1.0).atan2(x + 1.0));
            if (0.4..0.46).contains(&r) && (angle + std::f64::consts::FRAC_PI_2).abs() < 0.5 {
                0.045
            } else {
                0.0
            }
        };
        // A 4.5 cm dome of 9 cm reach gone from the sand at (1, -1); the coral at (-1, -1)
        // unchanged, but for its rim.
        let from = surface(0.0, |x, y| vec![coral(x, y) + dome(x, y)]);
        let to = surface(0.01, |x, y| vec![coral(x, y) + rim(x, y)]);
        let surfaces = Surfaces { from, to, shared: 0 };
        let regions = |options: &ChangeOptions| detect(&model, "a", "b", &surfaces, options).expect("map").regions;
        let map = detect(&model, "a", "b", &surfaces, &ChangeOptions::default()).expect("map");
        // The rim's error is beyond its cells' level of detection, as the dome is.
        let at_rim = |c: &&Cell| c.significant && c.change > 0.0 && (c.core.x + 1.0).hypot(c.core.y + 1.0) < 0.6;
        assert!(
            map.cells.iter().filter(at_rim).count() >= 3,
            "{:?}",
            map.cells.iter().filter(at_rim).collect::<Vec<_>>()
        );
        let found = map.regions;
        assert_eq!(found.len(), 1, "{found:?}");
        let [x, y] = [found[0].centre.x, found[0].centre.y];
        assert!((x - 1.0).hypot(y + 1.0) < 0.05 && found[0].sign == Sign::Lowered, "region at ({x:.2}, {y:.2})");
        // The rule for structures both visits saw alone misses the dome too.
        let strict =
            ChangeOptions { level_lod_factor: ChangeOptions::default().region_lod_factor, ..Default::default() };
        assert_eq!(regions(&strict), vec![]);
    }

    #[test]
    fn bad_visits_and_sizes_are_named() {
        let model = two_visits(true);
        let err = sparse_map(&model, "a", "c", &all_points()).unwrap_err();
        assert_eq!(err.to_string(), "visit c has no image in the model (its visits: a, b)");
        assert_eq!(sparse_map(&model, "a", "a", &all_points()).unwrap_err(), ChangeError::SameVisit("a".into()));
        let options = ChangeOptions { cell: Some(-1.0), ..all_points() };
        assert!(sparse_map(&model, "a", "b", &options).unwrap_err().to_string().starts_with("invalid option --cell"));
        let options = ChangeOptions { cell: Some(1e-5), ..all_points() };
        assert!(sparse_map(&model, "a", "b", &options).unwrap_err().to_string().contains("choose a larger cell"));
    }
}
