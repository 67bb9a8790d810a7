//! Survey planning: the site, one lawnmower trajectory per session, cameras and
//! appearance, and lazy per-session scenes for rendering.

use std::sync::OnceLock;

use nalgebra::{Matrix3, Point2, Point3, Rotation3, UnitQuaternion, Vector3};
use serde::Serialize;

use revisit_core::{Camera, CameraId, CameraModel, Image, ImageId, Reconstruction, Rigid3};

use crate::noise::SplitMix64;
use crate::render::{self, sun_dir, Appearance, Rendered, View};
use crate::scene::{self, ObjectState, Seabed, SessionScene, Site};
use crate::{ChangeGrade, SynthError, SynthOptions};

/// Focal length as a share of the image width (about 64 degrees horizontal FOV).
const FOCAL_PER_WIDTH: f64 = 0.8;
/// Altitude used to size the surveyed area, metres.
const NOMINAL_ALTITUDE_M: f64 = 2.0;
/// Target overlap of consecutive images and of adjacent lines.
const ALONG_OVERLAP: f64 = 0.7;
const SIDE_OVERLAP: f64 = 0.4;
/// Seconds between consecutive images (drives caustic animation).
const FRAME_INTERVAL_S: f64 = 1.0;

/// One image of the survey and its true pose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageTruth {
    /// COLMAP image id in the truth model (1-based, session after session).
    pub image_id: ImageId,
    /// Index of the session in [`Survey::sessions`].
    pub session: usize,
    /// File name within the session folder, e.g. `s1_0000.png`.
    pub file: String,
    /// COLMAP image name `session/file`.
    pub name: String,
    pub cam_from_world: Rigid3,
    /// Capture time, seconds since the start of the session.
    pub time_s: f64,
}

/// One visit: its camera, trajectory parameters, water and images.
#[derive(Clone, Debug, Serialize)]
pub struct SessionPlan {
    /// Session name: `s1`, `s2`, ...
    pub name: String,
    pub camera: Camera,
    /// Nominal altitude above the seabed, metres.
    pub altitude_m: f64,
    /// Direction of the survey lines and of the image's "up", degrees
    /// counter-clockwise from east.
    pub heading_deg: f64,
    /// Offset of the survey pattern from the site centre, metres.
    pub offset_m: [f64; 2],
    /// Number of survey lines.
    pub lines: usize,
    pub appearance: Appearance,
    pub images: Vec<ImageTruth>,
}

/// Intrinsics of one session's camera, for `intrinsics.json`.
#[derive(Clone, Debug, Serialize)]
pub struct SessionIntrinsics {
    pub session: String,
    pub camera_id: CameraId,
    pub model: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Parameters in COLMAP's order for the model.
    pub params: Vec<f64>,
}

/// A planned survey: the reef, its change over sessions and the trajectories.
/// Scenes (textures) are built lazily per session and kept.
pub struct Survey {
    options: SynthOptions,
    site: Site,
    sessions: Vec<SessionPlan>,
    /// Structures per session.
    objects: Vec<Vec<ObjectState>>,
    /// Which scene slot a session renders with (sessions with identical
    /// structures share one).
    scene_slot: Vec<usize>,
    /// Seed of each session's centimetre-scale seabed texture: the site's for
    /// every session unless the grade moves sediment between visits.
    sediment: Vec<u32>,
    /// The seabed of each scene slot.
    seabeds: Vec<OnceLock<Seabed>>,
    scenes: Vec<OnceLock<SessionScene>>,
    /// (session, index within session) of each image, in image order.
    index: Vec<(usize, usize)>,
}

impl std::fmt::Debug for Survey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Survey")
            .field("options", &self.options)
            .field("site_half_m", &self.site.half_m)
            .field("sessions", &self.sessions.len())
            .finish_non_exhaustive()
    }
}

