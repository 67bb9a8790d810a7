//! The reef: a seabed heightfield (sand, ripples, relief) shared by all
//! sessions, and discrete structures (rocks, pebbles, coral heads, tables,
//! branching corals) whose state changes from session to session.
//!
//! World frame: x east, y north, z up, metres; the site is a square centred on
//! the origin. Geometry lives on a grid of `CELL_M`; albedo and object ids on a
//! finer texel grid of `TEXEL_M`, mip-mapped for filtered sampling.

use rayon::prelude::*;
use serde::Serialize;

use crate::noise::{self, cellular, fbm, gradient, lerp3, ridged, scale3, smoothstep, unit, SplitMix64};
use crate::{ChangeGrade, Growth};

/// Spacing of the geometry grid (mesh vertices), metres.
pub const CELL_M: f64 = 0.0125;
/// Size of an albedo texel, metres (about one pixel at 1.6 m altitude and 640 px width).
pub const TEXEL_M: f64 = 0.003;
/// Object id of the bare seabed (sand, rubble, algae turf). Never changes.
pub const SEABED_ID: u32 = 0;
/// Texels between samples of the slowly varying seabed fields.
const FIELD_STEP: usize = 8;

/// The kind of a discrete structure of the reef.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    Rock,
    Pebble,
    CoralHead,
    CoralTable,
    BranchingCoral,
}

impl ObjectKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Rock => "rock",
            Self::Pebble => "pebble",
            Self::CoralHead => "coral_head",
            Self::CoralTable => "coral_table",
            Self::BranchingCoral => "branching_coral",
        }
    }

    pub fn is_coral(self) -> bool {
        matches!(self, Self::CoralHead | Self::CoralTable | Self::BranchingCoral)
    }

    /// How far the outline may bulge beyond `radius_m` (radial noise amplitude).
    fn outline_noise(self) -> f32 {
        match self {
            Self::Rock | Self::Pebble => 0.22,
            Self::CoralHead => 0.15,
            Self::CoralTable => 0.12,
            Self::BranchingCoral => 0.25,
        }
    }
}

/// The state of one structure in one session. Two sessions see the same
/// structure unchanged exactly when its states compare equal.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectState {
    /// Stable across sessions; 0 is the seabed, so objects start at 1.
    pub id: u32,
    pub kind: ObjectKind,
    pub centre_m: [f64; 2],
    /// Outline radius before growth, metres.
    pub radius_m: f64,
    /// Height above its base before growth, metres.
    pub height_m: f64,
    /// Rotation about the vertical axis, radians.
    pub angle_rad: f64,
    /// Isotropic growth factor (1 when first seen).
    pub growth: f64,
    /// 0 = healthy colour, 1 = fully bleached (white).
    pub bleach: f64,
    /// World height of the base the profile stands on, metres.
    pub base_m: f64,
    /// Base colour (linear RGB).
    pub colour: [f32; 3],
    /// Seed of the object's shape and texture.
    pub seed: u32,
}

impl ObjectState {
    /// Largest horizontal reach from the centre, metres.
    pub fn reach_m(&self) -> f64 {
        self.radius_m * self.growth * (1.0 + 1.6 * f64::from(self.kind.outline_noise())) + 0.01
    }

    /// Median height of its surface above its base over a disc of `radius_m` about `centre_m`
    /// (sampled every centimetre; its outline's inside only), metres: the top a surface map
    /// measures. For a branching coral that is the canopy, between its tips and its gaps.
    pub fn median_height_over_m(&self, centre_m: [f64; 2], radius_m: f64) -> Option<f64> {
        let painter = Painter::new(self);
        let steps = (radius_m / 0.01).ceil() as i32;
        let mut heights: Vec<f32> = (-steps..=steps)
            .flat_map(|i| (-steps..=steps).map(move |j| (0.01 * f64::from(i), 0.01 * f64::from(j))))
            .filter(|(dx, dy)| dx.hypot(*dy) <= radius_m)
            .filter_map(|(dx, dy)| painter.height_at((centre_m[0] + dx) as f32, (centre_m[1] + dy) as f32))
            .collect();
        if heights.is_empty() {
            return None;
        }
        let mid = heights.len() / 2;
        let median = *heights.select_nth_unstable_by(mid, f32::total_cmp).1;
        Some(f64::from(median) - self.base_m)
    }
}

/// World height of the highest surface (the seabed or any of `objects`) at each of `points_m`,
/// metres: what a camera above sees there.
pub(crate) fn surface_heights_m<'a>(
    site: &Site,
    objects: impl Iterator<Item = &'a ObjectState>,
    points_m: &[[f64; 2]],
) -> Vec<f64> {
    let painters: Vec<Painter> = objects.map(Painter::new).collect();
    points_m
        .iter()
        .map(|&[x, y]| {
            let (x, y) = (x as f32, y as f32);
            let objects = painters.iter().filter_map(|p| p.height_at(x, y));
            f64::from(objects.fold(site.seabed_height(x, y), f32::max))
        })
        .collect()
}

/// A precomputed, f32 view of an object for the inner loops.
struct Painter<'a> {
    state: &'a ObjectState,
    cx: f32,
    cy: f32,
    cos: f32,
    sin: f32,
    inv_growth: f32,
    growth: f32,
    radius: f32,
    height: f32,
    base: f32,
    seed: u32,
}

impl<'a> Painter<'a> {
    fn new(state: &'a ObjectState) -> Self {
        let (sin, cos) = state.angle_rad.sin_cos();
        Self {
            state,
            cx: state.centre_m[0] as f32,
            cy: state.centre_m[1] as f32,
            cos: cos as f32,
            sin: sin as f32,
            inv_growth: (1.0 / state.growth) as f32,
            growth: state.growth as f32,
            radius: state.radius_m as f32,
            height: state.height_m as f32,
            base: state.base_m as f32,
            seed: state.seed,
        }
    }

