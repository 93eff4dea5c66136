//! Hostile and careless input: damaged models, text that breaks output formats, sizes beyond
//! the limits, outputs over inputs. Each class gets a typed error (or a warning), never a
//! panic or a silently wrong file.

use kinetree_core::{Error, Model};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{paper_arm, simulate};
use serde_json::{Value, json};
use std::path::PathBuf;
use std::sync::OnceLock;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kinetree-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

/// The paper arm's discovered model, once for every test of the file.
fn arm_model() -> &'static Model {
    static MODEL: OnceLock<Model> = OnceLock::new();
    MODEL.get_or_init(|| {
        let data = simulate(&paper_arm(0)).expect("simulate");
        Pipeline::from_config(&PipelineConfig::default())
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover")
            .model
    })
}

/// Writes `value` as a model file and reads it back.
fn read_back(name: &str, value: &Value) -> kinetree_core::Result<Model> {
    let path = tmp(name);
    std::fs::write(&path, serde_json::to_string(value).expect("json")).expect("write");
    kinetree_io::read_model(&path)
}

/// One way of damaging a model: what it does, the JSON edit, and the field the error must
/// name.
type Damage = (&'static str, fn(&mut Value), &'static str);

fn damages() -> Vec<Damage> {
    vec![
        (
            "schema version 999",
            |m| m["schema_version"] = json!(999),
            "schema_version",
        ),
        (
            "schema version 0",
            |m| m["schema_version"] = json!(0),
            "schema_version",
        ),
        (
            "a body id that is not its position",
            |m| m["bodies"][1]["id"] = json!(7),
            "bodies[1].id",
        ),
        (
            "a joint to body 99",
            |m| m["joints"][0]["child"] = json!(99),
            "joints[0].child",
        ),
        (
            "a joint from a body other than the parent",
            |m| {
                let child = m["joints"][1]["child"].clone();
                m["joints"][0]["child"] = child;
            },
            "joints[0].parent",
        ),
        (
            "a parent cycle",
            |m| {
                // Body 1's parent becomes body 2, whose ancestors include body 1.
                m["bodies"][1]["parent"] = json!(3);
            },
            "bodies[1].parent",
        ),
        (
            "a root with a parent",
            |m| m["bodies"][0]["parent"] = json!(1),
            "bodies[0].parent",
        ),
        (
            "a second root",
            |m| m["bodies"][2]["parent"] = Value::Null,
            "bodies[2].parent",
        ),
        (
            "the root beyond the bodies",
            |m| m["root_body"] = json!(40),
            "root_body",
        ),
        (
            "the static body beyond the bodies",
            |m| m["static_body"] = json!(40),
            "static_body",
        ),
        (
            "a zero axis",
            |m| m["joints"][0]["axis_in_parent"] = json!([0.0, 0.0, 0.0]),
            "joints[0].axis_in_parent",
        ),
        (
            "a null axis on a revolute joint",
            |m| m["joints"][0]["axis_in_parent"] = Value::Null,
            "joints[0].axis_in_parent",
        ),
        (
            "a long camera-frame axis",
            |m| m["joints"][1]["axis"] = json!([2.0, 0.0, 0.0]),
            "joints[1].axis",
        ),
        (
            "a null pivot on a revolute joint",
            |m| m["joints"][0]["point_in_parent"] = Value::Null,
            "joints[0].point_in_parent",
        ),
        (
            "inverted limits",
            |m| m["joints"][0]["range"] = json!([1.0, -1.0]),
            "joints[0].range",
        ),
        (
            "a reference frame beyond the frames",
            |m| m["joints"][0]["reference_frame"] = json!(1_000_000),
            "joints[0].reference_frame",
        ),
        (
            "a zero quaternion",
            |m| m["joints"][0]["reference_pose"]["rotation_xyzw"] = json!([0.0, 0.0, 0.0, 0.0]),
            "joints[0].reference_pose",
        ),
        (
            "positions of the wrong length",
            |m| m["joints"][0]["positions"] = json!([0.0, 0.1]),
            "joints[0].positions",
        ),
        (
            "a negative standard deviation",
            |m| m["joints"][0]["position_std"][0] = json!(-1.0),
            "joints[0].position_std[0]",
        ),
        (
            "a negative axis precision",
            |m| m["joints"][0]["axis_std_deg"] = json!(-0.1),
            "joints[0].axis_std_deg",
        ),
        (
            "a negative pivot precision",
            |m| m["joints"][0]["pivot_std_m"] = json!(-1e-3),
            "joints[0].pivot_std_m",
        ),
        (
            "coordinates on a one-coordinate joint",
            |m| m["joints"][0]["coordinates"] = json!([[0.0, 0.0, 0.0]]),
            "joints[0].coordinates",
        ),
        (
            "a spherical joint with two coordinates a frame",
            |m| {
                let j = &mut m["joints"][0];
                j["type"] = json!("spherical");
                let n = j["positions"].as_array().expect("positions").len();
                let mut c = vec![json!([0.0, 0.1, 0.2]); n];
                c[n / 2] = json!([0.0, 0.1]);
                j["coordinates"] = json!(c);
            },
            "joints[0].coordinates[50]",
        ),
        (
            "a spherical joint without a centre",
            |m| {
                m["joints"][0]["type"] = json!("spherical");
                m["joints"][0]["point_in_parent"] = Value::Null;
            },
            "joints[0].point_in_parent",
        ),
        (
            "a point on body 99",
            |m| m["point_body"][0] = json!(99),
            "point_body[0]",
        ),
        (
            "point_body of the wrong length",
            |m| {
                m["point_body"].as_array_mut().expect("array").pop();
            },
            "point_body",
        ),
        (
            "a body point beyond the points",
            |m| m["bodies"][1]["points"][0] = json!(500),
            "bodies[1].points[0]",
        ),
        (
            "body points out of order",
            |m| {
                m["bodies"][1]["points"]
                    .as_array_mut()
                    .expect("array")
                    .reverse();
            },
            "bodies[1].points",
        ),
        (
            "a missing joint",
            |m| {
                m["joints"].as_array_mut().expect("array").pop();
            },
            "joints",
        ),
        (
            "a zero noise level",
            |m| m["noise"]["sigma_m"] = json!(0.0),
            "noise.sigma_m",
        ),
        (
            "negative position limits",
            |m| m["position_limits"]["max_std_rad"] = json!(-1.0),
            "position_limits.max_std_rad",
        ),
        (
            "labels of the wrong count",
            |m| m["point_labels"] = json!(["a", "b"]),
            "point_labels",
        ),
        (
            "a poses file in another folder",
            |m| m["body_poses_file"] = json!("../elsewhere/model.poses.npy"),
            "body_poses_file",
        ),
        (
            "a poses file that is not .npy",
            |m| m["body_poses_file"] = json!("model.poses.json"),
            "body_poses_file",
        ),
        (
            "a chain through body 40",
            |m| m["chain"] = json!([0, 40]),
            "chain[1]",
        ),
        (
            "a pair test of body 40",
            |m| m["pairs"][0]["b"] = json!(40),
            "pairs[0]",
        ),
        (
            "no bodies",
            |m| m["bodies"] = json!([]),
            "n_frames, n_points, bodies",
        ),
    ]
}

