//! XFeat (Potje et al., CVPR 2024): the ONNX file is the raw backbone; the
//! detection and description steps are here, as the paper and the package's
//! `detectAndCompute` describe them:
//! 1. the image (grey = mean of R, G, B) is resized to multiples of 32;
//! 2. a softmax over the 65 keypoint channels, the dustbin dropped, each cell's
//!    64 values unfolded into its 8x8 pixels: a full-resolution heatmap;
//! 3. 5x5 non-maximum suppression and a threshold on that heatmap;
//! 4. score = heatmap value (nearest) x reliability (bilinear), top-k by score;
//! 5. descriptors sampled from the L2-normalised dense map with bicubic
//!    interpolation, then L2-normalised again.
//!
//! Sampling follows PyTorch's `grid_sample(align_corners=False)` with the
//! grid normalised by (W - 1, H - 1), as XFeat's own code does, so that the
//! keypoints and descriptors agree with the reference outputs.

use std::path::Path;

use image::RgbImage;
use ndarray::{ArrayD, ArrayView, IxDyn};
use revisit_core::{LearnedFeatures, Roll};
use revisit_onnx::{Contract, InputSpec, Model, OnnxError, OutputSpec, Runtime};

use super::{shape_error, Planar};

pub const DESCRIPTOR_DIM: usize = 64;
const CELL: usize = 8;
/// Keypoint logits per cell: one per pixel of the 8x8 cell, and the dustbin.
const KEYPOINT_CHANNELS: usize = CELL * CELL + 1;

const CONTRACT: Contract = Contract {
    inputs: &[InputSpec { name: "image", shape: &[Some(1), Some(1), None, None] }],
    outputs: &[
        OutputSpec { name: "feats", shape: &[Some(1), Some(DESCRIPTOR_DIM as i64), None, None] },
        OutputSpec { name: "keypoints", shape: &[Some(1), Some(KEYPOINT_CHANNELS as i64), None, None] },
        OutputSpec { name: "heatmap", shape: &[Some(1), Some(1), None, None] },
    ],
};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct XFeatOptions {
    /// Keypoints kept, by score.
    pub top_k: usize,
    /// Minimum heatmap value of a keypoint.
    pub detection_threshold: f32,
}

impl Default for XFeatOptions {
    fn default() -> Self {
        XFeatOptions { top_k: 4096, detection_threshold: 0.05 }
    }
}

pub struct XFeat {
    model: Model,
    pub options: XFeatOptions,
}

/// The backbone's three outputs for one `width` x `height` image, checked
/// to be of these shapes (h = height / 8, w = width / 8), row-major.
pub struct BackboneOutput {
    /// [64, h, w] dense descriptors.
    feats: ArrayD<f32>,
    /// [65, h, w] keypoint logits.
    keypoints: ArrayD<f32>,
    /// [1, h, w] reliability.
    heatmap: ArrayD<f32>,
    width: usize,
    height: usize,
}

impl BackboneOutput {
    /// [64, h, w] dense descriptors.
    pub fn feats(&self) -> &ArrayD<f32> {
        &self.feats
    }

    /// [65, h, w] keypoint logits.
    pub fn keypoints(&self) -> &ArrayD<f32> {
        &self.keypoints
    }

    /// [1, h, w] reliability.
    pub fn heatmap(&self) -> &ArrayD<f32> {
        &self.heatmap
    }
}

impl XFeat {
    pub fn open(runtime: &Runtime, path: &Path, options: XFeatOptions) -> Result<XFeat, OnnxError> {
        Ok(XFeat { model: Model::open(runtime, path, &CONTRACT)?, options })
    }

    pub fn extract(&mut self, image: &RgbImage, roll: Roll) -> Result<LearnedFeatures, OnnxError> {
        let grey = Planar::grey_mean(image, roll);
        let (width, height) = (grey.width / 32 * 32, grey.height / 32 * 32);
        if width == 0 || height == 0 {
            return Err(shape_error(
                &self.model,
                format!("image of {}x{} is under 32 pixels", grey.width, grey.height),
            ));
        }
        let input = grey.resized(width, height);
        let output = self.backbone(&input)?;
        let mut features = detect_and_describe(&output, &self.options);
        let (sx, sy) = (grey.width as f32 / width as f32, grey.height as f32 / height as f32);
        for p in &mut features.keypoints {
            // XFeat scales pixel indices (centre convention) by the resize ratio.
            *p = [p[0] * sx + 0.5, p[1] * sy + 0.5];
        }
        (features.width, features.height) = (grey.width as u32, grey.height as u32);
        Ok(features)
    }

