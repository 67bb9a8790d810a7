//! Keyframe selection for image streams (30 Hz video holds far more frames than mapping needs):
//! a frame is kept when enough time has passed, when the vehicle has travelled far enough (by
//! odometry), or when the image has moved so that its tracked overlap with the last keyframe falls
//! below a threshold. Sans-IO: frames are offered one at a time; the ingest node and
//! `reconstruct --bag` drive the same selector.

use image::{DynamicImage, GrayImage};
use serde::{Deserialize, Serialize};

/// The default: keep a frame when under 70% of the last keyframe is still in view.
pub const DEFAULT_MIN_OVERLAP: f64 = 0.7;

/// Width of the thumbnails overlap is tracked on, pixels.
const THUMB_WIDTH_PX: u32 = 64;

/// The width of image the selector needs at least, pixels: frames are offered as previews this
/// wide or wider ([`crate::bags::Frame::preview`]), not decoded in full.
pub const PREVIEW_WIDTH_PX: u32 = 2 * THUMB_WIDTH_PX;

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
    /// The last frame that still overlapped the last keyframe enough, kept because the next
    /// one does not.
    Overlap,
    /// The last frame of the stream.
    Last,
}

struct Seen<T> {
    frame: T,
    time_ns: u64,
    position_m: Option<[f64; 3]>,
    thumb: Option<Thumb>,
}

/// Chooses keyframes from a stream of frames, each carrying a payload `T` (what the caller
/// writes when a frame is kept). By overlap, the decision waits one frame: when a frame no
/// longer overlaps the last keyframe enough, the frame before it (which still did) is kept, so
/// that consecutive keyframes overlap by at least the threshold wherever the stream allows it.
pub struct KeyframeSelector<T> {
    options: KeyframeOptions,
    last: Option<Seen<()>>,
    pending: Option<Seen<T>>,
}

impl<T> KeyframeSelector<T> {
    pub fn new(options: KeyframeOptions) -> Self {
        Self { options, last: None, pending: None }
    }

    /// Offers the next frame: its payload, its time, the odometry position at that time if
    /// known, and its image (whole, or a preview at least [`PREVIEW_WIDTH_PX`] wide). Returns the frames that became keyframes (none, this one, the one
    /// before it, or both), in stream order.
    pub fn offer(
        &mut self,
        frame: T,
        time_ns: u64,
        position_m: Option<[f64; 3]>,
        image: &DynamicImage,
    ) -> Vec<(T, Reason)> {
        let options = self.options;
        let seen = Seen { frame, time_ns, position_m, thumb: options.min_overlap.map(|_| Thumb::of(image)) };
        let Some(last) = &self.last else { return vec![self.keep(seen, Reason::First)] };
        if options == KeyframeOptions::ALL {
            return vec![self.keep(seen, Reason::Every)];
        }
        let elapsed_s = time_ns.saturating_sub(last.time_ns) as f64 * 1e-9;
        let travelled_m = match (last.position_m, position_m) {
            (Some(a), Some(b)) => Some((0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()),
            _ => None,
        };
        if options.every_s.is_some_and(|every| elapsed_s >= every) {
            self.pending = None;
            return vec![self.keep(seen, Reason::Time)];
        }
        if options.distance_m.zip(travelled_m).is_some_and(|(limit, d)| d >= limit) {
            self.pending = None;
            return vec![self.keep(seen, Reason::Distance)];
        }
        let (Some(min), Some(last_thumb), Some(thumb)) = (options.min_overlap, &last.thumb, &seen.thumb) else {
            self.pending = Some(seen);
            return Vec::new();
        };
        if last_thumb.overlap(thumb) >= min {
            self.pending = Some(seen);
            return Vec::new();
        }
        let mut kept = Vec::new();
        if let Some(previous) = self.pending.take() {
            let still_overlaps = match &previous.thumb {
                Some(previous_thumb) => previous_thumb.overlap(thumb) >= min,
                None => false,
            };
            kept.push(self.keep(previous, Reason::Overlap));
            if still_overlaps {
                self.pending = Some(seen);
                return kept;
            }
        }
        kept.push(self.keep(seen, Reason::Overlap));
        kept
    }

    /// The last frame, if it was not kept: the end of a track is kept too.
    pub fn finish(&mut self) -> Option<(T, Reason)> {
        let last = self.pending.take()?;
        Some(self.keep(last, Reason::Last))
    }

    fn keep(&mut self, seen: Seen<T>, reason: Reason) -> (T, Reason) {
        let Seen { frame, time_ns, position_m, thumb } = seen;
        self.last = Some(Seen { frame: (), time_ns, position_m, thumb });
        (frame, reason)
    }
}

/// What a [`VisitStream`] decided.
#[derive(Debug)]
pub enum VisitEvent<T> {
    /// A visit begins; its keyframes follow.
    Started { visit: String },
    /// A frame was kept: the `index`-th frame of its visit (counting every frame offered).
    Keyframe { visit: String, index: usize, frame: T, reason: Reason },
    /// The visit is over, after `frames` frames.
    Ended { visit: String, frames: usize },
}

/// A camera stream cut into visits and keyframes, sans-IO: the bag ingest and the ingest node
/// drive the same one. A visit starts at the first frame (named `name`, or `name-1`, `name-2`,
/// ... when a gap of more than `split_gap_s` between frames splits the stream), or when told
/// ([`VisitStream::start`], a session-control message); it ends at a split, when told, or at
/// [`VisitStream::end`].
pub struct VisitStream<T> {
    keyframes: KeyframeOptions,
    name: String,
    split_gap_s: Option<f64>,
    splits: usize,
    current: Option<(String, usize)>,
    selector: KeyframeSelector<(usize, T)>,
    position_m: Option<[f64; 3]>,
    last_frame_ns: Option<u64>,
}

impl<T> VisitStream<T> {
    pub fn new(name: &str, split_gap_s: Option<f64>, keyframes: KeyframeOptions) -> Self {
        Self {
            keyframes,
            name: name.to_owned(),
            split_gap_s,
            splits: 0,
            current: None,
            selector: KeyframeSelector::new(keyframes),
            position_m: None,
            last_frame_ns: None,
        }
    }

