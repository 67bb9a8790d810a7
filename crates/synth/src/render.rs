//! CPU rendering of a downward-looking pinhole camera over the reef: a z-buffer
//! rasteriser of the heightfield mesh (depth only), then a deferred shading pass
//! (filtered albedo, Lambert light, caustics, water attenuation and
//! backscatter), blur and sensor noise.
//!
//! Pixel convention: COLMAP's. Pixel (col, row) covers [col, col+1) x [row, row+1)
//! and is sampled at its centre (col + 0.5, row + 0.5).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use revisit_core::Rigid3;

use crate::noise::{self, cellular, gradient, smoothstep};
use crate::scene::{for_rows, SessionScene, Site, CELL_M, TEXEL_M};

/// Depth of pixels that see no surface (outside the site).
pub const NO_DEPTH: f32 = f32::INFINITY;
/// Object id of pixels that see no surface.
pub const NO_OBJECT: u32 = u32::MAX;

/// One rendered image and its per-pixel truth (row-major, `width * height`).
#[derive(Clone, Debug)]
pub struct Rendered {
    pub rgb: image::RgbImage,
    /// Depth along the optical axis (camera z), metres; [`NO_DEPTH`] where
    /// nothing is hit.
    pub depth_m: Vec<f32>,
    /// The structure seen at each pixel: 0 = seabed, else an
    /// [`crate::ObjectState::id`]; [`NO_OBJECT`] where nothing is hit.
    pub object_id: Vec<u32>,
}

/// How the water and light look in one session.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Appearance {
    /// Colour of the daylight that reaches the seabed (linear RGB).
    pub light_rgb: [f32; 3],
    /// Overall light level (1 = nominal).
    pub light_level: f32,
    /// Unit vector towards the sun, world frame (z up).
    pub light_dir: [f32; 3],
    /// Share of diffuse (sky) light, 0..1.
    pub ambient: f32,
    /// Attenuation of the signal along the camera ray, per metre (RGB).
    pub attenuation_per_m: [f32; 3],
    /// Colour of the water column (backscatter) at infinite range (linear RGB).
    pub backscatter_rgb: [f32; 3],
    /// Backscatter build-up rate per metre of range.
    pub backscatter_per_m: f32,
    /// Caustic strength (0 = none).
    pub caustics: f32,
    /// Size of caustic cells on the seabed, metres.
    pub caustic_scale_m: f32,
    /// Gaussian blur sigma, pixels (0 = sharp).
    pub blur_px: f32,
    /// Sensor noise sigma in 8-bit levels (0 = none).
    pub noise_sigma: f32,
    /// Exposure of the tone curve.
    pub exposure: f32,
}

impl Appearance {
    /// Clear, blue-green water, sun high; no caustics, blur or noise.
    pub fn nominal() -> Self {
        Self {
            light_rgb: [0.88, 0.95, 1.0],
            light_level: 1.0,
            light_dir: sun_dir(52.0, 30.0),
            ambient: 0.35,
            attenuation_per_m: [0.2, 0.085, 0.07],
            backscatter_rgb: [0.03, 0.2, 0.3],
            backscatter_per_m: 0.07,
            caustics: 0.0,
            caustic_scale_m: 0.35,
            blur_px: 0.0,
            noise_sigma: 0.0,
            exposure: 1.1,
        }
    }
}

/// Unit vector towards a sun at `elevation_deg` above the horizon and
/// `azimuth_deg` counter-clockwise from east.
pub fn sun_dir(elevation_deg: f64, azimuth_deg: f64) -> [f32; 3] {
    let (e, a) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
    [(e.cos() * a.cos()) as f32, (e.cos() * a.sin()) as f32, e.sin() as f32]
}

/// A pinhole view: intrinsics in pixels and the pose.
#[derive(Clone, Copy, Debug)]
pub(crate) struct View {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: usize,
    pub height: usize,
    pub cam_from_world: Rigid3,
}

impl View {
    /// A view with the image (and intrinsics) scaled down by `factor`.
    pub fn scaled(&self, factor: usize) -> Self {
        let f = factor.max(1) as f64;
        Self {
            fx: self.fx / f,
            fy: self.fy / f,
            cx: self.cx / f,
            cy: self.cy / f,
            width: (self.width / factor.max(1)).max(1),
            height: (self.height / factor.max(1)).max(1),
            cam_from_world: self.cam_from_world,
        }
    }

    /// The viewing ray of a pixel position on the camera's z = 1 plane.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }
}

const BAND_ROWS: usize = 8;
/// Vertices closer than this to the camera plane are not drawn, metres.
const NEAR_M: f64 = 0.05;

