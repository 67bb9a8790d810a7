//! The pipeline through its library API alone (no binary, no command-line
//! words): synthetic surveys rendered here, a `Workspace`, its typed report.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use revisit_pipeline::ingest::{scan_session, SessionSpec};
use revisit_pipeline::locate::Tools;
use revisit_pipeline::{Cancel, CrossStrategy, ReconstructOptions, Silent, Workspace};
use revisit_synth::{ChangeGrade, SynthOptions};

/// The project's Python and the shared models, as a user has them.
fn tools() -> Tools {
    Tools {
        python: Some(revisit_testkit::python()),
        onnxruntime: None,
        models: Some(revisit_testkit::shared("models")),
    }
}

/// Renders a survey; each image goes to `dir(session)/prefix + its file name`.
fn render(options: &SynthOptions, dir: impl Fn(&str) -> PathBuf, prefix: &str) {
    let survey = revisit_synth::plan(options).unwrap();
    for s in 0..survey.sessions().len() {
        survey.prepare(s).unwrap();
    }
    for index in 0..survey.num_images() {
        let image = survey.image(index).unwrap();
        let (session, file) = image.name.split_once('/').unwrap();
        let folder = dir(session);
        std::fs::create_dir_all(&folder).unwrap();
        survey.render(index).unwrap().rgb.save(folder.join(format!("{prefix}{file}"))).unwrap();
    }
}

fn add(workspace: &mut Workspace, name: &str, dir: &Path) {
    let spec = SessionSpec { name: name.to_owned(), dir: dir.to_path_buf() };
    workspace.add_session(scan_session(&spec).unwrap()).unwrap();
}

#[test]
fn two_visits_reconstruct_through_the_library_and_resume() {
    let dir = tempfile::tempdir().unwrap();
    let sessions = dir.path().join("sessions");
    let options =
        SynthOptions { sessions: 2, images_per_session: 8, change: ChangeGrade::None, seed: 3, ..Default::default() };
    render(&options, |s| sessions.join(s), "");
    let mut options = ReconstructOptions { cross: CrossStrategy::Sift, ..Default::default() };
    options.features.sift.max_num_features = 1024;
    let work = dir.path().join("work");

    let mut workspace = Workspace::open(&work, options.clone(), tools()).unwrap();
    // Given in reverse order the first time: visit order is the order of addition.
    add(&mut workspace, "s2", &sessions.join("s2"));
    add(&mut workspace, "s1", &sessions.join("s1"));
    let report = workspace.run(&Silent, &Cancel::new()).unwrap();
    assert_eq!(report.models, 1, "{report:#?}");
    assert_eq!(report.fully_registered(), ["s1", "s2"], "{report:#?}");
    assert_eq!(report.sessions["s2"].visit, 0);
    assert_eq!(report.sessions["s1"].visit, 1);
    assert!(report.pairs_of(revisit_core::PairKind::Cross).verified > 0, "{report:#?}");
    // report.json is the typed report written out.
    assert_eq!(revisit_pipeline::Report::read(&work.join("report.json")).unwrap(), report);

    // Opened again with the sessions in the other order: each keeps its
    // visit, nothing is redone, the model is kept.
    let mut workspace = Workspace::open(&work, options.clone(), tools()).unwrap();
    add(&mut workspace, "s1", &sessions.join("s1"));
    add(&mut workspace, "s2", &sessions.join("s2"));
    let names: Vec<&str> = workspace.sessions().iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["s2", "s1"]);
    let again = workspace.run(&Silent, &Cancel::new()).unwrap();
    assert_eq!(again.features.done, 0);
    assert_eq!(again.matching.done, 0);
    assert!(again.mapping.reused);

    // Options that shape stored work cannot change under a store.
    let mut other = options;
    other.features.sift.max_num_features = 512;
    let Err(err) = Workspace::open(&work, other, tools()) else { panic!("other feature options were accepted") };
    assert!(err.to_string().contains("features"), "{err}");

    // A cancelled run stops before doing anything and says so.
    let cancel = Cancel::new();
    cancel.cancel();
    let fresh = dir.path().join("cancelled");
    let mut workspace = Workspace::open(&fresh, ReconstructOptions::default(), tools()).unwrap();
    add(&mut workspace, "s1", &sessions.join("s1"));
    let err = workspace.run(&Silent, &cancel).unwrap_err();
    assert!(matches!(err, revisit_pipeline::PipelineError::Cancelled), "{err}");
}

#[test]
fn a_visit_with_two_image_sizes_reconstructs_with_two_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let visit = dir.path().join("visit");
    // The same survey rendered by two cameras of different sizes, in one folder.
    for (size, prefix) in [((640, 480), "a_"), ((800, 600), "b_")] {
        let options = SynthOptions {
            sessions: 1,
            images_per_session: 8,
            change: ChangeGrade::None,
            width: size.0,
            height: size.1,
            seed: 5,
            ..Default::default()
        };
        render(&options, |_| visit.clone(), prefix);
    }
    let mut options = ReconstructOptions { cross: CrossStrategy::None, ..Default::default() };
    options.features.sift.max_num_features = 1024;
    let mut workspace = Workspace::open(&dir.path().join("work"), options, tools()).unwrap();
    add(&mut workspace, "reef", &visit);
    let report = workspace.run(&Silent, &Cancel::new()).unwrap();
    let cameras = &report.sessions["reef"].cameras;
    let sizes: Vec<(&str, u32, u32, usize)> =
        cameras.iter().map(|(name, c)| (name.as_str(), c.width, c.height, c.images)).collect();
    assert_eq!(sizes, [("640x480", 640, 480, 8), ("800x600", 800, 600, 8)]);
    assert_ne!(cameras["640x480"].camera_id, cameras["800x600"].camera_id);
    assert_eq!(report.models, 1, "{report:#?}");
    assert_eq!(report.sessions["reef"].registered, 16, "{report:#?}");
}
