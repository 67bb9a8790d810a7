//! `revisit synth`: render a synthetic multi-visit reef survey and write its
//! ground truth.
//!
//! Layout of `--out DIR`:
//! - `sessions/<name>/<name>_NNNN.png`: the images, one folder per session;
//! - `truth/`: the COLMAP text model of the true cameras, `poses.csv`,
//!   `intrinsics.json`, `survey.json`, `overlaps.csv`,
//!   `evaluation_points_<A>-<B>.csv` and `changes_<A>-<B>.csv` per session
//!   pair, and `README.txt`;
//! - `nav/<name>.csv`: each image's navigation (position and its standard
//!   deviation, as a vehicle's INS with a position fix reports it).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;
use serde::Serialize;
use tracing::info;

use revisit_core::Rigid3;
use revisit_synth::{
    ChangeGrade, EvaluationOptions, EvaluationPair, Growth, Overlap, StructureChange, Survey, SynthOptions,
};

/// Cross-session pairs with a smaller overlap are not listed in overlaps.csv.
const MIN_LISTED_OVERLAP: f64 = 0.1;

#[derive(clap::Args)]
pub struct Args {
    /// Output folder (created if missing): sessions/NAME/*.png, truth/ and nav/NAME.csv (navigation).
    #[arg(long)]
    out: PathBuf,
    /// Number of visits.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=1000))]
    sessions: u16,
    /// Images per visit (at least 2).
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(2..=100_000))]
    images_per_session: u32,
    /// Seed of everything random; the same seed gives byte-identical images.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Change between visits: none, mild, strong or storm.
    #[arg(long, default_value = "mild", value_parser = parse_change)]
    change: ChangeGrade,
    /// Growth of every living coral per visit, replacing the change grade's own: `yearly` (a
    /// year at typical Indo-Pacific rates: heads 4%, tables 12%, branching corals 25% of their
    /// size), `none`, one fraction for all types (0.1), or per type head=F,table=F,branching=F.
    /// Without it: none at none and strong, 20% of corals by 3-8% at mild, 10% by 2-10% at storm.
    #[arg(long, value_parser = parse_growth)]
    growth: Option<Growth>,
    /// Coral cover: the share of the site's plan area inside coral outlines in the first visit
    /// (0-0.8; without it about 0.2). Real reef slopes range 0.1-0.5 (e.g. the Great Barrier
    /// Reef's long-term average near 0.3, AIMS LTMP). survey.json reports the cover seen.
    #[arg(long, value_parser = parse_cover)]
    cover: Option<f64>,
    /// Image size WxH in pixels (at least 64x48).
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    size: (u32, u32),
    /// Frames per step between planned survey positions: N > 1 renders a video-rate sequence
    /// (each step subdivided along the track; a visit holds (images-per-session - 1) * N + 1 frames).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=1000))]
    frames_per_step: u16,
    /// Evaluation image pairs per session pair.
    #[arg(long, default_value_t = 30)]
    eval_pairs: usize,
    /// Also write each visit as a ROS 2 bag, bags/NAME/ (rosbag2 mcap): the images as
    /// sensor_msgs/CompressedImage PNG on /camera/image_raw/compressed, the true calibration on
    /// /camera/camera_info, dead-reckoned navigation (truth plus scale, heading and random-walk
    /// drift) as nav_msgs/Odometry on /odom, and revisit_msgs/SessionControl on /revisit/session.
    #[arg(long)]
    bag: bool,
    /// Frames per second of the bags' timeline.
    #[arg(long, default_value_t = 1.0, requires = "bag")]
    bag_rate: f64,
    /// Also write the georeferenced navigation of nav/NAME.csv into the bags (the same track with
    /// its position fix, in the world frame, with its covariance) as
    /// geometry_msgs/PoseWithCovarianceStamped on /nav (`reconstruct --nav-topic /nav`).
    #[arg(long, requires = "bag")]
    bag_navigation: bool,
}

fn parse_change(text: &str) -> Result<ChangeGrade, String> {
    text.parse::<ChangeGrade>().map_err(|e| e.to_string())
}