    /// The vehicle's position now (odometry), for keyframes by distance.
    pub fn position(&mut self, position_m: [f64; 3]) {
        self.position_m = Some(position_m);
    }

    /// Ends the current visit, if any, and starts `visit`.
    pub fn start(&mut self, visit: &str) -> Vec<VisitEvent<T>> {
        let mut events = self.end();
        self.current = Some((visit.to_owned(), 0));
        events.push(VisitEvent::Started { visit: visit.to_owned() });
        events
    }

    /// Ends the current visit: its last frame is kept if it was not.
    pub fn end(&mut self) -> Vec<VisitEvent<T>> {
        let Some((visit, frames)) = self.current.take() else { return Vec::new() };
        let mut events = Vec::new();
        if let Some(((index, frame), reason)) = self.selector.finish() {
            events.push(VisitEvent::Keyframe { visit: visit.clone(), index, frame, reason });
        }
        self.selector = KeyframeSelector::new(self.keyframes);
        self.last_frame_ns = None;
        events.push(VisitEvent::Ended { visit, frames });
        events
    }

    /// The name of the visit frames go to now, if one has started.
    pub fn visit(&self) -> Option<&str> {
        self.current.as_ref().map(|(name, _)| name.as_str())
    }

    /// Offers the next frame, taken at `time_ns`, with its image (whole or a preview).
    pub fn frame(&mut self, frame: T, time_ns: u64, image: &DynamicImage) -> Vec<VisitEvent<T>> {
        let gap = self
            .split_gap_s
            .zip(self.last_frame_ns)
            .is_some_and(|(gap_s, last)| time_ns.saturating_sub(last) as f64 * 1e-9 > gap_s);
        let mut events = Vec::new();
        if self.current.is_none() || gap {
            let visit = match self.split_gap_s {
                Some(_) => {
                    self.splits += 1;
                    format!("{}-{}", self.name, self.splits)
                }
                None => self.name.clone(),
            };
            events = self.start(&visit);
        }
        self.last_frame_ns = Some(time_ns);
        let Some((visit, frames)) = &mut self.current else { return events };
        let index = *frames;
        *frames += 1;
        for ((index, frame), reason) in self.selector.offer((index, frame), time_ns, self.position_m, image) {
            events.push(VisitEvent::Keyframe { visit: visit.clone(), index, frame, reason });
        }
        events
    }
}

/// A small grey copy of a frame, high-passed (each pixel minus its 5x5 neighbourhood's mean) so
/// that smooth shading cannot correlate by chance.
struct Thumb {
    width: usize,
    height: usize,
    pixels: Vec<f32>,
}

impl Thumb {
    fn of(image: &DynamicImage) -> Thumb {
        let height =
            (THUMB_WIDTH_PX as f64 * image.height() as f64 / image.width().max(1) as f64).round().max(8.0) as u32;
        // An area average (what a coarser sensor would see): fast at any size, and the same
        // thumbnail from a full frame as from its preview, up to rounding.
        let grey: GrayImage = image.thumbnail_exact(THUMB_WIDTH_PX, height).into_luma8();
        let (w, h) = (THUMB_WIDTH_PX as usize, height as usize);
        let at = |x: usize, y: usize| f32::from(grey.as_raw()[y * w + x]);
        let mut pixels = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (ys, xs) = (y.saturating_sub(2)..(y + 3).min(h), x.saturating_sub(2)..(x + 3).min(w));
                let count = (ys.len() * xs.len()) as f32;
                let sum: f32 = ys.flat_map(|v| xs.clone().map(move |u| (u, v))).map(|(u, v)| at(u, v)).sum();
                pixels.push(at(x, y) - sum / count);
            }
        }
        Thumb { width: w, height: h, pixels }
    }

    /// The fraction of this thumbnail still seen in `other`: the translation (up to half the
    /// image each way) whose shared area correlates best (normalised cross-correlation) gives
    /// the shared area. When no shift correlates well (a turn, a jump, another scene), 0.
    fn overlap(&self, other: &Thumb) -> f64 {
        if (self.width, self.height) != (other.width, other.height) {
            return 0.0;
        }
        let (w, h) = (self.width as isize, self.height as isize);
        let mut best = (f64::NEG_INFINITY, 0.0);
        for dy in -h / 2..=h / 2 {
            for dx in -w / 2..=w / 2 {
                let (x0, x1) = (dx.max(0), (w + dx).min(w));
                let (y0, y1) = (dy.max(0), (h + dy).min(h));
                let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
                for y in y0..y1 {
                    let a = &self.pixels[(y * w) as usize..][x0 as usize..x1 as usize];
                    let b = &other.pixels[((y - dy) * w) as usize..][(x0 - dx) as usize..(x1 - dx) as usize];
                    for (&p, &q) in a.iter().zip(b) {
                        sa += p;
                        sb += q;
                        saa += p * p;
                        sbb += q * q;
                        sab += p * q;
                    }
                }
                let n = ((x1 - x0) * (y1 - y0)) as f64;
                let (sa, sb, saa, sbb, sab) =
                    (f64::from(sa), f64::from(sb), f64::from(saa), f64::from(sbb), f64::from(sab));
                let variance = (saa - sa * sa / n) * (sbb - sb * sb / n);
                let ncc = if variance > 0.0 { (sab - sa * sb / n) / variance.sqrt() } else { 0.0 };
                if ncc > best.0 {
                    best = (ncc, n / (w * h) as f64);
                }
            }
        }
        if best.0 >= MIN_CORRELATION {
            best.1
        } else {
            0.0
        }
    }
}

