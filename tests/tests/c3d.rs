//! C3D input: the five real recordings under experiments/real/data, files written here for
//! every processor and data format, and damaged files (random damage is in fuzz.rs).

use kinetree_io::{c3d_tracks, read_c3d, read_npy};
use kinetree_tests::{RECORDINGS, real_c3d as c3d_in, real_data as data};

#[test]
fn every_real_recording_reads_with_its_labels() {
    for dir in RECORDINGS {
        let t = read_c3d(&c3d_in(dir)).unwrap_or_else(|e| panic!("{dir}: {e}"));
        let labels: Vec<String> = serde_json::from_str(
            &std::fs::read_to_string(data(dir).join("labels.json")).expect("labels"),
        )
        .expect("json");
        let ours = t.labels().expect("labels").to_vec();
        // Kinetics Toolkit's racing file has six probe markers missing in every frame; the
        // reference conversion dropped them, we keep them (never visible).
        let kept: Vec<String> = ours
            .iter()
            .enumerate()
            .filter(|&(i, _)| t.visible_count(i) > 0)
            .map(|(_, l)| l.clone())
            .collect();
        assert!(ours == labels || kept == labels, "{dir}: {ours:?}");
        // Metres: a human or a wheelchair spans 0.1-20 m.
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for f in 0..t.n_frames() {
            for i in 0..t.n_points() {
                if let Some(p) = t.get(f, i) {
                    for c in 0..3 {
                        lo[c] = lo[c].min(p[c]);
                        hi[c] = hi[c].max(p[c]);
                    }
                }
            }
        }
        let span = (0..3).map(|c| hi[c] - lo[c]).fold(0.0, f64::max);
        assert!((0.1..20.0).contains(&span), "{dir}: span {span} m");
    }
}

/// The reference arrays were converted with ezc3d by the people who collected the data.
#[test]
fn real_recordings_match_an_independent_reader() {
    for dir in ["c3dorg-fullbody-triads", "c3dorg-qualisys-walk"] {
        let ours = read_c3d(&c3d_in(dir)).expect("c3d");
        let theirs = read_npy(&data(dir).join("reference-tracks.npy")).expect("npy");
        assert_eq!(
            (ours.n_frames(), ours.n_points()),
            (theirs.n_frames(), theirs.n_points())
        );
        for f in 0..ours.n_frames() {
            for i in 0..ours.n_points() {
                match (ours.get(f, i), theirs.get(f, i)) {
                    (Some(a), Some(b)) => assert!((a - b).norm() < 1e-9, "{dir} {f} {i}"),
                    (None, None) => {}
                    (a, b) => panic!("{dir} frame {f} point {i}: {a:?} vs {b:?}"),
                }
            }
        }
    }
}

/// A Vicon Nexus export (`experiments/real/data/gaitalytics-treadmill`) stores 124 points: 26
/// markers, 46 Plug-in Gait outputs in `POINT:ANGLES`, `FORCES`, `MOMENTS` and `POWERS`, 16
/// modelled copies of markers in `POINT:MODELED_MARKERS` (a group `POINT:TYPE_GROUPS` lists) and
/// 36 segment axes that no group names. The reader keeps the 26 markers, names what it left
/// out, and nothing it keeps repeats another point's track.
#[test]
fn a_vicon_export_keeps_its_markers_and_names_the_models_points() {
    let dir = "gaitalytics-treadmill";
    let t = read_c3d(&c3d_in(dir)).expect("c3d");
    let labels: Vec<String> = serde_json::from_str(
        &std::fs::read_to_string(data(dir).join("labels.json")).expect("labels"),
    )
    .expect("json");
    assert_eq!(t.labels().expect("labels"), labels);
    assert_eq!((t.n_frames(), t.n_points()), (1206, 26));
    assert_eq!(t.frame_rate_hz(), Some(100.0));
    let mut skipped = 0;
    for w in t.warnings() {
        match w {
            kinetree_core::Warning::C3dOutputsSkipped { groups, labels } => {
                assert_eq!(
                    groups,
                    &["ANGLES", "FORCES", "MOMENTS", "POWERS", "MODELED_MARKERS"]
                );
                assert_eq!(labels.len(), 62);
                assert!(
                    labels.iter().any(|l| l == "LASI") && labels.iter().any(|l| l == "LHipAngles")
                );
                skipped += labels.len();
            }
            kinetree_core::Warning::ModelPointsSkipped { labels } => {
                assert_eq!(labels.len(), 36);
                assert!(labels.iter().all(|l| l.len() == 4));
                skipped += labels.len();
            }
            other => panic!("unexpected warning {other}"),
        }
    }
    assert_eq!(skipped, 124 - 26);
    // The markers are seen in every frame, and no two of them keep within a millimetre (the
    // modelled copies did, at 0.015-0.044 mm).
    for i in 0..26 {
        assert_eq!(t.visible_count(i), 1206, "{}", labels[i]);
        for j in 0..i {
            let near = (0..1206)
                .filter(|&f| {
                    (t.get(f, i).expect("seen") - t.get(f, j).expect("seen")).norm() < 1e-3
                })
                .count();
            assert_eq!(near, 0, "{} and {}", labels[i], labels[j]);
        }
    }
}