fn parse_growth(text: &str) -> Result<Growth, String> {
    text.parse::<Growth>().map_err(|e| e.to_string())
}

fn parse_cover(text: &str) -> Result<f64, String> {
    let cover: f64 = text.parse().map_err(|_| format!("expected a share such as 0.3, got {text:?}"))?;
    if !(0.0..=revisit_synth::MAX_COVER).contains(&cover) {
        return Err(format!("{cover} is outside 0-{}", revisit_synth::MAX_COVER));
    }
    Ok(cover)
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(|| format!("expected WxH such as 640x480, got {text:?}"))?;
    let parse = |s: &str| s.trim().parse::<u32>().map_err(|_| format!("expected WxH such as 640x480, got {text:?}"));
    let (w, h) = (parse(w)?, parse(h)?);
    if w < revisit_synth::MIN_WIDTH || h < revisit_synth::MIN_HEIGHT {
        return Err(format!(
            "{w}x{h} is smaller than the minimum {}x{}",
            revisit_synth::MIN_WIDTH,
            revisit_synth::MIN_HEIGHT
        ));
    }
    if w > revisit_synth::MAX_SIDE || h > revisit_synth::MAX_SIDE {
        return Err(format!("{w}x{h} is larger than the maximum {0}x{0}", revisit_synth::MAX_SIDE));
    }
    Ok((w, h))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let options = SynthOptions {
        sessions: usize::from(args.sessions),
        images_per_session: args.images_per_session as usize,
        seed: args.seed,
        change: args.change,
        width: args.size.0,
        height: args.size.1,
        frames_per_step: usize::from(args.frames_per_step),
        growth: args.growth,
        cover: args.cover,
    };
    let survey = write_survey(&options, &args.out, args.eval_pairs)?;
    let sessions_dir = args.out.join("sessions");
    if args.bag {
        anyhow::ensure!(
            args.bag_rate.is_finite() && args.bag_rate > 0.0,
            "--bag-rate must be a positive number of frames per second"
        );
        for s in 0..survey.sessions().len() {
            let written =
                write_bag(&survey, s, &sessions_dir, &args.out.join("bags"), args.bag_rate, args.bag_navigation)?;
            info!("wrote {} messages to {}", written.messages, written.dir.display());
        }
    }
    info!("wrote {}", args.out.display());
    Ok(())
}

