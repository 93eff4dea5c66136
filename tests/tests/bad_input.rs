//! Every bad-input case of issue 2 gets its typed error, naming the file and the position.

use kinetree_core::{Error, Tracks};
use kinetree_io::{read_csv, read_model, read_npy, read_tracks};
use npyz::WriterBuilder;
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kinetree-bad-input-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

fn write_npy_f64(path: &Path, shape: &[u64], data: &[f64]) {
    let f = std::fs::File::create(path).expect("create");
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(f)
        .begin_nd()
        .expect("header");
    w.extend(data.iter().copied()).expect("data");
    w.finish().expect("finish");
}

fn root(e: &Error) -> &Error {
    e.root()
}

fn names_file(e: &Error, path: &Path) {
    assert!(
        matches!(e, Error::File { .. }),
        "{e:?} should name the file"
    );
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");
}

fn good(t: usize, n: usize) -> Vec<f64> {
    (0..t * n * 3)
        .map(|k| (k % 7) as f64 * 0.1 + (k / 3) as f64 * 1e-3)
        .collect()
}

#[test]
fn npy_wrong_dtype() {
    let p = tmp("i32.npy");
    let f = std::fs::File::create(&p).expect("create");
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[2, 3, 3])
        .writer(f)
        .begin_nd()
        .expect("header");
    w.extend(0..18i32).expect("data");
    w.finish().expect("finish");
    let e = read_npy(&p).expect_err("integer coordinates rejected");
    names_file(&e, &p);
    assert!(
        matches!(root(&e), Error::DType { found, .. } if found == "<i4"),
        "{e:?}"
    );
}

#[test]
fn npy_wrong_shape() {
    for shape in [vec![4u64, 9], vec![2, 3, 2]] {
        let p = tmp("shape.npy");
        let len: u64 = shape.iter().product();
        write_npy_f64(&p, &shape, &vec![0.5; len as usize]);
        let e = read_npy(&p).expect_err("bad shape");
        assert!(matches!(root(&e), Error::Shape { .. }), "{e:?}");
    }
}

#[test]
fn npy_partly_nan_and_inf_are_located() {
    let p = tmp("nan.npy");
    let mut d = good(4, 3);
    d[(2 * 3 + 1) * 3 + 1] = f64::NAN; // frame 2, point 1, y only
    write_npy_f64(&p, &[4, 3, 3], &d);
    let e = read_npy(&p).expect_err("partial NaN");
    names_file(&e, &p);
    assert!(
        matches!(root(&e), Error::PartialNan { frame: 2, point: 1 }),
        "{e:?}"
    );

    let mut d = good(4, 3);
    d[(3 * 3 + 2) * 3] = f64::INFINITY;
    write_npy_f64(&p, &[4, 3, 3], &d);
    let e = read_npy(&p).expect_err("inf");
    assert!(
        matches!(root(&e), Error::NonFinite { frame: 3, point: 2 }),
        "{e:?}"
    );
}

#[test]
fn too_few_frames_points_and_no_visible_data() {
    let p = tmp("small.npy");
    write_npy_f64(&p, &[1, 3, 3], &good(1, 3));
    assert!(matches!(
        root(&read_npy(&p).expect_err("T=1")),
        Error::TooFewFrames { found: 1, .. }
    ));
    write_npy_f64(&p, &[5, 2, 3], &good(5, 2));
    assert!(matches!(
        root(&read_npy(&p).expect_err("N=2")),
        Error::TooFewPoints { found: 2, .. }
    ));
    write_npy_f64(&p, &[5, 4, 3], &[f64::NAN; 60]);
    assert!(matches!(
        root(&read_npy(&p).expect_err("all NaN")),
        Error::NoVisibleData
    ));
    assert!(matches!(
        Tracks::new(3, 4, vec![0.0; 5]),
        Err(Error::Shape { .. })
    ));
}

#[test]
fn npy_garbage_is_malformed() {
    let p = tmp("garbage.npy");
    std::fs::write(&p, b"not an npy file at all").expect("write");
    let e = read_npy(&p).expect_err("garbage");
    names_file(&e, &p);
    assert!(matches!(root(&e), Error::Malformed { .. }), "{e:?}");
}

