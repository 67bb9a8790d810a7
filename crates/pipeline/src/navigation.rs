//! A visit's navigation from its CSV: per image, the position the vehicle's navigation gave (a
//! DVL-aided INS with a position fix, as `revisit synth` writes `nav/SESSION.csv`), stored as
//! COLMAP pose priors so that mapping pins each visit's scale and placement.

use std::path::Path;

use nalgebra::{Point3, Vector3};
use revisit_core::NavigationFix;

use crate::PipelineError;

/// The columns a navigation CSV holds, for help texts and errors.
pub const NAVIGATION_COLUMNS: &str = "image,x,y,z[,sigma_x,sigma_y,sigma_z]";

/// Parses a visit's navigation CSV (columns [`NAVIGATION_COLUMNS`] in any order, found by their
/// header, `image` being the file within session `session`; other columns are ignored); `source`
/// names the file in errors, with the row (1 = the header) and the column at fault.
pub fn parse_navigation_csv(text: &str, session: &str, source: &str) -> Result<Vec<NavigationFix>, PipelineError> {
    let bad = |row: usize, message: String| PipelineError::BadNavigation { file: source.to_owned(), row, message };
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let header = reader.headers().map_err(|e| bad(1, e.to_string()))?.clone();
    let column = |name: &str| header.iter().position(|h| h.trim() == name);
    let [image, x, y, z] = ["image", "x", "y", "z"].map(column);
    let (Some(image), Some(x), Some(y), Some(z)) = (image, x, y, z) else {
        return Err(bad(1, format!("expected the columns {NAVIGATION_COLUMNS}")));
    };
    let sigma = [column("sigma_x"), column("sigma_y"), column("sigma_z")];
    let mut fixes = Vec::new();
    for (k, record) in reader.records().enumerate() {
        let row = k + 2;
        let record = record.map_err(|e| bad(row, e.to_string()))?;
        let number = |i: usize| -> Result<f64, PipelineError> {
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
            [Some(sx), Some(sy), Some(sz)] => {
                let sigma = Vector3::new(number(sx)?, number(sy)?, number(sz)?);
                if sigma.iter().any(|s| *s <= 0.0) {
                    return Err(bad(row, format!("a standard deviation must be above 0 m, not {sigma:?}")));
                }
                Some(sigma)
            }
            _ => None,
        };
        fixes.push(NavigationFix {
            image: format!("{session}/{file}"),
            position_m: Point3::new(number(x)?, number(y)?, number(z)?),
            sigma_m,
        });
    }
    if fixes.is_empty() {
        return Err(bad(2, "no rows".to_owned()));
    }
    Ok(fixes)
}

/// Reads and parses the navigation CSV at `path` of session `session`.
pub fn read_navigation_csv(path: &Path, session: &str) -> Result<Vec<NavigationFix>, PipelineError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| PipelineError::Io { path: path.to_path_buf(), source })?;
    parse_navigation_csv(&text, session, &path.display().to_string())
}

/// Writes session `session`'s navigation to `path` as [`read_navigation_csv`] reads it back: each
/// fix's image as its file within the session, and the deviations when every fix has them.
pub fn write_navigation_csv(path: &Path, fixes: &[NavigationFix], session: &str) -> Result<(), PipelineError> {
    let io_error = |source: std::io::Error| PipelineError::Io { path: path.to_path_buf(), source };
    let with_sigma = fixes.iter().all(|fix| fix.sigma_m.is_some());
    let header = ["image", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z"];
    let partial = path.with_extension("partial");
    let mut writer = csv::Writer::from_path(&partial).map_err(|e| io_error(e.into()))?;
    writer.write_record(&header[..if with_sigma { 7 } else { 4 }]).map_err(|e| io_error(e.into()))?;
    for fix in fixes {
        let file = fix.image.strip_prefix(&format!("{session}/")).unwrap_or(&fix.image);
        let mut row = vec![file.to_owned()];
        row.extend(fix.position_m.iter().map(|v| format!("{v:?}")));
        if let (true, Some(sigma)) = (with_sigma, fix.sigma_m) {
            row.extend(sigma.iter().map(|v| format!("{v:?}")));
        }
        writer.write_record(&row).map_err(|e| io_error(e.into()))?;
    }
    writer.flush().map_err(io_error)?;
    drop(writer);
    // Written beside, then renamed: a killed run leaves no half file.
    std::fs::rename(&partial, path).map_err(io_error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_cell_names_its_row_and_column() {
        let text = "image,x,y,z\na.png,1,2,3\nb.png,1,nan,3\n";
        let error = parse_navigation_csv(text, "s1", "nav/s1.csv").unwrap_err().to_string();
        assert_eq!(error, "nav/s1.csv: row 3: \"nan\" is not a finite number (y)");
        let text = "image,x,y,z,sigma_x,sigma_y,sigma_z\na.png,1,2,3,0.1,0,0.1\n";
        let error = parse_navigation_csv(text, "s1", "nav/s1.csv").unwrap_err().to_string();
        assert!(error.starts_with("nav/s1.csv: row 2: a standard deviation must be above 0 m"), "{error}");
        let error = parse_navigation_csv("image,x,y\n", "s1", "f.csv").unwrap_err().to_string();
        assert_eq!(error, format!("f.csv: row 1: expected the columns {NAVIGATION_COLUMNS}"));
    }

    #[test]
    fn written_navigation_reads_back_the_same() {
        let fix = |file: &str, x: f64, sigma_m| NavigationFix {
            image: format!("s1/{file}"),
            position_m: Point3::new(x, -0.1 / 3.0, 1e-17),
            sigma_m,
        };
        let with_sigma = vec![
            fix("a,b.png", 1.0, Some(Vector3::new(0.1, 0.2, 0.3))),
            fix("c.png", 2.5, Some(Vector3::new(1.0, 1.0, 0.02))),
        ];
        let without = vec![fix("a.png", 1.0, Some(Vector3::new(0.1, 0.2, 0.3))), fix("c.png", 2.5, None)];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s1.csv");
        for fixes in [with_sigma, without] {
            write_navigation_csv(&path, &fixes, "s1").unwrap();
            let text = std::fs::read_to_string(&path).unwrap();
            let read = read_navigation_csv(&path, "s1").unwrap();
            let expected: Vec<_> = match fixes.iter().all(|f| f.sigma_m.is_some()) {
                true => fixes,
                false => fixes.into_iter().map(|f| NavigationFix { sigma_m: None, ..f }).collect(),
            };
            assert_eq!(read, expected, "{text}");
        }
    }

    #[test]
    fn columns_are_found_by_their_header() {
        let fixes = parse_navigation_csv("yaw,image,z,y,x\n90,a.png,3,2,1\n", "s1", "f").unwrap();
        assert_eq!((fixes[0].image.as_str(), fixes[0].position_m), ("s1/a.png", Point3::new(1.0, 2.0, 3.0)));
        assert_eq!(fixes[0].sigma_m, None);
    }
}