/// Renders the survey `options` describe into `out` (images, truth and
/// navigation, as `revisit synth` writes them).
pub fn write_survey(options: &SynthOptions, out: &Path, eval_pairs: usize) -> anyhow::Result<Survey> {
    let survey = revisit_synth::plan(options).context("planning the survey")?;
    info!(
        "synthetic reef {:.1} m across, {} sessions x {} images, change {}, seed {}",
        survey.site_size_m(),
        options.sessions,
        options.images_per_session,
        options.change,
        options.seed
    );
    let sessions_dir = out.join("sessions");
    let truth_dir = out.join("truth");
    for session in survey.sessions() {
        let dir = sessions_dir.join(&session.name);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::create_dir_all(&truth_dir).with_context(|| format!("creating {}", truth_dir.display()))?;

    let build_start = Instant::now();
    for s in 0..survey.sessions().len() {
        survey.prepare(s).context("building the scene")?;
    }
    let build_secs = build_start.elapsed().as_secs_f64();
    info!("built the scene textures in {build_secs:.1} s");

    let count = survey.num_images();
    let bar = crate::progress::bar(count as u64, "render");
    let render_start = Instant::now();
    (0..count).into_par_iter().try_for_each(|index| -> anyhow::Result<()> {
        let image = survey.image(index)?;
        let rendered = survey.render(index).with_context(|| format!("rendering {}", image.name))?;
        let path = sessions_dir.join(&image.name);
        rendered.rgb.save(&path).with_context(|| format!("writing {}", path.display()))?;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    let render_secs = render_start.elapsed().as_secs_f64();
    info!(
        "rendered {count} images in {render_secs:.1} s = {:.1} img/s ({}x{}, scene build {build_secs:.1} s)",
        count as f64 / render_secs.max(1e-9),
        options.width,
        options.height,
    );

    write_truth(&survey, &truth_dir, eval_pairs)?;
    write_navigation(&survey, &out.join("nav"))?;
    Ok(survey)
}

/// One visit as a rosbag2 bag: images, camera info, odometry, navigation and visit markers.
fn write_bag(
    survey: &Survey,
    s: usize,
    sessions_dir: &Path,
    bags_dir: &Path,
    rate_hz: f64,
    with_navigation: bool,
) -> anyhow::Result<revisit_bag::WrittenBag> {
    use revisit_bag::{BagWriter, QosProfile};
    use revisit_msgs::{
        builtin_interfaces::Time,
        geometry_msgs::{Point, Pose, PoseWithCovariance, PoseWithCovarianceStamped, Quaternion},
        nav_msgs::Odometry,
        revisit_msgs::SessionControl,
        sensor_msgs::{CameraInfo, CompressedImage},
        std_msgs::Header,
    };
    let session = &survey.sessions()[s];
    let intrinsics = survey.intrinsics().into_iter().nth(s).context("the session's intrinsics")?;
    std::fs::create_dir_all(bags_dir).with_context(|| format!("creating {}", bags_dir.display()))?;
    let dir = bags_dir.join(&session.name);
    if dir.exists() {
        std::fs::remove_dir_all(&dir).with_context(|| format!("replacing {}", dir.display()))?;
    }
    let mut bag = BagWriter::create(&dir)?;
    let images = bag.add_topic::<CompressedImage>("/camera/image_raw/compressed", QosProfile::SENSOR_DATA)?;
    let infos = bag.add_topic::<CameraInfo>("/camera/camera_info", QosProfile::SENSOR_DATA)?;
    let odometry = bag.add_topic::<Odometry>("/odom", QosProfile::SENSOR_DATA)?;
    let georeferenced = match with_navigation {
        true => Some(bag.add_topic::<PoseWithCovarianceStamped>("/nav", QosProfile::SENSOR_DATA)?),
        false => None,
    };
    let control = bag.add_topic::<SessionControl>(revisit_pipeline::bags::SESSION_TOPIC, QosProfile::LATCHED)?;

    let start_ns = revisit_pipeline::bags::PACK_START_NS + s as u64 * 86_400_000_000_000;
    let time_ns = |i: usize| start_ns + (i as f64 * 1e9 / rate_hz).round() as u64;
    let header =
        |time_ns: u64, frame_id: &str| Header { stamp: Time::from_nanos(time_ns as i64), frame_id: frame_id.into() };
    let marker = |command, time_ns| SessionControl {
        header: header(time_ns, ""),
        command,
        session: session.name.clone(),
        source: "revisit synth".into(),
        ..SessionControl::default()
    };
    bag.write(control, start_ns, &marker(SessionControl::START, start_ns))?;
    let (fx, fy, cx, cy) = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy);
    // COLMAP's pixel centres are at +0.5; ROS's at 0.
    let info = |time_ns| CameraInfo {
        header: header(time_ns, "camera"),
        width: intrinsics.width,
        height: intrinsics.height,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [fx, 0.0, cx - 0.5, 0.0, fy, cy - 0.5, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx - 0.5, 0.0, 0.0, fy, cy - 0.5, 0.0, 0.0, 0.0, 1.0, 0.0],
        ..CameraInfo::default()
    };
    let (navigation, fixes) = (survey.navigation(s), survey.navigation_fixes(s));
    for (i, ((image, nav), fix)) in session.images.iter().zip(&navigation).zip(&fixes).enumerate() {
        let t = time_ns(i);
        let path = sessions_dir.join(&session.name).join(&image.file);
        let data = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        bag.write(images, t, &CompressedImage { header: header(t, "camera"), format: "png".into(), data })?;
        bag.write(infos, t, &info(t))?;
        let ([w, x, y, z], p) = (nav.odom_from_cam.wxyz(), nav.odom_from_cam.translation);
        let mut covariance = [0.0; 36];
        for (k, sigma) in [0.05, 0.05, 0.02, 0.01, 0.01, 0.02].into_iter().enumerate() {
            covariance[k * 7] = sigma * sigma;
        }
        let pose = PoseWithCovariance {
            pose: Pose { position: Point { x: p.x, y: p.y, z: p.z }, orientation: Quaternion { x, y, z, w } },
            covariance,
        };
        bag.write(
            odometry,
            t,
            &Odometry { header: header(t, "odom"), child_frame_id: "camera".into(), pose, ..Odometry::default() },
        )?;
        // The fix's position with its variances; the attitude as the INS has it, its covariance
        // not given (zeros).
        let (p, sigma) = (fix.position_m, fix.sigma_m);
        let mut covariance = [0.0; 36];
        for (k, s) in sigma.iter().enumerate() {
            covariance[k * 7] = s * s;
        }
        let pose = PoseWithCovariance {
            pose: Pose { position: Point { x: p.x, y: p.y, z: p.z }, orientation: Quaternion { x, y, z, w } },
            covariance,
        };
        if let Some(georeferenced) = georeferenced {
            bag.write(georeferenced, t, &PoseWithCovarianceStamped { header: header(t, "map"), pose })?;
        }
    }
    let end = time_ns(session.images.len());
    bag.write(control, end, &marker(SessionControl::END, end))?;
    Ok(bag.finish()?)
}

fn write_file(path: &Path, contents: &str) -> anyhow::Result<()> {
    std::fs::write(path, contents).with_context(|| format!("writing {}", path.display()))
}

/// A number as the shortest text that reads back to the same f64.
fn num(value: f64) -> String {
    format!("{value:?}")
}

fn write_truth(survey: &Survey, dir: &Path, eval_pairs: usize) -> anyhow::Result<()> {
    revisit_colmap::write_text(&survey.truth_model(), dir)
        .with_context(|| format!("writing the truth model to {}", dir.display()))?;

    let poses = survey.sessions().iter().flat_map(|session| {
        session.images.iter().map(|image| (session.name.as_str(), image.file.as_str(), &image.cam_from_world))
    });
    write_file(&dir.join("poses.csv"), &poses_csv(poses)?)?;

    let intrinsics = serde_json::to_string_pretty(&survey.intrinsics()).context("encoding intrinsics")?;
    write_file(&dir.join("intrinsics.json"), &(intrinsics + "\n"))?;
    let summary = serde_json::to_string_pretty(&summary(survey)).context("encoding the survey summary")?;
    write_file(&dir.join("survey.json"), &(summary + "\n"))?;

    let started = Instant::now();
    let overlaps = survey.overlaps(MIN_LISTED_OVERLAP).context("computing overlaps")?;
    write_file(&dir.join("overlaps.csv"), &overlaps_csv(&overlaps)?)?;
    info!("{} overlapping cross-session pairs ({:.1} s)", overlaps.len(), started.elapsed().as_secs_f64());

    let options = EvaluationOptions { pairs: eval_pairs, ..EvaluationOptions::default() };
    let sessions = survey.sessions();
    for a in 0..sessions.len() {
        for b in a + 1..sessions.len() {
            let (Some(sa), Some(sb)) = (sessions.get(a), sessions.get(b)) else { continue };
            let pairs = survey
                .evaluation_points(a, b, &overlaps, &options)
                .with_context(|| format!("picking evaluation points for {}-{}", sa.name, sb.name))?;
            let path = dir.join(format!("evaluation_points_{}-{}.csv", sa.name, sb.name));
            write_file(&path, &evaluation_csv(&pairs)?)?;
            let points: usize = pairs.iter().map(|p| p.uv_clicked.len()).sum();
            info!("{}: {} pairs, {} points", path.display(), pairs.len(), points);
            let changes = survey.changes(a, b).context("listing the changes")?;
            write_file(&dir.join(format!("changes_{}-{}.csv", sa.name, sb.name)), &changes_csv(&changes)?)?;
        }
    }
    write_file(&dir.join("README.txt"), README)?;
    Ok(())
}

/// `DIR/NAME.csv` per visit: each image's georeferenced navigation (a DVL-aided INS with a
/// position fix), `image,x,y,z,sigma_x,sigma_y,sigma_z` in metres in the truth's world frame.
fn write_navigation(survey: &Survey, dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (s, session) in survey.sessions().iter().enumerate() {
        let rows = survey.navigation_fixes(s).into_iter().map(|fix| {
            let (p, sigma) = (fix.position_m, fix.sigma_m);
            [fix.file, num(p.x), num(p.y), num(p.z), num(sigma.x), num(sigma.y), num(sigma.z)]
        });
        let text = csv_text(["image", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z"], rows)?;
        write_file(&dir.join(format!("{}.csv", session.name)), &text)?;
    }
    Ok(())
}

/// A JSON list of [u, v] pairs, e.g. `[[12.5, 33.0], [100.0, 7.25]]`.
fn uv_list(points: &[[f64; 2]]) -> String {
    let round = |v: f64| (v * 1e6).round() / 1e6;
    let items: Vec<String> = points.iter().map(|p| format!("[{}, {}]", num(round(p[0])), num(round(p[1])))).collect();
    format!("[{}]", items.join(", "))
}

/// A CSV file's text: the header, then the rows, quoted where a cell needs it
/// (image names may hold commas, quotes or any letter).
fn csv_text<const N: usize>(header: [&str; N], rows: impl IntoIterator<Item = [String; N]>) -> anyhow::Result<String> {
    let mut writer = csv::Writer::from_writer(Vec::new());
    writer.write_record(header)?;
    for row in rows {
        writer.write_record(&row)?;
    }
    let bytes = writer.into_inner().map_err(|e| anyhow::anyhow!("writing CSV: {e}"))?;
    Ok(String::from_utf8(bytes)?)
}

/// poses.csv: `session,image,qw,qx,qy,qz,tx,ty,tz` of each (session, file,
/// cam_from_world).
fn poses_csv<'a>(poses: impl IntoIterator<Item = (&'a str, &'a str, &'a Rigid3)>) -> anyhow::Result<String> {
    let header = ["session", "image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"];
    let rows = poses.into_iter().map(|(session, file, cam_from_world)| {
        let ([qw, qx, qy, qz], t) = (cam_from_world.wxyz(), cam_from_world.translation);
        [session.to_owned(), file.to_owned(), num(qw), num(qx), num(qy), num(qz), num(t.x), num(t.y), num(t.z)]
    });
    csv_text(header, rows)
}

/// overlaps.csv: `img0,img1,overlap`.
fn overlaps_csv(overlaps: &[Overlap]) -> anyhow::Result<String> {
    let rows = overlaps.iter().map(|o| [o.img0.clone(), o.img1.clone(), format!("{:.4}", o.overlap)]);
    csv_text(["img0", "img1", "overlap"], rows)
}

/// Every structure of two visits and what became of it, for scoring change maps.
fn changes_csv(changes: &[StructureChange]) -> anyhow::Result<String> {
    let xy = |c: Option<[f64; 2]>| c.map_or((String::new(), String::new()), |c| (num(c[0]), num(c[1])));
    let rows = changes.iter().map(|c| {
        let ((x0, y0), (x1, y1)) = (xy(c.centre_before_m), xy(c.centre_after_m));
        [
            c.id.to_string(),
            c.kind.name().to_owned(),
            c.change.name().to_owned(),
            x0,
            y0,
            x1,
            y1,
            num(c.reach_m),
            num(c.moved_m),
            num(c.turned_deg),
            num(c.growth),
            num(c.height_change_m),
            num(c.bleach_change),
            num(c.top_change_m),
            num(c.surface_change_m),
        ]
    });
    let header = [
        "id",
        "kind",
        "change",
        "x0",
        "y0",
        "x1",
        "y1",
        "reach_m",
        "moved_m",
        "turned_deg",
        "growth",
        "height_change_m",
        "bleach_change",
        "top_change_m",
        "surface_change_m",
    ];
    csv_text(header, rows)
}

/// The published evaluation format: `img0,img1,uv_clicked,uv_groundtruth`.
fn evaluation_csv(pairs: &[EvaluationPair]) -> anyhow::Result<String> {
    let rows =
        pairs.iter().map(|p| [p.img0.clone(), p.img1.clone(), uv_list(&p.uv_clicked), uv_list(&p.uv_groundtruth)]);
    csv_text(["img0", "img1", "uv_clicked", "uv_groundtruth"], rows)
}

#[derive(Serialize)]
struct SessionSummary<'a> {
    name: &'a str,
    altitude_m: f64,
    heading_deg: f64,
    offset_m: [f64; 2],
    lines: usize,
    images: usize,
    appearance: &'a revisit_synth::Appearance,
    structures: usize,
    /// Share of the site's plan area under coral.
    coral_cover: f64,
    /// Structures identical to the previous session (growth, bleaching and
    /// moves excluded).
    unchanged_from_previous: usize,
}

#[derive(Serialize)]
struct Summary<'a> {
    options: &'a SynthOptions,
    site_size_m: f64,
    sessions: Vec<SessionSummary<'a>>,
}

