//! Dominant orientations and the 4x4x8 SIFT descriptor (Lowe 2004, sections 5
//! and 6), computed on the Gaussian image of the keypoint's scale layer.
//!
//! Angles are in the image's y-down frame: an orientation `theta` means the
//! keypoint's x axis points along `(cos theta, sin theta)` in pixels, the
//! convention of COLMAP's affine keypoint columns.

use std::f32::consts::{PI, TAU};

use super::pyramid::Plane;
use super::Normalization;

/// Bins of the orientation histogram.
const ORIENTATION_BINS: usize = 36;
/// The orientation window's sigma in units of the keypoint's sigma.
const ORIENTATION_SIGMA_FACTOR: f32 = 1.5;
/// The orientation window's radius in units of its sigma.
const ORIENTATION_RADIUS_FACTOR: f32 = 3.0;
/// Secondary orientation peaks at least this fraction of the highest are kept.
const ORIENTATION_PEAK_RATIO: f32 = 0.8;

/// Spatial bins per side of the descriptor.
const SPATIAL_BINS: usize = 4;
/// Orientation bins of the descriptor.
const DESCRIPTOR_ORIENTATION_BINS: usize = 8;
/// Length of the descriptor.
pub(crate) const DESCRIPTOR_DIM: usize = SPATIAL_BINS * SPATIAL_BINS * DESCRIPTOR_ORIENTATION_BINS;
/// Width of one spatial bin in units of the keypoint's sigma.
const DESCRIPTOR_BIN_FACTOR: f32 = 3.0;
/// Descriptor entries are clamped at this fraction of the norm (Lowe's 0.2).
const DESCRIPTOR_CLAMP: f32 = 0.2;

/// `atan2(y, x)` in `[0, 2 pi)`, absolute error below 2e-5 rad; branch-free
/// so that loops over it vectorise.
#[inline]
pub(crate) fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    let a = lo / hi.max(f32::MIN_POSITIVE);
    let s = a * a;
    let poly = -0.011_721_2_f32;
    let poly = poly * s + 0.052_653_32;
    let poly = poly * s - 0.116_432_87;
    let poly = poly * s + 0.193_543_46;
    let poly = poly * s - 0.332_623_47;
    let poly = poly * s + 0.999_977_26;
    let mut angle = poly * a;
    angle = if ay > ax { 0.5 * PI - angle } else { angle };
    angle = if x < 0.0 { PI - angle } else { angle };
    if y < 0.0 {
        TAU - angle
    } else {
        angle
    }
}

/// Up to `max_orientations` dominant gradient orientations (radians, `[0, 2 pi)`)
/// around the integer pixel (column, row) of `gaussian`, strongest first.
pub(crate) fn orientations(
    gaussian: &Plane,
    column: usize,
    row: usize,
    sigma_octave: f32,
    max_orientations: usize,
) -> Vec<f32> {
    let sigma = ORIENTATION_SIGMA_FACTOR * sigma_octave;
    let radius = (ORIENTATION_RADIUS_FACTOR * sigma).round() as isize;
    let weights: Vec<f32> = (-radius..=radius).map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp()).collect();
    let (width, height) = (gaussian.width as isize, gaussian.height as isize);
    let (c, r) = (column as isize, row as isize);
    let mut hist = [0.0_f32; ORIENTATION_BINS];
    let (mut values, mut bins) = (Vec::new(), Vec::new());
    let bins_per_radian = ORIENTATION_BINS as f32 / TAU;
    let x_start = (c - radius).max(1);
    let x_end = (c + radius).min(width - 2);
    if x_start > x_end {
        return Vec::new();
    }
    for (i, &weight_y) in (-radius..=radius).zip(&weights) {
        let y = r + i;
        if y < 1 || y >= height - 1 {
            continue;
        }
        let (x0, x1) = (x_start as usize, x_end as usize);
        let (Some(above), Some(middle), Some(below)) = (
            gaussian.row(y as usize - 1).get(x0..=x1),
            gaussian.row(y as usize).get(x0 - 1..=x1 + 1),
            gaussian.row(y as usize + 1).get(x0..=x1),
        ) else {
            continue;
        };
        let weights_x = weights.get((x_start - (c - radius)) as usize..).unwrap_or(&[]);
        // Vectorisable pass, then the scatter into the histogram.
        let count = x1 - x0 + 1;
        values.resize(count, 0.0);
        bins.resize(count, 0.0);
        let samples = middle.array_windows::<3>().zip(above).zip(below).zip(weights_x);
        for (((([left, _, right], &up), &down), &weight_x), (value, bin)) in
            samples.zip(values.iter_mut().zip(bins.iter_mut()))
        {
            let (dx, dy) = (right - left, down - up);
            *value = (dx * dx + dy * dy).sqrt() * weight_x * weight_y;
            // Nearest bin (the angle is >= 0, so truncation after + 0.5 rounds).
            *bin = fast_atan2(dy, dx) * bins_per_radian + 0.5;
        }
        for (&value, &bin) in values.iter().zip(bins.iter()) {
            let bin = bin as usize;
            let bin = if bin >= ORIENTATION_BINS { bin - ORIENTATION_BINS } else { bin };
            if let Some(h) = hist.get_mut(bin) {
                *h += value;
            }
        }
    }
    // Circular smoothing with [1 4 6 4 1] / 16, as OpenCV.
    let n = ORIENTATION_BINS;
    let at = |k: usize| hist.get(k % n).copied().unwrap_or(0.0);
    let smooth: Vec<f32> = (0..n)
        .map(|k| {
            (at(k + n - 2) + at(k + 2)) * (1.0 / 16.0)
                + (at(k + n - 1) + at(k + 1)) * (4.0 / 16.0)
                + at(k) * (6.0 / 16.0)
        })
        .collect();
    let max = smooth.iter().copied().fold(0.0_f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let threshold = ORIENTATION_PEAK_RATIO * max;
    let value = |k: usize| smooth.get(k % n).copied().unwrap_or(0.0);
    let mut peaks: Vec<(f32, f32)> = Vec::new();
    for k in 0..n {
        let (left, centre, right) = (value(k + n - 1), value(k), value(k + 1));
        if centre > left && centre > right && centre >= threshold {
            let denominator = left - 2.0 * centre + right;
            let shift = if denominator != 0.0 { 0.5 * (left - right) / denominator } else { 0.0 };
            let bin = (k as f32 + shift).rem_euclid(n as f32);
            let angle = (bin * TAU / n as f32).rem_euclid(TAU);
            peaks.push((centre, angle));
        }
    }
    peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.total_cmp(&b.1)));
    peaks.into_iter().take(max_orientations).map(|(_, angle)| angle).collect()
}

