//! What the learned extractors see of each image, so that visits under other
//! light, water and colour look alike to the network.
//!
//! [`stretch`]: each colour channel mapped linearly from its 1st to its 99th
//! percentile (takes out a visit's colour cast, haze and light level).
//! [`equalize`]: stretched, then CLAHE (OpenCV's contrast-limited
//! adaptive histogram equalization, clip 2, 8 x 8 tiles, as
//! `kornia_imgproc::clahe` computes it) on the luminance, applied to the three
//! channels as one gain per pixel (the hues stay): more matches than the
//! stretch, but more wrong ones too (README). Both are local to one image.

use image::RgbImage;
use kornia_image::{Image, ImageSize};
use serde::{Deserialize, Serialize};

/// Which image the learned extractor is given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LearnedInput {
    /// The image as it is.
    Raw,
    /// Each channel stretched between its percentiles ([`stretch`]): the
    /// default.
    #[default]
    Stretched,
    /// Stretched, then CLAHE on the luminance ([`equalize`]).
    Equalized,
}

impl LearnedInput {
    /// `image` as the extractor is to see it (`None`: as it is).
    pub fn prepare(self, image: &RgbImage) -> Option<RgbImage> {
        match self {
            LearnedInput::Raw => None,
            LearnedInput::Stretched => Some(stretch(image)),
            LearnedInput::Equalized => Some(equalize(image)),
        }
    }
}

/// Share of pixels each channel's stretch leaves dark (and bright).
const STRETCH_TAIL: f64 = 0.01;
/// CLAHE's clip limit and tile grid (OpenCV's usual values).
const CLAHE_CLIP: f64 = 2.0;
const CLAHE_GRID: (usize, usize) = (8, 8);

/// `image` with each channel mapped linearly so that its `STRETCH_TAIL`
/// and 1 - `STRETCH_TAIL` quantiles become 0 and 255. Deterministic.
pub fn stretch(image: &RgbImage) -> RgbImage {
    let mut stretched = image.clone();
    for channel in 0..3 {
        stretch_channel(&mut stretched, channel);
    }
    stretched
}

/// [`stretch`]ed `image` with CLAHE's gain on the luminance applied to every
/// channel. Deterministic.
pub fn equalize(image: &RgbImage) -> RgbImage {
    let (width, height) = image.dimensions();
    let mut pixels = stretch(image).into_raw();
    // ITU-R BT.601 luma, in 0..=255.
    let luma: Vec<u8> = pixels
        .chunks_exact(3)
        .map(|p| (0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2])).round() as u8)
        .collect();
    if let Some(equalized) = clahe(&luma, width as usize, height as usize) {
        for ((p, &before), &after) in pixels.chunks_exact_mut(3).zip(&luma).zip(&equalized) {
            let gain = (f32::from(after) + 1.0) / (f32::from(before) + 1.0);
            p.iter_mut().for_each(|v| *v = (f32::from(*v) * gain).round().clamp(0.0, 255.0) as u8);
        }
    }
    RgbImage::from_raw(width, height, pixels).unwrap_or_else(|| image.clone())
}

/// [`stretch`] of one channel.
fn stretch_channel(image: &mut RgbImage, channel: usize) {
    let pixels: &mut [u8] = image;
    let mut histogram = [0usize; 256];
    pixels.iter().skip(channel).step_by(3).for_each(|&v| histogram[usize::from(v)] += 1);
    let count = pixels.len() / 3;
    let quantile = |share: f64| -> u8 {
        let wanted = (share * count as f64).ceil().max(1.0) as usize;
        let mut seen = 0;
        for (value, n) in histogram.iter().enumerate() {
            seen += n;
            if seen >= wanted {
                return value as u8;
            }
        }
        u8::MAX
    };
    let (low, high) = (f32::from(quantile(STRETCH_TAIL)), f32::from(quantile(1.0 - STRETCH_TAIL)));
    let scale = 255.0 / (high - low).max(1.0);
    for v in pixels.iter_mut().skip(channel).step_by(3) {
        *v = ((f32::from(*v) - low) * scale).round().clamp(0.0, 255.0) as u8;
    }
}

/// CLAHE of a one-channel image; `None` for an image it cannot tile.
fn clahe(luma: &[u8], width: usize, height: usize) -> Option<Vec<u8>> {
    let size = ImageSize { width, height };
    let source = Image::<u8, 1>::new(size, luma.to_vec()).ok()?;
    let mut equalized = Image::<u8, 1>::new(size, vec![0; luma.len()]).ok()?;
    kornia_imgproc::clahe::clahe(&source, &mut equalized, CLAHE_CLIP, CLAHE_GRID).ok()?;
    Some(equalized.as_slice().to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dim, hazy, green-cast version of a textured image.
    fn scene(level: f32, cast: [f32; 3], haze: f32) -> RgbImage {
        RgbImage::from_fn(64, 48, |x, y| {
            let texture = ((x * 7 + y * 13) % 17) as f32 / 16.0 * if x < 32 { 0.3 } else { 1.0 };
            image::Rgb(cast.map(|c| ((texture * level * c + haze) * 255.0).clamp(0.0, 255.0) as u8))
        })
    }

    fn mean_abs_difference(a: &RgbImage, b: &RgbImage) -> f64 {
        let sum: f64 = a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| f64::from(x.abs_diff(*y))).sum();
        sum / a.as_raw().len() as f64
    }

    #[test]
    fn two_looks_of_one_scene_come_out_alike() {
        let clear = scene(0.9, [1.0, 1.0, 1.0], 0.0);
        let murky = scene(0.5, [0.6, 1.0, 0.8], 0.25);
        let before = mean_abs_difference(&clear, &murky);
        for input in [LearnedInput::Stretched, LearnedInput::Equalized] {
            let prepare = |image: &RgbImage| input.prepare(image).unwrap_or_else(|| image.clone());
            let after = mean_abs_difference(&prepare(&clear), &prepare(&murky));
            assert!(after < before / 4.0, "{input:?}: {after:.1} apart, raw {before:.1}");
        }
        assert_eq!(LearnedInput::Raw.prepare(&clear), None);
    }

    #[test]
    fn a_flat_image_stays_flat_and_the_size_is_kept() {
        let flat = RgbImage::from_pixel(40, 30, image::Rgb([90, 120, 100]));
        for prepared in [stretch(&flat), equalize(&flat)] {
            assert_eq!(prepared.dimensions(), (40, 30));
            let first = *prepared.get_pixel(0, 0);
            assert!(prepared.pixels().all(|p| *p == first));
        }
    }
}
