//! Image preparation for the learned models: planar float images, bilinear
//! resizing as PyTorch's `interpolate(..., mode="bilinear",
//! align_corners=False)` does it (half-pixel centres, no antialiasing: what
//! XFeat's code does), fitting into a fixed frame, and rolls. ALIKED's
//! reference resizes with antialiasing (PIL's bilinear), which the `image`
//! crate's triangle filter reproduces.

use image::RgbImage;
use revisit_core::Roll;

/// A planar float image: `channels` planes of `height` rows of `width` values.
#[derive(Clone, Debug, PartialEq)]
pub struct Planar {
    pub data: Vec<f32>,
    pub channels: usize,
    pub width: usize,
    pub height: usize,
}

impl Planar {
    /// RGB in [0, 1], after rolling the image by `roll`.
    pub fn rgb(image: &RgbImage, roll: Roll) -> Planar {
        let rolled = rolled(image, roll);
        let (width, height) = (rolled.width() as usize, rolled.height() as usize);
        let mut data = vec![0.0; 3 * width * height];
        for (x, y, pixel) in rolled.enumerate_pixels() {
            for c in 0..3 {
                data[(c * height + y as usize) * width + x as usize] = f32::from(pixel[c]) / 255.0;
            }
        }
        Planar { data, channels: 3, width, height }
    }

    /// Grey in [0, 1] as the mean of R, G and B (XFeat's own conversion), after rolling.
    pub fn grey_mean(image: &RgbImage, roll: Roll) -> Planar {
        let rgb = Planar::rgb(image, roll);
        let plane = rgb.width * rgb.height;
        let data = (0..plane).map(|i| (rgb.data[i] + rgb.data[plane + i] + rgb.data[2 * plane + i]) / 3.0).collect();
        Planar { data, channels: 1, width: rgb.width, height: rgb.height }
    }

    /// Bilinear resize to `width` x `height` (half-pixel centres, no antialiasing).
    pub fn resized(&self, width: usize, height: usize) -> Planar {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        let taps = |out: usize, input: usize| -> Vec<(usize, usize, f32)> {
            let scale = input as f32 / out as f32;
            (0..out)
                .map(|i| {
                    let source = ((i as f32 + 0.5) * scale - 0.5).max(0.0);
                    let low = (source as usize).min(input - 1);
                    let high = (low + 1).min(input - 1);
                    (low, high, source - low as f32)
                })
                .collect()
        };
        let columns = taps(width, self.width);
        let rows = taps(height, self.height);
        let mut data = vec![0.0; self.channels * width * height];
        for c in 0..self.channels {
            let plane = &self.data[c * self.width * self.height..(c + 1) * self.width * self.height];
            for (y, &(y0, y1, ty)) in rows.iter().enumerate() {
                for (x, &(x0, x1, tx)) in columns.iter().enumerate() {
                    let at = |yy: usize, xx: usize| plane[yy * self.width + xx];
                    let top = at(y0, x0) * (1.0 - tx) + at(y0, x1) * tx;
                    let bottom = at(y1, x0) * (1.0 - tx) + at(y1, x1) * tx;
                    data[(c * height + y) * width + x] = top * (1.0 - ty) + bottom * ty;
                }
            }
        }
        Planar { data, channels: self.channels, width, height }
    }

    /// This image on a black `width` x `height` canvas, at its top-left corner.
    pub fn padded(&self, width: usize, height: usize) -> Planar {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        let (w, h) = (self.width.min(width), self.height.min(height));
        let mut data = vec![0.0; self.channels * width * height];
        for c in 0..self.channels {
            for y in 0..h {
                let from = (c * self.height + y) * self.width;
                let to = (c * height + y) * width;
                data[to..to + w].copy_from_slice(&self.data[from..from + w]);
            }
        }
        Planar { data, channels: self.channels, width, height }
    }
}

/// The largest size with the aspect ratio of `width` x `height` that fits in `frame`.
pub fn fit_size(width: u32, height: u32, [frame_w, frame_h]: [u32; 2]) -> [u32; 2] {
    let scale = (frame_w as f32 / width as f32).min(frame_h as f32 / height as f32);
    [
        ((width as f32 * scale).round() as u32).clamp(1, frame_w),
        ((height as f32 * scale).round() as u32).clamp(1, frame_h),
    ]
}

/// `image` rotated clockwise by `roll`.
pub fn rolled(image: &RgbImage, roll: Roll) -> RgbImage {
    match roll {
        Roll::R0 => image.clone(),
        Roll::R90 => image::imageops::rotate90(image),
        Roll::R180 => image::imageops::rotate180(image),
        Roll::R270 => image::imageops::rotate270(image),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_averages_pixel_pairs_like_pytorch() {
        let image = Planar { data: vec![0.0, 1.0, 2.0, 3.0], channels: 1, width: 4, height: 1 };
        let half = image.resized(2, 1);
        assert_eq!(half.data, vec![0.5, 2.5]);
    }

    #[test]
    fn rolled_pixels_land_where_roll_point_says() {
        let mut image = RgbImage::new(5, 3);
        image.put_pixel(1, 0, image::Rgb([255, 0, 0]));
        for roll in Roll::ALL {
            let rolled = rolled(&image, roll);
            let [x, y] = roll.roll_point([1.5, 0.5], 5, 3);
            assert_eq!(rolled.get_pixel(x as u32, y as u32)[0], 255, "{roll:?}");
        }
    }
}
