//! Image planes, separable Gaussian blur and octave resampling.
//!
//! Hot loops are written over equal-length slices zipped together so that the
//! compiler vectorises them (no `unsafe`, no bounds checks in the inner loops).

/// A single-channel `f32` image, row-major, values in `[0, 1]` for input images.
#[derive(Clone, Debug, Default)]
pub(crate) struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    pub fn new(width: usize, height: usize) -> Self {
        Self { width, height, data: vec![0.0; width * height] }
    }

    /// Row `y`, empty when out of range.
    pub fn row(&self, y: usize) -> &[f32] {
        let start = y * self.width;
        self.data.get(start..start + self.width).unwrap_or(&[])
    }

    /// The value at (x, y), 0 outside the plane.
    pub fn at(&self, x: usize, y: usize) -> f32 {
        if x >= self.width {
            return 0.0;
        }
        self.data.get(y * self.width + x).copied().unwrap_or(0.0)
    }

    /// Makes the plane `width` x `height`, reusing its allocation.
    pub fn resize(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.resize(width * height, 0.0);
    }
}

/// Half of a normalised Gaussian kernel: `taps[0]` is the centre weight and
/// `taps[k]` the weight at distance `k`; radius `ceil(4 sigma)` like VLFeat/OpenCV.
pub(crate) fn gaussian_taps(sigma: f32) -> Vec<f32> {
    let radius = ((4.0 * sigma).ceil() as usize).max(1);
    let mut taps: Vec<f32> = (0..=radius).map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp()).collect();
    let total: f32 = taps.iter().skip(1).sum::<f32>() * 2.0 + taps.first().copied().unwrap_or(0.0);
    for tap in &mut taps {
        *tap /= total;
    }
    taps
}

/// Index `i` (may be negative or past the end) mirrored into `0..len` without
/// repeating the edge sample (OpenCV's BORDER_REFLECT_101: `dcb|abcd|cba`).
fn reflect101(i: isize, len: usize) -> usize {
    let len = len as isize;
    if len <= 1 {
        return 0;
    }
    let period = 2 * (len - 1);
    let mut i = i.rem_euclid(period);
    if i >= len {
        i = period - i;
    }
    i as usize
}

/// Reusable row buffers for [`blur`].
#[derive(Default)]
pub(crate) struct BlurScratch {
    padded: Vec<f32>,
    row_offsets: Vec<(usize, usize)>,
}

/// Output values computed together, held in registers across all taps.
const LANES: usize = 16;

/// A `LANES`-long window of `data` starting at `start`, if it fits.
#[inline]
fn window(data: &[f32], start: usize) -> Option<&[f32; LANES]> {
    data.get(start..start + LANES).and_then(|w| w.try_into().ok())
}