fn summary(survey: &Survey) -> Summary<'_> {
    let sessions = survey
        .sessions()
        .iter()
        .enumerate()
        .map(|(s, plan)| {
            let objects = survey.objects(s).unwrap_or(&[]);
            let unchanged = if s == 0 {
                objects.len()
            } else {
                objects.iter().filter(|o| survey.object_unchanged(o.id, s - 1, s)).count()
            };
            SessionSummary {
                name: &plan.name,
                altitude_m: plan.altitude_m,
                heading_deg: plan.heading_deg,
                offset_m: plan.offset_m,
                lines: plan.lines,
                images: plan.images.len(),
                appearance: &plan.appearance,
                structures: objects.len(),
                coral_cover: survey.coral_cover(s).unwrap_or(0.0),
                unchanged_from_previous: unchanged,
            }
        })
        .collect();
    Summary { options: survey.options(), site_size_m: survey.site_size_m(), sessions }
}

const README: &str = "\
Ground truth of a synthetic multi-visit reef survey rendered by `revisit synth`.

World frame: x east, y north, z up, metres; the site is a square centred on the
origin. Camera frame and pixels follow COLMAP: x right, y down, z forward; the
centre of the top-left pixel is (0.5, 0.5). Poses are cam_from_world
(x_cam = R x_world + t). Images are named session/file, e.g. s1/s1_0000.png,
relative to ../sessions/. The .csv files are UTF-8 with standard (RFC 4180)
quoting: a cell holding a comma, a quote or a line break is quoted.

