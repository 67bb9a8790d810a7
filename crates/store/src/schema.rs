//! COLMAP 3.8's database schema, verbatim in meaning, COLMAP 4's `pose_priors`
//! (as pycolmap 4.2 makes it, so that it finds the table its own), plus
//! Revisit's tables (prefixed `revisit_`, which COLMAP ignores).

pub const SCHEMA: &str = "
PRAGMA foreign_keys = ON;
PRAGMA synchronous = NORMAL;
CREATE TABLE IF NOT EXISTS cameras (
    camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL,
    model INTEGER NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    params BLOB,
    prior_focal_length INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS images (
    image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL,
    name TEXT NOT NULL UNIQUE,
    camera_id INTEGER NOT NULL,
    prior_qw REAL, prior_qx REAL, prior_qy REAL, prior_qz REAL,
    prior_tx REAL, prior_ty REAL, prior_tz REAL,
    CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),
    FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX IF NOT EXISTS index_name ON images(name);
CREATE TABLE IF NOT EXISTS keypoints (
    image_id INTEGER PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB,
    FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS descriptors (
    image_id INTEGER PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB,
    FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS matches (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB);
CREATE TABLE IF NOT EXISTS two_view_geometries (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB,
    config INTEGER NOT NULL,
    F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
CREATE TABLE IF NOT EXISTS pose_priors (
    pose_prior_id INTEGER PRIMARY KEY NOT NULL,
    corr_data_id INTEGER NOT NULL,
    corr_sensor_id INTEGER NOT NULL,
    corr_sensor_type INTEGER NOT NULL,
    position BLOB,
    position_covariance BLOB,
    gravity BLOB,
    coordinate_system INTEGER NOT NULL);
CREATE UNIQUE INDEX IF NOT EXISTS pose_prior_data_assignment ON
    pose_priors(corr_data_id, corr_sensor_id, corr_sensor_type);

CREATE TABLE IF NOT EXISTS revisit_settings (
    key TEXT PRIMARY KEY NOT NULL,
    value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS revisit_sessions (
    name TEXT PRIMARY KEY NOT NULL,
    source TEXT NOT NULL,
    visit INTEGER NOT NULL UNIQUE);
CREATE TABLE IF NOT EXISTS revisit_cameras (
    name TEXT PRIMARY KEY NOT NULL,
    camera_id INTEGER NOT NULL UNIQUE REFERENCES cameras(camera_id));
CREATE TABLE IF NOT EXISTS revisit_pairs (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    image_id1 INTEGER NOT NULL,
    image_id2 INTEGER NOT NULL,
    kind TEXT NOT NULL,
    method TEXT NOT NULL,
    roll_deg INTEGER NOT NULL,
    num_matches INTEGER NOT NULL,
    num_inliers INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS revisit_roll_predictions (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    predicted_roll_deg INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS revisit_confident_geometries (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB,
    config INTEGER NOT NULL,
    F BLOB,
    E BLOB,
    H BLOB,
    qvec BLOB,
    tvec BLOB,
    in_use INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS revisit_set_aside (
    pair_id INTEGER PRIMARY KEY NOT NULL,
    reason TEXT NOT NULL,
    rows INTEGER NOT NULL,
    cols INTEGER NOT NULL,
    data BLOB,
    config INTEGER NOT NULL,
    F BLOB,
    E BLOB,
    H BLOB,
    qvec BLOB,
    tvec BLOB);
CREATE TABLE IF NOT EXISTS revisit_learned_features (
    image_id INTEGER NOT NULL REFERENCES images(image_id) ON DELETE CASCADE,
    method TEXT NOT NULL,
    roll_deg INTEGER NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    rows INTEGER NOT NULL,
    dim INTEGER NOT NULL,
    keypoints BLOB NOT NULL,
    descriptors BLOB NOT NULL,
    scores BLOB NOT NULL,
    PRIMARY KEY (image_id, method, roll_deg));
CREATE TABLE IF NOT EXISTS revisit_cross_keypoints (
    image_id INTEGER NOT NULL REFERENCES images(image_id) ON DELETE CASCADE,
    method TEXT NOT NULL,
    roll_deg INTEGER NOT NULL,
    learned_index INTEGER NOT NULL,
    keypoint_index INTEGER NOT NULL,
    PRIMARY KEY (image_id, method, roll_deg, learned_index));
CREATE TABLE IF NOT EXISTS revisit_global_descriptors (
    image_id INTEGER NOT NULL REFERENCES images(image_id) ON DELETE CASCADE,
    method TEXT NOT NULL,
    roll_deg INTEGER NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (image_id, method, roll_deg));
CREATE TABLE IF NOT EXISTS revisit_vocabularies (
    name TEXT PRIMARY KEY NOT NULL,
    rows INTEGER NOT NULL,
    dim INTEGER NOT NULL,
    data BLOB NOT NULL);
";
