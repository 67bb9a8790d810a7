//! Learned local features on ONNX Runtime: ALIKED (fixed-size export, whole
//! network in the model) and XFeat (raw backbone in the model; detection and
//! description written here). Both take an RGB image and a [`Roll`] and
//! return [`LearnedFeatures`] in the rolled image's pixel-corner frame.

mod aliked;
mod contrast;
mod resize;
mod xfeat;

pub use aliked::Aliked;
pub use contrast::{equalize, stretch, LearnedInput};
pub use resize::{rolled, Planar};
pub use xfeat::{XFeat, XFeatOptions};

use image::RgbImage;
use revisit_core::{LearnedFeatures, Roll};
use revisit_onnx::OnnxError;

/// A learned feature extractor chosen by name, and what it is given of each image.
pub struct LearnedExtractor {
    network: Network,
    input: LearnedInput,
}

enum Network {
    Aliked(Aliked),
    XFeat(XFeat),
}

impl LearnedExtractor {
    pub fn aliked(aliked: Aliked, input: LearnedInput) -> LearnedExtractor {
        LearnedExtractor { network: Network::Aliked(aliked), input }
    }

    pub fn xfeat(xfeat: XFeat, input: LearnedInput) -> LearnedExtractor {
        LearnedExtractor { network: Network::XFeat(xfeat), input }
    }

    /// Features of `image` (prepared as the input says) rolled by `roll`.
    pub fn extract(&mut self, image: &RgbImage, roll: Roll) -> Result<LearnedFeatures, OnnxError> {
        let prepared = self.input.prepare(image);
        let image = prepared.as_ref().unwrap_or(image);
        match &mut self.network {
            Network::Aliked(aliked) => aliked.extract(image, roll),
            Network::XFeat(xfeat) => xfeat.extract(image, roll),
        }
    }

    pub fn descriptor_dim(&self) -> usize {
        match self.network {
            Network::Aliked(_) => aliked::DESCRIPTOR_DIM,
            Network::XFeat(_) => xfeat::DESCRIPTOR_DIM,
        }
    }
}

fn shape_error(model: &revisit_onnx::Model, message: String) -> OnnxError {
    OnnxError::Run { path: model.path().to_path_buf(), message }
}