    /// Local (unrotated, ungrown) coordinates and the normalised radius t in
    /// [0, 1) inside the outline; `None` outside.
    #[inline]
    fn local(&self, x: f32, y: f32) -> Option<(f32, f32, f32)> {
        let (dx, dy) = (x - self.cx, y - self.cy);
        let u = (self.cos * dx + self.sin * dy) * self.inv_growth;
        let v = (-self.sin * dx + self.cos * dy) * self.inv_growth;
        let r = (u * u + v * v).sqrt();
        let amp = self.state.kind.outline_noise();
        if r >= self.radius * (1.0 + 1.6 * amp) {
            return None;
        }
        let (du, dv) = if r > 1e-6 { (u / r, v / r) } else { (1.0, 0.0) };
        let wobble = gradient(1.7 * du + 5.3, 1.7 * dv - 2.1, self.seed)
            + 0.5 * gradient(3.9 * du - 7.7, 3.9 * dv + 1.3, self.seed ^ 0xA5A5);
        let r_eff = self.radius * (1.0 + amp * wobble);
        let t = r / r_eff.max(1e-4);
        (t < 1.0).then_some((u, v, t))
    }

    /// World height of the object's surface at (x, y), if inside its outline.
    #[inline]
    fn height_at(&self, x: f32, y: f32) -> Option<f32> {
        let (u, v, t) = self.local(x, y)?;
        Some(self.base + self.growth * self.profile(u, v, t))
    }

    fn profile(&self, u: f32, v: f32, t: f32) -> f32 {
        let h = self.height;
        let r = self.radius;
        let s = self.seed;
        match self.state.kind {
            ObjectKind::Rock | ObjectKind::Pebble => {
                let bumps = fbm(u / (0.35 * r), v / (0.35 * r), 3, 0.5, s ^ 0x11);
                h * (1.0 - t * t).max(0.0).sqrt() * (0.88 + 0.12 * bumps)
            }
            ObjectKind::CoralHead => {
                let lobes = gradient(u / (0.3 * r), v / (0.3 * r), s ^ 0x22);
                h * (1.0 - t * t).max(0.0).powf(0.6) * (0.93 + 0.07 * lobes)
            }
            ObjectKind::CoralTable => {
                let rim = smoothstep(0.0, 0.08, 1.0 - t);
                h * rim * (1.0 + 0.08 * (1.0 - t * t))
            }
            ObjectKind::BranchingCoral => {
                let cell = cellular(u / 0.028, v / 0.028, s ^ 0x33);
                let tip = (1.0 - cell.f1 / 0.7).max(0.0);
                let t2 = t * t;
                h * (1.0 - t2 * t2) * (0.5 + 0.5 * tip)
            }
        }
    }

    /// Albedo (linear RGB) at (x, y); call only inside the outline.
    fn albedo(&self, u: f32, v: f32, t: f32) -> [f32; 3] {
        let s = self.seed;
        let r = self.radius;
        let base = self.state.colour;
        let (tint, pattern) = match self.state.kind {
            ObjectKind::Rock | ObjectKind::Pebble => {
                let mottle = fbm(u / 0.12, v / 0.12, 5, 0.55, s ^ 0x44);
                let mut c = scale3(base, 0.78 + 0.35 * mottle);
                let algae = smoothstep(0.15, 0.35, fbm(u / 0.18, v / 0.18, 3, 0.5, s ^ 0x55));
                c = lerp3(c, [0.70, 0.46, 0.52], 0.8 * algae);
                let turf = smoothstep(0.2, 0.45, fbm(u / 0.25 + 9.0, v / 0.25, 3, 0.5, s ^ 0x56));
                c = lerp3(c, [0.32, 0.38, 0.20], 0.7 * turf);
                let pit = cellular(u / 0.014, v / 0.014, s ^ 0x66);
                let dark = if pit.f1 < 0.22 && unit(pit.id) < 0.35 { 0.55 } else { 1.0 };
                (c, dark * (1.0 - 0.35 * t.powi(8)))
            }
            ObjectKind::CoralHead => {
                let variation = fbm(u / 0.2, v / 0.2, 4, 0.5, s ^ 0x77);
                let c = scale3(base, 0.82 + 0.3 * variation);
                let p = if s & 1 == 0 {
                    // Brain coral: meandering ridges and valleys.
                    let warp = 2.5 * fbm(u / 0.1, v / 0.1, 2, 0.5, s ^ 0x88);
                    let ridge = ridged(u / 0.045 + warp, v / 0.045 - warp, 2, s ^ 0x99);
                    0.55 + 0.6 * ridge * ridge * ridge
                } else {
                    // Massive coral: polyp cups with bright walls.
                    let cell = cellular(u / 0.01, v / 0.01, s ^ 0xAA);
                    let wall = smoothstep(0.0, 0.22, cell.f2 - cell.f1);
                    0.62 + 0.45 * (1.0 - wall) + 0.12 * (unit(cell.id) - 0.5)
                };
                (c, p * (1.0 - 0.3 * t.powi(6)))
            }
            ObjectKind::CoralTable => {
                let angle = v.atan2(u);
                let rr = (u * u + v * v).sqrt() / r;
                let streak = ridged(angle * 5.0 + 3.0 * rr, rr * 9.0, 3, s ^ 0xBB);
                let polyp = cellular(u / 0.007, v / 0.007, s ^ 0xCC);
                let dots = if polyp.f1 < 0.3 { 0.85 } else { 1.0 };
                let variation = fbm(u / 0.15, v / 0.15, 4, 0.5, s ^ 0xDD);
                let c = scale3(base, 0.8 + 0.3 * variation);
                let rim = 1.0 + 0.35 * smoothstep(0.85, 0.97, t);
                (c, (0.6 + 0.5 * streak) * dots * rim)
            }
            ObjectKind::BranchingCoral => {
                let cell = cellular(u / 0.028, v / 0.028, s ^ 0x33);
                let tip = (1.0 - cell.f1 / 0.7).max(0.0);
                let variation = fbm(u / 0.1, v / 0.1, 3, 0.5, s ^ 0xEE);
                let c = scale3(base, 0.85 + 0.25 * variation + 0.15 * (unit(cell.id) - 0.5));
                (c, 0.35 + 0.85 * tip * tip)
            }
        };
        let healthy = scale3(tint, pattern);
        let bleach = self.state.bleach as f32;
        if bleach <= 0.0 {
            return healthy;
        }
        let white = scale3([0.93, 0.92, 0.88], 0.78 + 0.22 * pattern.min(1.2));
        lerp3(healthy, white, bleach)
    }
}

/// The seabed without structures: heights on the grid and albedo on the texel
/// grid (level 0). Shared by every session.
pub(crate) struct Seabed {
    pub heights: Vec<f32>,
    pub albedo: Vec<[u8; 3]>,
}