#[test]
fn damaged_models_are_refused_naming_the_field() {
    let model = arm_model();
    let good = serde_json::to_value(model).expect("json");
    assert!(
        model.bodies.len() >= 3,
        "the damages need three bodies, found {}",
        model.bodies.len()
    );
    read_back("good.json", &good).expect("the discovered model reads back");
    for (what, damage, field) in damages() {
        let mut m = good.clone();
        damage(&mut m);
        let e = read_back("damaged.json", &m).expect_err(what);
        match e.root() {
            Error::InvalidModel { field: found, .. } => {
                assert_eq!(found, field, "{what}: {e}");
            }
            other => panic!("{what}: expected an invalid-model error, got {other:?}"),
        }
        assert!(e.to_string().contains("damaged.json"), "{what}: {e}");
        // An in-memory model with the same damage is refused by the exporter too.
        if let Ok(bad) = serde_json::from_value::<Model>(m) {
            assert!(
                kinetree_io::export::to_urdf(&bad).is_err(),
                "{what}: exported"
            );
        }
    }
}

#[test]
fn text_in_a_model_cannot_break_the_urdf() {
    let mut model = arm_model().clone();
    let hostile = [
        "a--b",
        "trailing-",
        "---",
        "<tag> & \"quote\" 'x'",
        "line\nbreak",
        "-->",
    ];
    model.point_labels = Some(
        (0..model.n_points)
            .map(|i| hostile[i % hostile.len()].to_string())
            .collect(),
    );
    model.generator = "kinetree -- evil -->".into();
    let text = kinetree_io::export::to_urdf(&model).expect("export");
    urdf_rs::read_from_string(&text).expect("the URDF parses");
    for comment in text.split("<!--").skip(1) {
        let body = comment.split("-->").next().expect("closed");
        assert!(
            !body.contains("--") && !body.ends_with('-'),
            "comment {body:?} breaks XML"
        );
    }
}

