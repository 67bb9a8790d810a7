//! One image-decoding policy for every stage: the same bytes are accepted or
//! refused the same way whether SIFT, the learned extractor or place
//! recognition reads them, from a file or from memory (a node's message).

use std::path::Path;

use image::{DynamicImage, GrayImage, ImageFormat, Rgb, RgbImage};
use revisit_msgs::sensor_msgs::{CompressedImage, Image};

use crate::PipelineError;

/// File extensions read as images (lower case).
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Whether `path` has an image extension.
pub fn is_image_file(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Decodes PNG or JPEG bytes. A JPEG must end with its end-of-image marker
/// (trailing padding allowed): decoders fill a cut-off file with grey
/// instead of failing. `origin` names the bytes in errors.
pub fn decode(bytes: &[u8], origin: &Path) -> Result<DynamicImage, PipelineError> {
    let bad = |reason: String| PipelineError::BadImage { path: origin.to_path_buf(), reason };
    let format = image::guess_format(bytes).map_err(|e| bad(e.to_string()))?;
    if !matches!(format, ImageFormat::Png | ImageFormat::Jpeg) {
        return Err(bad(format!("{format:?} is not PNG or JPEG")));
    }
    if format == ImageFormat::Jpeg {
        check_jpeg_end(bytes).map_err(bad)?;
    }
    image::load_from_memory_with_format(bytes, format).map_err(|e| bad(e.to_string()))
}

/// A small grey copy of PNG or JPEG bytes, at least `min_width_px` wide where the image is: what
/// a selector looking at every frame of a video needs, at a fraction of a full decode's cost. A
/// JPEG is decoded at the smallest of its DCT scales (1/8, 1/4, 1/2, 1) that keeps the width
/// (the entropy data is still read whole, so a corrupt frame still fails); a PNG is decoded
/// whole. Accepted and refused by [`decode`]'s policy.
pub fn preview(bytes: &[u8], origin: &Path, min_width_px: u32) -> Result<GrayImage, PipelineError> {
    let bad = |reason: String| PipelineError::BadImage { path: origin.to_path_buf(), reason };
    if image::guess_format(bytes).ok() != Some(ImageFormat::Jpeg) {
        return Ok(decode(bytes, origin)?.into_luma8());
    }
    check_jpeg_end(bytes).map_err(bad)?;
    let mut decoder = jpeg_decoder::Decoder::new(bytes);
    decoder.read_info().map_err(|e| bad(e.to_string()))?;
    let info = decoder.info().ok_or_else(|| bad("no JPEG header".to_owned()))?;
    let height_px = (u32::from(info.height) * min_width_px).div_ceil(u32::from(info.width).max(1));
    let (width, height) = decoder
        .scale(min_width_px.min(u32::from(u16::MAX)) as u16, height_px.min(u32::from(u16::MAX)) as u16)
        .map_err(|e| bad(e.to_string()))?;
    let pixels = decoder.decode().map_err(|e| bad(e.to_string()))?;
    let (width, height) = (u32::from(width), u32::from(height));
    let grey = match info.pixel_format {
        jpeg_decoder::PixelFormat::L8 => pixels,
        jpeg_decoder::PixelFormat::L16 => pixels.chunks_exact(2).map(|p| p[0]).collect(),
        jpeg_decoder::PixelFormat::RGB24 => {
            let rgb = RgbImage::from_raw(width, height, pixels).ok_or_else(|| bad("short JPEG data".to_owned()))?;
            return Ok(DynamicImage::ImageRgb8(rgb).into_luma8());
        }
        jpeg_decoder::PixelFormat::CMYK32 => return Ok(decode(bytes, origin)?.into_luma8()),
    };
    GrayImage::from_raw(width, height, grey).ok_or_else(|| bad("short JPEG data".to_owned()))
}

/// A JPEG must end with its end-of-image marker (trailing padding allowed).
fn check_jpeg_end(bytes: &[u8]) -> Result<(), String> {
    let end = bytes.iter().rposition(|&b| b != 0 && b != b'\n' && b != b'\r').unwrap_or(0);
    if end < 1 || bytes.get(end - 1..=end) != Some(&[0xFF, 0xD9][..]) {
        return Err("truncated JPEG (no end-of-image marker)".to_owned());
    }
    Ok(())
}

/// Reads and decodes an image file by [`decode`]'s policy.
pub fn read(path: &Path) -> Result<DynamicImage, PipelineError> {
    let bytes = std::fs::read(path).map_err(|source| PipelineError::Io { path: path.to_path_buf(), source })?;
    decode(&bytes, path)
}

/// The image in grey, downscaled so its larger side is at most
/// `max_size_px`, with the factor back to full resolution.
pub fn grey_at_most(image: &DynamicImage, max_size_px: u32) -> (GrayImage, f32) {
    let grey = image.to_luma8();
    let longest = grey.width().max(grey.height());
    if longest <= max_size_px {
        return (grey, 1.0);
    }
    let factor = longest as f32 / max_size_px as f32;
    let width = ((grey.width() as f32 / factor).round() as u32).max(1);
    let height = ((grey.height() as f32 / factor).round() as u32).max(1);
    let small = image::imageops::resize(&grey, width, height, image::imageops::FilterType::Triangle);
    (small, grey.width() as f32 / width as f32)
}

/// The EXIF focal length of a JPEG in pixels, for an image `width_px` x
/// `height_px`: from the 35 mm equivalent (`FocalLengthIn35mmFilm`, 36 mm
/// across the larger side), else from `FocalLength` and the focal plane
/// resolution. `None` when the file carries neither, as COLMAP falls back
/// to its default guess.
pub fn exif_focal_px(bytes: &[u8], width_px: u32, height_px: u32) -> Option<f64> {
    let exif = exif::Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)).ok()?;
    let rational = |tag: exif::Tag| -> Option<f64> {
        let field = exif.get_field(tag, exif::In::PRIMARY)?;
        match &field.value {
            exif::Value::Rational(v) => v.first().map(|r| r.to_f64()),
            exif::Value::Short(v) => v.first().map(|&s| f64::from(s)),
            exif::Value::Long(v) => v.first().map(|&s| f64::from(s)),
            _ => None,
        }
    };
    let longest = f64::from(width_px.max(height_px));
    let focal = rational(exif::Tag::FocalLengthIn35mmFilm)
        .filter(|f| *f > 0.0)
        .map(|f35| f35 / 36.0 * longest)
        .or_else(|| {
            let focal_mm = rational(exif::Tag::FocalLength)?;
            let per_unit = rational(exif::Tag::FocalPlaneXResolution)?;
            // ResolutionUnit 2: inches, 3: centimetres (EXIF's default is inches).
            let unit_mm = match exif.get_field(exif::Tag::FocalPlaneResolutionUnit, exif::In::PRIMARY) {
                Some(f) if f.value.get_uint(0) == Some(3) => 10.0,
                _ => 25.4,
            };
            Some(focal_mm * per_unit / unit_mm)
        })?;
    (focal.is_finite() && focal > 0.0).then_some(focal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jpeg() -> Vec<u8> {
        let mut bytes = Vec::new();
        DynamicImage::ImageRgb8(image::RgbImage::new(32, 24))
            .write_to(&mut std::io::Cursor::new(&mut bytes), ImageFormat::Jpeg)
            .unwrap();
        bytes
    }

    #[test]
    fn a_truncated_jpeg_is_refused_from_memory_and_from_a_file() {
        let bytes = jpeg();
        assert!(decode(&bytes, Path::new("a.jpg")).is_ok());
        let cut = &bytes[..bytes.len() / 2];
        let err = decode(cut, Path::new("cut.jpg")).unwrap_err().to_string();
        assert!(err.contains("cut.jpg") && err.contains("truncated JPEG"), "{err}");
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("cut.jpg"), cut).unwrap();
        assert!(read(&dir.path().join("cut.jpg")).is_err());
        assert!(decode(b"GIF89a....", Path::new("x.gif")).is_err());
    }

    #[test]
    fn a_jpeg_preview_is_a_reduced_decode_of_the_same_picture() {
        // Left half dark, right half bright, 640x480.
        let picture = image::RgbImage::from_fn(640, 480, |x, _| image::Rgb([if x < 320 { 30 } else { 220 }; 3]));
        let mut bytes = Vec::new();
        DynamicImage::ImageRgb8(picture).write_to(&mut std::io::Cursor::new(&mut bytes), ImageFormat::Jpeg).unwrap();
        let small = preview(&bytes, Path::new("a.jpg"), 128).unwrap();
        // The smallest DCT scale at least 128 wide: 1/4.
        assert_eq!((small.width(), small.height()), (160, 120));
        let (left, right) = (small.get_pixel(20, 60).0[0], small.get_pixel(140, 60).0[0]);
        assert!(left.abs_diff(30) < 8 && right.abs_diff(220) < 8, "{left} {right}");
        let err = preview(&bytes[..bytes.len() / 2], Path::new("cut.jpg"), 128).unwrap_err().to_string();
        assert!(err.contains("cut.jpg") && err.contains("truncated JPEG"), "{err}");
    }

    #[test]
    fn grey_images_are_downscaled_with_their_factor() {
        let image = DynamicImage::ImageRgb8(image::RgbImage::new(800, 600));
        let (small, factor) = grey_at_most(&image, 400);
        assert_eq!((small.width(), small.height()), (400, 300));
        assert_eq!(factor, 2.0);
        assert_eq!(grey_at_most(&image, 3200).1, 1.0);
    }

    #[test]
    fn no_exif_means_no_focal_length() {
        assert_eq!(exif_focal_px(&jpeg(), 32, 24), None);
    }
}