/// The square site and its two grids.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Site {
    pub half_m: f64,
    pub seed: u32,
    /// Vertices per side of the geometry grid.
    pub grid_n: usize,
    /// Texels per side of the albedo grid.
    pub tex_n: usize,
}

impl Site {
    pub fn new(half_m: f64, seed: u32) -> Self {
        let grid_n = (2.0 * half_m / CELL_M).ceil() as usize + 1;
        let tex_n = (2.0 * half_m / TEXEL_M).ceil() as usize;
        Self { half_m, seed, grid_n, tex_n }
    }

    pub fn vertex_m(&self, i: usize) -> f64 {
        -self.half_m + i as f64 * CELL_M
    }

    pub fn texel_centre_m(&self, i: usize) -> f64 {
        -self.half_m + (i as f64 + 0.5) * TEXEL_M
    }

    /// Height of the bare seabed: low relief, small undulations and ripples.
    pub fn seabed_height(&self, x: f32, y: f32) -> f32 {
        let s = self.seed;
        let relief = 0.22 * fbm(x / 3.5, y / 3.5, 3, 0.5, s ^ 0x100);
        let undulation = 0.025 * fbm(x / 0.45, y / 0.45, 3, 0.5, s ^ 0x101);
        relief + undulation + self.ripple(x, y).0
    }

    /// Sand ripples: (height, trough weight in [0, 1]).
    fn ripple(&self, x: f32, y: f32) -> (f32, f32) {
        let s = self.seed;
        let angle = unit(noise::mix(s, 0x102)) * std::f32::consts::PI;
        let (sin, cos) = angle.sin_cos();
        let warp = 7.0 * fbm(x / 1.3, y / 1.3, 3, 0.5, s ^ 0x103);
        let phase = (x * cos + y * sin) * (std::f32::consts::TAU / 0.09) + warp;
        let field = smoothstep(-0.25, 0.25, fbm(x / 2.2, y / 2.2, 2, 0.5, s ^ 0x104));
        let wave = phase.sin() + 0.3 * (2.0 * phase + 0.7).sin();
        (0.0045 * field * wave, field * smoothstep(0.2, -0.9, wave))
    }

    /// Slowly varying seabed fields, sampled on a coarse grid:
    /// [hue, turf patch, ripple warp, ripple field, rubble density, low grain].
    fn seabed_fields(&self, x: f32, y: f32) -> [f32; 6] {
        let s = self.seed;
        [
            smoothstep(-0.45, 0.45, fbm(x / 2.5, y / 2.5, 3, 0.5, s ^ 0x200)),
            smoothstep(0.12, 0.42, fbm(x / 1.7, y / 1.7, 4, 0.5, s ^ 0x202)),
            7.0 * fbm(x / 1.3, y / 1.3, 3, 0.5, s ^ 0x103),
            smoothstep(-0.25, 0.25, fbm(x / 2.2, y / 2.2, 2, 0.5, s ^ 0x104)),
            smoothstep(-0.45, 0.25, fbm(x / 1.3, y / 1.3, 3, 0.5, s ^ 0x204)),
            fbm(x / 0.5, y / 0.5, 3, 0.6, s ^ 0x201),
        ]
    }

    /// Albedo of the bare seabed (linear RGB) from the interpolated coarse
    /// fields. `fine` seeds the centimetre-scale texture (grain, turf detail,
    /// film, rubble, specks): sediment that moves between visits.
    fn seabed_albedo(&self, x: f32, y: f32, tx: usize, ty: usize, f: [f32; 6], fine: u32) -> [f32; 3] {
        let s = fine;
        let [hue, patch, warp, field, density, grain_low] = f;
        let mut c = lerp3([0.86, 0.79, 0.62], [0.66, 0.66, 0.62], hue);
        let grain_fine = fbm(x / 0.05, y / 0.05, 4, 0.75, s ^ 0x208);
        c = scale3(c, 0.85 + 0.22 * grain_low + 0.5 * grain_fine);
        // Algae turf and detritus patches.
        if patch > 0.0 {
            let detail = fbm(x / 0.04, y / 0.04, 3, 0.6, s ^ 0x203);
            let turf = scale3([0.38, 0.42, 0.22], 0.7 + 0.6 * detail);
            c = lerp3(c, turf, 0.85 * patch);
        }
        // Darker detritus collects in ripple troughs.
        let angle = unit(noise::mix(self.seed, 0x102)) * std::f32::consts::PI;
        let (sin, cos) = angle.sin_cos();
        let phase = (x * cos + y * sin) * (std::f32::consts::TAU / 0.09) + warp;
        let wave = phase.sin() + 0.3 * (2.0 * phase + 0.7).sin();
        let trough = field * smoothstep(0.2, -0.9, wave);
        c = scale3(c, 1.0 - 0.15 * trough);
        // Blotches of algae film and fine sediment, 2-10 cm across.
        let blotch = fbm(x / 0.09, y / 0.09, 3, 0.5, s ^ 0x209);
        let film = smoothstep(0.12, 0.3, blotch);
        c = lerp3(c, scale3([0.45, 0.47, 0.30], 0.9 + 0.3 * grain_fine), 0.6 * film);
        let pale = smoothstep(-0.22, -0.38, blotch);
        c = lerp3(c, [0.92, 0.88, 0.78], 0.5 * pale);
        // Rubble and shells in patches, two sizes.
        if density > 0.0 {
            for (cell_m, chance, salt) in [(0.06, 0.6, 0x205u32), (0.028, 0.8, 0x20A)] {
                let cell = cellular(x / cell_m, y / cell_m, s ^ salt);
                let size = 0.15 + 0.25 * unit(cell.id.rotate_left(7));
                if unit(cell.id) < chance * density && cell.f1 < size {
                    let kind = unit(cell.id.rotate_left(13));
                    let shade = if kind < 0.4 {
                        [0.93, 0.90, 0.84]
                    } else if kind < 0.75 {
                        [0.42, 0.40, 0.38]
                    } else {
                        [0.60, 0.42, 0.30]
                    };
                    let edge = smoothstep(size, size * 0.6, cell.f1);
                    c = lerp3(scale3(c, 0.55), shade, edge);
                }
            }
        }
        // Dark specks (small holes, burrows).
        let speck = cellular(x / 0.02, y / 0.02, s ^ 0x206);
        if unit(speck.id) < 0.1 && speck.f1 < 0.3 {
            c = scale3(c, 0.45);
        }
        // Grain-level variation.
        let grain_px = unit(noise::hash2(tx as i32, ty as i32, s ^ 0x207)) - 0.5;
        scale3(c, 0.92 + 0.05 * grain_px)
    }