#[test]
fn a_detached_body_is_a_valid_forest_and_exports_as_one_tree() {
    let mut model = arm_model().clone();
    let last = model.bodies.len() - 1;
    model.bodies[last].parent = None;
    model.joints.retain(|j| j.child != last);
    let e = model
        .validate()
        .expect_err("a second root without a warning");
    assert!(
        matches!(e, Error::InvalidModel { ref field, .. } if *field == format!("bodies[{last}].parent")),
        "{e}"
    );
    model
        .warnings
        .push(kinetree_core::Warning::BodyDetached { body: last });
    model.validate().expect("a detached body with its warning");
    let text = kinetree_io::export::to_urdf(&model).expect("export");
    let robot = urdf_rs::read_from_string(&text).expect("parses");
    assert_eq!(robot.joints.len(), model.bodies.len() - 1, "one tree");
    let hung = robot
        .joints
        .iter()
        .find(|j| j.child.link == kinetree_io::export::link_name(last))
        .expect("the detached body's joint");
    assert!(matches!(hung.joint_type, urdf_rs::JointType::Floating));
}

#[test]
fn a_failed_write_leaves_the_previous_file_whole() {
    let path = tmp("atomic-model.json");
    let model = arm_model();
    kinetree_io::write_json(&path, model).expect("first write");
    let before = std::fs::read(&path).expect("read");
    // A write that fails half-way, as a full disk or a file-size limit makes it.
    let e = kinetree_io::write_atomically(&path, |w| {
        use std::io::Write;
        w.write_all(&before[..before.len() / 2])?;
        Err(Error::Io(std::io::Error::new(
            std::io::ErrorKind::StorageFull,
            "no space left on device",
        )))
    })
    .expect_err("the write fails");
    assert!(e.to_string().contains("atomic-model.json"), "{e}");
    assert_eq!(std::fs::read(&path).expect("read"), before, "file changed");
    let dir = path.parent().expect("dir");
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .expect("list")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".part"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    assert!(kinetree_io::read_model(&path).is_ok());
}

/// An output that is a pipe (or a device such as `/dev/null`) is written in place: a file
/// renamed over it would replace the pipe itself, and `-o /dev/null` run as root would leave
/// the machine without its null device.
#[cfg(unix)]
#[test]
fn an_output_that_is_a_pipe_is_written_in_place() {
    use std::os::unix::fs::FileTypeExt;
    let path = tmp("model-pipe");
    let _ = std::fs::remove_file(&path);
    let made = std::process::Command::new("mkfifo")
        .arg(&path)
        .status()
        .expect("mkfifo (coreutils) runs");
    assert!(made.success());
    let (send, received) = std::sync::mpsc::channel();
    {
        let path = path.clone();
        std::thread::spawn(move || send.send(std::fs::read(&path).expect("read the pipe")));
    }
    let model = arm_model();
    kinetree_io::write_json(&path, model).expect("write into the pipe");
    let kind = std::fs::symlink_metadata(&path)
        .expect("still there")
        .file_type();
    assert!(kind.is_fifo(), "the pipe was replaced: {kind:?}");
    let sent = received
        .recv_timeout(std::time::Duration::from_secs(30))
        .expect("the reader got the model");
    let back: kinetree_core::Model = serde_json::from_slice(&sent).expect("a model came through");
    assert_eq!(back.bodies.len(), model.bodies.len());
    let _ = std::fs::remove_file(&path);
}

