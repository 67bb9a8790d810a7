//! The similarity that places a visit's model on its navigation.

use std::collections::BTreeMap;

use nalgebra::Point3;
use revisit_core::{umeyama, NavigationFix, Reconstruction, Similarity};

/// The similarity taking `model` onto the navigation (its registered
/// cameras' centres onto their navigation positions, least squares), and the
/// RMS distance left between them, metres; or why there is none.
pub fn fit_to_navigation(model: &Reconstruction, navigation: &[NavigationFix]) -> Result<(Similarity, f64), String> {
    let positions: BTreeMap<&str, &Point3<f64>> =
        navigation.iter().map(|f| (f.image.as_str(), &f.position_m)).collect();
    let (centres, fixes): (Vec<Point3<f64>>, Vec<Point3<f64>>) = model
        .images
        .values()
        .filter_map(|image| Some((image.cam_from_world.origin_of_target(), **positions.get(image.name.as_str())?)))
        .unzip();
    let nav_from_model =
        umeyama(&centres, &fixes).map_err(|e| format!("{} registered images with navigation: {e}", centres.len()))?;
    let squared: f64 = centres.iter().zip(&fixes).map(|(c, f)| (nav_from_model.apply(c) - f).norm_squared()).sum();
    Ok((nav_from_model, (squared / centres.len() as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};
    use revisit_core::{Image, Rigid3};

    use super::*;

    #[test]
    fn cameras_fit_onto_their_navigation() {
        let truth = Similarity {
            scale: 0.3,
            rotation: UnitQuaternion::from_euler_angles(0.1, 0.2, 2.0),
            translation: Vector3::new(10.0, -4.0, 2.0),
        };
        let mut model = Reconstruction::default();
        let mut navigation = Vec::new();
        for (k, centre) in [[0.0, 0.0, 0.0], [4.0, 0.0, 0.1], [4.0, 3.0, 0.0], [0.0, 3.0, -0.2]].iter().enumerate() {
            let centre = Point3::from(*centre);
            let name = format!("s1/{k}.png");
            let cam_from_world = Rigid3::new(UnitQuaternion::identity(), -centre.coords);
            let image_id = k as u32 + 1;
            model.images.insert(
                image_id,
                Image { image_id, camera_id: 1, name: name.clone(), cam_from_world, points2d: vec![] },
            );
            navigation.push(NavigationFix { image: name, position_m: truth.apply(&centre), sigma_m: None });
        }
        let (fitted, rms) = fit_to_navigation(&model, &navigation).unwrap();
        assert!((fitted.scale - 0.3).abs() < 1e-9 && rms < 1e-9);
        assert!(fit_to_navigation(&model, &navigation[..2]).unwrap_err().contains("2 registered images"));
    }
}
