//! Round trips and error reports of the COLMAP model codecs.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers outside #[test] fns

mod common;

use revisit_colmap::model::*;
use revisit_colmap::{read_model, read_models, write_binary, write_ply, write_text};

use common::sample_model;

#[test]
fn binary_round_trip_is_byte_identical() {
    let model = sample_model();
    let cameras = encode_cameras_bin(&model.cameras);
    let images = encode_images_bin(&model.images).unwrap();
    let points = encode_points3d_bin(&model.points3d);
    let decoded = revisit_core::Reconstruction {
        cameras: decode_cameras_bin(&cameras).unwrap(),
        images: decode_images_bin(&images).unwrap(),
        points3d: decode_points3d_bin(&points).unwrap(),
    };
    assert_eq!(decoded, model);
    assert_eq!(encode_cameras_bin(&decoded.cameras), cameras);
    assert_eq!(encode_images_bin(&decoded.images).unwrap(), images);
    assert_eq!(encode_points3d_bin(&decoded.points3d), points);
}

#[test]
fn binary_layout_matches_colmap() {
    let model = sample_model();
    let cameras = encode_cameras_bin(&model.cameras);
    // count u64, then id u32, model i32, width u64, height u64, params f64[]
    assert_eq!(cameras.len(), 8 + (24 + 4 * 8) + (24 + 8 * 8));
    assert_eq!(&cameras[..8], &2u64.to_le_bytes());
    assert_eq!(&cameras[8..12], &1u32.to_le_bytes());
    assert_eq!(&cameras[12..16], &2i32.to_le_bytes()); // SIMPLE_RADIAL
    assert_eq!(&cameras[16..24], &640u64.to_le_bytes());
    let images = encode_images_bin(&model.images).unwrap();
    // first image: id, 7 doubles, camera id, "2019/a.png\0", num points2D
    let name_at = 8 + 4 + 56 + 4;
    assert_eq!(&images[name_at..name_at + 11], b"2019/a.png\0");
    let num_points_at = name_at + 11;
    let n = model.images[&1].points2d.len() as u64;
    assert_eq!(&images[num_points_at..num_points_at + 8], &n.to_le_bytes());
    // the first three observations are untriangulated: id u64::MAX
    let id_at = num_points_at + 8 + 16;
    assert_eq!(&images[id_at..id_at + 8], &u64::MAX.to_le_bytes());
}

#[test]
fn text_round_trip_is_exact() {
    let model = sample_model();
    let cameras = encode_cameras_txt(&model.cameras);
    let images = encode_images_txt(&model.images).unwrap();
    let points = encode_points3d_txt(&model.points3d);
    assert!(cameras.starts_with("# Camera list with one line of data per camera:\n"));
    assert!(cameras.contains("# Number of cameras: 2\n1 SIMPLE_RADIAL 640 480 "), "{cameras}");
    assert!(cameras.contains(" 1e-300 0\n"), "{cameras}");
    assert!(images.contains("# Number of images: 4, mean observations per image: "), "{images}");
    assert!(points.contains("# Number of points: 12, mean track length: 3\n"), "{points}");
    let decoded = revisit_core::Reconstruction {
        cameras: decode_cameras_txt(&cameras).unwrap(),
        images: decode_images_txt(&images).unwrap(),
        points3d: decode_points3d_txt(&points).unwrap(),
    };
    assert_eq!(decoded, model);
    assert_eq!(encode_images_txt(&decoded.images).unwrap(), images);
}

#[test]
fn text_reads_crlf_and_empty_point_lines() {
    let text = "# header\r\n1 1 0 0 0 0.5 0.25 3 7 s/x.png\r\n\r\n2 1 0 0 0 0 0 1 7 s/y.png\r\n10.5 2 -1 3 4 42\r\n";
    let images = decode_images_txt(text).unwrap();
    assert_eq!(images.len(), 2);
    assert!(images[&1].points2d.is_empty());
    assert_eq!(images[&2].points2d[0].point3d_id, None);
    assert_eq!(images[&2].points2d[1].point3d_id, Some(42));
    assert_eq!(images[&2].name, "s/y.png");
}

#[test]
fn files_round_trip_and_binary_equals_text() {
    let model = sample_model();
    let dir = tempfile::tempdir().unwrap();
    let (bin_dir, txt_dir) = (dir.path().join("bin"), dir.path().join("txt"));
    write_binary(&model, &bin_dir).unwrap();
    write_text(&model, &txt_dir).unwrap();
    assert_eq!(detect_format(&bin_dir), Some(ModelFormat::Binary));
    assert_eq!(detect_format(&txt_dir), Some(ModelFormat::Text));
    let from_bin = read_model(&bin_dir).unwrap();
    let from_txt = read_model(&txt_dir).unwrap();
    assert_eq!(from_bin, model);
    assert_eq!(from_txt, model);
    // Re-writing what was read gives the same bytes; no temporary files remain.
    let again = dir.path().join("again");
    write_binary(&from_txt, &again).unwrap();
    for file in ["cameras.bin", "images.bin", "points3D.bin"] {
        assert_eq!(std::fs::read(bin_dir.join(file)).unwrap(), std::fs::read(again.join(file)).unwrap(), "{file}");
    }
    let mut names: Vec<String> =
        std::fs::read_dir(&again).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["cameras.bin", "images.bin", "points3D.bin"]);
}