/// The correlation below which two frames are taken not to overlap at all.
const MIN_CORRELATION: f64 = 0.6;

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Luma, RgbImage};

    /// Value noise: a hashed value per cell of `cell` pixels, interpolated bilinearly.
    fn noise(u: f32, v: f32, cell: f32) -> f32 {
        let hash = |i: i64, j: i64| {
            // splitmix64's finaliser of the cell's coordinates.
            let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 40) as f32 / 16_777_215.0
        };
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
        let unrelated =
            DynamicImage::ImageRgb8(RgbImage::from_fn(320, 240, |x, y| image::Rgb([((x * y) % 251) as u8; 3])));
        assert!(start.overlap(&Thumb::of(&unrelated)) < 0.3);
    }

    #[test]
    fn a_frame_is_kept_when_overlap_time_or_distance_says_so() {
        let mut selector = KeyframeSelector::new(KeyframeOptions::default());
        let mut kept: Vec<u32> = Vec::new();
        for i in 0..=40u32 {
            let frames = selector.offer(i, u64::from(i) * 33_000_000, None, &view(100 + 8 * i, 100));
            kept.extend(frames.into_iter().map(|(frame, _)| frame));
        }
        kept.extend(selector.finish().map(|(frame, _)| frame));
        // 8 px a frame: the overlap with the last keyframe falls below 0.7 after 96 px, so every
        // 12th frame is kept (the last one still at or above 0.7), and the stream's last frame.
        assert_eq!(kept, vec![0, 12, 24, 36, 40]);

        let options = KeyframeOptions { min_overlap: None, every_s: Some(1.0), distance_m: Some(2.0) };
        let mut selector = KeyframeSelector::new(options);
        let still = view(100, 100);
        let mut reasons = Vec::new();
        for (t_s, x_m) in [(0.0, 0.0), (0.5, 0.5), (0.9, 2.5), (1.5, 2.6), (2.0, 2.7)] {
            reasons.push(selector.offer((), (t_s * 1e9) as u64, Some([x_m, 0.0, 0.0]), &still).first().map(|k| k.1));
        }
        assert_eq!(reasons, vec![Some(Reason::First), None, Some(Reason::Distance), None, Some(Reason::Time)]);

        let mut every = KeyframeSelector::new(KeyframeOptions::ALL);
        assert!((0..5).all(|i| every.offer((), i, None, &still).len() == 1));
    }

    #[test]
    fn a_jump_keeps_the_frames_on_both_sides() {
        // Along a line, then a jump to the next line (no overlap), then along again.
        let mut selector = KeyframeSelector::new(KeyframeOptions::default());
        let mut kept = Vec::new();
        for (i, (x, y)) in
            [(100, 100), (110, 100), (120, 100), (120, 400), (110, 400), (100, 400)].into_iter().enumerate()
        {
            kept.extend(selector.offer(i, i as u64, None, &view(x, y)));
        }
        kept.extend(selector.finish());
        let frames: Vec<usize> = kept.iter().map(|k| k.0).collect();
        assert_eq!(frames, vec![0, 2, 3, 5]);
    }
}
