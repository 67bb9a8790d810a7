use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::{ImageId, Rigid3};

/// A local feature's frame in pixels: position (pixel corner convention, as
/// COLMAP), scale (pixels, the detection sigma) and orientation (radians).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Keypoint {
    pub x: f32,
    pub y: f32,
    pub scale: f32,
    pub orientation: f32,
}

impl Keypoint {
    /// The affine shape as COLMAP stores it in its 6-column keypoint blobs:
    /// `x, y, a11, a12, a21, a22`.
    pub fn to_affine(&self) -> [f32; 6] {
        let (sin, cos) = self.orientation.sin_cos();
        [self.x, self.y, self.scale * cos, -self.scale * sin, self.scale * sin, self.scale * cos]
    }

    /// The inverse of [`Keypoint::to_affine`] (also accepts 2 or 4 columns).
    pub fn from_columns(row: &[f32]) -> Option<Self> {
        match *row {
            [x, y] => Some(Self { x, y, scale: 1.0, orientation: 0.0 }),
            [x, y, scale, orientation] => Some(Self { x, y, scale, orientation }),
            [x, y, a11, _a12, a21, _a22] => Some(Self { x, y, scale: a11.hypot(a21), orientation: a21.atan2(a11) }),
            _ => None,
        }
    }
}

/// The local features of one image: keypoints and their descriptors, row-major,
/// `descriptor_dim` bytes per keypoint (SIFT: 128, as COLMAP stores them).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Features {
    pub keypoints: Vec<Keypoint>,
    pub descriptors: Vec<u8>,
    pub descriptor_dim: usize,
}

impl Features {
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// The descriptor of keypoint `index`, if there is one.
    pub fn descriptor(&self, index: usize) -> Option<&[u8]> {
        let start = index.checked_mul(self.descriptor_dim)?;
        self.descriptors.get(start..start + self.descriptor_dim)
    }
}

/// COLMAP's largest image id, the multiplier of its pair ids.
const MAX_NUM_IMAGES: u64 = 2_147_483_647;

/// COLMAP's identifier of an unordered image pair (smaller id first).
pub fn pair_id(image_id1: ImageId, image_id2: ImageId) -> u64 {
    let (a, b) = if image_id1 > image_id2 { (image_id2, image_id1) } else { (image_id1, image_id2) };
    MAX_NUM_IMAGES * u64::from(a) + u64::from(b)
}

/// The image ids of a COLMAP pair id, smaller first.
pub fn pair_from_id(pair_id: u64) -> (ImageId, ImageId) {
    let b = pair_id % MAX_NUM_IMAGES;
    let a = (pair_id - b) / MAX_NUM_IMAGES;
    (a as ImageId, b as ImageId)
}

/// COLMAP's two-view configuration codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum TwoViewConfig {
    Undefined = 0,
    Degenerate = 1,
    Calibrated = 2,
    Uncalibrated = 3,
    Planar = 4,
    Panoramic = 5,
    PlanarOrPanoramic = 6,
    Watermark = 7,
    Multiple = 8,
}

impl TwoViewConfig {
    pub fn from_code(code: i64) -> Self {
        match code {
            1 => Self::Degenerate,
            2 => Self::Calibrated,
            3 => Self::Uncalibrated,
            4 => Self::Planar,
            5 => Self::Panoramic,
            6 => Self::PlanarOrPanoramic,
            7 => Self::Watermark,
            8 => Self::Multiple,
            _ => Self::Undefined,
        }
    }
}

/// The verified geometry of an image pair: which matches are inliers and the
/// model they satisfy. Indices are keypoint indices of image 1 and image 2.
#[derive(Clone, Debug, PartialEq)]
pub struct TwoViewGeometry {
    pub config: TwoViewConfig,
    pub inlier_matches: Vec<[u32; 2]>,
    /// Fundamental matrix, `x2^T F x1 = 0` in pixels.
    pub f: Option<Matrix3<f64>>,
    pub e: Option<Matrix3<f64>>,
    /// Homography `x2 ~ H x1` in pixels.
    pub h: Option<Matrix3<f64>>,
    pub cam2_from_cam1: Option<Rigid3>,
}