#[derive(Clone, Copy)]
struct ScreenVertex {
    x: f32,
    y: f32,
    inv_z: f32,
}

/// Rasterises the heightfield mesh (every `stride`-th vertex) into a depth
/// buffer of camera-z depths.
pub(crate) fn rasterize(site: &Site, scene: &SessionScene, view: &View, stride: usize, parallel: bool) -> Vec<f32> {
    let (w, h) = (view.width, view.height);
    let mut depth = vec![NO_DEPTH; w * h];
    let stride = stride.max(1);
    let n = site.grid_n;
    if n < 2 || w == 0 || h == 0 {
        return depth;
    }
    let world_from_cam = view.cam_from_world.inverse();
    let centre = world_from_cam.translation;
    let rot_wc = world_from_cam.rotation_matrix();
    let rot_cw: Matrix3<f64> = view.cam_from_world.rotation_matrix();
    let t_cw = view.cam_from_world.translation;

    // The part of the grid the view can see: its rays between the lowest and
    // highest surface.
    let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut bounded = true;
    for (u, v) in [(0.0, 0.0), (w as f64, 0.0), (0.0, h as f64), (w as f64, h as f64)] {
        let ray = rot_wc * view.ray(u, v);
        for z in [f64::from(scene.min_height_m), f64::from(scene.max_height_m)] {
            if ray.z >= -1e-6 || z >= centre.z {
                bounded = false;
                continue;
            }
            let s = (z - centre.z) / ray.z;
            let p = centre + s * ray;
            lo_x = lo_x.min(p.x);
            lo_y = lo_y.min(p.y);
            hi_x = hi_x.max(p.x);
            hi_y = hi_y.max(p.y);
        }
    }
    let to_index = |m: f64| ((m + site.half_m) / CELL_M).clamp(0.0, (n - 1) as f64);
    let (i0, i1, j0, j1) = if bounded {
        let snap_lo = |m: f64| ((to_index(m).floor() as usize).saturating_sub(2 * stride) / stride) * stride;
        let snap_hi = |m: f64| (to_index(m).ceil() as usize + 2 * stride).min(n - 1);
        (snap_lo(lo_x), snap_hi(hi_x), snap_lo(lo_y), snap_hi(hi_y))
    } else {
        (0, n - 1, 0, n - 1)
    };
    let xs: Vec<usize> = (i0..=i1).step_by(stride).collect();
    let ys: Vec<usize> = (j0..=j1).step_by(stride).collect();
    let (cols, rows) = (xs.len(), ys.len());
    if cols < 2 || rows < 2 {
        return depth;
    }

    let mut screen = vec![ScreenVertex { x: 0.0, y: 0.0, inv_z: 0.0 }; cols * rows];
    let project_row = |r: usize, out: &mut [ScreenVertex]| {
        let Some(&j) = ys.get(r) else { return };
        let y = site.vertex_m(j);
        for (c, vertex) in out.iter_mut().enumerate() {
            let Some(&i) = xs.get(c) else { continue };
            let z_world = scene.heights.get(j * n + i).copied().unwrap_or(0.0);
            let p = rot_cw * Vector3::new(site.vertex_m(i), y, f64::from(z_world)) + t_cw;
            *vertex = if p.z > NEAR_M {
                ScreenVertex {
                    x: (view.fx * p.x / p.z + view.cx) as f32,
                    y: (view.fy * p.y / p.z + view.cy) as f32,
                    inv_z: (1.0 / p.z) as f32,
                }
            } else {
                ScreenVertex { x: 0.0, y: 0.0, inv_z: 0.0 }
            };
        }
    };
    for_rows(&mut screen, cols, parallel, project_row);

    // Bin the triangles into bands of rows.
    let bands = h.div_ceil(BAND_ROWS);
    let mut bins: Vec<Vec<[u32; 3]>> = vec![Vec::new(); bands];
    let vertex = |r: usize, c: usize| screen.get(r * cols + c).copied();
    for r in 0..rows - 1 {
        for c in 0..cols - 1 {
            let ids = [
                (r * cols + c) as u32,
                (r * cols + c + 1) as u32,
                ((r + 1) * cols + c + 1) as u32,
                ((r + 1) * cols + c) as u32,
            ];
            let (Some(a), Some(b), Some(cc), Some(d)) =
                (vertex(r, c), vertex(r, c + 1), vertex(r + 1, c + 1), vertex(r + 1, c))
            else {
                continue;
            };
            for (tri, verts) in [([ids[0], ids[1], ids[2]], [a, b, cc]), ([ids[0], ids[2], ids[3]], [a, cc, d])] {
                if verts.iter().any(|v| v.inv_z <= 0.0) {
                    continue;
                }
                let min_y = verts.iter().map(|v| v.y).fold(f32::INFINITY, f32::min);
                let max_y = verts.iter().map(|v| v.y).fold(f32::NEG_INFINITY, f32::max);
                let min_x = verts.iter().map(|v| v.x).fold(f32::INFINITY, f32::min);
                let max_x = verts.iter().map(|v| v.x).fold(f32::NEG_INFINITY, f32::max);
                if max_y < 0.0 || min_y > h as f32 || max_x < 0.0 || min_x > w as f32 {
                    continue;
                }
                let first = (min_y.max(0.0) as usize / BAND_ROWS).min(bands - 1);
                let last = (max_y.min(h as f32) as usize / BAND_ROWS).min(bands - 1);
                for bin in bins.iter_mut().take(last + 1).skip(first) {
                    bin.push(tri);
                }
            }
        }
    }

    let raster_band = |band: usize, out: &mut [f32]| {
        let Some(tris) = bins.get(band) else { return };
        let row0 = band * BAND_ROWS;
        let band_rows = out.len() / w;
        for tri in tris {
            let (Some(a), Some(b), Some(c)) = (
                screen.get(tri[0] as usize).copied(),
                screen.get(tri[1] as usize).copied(),
                screen.get(tri[2] as usize).copied(),
            ) else {
                continue;
            };
            raster_triangle(a, b, c, row0, band_rows, w, out);
        }
    };
    if parallel {
        depth.par_chunks_mut(BAND_ROWS * w).enumerate().for_each(|(band, out)| raster_band(band, out));
    } else {
        depth.chunks_mut(BAND_ROWS * w).enumerate().for_each(|(band, out)| raster_band(band, out));
    }
    depth
}