/// Reusable buffers for [`descriptor`].
#[derive(Default)]
pub(crate) struct DescriptorScratch {
    weights_x: Vec<f32>,
    magnitudes: Vec<f32>,
    obins: Vec<f32>,
    rbins: Vec<f32>,
    cbins: Vec<f32>,
}

/// A keypoint in its octave: sub-pixel position (octave pixels, centres at
/// integers), sigma (octave pixels) and orientation (radians).
#[derive(Clone, Copy, Debug)]
pub(crate) struct OctaveFrame {
    pub x: f32,
    pub y: f32,
    pub sigma: f32,
    pub orientation: f32,
}

/// The descriptor of the keypoint `frame` on its Gaussian image, normalised
/// and converted to bytes as COLMAP stores them.
pub(crate) fn descriptor(
    gaussian: &Plane,
    frame: &OctaveFrame,
    normalization: Normalization,
    scratch: &mut DescriptorScratch,
) -> [u8; DESCRIPTOR_DIM] {
    let mut hist = [0.0_f32; DESCRIPTOR_DIM];
    let mut padded = [0.0_f32; PADDED_LEN];
    accumulate(gaussian, frame, &mut padded, &mut hist, scratch);
    to_bytes(&mut hist, normalization)
}

/// The offsets `t` with `|a t + b| < half` as an open interval, or `None`.
fn band(a: f32, b: f32, half: f32) -> Option<(f32, f32)> {
    if a.abs() < 1e-6 {
        return (b.abs() < half).then_some((f32::NEG_INFINITY, f32::INFINITY));
    }
    let (p, q) = ((-half - b) / a, (half - b) / a);
    Some((p.min(q), p.max(q)))
}