/// A model's noise-free output stored as integers on a 0.1 mm grid: static markers keep their
/// rounding in every frame, so their distances do not vary at all, and the noise estimate would
/// fall below the rounding. It is raised to the rounding's std-dev (step / sqrt 12) with a
/// warning, and the hinge is still found; stored as floats, no grid is known and no such
/// warning is given.
#[test]
fn noise_estimates_stop_at_the_rounding_of_integer_samples() {
    let base = [
        [100.0, 0.0, 0.0],
        [0.0, 100.0, 0.0],
        [0.0, 0.0, 100.0],
        [80.0, 80.0, 20.0],
    ];
    let arm = [
        [300.0, 50.0, 30.0],
        [400.0, -40.0, 60.0],
        [350.0, 20.0, -50.0],
        [450.0, 0.0, 10.0],
    ];
    let frames: Vec<Vec<Option<[f64; 3]>>> = (0..80)
        .map(|t| {
            let a = 1.2 * (f64::from(t) / 9.0).sin();
            let (s, c) = a.sin_cos();
            // The arm turns about the vertical line through (200, 0, 0).
            let turn = |p: &[f64; 3]| {
                let (x, y) = (p[0] - 200.0, p[1]);
                Some([200.0 + c * x - s * y, s * x + c * y, p[2]])
            };
            base.iter()
                .map(|p| Some(*p))
                .chain(arm.iter().map(turn))
                .collect()
        })
        .collect();
    let labels = ["B1", "B2", "B3", "B4", "A1", "A2", "A3", "A4"];
    let integer = c3d_tracks(&write_c3d(Proc::Intel, false, &labels, &frames)).expect("c3d");
    assert!((integer.precision_m().expect("grid") - 1e-4).abs() < 1e-10);
    let model =
        kinetree_pipeline::Pipeline::from_config(&kinetree_pipeline::PipelineConfig::default())
            .expect("pipeline")
            .run(&integer)
            .expect("discover")
            .model;
    let floor = 1e-4 / 12f64.sqrt();
    assert!(
        (model.noise.sigma_m - floor).abs() < 1e-10,
        "{}",
        model.noise.sigma_m
    );
    assert!(model.warnings.iter().any(|w| matches!(
        w,
        kinetree_core::Warning::NoiseAtPrecision { precision_m, .. } if (precision_m - 1e-4).abs() < 1e-10
    )));
    assert_eq!(model.bodies.len(), 2);
    assert!(
        model
            .joints
            .iter()
            .any(|j| j.joint_type == kinetree_core::model::JointType::Revolute),
        "{:?}",
        model.joints
    );
    let float = c3d_tracks(&write_c3d(Proc::Intel, true, &labels, &frames)).expect("c3d");
    assert_eq!(float.precision_m(), None);
    let model =
        kinetree_pipeline::Pipeline::from_config(&kinetree_pipeline::PipelineConfig::default())
            .expect("pipeline")
            .run(&float)
            .expect("discover")
            .model;
    assert!(
        !model
            .warnings
            .iter()
            .any(|w| matches!(w, kinetree_core::Warning::NoiseAtPrecision { .. }))
    );
}

#[derive(Debug, Clone, Copy)]
enum Proc {
    Intel,
    Dec,
    Mips,
}

/// A C3D file written from scratch: `frames[t][i] = Some([x, y, z])` in millimetres, `None`
/// for an invalid sample (residual -1).
fn write_c3d(
    proc: Proc,
    float: bool,
    labels: &[&str],
    frames: &[Vec<Option<[f64; 3]>>],
) -> Vec<u8> {
    write_c3d_counting(proc, float, labels, frames, labels.len(), labels.len(), &[])
}

