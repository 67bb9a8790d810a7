//! ALIKED (Zhao et al., 2023) from a fixed-size ONNX export: the image is
//! resized (antialiased bilinear, as the reference) to fit the model's frame
//! with its aspect ratio kept, placed top-left on black, and keypoints in the
//! black margin are dropped.

use std::path::Path;

use image::RgbImage;
use ndarray::{ArrayView, IxDyn};
use revisit_core::{LearnedFeatures, Roll};
use revisit_onnx::{Contract, InputSpec, Model, OnnxError, OutputSpec, Runtime};

use image::imageops::FilterType;

use super::resize::fit_size;
use super::{rolled, shape_error, Planar};

pub const DESCRIPTOR_DIM: usize = 128;

const CONTRACT: Contract = Contract {
    inputs: &[InputSpec { name: "image", shape: &[Some(1), Some(3), None, None] }],
    outputs: &[
        OutputSpec { name: "keypoints", shape: &[Some(1), None, Some(2)] },
        OutputSpec { name: "descriptors", shape: &[Some(1), None, Some(DESCRIPTOR_DIM as i64)] },
        OutputSpec { name: "scores", shape: &[Some(1), None] },
    ],
};

/// An opened ALIKED model and the frame size it was exported for.
pub struct Aliked {
    model: Model,
    width: usize,
    height: usize,
}

impl Aliked {
    pub fn open(runtime: &Runtime, path: &Path) -> Result<Aliked, OnnxError> {
        let model = Model::open(runtime, path, &CONTRACT)?;
        // The contract checked that the input is [1, 3, H, W].
        let shape = model.input_shape("image").unwrap_or_default();
        let (height, width) = match shape[..] {
            [_, _, height, width] => (height, width),
            _ => (-1, -1),
        };
        if height <= 0 || width <= 0 {
            return Err(OnnxError::Contract {
                path: path.to_path_buf(),
                input: "image".to_owned(),
                message: "must have a fixed height and width (ALIKED's dynamic exports give wrong descriptors)"
                    .to_owned(),
            });
        }
        Ok(Aliked { model, width: width as usize, height: height as usize })
    }

    /// The model's frame, width by height.
    pub fn frame(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    pub fn extract(&mut self, image: &RgbImage, roll: Roll) -> Result<LearnedFeatures, OnnxError> {
        let rolled = rolled(image, roll);
        let (width, height) = rolled.dimensions();
        let [fit_w, fit_h] = fit_size(width, height, [self.width as u32, self.height as u32]);
        let fitted = image::imageops::resize(&rolled, fit_w, fit_h, FilterType::Triangle);
        let mut features = self.run(&Planar::rgb(&fitted, Roll::R0).padded(self.width, self.height))?;
        let (fit_w, fit_h) = (fit_w as f32, fit_h as f32);
        let scale = [fit_w / width as f32, fit_h / height as f32];
        let keep: Vec<usize> = (0..features.len())
            .filter(|&i| features.keypoints[i][0] < fit_w && features.keypoints[i][1] < fit_h)
            .collect();
        let dim = DESCRIPTOR_DIM;
        features.keypoints =
            keep.iter().map(|&i| [features.keypoints[i][0] / scale[0], features.keypoints[i][1] / scale[1]]).collect();
        features.descriptors =
            keep.iter().flat_map(|&i| features.descriptors[i * dim..(i + 1) * dim].to_vec()).collect();
        features.scores = keep.iter().map(|&i| features.scores[i]).collect();
        (features.width, features.height) = (width, height);
        Ok(features)
    }

    /// Runs the model on an image already in its frame; keypoints come back
    /// in that frame's pixel-corner convention.
    pub fn run(&mut self, input: &Planar) -> Result<LearnedFeatures, OnnxError> {
        let view = ArrayView::from_shape(IxDyn(&[1, 3, input.height, input.width]), &input.data)
            .map_err(|e| shape_error(&self.model, e.to_string()))?;
        let mut outputs = self.model.run(&[("image", view)], &CONTRACT.output_names())?;
        let mut take = |name: &str| outputs.remove(name).unwrap_or_default();
        let (keypoints, descriptors, scores) = (take("keypoints"), take("descriptors"), take("scores"));
        // The run checked each output against the contract; the keypoint counts must agree.
        let count = keypoints.shape().get(1).copied().unwrap_or_default();
        self.model.check_output("keypoints", keypoints.shape(), &[Some(1), Some(count), Some(2)])?;
        self.model.check_output("descriptors", descriptors.shape(), &[Some(1), Some(count), Some(DESCRIPTOR_DIM)])?;
        self.model.check_output("scores", scores.shape(), &[Some(1), Some(count)])?;
        // ALIKED's (0, 0) is the centre of the top-left pixel.
        let xy: Vec<f32> = keypoints.iter().copied().collect();
        Ok(LearnedFeatures {
            keypoints: xy.chunks_exact(2).map(|p| [p[0] + 0.5, p[1] + 0.5]).collect(),
            descriptors: descriptors.iter().copied().collect(),
            descriptor_dim: DESCRIPTOR_DIM,
            scores: scores.iter().copied().collect(),
            width: input.width as u32,
            height: input.height as u32,
        })
    }
}