    /// Runs the backbone on a grey image whose sides are multiples of 32. Each
    /// output must be [1, channels, H/8, W/8] (64 channels for `feats`, 65 for
    /// `keypoints`, 1 for `heatmap`); another shape is an
    /// [`OnnxError::Output`] naming the file and the output.
    pub fn backbone(&mut self, input: &Planar) -> Result<BackboneOutput, OnnxError> {
        let (width, height) = (input.width, input.height);
        if width % 32 != 0 || height % 32 != 0 || width == 0 || height == 0 {
            return Err(shape_error(&self.model, format!("input of {width}x{height}: sides must be multiples of 32")));
        }
        let view = ArrayView::from_shape(IxDyn(&[1, 1, height, width]), &input.data)
            .map_err(|e| shape_error(&self.model, e.to_string()))?;
        let mut outputs = self.model.run(&[("image", view)], &CONTRACT.output_names())?;
        let mut take = |name: &str, channels: usize| -> Result<ArrayD<f32>, OnnxError> {
            let array = outputs.remove(name).unwrap_or_default();
            let expected = [Some(1), Some(channels), Some(height / CELL), Some(width / CELL)];
            self.model.check_output(name, array.shape(), &expected)?;
            let planes = array.index_axis_move(ndarray::Axis(0), 0);
            // Row-major, so that the steps below can read the planes as slices.
            Ok(if planes.is_standard_layout() { planes } else { planes.as_standard_layout().into_owned() })
        };
        Ok(BackboneOutput {
            feats: take("feats", DESCRIPTOR_DIM)?,
            keypoints: take("keypoints", KEYPOINT_CHANNELS)?,
            heatmap: take("heatmap", 1)?,
            width,
            height,
        })
    }
}