/// Side of the square area the camera centres cover, so that `images` images at
/// `altitude_m` overlap by the target fractions.
fn region_side_m(images: usize, footprint_w: f64, footprint_h: f64) -> f64 {
    // (R / a + 1) (R / b + 1) = images, with a, b the along/side spacings.
    let a = (1.0 - ALONG_OVERLAP) * footprint_h;
    let b = (1.0 - SIDE_OVERLAP) * footprint_w;
    let (qa, qb, qc) = (1.0 / (a * b), 1.0 / a + 1.0 / b, 1.0 - images as f64);
    let disc = (qb * qb - 4.0 * qa * qc).max(0.0);
    ((-qb + disc.sqrt()) / (2.0 * qa)).max(0.3)
}

/// Number of lines that best balances along- and across-track overlap.
fn choose_lines(images: usize, region_m: f64, footprint_w: f64, footprint_h: f64) -> usize {
    let mut best = (f64::NEG_INFINITY, 1);
    for lines in 1..=(images / 2).max(1) {
        let per_line = images / lines;
        if per_line < 2 {
            break;
        }
        let side = if lines > 1 { 1.0 - region_m / (lines - 1) as f64 / footprint_w } else { 0.0 };
        let along = 1.0 - region_m / (per_line - 1) as f64 / footprint_h;
        let score =
            if lines > 1 { (side / SIDE_OVERLAP).min(along / ALONG_OVERLAP) } else { along / ALONG_OVERLAP - 1.0 };
        if score > best.0 {
            best = (score, lines);
        }
    }
    best.1
}

fn appearance(grade: ChangeGrade, rng: &mut SplitMix64) -> Appearance {
    let mut look = Appearance::nominal();
    let (level, elevation, azimuth_spread, attenuation, backscatter, green, caustics, blur, noise) = match grade {
        ChangeGrade::None => return look,
        ChangeGrade::Mild => {
            ((0.85, 1.15), (55.0, 80.0), 40.0, (0.85, 1.2), (0.8, 1.3), 0.3, (0.1, 0.3), (0.0, 0.5), (1.0, 2.5))
        }
        ChangeGrade::Strong => {
            ((0.65, 1.25), (45.0, 85.0), 180.0, (0.7, 1.7), (0.8, 2.0), 0.7, (0.2, 0.6), (0.3, 1.0), (2.0, 4.0))
        }
        ChangeGrade::Storm => {
            ((0.6, 0.95), (45.0, 85.0), 180.0, (1.3, 2.2), (1.8, 3.0), 0.8, (0.0, 0.3), (0.5, 1.2), (2.0, 4.0))
        }
    };
    let base_azimuth = 30.0;
    look.light_level = rng.range(level.0, level.1) as f32;
    look.light_dir =
        sun_dir(rng.range(elevation.0, elevation.1), base_azimuth + rng.range(-azimuth_spread, azimuth_spread));
    let a = rng.range(attenuation.0, attenuation.1) as f32;
    let red_shift = rng.range(0.9, 1.2) as f32;
    look.attenuation_per_m = [
        look.attenuation_per_m[0] * a * red_shift,
        look.attenuation_per_m[1] * a,
        look.attenuation_per_m[2] * a * rng.range(0.9, 1.3) as f32,
    ];
    look.backscatter_per_m *= rng.range(backscatter.0, backscatter.1) as f32;
    let g = rng.range(0.0, green) as f32;
    let greenish = [0.12, 0.34, 0.24];
    look.backscatter_rgb = crate::noise::lerp3(look.backscatter_rgb, greenish, g);
    look.light_rgb = crate::noise::lerp3(look.light_rgb, [0.6, 0.9, 0.7], 0.6 * g);
    look.caustics = rng.range(caustics.0, caustics.1) as f32;
    look.caustic_scale_m = rng.range(0.25, 0.5) as f32;
    look.blur_px = rng.range(blur.0, blur.1) as f32;
    look.noise_sigma = rng.range(noise.0, noise.1) as f32;
    look
}

/// world_from_cam rotation of a downward camera whose image "up" points along
/// `heading_rad`, perturbed by small roll, pitch and yaw (camera frame).
fn downward_rotation(heading_rad: f64, roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
    let (s, c) = heading_rad.sin_cos();
    let x_cam = Vector3::new(s, -c, 0.0);
    let y_cam = Vector3::new(-c, -s, 0.0);
    let z_cam = Vector3::new(0.0, 0.0, -1.0);
    let base = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x_cam, y_cam, z_cam]));
    let jitter = Rotation3::from_euler_angles(roll, pitch, yaw);
    UnitQuaternion::from_rotation_matrix(&(base * jitter))
}

