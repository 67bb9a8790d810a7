//! One image-decoding policy for every stage: the same bytes are accepted or
//! refused the same way whether SIFT, the learned extractor or place
//! recognition reads them, from a file or from memory (a node's message).

use std::path::Path;

use image::{DynamicImage, GrayImage, ImageFormat};

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
        let end = bytes.iter().rposition(|&b| b != 0 && b != b'\n' && b != b'\r').unwrap_or(0);
        if end < 1 || bytes.get(end - 1..=end) != Some(&[0xFF, 0xD9][..]) {
            return Err(bad("truncated JPEG (no end-of-image marker)".to_owned()));
        }
    }
    image::load_from_memory_with_format(bytes, format).map_err(|e| bad(e.to_string()))
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