#[inline]
fn edge(a: ScreenVertex, b: ScreenVertex, px: f32, py: f32) -> f32 {
    (b.x - a.x) * (py - a.y) - (b.y - a.y) * (px - a.x)
}

fn raster_triangle(
    a: ScreenVertex,
    b: ScreenVertex,
    c: ScreenVertex,
    row0: usize,
    band_rows: usize,
    w: usize,
    out: &mut [f32],
) {
    let area = edge(a, b, c.x, c.y);
    if area.abs() < 1e-9 {
        return;
    }
    let inv_area = 1.0 / area;
    let min_x = a.x.min(b.x).min(c.x);
    let max_x = a.x.max(b.x).max(c.x);
    let min_y = a.y.min(b.y).min(c.y);
    let max_y = a.y.max(b.y).max(c.y);
    let col_lo = (min_x - 0.5).ceil().max(0.0) as usize;
    let col_hi = ((max_x - 0.5).floor()).min(w as f32 - 1.0);
    let row_lo = ((min_y - 0.5).ceil().max(row0 as f32)) as usize;
    let row_hi = ((max_y - 0.5).floor()).min((row0 + band_rows) as f32 - 1.0);
    if col_hi < 0.0 || row_hi < 0.0 {
        return;
    }
    let (col_hi, row_hi) = (col_hi as usize, row_hi as usize);
    // Inclusive edges with a tiny tolerance: a pixel on a shared edge is drawn
    // by both triangles (same depth), never by neither.
    let tolerance = -1e-5;
    for row in row_lo..=row_hi {
        let py = row as f32 + 0.5;
        let Some(line) = out.get_mut((row - row0) * w..(row - row0 + 1) * w) else { continue };
        for col in col_lo..=col_hi {
            let px = col as f32 + 0.5;
            let w0 = edge(b, c, px, py) * inv_area;
            let w1 = edge(c, a, px, py) * inv_area;
            let w2 = edge(a, b, px, py) * inv_area;
            if w0 < tolerance || w1 < tolerance || w2 < tolerance {
                continue;
            }
            let inv_z = w0 * a.inv_z + w1 * b.inv_z + w2 * c.inv_z;
            if inv_z <= 0.0 {
                continue;
            }
            let z = 1.0 / inv_z;
            if let Some(d) = line.get_mut(col) {
                if z < *d {
                    *d = z;
                }
            }
        }
    }
}

/// Object ids of a depth buffer's pixels.
pub(crate) fn object_ids(site: &Site, scene: &SessionScene, view: &View, depth: &[f32], parallel: bool) -> Vec<u32> {
    let w = view.width;
    let mut ids = vec![NO_OBJECT; depth.len()];
    let world_from_cam = view.cam_from_world.inverse();
    let rot_wc = world_from_cam.rotation_matrix();
    let centre = world_from_cam.translation;
    for_rows(&mut ids, w, parallel, |row, out| {
        for (col, id) in out.iter_mut().enumerate() {
            let Some(&z) = depth.get(row * w + col) else { continue };
            if !z.is_finite() {
                continue;
            }
            let p = centre + rot_wc * (view.ray(col as f64 + 0.5, row as f64 + 0.5) * f64::from(z));
            *id = scene.id_at(site, p.x, p.y);
        }
    });
    ids
}