/// Steps 2 to 5 on the backbone's output for its `width` x `height` input.
/// Keypoints are pixel indices of that input (centre convention).
pub fn detect_and_describe(output: &BackboneOutput, options: &XFeatOptions) -> LearnedFeatures {
    let (width, height) = (output.width, output.height);
    let heatmap = keypoint_heatmap(&output.keypoints, width, height);
    let candidates = non_maximum_suppression(&heatmap, width, height, options.detection_threshold);
    let reliability = output.heatmap.as_slice().unwrap_or_default();
    let (cell_w, cell_h) = (width / CELL, height / CELL);
    let mut scored: Vec<(f32, [usize; 2])> = candidates
        .into_iter()
        .map(|[x, y]| {
            let [gx, gy] = grid([x as f32, y as f32], width, height);
            let detection = sample_nearest(&heatmap, width, height, gx, gy);
            let score = detection * sample_bilinear(reliability, cell_w, cell_h, gx, gy);
            (if x == 0 && y == 0 { -1.0 } else { score }, [x, y])
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.truncate(options.top_k);
    scored.retain(|(score, _)| *score > 0.0);

    let dense = normalised_dense(&output.feats, cell_w, cell_h);
    let mut descriptors = Vec::with_capacity(scored.len() * DESCRIPTOR_DIM);
    for (_, [x, y]) in &scored {
        let [gx, gy] = grid([*x as f32, *y as f32], width, height);
        let start = descriptors.len();
        for c in 0..DESCRIPTOR_DIM {
            let plane = &dense[c * cell_w * cell_h..(c + 1) * cell_w * cell_h];
            descriptors.push(sample_bicubic(plane, cell_w, cell_h, gx, gy));
        }
        l2_normalise(&mut descriptors[start..]);
    }
    LearnedFeatures {
        keypoints: scored.iter().map(|(_, [x, y])| [*x as f32, *y as f32]).collect(),
        descriptors,
        descriptor_dim: DESCRIPTOR_DIM,
        scores: scored.iter().map(|(s, _)| *s).collect(),
        width: width as u32,
        height: height as u32,
    }
}

/// Softmax over the 65 channels of each cell, dustbin dropped, unfolded to a
/// `width` x `height` heatmap (channel `dy * 8 + dx` is pixel (dx, dy) of the cell).
fn keypoint_heatmap(logits: &ArrayD<f32>, width: usize, height: usize) -> Vec<f32> {
    let (cell_w, cell_h) = (width / CELL, height / CELL);
    let channels = KEYPOINT_CHANNELS;
    let logits = logits.as_slice().unwrap_or_default();
    let plane = cell_w * cell_h;
    let mut heatmap = vec![0.0; width * height];
    let mut values = vec![0.0f32; channels];
    for cy in 0..cell_h {
        for cx in 0..cell_w {
            for (c, value) in values.iter_mut().enumerate() {
                *value = logits[c * plane + cy * cell_w + cx];
            }
            let max = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let sum: f32 = values.iter().map(|v| (v - max).exp()).sum();
            for dy in 0..CELL {
                for dx in 0..CELL {
                    let p = ((values[dy * CELL + dx] - max).exp()) / sum;
                    heatmap[(cy * CELL + dy) * width + cx * CELL + dx] = p;
                }
            }
        }
    }
    heatmap
}

/// Pixels that equal the maximum of their 5x5 neighbourhood and exceed
/// `threshold`, in row-major order, as (x, y).
fn non_maximum_suppression(heatmap: &[f32], width: usize, height: usize, threshold: f32) -> Vec<[usize; 2]> {
    const RADIUS: usize = 2;
    // Separable maximum: rows, then columns.
    let mut row_max = vec![0.0f32; width * height];
    for y in 0..height {
        for x in 0..width {
            let (lo, hi) = (x.saturating_sub(RADIUS), (x + RADIUS).min(width - 1));
            row_max[y * width + x] = heatmap[y * width + lo..=y * width + hi].iter().copied().fold(f32::MIN, f32::max);
        }
    }
    let mut found = Vec::new();
    for y in 0..height {
        let (lo, hi) = (y.saturating_sub(RADIUS), (y + RADIUS).min(height - 1));
        for x in 0..width {
            let value = heatmap[y * width + x];
            if value > threshold && (lo..=hi).all(|yy| row_max[yy * width + x] <= value) {
                found.push([x, y]);
            }
        }
    }
    found
}

/// XFeat's grid coordinate of pixel index (x, y): normalised by (W - 1, H - 1).
fn grid([x, y]: [f32; 2], width: usize, height: usize) -> [f32; 2] {
    [2.0 * x / (width as f32 - 1.0) - 1.0, 2.0 * y / (height as f32 - 1.0) - 1.0]
}

/// `grid_sample`'s source coordinate for `align_corners=False`.
fn unnormalise(g: f32, size: usize) -> f32 {
    ((g + 1.0) * size as f32 - 1.0) / 2.0
}

fn at(plane: &[f32], width: usize, height: usize, x: i64, y: i64) -> f32 {
    if x < 0 || y < 0 || x >= width as i64 || y >= height as i64 {
        0.0
    } else {
        plane[y as usize * width + x as usize]
    }
}

fn sample_nearest(plane: &[f32], width: usize, height: usize, gx: f32, gy: f32) -> f32 {
    let x = unnormalise(gx, width).round_ties_even() as i64;
    let y = unnormalise(gy, height).round_ties_even() as i64;
    at(plane, width, height, x, y)
}

fn sample_bilinear(plane: &[f32], width: usize, height: usize, gx: f32, gy: f32) -> f32 {
    let (x, y) = (unnormalise(gx, width), unnormalise(gy, height));
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let value = |dx: i64, dy: i64| at(plane, width, height, x0 + dx, y0 + dy);
    value(0, 0) * (1.0 - tx) * (1.0 - ty)
        + value(1, 0) * tx * (1.0 - ty)
        + value(0, 1) * (1.0 - tx) * ty
        + value(1, 1) * tx * ty
}

/// PyTorch's cubic convolution weights (A = -0.75) for fraction `t`.
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let near = |x: f32| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    let far = |x: f32| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    [far(t + 1.0), near(t), near(1.0 - t), far(2.0 - t)]
}

fn sample_bicubic(plane: &[f32], width: usize, height: usize, gx: f32, gy: f32) -> f32 {
    let (x, y) = (unnormalise(gx, width), unnormalise(gy, height));
    let (x0, y0) = (x.floor(), y.floor());
    let (wx, wy) = (cubic_weights(x - x0), cubic_weights(y - y0));
    let (x0, y0) = (x0 as i64, y0 as i64);
    let mut sum = 0.0;
    for (j, wy) in wy.iter().enumerate() {
        let mut row = 0.0;
        for (i, wx) in wx.iter().enumerate() {
            row += wx * at(plane, width, height, x0 - 1 + i as i64, y0 - 1 + j as i64);
        }
        sum += wy * row;
    }
    sum
}

/// The dense descriptor map with each pixel's 64-vector L2-normalised.
fn normalised_dense(feats: &ArrayD<f32>, width: usize, height: usize) -> Vec<f32> {
    let mut dense = feats.as_slice().map(<[f32]>::to_vec).unwrap_or_else(|| feats.iter().copied().collect());
    let plane = width * height;
    for p in 0..plane {
        let norm = (0..DESCRIPTOR_DIM).map(|c| dense[c * plane + p].powi(2)).sum::<f32>().sqrt().max(1e-12);
        for c in 0..DESCRIPTOR_DIM {
            dense[c * plane + p] /= norm;
        }
    }
    dense
}

fn l2_normalise(vector: &mut [f32]) {
    let norm = vector.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
    vector.iter_mut().for_each(|v| *v /= norm);
}