    /// Builds the seabed (heights and level-0 albedo); `fine` seeds its
    /// centimetre-scale texture (the site's seed for the original sediment).
    pub fn build_seabed(&self, fine: u32, parallel: bool) -> Seabed {
        let n = self.grid_n;
        let height_row = |j: usize, row: &mut [f32]| {
            let y = self.vertex_m(j) as f32;
            for (i, h) in row.iter_mut().enumerate() {
                *h = self.seabed_height(self.vertex_m(i) as f32, y);
            }
        };
        let mut heights = vec![0.0f32; n * n];
        for_rows(&mut heights, n, parallel, height_row);
        // Coarse fields every FIELD_STEP texels, interpolated per texel.
        let t = self.tex_n;
        let m = t / FIELD_STEP + 2;
        let mut fields = vec![[0.0f32; 6]; m * m];
        for_rows(&mut fields, m, parallel, |j, row| {
            let y = self.texel_centre_m(j * FIELD_STEP) as f32;
            for (i, f) in row.iter_mut().enumerate() {
                *f = self.seabed_fields(self.texel_centre_m(i * FIELD_STEP) as f32, y);
            }
        });
        let field_at = |tx: usize, ty: usize| -> [f32; 6] {
            let (i, j) = (tx / FIELD_STEP, ty / FIELD_STEP);
            let fx = (tx % FIELD_STEP) as f32 / FIELD_STEP as f32;
            let fy = (ty % FIELD_STEP) as f32 / FIELD_STEP as f32;
            let at = |i: usize, j: usize| fields.get(j.min(m - 1) * m + i.min(m - 1)).copied().unwrap_or([0.0; 6]);
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            let mut out = [0.0; 6];
            for k in 0..6 {
                let top = a[k] + (b[k] - a[k]) * fx;
                let bottom = c[k] + (d[k] - c[k]) * fx;
                out[k] = top + (bottom - top) * fy;
            }
            out
        };
        let mut albedo = vec![[0u8; 3]; t * t];
        for_rows(&mut albedo, t, parallel, |ty, row| {
            let y = self.texel_centre_m(ty) as f32;
            for (tx, texel) in row.iter_mut().enumerate() {
                *texel = to_u8(self.seabed_albedo(self.texel_centre_m(tx) as f32, y, tx, ty, field_at(tx, ty), fine));
            }
        });
        Seabed { heights, albedo }
    }

    /// Bilinear interpolation of a grid-valued field at world (x, y).
    pub fn grid_bilinear(&self, field: &[f32], x: f64, y: f64) -> f32 {
        let n = self.grid_n;
        let gx = ((x + self.half_m) / CELL_M).clamp(0.0, (n - 1) as f64);
        let gy = ((y + self.half_m) / CELL_M).clamp(0.0, (n - 1) as f64);
        let i = (gx.floor() as usize).min(n.saturating_sub(2));
        let j = (gy.floor() as usize).min(n.saturating_sub(2));
        let (fx, fy) = ((gx - i as f64) as f32, (gy - j as f64) as f32);
        let at = |i: usize, j: usize| field.get(j * n + i).copied().unwrap_or(0.0);
        let a = at(i, j) + (at(i + 1, j) - at(i, j)) * fx;
        let b = at(i, j + 1) + (at(i + 1, j + 1) - at(i, j + 1)) * fx;
        a + (b - a) * fy
    }
}

pub(crate) fn to_u8(c: [f32; 3]) -> [u8; 3] {
    let q = |v: f32| (v * 255.0 + 0.5).clamp(0.0, 255.0) as u8;
    [q(c[0]), q(c[1]), q(c[2])]
}

/// Coral colours (linear RGB) the generator picks from.
const CORAL_COLOURS: [[f32; 3]; 10] = [
    [0.70, 0.52, 0.30],
    [0.52, 0.33, 0.17],
    [0.48, 0.50, 0.22],
    [0.62, 0.32, 0.55],
    [0.85, 0.48, 0.45],
    [0.40, 0.50, 0.66],
    [0.72, 0.70, 0.28],
    [0.62, 0.40, 0.22],
    [0.80, 0.60, 0.40],
    [0.45, 0.30, 0.40],
];

fn pick_colour(rng: &mut SplitMix64, kind: ObjectKind) -> [f32; 3] {
    let base = match kind {
        ObjectKind::Rock | ObjectKind::Pebble => {
            let g = rng.range(0.38, 0.58) as f32;
            [g * 1.05, g, g * 0.9]
        }
        _ => CORAL_COLOURS.get(rng.below(CORAL_COLOURS.len())).copied().unwrap_or([0.6, 0.5, 0.3]),
    };
    let jitter = |rng: &mut SplitMix64| rng.range(0.88, 1.12) as f32;
    [base[0] * jitter(rng), base[1] * jitter(rng), base[2] * jitter(rng)]
}

fn new_object(rng: &mut SplitMix64, site: &Site, id: u32, kind: ObjectKind, spread_half_m: f64) -> ObjectState {
    let centre_m = [rng.range(-spread_half_m, spread_half_m), rng.range(-spread_half_m, spread_half_m)];
    let small = rng.f64() * rng.f64(); // skewed towards small structures
    let (radius_m, height_m) = match kind {
        ObjectKind::Rock => {
            let r = 0.12 + 0.4 * small;
            (r, r * rng.range(0.4, 0.8))
        }
        ObjectKind::Pebble => {
            let r = rng.range(0.015, 0.06);
            (r, r * rng.range(0.3, 0.6))
        }
        ObjectKind::CoralHead => {
            let r = 0.14 + 0.5 * small;
            (r, r * rng.range(0.5, 1.0))
        }
        ObjectKind::CoralTable => (rng.range(0.3, 0.8), rng.range(0.22, 0.45)),
        ObjectKind::BranchingCoral => {
            let r = 0.12 + 0.33 * small;
            (r, rng.range(0.1, 0.35))
        }
    };
    let mut state = ObjectState {
        id,
        kind,
        centre_m,
        radius_m,
        height_m,
        angle_rad: rng.range(0.0, std::f64::consts::TAU),
        growth: 1.0,
        bleach: 0.0,
        base_m: 0.0,
        colour: pick_colour(rng, kind),
        seed: rng.next_u32(),
    };
    settle(&mut state, site);
    state
}