/// Plans the survey: site, structures per session, trajectories, cameras and
/// water. Cheap: textures are built on first render of a session.
pub fn plan(options: &SynthOptions) -> Result<Survey, SynthError> {
    options.check()?;
    let (w, h) = (f64::from(options.width), f64::from(options.height));
    let focal_px = FOCAL_PER_WIDTH * w;
    let footprint = |altitude: f64| (altitude * w / focal_px, altitude * h / focal_px);
    let (nominal_w, nominal_h) = footprint(NOMINAL_ALTITUDE_M);
    let n = options.images_per_session;
    let region_m = region_side_m(n, nominal_w, nominal_h);

    let mut rng = SplitMix64::stream(options.seed, 0x5E55);
    let first_heading = rng.range(0.0, 360.0);
    struct Track {
        altitude_m: f64,
        heading_deg: f64,
        offset_m: [f64; 2],
    }
    let tracks: Vec<Track> = (0..options.sessions)
        .map(|s| {
            let altitude_m = if s == 0 { rng.range(1.8, 2.2) } else { rng.range(1.6, 2.6) };
            // Repeated surveys of a site follow its survey plan's axes: each
            // visit turns a quarter further (s2 ~90, s3 ~180, s4 ~270
            // degrees from s1), give or take 8 degrees.
            let heading_deg = match s {
                0 => first_heading,
                _ => first_heading + 90.0 * s as f64 + rng.range(-8.0, 8.0),
            }
            .rem_euclid(360.0);
            let offset_m = [rng.range(-0.3, 0.3), rng.range(-0.3, 0.3)];
            Track { altitude_m, heading_deg, offset_m }
        })
        .collect();
    // The site reaches beyond the widest view of the outermost camera.
    let tilt_margin = 6f64.to_radians().tan();
    let half_m = tracks
        .iter()
        .map(|t| {
            let (fw, fh) = footprint(t.altitude_m + 0.3);
            let diag = 0.5 * (fw * fw + fh * fh).sqrt();
            0.5 * region_m * std::f64::consts::SQRT_2
                + t.offset_m[0].abs().max(t.offset_m[1].abs())
                + diag
                + t.altitude_m * tilt_margin
        })
        .fold(0.0, f64::max)
        + 0.3;
    let site = Site::new(half_m, (options.seed ^ (options.seed >> 32)) as u32 ^ 0x00C0_FFEE);

    let mut sessions = Vec::with_capacity(options.sessions);
    let mut index = Vec::new();
    for (s, track) in tracks.iter().enumerate() {
        let name = format!("s{}", s + 1);
        let camera_id = (s + 1) as CameraId;
        let camera = Camera::new(
            camera_id,
            CameraModel::Pinhole,
            options.width,
            options.height,
            vec![focal_px, focal_px, w / 2.0, h / 2.0],
        )
        .map_err(|source| SynthError::Camera { session: name.clone(), source })?;
        let mut srng = SplitMix64::stream(options.seed, 0x1000 + s as u64);
        let look = appearance(options.change, &mut srng);
        let (fw, fh) = footprint(track.altitude_m);
        let lines = choose_lines(n, region_m, fw, fh);
        let heading = track.heading_deg.to_radians();
        let along = Vector3::new(heading.cos(), heading.sin(), 0.0);
        let across = Vector3::new(-heading.sin(), heading.cos(), 0.0);
        let mut images = Vec::with_capacity(n);
        let mut poses = Vec::with_capacity(n);
        for line in 0..lines {
            let per_line = n / lines + usize::from(line < n % lines);
            let cross = if lines > 1 { -0.5 * region_m + region_m * line as f64 / (lines - 1) as f64 } else { 0.0 };
            for k in 0..per_line {
                let step = if per_line > 1 { region_m / (per_line - 1) as f64 } else { 0.0 };
                let k_dir = if line % 2 == 0 { k } else { per_line - 1 - k };
                let a = -0.5 * region_m + step * k_dir as f64;
                let jitter = Vector3::new(0.03 * srng.normal(), 0.03 * srng.normal(), 0.0);
                let xy = Vector3::new(track.offset_m[0], track.offset_m[1], 0.0) + along * a + across * cross + jitter;
                let ground = f64::from(site.seabed_height(xy.x as f32, xy.y as f32));
                let z = ground + track.altitude_m + 0.04 * srng.normal();
                let centre = Vector3::new(xy.x, xy.y, z);
                let attitude = 1.5f64.to_radians();
                let world_from_cam_rot = downward_rotation(
                    heading,
                    (attitude * srng.normal()).clamp(-0.07, 0.07),
                    (attitude * srng.normal()).clamp(-0.07, 0.07),
                    (attitude * srng.normal()).clamp(-0.07, 0.07),
                );
                poses.push(Rigid3::new(world_from_cam_rot, centre));
            }
        }
        // Video: each step between planned positions subdivided along the track.
        let steps = options.frames_per_step.max(1);
        let mut frames = Vec::with_capacity(poses.len() * steps);
        for pair in poses.windows(2) {
            for k in 0..steps {
                let f = k as f64 / steps as f64;
                let rotation = pair[0].rotation.slerp(&pair[1].rotation, f);
                frames.push(Rigid3 { rotation, translation: pair[0].translation.lerp(&pair[1].translation, f) });
            }
        }
        frames.extend(poses.last().copied());
        for world_from_cam in frames {
            let i = images.len();
            let file = format!("{name}_{i:04}.png");
            images.push(ImageTruth {
                image_id: (index.len() + 1) as ImageId,
                session: s,
                name: revisit_core::image_name(&name, &file),
                file,
                cam_from_world: world_from_cam.inverse(),
                time_s: i as f64 * FRAME_INTERVAL_S / steps as f64,
            });
            index.push((s, i));
        }
        sessions.push(SessionPlan {
            name,
            camera,
            altitude_m: track.altitude_m,
            heading_deg: track.heading_deg,
            offset_m: track.offset_m,
            lines,
            appearance: look,
            images,
        });
    }

    let mut objects = vec![scene::initial_objects(&site, options.seed, options.cover)];
    for s in 1..options.sessions {
        let previous = objects.last().map(Vec::as_slice).unwrap_or(&[]);
        let next = scene::evolve(&site, previous, options.change, options.growth.as_ref(), options.seed, s);
        objects.push(next);
    }
    let count = objects.iter().flatten().map(|o| o.id).max().unwrap_or(0) as usize;
    if count >= usize::from(u16::MAX) {
        return Err(SynthError::TooManyObjects(count));
    }
    // Strong change and storms move the sediment: a new fine seabed texture per visit.
    let moves_sediment = matches!(options.change, ChangeGrade::Strong | ChangeGrade::Storm);
    let sediment: Vec<u32> = (0..options.sessions)
        .map(|s| if moves_sediment && s > 0 { crate::noise::mix(site.seed, 0x5ED1_0000 + s as u32) } else { site.seed })
        .collect();
    let mut scene_slot = Vec::with_capacity(objects.len());
    for (s, states) in objects.iter().enumerate() {
        let light = sessions.get(s).map(|p: &SessionPlan| p.appearance.light_dir);
        let slot = (0..s)
            .find(|&p| {
                objects.get(p) == Some(states)
                    && sessions.get(p).map(|q| q.appearance.light_dir) == light
                    && sediment.get(p) == sediment.get(s)
            })
            .map_or(s, |p| scene_slot.get(p).copied().unwrap_or(p));
        scene_slot.push(slot);
    }
    let scenes = (0..options.sessions).map(|_| OnceLock::new()).collect();
    let seabeds = (0..options.sessions).map(|_| OnceLock::new()).collect();
    Ok(Survey { options: options.clone(), site, sessions, objects, scene_slot, sediment, seabeds, scenes, index })
}