const SMALL_SWEEP: &str = r#"
[experiment]
name = "resumable"

[sweep]
seeds = [1, 2]
timing = true

[sweep.grid]
"data.noise_sigma_m" = [0.001, 0.002]

[data]
kind = "random"
n_joints = 1
n_frames = 60
"#;

#[test]
fn an_interrupted_sweep_keeps_its_finished_runs_and_resumes_with_the_rest() {
    use kinetree_pipeline::sweep::{Sweep, SweepOptions, run_sweep, runs_csv};
    let sweep = Sweep::from_toml(SMALL_SWEEP).expect("parses");
    let dir = tmp("sweep-resume");
    let full = run_sweep(
        &sweep,
        std::path::Path::new("."),
        &dir,
        &|_, _| {},
        SweepOptions::default(),
    )
    .expect("runs");
    let csv_path = dir.join("runs.csv");
    let complete = std::fs::read_to_string(&csv_path).expect("runs.csv");
    let without_time = |text: &str| -> Vec<String> {
        text.lines()
            .map(|l| l.rsplit_once(',').map_or(l, |(head, _)| head).to_string())
            .collect()
    };
    // As an interruption leaves it: two finished rows, out of order, and a row cut short.
    let lines: Vec<&str> = complete.lines().collect();
    let cut = &lines[2][..lines[2].len() / 2];
    std::fs::write(
        &csv_path,
        format!("{}\n{}\n{}\n{cut}", lines[0], lines[3], lines[1]),
    )
    .expect("write");
    let ran = std::sync::atomic::AtomicUsize::new(0);
    let count = |_: usize, _: usize| {
        ran.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let resumed = run_sweep(
        &sweep,
        std::path::Path::new("."),
        &dir,
        &count,
        SweepOptions {
            resume: true,
            shard: None,
        },
    )
    .expect("resume");
    assert_eq!(
        ran.into_inner(),
        full.len() - 2,
        "only the missing runs ran"
    );
    let after = std::fs::read_to_string(&csv_path).expect("runs.csv");
    assert_eq!(without_time(&after), without_time(&complete));
    assert_eq!(
        without_time(&runs_csv(&sweep, &resumed)),
        without_time(&complete)
    );
    // A runs.csv of another sweep is not taken for this one's.
    let other = SMALL_SWEEP.replace("0.002]", "0.003]");
    let other = Sweep::from_toml(&other).expect("parses");
    let e = run_sweep(
        &other,
        std::path::Path::new("."),
        &dir,
        &|_, _| {},
        SweepOptions {
            resume: true,
            shard: None,
        },
    )
    .expect_err("another sweep's runs");
    assert!(e.to_string().contains("runs.csv"), "{e}");
}

#[test]
fn a_sweep_beyond_the_run_limit_is_refused_before_it_expands() {
    use kinetree_pipeline::sweep::Sweep;
    // 10^6 grid points would take minutes to expand and hours to run.
    let values: Vec<String> = (0..1000)
        .map(|k| format!("{}", 1e-4 * (k + 1) as f64))
        .collect();
    let text = format!(
        "[experiment]\nname = \"huge\"\n\n[sweep]\nseeds = 1000\n\n[sweep.grid]\n\"data.noise_sigma_m\" = [{}]\n\n[data]\nkind = \"random\"\n",
        values.join(", ")
    );
    let e = Sweep::from_toml(&text).expect_err("a million runs");
    match &e {
        Error::TooLarge {
            estimate, limit, ..
        } => {
            assert_eq!(estimate, "1000000 runs");
            assert_eq!(limit, "10000 runs");
        }
        other => panic!("expected TooLarge, got {other:?}"),
    }
    Sweep::from_toml_within(SMALL_SWEEP, 4).expect("four runs within four");
    assert!(Sweep::from_toml_within(SMALL_SWEEP, 3).is_err());
}

fn write_npy_header_only(path: &std::path::Path, shape: &[u64]) {
    // A valid header claiming `shape`, followed by one value: what a damaged or hostile file
    // looks like.
    let dims: Vec<String> = shape.iter().map(u64::to_string).collect();
    let dict = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}), }}",
        dims.join(", ")
    );
    let mut header = dict.into_bytes();
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(b' ');
    }
    header.push(b'\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(&header);
    bytes.extend_from_slice(&0.5f64.to_le_bytes());
    std::fs::write(path, bytes).expect("write");
}