/// [`write_c3d`] with the header's point count and `POINT:USED` given (the data keep a stride
/// of every label), and `POINT` string parameters `groups` (name, strings) such as `ANGLES`.
fn write_c3d_counting(
    proc: Proc,
    float: bool,
    labels: &[&str],
    frames: &[Vec<Option<[f64; 3]>>],
    header_points: usize,
    used: usize,
    groups: &[(&str, &[&str])],
) -> Vec<u8> {
    let i16b = |v: i16| match proc {
        Proc::Mips => v.to_be_bytes(),
        _ => v.to_le_bytes(),
    };
    let f32b = |v: f32| match proc {
        Proc::Intel => v.to_le_bytes(),
        Proc::Mips => v.to_be_bytes(),
        Proc::Dec => {
            let b = (v * 4.0).to_le_bytes();
            [b[2], b[3], b[0], b[1]]
        }
    };
    let n = labels.len();
    let scale: f32 = if float { -0.1 } else { 0.1 };
    let mut header = vec![0u8; 512];
    header[0] = 2;
    header[1] = 0x50;
    header[2..4].copy_from_slice(&i16b(header_points as i16));
    header[6..8].copy_from_slice(&i16b(1));
    header[8..10].copy_from_slice(&i16b(frames.len() as i16));
    header[12..16].copy_from_slice(&f32b(scale));
    header[16..18].copy_from_slice(&i16b(3));
    header[20..24].copy_from_slice(&f32b(100.0));
    let mut params = vec![
        1u8,
        0x50,
        1,
        match proc {
            Proc::Intel => 84,
            Proc::Dec => 85,
            Proc::Mips => 86,
        },
    ];
    params.extend([5u8, (-1i8) as u8]);
    params.extend(b"POINT");
    params.extend(i16b(3));
    params.push(0);
    let mut param = |name: &str, kind: i8, dims: &[u8], data: &[u8]| {
        params.extend([name.len() as u8, 1]);
        params.extend(name.as_bytes());
        params.extend(i16b((2 + 1 + 1 + dims.len() + data.len() + 1) as i16));
        params.push(kind as u8);
        params.push(dims.len() as u8);
        params.extend(dims);
        params.extend(data);
        params.push(0);
    };
    param("USED", 2, &[], &i16b(used as i16));
    param("SCALE", 4, &[], &f32b(scale));
    param("DATA_START", 2, &[], &i16b(3));
    param("UNITS", -1, &[2], b"mm");
    let width = labels.iter().map(|l| l.len()).max().unwrap_or(1);
    let mut text = Vec::new();
    for l in labels {
        text.extend(format!("{l:<width$}").as_bytes());
    }
    param("LABELS", -1, &[width as u8, n as u8], &text);
    for (name, strings) in groups {
        let width = strings.iter().map(|l| l.len()).max().unwrap_or(1);
        let mut text = Vec::new();
        for l in *strings {
            text.extend(format!("{l:<width$}").as_bytes());
        }
        param(name, -1, &[width as u8, strings.len() as u8], &text);
    }
    params.extend([0, 0]);
    params.resize(512, 0);
    let mut out = header;
    out.extend(params);
    for frame in frames {
        for p in frame {
            let (xyz, residual) = match p {
                Some(p) => (*p, 1.0),
                None => ([0.0; 3], -1.0),
            };
            for v in xyz.iter().chain([&residual]) {
                if float {
                    out.extend(f32b(*v as f32));
                } else {
                    out.extend(i16b((v / f64::from(scale)).round() as i16));
                }
            }
        }
    }
    out
}