/// Decodes a `sensor_msgs/Image`: `rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8`, `mono16`, and
/// `bayer_{rggb,bggr,gbrg,grbg}{8,16}` (debayered to RGB by averaging each colour's samples in
/// the 3x3 neighbourhood). The data must be exactly `height` rows of `step` bytes. `origin` names
/// the message in errors (bag, topic, time).
pub fn from_raw(message: &Image, origin: &Path) -> Result<DynamicImage, PipelineError> {
    let bad = |reason: String| PipelineError::BadImage { path: origin.to_path_buf(), reason };
    let (width, height, step) = (message.width, message.height, message.step as usize);
    let encoding = message.encoding.as_str();
    let (channels, bytes_per_sample) = match encoding {
        "mono8" => (1, 1),
        "mono16" => (1, 2),
        "rgb8" | "bgr8" => (3, 1),
        "rgba8" | "bgra8" => (4, 1),
        e if e.starts_with("bayer_") && e.ends_with('8') => (1, 1),
        e if e.starts_with("bayer_") && e.ends_with("16") => (1, 2),
        other => {
            return Err(bad(format!(
                "encoding {other:?} is not one of rgb8, bgr8, rgba8, bgra8, mono8, mono16, bayer_*8, bayer_*16"
            )))
        }
    };
    let row_bytes = width as usize * channels * bytes_per_sample;
    if width == 0 || height == 0 || step < row_bytes {
        return Err(bad(format!("{width}x{height} {encoding} needs a step of at least {row_bytes}, not {step}")));
    }
    if (message.data.len() as u64) != step as u64 * u64::from(height) {
        return Err(bad(format!(
            "{} bytes of data, but {height} rows of step {step} are {}",
            message.data.len(),
            step as u64 * u64::from(height)
        )));
    }
    // Each row without its padding; the pixel layouts below copy row by row.
    let rows = || message.data.chunks_exact(step).map(|row| &row[..row_bytes]);
    let sixteen = |bytes: &[u8]| {
        let pair = [bytes[0], bytes[1]];
        if message.is_bigendian != 0 {
            u16::from_be_bytes(pair)
        } else {
            u16::from_le_bytes(pair)
        }
    };
    let too_big = || bad(format!("{width}x{height} does not fit in memory"));
    let packed = || {
        let mut bytes = Vec::with_capacity(row_bytes * height as usize);
        rows().for_each(|row| bytes.extend_from_slice(row));
        bytes
    };
    let image = match encoding {
        "mono8" => DynamicImage::ImageLuma8(GrayImage::from_raw(width, height, packed()).ok_or_else(too_big)?),
        "rgb8" => DynamicImage::ImageRgb8(RgbImage::from_raw(width, height, packed()).ok_or_else(too_big)?),
        "mono16" => {
            let pixels = rows().flat_map(|row| row.chunks_exact(2).map(sixteen)).collect();
            DynamicImage::ImageLuma16(image::ImageBuffer::from_raw(width, height, pixels).ok_or_else(too_big)?)
        }
        "rgba8" | "bgr8" | "bgra8" => {
            let order = if encoding == "rgba8" { [0, 1, 2] } else { [2, 1, 0] };
            let pixels =
                rows().flat_map(|row| row.chunks_exact(channels).flat_map(move |p| order.map(|c| p[c]))).collect();
            DynamicImage::ImageRgb8(RgbImage::from_raw(width, height, pixels).ok_or_else(too_big)?)
        }
        bayer => {
            let pattern = bayer_pattern(bayer).ok_or_else(|| bad(format!("unknown Bayer pattern in {bayer:?}")))?;
            let sample = |x: u32, y: u32| {
                let at = y as usize * step + x as usize * bytes_per_sample;
                match bytes_per_sample {
                    1 => message.data[at],
                    _ => (sixteen(&message.data[at..]) >> 8) as u8,
                }
            };
            DynamicImage::ImageRgb8(debayer(width, height, pattern, sample))
        }
    };
    Ok(image)
}