#[test]
fn sizes_beyond_memory_are_refused_before_they_are_allocated() {
    // A CSV size line asking for 10^7 frames of 214 points: about 50 GiB.
    let csv = tmp("huge.csv");
    std::fs::write(
        &csv,
        "# frames=10000000 points=214\nframe,point,x,y,z\n0,0,1,2,3\n",
    )
    .expect("write");
    let e = kinetree_io::read_tracks(&csv).expect_err("50 GiB");
    assert!(matches!(e.root(), Error::TooLarge { .. }), "{e}");
    assert!(e.to_string().contains("huge.csv"), "{e}");
    // The limit is a parameter: a declared 1000 x 214 (5 MiB) reads within 1 GiB, not
    // within 100 KiB.
    std::fs::write(
        &csv,
        "# frames=1000 points=214\nframe,point,x,y,z\n0,0,1,2,3\n",
    )
    .expect("write");
    kinetree_io::read_tracks_within(&csv, 1.0).expect("a small declared size reads");
    assert!(
        kinetree_io::read_tracks_within(&csv, 1e-4).is_err(),
        "below 5 MiB"
    );

    // An npy header claiming more data than the file holds.
    let npy = tmp("lying.npy");
    write_npy_header_only(&npy, &[100_000, 100_000, 3]);
    let e = kinetree_io::read_tracks(&npy).expect_err("lying header");
    assert!(
        matches!(e.root(), Error::Malformed { position, .. } if position == "header"),
        "{e}"
    );
    write_npy_header_only(&npy, &[u64::MAX, 2, 3]);
    assert!(
        kinetree_io::read_tracks(&npy).is_err(),
        "an overflowing shape"
    );

    // 20 000 points in 3 frames: a small file, but a discovery on every point of about
    // 18 GiB (the default discovers on a sample of them instead).
    let n = 20_000;
    let xyz: Vec<f64> = (0..3 * n * 3).map(|k| (k % 97) as f64 * 1e-2).collect();
    let tracks = kinetree_core::Tracks::new(3, n, xyz).expect("tracks");
    let mut every_point = PipelineConfig::default();
    every_point.sampling.max_points = n;
    let e = Pipeline::from_config(&every_point)
        .expect("pipeline")
        .run(&tracks)
        .expect_err("18 GiB");
    match &e {
        Error::TooLarge { what, limit, .. } => {
            assert!(what.contains("20000 points"), "{e}");
            assert_eq!(limit, "8.0 GiB");
        }
        other => panic!("expected TooLarge, got {other:?}"),
    }
    // Simulated data are checked the same way before they are simulated.
    let data = kinetree_pipeline::config::DataConfig::Random(kinetree_synth::RandomParams {
        n_joints: 200,
        extra_points: 10_000,
        n_frames: 1_000_000,
        ..kinetree_synth::RandomParams::default()
    });
    let e =
        kinetree_pipeline::load_data(&data, std::path::Path::new("."), 8.0).expect_err("terabytes");
    assert!(matches!(e, Error::TooLarge { .. }), "{e}");
    let config = PipelineConfig {
        max_memory_gib: f64::NAN,
        ..PipelineConfig::default()
    };
    assert!(Pipeline::from_config(&config).is_err(), "a NaN limit");
}