/// Gradient samples weighted by a Gaussian of half the window and spread over
/// the 4x4x8 bins by trilinear interpolation.
fn accumulate(
    gaussian: &Plane,
    frame: &OctaveFrame,
    padded: &mut [f32; PADDED_LEN],
    hist: &mut [f32; DESCRIPTOR_DIM],
    scratch: &mut DescriptorScratch,
) {
    let &OctaveFrame { x, y, sigma: sigma_octave, orientation } = frame;
    let d = SPATIAL_BINS as f32;
    let n = DESCRIPTOR_ORIENTATION_BINS as f32;
    let bin_width = DESCRIPTOR_BIN_FACTOR * sigma_octave;
    let (sin, cos) = orientation.sin_cos();
    // Samples contribute while their bin coordinate is in (-1, d): a rotated
    // square of half side (d / 2 + 0.5) bins around the keypoint.
    let half_side = (0.5 * d + 0.5) * bin_width;
    let radius = (half_side * (cos.abs() + sin.abs())).ceil() as isize;
    let (width, height) = (gaussian.width as isize, gaussian.height as isize);
    let (ci, ri) = (x.round() as isize, y.round() as isize);
    let (fx, fy) = (x - ci as f32, y - ri as f32);
    let x_start = (ci - radius).max(1);
    let x_end = (ci + radius).min(width - 2);
    if x_start > x_end {
        return;
    }
    // Gaussian weight exp(-(c^2 + r^2) / (2 (d / 2)^2)) in bin units is
    // separable in the unrotated pixel offsets.
    let weight_scale = -1.0 / (0.5 * d * d * bin_width * bin_width);
    scratch.weights_x.clear();
    scratch.weights_x.extend((x_start..=x_end).map(|xs| {
        let dx = (xs - ci) as f32 - fx;
        (dx * dx * weight_scale).exp()
    }));
    let (cos_b, sin_b) = (cos / bin_width, sin / bin_width);
    let bins_per_radian = n / TAU;
    for ys in (ri - radius).max(1)..=(ri + radius).min(height - 2) {
        let dy = (ys - ri) as f32 - fy;
        // This row's samples inside the rotated square.
        let (Some((a_lo, a_hi)), Some((b_lo, b_hi))) =
            (band(cos, dy * sin, half_side), band(-sin, dy * cos, half_side))
        else {
            continue;
        };
        let lo = ((a_lo.max(b_lo) + fx).ceil() as isize + ci).max(x_start);
        let hi = ((a_hi.min(b_hi) + fx).floor() as isize + ci).min(x_end);
        if lo > hi {
            continue;
        }
        let (x0, x1) = (lo as usize, hi as usize);
        let (Some(above), Some(middle), Some(below), Some(weights_x)) = (
            gaussian.row(ys as usize - 1).get(x0..=x1),
            gaussian.row(ys as usize).get(x0 - 1..=x1 + 1),
            gaussian.row(ys as usize + 1).get(x0..=x1),
            scratch.weights_x.get((lo - x_start) as usize..=(hi - x_start) as usize),
        ) else {
            continue;
        };
        let weight_y = (dy * dy * weight_scale).exp();
        // Vectorisable pass: weighted gradient magnitude, orientation bin and
        // spatial bins of every sample of the row.
        let count = x1 - x0 + 1;
        for buffer in [&mut scratch.magnitudes, &mut scratch.obins, &mut scratch.rbins, &mut scratch.cbins] {
            buffer.resize(count, 0.0);
        }
        let dy_cos = dy * cos_b + 0.5 * d - 0.5;
        let dy_sin = dy * sin_b + 0.5 * d - 0.5;
        let dx_first = (lo - ci) as f32 - fx;
        let gradients = middle.array_windows::<3>().zip(above).zip(below).zip(weights_x);
        let outputs = scratch
            .magnitudes
            .iter_mut()
            .zip(scratch.obins.iter_mut())
            .zip(scratch.rbins.iter_mut().zip(scratch.cbins.iter_mut()));
        for (k, (((([left, _, right], &up), &down), &weight_x), ((magnitude, obin), (rbin, cbin)))) in
            gradients.zip(outputs).enumerate()
        {
            let (gx, gy) = (right - left, down - up);
            *magnitude = (gx * gx + gy * gy).sqrt() * weight_x * weight_y;
            let relative = fast_atan2(gy, gx) - orientation;
            let relative = if relative < 0.0 { relative + TAU } else { relative };
            *obin = (relative * bins_per_radian).min(n - 1e-3);
            let dx = dx_first + k as f32;
            *cbin = dx * cos_b + dy_sin;
            *rbin = -dx * sin_b + dy_cos;
        }
        // Scatter pass.
        let samples = scratch.magnitudes.iter().zip(&scratch.obins).zip(scratch.rbins.iter().zip(&scratch.cbins));
        for ((&magnitude, &obin), (&rbin, &cbin)) in samples {
            if cbin > -1.0 && cbin < d && rbin > -1.0 && rbin < d {
                spread(padded, rbin, cbin, obin, magnitude);
            }
        }
    }
    // Fold the padding: orientation bin n wraps to 0, spatial pads are dropped.
    for r in 0..SPATIAL_BINS {
        for c in 0..SPATIAL_BINS {
            let source = ((r + 1) * PADDED_SIDE + c + 1) * PADDED_ORIENTATIONS;
            let target = (r * SPATIAL_BINS + c) * DESCRIPTOR_ORIENTATION_BINS;
            let (Some(from), Some(to)) = (
                padded.get(source..source + PADDED_ORIENTATIONS),
                hist.get_mut(target..target + DESCRIPTOR_ORIENTATION_BINS),
            ) else {
                continue;
            };
            to.copy_from_slice(from.get(..DESCRIPTOR_ORIENTATION_BINS).unwrap_or(&[0.0; DESCRIPTOR_ORIENTATION_BINS]));
            if let (Some(first), Some(&wrapped)) = (to.first_mut(), from.get(DESCRIPTOR_ORIENTATION_BINS)) {
                *first += wrapped;
            }
        }
    }
}