#[test]
fn numbered_sub_models_are_read_in_order() {
    let model = sample_model();
    let dir = tempfile::tempdir().unwrap();
    for sub in ["10", "2", "0"] {
        write_binary(&model, &dir.path().join(sub)).unwrap();
    }
    std::fs::create_dir(dir.path().join("notes")).unwrap();
    let models = read_models(dir.path()).unwrap();
    let subs: Vec<String> = models.iter().map(|(p, _)| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(subs, ["0", "2", "10"]);
    assert_eq!(read_models(&dir.path().join("2")).unwrap().len(), 1);
    let err = read_models(&dir.path().join("notes")).unwrap_err();
    assert!(matches!(err, ColmapError::NoModel { .. }), "{err}");
}

#[test]
fn truncated_binary_names_file_and_record() {
    let model = sample_model();
    let dir = tempfile::tempdir().unwrap();
    write_binary(&model, dir.path()).unwrap();
    let images_path = dir.path().join("images.bin");
    let bytes = std::fs::read(&images_path).unwrap();
    // Every prefix fails cleanly (no panic); cutting inside the second image names record 2.
    for len in 0..bytes.len() {
        assert!(decode_images_bin(&bytes[..len]).is_err(), "prefix of {len} bytes decoded");
    }
    let first_len = 8 + 4 + 56 + 4 + 11 + 8 + 24 * model.images[&1].points2d.len();
    std::fs::write(&images_path, &bytes[..first_len + 10]).unwrap();
    let err = read_model(dir.path()).unwrap_err();
    assert!(matches!(&err, ColmapError::Truncated { record: 2, .. }), "{err:?}");
    let message = err.to_string();
    assert!(message.contains("images.bin") && message.contains("record 2"), "{message}");
    // Trailing garbage is reported, not ignored.
    let mut long = bytes.clone();
    long.push(0);
    assert!(decode_images_bin(&long).unwrap_err().to_string().contains("1 bytes after the last record"));
}

#[test]
fn bad_text_line_is_named() {
    let text = "# c\n1 PINHOLE 640 480 500 500 320 240\n2 PINHOLE 640 480 500 500 320\n";
    let err = decode_cameras_txt(text).unwrap_err();
    assert_eq!(err.to_string(), "cameras.txt: line 3: camera model PINHOLE takes 4 parameters, got 3");
    let err = decode_points3d_txt("7 0 0 zero 1 2 3 0.5 1 0\n").unwrap_err();
    assert_eq!(err.to_string(), "points3D.txt: line 1: Z \"zero\" is not a valid number");
    let dir = tempfile::tempdir().unwrap();
    write_text(&sample_model(), dir.path()).unwrap();
    std::fs::write(dir.path().join("images.txt"), "1 1 0 0 0 0 0 0 1 a/b.png\n1.0 2.0\n").unwrap();
    let err = read_model(dir.path()).unwrap_err().to_string();
    assert!(err.contains("images.txt: line 2:") && err.contains("not triples"), "{err}");
}

#[test]
fn names_text_cannot_hold_are_refused() {
    let mut model = sample_model();
    model.images.get_mut(&1).unwrap().name = " lead/space.png".into();
    let err = encode_images_txt(&model.images).unwrap_err().to_string();
    assert!(err.contains("image 1") && err.contains("whitespace"), "{err}");
    assert!(encode_images_bin(&model.images).is_ok());
    model.images.get_mut(&1).unwrap().name = "nul\0.png".into();
    assert!(encode_images_bin(&model.images).is_err());
}

#[test]
fn ply_holds_every_point_with_session_colours() {
    let model = sample_model();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out/points.ply");
    write_ply(&model, &path, PlyColors::BySession).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&bytes[..header_end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(header.contains("element vertex 12\n"));
    assert_eq!(bytes.len() - header_end, 12 * (3 * 8 + 3));
    let palette = session_palette(&model);
    assert_eq!(palette, vec![("2019".to_owned(), SESSION_PALETTE[0]), ("2024".to_owned(), SESSION_PALETTE[1])]);
    for (k, point) in model.points3d.values().enumerate() {
        let record = &bytes[header_end + k * 27..header_end + (k + 1) * 27];
        let x = f64::from_le_bytes(record[..8].try_into().unwrap());
        assert_eq!(x, point.xyz.x);
        let session = model.images[&point.track[0].image_id].name.split('/').next().unwrap();
        let expected = if session == "2019" { SESSION_PALETTE[0] } else { SESSION_PALETTE[1] };
        assert_eq!(&record[24..], &expected);
    }
    let rgb = encode_ply(&model, PlyColors::Rgb);
    let first = model.points3d.values().next().unwrap();
    assert_eq!(&rgb[header_end + 24..header_end + 27], &first.rgb);
}