/// Dead-reckoned navigation of one image: what a vehicle's odometry says, truth plus drift.
#[derive(Clone, Debug, PartialEq)]
pub struct NavigationSample {
    pub time_s: f64,
    /// The camera's pose in the odometry frame (the world frame at the visit's first image,
    /// drifting away from it).
    pub odom_from_cam: Rigid3,
}

/// Odometry drift: scale error (fraction), heading error (degrees) and a random walk (metres per
/// square root of image), each drawn per visit.
const DRIFT_SCALE_SIGMA: f64 = 0.01;
const DRIFT_HEADING_SIGMA_DEG: f64 = 1.0;
const DRIFT_WALK_SIGMA_M: f64 = 0.02;

/// A visit's position fix error (USBL in shallow water, depth from a pressure sensor): standard
/// deviation in x, y, z, metres.
pub const NAV_FIX_SIGMA_M: [f64; 3] = [0.10, 0.10, 0.02];
/// How a DVL-aided INS's position uncertainty grows: a fraction of the distance travelled
/// (0.5-1% is typical; the dead-reckoned track's own drift is drawn with about this size).
pub const NAV_DRIFT_PER_M: f64 = 0.01;

/// One image's georeferenced navigation: position in the world frame (x east, y north, z up,
/// metres) with its standard deviation per axis.
#[derive(Clone, Debug, PartialEq)]
pub struct NavigationFix {
    /// The image's file name within its session.
    pub file: String,
    pub position_m: Vector3<f64>,
    pub sigma_m: Vector3<f64>,
}

