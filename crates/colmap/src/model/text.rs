//! COLMAP's text model files: `#` comments, then one line per camera and
//! point, two lines per image (pose and name, then the 2D points).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::str::FromStr;

use nalgebra::{Point2, Point3};
use revisit_core::{Camera, CameraId, CameraModel, Image, ImageId, Observation, Point3D, Point3DId, TrackElement};

use super::{check_image_name, pose_from_stored, ColmapError};

const CAMERAS_TXT: &str = "cameras.txt";
const IMAGES_TXT: &str = "images.txt";
const POINTS3D_TXT: &str = "points3D.txt";

/// A number as Rust's shortest round-trip form (parses back to the same
/// `f64`), plain for ordinary magnitudes and with an exponent for tiny or huge
/// ones (as C++ streams do). COLMAP itself prints 17 significant digits.
fn fmt_f64(value: f64) -> String {
    let magnitude = value.abs();
    if value == 0.0 || !value.is_finite() || (1e-5..1e16).contains(&magnitude) {
        format!("{value}")
    } else {
        format!("{value:e}")
    }
}

/// A mean in the header comments, as a C++ stream prints it (6 significant digits).
fn fmt_mean(value: f64) -> String {
    if value == 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    let exponent = value.abs().log10().floor() as i32;
    let decimals = usize::try_from(5 - exponent).unwrap_or(0);
    let fixed = format!("{value:.decimals$}");
    if fixed.contains('.') {
        fixed.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        fixed
    }
}

/// The data lines of a text file, with 1-based line numbers: comments and
/// blank lines skipped, surrounding whitespace trimmed.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, line)| (i + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'))
}

/// Parses whitespace-separated fields of one line, naming the line on error.
struct Fields<'a> {
    tokens: std::str::SplitAsciiWhitespace<'a>,
    file: &'static str,
    line: usize,
}

impl<'a> Fields<'a> {
    fn new(line_text: &'a str, file: &'static str, line: usize) -> Self {
        Self { tokens: line_text.split_ascii_whitespace(), file, line }
    }

    fn bad(&self, reason: impl Into<String>) -> ColmapError {
        ColmapError::BadLine { file: self.file.to_owned(), line: self.line, reason: reason.into() }
    }

    fn next_token(&mut self, what: &str) -> Result<&'a str, ColmapError> {
        self.tokens.next().ok_or_else(|| self.bad(format!("missing {what}")))
    }

    fn parse<T: FromStr>(&mut self, what: &str) -> Result<T, ColmapError> {
        let token = self.next_token(what)?;
        token.parse().map_err(|_| self.bad(format!("{what} {token:?} is not a valid number")))
    }

    fn rest(&mut self) -> Vec<&'a str> {
        self.tokens.by_ref().collect()
    }
}

/// Decodes `cameras.txt`.
pub fn decode_cameras_txt(text: &str) -> Result<BTreeMap<CameraId, Camera>, ColmapError> {
    let mut cameras = BTreeMap::new();
    for (line, line_text) in data_lines(text) {
        let mut f = Fields::new(line_text, CAMERAS_TXT, line);
        let camera_id: CameraId = f.parse("CAMERA_ID")?;
        let model_name = f.next_token("MODEL")?;
        let model = CameraModel::from_name(model_name).map_err(|e| f.bad(e.to_string()))?;
        let width: u32 = f.parse("WIDTH")?;
        let height: u32 = f.parse("HEIGHT")?;
        let params = f
            .rest()
            .into_iter()
            .map(|token| token.parse::<f64>().map_err(|_| f.bad(format!("parameter {token:?} is not a number"))))
            .collect::<Result<Vec<_>, _>>()?;
        let camera = Camera::new(camera_id, model, width, height, params).map_err(|e| f.bad(e.to_string()))?;
        if cameras.insert(camera_id, camera).is_some() {
            return Err(f.bad(format!("duplicate camera id {camera_id}")));
        }
    }
    Ok(cameras)
}