/// Puts an object's base slightly below the seabed at its centre.
fn settle(state: &mut ObjectState, site: &Site) {
    let ground = site.seabed_height(state.centre_m[0] as f32, state.centre_m[1] as f32);
    state.base_m = f64::from(ground) - 0.015 - 0.08 * state.height_m;
}

/// The structures of the first session. With `cover` (a share of the plan
/// area), corals are added (drawn from a stream of their own, in the plan's
/// proportions) until the share of the site inside coral outlines reaches it,
/// or, above it, left out in an order blind to their kind.
pub(crate) fn initial_objects(site: &Site, seed: u64, cover: Option<f64>) -> Vec<ObjectState> {
    let mut rng = SplitMix64::stream(seed, 0x0B1E);
    let spread = site.half_m - 0.2;
    let area = (2.0 * spread) * (2.0 * spread);
    let corals = [(ObjectKind::CoralTable, 0.10), (ObjectKind::CoralHead, 0.5), (ObjectKind::BranchingCoral, 0.35)];
    let plan = [corals[0], corals[1], (ObjectKind::Rock, 0.3), corals[2], (ObjectKind::Pebble, 6.0)];
    let mut objects = Vec::new();
    for (kind, per_m2) in plan {
        let count = (per_m2 * area).round() as usize;
        for _ in 0..count {
            let id = objects.len() as u32 + 1;
            objects.push(new_object(&mut rng, site, id, kind, spread));
        }
    }
    let Some(target) = cover else { return objects };
    let mut raster = CoverRaster::new(site);
    objects.iter().filter(|o| o.kind.is_coral()).for_each(|o| raster.add(o));
    if raster.share() > target {
        // Keep corals in an order that ignores their kind (their seeds') while
        // they fit, then number the structures again.
        let mut raster = CoverRaster::new(site);
        let mut corals: Vec<&ObjectState> = objects.iter().filter(|o| o.kind.is_coral()).collect();
        corals.sort_by_key(|o| (o.seed, o.id));
        let mut kept = std::collections::HashSet::new();
        for o in corals {
            if raster.share() + raster.adds(o) <= target {
                raster.add(o);
                kept.insert(o.id);
            }
        }
        objects.retain(|o| !o.kind.is_coral() || kept.contains(&o.id));
        for (id, o) in (1u32..).zip(objects.iter_mut()) {
            o.id = id;
        }
        return objects;
    }
    let mut rng = SplitMix64::stream(seed, 0xC0FE_0000);
    let weights: f64 = corals.iter().map(|c| c.1).sum();
    let mut next_id = objects.len() as u32 + 1;
    while raster.share() < target && next_id < u32::from(u16::MAX) {
        let mut pick = rng.range(0.0, weights);
        let kind = corals.iter().find(|c| {
            pick -= c.1;
            pick < 0.0
        });
        let o = new_object(&mut rng, site, next_id, kind.map_or(ObjectKind::CoralHead, |c| c.0), spread);
        raster.add(&o);
        objects.push(o);
        next_id += 1;
    }
    objects
}

/// The site's plan area on a coarse grid, marked where a coral's nominal
/// outline (its disc of `radius_m` times its growth) covers it.
struct CoverRaster {
    half_m: f64,
    n: usize,
    covered: Vec<bool>,
    count: usize,
}

impl CoverRaster {
    const CELL_M: f64 = 0.02;

    fn new(site: &Site) -> Self {
        let n = (2.0 * site.half_m / Self::CELL_M).ceil() as usize;
        Self { half_m: site.half_m, n, covered: vec![false; n * n], count: 0 }
    }

    fn share(&self) -> f64 {
        self.count as f64 / (self.n * self.n).max(1) as f64
    }

    /// The cells of `o`'s disc.
    fn cells(&self, o: &ObjectState) -> impl Iterator<Item = usize> + '_ {
        let r = o.radius_m * o.growth;
        let cell = |v: f64| ((v + self.half_m) / Self::CELL_M).floor().clamp(0.0, (self.n - 1) as f64) as usize;
        let [cx, cy] = o.centre_m;
        let (i0, i1, j0, j1) = (cell(cx - r), cell(cx + r), cell(cy - r), cell(cy + r));
        (j0..=j1).flat_map(move |j| (i0..=i1).map(move |i| (i, j))).filter_map(move |(i, j)| {
            let x = -self.half_m + (i as f64 + 0.5) * Self::CELL_M;
            let y = -self.half_m + (j as f64 + 0.5) * Self::CELL_M;
            ((x - cx).hypot(y - cy) <= r).then_some(j * self.n + i)
        })
    }

    /// The share `o` would add.
    fn adds(&self, o: &ObjectState) -> f64 {
        let new = self.cells(o).filter(|&k| !self.covered.get(k).copied().unwrap_or(true)).count();
        new as f64 / (self.n * self.n).max(1) as f64
    }

    fn add(&mut self, o: &ObjectState) {
        let cells: Vec<usize> = self.cells(o).collect();
        for k in cells {
            if let Some(c) = self.covered.get_mut(k) {
                if !*c {
                    *c = true;
                    self.count += 1;
                }
            }
        }
    }
}

/// Rates of change from one session to the next.
struct ChangeRates {
    growth_p: f64,
    growth: (f64, f64),
    bleach_p: f64,
    bleach: (f64, f64),
    loss_p: f64,
    move_p: f64,
    move_m: (f64, f64),
    move_rad: f64,
    rock_move_p: f64,
    recruits_per_m2: f64,
}