#[test]
fn written_files_read_back_for_every_processor_and_format() {
    let frames = vec![
        vec![Some([100.0, -250.5, 1200.0]), None, Some([0.0, 0.0, 0.0])],
        vec![
            Some([110.0, -240.0, 1190.5]),
            Some([5.0, 6.0, 7.0]),
            Some([1.0, 2.0, 3.0]),
        ],
    ];
    for proc in [Proc::Intel, Proc::Dec, Proc::Mips] {
        for float in [false, true] {
            let bytes = write_c3d(proc, float, &["LASI", "RASI", "C7"], &frames);
            let t = c3d_tracks(&bytes).unwrap_or_else(|e| panic!("{proc:?} float {float}: {e}"));
            assert_eq!((t.n_frames(), t.n_points()), (2, 3));
            assert_eq!(t.labels().expect("labels"), ["LASI", "RASI", "C7"]);
            // No POINT:RATE: the header's rate, in the processor's float format.
            assert_eq!(t.frame_rate_hz(), Some(100.0), "{proc:?}");
            for (f, frame) in frames.iter().enumerate() {
                for (i, p) in frame.iter().enumerate() {
                    let got = t.get(f, i);
                    match p {
                        // Missing (residual -1) and exactly zero are not visible.
                        None => assert!(got.is_none()),
                        Some(p) if *p == [0.0; 3] => assert!(got.is_none()),
                        Some(p) => {
                            let g = got.expect("visible");
                            for c in 0..3 {
                                // Millimetres to metres; int data rounds to the 0.1 mm scale.
                                assert!(
                                    (g[c] - p[c] * 1e-3).abs() < 1e-7,
                                    "{proc:?} {float} {f} {i}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn damaged_files_give_typed_errors() {
    let frames = vec![vec![Some([1.0, 2.0, 3.0]); 3]; 4];
    let good = write_c3d(Proc::Intel, true, &["A", "B", "C"], &frames);
    assert!(c3d_tracks(&good).is_ok());
    let truncated = &good[..good.len() - 10];
    let e = c3d_tracks(truncated).expect_err("truncated");
    assert!(e.to_string().contains("truncated"), "{e}");
    let mut bad_key = good.clone();
    bad_key[1] = 0;
    assert!(c3d_tracks(&bad_key).is_err());
    let mut bad_proc = good.clone();
    bad_proc[512 + 3] = 99;
    assert!(
        c3d_tracks(&bad_proc)
            .expect_err("processor")
            .to_string()
            .contains("processor")
    );
    assert!(c3d_tracks(&[]).is_err());
    // Through the file reader the error names the file.
    let p = std::env::temp_dir().join(format!("kinetree-bad-{}.c3d", std::process::id()));
    std::fs::write(&p, truncated).expect("write");
    let e = kinetree_io::read_tracks(&p).expect_err("bad file");
    assert!(e.to_string().contains(&p.display().to_string()), "{e}");
}

#[test]
fn point_counts_that_disagree_are_errors_and_unused_labels_warnings() {
    let frames = vec![vec![Some([1.0, 2.0, 3.0]); 4]; 5];
    let labels = ["A", "B", "C", "D"];
    // POINT:USED below the header's count and the labels: the stride would be wrong.
    let used_low = write_c3d_counting(Proc::Intel, true, &labels, &frames, 4, 3, &[]);
    let e = c3d_tracks(&used_low).expect_err("USED below the header");
    assert!(e.to_string().contains("POINT:USED"), "{e}");
    // Both counts edited down: four labels for three points. Writers leave unused label
    // slots, so this reads, and the extra name is reported, not dropped in silence.
    let both_low = write_c3d_counting(Proc::Intel, true, &labels, &frames, 3, 3, &[]);
    let t = c3d_tracks(&both_low).expect("labels beyond USED");
    assert_eq!(t.labels().expect("labels"), ["A", "B", "C"]);
    assert_eq!(
        t.warnings(),
        [kinetree_core::Warning::C3dLabelsUnused {
            points_used: 3,
            labels: vec!["D".into()],
        }]
    );
    assert!(c3d_tracks(&write_c3d(Proc::Intel, true, &labels, &frames)).is_ok());
}

/// Four frames of `n` points in millimetres: point `i` of frame `t` at
/// `(100 i + t, 20, 30 + i)`, so each point's samples tell which column they came from.
fn spaced_points(n: usize) -> Vec<Vec<Option<[f64; 3]>>> {
    (0..4)
        .map(|t| {
            (0..n)
                .map(|i| Some([100.0 * i as f64 + f64::from(t), 20.0, 30.0 + i as f64]))
                .collect()
        })
        .collect()
}

/// Vicon and Plug-in Gait store joint angles, forces, moments and powers as points and name
/// them in `POINT:ANGLES`, `POINT:MOMENTS`, ...: they are left out, with a warning naming
/// them, and a file of nothing else is an error.
#[test]
fn modelling_outputs_stored_as_points_are_skipped_with_a_warning() {
    let labels = ["LASI", "LHipAngles", "RASI", "LHipMoment", "C7"];
    let frames = spaced_points(labels.len());
    let groups: [(&str, &[&str]); 2] = [
        ("ANGLES", &["LHipAngles", "RHipAngles"]),
        ("MOMENTS", &["LHipMoment"]),
    ];
    for proc in [Proc::Intel, Proc::Mips] {
        let bytes = write_c3d_counting(proc, true, &labels, &frames, 5, 5, &groups);
        let t = c3d_tracks(&bytes).expect("c3d");
        assert_eq!(t.labels().expect("labels"), ["LASI", "RASI", "C7"]);
        // The markers keep their own samples: RASI is the file's third point.
        let p = t.get(3, 1).expect("visible");
        assert!(
            (p.x - 0.203).abs() < 1e-6 && (p.z - 0.032).abs() < 1e-6,
            "{p:?}"
        );
        assert_eq!(
            t.warnings(),
            [kinetree_core::Warning::C3dOutputsSkipped {
                groups: vec!["ANGLES".into(), "MOMENTS".into()],
                labels: vec!["LHipAngles".into(), "LHipMoment".into()],
            }]
        );
    }
    let only = write_c3d_counting(
        Proc::Intel,
        true,
        &["LHipAngles"],
        &vec![vec![Some([1.0, 2.0, 3.0])]; 3],
        1,
        1,
        &groups,
    );
    let e = c3d_tracks(&only).expect_err("no markers");
    assert!(e.to_string().contains("POINT:ANGLES"), "{e}");
}

/// Vicon lists its output groups in `POINT:TYPE_GROUPS` (group and type name pairs), among
/// them `MODELED_MARKERS`, the model's copies of the markers; Plug-in Gait also stores each
/// segment's axes as four points (`PELO`, `PELA`, `PELL`, `PELP`) that no group names. Both
/// are left out with warnings naming them; a lone `LFEO` without its quartet is kept.
#[test]
fn type_groups_and_plug_in_gait_segment_axes_are_skipped_with_warnings() {
    let labels = [
        "LASI", "PELO", "PELA", "RASI", "PELL", "PELP", "LASIm", "LFEO", "C7",
    ];
    let frames = spaced_points(labels.len());
    let groups: [(&str, &[&str]); 2] = [
        ("TYPE_GROUPS", &["MODELED_MARKERS", "MODELED_MARKER"]),
        ("MODELED_MARKERS", &["LASIm"]),
    ];
    let n = labels.len();
    for proc in [Proc::Intel, Proc::Dec] {
        let bytes = write_c3d_counting(proc, true, &labels, &frames, n, n, &groups);
        let t = c3d_tracks(&bytes).expect("c3d");
        assert_eq!(t.labels().expect("labels"), ["LASI", "RASI", "LFEO", "C7"]);
        // RASI keeps its own samples: it is the file's fourth point.
        let p = t.get(2, 1).expect("visible");
        assert!((p.x - 0.302).abs() < 1e-6, "{p:?}");
        assert_eq!(
            t.warnings(),
            [
                kinetree_core::Warning::C3dOutputsSkipped {
                    groups: vec!["MODELED_MARKERS".into()],
                    labels: vec!["LASIm".into()],
                },
                kinetree_core::Warning::ModelPointsSkipped {
                    labels: ["PELO", "PELA", "PELL", "PELP"].map(String::from).to_vec(),
                },
            ]
        );
    }
    // Without TYPE_GROUPS the modelled copy is an ordinary point.
    let bytes = write_c3d_counting(Proc::Intel, true, &labels, &frames, n, n, &groups[1..]);
    let t = c3d_tracks(&bytes).expect("c3d");
    assert!(t.labels().expect("labels").contains(&"LASIm".to_string()));
    // A file of nothing but segment axes has no markers.
    let axes = ["PELO", "PELA", "PELL", "PELP"];
    let four: Vec<Vec<Option<[f64; 3]>>> = frames.iter().map(|f| f[..4].to_vec()).collect();
    let only = write_c3d_counting(Proc::Intel, true, &axes, &four, 4, 4, &[]);
    let e = c3d_tracks(&only).expect_err("no markers");
    assert!(e.to_string().contains("segment axes"), "{e}");
}

/// The case the fuzz test (tests/tests/fuzz.rs) shrank to when the parameter walk multiplied
/// dimensions unchecked: an integer overflow panic in debug builds.
#[test]
fn overflowing_parameter_dimensions_are_an_error() {
    let mut b = std::fs::read(c3d_in("c3dorg-fullbody-triads")).expect("read");
    b.truncate(21915);
    let at = 25732 % b.len();
    b[at] = 11;
    assert!(c3d_tracks(&b).is_err());
}