fn csv(name: &str, body: &str) -> PathBuf {
    let p = tmp(name);
    std::fs::write(&p, body).expect("write");
    p
}

#[test]
fn csv_errors_name_the_line() {
    let cases = [
        ("header.csv", "f,p,x,y,z\n0,0,1,2,3\n", "line 1"),
        ("fields.csv", "frame,point,x,y,z\n0,0,1,2\n", "line 2"),
        (
            "negative.csv",
            "frame,point,x,y,z\n0,0,1,2,3\n-1,0,1,2,3\n",
            "line 3",
        ),
        (
            "huge.csv",
            "frame,point,x,y,z\n0,99999999999,1,2,3\n",
            "line 2",
        ),
        ("number.csv", "frame,point,x,y,z\n0,0,1,abc,3\n", "line 2"),
        ("inf.csv", "frame,point,x,y,z\n0,0,1,inf,3\n", "line 2"),
        (
            "dup.csv",
            "frame,point,x,y,z\n0,0,1,2,3\n0,0,1,2,3\n",
            "data row 2",
        ),
        ("empty.csv", "", "line 1"),
        (
            "declared.csv",
            "# frames=2 points=3\nframe,point,x,y,z\n0,3,1,2,3\n",
            "line 3",
        ),
        ("baddecl.csv", "# frames=x\nframe,point,x,y,z\n", "line 1"),
    ];
    for (name, body, position) in cases {
        let p = csv(name, body);
        let e = read_csv(&p).expect_err(name);
        names_file(&e, &p);
        assert!(
            matches!(root(&e), Error::Malformed { position: pos, .. } if pos == position),
            "{name}: {e}"
        );
    }
    let p = csv("novis.csv", "frame,point,x,y,z\n");
    assert!(matches!(
        root(&read_csv(&p).expect_err("no rows")),
        Error::NoVisibleData
    ));
    let p = csv("twopoints.csv", "frame,point,x,y,z\n0,0,1,2,3\n1,1,1,2,3\n");
    assert!(matches!(
        root(&read_csv(&p).expect_err("N=2")),
        Error::TooFewPoints { .. }
    ));
}

#[test]
fn unknown_extension_and_bad_model_json() {
    let p = csv("tracks.txt", "whatever");
    assert!(matches!(
        root(&read_tracks(&p).expect_err("ext")),
        Error::Malformed { .. }
    ));
    let p = csv("model.json", "{\"schema_version\": 1, \"bodies\": [");
    let e = read_model(&p).expect_err("truncated JSON");
    names_file(&e, &p);
    assert!(matches!(root(&e), Error::Malformed { .. }), "{e:?}");
}