/// Separable Gaussian blur of `src` into `dst` (resized to match) with the half
/// kernel `taps`. Vertical pass first, one output row at a time into a padded
/// row buffer, then the horizontal pass from that buffer: no full-size
/// temporary image. Both passes accumulate `LANES` outputs in registers over
/// all taps, which the compiler turns into SIMD code.
pub(crate) fn blur(src: &Plane, dst: &mut Plane, taps: &[f32], scratch: &mut BlurScratch) {
    let (width, height) = (src.width, src.height);
    dst.resize(width, height);
    let radius = taps.len().saturating_sub(1);
    let Some((&center, side_taps)) = taps.split_first() else {
        dst.data.copy_from_slice(&src.data);
        return;
    };
    let BlurScratch { padded, row_offsets } = scratch;
    padded.clear();
    padded.resize(width + 2 * radius, 0.0);
    for (y, out_row) in dst.data.chunks_exact_mut(width).enumerate() {
        // Vertical pass into the middle of the padded row.
        row_offsets.clear();
        row_offsets.extend((1..=radius).map(|distance| {
            let above = reflect101(y as isize - distance as isize, height);
            let below = reflect101((y + distance) as isize, height);
            (above * width, below * width)
        }));
        let centre_offset = y * width;
        let (left, rest) = padded.split_at_mut(radius);
        let (middle, right) = rest.split_at_mut(width);
        let mut chunks = middle.chunks_exact_mut(LANES);
        for (index, chunk) in (&mut chunks).enumerate() {
            let x = index * LANES;
            let Some(values) = window(&src.data, centre_offset + x) else {
                continue;
            };
            let mut acc = values.map(|v| center * v);
            for (&weight, &(above, below)) in side_taps.iter().zip(row_offsets.iter()) {
                let (Some(a), Some(b)) = (window(&src.data, above + x), window(&src.data, below + x)) else {
                    continue;
                };
                for ((o, &p), &q) in acc.iter_mut().zip(a).zip(b) {
                    *o += weight * (p + q);
                }
            }
            chunk.copy_from_slice(&acc);
        }
        let done = width - chunks.into_remainder().len();
        for x in done..width {
            let mut acc = center * src.data.get(centre_offset + x).copied().unwrap_or(0.0);
            for (&weight, &(above, below)) in side_taps.iter().zip(row_offsets.iter()) {
                let p = src.data.get(above + x).copied().unwrap_or(0.0);
                let q = src.data.get(below + x).copied().unwrap_or(0.0);
                acc += weight * (p + q);
            }
            if let Some(slot) = middle.get_mut(x) {
                *slot = acc;
            }
        }
        // Mirror the borders of the vertically blurred row.
        for (k, pad) in left.iter_mut().enumerate() {
            let source = reflect101(k as isize - radius as isize, width);
            *pad = middle.get(source).copied().unwrap_or(0.0);
        }
        for (k, pad) in right.iter_mut().enumerate() {
            let source = reflect101((width + k) as isize, width);
            *pad = middle.get(source).copied().unwrap_or(0.0);
        }
        // Horizontal pass: output x reads padded[x .. x + 2 radius].
        let padded: &[f32] = padded;
        let mut chunks = out_row.chunks_exact_mut(LANES);
        for (index, chunk) in (&mut chunks).enumerate() {
            let x = index * LANES;
            let Some(values) = window(padded, x + radius) else {
                continue;
            };
            let mut acc = values.map(|v| center * v);
            for (k, &weight) in side_taps.iter().enumerate() {
                let distance = k + 1;
                let (Some(a), Some(b)) = (window(padded, x + radius - distance), window(padded, x + radius + distance))
                else {
                    continue;
                };
                for ((o, &p), &q) in acc.iter_mut().zip(a).zip(b) {
                    *o += weight * (p + q);
                }
            }
            chunk.copy_from_slice(&acc);
        }
        let done = width - chunks.into_remainder().len();
        for (x, out) in out_row.iter_mut().enumerate().skip(done) {
            let mut acc = center * padded.get(x + radius).copied().unwrap_or(0.0);
            for (k, &weight) in side_taps.iter().enumerate() {
                let distance = k + 1;
                let p = padded.get(x + radius - distance).copied().unwrap_or(0.0);
                let q = padded.get(x + radius + distance).copied().unwrap_or(0.0);
                acc += weight * (p + q);
            }
            *out = acc;
        }
    }
}

/// Doubles the resolution by linear interpolation as VLFeat does: output pixel
/// `2i` is input pixel `i` and `2i + 1` the mean of `i` and `i + 1` (the last
/// one repeats), so output pixel centre `u` sits at input pixel centre `u / 2`.
pub(crate) fn upsample2(src: &Plane) -> Plane {
    let (width, height) = (src.width, src.height);
    let mut wide = Plane::new(2 * width, height);
    for (y, out) in wide.data.chunks_exact_mut(2 * width).enumerate() {
        let row = src.row(y);
        for (x, pair) in out.chunks_exact_mut(2).enumerate() {
            let a = row.get(x).copied().unwrap_or(0.0);
            let b = row.get(x + 1).copied().unwrap_or(a);
            if let [even, odd] = pair {
                *even = a;
                *odd = 0.5 * (a + b);
            }
        }
    }
    let mut tall = Plane::new(2 * width, 2 * height);
    let out_width = 2 * width;
    for (y, pair) in tall.data.chunks_exact_mut(2 * out_width).enumerate() {
        let a = wide.row(y);
        let b = if y + 1 < height { wide.row(y + 1) } else { a };
        let (even, odd) = pair.split_at_mut(out_width);
        even.copy_from_slice(a);
        for ((o, &p), &q) in odd.iter_mut().zip(a).zip(b) {
            *o = 0.5 * (p + q);
        }
    }
    tall
}

