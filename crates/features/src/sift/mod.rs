//! Lowe's SIFT, as COLMAP (VLFeat) and OpenCV compute it: a Gaussian scale
//! space with `octave_resolution` scales per octave, DoG extrema refined by a
//! quadratic fit, contrast and edge tests, 36-bin orientation histograms and
//! the 4x4x8 descriptor, stored as COLMAP stores descriptors (128 bytes).
//!
//! One image is processed on the calling thread; callers parallelise over
//! images.

mod describe;
mod detect;
mod pyramid;

use serde::{Deserialize, Serialize};

use revisit_core::{Features, Keypoint};

use crate::FeatureError;
use describe::{DescriptorScratch, OctaveFrame, DESCRIPTOR_DIM};
use detect::{DetectParams, Extremum, BORDER_PX};
use pyramid::{BlurScratch, Plane};

/// How descriptors are normalised before conversion to bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalization {
    /// RootSIFT (Arandjelovic and Zisserman 2012): L1-normalise, then take the
    /// square root of every entry. COLMAP's default.
    #[default]
    L1Root,
    /// Lowe's: L2-normalise, clamp at 0.2, L2-normalise again.
    L2,
}

/// Options of [`extract_sift`]. Defaults are COLMAP's where COLMAP has the
/// option, and were checked against OpenCV on real underwater frames
/// (`revisit bench sift`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SiftOptions {
    /// Keep at most this many keypoints, the strongest by |DoG| (8192).
    /// Every orientation of a location counts as one keypoint.
    pub max_num_features: usize,
    /// The first octave: -1 doubles the image first (more small features,
    /// about 2.5x the time), 0 starts at the input resolution, k > 0 at 1/2^k
    /// of it (0). COLMAP's default is -1, but on real 1280x720 underwater
    /// frames 0 gave 45% more verified inliers at 2048 features, because the
    /// cap then keeps larger, more repeatable features (`revisit bench sift`).
    pub first_octave: i32,
    /// At most this many octaves; fewer when the image gets too small (8).
    pub max_num_octaves: usize,
    /// Scales per octave (3).
    pub octave_resolution: usize,
    /// Blur of the first scale of every octave, in that octave's pixels (1.6).
    pub sigma: f32,
    /// Blur already present in the input image, in its pixels (0.5).
    pub input_sigma: f32,
    /// Refined extrema with |DoG| below this are dropped; intensities are
    /// scaled to [0, 1]. COLMAP's `0.02 / octave_resolution` (0.006 667).
    pub peak_threshold: f32,
    /// Extrema whose ratio of principal curvatures exceeds this are edges and
    /// are dropped (10).
    pub edge_threshold: f32,
    /// Orientations kept per location, strongest first (2).
    pub max_num_orientations: usize,
    /// Skip orientation estimation: every keypoint gets orientation 0 (false).
    pub upright: bool,
    /// Descriptor normalisation (L1Root).
    pub normalization: Normalization,
    /// Rectangles `[x, y, width, height]` in input pixels whose keypoints are
    /// dropped before the `max_num_features` cap, such as a burned-in
    /// timestamp (none).
    pub ignore_regions_px: Vec<[u32; 4]>,
}

impl Default for SiftOptions {
    fn default() -> Self {
        Self {
            max_num_features: 8192,
            first_octave: 0,
            max_num_octaves: 8,
            octave_resolution: 3,
            sigma: 1.6,
            input_sigma: 0.5,
            peak_threshold: 0.02 / 3.0,
            edge_threshold: 10.0,
            max_num_orientations: 2,
            upright: false,
            normalization: Normalization::L1Root,
            ignore_regions_px: Vec::new(),
        }
    }
}

/// Images smaller than this on either side are refused.
pub const MIN_IMAGE_SIZE_PX: u32 = 16;
/// Octaves smaller than this on either side are not built.
const MIN_OCTAVE_SIZE_PX: usize = 2 * BORDER_PX + 8;

