//! A binary little-endian PLY of a model's points, for Open3D, MeshLab and
//! CloudCompare.

use std::collections::BTreeMap;

use revisit_core::{session_of, Reconstruction};

/// How [`encode_ply`] colours the points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlyColors {
    /// The points' own colours (COLMAP's `rgb`).
    #[default]
    Rgb,
    /// One colour per session (see [`session_palette`]): the session of the
    /// first image in each point's track.
    BySession,
}

/// The session colours, in order (Tableau 10), repeated when there are more
/// sessions than colours.
pub const SESSION_PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// Colour of points whose track names no image of the model.
const NO_SESSION_RGB: [u8; 3] = [0, 0, 0];

/// Each session of the model's images (the image-name prefix before `/`, or
/// `""` for names without one) with its colour, sorted by session name.
pub fn session_palette(model: &Reconstruction) -> Vec<(String, [u8; 3])> {
    let mut sessions: Vec<&str> = model.images.values().map(|image| session_of(&image.name)).collect();
    sessions.sort_unstable();
    sessions.dedup();
    sessions.into_iter().zip(SESSION_PALETTE.iter().cycle()).map(|(session, rgb)| (session.to_owned(), *rgb)).collect()
}

/// The model's points as a binary little-endian PLY: `double x, y, z` and
/// `uchar red, green, blue` per vertex, in point-id order.
pub fn encode_ply(model: &Reconstruction, colors: PlyColors) -> Vec<u8> {
    let palette: BTreeMap<String, [u8; 3]> = session_palette(model).into_iter().collect();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment Revisit sparse points\nelement vertex {}\n\
         property double x\nproperty double y\nproperty double z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        model.points3d.len()
    );
    let mut out = Vec::with_capacity(header.len() + model.points3d.len() * 27);
    out.extend_from_slice(header.as_bytes());
    for point in model.points3d.values() {
        for value in point.xyz.coords.iter() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        let rgb = match colors {
            PlyColors::Rgb => point.rgb,
            PlyColors::BySession => point
                .track
                .first()
                .and_then(|element| model.images.get(&element.image_id))
                .and_then(|image| palette.get(session_of(&image.name)))
                .copied()
                .unwrap_or(NO_SESSION_RGB),
        };
        out.extend_from_slice(&rgb);
    }
    out
}