/// Encodes `cameras.txt` with COLMAP's header.
pub fn encode_cameras_txt(cameras: &BTreeMap<CameraId, Camera>) -> String {
    let mut out = String::new();
    out.push_str("# Camera list with one line of data per camera:\n");
    out.push_str("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    let _ = writeln!(out, "# Number of cameras: {}", cameras.len());
    for camera in cameras.values() {
        let _ = write!(out, "{} {} {} {}", camera.camera_id, camera.model.name(), camera.width, camera.height);
        for param in &camera.params {
            let _ = write!(out, " {}", fmt_f64(*param));
        }
        out.push('\n');
    }
    out
}

/// Decodes `images.txt`. The line after each image line holds its 2D points
/// (it may be empty); a point id of -1 means "not triangulated".
pub fn decode_images_txt(text: &str) -> Result<BTreeMap<ImageId, Image>, ColmapError> {
    let mut images = BTreeMap::new();
    let mut lines = text.lines().enumerate().map(|(i, line)| (i + 1, line.trim()));
    while let Some((line, line_text)) = lines.next() {
        if line_text.is_empty() || line_text.starts_with('#') {
            continue;
        }
        let mut f = Fields::new(line_text, IMAGES_TXT, line);
        let image_id: ImageId = f.parse("IMAGE_ID")?;
        let q_wxyz = [f.parse("QW")?, f.parse("QX")?, f.parse("QY")?, f.parse("QZ")?];
        let t = [f.parse("TX")?, f.parse("TY")?, f.parse("TZ")?];
        let camera_id: CameraId = f.parse("CAMERA_ID")?;
        // The name is the rest of the line (COLMAP stops at the first space;
        // taking the rest also reads names that hold spaces).
        let name = f.rest().join(" ");
        if name.is_empty() {
            return Err(f.bad("missing NAME"));
        }
        let Some((points_line, points_text)) = lines.next() else {
            return Err(f.bad(format!("image {image_id}: missing the POINTS2D line that follows")));
        };
        let mut p = Fields::new(points_text, IMAGES_TXT, points_line);
        let tokens = p.rest();
        if !tokens.len().is_multiple_of(3) {
            return Err(p.bad(format!(
                "POINTS2D of image {image_id}: {} values, not triples (X, Y, POINT3D_ID)",
                tokens.len()
            )));
        }
        let mut points2d = Vec::with_capacity(tokens.len() / 3);
        for triple in tokens.chunks_exact(3) {
            let &[x, y, id] = triple else { continue };
            let parse_f64 = |token: &str| {
                token
                    .parse::<f64>()
                    .map_err(|_| p.bad(format!("POINTS2D of image {image_id}: {token:?} is not a number")))
            };
            let point3d_id = match id {
                "-1" => None,
                _ => match id.parse::<u64>() {
                    Ok(u64::MAX) => None,
                    Ok(id) => Some(id),
                    Err(_) => return Err(p.bad(format!("POINTS2D of image {image_id}: bad POINT3D_ID {id:?}"))),
                },
            };
            points2d.push(Observation { xy: Point2::new(parse_f64(x)?, parse_f64(y)?), point3d_id });
        }
        let image = Image { image_id, camera_id, name, cam_from_world: pose_from_stored(q_wxyz, t), points2d };
        if images.insert(image_id, image).is_some() {
            return Err(f.bad(format!("duplicate image id {image_id}")));
        }
    }
    Ok(images)
}

/// Encodes `images.txt` with COLMAP's header. Fails on an image name the text
/// form cannot hold.
pub fn encode_images_txt(images: &BTreeMap<ImageId, Image>) -> Result<String, ColmapError> {
    let observations: usize =
        images.values().map(|image| image.points2d.iter().filter(|o| o.point3d_id.is_some()).count()).sum();
    let mean = if images.is_empty() { 0.0 } else { observations as f64 / images.len() as f64 };
    let mut out = String::new();
    out.push_str("# Image list with two lines of data per image:\n");
    out.push_str("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n");
    out.push_str("#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
    let _ = writeln!(out, "# Number of images: {}, mean observations per image: {}", images.len(), fmt_mean(mean));
    for image in images.values() {
        check_image_name(IMAGES_TXT, image.image_id, &image.name, true)?;
        let _ = write!(out, "{}", image.image_id);
        for value in image.cam_from_world.wxyz().into_iter().chain(image.cam_from_world.translation.iter().copied()) {
            let _ = write!(out, " {}", fmt_f64(value));
        }
        let _ = writeln!(out, " {} {}", image.camera_id, image.name);
        let mut first = true;
        for observation in &image.points2d {
            if !first {
                out.push(' ');
            }
            first = false;
            let _ = write!(out, "{} {} ", fmt_f64(observation.xy.x), fmt_f64(observation.xy.y));
            match observation.point3d_id {
                Some(id) => {
                    let _ = write!(out, "{id}");
                }
                None => out.push_str("-1"),
            }
        }
        out.push('\n');
    }
    Ok(out)
}

/// Decodes `points3D.txt`.
pub fn decode_points3d_txt(text: &str) -> Result<BTreeMap<Point3DId, Point3D>, ColmapError> {
    let mut points = BTreeMap::new();
    for (line, line_text) in data_lines(text) {
        let mut f = Fields::new(line_text, POINTS3D_TXT, line);
        let point3d_id: Point3DId = f.parse("POINT3D_ID")?;
        let xyz = Point3::new(f.parse("X")?, f.parse("Y")?, f.parse("Z")?);
        let rgb = [f.parse("R")?, f.parse("G")?, f.parse("B")?];
        let error: f64 = f.parse("ERROR")?;
        let tokens = f.rest();
        if !tokens.len().is_multiple_of(2) {
            return Err(f.bad(format!(
                "TRACK of point {point3d_id}: {} values, not pairs (IMAGE_ID, POINT2D_IDX)",
                tokens.len()
            )));
        }
        let mut track = Vec::with_capacity(tokens.len() / 2);
        for pair in tokens.chunks_exact(2) {
            let &[image_id, point2d_idx] = pair else {
                continue;
            };
            let (Ok(image_id), Ok(point2d_idx)) = (image_id.parse::<u32>(), point2d_idx.parse::<u32>()) else {
                return Err(f.bad(format!("TRACK of point {point3d_id}: bad element ({image_id}, {point2d_idx})")));
            };
            track.push(TrackElement { image_id, point2d_idx });
        }
        if points.insert(point3d_id, Point3D { xyz, rgb, error, track }).is_some() {
            return Err(f.bad(format!("duplicate point3D id {point3d_id}")));
        }
    }
    Ok(points)
}

/// Encodes `points3D.txt` with COLMAP's header.
pub fn encode_points3d_txt(points: &BTreeMap<Point3DId, Point3D>) -> String {
    let track_elements: usize = points.values().map(|p| p.track.len()).sum();
    let mean = if points.is_empty() { 0.0 } else { track_elements as f64 / points.len() as f64 };
    let mut out = String::new();
    out.push_str("# 3D point list with one line of data per point:\n");
    out.push_str("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    let _ = writeln!(out, "# Number of points: {}, mean track length: {}", points.len(), fmt_mean(mean));
    for (point3d_id, point) in points {
        let [r, g, b] = point.rgb;
        let _ = write!(
            out,
            "{point3d_id} {} {} {} {r} {g} {b} {}",
            fmt_f64(point.xyz.x),
            fmt_f64(point.xyz.y),
            fmt_f64(point.xyz.z),
            fmt_f64(point.error)
        );
        for element in &point.track {
            let _ = write!(out, " {} {}", element.image_id, element.point2d_idx);
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_shortest_and_parse_back() {
        for value in [0.0, -0.0, 1.0, 0.1, 320.0, 1e-300, -2.5e-7, 1.0e20, 123456.789, f64::MAX, f64::MIN_POSITIVE] {
            let text = fmt_f64(value);
            assert_eq!(text.parse::<f64>().unwrap().to_bits(), value.to_bits(), "{text}");
        }
        assert_eq!(fmt_f64(320.0), "320");
        assert_eq!(fmt_f64(1e-300), "1e-300");
    }

    #[test]
    fn means_print_like_a_cpp_stream() {
        assert_eq!(fmt_mean(2.0), "2");
        assert_eq!(fmt_mean(0.0), "0");
        assert_eq!(fmt_mean(2.0 / 3.0), "0.666667");
        assert_eq!(fmt_mean(1234.5678), "1234.57");
    }
}