impl SiftOptions {
    /// Checks every option; [`extract_sift`] calls it first.
    pub fn check(&self) -> Result<(), FeatureError> {
        let invalid = |option: &'static str, reason: String| Err(FeatureError::InvalidOption { option, reason });
        if self.max_num_features == 0 {
            return invalid("max_num_features", "must be at least 1".into());
        }
        if !(-1..=6).contains(&self.first_octave) {
            return invalid("first_octave", format!("{} is not in -1..=6", self.first_octave));
        }
        if self.max_num_octaves == 0 {
            return invalid("max_num_octaves", "must be at least 1".into());
        }
        if !(1..=10).contains(&self.octave_resolution) {
            return invalid("octave_resolution", format!("{} is not in 1..=10", self.octave_resolution));
        }
        if !(self.sigma.is_finite() && self.sigma > 0.0) {
            return invalid("sigma", format!("{} is not a positive number", self.sigma));
        }
        if !(self.input_sigma.is_finite() && self.input_sigma >= 0.0) {
            return invalid("input_sigma", format!("{} is not a number >= 0", self.input_sigma));
        }
        if !(self.peak_threshold.is_finite() && self.peak_threshold >= 0.0) {
            return invalid("peak_threshold", format!("{} is not a number >= 0", self.peak_threshold));
        }
        if !(self.edge_threshold.is_finite() && self.edge_threshold > 1.0) {
            return invalid("edge_threshold", format!("{} is not a number > 1", self.edge_threshold));
        }
        if self.max_num_orientations == 0 {
            return invalid("max_num_orientations", "must be at least 1".into());
        }
        Ok(())
    }

    fn ignores(&self, x_px: f32, y_px: f32) -> bool {
        self.ignore_regions_px.iter().any(|&[x, y, width, height]| {
            let (x, y) = (x as f32, y as f32);
            x_px >= x && x_px < x + width as f32 && y_px >= y && y_px < y + height as f32
        })
    }
}

/// Extracts SIFT keypoints and descriptors from a grayscale image.
///
/// Keypoints use COLMAP's pixel-corner convention (the centre of the top-left
/// pixel is (0.5, 0.5)), `scale` is the detection sigma in input pixels and
/// `orientation` is in radians, `[0, 2 pi)`, in the y-down image frame.
/// Keypoints come strongest first (ties broken by position), descriptors are
/// 128 bytes each, in the same order. The output is a pure function of the
/// image and the options.
pub fn extract_sift(options: &SiftOptions, image: &image::GrayImage) -> Result<Features, FeatureError> {
    options.check()?;
    let (width, height) = image.dimensions();
    if width < MIN_IMAGE_SIZE_PX || height < MIN_IMAGE_SIZE_PX {
        return Err(FeatureError::ImageTooSmall { width, height, min: MIN_IMAGE_SIZE_PX });
    }
    let input = Plane {
        width: width as usize,
        height: height as usize,
        data: image.as_raw().iter().map(|&v| f32::from(v) * (1.0 / 255.0)).collect(),
    };
    let pyramid = build_and_detect(options, input);
    Ok(describe_strongest(options, &pyramid))
}

/// The Gaussian layers that orientations and descriptors need, and the
/// refined extrema of every octave.
struct Pyramid {
    /// Per octave, the Gaussian images of layers `1..=octave_resolution`.
    gaussians: Vec<Vec<Plane>>,
    extrema: Vec<Extremum>,
}