#[test]
fn bad_pipeline_parameters_are_typed_errors() {
    use kinetree_pipeline::{ExperimentConfig, Pipeline, PipelineConfig};
    let cfg = PipelineConfig {
        noise_sigma_m: Some(-1.0),
        ..PipelineConfig::default()
    };
    assert!(matches!(
        Pipeline::from_config(&cfg),
        Err(Error::InvalidParameter { .. })
    ));
    let negative_error = "[dof]\nkind = \"chi2_rank\"\nmodel_error_m = -0.001\n";
    let cfg = kinetree_pipeline::config::pipeline_from_toml(negative_error).expect("parses");
    assert!(matches!(
        Pipeline::from_config(&cfg),
        Err(Error::InvalidParameter { ref name, .. }) if name == "pipeline.dof.model_error_m"
    ));
    for key in ["hidden_hinge_ratio", "hidden_hinge_min_angle_deg"] {
        let bad = format!("[dof]\nkind = \"chi2_rank\"\n{key} = -1.0\n");
        let cfg = kinetree_pipeline::config::pipeline_from_toml(&bad).expect("parses");
        assert!(matches!(
            Pipeline::from_config(&cfg),
            Err(Error::InvalidParameter { ref name, .. }) if *name == format!("pipeline.dof.{key}")
        ));
    }
    // A stage's parameter is named with its section.
    let cut = "clustering = { kind = \"hierarchical\", cut = -1.0 }\n";
    let cfg = kinetree_pipeline::config::pipeline_from_toml(cut).expect("parses");
    assert!(matches!(
        Pipeline::from_config(&cfg),
        Err(Error::InvalidParameter { ref name, .. }) if name == "pipeline.clustering.cut"
    ));
    // The README's block, with its `[pipeline]` header, is read as a pipeline config.
    let readme = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"),
    )
    .expect("README");
    let block = readme
        .split("```toml\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("a toml block");
    assert!(block.starts_with("[pipeline]"), "{block}");
    let cfg = kinetree_pipeline::config::pipeline_from_toml(block).expect("the README's block");
    Pipeline::from_config(&cfg).expect("valid");
    assert!(matches!(
        cfg.dof,
        kinetree_pipeline::config::DofConfig::SvdRank(_)
    ));
    // The clusterers on the spectral embedding: their `embedding` table is checked like the
    // rest, and DBSCAN cannot be the halves slot.
    let gmm = "clustering = { kind = \"spectral_gmm\", embedding = { max_clusters = 30 } }\n";
    let cfg = kinetree_pipeline::config::pipeline_from_toml(gmm).expect("parses");
    Pipeline::from_config(&cfg).expect("valid");
    let typo = "clustering = { kind = \"spectral_gmm\", embedding = { max_cluster = 30 } }\n";
    let e = kinetree_pipeline::config::pipeline_from_toml(typo).expect_err("typo in a key");
    assert!(e.to_string().contains("max_cluster"), "{e}");
    let wide = "clustering = { kind = \"spectral_dbscan\", eps = 5.0 }\n";
    let cfg = kinetree_pipeline::config::pipeline_from_toml(wide).expect("parses");
    assert!(matches!(
        Pipeline::from_config(&cfg),
        Err(Error::InvalidParameter { ref name, .. }) if name == "pipeline.clustering.eps"
    ));
    let halves = "halves = { kind = \"spectral_dbscan\" }\n";
    let cfg = kinetree_pipeline::config::pipeline_from_toml(halves).expect("parses");
    assert!(matches!(
        Pipeline::from_config(&cfg),
        Err(Error::InvalidParameter { ref name, .. }) if name == "pipeline.halves.kind"
    ));
    let text = "[experiment]\nname = \"x\"\n[data]\nkind = \"paper_arm\"\nsede = 3\n";
    let e = ExperimentConfig::from_toml(text).expect_err("typo in a key");
    assert!(
        matches!(e, Error::Config(ref m) if m.contains("sede")),
        "{e}"
    );
}

#[test]
fn constant_and_sparse_data_give_typed_errors() {
    use kinetree_pipeline::{Pipeline, PipelineConfig};
    // Four points that never move and carry no noise.
    let frame = [0.0, 0.0, 1.0, 0.1, 0.0, 1.0, 0.0, 0.1, 1.0, 0.1, 0.1, 1.1];
    let xyz: Vec<f64> = (0..5).flat_map(|_| frame).collect();
    let constant = Tracks::new(5, 4, xyz).expect("valid");
    let estimate = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    let e = estimate.run(&constant).expect_err("no noise to estimate");
    assert!(
        matches!(&e, Error::Degenerate(m) if m.contains("constant")),
        "{e}"
    );
    // With a given noise level the same data are one static body.
    let given = Pipeline::from_config(&PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    })
    .expect("pipeline");
    let m = given.run(&constant).expect("one static body").model;
    assert_eq!(m.bodies.len(), 1);
    assert_eq!(m.static_body, Some(0));
    assert!(m.joints.is_empty());
    // Each point visible in a single frame: nothing can be paired.
    let mut xyz = vec![f64::NAN; 3 * 3 * 3];
    for k in 0..3 {
        xyz[(k * 3 + k) * 3..(k * 3 + k) * 3 + 3].copy_from_slice(&[0.1 * k as f64, 0.0, 1.0]);
    }
    let sparse = Tracks::new(3, 3, xyz).expect("valid");
    assert!(matches!(given.run(&sparse), Err(Error::Degenerate(_))));
    assert!(matches!(estimate.run(&sparse), Err(Error::Degenerate(_))));
    // Stage 1 alone says the same.
    let e = estimate.group(&constant).expect_err("no noise to estimate");
    assert!(
        matches!(&e, Error::Degenerate(m) if m.contains("constant")),
        "{e}"
    );
    let g = given.group(&constant).expect("one group");
    assert_eq!(g.segmentation.n_bodies(), 1);
    // Nothing paired: no body, and a warning per point (the whole run then has no body to
    // pose and says so).
    let g = given.group(&sparse).expect("stage 1 runs");
    assert_eq!(g.segmentation.n_bodies(), 0);
    for point in 0..3 {
        assert!(
            g.warnings.iter().any(
                |w| matches!(w, kinetree_core::Warning::PointUnpaired { point: p } if *p == point)
            ),
            "{:?}",
            g.warnings
        );
    }
    assert!(matches!(estimate.group(&sparse), Err(Error::Degenerate(_))));
}