fn caustic(x: f32, y: f32, time_s: f32, scale_m: f32) -> f32 {
    let (sx, sy) = (x / scale_m, y / scale_m);
    let warp = 0.35 * gradient(sx * 0.7 + 0.05 * time_s, sy * 0.7, 0xCA05);
    let a = cellular(sx + warp + 0.11 * time_s, sy - warp + 0.05 * time_s, 0xCA01);
    let b = cellular(sx * 1.37 - warp - 0.08 * time_s, sy * 1.37 + warp + 0.1 * time_s, 0xCA02);
    let la = smoothstep(0.16, 0.0, a.f2 - a.f1);
    let lb = smoothstep(0.16, 0.0, b.f2 - b.f1);
    0.5 * (la + lb) + la * lb
}

/// Shades a depth buffer into a linear-light RGB buffer (3 floats per pixel).
#[allow(clippy::too_many_arguments)]
fn shade(
    site: &Site,
    scene: &SessionScene,
    view: &View,
    look: &Appearance,
    time_s: f64,
    depth: &[f32],
    parallel: bool,
) -> Vec<f32> {
    let w = view.width;
    let mut rgb = vec![0.0f32; depth.len() * 3];
    let world_from_cam = view.cam_from_world.inverse();
    let rot_wc = world_from_cam.rotation_matrix();
    let centre = world_from_cam.translation;
    let l = look.light_dir;
    let time = time_s as f32;
    let far = look.backscatter_rgb;
    for_rows(&mut rgb, w * 3, parallel, |row, out| {
        for (col, px) in out.chunks_exact_mut(3).enumerate() {
            let z = depth.get(row * w + col).copied().unwrap_or(NO_DEPTH);
            if !z.is_finite() {
                px.copy_from_slice(&far);
                continue;
            }
            let ray_c = view.ray(col as f64 + 0.5, row as f64 + 0.5);
            let ray_w = rot_wc * ray_c;
            let p = centre + ray_w * f64::from(z);
            let range = (f64::from(z) * ray_c.norm()) as f32;
            // Footprint of the pixel on the ground plane, in texels.
            let down = (ray_w.z.abs() / ray_w.norm()).max(0.3);
            let footprint = (f64::from(z) * ray_c.norm() / view.fx / down / TEXEL_M) as f32;
            let tx = ((p.x + site.half_m) / TEXEL_M) as f32;
            let ty = ((p.y + site.half_m) / TEXEL_M) as f32;
            let albedo = scene.albedo.sample(tx, ty, footprint);
            let (n, occlusion, sunlit) = surface_at(site, scene, p.x, p.y);
            let lambert = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0);
            let (xf, yf) = (p.x as f32, p.y as f32);
            let caustics =
                if look.caustics > 0.0 { look.caustics * caustic(xf, yf, time, look.caustic_scale_m) } else { 0.0 };
            let irradiance = look.light_level
                * (look.ambient * occlusion + (1.0 - look.ambient) * lambert * sunlit * (1.0 + caustics));
            let build_up = 1.0 - (-look.backscatter_per_m * range).exp();
            for k in 0..3 {
                let signal = albedo[k] * look.light_rgb[k] * irradiance * (-look.attenuation_per_m[k] * range).exp();
                px[k] = signal + far[k] * build_up;
            }
        }
    });
    rgb
}

/// Interpolated normal, ambient occlusion and sun visibility at world (x, y).
fn surface_at(site: &Site, scene: &SessionScene, x: f64, y: f64) -> ([f32; 3], f32, f32) {
    let n = site.grid_n;
    let gx = ((x + site.half_m) / CELL_M).clamp(0.0, (n - 1) as f64);
    let gy = ((y + site.half_m) / CELL_M).clamp(0.0, (n - 1) as f64);
    let i = (gx.floor() as usize).min(n.saturating_sub(2));
    let j = (gy.floor() as usize).min(n.saturating_sub(2));
    let (fx, fy) = ((gx - i as f64) as f32, (gy - j as f64) as f32);
    let at = |i: usize, j: usize| scene.normals.get(j * n + i).copied().unwrap_or([0.0, 0.0, 1.0]);
    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
    let mut out = [0.0; 3];
    for k in 0..3 {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bottom = c[k] + (d[k] - c[k]) * fx;
        out[k] = top + (bottom - top) * fy;
    }
    let len = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt().max(1e-6);
    let scalar = |field: &[f32]| {
        let at = |i: usize, j: usize| field.get(j * n + i).copied().unwrap_or(1.0);
        let top = at(i, j) + (at(i + 1, j) - at(i, j)) * fx;
        let bottom = at(i, j + 1) + (at(i + 1, j + 1) - at(i, j + 1)) * fx;
        top + (bottom - top) * fy
    };
    ([out[0] / len, out[1] / len, out[2] / len], scalar(&scene.occlusion), scalar(&scene.sunlit))
}