fn build_and_detect(options: &SiftOptions, input: Plane) -> Pyramid {
    let resolution = options.octave_resolution;
    let mut base = if options.first_octave < 0 { pyramid::upsample2(&input) } else { input };
    for _ in 0..options.first_octave.max(0) {
        let mut smaller = Plane::default();
        pyramid::downsample2(&base, &mut smaller);
        base = smaller;
    }
    let mut scratch = BlurScratch::default();
    // Bring the input's assumed blur up to `sigma` (in first-octave pixels).
    let have = options.input_sigma * (-options.first_octave as f32).exp2();
    let initial = (options.sigma * options.sigma - have * have).max(0.01).sqrt();
    let mut first = Plane::default();
    pyramid::blur(&base, &mut first, &pyramid::gaussian_taps(initial), &mut scratch);
    drop(base);

    // Incremental blurs: layer i is layer i-1 blurred by sqrt(s_i^2 - s_{i-1}^2).
    let k = (1.0 / resolution as f32).exp2();
    let taps: Vec<Vec<f32>> = (1..resolution + 3)
        .map(|i| {
            let previous = options.sigma * k.powi(i as i32 - 1);
            let total = previous * k;
            pyramid::gaussian_taps((total * total - previous * previous).sqrt())
        })
        .collect();
    let params = DetectParams {
        octave_resolution: resolution,
        sigma: options.sigma,
        prelim_threshold: 0.5 * options.peak_threshold,
        peak_threshold: options.peak_threshold,
        edge_threshold: options.edge_threshold,
    };

    let mut layers: Vec<Plane> = vec![Plane::default(); resolution + 3];
    let mut dogs: Vec<Plane> = vec![Plane::default(); resolution + 2];
    let mut pyramid = Pyramid { gaussians: Vec::new(), extrema: Vec::new() };
    let mut next_base = Some(first);
    for octave in 0..options.max_num_octaves {
        let Some(base) = next_base.take() else {
            break;
        };
        if base.width.min(base.height) < MIN_OCTAVE_SIZE_PX {
            break;
        }
        if let Some(slot) = layers.first_mut() {
            *slot = base;
        }
        for (i, kernel) in taps.iter().enumerate() {
            let (done, rest) = layers.split_at_mut(i + 1);
            if let (Some(source), Some(target)) = (done.last(), rest.first_mut()) {
                pyramid::blur(source, target, kernel, &mut scratch);
            }
        }
        for (i, dog) in dogs.iter_mut().enumerate() {
            if let (Some(lower), Some(upper)) = (layers.get(i), layers.get(i + 1)) {
                pyramid::subtract(upper, lower, dog);
            }
        }
        detect::detect_octave(&dogs, octave, &params, &mut pyramid.extrema);
        // The layer at twice the first sigma seeds the next octave.
        if let Some(seed) = layers.get(resolution) {
            let mut smaller = Plane::default();
            pyramid::downsample2(seed, &mut smaller);
            next_base = Some(smaller);
        }
        let kept = layers.get_mut(1..=resolution).map(|kept| kept.iter_mut().map(std::mem::take).collect());
        pyramid.gaussians.push(kept.unwrap_or_default());
    }
    pyramid
}

/// Input-image position (pixel-corner convention) and scale of an extremum.
fn to_input(options: &SiftOptions, extremum: &Extremum) -> (f32, f32, f32) {
    let factor = (options.first_octave + extremum.octave as i32) as f32;
    let factor = factor.exp2();
    (extremum.x_octave * factor + 0.5, extremum.y_octave * factor + 0.5, extremum.sigma_octave * factor)
}

fn describe_strongest(options: &SiftOptions, pyramid: &Pyramid) -> Features {
    let mut extrema: Vec<&Extremum> = pyramid
        .extrema
        .iter()
        .filter(|e| {
            let (x, y, _) = to_input(options, e);
            !options.ignores(x, y)
        })
        .collect();
    // Strongest first; ties (and refinements that converged to the same
    // sample) ordered by position so the output is deterministic.
    let key = |e: &Extremum| (e.octave, e.layer, e.row, e.column);
    extrema.sort_by(|a, b| b.response.total_cmp(&a.response).then_with(|| key(a).cmp(&key(b))));
    extrema.dedup_by(|a, b| key(a) == key(b));

    let mut features = Features { keypoints: Vec::new(), descriptors: Vec::new(), descriptor_dim: DESCRIPTOR_DIM };
    let mut scratch = DescriptorScratch::default();
    for extremum in extrema {
        if features.keypoints.len() >= options.max_num_features {
            break;
        }
        let Some(gaussian) = pyramid.gaussians.get(extremum.octave).and_then(|g| g.get(extremum.layer - 1)) else {
            continue;
        };
        let angles = if options.upright {
            vec![0.0]
        } else {
            describe::orientations(
                gaussian,
                extremum.column,
                extremum.row,
                extremum.sigma_octave,
                options.max_num_orientations,
            )
        };
        let (x, y, scale) = to_input(options, extremum);
        for orientation in angles {
            if features.keypoints.len() >= options.max_num_features {
                break;
            }
            let frame =
                OctaveFrame { x: extremum.x_octave, y: extremum.y_octave, sigma: extremum.sigma_octave, orientation };
            let bytes = describe::descriptor(gaussian, &frame, options.normalization, &mut scratch);
            features.keypoints.push(Keypoint { x, y, scale, orientation });
            features.descriptors.extend_from_slice(&bytes);
        }
    }
    features
}
