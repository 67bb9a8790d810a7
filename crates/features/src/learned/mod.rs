//! Learned local features on ONNX Runtime: ALIKED (fixed-size export, whole
//! network in the model) and XFeat (raw backbone in the model; detection and
//! description written here). Both take an RGB image and a [`Roll`] and
//! return [`LearnedFeatures`] in the rolled image's pixel-corner frame.

mod aliked;
mod resize;
mod xfeat;

pub use aliked::Aliked;
pub use resize::{rolled, Planar};
pub use xfeat::{XFeat, XFeatOptions};

use image::RgbImage;
use revisit_core::{LearnedFeatures, Roll};
use revisit_onnx::OnnxError;

/// A learned feature extractor chosen by name.
pub enum LearnedExtractor {
    Aliked(Aliked),
    XFeat(XFeat),
}

impl LearnedExtractor {
    /// Features of `image` rolled by `roll`.
    pub fn extract(&mut self, image: &RgbImage, roll: Roll) -> Result<LearnedFeatures, OnnxError> {
        match self {
            LearnedExtractor::Aliked(aliked) => aliked.extract(image, roll),
            LearnedExtractor::XFeat(xfeat) => xfeat.extract(image, roll),
        }
    }

    pub fn descriptor_dim(&self) -> usize {
        match self {
            LearnedExtractor::Aliked(_) => aliked::DESCRIPTOR_DIM,
            LearnedExtractor::XFeat(_) => xfeat::DESCRIPTOR_DIM,
        }
    }
}

fn shape_error(model: &revisit_onnx::Model, message: String) -> OnnxError {
    OnnxError::Run { path: model.path().to_path_buf(), message }
}