/// The structure of a model: every point's body and every joint's bodies and type.
fn structure(m: &Model) -> (Vec<i64>, Vec<(usize, usize, String)>) {
    (
        m.point_body.clone(),
        m.joints
            .iter()
            .map(|j| (j.parent, j.child, j.joint_type.to_string()))
            .collect(),
    )
}

/// `tracks` with gross glitches in visible samples drawn from `seed`: one-sample jumps of
/// metres, and values as broken C3D samples hold.
fn glitched(tracks: &kinetree_core::Tracks, seed: u64, n: usize) -> kinetree_core::Tracks {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut xyz = tracks.raw().to_vec();
    let np = tracks.n_points();
    let mut done = 0;
    while done < n {
        let (t, i) = (
            rng.random_range(0..tracks.n_frames()),
            rng.random_range(0..np),
        );
        let k = (t * np + i) * 3;
        if xyz[k].is_nan() {
            continue;
        }
        match done % 3 {
            0 => xyz[k] += 10.0,
            1 => xyz[k + 1] = 3e38,
            _ => xyz[k + 2] -= rng.random_range(0.5..5.0),
        }
        done += 1;
    }
    let out = kinetree_core::Tracks::new(tracks.n_frames(), np, xyz).expect("tracks");
    match tracks.labels() {
        Some(l) => out.with_labels(l.to_vec()).expect("labels"),
        None => out,
    }
}

#[test]
fn gross_glitches_are_dropped_and_leave_the_structure_as_it_was() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../experiments/real");
    let real = kinetree_pipeline::config::pipeline_from_toml(
        &std::fs::read_to_string(root.join("pipeline.toml")).expect("pipeline.toml"),
    )
    .expect("config");
    let walk =
        kinetree_io::read_c3d(&kinetree_tests::real_c3d("c3dorg-qualisys-walk")).expect("read");
    let arm = simulate(&paper_arm(3)).expect("simulate").tracks;
    for (what, tracks, config, n) in [
        ("a real gait recording", &walk, &real, 12),
        ("the paper arm", &arm, &PipelineConfig::default(), 6),
    ] {
        let pipeline = Pipeline::from_config(config).expect("pipeline");
        let clean = pipeline.run(tracks).expect("discover").model;
        for seed in 0..2 {
            let bad = glitched(tracks, seed, n);
            let found = pipeline.run(&bad).expect("discover glitched").model;
            assert_eq!(structure(&found), structure(&clean), "{what}, seed {seed}");
            let dropped = found.warnings.iter().find_map(|w| match w {
                kinetree_core::Warning::ImpossibleSamplesDropped { count, .. } => Some(*count),
                _ => None,
            });
            let already = clean.warnings.iter().find_map(|w| match w {
                kinetree_core::Warning::ImpossibleSamplesDropped { count, .. } => Some(*count),
                _ => None,
            });
            assert_eq!(
                dropped,
                Some(already.unwrap_or(0) + n),
                "{what}, seed {seed}: every glitch and nothing else dropped"
            );
        }
    }
}