fn rates(grade: ChangeGrade) -> Option<ChangeRates> {
    match grade {
        ChangeGrade::None => None,
        ChangeGrade::Mild => Some(ChangeRates {
            growth_p: 0.2,
            growth: (1.03, 1.08),
            bleach_p: 0.08,
            bleach: (0.3, 0.6),
            loss_p: 0.03,
            move_p: 0.02,
            move_m: (0.02, 0.06),
            move_rad: 0.2,
            rock_move_p: 0.0,
            recruits_per_m2: 0.05,
        }),
        // No growth: growth is geometry, not appearance. With the sand
        // renewed, matches fall on corals, and a grown coral is a different
        // shape that biases the one joint solution (measured on 3 x 12 images:
        // growth of 5-20% per visit gave 45 px across visits, 3-8% 16 px,
        // 1-3% 2.8 px, none 0.95 px). Strong change is strong in appearance.
        ChangeGrade::Strong => Some(ChangeRates {
            growth_p: 0.0,
            growth: (1.0, 1.0),
            bleach_p: 0.25,
            bleach: (0.5, 1.0),
            loss_p: 0.1,
            move_p: 0.08,
            move_m: (0.05, 0.2),
            move_rad: 0.6,
            rock_move_p: 0.02,
            recruits_per_m2: 0.1,
        }),
        ChangeGrade::Storm => Some(ChangeRates {
            growth_p: 0.1,
            growth: (1.02, 1.1),
            bleach_p: 0.2,
            bleach: (0.4, 1.0),
            loss_p: 0.2,
            move_p: 0.22,
            move_m: (0.2, 1.0),
            move_rad: std::f64::consts::PI,
            rock_move_p: 0.1,
            recruits_per_m2: 0.02,
        }),
    }
}

/// The structures of the next session, from the previous one. `growth`, when
/// given, replaces the grade's growth and draws from a stream of its own.
pub(crate) fn evolve(
    site: &Site,
    previous: &[ObjectState],
    grade: ChangeGrade,
    growth: Option<&Growth>,
    seed: u64,
    session: usize,
) -> Vec<ObjectState> {
    let mut growth_rng = SplitMix64::stream(seed, 0x6A0E_0000 + session as u64);
    let mut grow = |o: &mut ObjectState| {
        if let Some(growth) = growth {
            o.growth *= 1.0 + growth.fraction(o.kind) * growth_rng.range(0.5, 1.5);
        }
    };
    let Some(rates) = rates(grade) else {
        let mut next = previous.to_vec();
        next.iter_mut().for_each(&mut grow);
        return next;
    };
    let mut rng = SplitMix64::stream(seed, 0xC4A9_0000 + session as u64);
    let spread = site.half_m - 0.2;
    let mut next = Vec::with_capacity(previous.len());
    for object in previous {
        let mut o = object.clone();
        let coral = o.kind.is_coral();
        let move_p =
            if coral { rates.move_p } else { rates.rock_move_p * if o.kind == ObjectKind::Pebble { 3.0 } else { 1.0 } };
        if coral && rng.chance(rates.loss_p) {
            continue;
        }
        if rng.chance(move_p) {
            let distance = rng.range(rates.move_m.0, rates.move_m.1);
            let direction = rng.range(0.0, std::f64::consts::TAU);
            o.centre_m[0] = (o.centre_m[0] + distance * direction.cos()).clamp(-spread, spread);
            o.centre_m[1] = (o.centre_m[1] + distance * direction.sin()).clamp(-spread, spread);
            o.angle_rad += rng.range(-rates.move_rad, rates.move_rad);
            settle(&mut o, site);
        }
        // The grade's growth is drawn even when `growth` replaces it, so that
        // everything else stays as the grade's own survey has it.
        if coral && rng.chance(rates.growth_p) {
            let factor = rng.range(rates.growth.0, rates.growth.1);
            if growth.is_none() {
                o.growth *= factor;
            }
        }
        grow(&mut o);
        if coral && rng.chance(rates.bleach_p) {
            o.bleach = (o.bleach + rng.range(rates.bleach.0, rates.bleach.1)).min(1.0);
        }
        next.push(o);
    }
    let area = (2.0 * spread) * (2.0 * spread);
    let recruits = (rates.recruits_per_m2 * area).round() as usize;
    let first_id = previous.iter().map(|o| o.id).max().unwrap_or(0) + 1;
    for next_id in (first_id..).take(recruits) {
        let kind = if rng.chance(0.5) { ObjectKind::CoralHead } else { ObjectKind::BranchingCoral };
        let mut o = new_object(&mut rng, site, next_id, kind, spread);
        o.radius_m = rng.range(0.06, 0.14);
        o.height_m = o.radius_m * 0.5;
        settle(&mut o, site);
        next.push(o);
    }
    next
}

/// A mip-mapped RGB texture over the site (level 0 = `TEXEL_M`).
pub(crate) struct MipChain {
    levels: Vec<(usize, Vec<[u8; 3]>)>,
}

impl MipChain {
    pub fn new(size: usize, level0: Vec<[u8; 3]>, parallel: bool) -> Self {
        let mut levels = vec![(size, level0)];
        while let Some((n, data)) = levels.last() {
            let n = *n;
            if n <= 1 {
                break;
            }
            let m = n.div_ceil(2);
            let fetch = |i: usize, j: usize| -> [u32; 3] {
                let c = data.get(j.min(n - 1) * n + i.min(n - 1)).copied().unwrap_or([0; 3]);
                [u32::from(c[0]), u32::from(c[1]), u32::from(c[2])]
            };
            let mut next = vec![[0u8; 3]; m * m];
            let row = |j: usize, row: &mut [[u8; 3]]| {
                for (i, texel) in row.iter_mut().enumerate() {
                    let (a, b, c, d) = (
                        fetch(2 * i, 2 * j),
                        fetch(2 * i + 1, 2 * j),
                        fetch(2 * i, 2 * j + 1),
                        fetch(2 * i + 1, 2 * j + 1),
                    );
                    for k in 0..3 {
                        texel[k] = ((a[k] + b[k] + c[k] + d[k] + 2) / 4) as u8;
                    }
                }
            };
            for_rows(&mut next, m, parallel, row);
            levels.push((m, next));
        }
        Self { levels }
    }

    fn bilinear(&self, level: usize, x: f32, y: f32) -> [f32; 3] {
        let Some((n, data)) = self.levels.get(level.min(self.levels.len().saturating_sub(1))) else {
            return [0.0; 3];
        };
        let n = *n;
        let max = (n - 1) as f32;
        let gx = (x - 0.5).clamp(0.0, max);
        let gy = (y - 0.5).clamp(0.0, max);
        let i = gx as usize;
        let j = gy as usize;
        let (fx, fy) = (gx - i as f32, gy - j as f32);
        let i1 = (i + 1).min(n - 1);
        let j1 = (j + 1).min(n - 1);
        let at = |i: usize, j: usize| data.get(j * n + i).copied().unwrap_or([0; 3]);
        let (a, b, c, d) = (at(i, j), at(i1, j), at(i, j1), at(i1, j1));
        let mut out = [0.0; 3];
        for k in 0..3 {
            let top = f32::from(a[k]) + (f32::from(b[k]) - f32::from(a[k])) * fx;
            let bottom = f32::from(c[k]) + (f32::from(d[k]) - f32::from(c[k])) * fx;
            out[k] = (top + (bottom - top) * fy) * (1.0 / 255.0);
        }
        out
    }

