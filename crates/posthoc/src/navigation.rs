//! A vehicle's navigation: per image, where the camera was (a DVL-aided INS
//! with a position fix), and the similarity that places a visit's model on it.

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};
use revisit_core::{umeyama, Reconstruction, Similarity};

use crate::PosthocError;

/// One image's navigation position, metres in the navigation frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NavigationFix {
    /// `session/file`.
    pub image: String,
    pub position_m: Point3<f64>,
    /// Standard deviation per axis, metres, when the file gives it.
    pub sigma_m: Option<Vector3<f64>>,
}

/// A visit's navigation CSV (`image,x,y,z[,sigma_x,sigma_y,sigma_z]`, image
/// being the file within the session, as `revisit synth` writes
/// `nav/SESSION.csv`); `source` names the file in errors.
pub fn parse_navigation_csv(text: &str, session: &str, source: &str) -> Result<Vec<NavigationFix>, PosthocError> {
    let bad =
        |row: usize, message: String| PosthocError::BadNavigation { source_name: source.to_owned(), row, message };
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let header = reader.headers().map_err(|e| bad(1, e.to_string()))?.clone();
    let column = |name: &str| header.iter().position(|h| h.trim() == name);
    let [image, x, y, z] = ["image", "x", "y", "z"].map(column);
    let (Some(image), Some(x), Some(y), Some(z)) = (image, x, y, z) else {
        return Err(bad(1, "expected the columns image,x,y,z[,sigma_x,sigma_y,sigma_z]".to_owned()));
    };
    let sigma = [column("sigma_x"), column("sigma_y"), column("sigma_z")];
    let mut fixes = Vec::new();
    for (k, record) in reader.records().enumerate() {
        let row = k + 2;
        let record = record.map_err(|e| bad(row, e.to_string()))?;
        let number = |i: usize| -> Result<f64, PosthocError> {
            let cell = record.get(i).unwrap_or_default().trim();
            cell.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(row, format!("{:?} is not a finite number ({})", cell, &header[i])))
        };
        let file = record.get(image).unwrap_or_default().trim();
        if file.is_empty() {
            return Err(bad(row, "no image name".to_owned()));
        }
        let sigma_m = match sigma {
            [Some(sx), Some(sy), Some(sz)] => Some(Vector3::new(number(sx)?, number(sy)?, number(sz)?)),
            _ => None,
        };
        fixes.push(NavigationFix {
            image: format!("{session}/{file}"),
            position_m: Point3::new(number(x)?, number(y)?, number(z)?),
            sigma_m,
        });
    }
    Ok(fixes)
}

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
    use nalgebra::UnitQuaternion;
    use revisit_core::{Image, Rigid3};

    use super::*;

    #[test]
    fn a_bad_cell_names_its_row_and_column() {
        let text = "image,x,y,z\na.png,1,2,3\nb.png,1,nan,3\n";
        let error = parse_navigation_csv(text, "s1", "nav/s1.csv").unwrap_err().to_string();
        assert_eq!(error, "nav/s1.csv: row 3: \"nan\" is not a finite number (y)");
        let fixes = parse_navigation_csv("image,z,y,x\na.png,3,2,1\n", "s1", "f").unwrap();
        assert_eq!((fixes[0].image.as_str(), fixes[0].position_m), ("s1/a.png", Point3::new(1.0, 2.0, 3.0)));
    }

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