/// Spatial side of the padded histogram: one guard bin on each side.
const PADDED_SIDE: usize = SPATIAL_BINS + 2;
/// Orientation bins of the padded histogram: bin n collects the wrap to 0.
const PADDED_ORIENTATIONS: usize = DESCRIPTOR_ORIENTATION_BINS + 2;
const PADDED_LEN: usize = PADDED_SIDE * PADDED_SIDE * PADDED_ORIENTATIONS;

/// Adds `value` to the 8 bins around (rbin, cbin, obin) of the padded
/// histogram with trilinear weights; `rbin`, `cbin` in (-1, SPATIAL_BINS),
/// `obin` in [0, 8). Branch-free apart from bounds checks that always pass.
#[inline]
fn spread(padded: &mut [f32; PADDED_LEN], rbin: f32, cbin: f32, obin: f32, value: f32) {
    // Truncation is floor here: every coordinate + 1 is positive.
    let (r0, c0, o0) = ((rbin + 1.0) as usize, (cbin + 1.0) as usize, obin.max(0.0) as usize);
    let (fr, fc, fo) = (rbin + 1.0 - r0 as f32, cbin + 1.0 - c0 as f32, obin - o0 as f32);
    let v_r1 = value * fr;
    let v_r0 = value - v_r1;
    let v_rc11 = v_r1 * fc;
    let v_rc10 = v_r1 - v_rc11;
    let v_rc01 = v_r0 * fc;
    let v_rc00 = v_r0 - v_rc01;
    let index = (r0 * PADDED_SIDE + c0) * PADDED_ORIENTATIONS + o0;
    let row_step = PADDED_SIDE * PADDED_ORIENTATIONS;
    for (offset, v) in
        [(0, v_rc00), (PADDED_ORIENTATIONS, v_rc01), (row_step, v_rc10), (row_step + PADDED_ORIENTATIONS, v_rc11)]
    {
        let v1 = v * fo;
        if let Some([a, b]) = padded.get_mut(index + offset..index + offset + 2) {
            *a += v - v1;
            *b += v1;
        }
    }
}

/// L2-normalises, clamps at 0.2 and renormalises (Lowe), then applies the
/// requested normalisation and COLMAP's `FeatureDescriptorsToUnsignedByte`:
/// `min(255, round(512 v))`.
fn to_bytes(hist: &mut [f32; DESCRIPTOR_DIM], normalization: Normalization) -> [u8; DESCRIPTOR_DIM] {
    let l2 = |h: &[f32; DESCRIPTOR_DIM]| h.iter().map(|v| v * v).sum::<f32>().sqrt().max(f32::MIN_POSITIVE);
    let norm = l2(hist);
    for v in hist.iter_mut() {
        *v = (*v / norm).min(DESCRIPTOR_CLAMP);
    }
    let norm = l2(hist);
    for v in hist.iter_mut() {
        *v /= norm;
    }
    if normalization == Normalization::L1Root {
        let l1 = hist.iter().sum::<f32>().max(f32::MIN_POSITIVE);
        for v in hist.iter_mut() {
            *v = (*v / l1).sqrt();
        }
    }
    hist.map(|v| (512.0 * v).round().min(255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_matches_std_everywhere() {
        for k in 0..3600 {
            let angle = k as f32 * TAU / 3600.0;
            let (s, c) = angle.sin_cos();
            for radius in [1e-3_f32, 0.7, 300.0] {
                let got = fast_atan2(radius * s, radius * c);
                let expected = (radius * s).atan2(radius * c).rem_euclid(TAU);
                let error = (got - expected).abs().min(TAU - (got - expected).abs());
                assert!(error < 1e-4, "angle {angle}: {got} vs {expected}");
            }
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
    }

    #[test]
    fn l2_bytes_have_norm_512_and_l1_root_bytes_too() {
        let mut hist = [0.0_f32; DESCRIPTOR_DIM];
        for (i, v) in hist.iter_mut().enumerate() {
            *v = ((i * 37) % 11) as f32;
        }
        for normalization in [Normalization::L2, Normalization::L1Root] {
            let bytes = to_bytes(&mut hist.clone(), normalization);
            let sum_sq: f32 = bytes.iter().map(|&b| f32::from(b) * f32::from(b)).sum();
            assert!((sum_sq.sqrt() - 512.0).abs() < 8.0, "{normalization:?}: {}", sum_sq.sqrt());
        }
    }
}