impl Survey {
    /// The odometry of session `s`: each image's true pose relative to the first, with a scale
    /// error, a heading error and a random walk (seeded by the survey's seed), as a DVL/INS would
    /// report it.
    pub fn navigation(&self, s: usize) -> Vec<NavigationSample> {
        let Some(session) = self.sessions.get(s) else { return Vec::new() };
        let mut rng = SplitMix64::stream(self.options.seed, 0x0D0_0000 + s as u64);
        let scale = 1.0 + DRIFT_SCALE_SIGMA * rng.normal();
        let heading =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (DRIFT_HEADING_SIGMA_DEG * rng.normal()).to_radians());
        let Some(first) = session.images.first() else { return Vec::new() };
        let origin = first.cam_from_world.inverse().translation;
        let mut walk = Vector3::zeros();
        session
            .images
            .iter()
            .map(|image| {
                let world_from_cam = image.cam_from_world.inverse();
                let travelled = world_from_cam.translation - origin;
                let position = origin + heading * (travelled * scale) + walk;
                walk += Vector3::new(rng.normal(), rng.normal(), 0.2 * rng.normal()) * DRIFT_WALK_SIGMA_M;
                NavigationSample {
                    time_s: image.time_s,
                    odom_from_cam: Rigid3 { rotation: heading * world_from_cam.rotation, translation: position },
                }
            })
            .collect()
    }

    /// Georeferenced navigation of session `s`, as an AUV's DVL-aided INS with a position fix
    /// (USBL) reports it in the world frame: the dead-reckoned track of
    /// [`Survey::navigation`] shifted by the fix's error (drawn once per visit), with each
    /// position's standard deviation (the fix's, growing by [`NAV_DRIFT_PER_M`] of the distance
    /// travelled).
    pub fn navigation_fixes(&self, s: usize) -> Vec<NavigationFix> {
        let Some(session) = self.sessions.get(s) else { return Vec::new() };
        let mut rng = SplitMix64::stream(self.options.seed, 0x0F1_0000 + s as u64);
        let fix_error = Vector3::new(
            NAV_FIX_SIGMA_M[0] * rng.normal(),
            NAV_FIX_SIGMA_M[1] * rng.normal(),
            NAV_FIX_SIGMA_M[2] * rng.normal(),
        );
        let mut travelled_m = 0.0;
        let mut previous: Option<Vector3<f64>> = None;
        session
            .images
            .iter()
            .zip(self.navigation(s))
            .map(|(image, sample)| {
                let position = sample.odom_from_cam.translation;
                travelled_m += previous.map_or(0.0, |p| (position - p).norm());
                previous = Some(position);
                let drift = NAV_DRIFT_PER_M * travelled_m;
                NavigationFix {
                    file: image.file.clone(),
                    position_m: position + fix_error,
                    sigma_m: Vector3::new(
                        NAV_FIX_SIGMA_M[0].hypot(drift),
                        NAV_FIX_SIGMA_M[1].hypot(drift),
                        NAV_FIX_SIGMA_M[2].hypot(0.2 * drift),
                    ),
                }
            })
            .collect()
    }

    pub fn options(&self) -> &SynthOptions {
        &self.options
    }

    pub fn sessions(&self) -> &[SessionPlan] {
        &self.sessions
    }

    /// Side of the square site, metres (centred on the world origin).
    pub fn site_size_m(&self) -> f64 {
        2.0 * self.site.half_m
    }

    /// Number of images over all sessions.
    pub fn num_images(&self) -> usize {
        self.index.len()
    }

    /// Image `index` (0-based, session after session).
    pub fn image(&self, index: usize) -> Result<&ImageTruth, SynthError> {
        self.index
            .get(index)
            .and_then(|&(s, i)| self.sessions.get(s)?.images.get(i))
            .ok_or(SynthError::NoSuchImage { index, count: self.index.len() })
    }

    /// All images, session after session.
    pub fn images(&self) -> impl Iterator<Item = &ImageTruth> {
        self.sessions.iter().flat_map(|s| s.images.iter())
    }

    fn session(&self, index: usize) -> Result<&SessionPlan, SynthError> {
        self.sessions.get(index).ok_or(SynthError::NoSuchSession { index, count: self.sessions.len() })
    }

    /// The site: its seabed and extent.
    pub(crate) fn site(&self) -> &Site {
        &self.site
    }

    /// The structures of a session, sorted by id.
    pub fn objects(&self, session: usize) -> Result<&[ObjectState], SynthError> {
        self.objects
            .get(session)
            .map(Vec::as_slice)
            .ok_or(SynthError::NoSuchSession { index: session, count: self.sessions.len() })
    }

    /// Structure `id` as session `s` has it, if there.
    pub(crate) fn object(&self, s: usize, id: u32) -> Option<&ObjectState> {
        let objects = self.objects.get(s)?;
        objects.binary_search_by_key(&id, |o| o.id).ok().and_then(|k| objects.get(k))
    }

    /// Whether object `id` looks and lies exactly the same in sessions `a` and
    /// `b` (the seabed always does; an object missing from either does not).
    pub fn object_unchanged(&self, id: u32, a: usize, b: usize) -> bool {
        if id == scene::SEABED_ID {
            return true;
        }
        matches!((self.object(a, id), self.object(b, id)), (Some(x), Some(y)) if x == y)
    }

    /// Builds the textures of a session now (in parallel when called outside
    /// the rayon pool). Rendering calls this itself; calling it first from the
    /// main thread makes later parallel rendering fast.
    pub fn prepare(&self, session: usize) -> Result<(), SynthError> {
        self.scene(session).map(|_| ())
    }

    /// The share of the site's plan area under coral (living or bleached) in a
    /// session, counted on the object-id texels (what is seen from above).
    pub fn coral_cover(&self, session: usize) -> Result<f64, SynthError> {
        let scene = self.scene(session)?;
        let corals: std::collections::HashSet<u32> =
            self.objects(session)?.iter().filter(|o| o.kind.is_coral()).map(|o| o.id).collect();
        let covered = scene.ids.iter().filter(|&&id| corals.contains(&u32::from(id))).count();
        Ok(covered as f64 / scene.ids.len().max(1) as f64)
    }

    pub(crate) fn scene(&self, session: usize) -> Result<&SessionScene, SynthError> {
        let count = self.sessions.len();
        let slot = *self.scene_slot.get(session).ok_or(SynthError::NoSuchSession { index: session, count })?;
        let cell = self.scenes.get(slot).ok_or(SynthError::NoSuchSession { index: session, count })?;
        let states = self.objects.get(slot).ok_or(SynthError::NoSuchSession { index: session, count })?;
        let light_dir = self.session(slot)?.appearance.light_dir;
        // Nested parallelism inside a lazily initialised cell could re-enter it
        // through rayon's work stealing: build sequentially inside the pool.
        let parallel = rayon::current_thread_index().is_none();
        let fine = self.sediment.get(slot).copied().unwrap_or(self.site.seed);
        let seabed = self
            .seabeds
            .get(slot)
            .ok_or(SynthError::NoSuchSession { index: session, count })?
            .get_or_init(|| self.site.build_seabed(fine, parallel));
        Ok(cell.get_or_init(|| SessionScene::build(&self.site, seabed, states, light_dir, parallel)))
    }

    pub(crate) fn view(&self, session: usize, cam_from_world: &Rigid3) -> Result<View, SynthError> {
        let plan = self.session(session)?;
        let p = &plan.camera.params;
        let get = |i: usize| p.get(i).copied().unwrap_or(0.0);
        Ok(View {
            fx: get(0),
            fy: get(1),
            cx: get(2),
            cy: get(3),
            width: plan.camera.width as usize,
            height: plan.camera.height as usize,
            cam_from_world: *cam_from_world,
        })
    }

    /// Renders image `index` (0-based over all sessions) with its depth and
    /// object ids.
    pub fn render(&self, index: usize) -> Result<Rendered, SynthError> {
        let image = self.image(index)?;
        let seed = self.options.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ u64::from(image.image_id);
        self.render_pose(image.session, &image.cam_from_world, image.time_s, seed)
    }

    /// Renders session `session`'s reef and water from any pose with its
    /// camera; `time_s` drives the caustics, `noise_seed` the sensor noise.
    pub fn render_pose(
        &self,
        session: usize,
        cam_from_world: &Rigid3,
        time_s: f64,
        noise_seed: u64,
    ) -> Result<Rendered, SynthError> {
        let scene = self.scene(session)?;
        let view = self.view(session, cam_from_world)?;
        let look = &self.session(session)?.appearance;
        Ok(render::render_view(&self.site, scene, &view, look, time_s, noise_seed))
    }

    /// Depth (camera z, metres) and object ids of image `index` without shading,
    /// at `1 / downscale` of the image size (intrinsics scaled alike).
    pub fn render_geometry(
        &self,
        index: usize,
        downscale: usize,
    ) -> Result<(Vec<f32>, Vec<u32>, usize, usize), SynthError> {
        let image = self.image(index)?;
        let scene = self.scene(image.session)?;
        let view = self.view(image.session, &image.cam_from_world)?.scaled(downscale);
        let parallel = rayon::current_thread_index().is_none();
        let stride = (downscale / 2).max(1);
        let depth = render::rasterize(&self.site, scene, &view, stride, parallel);
        let ids = render::object_ids(&self.site, scene, &view, &depth, parallel);
        Ok((depth, ids, view.width, view.height))
    }

    /// The world point seen at `pixel` of image `index` at camera depth `depth_m`.
    pub fn world_point(&self, index: usize, pixel: Point2<f64>, depth_m: f64) -> Result<Point3<f64>, SynthError> {
        let image = self.image(index)?;
        let view = self.view(image.session, &image.cam_from_world)?;
        Ok(image.cam_from_world.inverse() * Point3::from(view.ray(pixel.x, pixel.y) * depth_m))
    }

    /// The truth as a COLMAP model: one PINHOLE camera per session, every image
    /// with its exact pose, no points.
    pub fn truth_model(&self) -> Reconstruction {
        let mut model = Reconstruction::default();
        for session in &self.sessions {
            model.cameras.insert(session.camera.camera_id, session.camera.clone());
            for image in &session.images {
                model.images.insert(
                    image.image_id,
                    Image {
                        image_id: image.image_id,
                        camera_id: session.camera.camera_id,
                        name: image.name.clone(),
                        cam_from_world: image.cam_from_world,
                        points2d: Vec::new(),
                    },
                );
            }
        }
        model
    }

    /// Intrinsics of every session's camera.
    pub fn intrinsics(&self) -> Vec<SessionIntrinsics> {
        self.sessions
            .iter()
            .map(|s| {
                let p = &s.camera.params;
                let get = |i: usize| p.get(i).copied().unwrap_or(0.0);
                SessionIntrinsics {
                    session: s.name.clone(),
                    camera_id: s.camera.camera_id,
                    model: s.camera.model.name().to_owned(),
                    width: s.camera.width,
                    height: s.camera.height,
                    fx: get(0),
                    fy: get(1),
                    cx: get(2),
                    cy: get(3),
                    params: p.clone(),
                }
            })
            .collect()
    }
}