/// Keeps every other pixel (even rows and columns): output pixel centre `u`
/// sits at input pixel centre `2u`.
pub(crate) fn downsample2(src: &Plane, dst: &mut Plane) {
    let (width, height) = (src.width / 2, src.height / 2);
    dst.resize(width, height);
    for (y, out) in dst.data.chunks_exact_mut(width.max(1)).enumerate() {
        let row = src.row(2 * y);
        for (o, &value) in out.iter_mut().zip(row.iter().step_by(2)) {
            *o = value;
        }
    }
}

/// `dst = a - b`, elementwise.
pub(crate) fn subtract(a: &Plane, b: &Plane, dst: &mut Plane) {
    dst.resize(a.width, a.height);
    for ((d, &p), &q) in dst.data.iter_mut().zip(&a.data).zip(&b.data) {
        *d = p - q;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_preserves_constant_and_mass() {
        let mut src = Plane::new(37, 23);
        for (i, v) in src.data.iter_mut().enumerate() {
            *v = if i == 11 * 37 + 18 { 1.0 } else { 0.25 };
        }
        let taps = gaussian_taps(1.7);
        let mut dst = Plane::default();
        blur(&src, &mut dst, &taps, &mut BlurScratch::default());
        let sum: f32 = dst.data.iter().sum();
        let expected: f32 = src.data.iter().sum();
        assert!((sum - expected).abs() < 1e-3, "{sum} vs {expected}");
        assert!((dst.at(0, 0) - 0.25).abs() < 1e-6);
        // The impulse spreads symmetrically.
        let (cx, cy) = (18, 11);
        assert!((dst.at(cx - 2, cy) - dst.at(cx + 2, cy)).abs() < 1e-6);
        assert!((dst.at(cx, cy - 2) - dst.at(cx, cy + 2)).abs() < 1e-6);
    }

    #[test]
    fn blur_matches_a_direct_2d_convolution() {
        let (width, height) = (53, 29);
        let mut src = Plane::new(width, height);
        for (i, v) in src.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 101) as f32 / 101.0;
        }
        let taps = gaussian_taps(2.3);
        let mut dst = Plane::default();
        blur(&src, &mut dst, &taps, &mut BlurScratch::default());
        let r = taps.len() as isize - 1;
        for y in 0..height {
            for x in 0..width {
                let mut expected = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let sx = reflect101(x as isize + dx, width);
                        let sy = reflect101(y as isize + dy, height);
                        expected += taps[dx.unsigned_abs()] * taps[dy.unsigned_abs()] * src.at(sx, sy);
                    }
                }
                assert!((dst.at(x, y) - expected).abs() < 1e-5, "({x}, {y}): {} vs {expected}", dst.at(x, y));
            }
        }
    }

    #[test]
    fn reflect101_mirrors_without_repeating_the_edge() {
        let got: Vec<usize> = (-3..7).map(|i| reflect101(i, 4)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 1, 2, 3, 2, 1, 0]);
    }

    #[test]
    fn up_and_down_sampling_keep_pixel_centres() {
        let mut src = Plane::new(3, 2);
        src.data = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let up = upsample2(&src);
        assert_eq!((up.width, up.height), (6, 4));
        assert_eq!(up.row(0), &[0.0, 0.5, 1.0, 1.5, 2.0, 2.0]);
        assert_eq!(up.row(1), &[1.5, 2.0, 2.5, 3.0, 3.5, 3.5]);
        let mut down = Plane::default();
        downsample2(&up, &mut down);
        assert_eq!(down.data, src.data);
    }
}