/// A model file whose joint reference pose is no rigid transform (a zero quaternion, or a
/// translation that is not finite) is refused by the observer and by the URDF export, naming
/// the joint's reference pose, instead of being fitted or written with NaN.
#[test]
fn a_reference_pose_that_is_no_rigid_transform_is_a_typed_error() {
    let data = kinetree_synth::simulate(&kinetree_synth::paper_arm(0)).expect("simulate");
    let model = kinetree_pipeline::Pipeline::from_config(&Default::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
        .model;
    for bad in [[0.0, 0.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0, 1.0]] {
        let mut m = model.clone();
        if let Some(r) = m.joints[0].reference_pose.as_mut() {
            r.rotation_xyzw = bad;
        }
        let e = kinetree_fit::Observer::new(&m).expect_err("observer");
        assert!(
            matches!(e, Error::Config(_)) && e.to_string().contains("reference_pose"),
            "{e}"
        );
        let e = kinetree_io::export::to_urdf(&m).expect_err("urdf");
        assert!(e.to_string().contains("reference_pose"), "{e}");
    }
    let mut m = model;
    if let Some(r) = m.joints[0].reference_pose.as_mut() {
        r.translation[1] = f64::INFINITY;
    }
    let e = kinetree_fit::Observer::new(&m).expect_err("observer");
    assert!(e.to_string().contains("reference_pose"), "{e}");
}

/// Sizes and fractions of a random mechanism out of range, and a sweep asking for more seeds
/// than it can hold, are typed errors naming the key, not panics.
#[test]
fn random_data_and_sweep_sizes_out_of_range_are_typed_errors() {
    use kinetree_pipeline::config::DataConfig;
    let cases = [
        (
            kinetree_synth::RandomParams {
                prismatic_fraction: f64::NAN,
                ..Default::default()
            },
            "data.prismatic_fraction",
        ),
        (
            kinetree_synth::RandomParams {
                n_joints: 100_000,
                ..Default::default()
            },
            "data.n_joints",
        ),
        (
            kinetree_synth::RandomParams {
                extra_points: 1_000_000_000,
                ..Default::default()
            },
            "data.extra_points",
        ),
        (
            kinetree_synth::RandomParams {
                n_frames: 1_000_000_000_000,
                ..Default::default()
            },
            "data.n_frames",
        ),
        (
            kinetree_synth::RandomParams {
                dropout: 1.5,
                ..Default::default()
            },
            "data.dropout",
        ),
    ];
    for (params, key) in cases {
        let e = kinetree_pipeline::load_data(&DataConfig::Random(params), Path::new("."), 8.0)
            .expect_err(key);
        assert!(
            matches!(e, Error::InvalidParameter { ref name, .. } if name == key),
            "{key}: {e}"
        );
    }
    // The sweep refuses the size before it expands the grid.
    let text = "[experiment]\nname = \"x\"\n[sweep]\nseeds = 9223372036854775807\n[data]\nkind = \"random\"\n";
    let e = kinetree_pipeline::sweep::Sweep::from_toml(text).expect_err("too many seeds");
    assert!(e.to_string().contains("sweep.seeds"), "{e}");
    // A sweep point with bad data fails as a run, without a panic.
    let text = "[experiment]\nname = \"x\"\n[sweep]\nseeds = 1\n[data]\nkind = \"random\"\nprismatic_fraction = nan\n";
    let sweep = kinetree_pipeline::sweep::Sweep::from_toml(text).expect("parses");
    let c = sweep.config(0, 0).expect("config");
    let e = kinetree_pipeline::run_experiment(&c, Path::new(".")).expect_err("bad data");
    assert!(e.to_string().contains("data.prismatic_fraction"), "{e}");
}