/// Decodes a `sensor_msgs/CompressedImage` (`jpeg` or `png`) by [`decode`]'s policy.
pub fn from_compressed(message: &CompressedImage, origin: &Path) -> Result<DynamicImage, PipelineError> {
    decode(&message.data, origin)
}

/// The colour (0 red, 1 green, 2 blue) at (x % 2, y % 2) as `pattern[y % 2 * 2 + x % 2]`.
fn bayer_pattern(encoding: &str) -> Option<[usize; 4]> {
    let name = encoding.strip_prefix("bayer_")?.trim_end_matches(|c: char| c.is_ascii_digit());
    let colour = |c: u8| match c {
        b'r' => Some(0),
        b'g' => Some(1),
        b'b' => Some(2),
        _ => None,
    };
    let [a, b, c, d] = name.as_bytes() else { return None };
    Some([colour(*a)?, colour(*b)?, colour(*c)?, colour(*d)?])
}

/// Bilinear-style demosaicing: each colour is the mean of that colour's samples in the 3x3
/// neighbourhood (the pixel's own sample for its own colour).
fn debayer(width: u32, height: u32, pattern: [usize; 4], sample: impl Fn(u32, u32) -> u8) -> RgbImage {
    let colour_at = |x: u32, y: u32| pattern[(y % 2 * 2 + x % 2) as usize];
    RgbImage::from_fn(width, height, |x, y| {
        let own = colour_at(x, y);
        let mut sums = [0u32; 3];
        let mut counts = [0u32; 3];
        for ny in y.saturating_sub(1)..=(y + 1).min(height - 1) {
            for nx in x.saturating_sub(1)..=(x + 1).min(width - 1) {
                let colour = colour_at(nx, ny);
                if colour == own && (nx, ny) != (x, y) {
                    continue;
                }
                sums[colour] += u32::from(sample(nx, ny));
                counts[colour] += 1;
            }
        }
        Rgb([0, 1, 2].map(|c| sums[c].checked_div(counts[c]).unwrap_or(0).min(255) as u8))
    })
}