impl TwoViewGeometry {
    /// A pair that did not verify: no inliers, no model.
    pub fn degenerate() -> TwoViewGeometry {
        TwoViewGeometry {
            config: TwoViewConfig::Degenerate,
            inlier_matches: Vec::new(),
            f: None,
            e: None,
            h: None,
            cam2_from_cam1: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_ids_match_colmap() {
        assert_eq!(pair_id(1, 2), 2_147_483_649);
        assert_eq!(pair_id(2, 1), pair_id(1, 2));
        assert_eq!(pair_from_id(pair_id(7, 3)), (3, 7));
    }

    #[test]
    fn affine_keypoints_round_trip() {
        let kp = Keypoint { x: 10.5, y: 3.25, scale: 2.0, orientation: 0.7 };
        let back = Keypoint::from_columns(&kp.to_affine()).unwrap();
        assert!((back.scale - 2.0).abs() < 1e-6 && (back.orientation - 0.7).abs() < 1e-6);
    }
}

/// Learned local features of one image (ALIKED, XFeat): keypoints in the
/// pixel-corner convention of the image they were extracted from (after any
/// roll, see [`Roll`]), L2-normalised float descriptors, row-major,
/// `descriptor_dim` floats per keypoint, and the detector's score per keypoint.
/// `width` and `height` are that image's size in pixels.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LearnedFeatures {
    pub keypoints: Vec<[f32; 2]>,
    pub descriptors: Vec<f32>,
    pub descriptor_dim: usize,
    pub scores: Vec<f32>,
    pub width: u32,
    pub height: u32,
}

impl LearnedFeatures {
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// The `budget` keypoints with the highest scores (ties by index), as a
    /// new set in that order: what a cheap first look at a pair matches.
    pub fn strongest(&self, budget: usize) -> LearnedFeatures {
        let mut order: Vec<u32> = (0..self.len() as u32).collect();
        order.sort_by(|&a, &b| self.scores[b as usize].total_cmp(&self.scores[a as usize]).then(a.cmp(&b)));
        order.truncate(budget);
        self.subset(&order)
    }

    /// The keypoints at `indices` (each less than [`LearnedFeatures::len`]), in that order.
    pub fn subset(&self, indices: &[u32]) -> LearnedFeatures {
        let dim = self.descriptor_dim;
        let at = |i: u32| i as usize;
        LearnedFeatures {
            keypoints: indices.iter().map(|&i| self.keypoints[at(i)]).collect(),
            descriptors: indices
                .iter()
                .flat_map(|&i| self.descriptors[at(i) * dim..(at(i) + 1) * dim].iter().copied())
                .collect(),
            descriptor_dim: dim,
            scores: indices.iter().map(|&i| self.scores[at(i)]).collect(),
            width: self.width,
            height: self.height,
        }
    }
}

/// One end of a cross-visit match: which keypoint of the image it uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CrossKey {
    /// An existing keypoint of the image (e.g. a SIFT keypoint a learned one
    /// was anchored to), by its index in the image's keypoint list.
    Own(u32),
    /// A learned keypoint, by its index in the learned features of its side.
    Learned(u32),
}

/// A rotation of an image about the optical axis by a multiple of 90 degrees,
/// clockwise as displayed. Downward-looking cameras revisit a place at any
/// heading, so cross-visit matching tries all four.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Roll {
    R0,
    R90,
    R180,
    R270,
}

impl Roll {
    pub const ALL: [Roll; 4] = [Roll::R0, Roll::R90, Roll::R180, Roll::R270];

    pub fn degrees(self) -> u32 {
        match self {
            Roll::R0 => 0,
            Roll::R90 => 90,
            Roll::R180 => 180,
            Roll::R270 => 270,
        }
    }

    pub fn from_degrees(degrees: u32) -> Option<Roll> {
        Roll::ALL.into_iter().find(|r| r.degrees() == degrees)
    }

    /// The size of a `width` x `height` image after this roll.
    pub fn rolled_size(self, width: u32, height: u32) -> (u32, u32) {
        match self {
            Roll::R0 | Roll::R180 => (width, height),
            Roll::R90 | Roll::R270 => (height, width),
        }
    }

    /// Maps a point of the rolled image back to the unrolled `width` x
    /// `height` image (pixel-corner convention, so the map is exact).
    pub fn unroll_point(self, [x, y]: [f32; 2], width: u32, height: u32) -> [f32; 2] {
        let (w, h) = (width as f32, height as f32);
        match self {
            Roll::R0 => [x, y],
            Roll::R90 => [y, h - x],
            Roll::R180 => [w - x, h - y],
            Roll::R270 => [w - y, x],
        }
    }

    /// Maps a point of the unrolled `width` x `height` image into the rolled one.
    pub fn roll_point(self, [x, y]: [f32; 2], width: u32, height: u32) -> [f32; 2] {
        let (w, h) = (width as f32, height as f32);
        match self {
            Roll::R0 => [x, y],
            Roll::R90 => [h - y, x],
            Roll::R180 => [w - x, h - y],
            Roll::R270 => [y, w - x],
        }
    }
}

#[cfg(test)]
mod roll_tests {
    use super::Roll;

    #[test]
    fn unroll_inverts_roll() {
        for roll in Roll::ALL {
            let p = [12.25, 7.5];
            let rolled = roll.roll_point(p, 64, 48);
            let (w, h) = roll.rolled_size(64, 48);
            assert!(rolled[0] >= 0.0 && rolled[0] <= w as f32 && rolled[1] >= 0.0 && rolled[1] <= h as f32);
            assert_eq!(roll.unroll_point(rolled, 64, 48), p, "{roll:?}");
        }
    }
}
