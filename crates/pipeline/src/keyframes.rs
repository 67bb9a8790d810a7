//! Keyframe selection for image streams (30 Hz video holds far more frames than mapping needs):
//! a frame is kept when enough time has passed, when the vehicle has travelled far enough (by
//! odometry), or when the image has moved so that its tracked overlap with the last keyframe falls
//! below a threshold. Sans-IO: frames are offered one at a time; the ingest node and
//! `reconstruct --bag` drive the same selector.

use image::{imageops::FilterType, DynamicImage, GrayImage};
use serde::{Deserialize, Serialize};

/// The default: keep a frame when under 70% of the last keyframe is still in view.
pub const DEFAULT_MIN_OVERLAP: f64 = 0.7;

/// Width of the thumbnails overlap is tracked on, pixels.
const THUMB_WIDTH_PX: u32 = 64;

/// When a frame becomes a keyframe; a criterion left `None` is not used. With none set, every
/// frame is kept.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeOptions {
    /// Keep a frame whose overlap with the last keyframe (fraction of the image, tracked as the
    /// image translation that best aligns the two) is below this.
    pub min_overlap: Option<f64>,
    /// Keep a frame this many seconds after the last keyframe.
    pub every_s: Option<f64>,
    /// Keep a frame this many metres (odometry) from the last keyframe.
    pub distance_m: Option<f64>,
}

impl Default for KeyframeOptions {
    fn default() -> Self {
        Self { min_overlap: Some(DEFAULT_MIN_OVERLAP), every_s: None, distance_m: None }
    }
}

impl KeyframeOptions {
    /// Every frame a keyframe.
    pub const ALL: KeyframeOptions = KeyframeOptions { min_overlap: None, every_s: None, distance_m: None };

    pub fn check(&self) -> Result<(), String> {
        if let Some(overlap) = self.min_overlap {
            if !(0.0..=1.0).contains(&overlap) {
                return Err(format!("--keyframe-overlap {overlap} is not between 0 and 1"));
            }
        }
        for (flag, value) in [("--keyframe-every", self.every_s), ("--keyframe-distance", self.distance_m)] {
            if value.is_some_and(|v| !(v.is_finite() && v > 0.0)) {
                return Err(format!("{flag} must be a positive number"));
            }
        }
        Ok(())
    }
}

/// Why a frame was kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reason {
    First,
    Every,
    Time,
    Distance,
    Overlap,
}

struct Last {
    time_ns: u64,
    position_m: Option<[f64; 3]>,
    thumb: Option<Thumb>,
}

/// Chooses keyframes from a stream of frames.
pub struct KeyframeSelector {
    options: KeyframeOptions,
    last: Option<Last>,
}

impl KeyframeSelector {
    pub fn new(options: KeyframeOptions) -> Self {
        Self { options, last: None }
    }

    /// Offers the next frame: its time, the odometry position at that time if known, and its
    /// image. Returns why it is a keyframe, or `None` to drop it.
    pub fn offer(&mut self, time_ns: u64, position_m: Option<[f64; 3]>, image: &DynamicImage) -> Option<Reason> {
        let options = self.options;
        let thumb = || options.min_overlap.map(|_| Thumb::of(image));
        let reason = match &self.last {
            None => Some(Reason::First),
            Some(_) if options == KeyframeOptions::ALL => Some(Reason::Every),
            Some(last) => {
                let elapsed_s = time_ns.saturating_sub(last.time_ns) as f64 * 1e-9;
                let travelled_m = match (last.position_m, position_m) {
                    (Some(a), Some(b)) => Some((0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()),
                    _ => None,
                };
                if options.every_s.is_some_and(|every| elapsed_s >= every) {
                    Some(Reason::Time)
                } else if options.distance_m.zip(travelled_m).is_some_and(|(limit, d)| d >= limit) {
                    Some(Reason::Distance)
                } else if let (Some(min), Some(last_thumb)) = (options.min_overlap, &last.thumb) {
                    let current = Thumb::of(image);
                    (last_thumb.overlap(&current) < min).then_some(Reason::Overlap)
                } else {
                    None
                }
            }
        };
        if reason.is_some() {
            self.last = Some(Last { time_ns, position_m, thumb: thumb() });
        }
        reason
    }
}

/// A small zero-mean grey copy of a frame.
struct Thumb {
    width: usize,
    height: usize,
    pixels: Vec<f32>,
}

impl Thumb {
    fn of(image: &DynamicImage) -> Thumb {
        let height = (THUMB_WIDTH_PX as f64 * image.height() as f64 / image.width().max(1) as f64).round().max(8.0) as u32;
        let grey: GrayImage = image.resize_exact(THUMB_WIDTH_PX, height, FilterType::Triangle).into_luma8();
        let mean = grey.pixels().map(|p| f32::from(p.0[0])).sum::<f32>() / grey.len() as f32;
        Thumb {
            width: THUMB_WIDTH_PX as usize,
            height: height as usize,
            pixels: grey.pixels().map(|p| f32::from(p.0[0]) - mean).collect(),
        }
    }