cameras.txt, images.txt, points3D.txt
    COLMAP text model of the exact cameras used to render: one PINHOLE camera
    per session, every image with its true pose, no 3D points.
poses.csv
    session,image,qw,qx,qy,qz,tx,ty,tz: the same poses (cam_from_world, COLMAP
    quaternion order w, x, y, z); image is the file name within the session.
intrinsics.json
    Per session: camera id, model, size and fx, fy, cx, cy (pixels).
survey.json
    Options, site size, and per session the altitude, heading (direction of
    the survey lines and of the image's up, degrees from east), track offset,
    water and light parameters, the share of the site under coral
    (coral_cover, seen from above), and how many structures stayed unchanged.
overlaps.csv
    img0,img1,overlap for cross-session pairs (img0 from the earlier session)
    that truly overlap: the fraction of img0's pixels whose seabed point is
    visible in img1 at the same depth (changed or occluded structures do not
    count). Pairs above 0.1 are listed; estimated on an 80x60 grid.
changes_A-B.csv
    Every structure (rock, pebble, coral_head, coral_table, branching_coral) of
    sessions A and B and what became of it from A to B: change is removed,
    new, moved, grown, bleached or unchanged (the first that applies: a moved
    coral may also have grown); x0,y0 and x1,y1 its centre in A and in B
    (empty when absent), reach_m its largest horizontal reach from the centre,
    moved_m, turned_deg, growth (B's size over A's, minus 1; radial and
    vertical), height_change_m (of its top above its base), bleach_change
    (0 healthy, 1 white) and top_change_m (grown structures: of the median
    height of its surface within a quarter of its reach of its centre, the top
    a surface map measures; a branching coral's canopy rises less than its
    tips) and surface_change_m (removed, new and moved structures: the largest
    change of the visible surface's height within half its reach of where it
    was or is; near 0 for one that lay inside a larger structure's outline,
    beneath its surface). Evaluation points never fall on changed structures.
evaluation_points_A-B.csv
    The published evaluation format for sessions A and B:
    img0,img1,uv_clicked,uv_groundtruth, each of the two last cells a JSON
    list of [u, v] pixel positions. Clicked pixels lie on textured structure
    that is unchanged between A and B, away from depth edges, and visible in
    img1 (depth test against img1's rendered depth); uv_groundtruth is the
    exact projection of the same 3D point into img1.

../nav/SESSION.csv
    image,x,y,z,sigma_x,sigma_y,sigma_z: each image's camera position as a
    vehicle's navigation reports it (a DVL-aided INS drifting about 1% of the
    distance travelled, shifted by one position-fix error per visit, 0.1 m
    horizontally and 0.02 m in depth), in the world frame above, metres, with
    its standard deviation per axis.
";

#[cfg(test)]
mod tests {
    use super::*;

    /// A session and image names that need quoting, and a letter beyond ASCII.
    const SESSION: &str = "visite \"été\", 2";
    const FILE: &str = "a,b \"é\".png";

    #[test]
    fn truth_csv_names_with_commas_quotes_and_accents_round_trip() {
        let cam_from_world = Rigid3::from_wxyz([0.5, 0.5, -0.5, 0.5], [1.25, -2.0, 3.5]);
        let poses = poses_csv([(SESSION, FILE, &cam_from_world)]).unwrap();
        let read = revisit_eval::parse_truth_poses_csv(&poses, "poses.csv").unwrap();
        assert_eq!(read.len(), 1, "{poses}");
        assert_eq!((read[0].session.as_str(), read[0].name.clone()), (SESSION, format!("{SESSION}/{FILE}")));
        let (q_read, q) = (read[0].cam_from_world.wxyz(), cam_from_world.wxyz());
        assert!(q_read.iter().zip(q).all(|(a, b)| (a - b).abs() < 1e-12), "{q_read:?} != {q:?}");
        assert_eq!(read[0].cam_from_world.translation, cam_from_world.translation);

        let (img0, img1) = (format!("{SESSION}/{FILE}"), "s2/\"b\",é.png".to_owned());
        let pair = EvaluationPair {
            img0: img0.clone(),
            img1: img1.clone(),
            uv_clicked: vec![[12.5, 33.0], [100.0, 7.25]],
            uv_groundtruth: vec![[14.0, 30.5], [98.125, 9.0]],
        };
        let points = evaluation_csv(std::slice::from_ref(&pair)).unwrap();
        let read = revisit_eval::parse_points_csv(&points, "evaluation_points.csv").unwrap();
        assert!(read.malformed.is_empty(), "{:?}", read.malformed);
        let [click] = read.pairs.as_slice() else { panic!("{points}") };
        assert_eq!((&click.img0, &click.img1), (&pair.img0, &pair.img1));
        assert_eq!((&click.uv_clicked, &click.uv_groundtruth), (&pair.uv_clicked, &pair.uv_groundtruth));

        let overlaps = overlaps_csv(&[Overlap { img0: img0.clone(), img1: img1.clone(), overlap: 0.5 }]).unwrap();
        let mut reader = csv::Reader::from_reader(overlaps.as_bytes());
        let rows: Vec<csv::StringRecord> = reader.records().collect::<Result<_, _>>().unwrap();
        assert_eq!(rows, vec![csv::StringRecord::from(vec![img0.as_str(), img1.as_str(), "0.5000"])]);
    }

    #[test]
    fn truth_csv_of_plain_names_is_unquoted_but_for_the_uv_lists() {
        let pair = EvaluationPair {
            img0: "s1/s1_0000.png".to_owned(),
            img1: "s2/s2_0003.png".to_owned(),
            uv_clicked: vec![[1.5, 2.0]],
            uv_groundtruth: vec![[3.25, 4.0]],
        };
        assert_eq!(
            evaluation_csv(&[pair]).unwrap(),
            "img0,img1,uv_clicked,uv_groundtruth\ns1/s1_0000.png,s2/s2_0003.png,\"[[1.5, 2.0]]\",\"[[3.25, 4.0]]\"\n"
        );
    }
}
