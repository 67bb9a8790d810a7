//! Global descriptors from a user's ONNX model. The contract: one float input
//! [1, 3, H, W], RGB in [0, 1] (any normalisation is the model's own), and one
//! float output [1, D], the image's descriptor. A model with a fixed H and W
//! gets the image resized to them; a dynamic one gets the image as it is.
//! The output is L2-normalised here whatever the model does.

use std::path::Path;

use image::RgbImage;
use ndarray::{ArrayView, IxDyn};
use revisit_core::Roll;
use revisit_features::learned::{rolled, Planar};
use revisit_onnx::{Model, OnnxError, Runtime};

use crate::{l2_normalise, GlobalDescriptor};

pub struct OnnxPlaces {
    model: Model,
    input: String,
    output: String,
    /// Fixed (width, height) of the input, if the model has one.
    size: Option<(u32, u32)>,
    name: String,
}

impl OnnxPlaces {
    pub fn open(runtime: &Runtime, path: &Path) -> Result<OnnxPlaces, OnnxError> {
        let model = Model::open_unchecked(runtime, path)?;
        let contract = |input: &str, message: &str| OnnxError::Contract {
            path: path.to_path_buf(),
            input: input.to_owned(),
            message: format!("{message} (a place-recognition model takes one [1, 3, H, W] RGB image)"),
        };
        let inputs = model.inputs();
        let [input] = inputs.as_slice() else {
            return Err(contract("*", &format!("count is {}, not 1", inputs.len())));
        };
        if !input.is_float_tensor || input.shape.len() != 4 || input.shape[1] != 3 {
            return Err(contract(&input.name, &format!("has shape {:?}", input.shape)));
        }
        let outputs = model.outputs();
        let Some(output) = outputs.first().filter(|o| o.is_float_tensor && o.shape.len() == 2) else {
            return Err(OnnxError::BadModel {
                path: path.to_path_buf(),
                message: "its first output is not a float [1, D] descriptor".to_owned(),
            });
        };
        let size = (input.shape[2] > 0 && input.shape[3] > 0).then(|| (input.shape[3] as u32, input.shape[2] as u32));
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(OnnxPlaces {
            input: input.name.clone(),
            output: output.name.clone(),
            size,
            name: format!("onnx-{stem}"),
            model,
        })
    }

    /// The descriptor of `image` rolled by `roll`.
    pub fn describe(&mut self, image: &RgbImage, roll: Roll) -> Result<Vec<f32>, OnnxError> {
        let rolled = rolled(image, roll);
        let fitted = match self.size {
            Some((w, h)) if (w, h) != rolled.dimensions() => {
                image::imageops::resize(&rolled, w, h, image::imageops::FilterType::Triangle)
            }
            _ => rolled,
        };
        let input = Planar::rgb(&fitted, Roll::R0);
        let view = ArrayView::from_shape(IxDyn(&[1, 3, input.height, input.width]), &input.data)
            .map_err(|e| OnnxError::Run { path: self.model.path().to_path_buf(), message: e.to_string() })?;
        let output = self.model.run(&[(self.input.as_str(), view)], &[self.output.as_str()])?.remove(&self.output);
        let output = output.unwrap_or_default();
        self.model.check_output(&self.output, output.shape(), &[Some(1), None])?;
        let mut descriptor: Vec<f32> = output.into_iter().collect();
        if descriptor.is_empty() || descriptor.iter().any(|v| !v.is_finite()) {
            return Err(OnnxError::Run {
                path: self.model.path().to_path_buf(),
                message: "the descriptor is empty or not finite".to_owned(),
            });
        }
        l2_normalise(&mut descriptor);
        Ok(descriptor)
    }
}

impl GlobalDescriptor for OnnxPlaces {
    fn name(&self) -> String {
        self.name.clone()
    }
}