    /// The fraction of this thumbnail still seen in `other`: the translation (up to half the
    /// image each way) with the least mean absolute difference over the shared area gives the
    /// shared area. A frame that matches no shift well (a turn, a different scene) overlaps 0.
    fn overlap(&self, other: &Thumb) -> f64 {
        if (self.width, self.height) != (other.width, other.height) {
            return 0.0;
        }
        let (w, h) = (self.width as isize, self.height as isize);
        let mut best = (f32::INFINITY, 0.0);
        for dy in -h / 2..=h / 2 {
            for dx in -w / 2..=w / 2 {
                let (x0, x1) = (dx.max(0), (w + dx).min(w));
                let (y0, y1) = (dy.max(0), (h + dy).min(h));
                let mut sum = 0.0;
                for y in y0..y1 {
                    let a = &self.pixels[(y * w) as usize..][x0 as usize..x1 as usize];
                    let b = &other.pixels[((y - dy) * w) as usize..][(x0 - dx) as usize..(x1 - dx) as usize];
                    sum += a.iter().zip(b).map(|(p, q)| (p - q).abs()).sum::<f32>();
                }
                let area = ((x1 - x0) * (y1 - y0)) as f32;
                let cost = sum / area;
                if cost < best.0 {
                    best = (cost, area as f64 / (w * h) as f64);
                }
            }
        }
        // Aligned content differs by noise; unrelated content by about its own contrast.
        let contrast = self.pixels.iter().map(|p| p.abs()).sum::<f32>() / self.pixels.len() as f32;
        if best.0 > 0.5 * contrast { 0.0 } else { best.1 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Luma, RgbImage};

    /// Value noise: a hashed value per cell of `cell` pixels, interpolated bilinearly.
    fn noise(u: f32, v: f32, cell: f32) -> f32 {
        let hash = |i: i64, j: i64| ((i.wrapping_mul(73_856_093) ^ j.wrapping_mul(19_349_663)) & 0xFFFF) as f32 / 65_535.0;
        let (x, y) = (u / cell, v / cell);
        let (i, j) = (x.floor() as i64, y.floor() as i64);
        let (fx, fy) = (x - x.floor(), y - y.floor());
        let top = hash(i, j) * (1.0 - fx) + hash(i + 1, j) * fx;
        let bottom = hash(i, j + 1) * (1.0 - fx) + hash(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// A textured, non-repeating scene, and a 320x240 view of it at (x, y).
    fn view(x: u32, y: u32) -> DynamicImage {
        let image = GrayImage::from_fn(320, 240, |u, v| {
            let (u, v) = ((u + x) as f32, (v + y) as f32);
            Luma([(40.0 + 120.0 * noise(u, v, 23.0) + 60.0 * noise(u, v, 7.0)) as u8])
        });
        DynamicImage::ImageLuma8(image)
    }

    #[test]
    fn tracked_overlap_follows_the_image_translation() {
        let start = Thumb::of(&view(100, 100));
        for (dx, dy, expected) in [(0, 0, 1.0), (32, 0, 0.9), (80, 0, 0.75), (80, 60, 0.5625), (0, 96, 0.6)] {
            let overlap = start.overlap(&Thumb::of(&view(100 + dx, 100 + dy)));
            assert!((overlap - expected).abs() < 0.05, "shift ({dx}, {dy}): overlap {overlap:.3}, expected {expected}");
        }
        let unrelated = DynamicImage::ImageRgb8(RgbImage::from_fn(320, 240, |x, y| image::Rgb([((x * y) % 251) as u8; 3])));
        assert!(start.overlap(&Thumb::of(&unrelated)) < 0.3);
    }

    #[test]
    fn a_frame_is_kept_when_overlap_time_or_distance_says_so() {
        let mut selector = KeyframeSelector::new(KeyframeOptions::default());
        let kept: Vec<u32> = (0..=40)
            .filter(|i| selector.offer(u64::from(*i) * 33_000_000, None, &view(100 + 8 * i, 100)).is_some())
            .collect();
        // 8 px a frame: overlap falls below 0.7 after 96 px, i.e. every 13th frame.
        assert_eq!(kept, vec![0, 13, 26, 39]);

        let options = KeyframeOptions { min_overlap: None, every_s: Some(1.0), distance_m: Some(2.0) };
        let mut selector = KeyframeSelector::new(options);
        let still = view(100, 100);
        let mut reasons = Vec::new();
        for (t_s, x_m) in [(0.0, 0.0), (0.5, 0.5), (0.9, 2.5), (1.5, 2.6), (2.0, 2.7)] {
            reasons.push(selector.offer((t_s * 1e9) as u64, Some([x_m, 0.0, 0.0]), &still));
        }
        assert_eq!(reasons, vec![Some(Reason::First), None, Some(Reason::Distance), None, Some(Reason::Time)]);

        let mut every = KeyframeSelector::new(KeyframeOptions::ALL);
        assert!((0..5).all(|i| every.offer(i, None, &still).is_some()));
    }
}