#[cfg(test)]
mod message_tests {
    use super::*;

    fn raw(width: u32, height: u32, encoding: &str, step: u32, data: Vec<u8>) -> Image {
        Image { width, height, encoding: encoding.into(), step, data, ..Image::default() }
    }

    fn origin() -> &'static Path {
        Path::new("bag:/camera/image_raw@1")
    }

    #[test]
    fn bgr8_swaps_to_rgb_and_honours_row_padding() -> Result<(), PipelineError> {
        // Two pixels a row, rows padded to 8 bytes.
        let data = vec![1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0];
        let image = from_raw(&raw(2, 2, "bgr8", 8, data), origin())?.to_rgb8();
        assert_eq!(image.get_pixel(0, 0).0, [3, 2, 1]);
        assert_eq!(image.get_pixel(1, 1).0, [12, 11, 10]);
        Ok(())
    }

    #[test]
    fn mono16_reads_either_byte_order() -> Result<(), PipelineError> {
        let mut message = raw(1, 1, "mono16", 2, vec![0x12, 0x34]);
        assert_eq!(from_raw(&message, origin())?.to_luma16().get_pixel(0, 0).0, [0x3412]);
        message.is_bigendian = 1;
        assert_eq!(from_raw(&message, origin())?.to_luma16().get_pixel(0, 0).0, [0x1234]);
        Ok(())
    }

    #[test]
    fn bayer_of_one_colour_debayers_to_that_colour() -> Result<(), PipelineError> {
        // An orange scene (200, 100, 50) seen through an RGGB mosaic.
        let (r, g, b) = (200, 100, 50);
        let data = (0..4 * 4)
            .map(|i| match (i % 4 % 2, i / 4 % 2) {
                (0, 0) => r,
                (1, 1) => b,
                _ => g,
            })
            .collect();
        let image = from_raw(&raw(4, 4, "bayer_rggb8", 4, data), origin())?.to_rgb8();
        assert!(image.pixels().all(|p| p.0 == [r, g, b]), "{:?}", image.pixels().collect::<Vec<_>>());
        Ok(())
    }

    #[test]
    fn a_wrong_data_length_or_encoding_is_one_error_naming_the_message() {
        let short = from_raw(&raw(2, 2, "mono8", 2, vec![0; 3]), origin()).map(|_| ());
        let message = short.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(message.contains("bag:/camera/image_raw@1") && message.contains("3 bytes"), "{message}");
        let yuv = from_raw(&raw(2, 2, "yuv422", 4, vec![0; 8]), origin()).map(|_| ());
        let message = yuv.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(message.contains("\"yuv422\""), "{message}");
        let huge = from_raw(&raw(u32::MAX, u32::MAX, "rgb8", u32::MAX, vec![0; 8]), origin()).map(|_| ());
        assert!(huge.is_err());
    }
}