    /// Trilinear sample at level-0 texel coordinates (texel centres at i + 0.5)
    /// for a footprint of `footprint` level-0 texels.
    pub fn sample(&self, x: f32, y: f32, footprint: f32) -> [f32; 3] {
        let lod = footprint.max(1.0).log2();
        let level = lod.floor();
        let frac = lod - level;
        let l = level as usize;
        let scale0 = 1.0 / (1u32 << l.min(30)) as f32;
        let a = self.bilinear(l, x * scale0, y * scale0);
        if frac < 1e-3 || l + 1 >= self.levels.len() {
            return a;
        }
        let b = self.bilinear(l + 1, x * scale0 * 0.5, y * scale0 * 0.5);
        lerp3(a, b, frac)
    }
}

/// The reef as one session sees it: geometry, normals, albedo and object ids.
pub(crate) struct SessionScene {
    pub heights: Vec<f32>,
    pub normals: Vec<[f32; 3]>,
    pub albedo: MipChain,
    /// Object id per level-0 texel.
    pub ids: Vec<u16>,
    /// Ambient occlusion per grid vertex (1 = open, lower in cavities).
    pub occlusion: Vec<f32>,
    /// Direct sunlight visibility per grid vertex (0 = in shadow).
    pub sunlit: Vec<f32>,
    pub min_height_m: f32,
    pub max_height_m: f32,
}

impl SessionScene {
    pub fn build(site: &Site, seabed: &Seabed, objects: &[ObjectState], light_dir: [f32; 3], parallel: bool) -> Self {
        let painters: Vec<Painter> = objects.iter().map(Painter::new).collect();
        let n = site.grid_n;
        // Geometry: the highest surface at each vertex.
        let mut heights = seabed.heights.clone();
        let heights_row = |j: usize, row: &mut [f32]| {
            let y = site.vertex_m(j);
            for p in painters.iter().filter(|p| (f64::from(p.cy) - y).abs() <= p.state.reach_m()) {
                let reach = p.state.reach_m();
                let i0 = (((f64::from(p.cx) - reach + site.half_m) / CELL_M).floor().max(0.0)) as usize;
                let i1 = ((((f64::from(p.cx) + reach + site.half_m) / CELL_M).ceil()) as usize).min(n - 1);
                for i in i0..=i1 {
                    if let (Some(h), Some(cell)) = (p.height_at(site.vertex_m(i) as f32, y as f32), row.get_mut(i)) {
                        *cell = cell.max(h);
                    }
                }
            }
        };
        // Albedo and ids: paint each object where it is the highest surface.
        let t = site.tex_n;
        let mut albedo = seabed.albedo.clone();
        let mut ids = vec![0u16; t * t];
        let paint_row = |ty: usize, colour_row: &mut [[u8; 3]], id_row: &mut [u16]| {
            let y = site.texel_centre_m(ty);
            let mut top = vec![f32::NEG_INFINITY; t];
            for p in painters.iter().filter(|p| (f64::from(p.cy) - y).abs() <= p.state.reach_m()) {
                let reach = p.state.reach_m();
                let i0 = (((f64::from(p.cx) - reach + site.half_m) / TEXEL_M).floor().max(0.0)) as usize;
                let i1 = ((((f64::from(p.cx) + reach + site.half_m) / TEXEL_M).ceil()) as usize).min(t - 1);
                for tx in i0..=i1 {
                    let x = site.texel_centre_m(tx);
                    let Some((u, v, tt)) = p.local(x as f32, y as f32) else { continue };
                    let h = p.base + p.growth * p.profile(u, v, tt);
                    let Some(current) = top.get_mut(tx) else { continue };
                    if *current == f32::NEG_INFINITY {
                        *current = site.grid_bilinear(&seabed.heights, x, y);
                    }
                    if h > *current {
                        *current = h;
                        if let (Some(colour), Some(id)) = (colour_row.get_mut(tx), id_row.get_mut(tx)) {
                            *colour = to_u8(p.albedo(u, v, tt));
                            *id = p.state.id.min(u32::from(u16::MAX)) as u16;
                        }
                    }
                }
            }
        };
        for_rows(&mut heights, n, parallel, heights_row);
        if parallel {
            albedo
                .par_chunks_mut(t)
                .zip(ids.par_chunks_mut(t))
                .enumerate()
                .for_each(|(ty, (c, i))| paint_row(ty, c, i));
        } else {
            albedo.chunks_mut(t).zip(ids.chunks_mut(t)).enumerate().for_each(|(ty, (c, i))| paint_row(ty, c, i));
        }
        let normals = grid_normals(&heights, n, parallel);
        let min_height_m = heights.iter().copied().fold(f32::INFINITY, f32::min);
        let max_height_m = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let occlusion = ambient_occlusion(&heights, n, parallel);
        let sunlit = sun_visibility(site, &heights, light_dir, max_height_m, parallel);
        Self {
            heights,
            normals,
            albedo: MipChain::new(t, albedo, parallel),
            ids,
            occlusion,
            sunlit,
            min_height_m,
            max_height_m,
        }
    }

    /// Object id at world (x, y) (nearest texel); the seabed outside the site.
    pub fn id_at(&self, site: &Site, x: f64, y: f64) -> u32 {
        let t = site.tex_n as f64;
        let tx = ((x + site.half_m) / TEXEL_M).floor();
        let ty = ((y + site.half_m) / TEXEL_M).floor();
        if tx < 0.0 || ty < 0.0 || tx >= t || ty >= t {
            return SEABED_ID;
        }
        self.ids.get(ty as usize * site.tex_n + tx as usize).map_or(SEABED_ID, |&id| u32::from(id))
    }
}