#[test]
fn coincident_points_get_no_invented_poses() {
    use kinetree_core::nalgebra::Point3;
    let arm = simulate(&paper_arm(2)).expect("simulate").tracks;
    let (nf, np) = (arm.n_frames(), arm.n_points());
    let pipeline = Pipeline::from_config(&PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    })
    .expect("pipeline");
    // Five points at one place: alone, and beside the arm (fixed, or on its last point).
    let alone: Vec<Vec<Option<Point3<f64>>>> = vec![vec![Some(Point3::new(0.1, 0.2, 0.3)); 5]; 40];
    let beside = |moving: bool| -> kinetree_core::Tracks {
        let frames: Vec<Vec<Option<Point3<f64>>>> = (0..nf)
            .map(|t| {
                let mut f: Vec<Option<Point3<f64>>> = (0..np).map(|i| arm.get(t, i)).collect();
                let at = if moving {
                    arm.get(t, np - 1)
                } else {
                    Some(Point3::new(0.5, 0.5, 2.0))
                };
                f.extend(std::iter::repeat_n(at, 5));
                f
            })
            .collect();
        kinetree_core::Tracks::from_points(&frames).expect("tracks")
    };
    let cases = [
        (
            "alone",
            kinetree_core::Tracks::from_points(&alone).expect("tracks"),
        ),
        ("fixed beside the arm", beside(false)),
        ("on the arm's last link", beside(true)),
    ];
    for (what, tracks) in cases {
        match pipeline.run(&tracks) {
            Err(e) => assert!(matches!(e, Error::Degenerate(_)), "{what}: {e}"),
            Ok(d) => {
                let m = d.model;
                assert!(
                    !m.warnings
                        .iter()
                        .any(|w| matches!(w, kinetree_core::Warning::BodyPosedThroughHinge { .. })),
                    "{what}: {:?}",
                    m.warnings
                );
                // The coincident points hold no orientation: no body of their own.
                let coincident: Vec<i64> = m.point_body[np.min(m.n_points)..].to_vec();
                for b in coincident.iter().filter(|&&b| b >= 0) {
                    let body = &m.bodies[*b as usize];
                    assert!(
                        body.points.iter().any(|&p| p < np),
                        "{what}: body {b} of coincident points only"
                    );
                }
            }
        }
    }
}

/// A discovery estimated to take longer than `max_minutes` is refused before its pair
/// statistics, or, once its bodies are found, before its model phases, with the estimate,
/// the limit and what to do; the default limit runs the same data.
#[test]
fn work_beyond_the_limit_is_refused_before_it_starts() {
    let data = simulate(&paper_arm(0)).expect("simulate");
    let (t, n) = (data.tracks.n_frames() as u64, data.tracks.n_points() as u64);
    let pairs = kinetree_core::limits::pairs_seconds(t, n);
    let model = kinetree_core::limits::model_seconds(t, 5);
    assert!(pairs < model / 10.0, "{pairs} s against {model} s");
    let with_limit = |seconds: f64, noise: Option<f64>| {
        let config = PipelineConfig {
            max_minutes: seconds / 60.0,
            noise_sigma_m: noise,
            ..PipelineConfig::default()
        };
        Pipeline::from_config(&config)
            .expect("pipeline")
            .run(&data.tracks)
    };
    // Below the pair statistics' estimate: refused before anything is computed.
    let e = with_limit(pairs / 2.0, None).expect_err("pair statistics");
    match &e {
        Error::TooLarge { what, hint, .. } => {
            assert!(what.starts_with("pair statistics of 100 frames"), "{e}");
            assert!(hint.contains("--max-minutes"), "{e}");
        }
        other => panic!("expected TooLarge, got {other:?}"),
    }
    // Between the two: the pair statistics and the clustering run, the model phases are
    // refused naming the bodies found, and an estimated noise level is named as a cause.
    let between = (pairs * model).sqrt();
    for (noise, advice) in [(None, true), (Some(1e-3), false)] {
        let e = with_limit(between, noise).expect_err("model phases");
        match &e {
            Error::TooLarge { what, hint, .. } => {
                assert!(what.starts_with("the bodies and model phases on"), "{e}");
                assert!(what.ends_with("bodies over 100 frames"), "{e}");
                assert_eq!(hint.contains("--noise-sigma"), advice, "{e}");
                assert!(hint.contains("`max_minutes` in [pipeline]"), "{e}");
            }
            other => panic!("expected TooLarge, got {other:?}"),
        }
    }
    let found = with_limit(60.0 * kinetree_core::limits::DEFAULT_MAX_MINUTES, None)
        .expect("the default limit");
    assert_eq!(structure(&found.model), structure(arm_model()));
    for bad in [f64::NAN, 0.0, -1.0] {
        let config = PipelineConfig {
            max_minutes: bad,
            ..PipelineConfig::default()
        };
        let e = Pipeline::from_config(&config).expect_err("not a limit");
        assert!(e.to_string().contains("pipeline.max_minutes"), "{e}");
    }
}