/// Separable Gaussian blur of an interleaved RGB float buffer.
fn blur(rgb: &mut Vec<f32>, w: usize, h: usize, sigma: f32, parallel: bool) {
    if sigma < 0.05 || w == 0 || h == 0 {
        return;
    }
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius).map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp()).collect();
    let sum: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / sum).collect();
    let mut tmp = vec![0.0f32; rgb.len()];
    {
        let src = &*rgb;
        for_rows(&mut tmp, w * 3, parallel, |row, out| {
            for (col, px) in out.chunks_exact_mut(3).enumerate() {
                let mut acc = [0.0f32; 3];
                for (k, weight) in kernel.iter().enumerate() {
                    let c = (col as isize + k as isize - radius).clamp(0, w as isize - 1) as usize;
                    let base = (row * w + c) * 3;
                    for (ch, a) in acc.iter_mut().enumerate() {
                        *a += weight * src.get(base + ch).copied().unwrap_or(0.0);
                    }
                }
                px.copy_from_slice(&acc);
            }
        });
    }
    let src = &tmp;
    for_rows(rgb, w * 3, parallel, |row, out| {
        for (col, px) in out.chunks_exact_mut(3).enumerate() {
            let mut acc = [0.0f32; 3];
            for (k, weight) in kernel.iter().enumerate() {
                let r = (row as isize + k as isize - radius).clamp(0, h as isize - 1) as usize;
                let base = (r * w + col) * 3;
                for (ch, a) in acc.iter_mut().enumerate() {
                    *a += weight * src.get(base + ch).copied().unwrap_or(0.0);
                }
            }
            px.copy_from_slice(&acc);
        }
    });
}

/// Tone curve, gamma, sensor noise and quantisation.
fn finish(rgb: &[f32], w: usize, h: usize, look: &Appearance, noise_seed: u64) -> image::RgbImage {
    let seed = (noise_seed ^ (noise_seed >> 32)) as u32;
    let mut bytes = vec![0u8; w * h * 3];
    bytes.par_chunks_mut(3).zip(rgb.par_chunks(3)).enumerate().for_each(|(i, (out, linear))| {
        for (k, (o, &v)) in out.iter_mut().zip(linear).enumerate() {
            // Linear exposure with a soft shoulder, then a display gamma.
            let x = look.exposure * v.max(0.0);
            let toned = if x < 0.8 { x } else { 0.8 + 0.2 * (1.0 - (-(x - 0.8) / 0.2).exp()) };
            let mut level = toned.powf(1.0 / 2.0) * 255.0;
            if look.noise_sigma > 0.0 {
                let hsh = noise::hash2(i as i32, k as i32, seed);
                let g = noise::unit(hsh)
                    + noise::unit(hsh.rotate_left(11) ^ 0x9E37_79B9)
                    + noise::unit(noise::hash2(k as i32, i as i32, seed ^ 0x55))
                    - 1.5;
                level += 2.0 * g * look.noise_sigma;
            }
            *o = (level + 0.5).clamp(0.0, 255.0) as u8;
        }
    });
    image::RgbImage::from_raw(w as u32, h as u32, bytes).unwrap_or_else(|| image::RgbImage::new(w as u32, h as u32))
}

/// Renders one view of a session's scene.
pub(crate) fn render_view(
    site: &Site,
    scene: &SessionScene,
    view: &View,
    look: &Appearance,
    time_s: f64,
    noise_seed: u64,
) -> Rendered {
    let parallel = rayon::current_thread_index().is_none();
    let depth_m = rasterize(site, scene, view, 1, parallel);
    let object_id = object_ids(site, scene, view, &depth_m, parallel);
    let mut linear = shade(site, scene, view, look, time_s, &depth_m, parallel);
    blur(&mut linear, view.width, view.height, look.blur_px, parallel);
    let rgb = finish(&linear, view.width, view.height, look, noise_seed);
    Rendered { rgb, depth_m, object_id }
}