/// Box blur of a square grid (radius in cells), separable, clamped at the border.
fn box_blur(field: &[f32], n: usize, radius: usize, parallel: bool) -> Vec<f32> {
    let pass = |src: &[f32], transpose: bool| -> Vec<f32> {
        let mut out = vec![0.0f32; n * n];
        for_rows(&mut out, n, parallel, |j, row| {
            let at = |i: usize| {
                let k = if transpose { i * n + j } else { j * n + i };
                src.get(k).copied().unwrap_or(0.0)
            };
            let mut prefix = Vec::with_capacity(n + 1);
            prefix.push(0.0f64);
            let mut acc = 0.0f64;
            for i in 0..n {
                acc += f64::from(at(i));
                prefix.push(acc);
            }
            for (i, v) in row.iter_mut().enumerate() {
                let lo = i.saturating_sub(radius);
                let hi = (i + radius + 1).min(n);
                let sum = prefix.get(hi).copied().unwrap_or(0.0) - prefix.get(lo).copied().unwrap_or(0.0);
                *v = (sum / (hi - lo).max(1) as f64) as f32;
            }
        });
        out
    };
    // Rows, then columns (the transposed pass writes the transpose back).
    let rows = pass(field, false);
    let cols = pass(&rows, true);
    let mut out = vec![0.0f32; n * n];
    for_rows(&mut out, n, parallel, |j, row| {
        for (i, v) in row.iter_mut().enumerate() {
            *v = cols.get(i * n + j).copied().unwrap_or(0.0);
        }
    });
    out
}

/// Cavities are darker: how far a vertex lies below the mean height around it.
fn ambient_occlusion(heights: &[f32], n: usize, parallel: bool) -> Vec<f32> {
    let near = box_blur(heights, n, 6, parallel);
    let wide = box_blur(heights, n, 20, parallel);
    heights
        .iter()
        .zip(near.iter().zip(&wide))
        .map(|(&h, (&a, &b))| (1.0 - 5.0 * (a - h).max(0.0) - 1.6 * (b - h).max(0.0)).clamp(0.3, 1.0))
        .collect()
}

/// Soft shadows of the sun: march from each vertex towards the light over the
/// heightfield.
fn sun_visibility(site: &Site, heights: &[f32], light_dir: [f32; 3], max_height_m: f32, parallel: bool) -> Vec<f32> {
    let n = site.grid_n;
    let horizontal = (light_dir[0] * light_dir[0] + light_dir[1] * light_dir[1]).sqrt();
    if horizontal < 1e-3 || light_dir[2] <= 0.0 {
        return vec![1.0; n * n];
    }
    let step = CELL_M as f32;
    let (dx, dy) = (light_dir[0] / horizontal * step, light_dir[1] / horizontal * step);
    let rise = step * light_dir[2] / horizontal;
    let mut out = vec![1.0f32; n * n];
    for_rows(&mut out, n, parallel, |j, row| {
        let y0 = site.vertex_m(j) as f32;
        for (i, v) in row.iter_mut().enumerate() {
            let x0 = site.vertex_m(i) as f32;
            let h0 = heights.get(j * n + i).copied().unwrap_or(0.0);
            let mut blocked = 0.0f32;
            let mut k = 1.0f32;
            loop {
                let ray_z = h0 + rise * k;
                if ray_z > max_height_m {
                    break;
                }
                let h = site.grid_bilinear(heights, f64::from(x0 + dx * k), f64::from(y0 + dy * k));
                blocked = blocked.max(h - ray_z);
                k += 1.0;
            }
            *v = 1.0 - smoothstep(0.0, 0.03, blocked);
        }
    });
    out
}

/// Runs `f(row_index, row)` over the rows of a row-major buffer, on the rayon
/// pool when `parallel` (callers pass false when already inside the pool, where
/// nested parallel work could re-enter a lazily built scene).
pub(crate) fn for_rows<T: Send, F>(data: &mut [T], row_len: usize, parallel: bool, f: F)
where
    F: Fn(usize, &mut [T]) + Sync + Send,
{
    if row_len == 0 {
        return;
    }
    if parallel {
        data.par_chunks_mut(row_len).enumerate().for_each(|(j, row)| f(j, row));
    } else {
        data.chunks_mut(row_len).enumerate().for_each(|(j, row)| f(j, row));
    }
}

fn grid_normals(heights: &[f32], n: usize, parallel: bool) -> Vec<[f32; 3]> {
    let at = |i: usize, j: usize| heights.get(j.min(n - 1) * n + i.min(n - 1)).copied().unwrap_or(0.0);
    let mut normals = vec![[0.0, 0.0, 1.0]; n * n];
    let scale = 1.0 / (2.0 * CELL_M as f32);
    for_rows(&mut normals, n, parallel, |j, row| {
        for (i, normal) in row.iter_mut().enumerate() {
            let dx = (at(i + 1, j) - at(i.saturating_sub(1), j)) * scale;
            let dy = (at(i, j + 1) - at(i, j.saturating_sub(1))) * scale;
            let len = (dx * dx + dy * dy + 1.0).sqrt();
            *normal = [-dx / len, -dy / len, 1.0 / len];
        }
    });
    normals
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(kind: ObjectKind, growth: f64) -> ObjectState {
        ObjectState {
            id: 1,
            kind,
            centre_m: [0.0, 0.0],
            radius_m: 0.3,
            height_m: 0.25,
            angle_rad: 0.0,
            growth,
            bleach: 0.0,
            base_m: -0.05,
            colour: [0.5; 3],
            seed: 11,
        }
    }

    #[test]
    fn a_branching_corals_canopy_stands_below_its_tips_and_grows_with_it() {
        let top = |kind, growth| state(kind, growth).median_height_over_m([0.0, 0.0], 0.08).expect("inside");
        let head = top(ObjectKind::CoralHead, 1.0);
        assert!(head > 0.9 * 0.25 && head <= 0.25 * 1.07, "head top {head}");
        let canopy = top(ObjectKind::BranchingCoral, 1.0);
        assert!(canopy > 0.5 * 0.25 && canopy < 0.9 * 0.25, "canopy {canopy}");
        // Grown by a fifth: the canopy rises by about a fifth of its own height, less than
        // the tips' 5 cm.
        let rise = top(ObjectKind::BranchingCoral, 1.2) - canopy;
        assert!(rise > 0.15 * canopy && rise < 0.25 * canopy && rise < 0.05, "rise {rise}");
        assert_eq!(state(ObjectKind::CoralHead, 1.0).median_height_over_m([2.0, 2.0], 0.1), None);
    }
}
