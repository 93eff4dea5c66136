//! The repairs: each on a small hand-built scene (the paper arm with a segmentation or an
//! occlusion made by hand), with the repair on and off; every built-in repair through the
//! conformance check; the parameter rules of `[pipeline.repairs]` and `[pipeline.runner]`.

use kinetree_core::nalgebra::Point3;
use kinetree_core::{Clustering, ClusteringInput, Repair, Result, Segmentation, Tracks};
use kinetree_pipeline::config::pipeline_from_toml;
use kinetree_pipeline::conformance::check_repair;
use kinetree_pipeline::{Discovery, Pipeline, PipelineConfig, RepairsConfig};
use kinetree_synth::{SynthData, paper_arm, simulate};

/// A clusterer that returns a segmentation fixed by hand, whatever the matrix says.
#[derive(Debug)]
struct Fixed(Vec<Option<usize>>);

impl Clustering for Fixed {
    fn name(&self) -> &str {
        "fixed"
    }
    fn cluster(&self, _: &ClusteringInput<'_>) -> Result<Segmentation> {
        Ok(Segmentation::from_raw(&self.0, 1))
    }
}

/// The paper arm (base, link 1, link 2) at 1 mm.
fn arm() -> SynthData {
    simulate(&paper_arm(11)).expect("paper arm simulates")
}

/// The points of true body `b`.
fn points_of(data: &SynthData, b: usize) -> Vec<usize> {
    (0..data.truth.point_body.len())
        .filter(|&i| data.truth.point_body[i] == b)
        .collect()
}

/// The true labels, with `edit` applied.
fn labels(data: &SynthData, edit: impl FnOnce(&mut Vec<Option<usize>>)) -> Vec<Option<usize>> {
    let mut l: Vec<Option<usize>> = data.truth.point_body.iter().map(|&b| Some(b)).collect();
    edit(&mut l);
    l
}

/// The noise given, and the point-by-point check after the clustering off, so the hand-made
/// segmentation reaches the repairs as it is.
fn config() -> PipelineConfig {
    let mut c = PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    };
    c.runner.point_check = false;
    c
}

/// Discovers `tracks` with the clustering replaced by `labels`.
fn run(tracks: &Tracks, labels: &[Option<usize>], c: &PipelineConfig) -> Result<Discovery> {
    let mut p = Pipeline::from_config(c)?;
    p.clustering = Box::new(Fixed(labels.to_vec()));
    p.run(tracks)
}

/// Whether the model's trace names `repair`.
fn traced(d: &Discovery, repair: &str) -> bool {
    d.model.trace.iter().any(|e| e.repair == repair)
}

/// Whether the model puts all of `points` on one body, alone.
fn one_body(d: &Discovery, points: &[usize]) -> bool {
    let b = d.model.point_body[points[0]];
    b >= 0
        && points.iter().all(|&p| d.model.point_body[p] == b)
        && d.model.point_body.iter().filter(|&&x| x == b).count() == points.len()
}

#[test]
fn split_separates_two_links_clustered_as_one() {
    let data = arm();
    let (l1, l2) = (points_of(&data, 1), points_of(&data, 2));
    let mixed = labels(&data, |l| l2.iter().for_each(|&p| l[p] = Some(1)));
    let on = run(&data.tracks, &mixed, &config()).expect("discover");
    assert!(traced(&on, "split"), "trace: {:?}", on.model.trace);
    assert!(
        one_body(&on, &l1) && one_body(&on, &l2),
        "{:?}",
        on.model.point_body
    );
    let mut c = config();
    c.repairs.split.enabled = false;
    let off = run(&data.tracks, &mixed, &c).expect("discover");
    assert!(!traced(&off, "split"));
    assert!(
        !one_body(&off, &l2),
        "without the split the links stay one body"
    );
}

#[test]
fn merge_joins_the_halves_of_a_link_clustered_as_two() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let halves = labels(&data, |l| {
        l2.iter().step_by(2).for_each(|&p| l[p] = Some(3))
    });
    let on = run(&data.tracks, &halves, &config()).expect("discover");
    assert!(traced(&on, "merge"));
    assert!(one_body(&on, &l2), "{:?}", on.model.point_body);
    assert_eq!(on.model.bodies.len(), 3);
    let mut c = config();
    c.repairs.merge.enabled = false;
    let off = run(&data.tracks, &halves, &c).expect("discover");
    assert_eq!(
        off.model.bodies.len(),
        4,
        "without the merge the halves stay apart"
    );
}

#[test]
fn attach_gives_points_on_no_body_to_the_body_whose_poses_explain_them() {
    let data = arm();
    let l1 = points_of(&data, 1);
    let left = labels(&data, |l| l1[..2].iter().for_each(|&p| l[p] = None));
    let mut c = config();
    c.runner.model_passes = 0;
    let on = run(&data.tracks, &left, &c).expect("discover");
    assert!(
        traced(&on, "attach"),
        "{:?} {:?} {:?}",
        l1,
        on.model.point_body,
        on.model.trace
    );
    assert!(one_body(&on, &l1), "{:?}", on.model.point_body);
    c.repairs.attach.enabled = false;
    let off = run(&data.tracks, &left, &c).expect("discover");
    assert!(
        !one_body(&off, &l1),
        "without the attachment the two points stay off link 1"
    );
}

#[test]
fn regroup_makes_a_body_of_unassigned_points_that_move_as_one() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let left = labels(&data, |l| l2.iter().for_each(|&p| l[p] = None));
    let mut c = config();
    c.runner.model_passes = 0;
    c.repairs.hinge_groups.enabled = false;
    let on = run(&data.tracks, &left, &c).expect("discover");
    assert!(traced(&on, "regroup"));
    assert!(one_body(&on, &l2), "{:?}", on.model.point_body);
    c.repairs.regroup.enabled = false;
    let off = run(&data.tracks, &left, &c).expect("discover");
    assert!(l2.iter().all(|&p| off.model.point_body[p] < 0));
}

#[test]
fn hinge_groups_make_a_body_of_unassigned_points_turning_on_a_hinge() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let left = labels(&data, |l| l2.iter().for_each(|&p| l[p] = None));
    let mut c = config();
    c.runner.model_passes = 0;
    c.repairs.regroup.enabled = false;
    let on = run(&data.tracks, &left, &c).expect("discover");
    assert!(traced(&on, "hinge_groups"), "trace: {:?}", on.model.trace);
    assert!(one_body(&on, &l2), "{:?}", on.model.point_body);
    c.repairs.hinge_groups.enabled = false;
    let off = run(&data.tracks, &left, &c).expect("discover");
    assert!(l2.iter().all(|&p| off.model.point_body[p] < 0));
}

/// `tracks` with only the first two of `points` visible in three frames of four.
fn mostly_two_at_a_time(tracks: &Tracks, points: &[usize]) -> Tracks {
    let frames: Vec<Vec<Option<Point3<f64>>>> = (0..tracks.n_frames())
        .map(|t| {
            (0..tracks.n_points())
                .map(|i| {
                    let hidden = t % 4 != 0 && points[2..].contains(&i);
                    if hidden { None } else { tracks.get(t, i) }
                })
                .collect()
        })
        .collect();
    Tracks::from_points(&frames).expect("tracks")
}

#[test]
fn hinges_pose_a_link_seen_two_keypoints_at_a_time_through_its_joint() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let tracks = mostly_two_at_a_time(&data.tracks, &l2);
    let truth = labels(&data, |_| {});
    let registered = |d: &Discovery| {
        let b = d.model.point_body[l2[0]];
        d.model
            .bodies
            .iter()
            .find(|x| x.id as i64 == b)
            .map_or(0, |x| x.frames_registered)
    };
    let on = run(&tracks, &truth, &config()).expect("discover");
    assert!(traced(&on, "hinges"));
    let mut c = config();
    c.repairs.hinges.enabled = false;
    let off = run(&tracks, &truth, &c).expect("discover");
    assert!(
        registered(&on) as f64 >= 1.5 * registered(&off) as f64,
        "link 2 registered in {} frames with hinges, {} without",
        registered(&on),
        registered(&off)
    );
}

#[test]
fn drop_unposed_drops_a_body_registered_in_one_frame() {
    let data = arm();
    let l1 = points_of(&data, 1);
    let trio = [l1[0], l1[1], l1[2]];
    // The trio is seen whole only in frame 0.
    let frames: Vec<Vec<Option<Point3<f64>>>> = (0..data.tracks.n_frames())
        .map(|t| {
            (0..data.tracks.n_points())
                .map(|i| {
                    let hidden = t > 0 && trio[t % 3] == i;
                    if hidden { None } else { data.tracks.get(t, i) }
                })
                .collect()
        })
        .collect();
    let tracks = Tracks::from_points(&frames).expect("tracks");
    let apart = labels(&data, |l| trio.iter().for_each(|&p| l[p] = Some(3)));
    // Off, the hinges would pose the trio through link 1's joint.
    let mut c = config().with_hinges(false);
    let on = run(&tracks, &apart, &c).expect("discover");
    assert!(traced(&on, "drop_unposed"), "{:?}", on.model.trace);
    assert!(on.model.bodies.iter().all(|b| b.frames_registered >= 2));
    c.repairs.drop_unposed.enabled = false;
    let off = run(&tracks, &apart, &c);
    assert!(
        off.is_err()
            || off
                .as_ref()
                .is_ok_and(|d| d.model.bodies.iter().any(|b| b.frames_registered < 2)),
        "without the repair the one-frame body stays"
    );
}

#[test]
fn move_points_places_a_point_on_no_body_where_the_fitted_motion_explains_it() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let left = labels(&data, |l| l[l2[l2.len() - 1]] = None);
    // The attachment would place it from the per-body poses first.
    let mut c = config();
    c.repairs.attach.enabled = false;
    let on = run(&data.tracks, &left, &c).expect("discover");
    assert!(traced(&on, "move_points"), "trace: {:?}", on.model.trace);
    assert!(one_body(&on, &l2), "{:?}", on.model.point_body);
    c.repairs.move_points.enabled = false;
    let off = run(&data.tracks, &left, &c).expect("discover");
    assert!(!one_body(&off, &l2));
}

#[test]
fn eject_points_leaves_a_keypoint_that_fits_no_body_on_none() {
    let data = arm();
    let l1 = points_of(&data, 1);
    let n = data.tracks.n_points();
    // An extra keypoint that rides on link 1 with a 2 cm wobble: rigid to nothing.
    let frames: Vec<Vec<Option<Point3<f64>>>> =
        (0..data.tracks.n_frames())
            .map(|t| {
                let mut row: Vec<_> = (0..n).map(|i| data.tracks.get(t, i)).collect();
                let wobble = 0.02 * (t as f64 * 0.7).sin();
                row.push(data.tracks.get(t, l1[0]).map(|p| {
                    p + kinetree_core::nalgebra::Vector3::new(wobble, -wobble, 0.5 * wobble)
                }));
                row
            })
            .collect();
    let tracks = Tracks::from_points(&frames).expect("tracks");
    let mut with = labels(&data, |_| {});
    with.push(Some(1));
    let mut c = config();
    c.repairs.split.enabled = false;
    c.repairs.joint_spoilers.enabled = false;
    let on = run(&tracks, &with, &c).expect("discover");
    assert!(
        traced(&on, "eject_points"),
        "trace: {:?}\nbodies {:?}\nwarnings {:?}",
        on.model.trace,
        on.model.point_body,
        on.model.warnings
    );
    assert_eq!(on.model.point_body[n], -1);
    c.repairs.eject_points.enabled = false;
    let off = run(&tracks, &with, &c).expect("discover");
    assert!(off.model.point_body[n] >= 0);
}

#[test]
fn noise_refinement_refines_an_estimated_noise_level() {
    let data = arm();
    let estimated = PipelineConfig::default();
    let on = Pipeline::from_config(&estimated)
        .expect("pipeline")
        .group(&data.tracks)
        .expect("group");
    let mut off_config = estimated.clone();
    off_config.repairs.noise_refinement.enabled = false;
    let off = Pipeline::from_config(&off_config)
        .expect("pipeline")
        .group(&data.tracks)
        .expect("group");
    assert!(on.trace.iter().any(|e| e.repair == "noise_refinement"));
    assert!(off.trace.is_empty());
    assert_eq!(Some(off.noise_sigma_m), off.first_noise_estimate_m);
    assert_ne!(on.noise_sigma_m, off.noise_sigma_m);
    let limit = estimated.repairs.noise_refinement.limit;
    assert!((on.noise_sigma_m / off.noise_sigma_m - 1.0).abs() <= limit + 1e-12);
    assert!(
        (on.noise_sigma_m / 0.001 - 1.0).abs() < 0.05,
        "{}",
        on.noise_sigma_m
    );
}

#[test]
fn every_built_in_repair_conforms() {
    let repairs = RepairsConfig::default().build().expect("repairs");
    assert_eq!(
        repairs.len(),
        13,
        "one conformance line per built-in repair"
    );
    for r in &repairs {
        let v = check_repair(r.as_ref());
        assert!(v.is_empty(), "{}: {v:?}", r.name());
    }
}

/// A repair that panics is reported, not propagated.
#[test]
fn the_conformance_check_reports_a_panicking_repair() {
    #[derive(Debug)]
    struct Panics;
    impl Repair for Panics {
        fn name(&self) -> &str {
            "panics"
        }
        fn phase(&self) -> kinetree_core::RepairPhase {
            kinetree_core::RepairPhase::Bodies
        }
        fn propose(
            &self,
            _: &kinetree_core::RepairContext<'_>,
            _: &kinetree_core::Draft,
        ) -> Result<Option<kinetree_core::Proposal>> {
            panic!("on purpose")
        }
    }
    let v = check_repair(&Panics);
    assert!(v.iter().any(|m| m.contains("panicked")), "{v:?}");
}

#[test]
fn all_repairs_off_leaves_the_clustering_as_it_is() {
    let data = arm();
    let l2 = points_of(&data, 2);
    let mixed = labels(&data, |l| l2.iter().for_each(|&p| l[p] = Some(1)));
    let mut c = config();
    c.repairs = RepairsConfig::all_off();
    let d = run(&data.tracks, &mixed, &c).expect("discover");
    assert!(d.model.trace.is_empty(), "{:?}", d.model.trace);
    assert_eq!(d.model.bodies.len(), 2);
}

/// One row per parameter rule: the `[pipeline]` TOML, and the key the error must name.
#[test]
fn repair_parameter_rules_name_the_key() {
    let rows: &[(&str, &str)] = &[
        (
            "[repairs.split]\nresidual_in_sigma = -1.0",
            "pipeline.repairs.split.residual_in_sigma",
        ),
        (
            "[repairs.split]\nmax_rounds = 100000",
            "pipeline.repairs.split.max_rounds",
        ),
        (
            "[repairs.split]\nmin_frame_share = 1.5",
            "pipeline.repairs.split.min_frame_share",
        ),
        (
            "[repairs.split]\nlr_slack = nan",
            "pipeline.repairs.split.lr_slack",
        ),
        (
            "[repairs.merge]\nmax_rounds = 5000",
            "pipeline.repairs.merge.max_rounds",
        ),
        (
            "[repairs.merge]\nresidual_in_sigma = inf",
            "pipeline.repairs.merge.residual_in_sigma",
        ),
        (
            "[repairs.hinges]\nmax_reposed_share = 2.0",
            "pipeline.repairs.hinges.max_reposed_share",
        ),
        (
            "[repairs.hinges]\nmin_repose_gain = 0.5",
            "pipeline.repairs.hinges.min_repose_gain",
        ),
        (
            "[repairs.hinges]\nslack = 0.0",
            "pipeline.repairs.hinges.slack",
        ),
        (
            "[repairs.hinge_groups]\nmin_frames = 1",
            "pipeline.repairs.hinge_groups.min_frames",
        ),
        (
            "[repairs.hinge_groups]\nmax_rms_in_sigma = -3.0",
            "pipeline.repairs.hinge_groups.max_rms_in_sigma",
        ),
        (
            "[repairs.regroup]\nresidual_in_sigma = 0.0",
            "pipeline.repairs.regroup.residual_in_sigma",
        ),
        (
            "[repairs.drop_unposed]\nmin_frames = 0",
            "pipeline.repairs.drop_unposed.min_frames",
        ),
        (
            "[repairs.tree_ties]\ngain = 1.0",
            "pipeline.repairs.tree_ties.gain",
        ),
        (
            "[repairs.tree_ties]\nmax_alternatives = 1000",
            "pipeline.repairs.tree_ties.max_alternatives",
        ),
        (
            "[repairs.noise_refinement]\nlimit = 0.95",
            "pipeline.repairs.noise_refinement.limit",
        ),
        (
            "[repairs.noise_refinement]\nrounds = 1000",
            "pipeline.repairs.noise_refinement.rounds",
        ),
        (
            "[runner]\nmodel_passes = 1000",
            "pipeline.runner.model_passes",
        ),
        (
            "halves = { kind = \"hierarchical\" }",
            "pipeline.halves.n_clusters",
        ),
        // Unknown keys and the replaced key are refused by the parser, naming where.
        ("[repairs.split]\nbogus = 1", "pipeline.repairs.split"),
        ("[repairs.bogus]\nenabled = false", "pipeline.repairs"),
        (
            "[repairs.attach]\nenabled = 3",
            "pipeline.repairs.attach.enabled",
        ),
        ("[runner]\nbogus = 1", "pipeline.runner"),
        ("hinged_bodies = false", "pipeline.repairs.hinges.enabled"),
    ];
    for (text, key) in rows {
        let err = pipeline_from_toml(text)
            .and_then(|c| Pipeline::from_config(&c))
            .expect_err(text)
            .to_string();
        assert!(
            err.contains(key),
            "`{text}`: the error `{err}` does not name `{key}`"
        );
    }
    // And every default is valid and round-trips through the resolved TOML.
    let c = PipelineConfig::default();
    c.validate().expect("defaults are valid");
    let text = toml::to_string(&c).expect("serialise");
    assert!(text.contains("[repairs.split]") && text.contains("residual_in_sigma = 2.5"));
    assert_eq!(pipeline_from_toml(&text).expect("parse"), c);
}

/// Two links turning on the base about axes `tilt_deg` apart through one anchor.
fn siblings_on_one_anchor(tilt_deg: f64, seed: u64) -> SynthData {
    use kinetree_tests::build::{base, body, joint, scenario, sine};
    let t = tilt_deg.to_radians();
    let mechanism = kinetree_synth::Mechanism {
        bodies: vec![
            base(),
            body([0.15, 0.0, 0.12], [0.12, 0.03, 0.03], 8),
            body([-0.12, 0.06, 0.16], [0.1, 0.03, 0.03], 8),
        ],
        joints: vec![
            joint(0, 1, true, [0.0, 0.0, 1.0], [0.0, 0.0, 0.1]),
            joint(0, 2, true, [t.sin(), 0.0, t.cos()], [0.0, 0.0, 0.1]),
        ],
    };
    let mut s = scenario(
        mechanism,
        vec![sine(0.8, 0.2, 0.0), sine(0.9, 0.33, 1.0)],
        0.001,
    );
    s.seed = seed;
    simulate(&s).expect("simulate")
}

#[test]
#[ignore = "probe"]
fn probe_tree_ties() {
    for tilt in [2.0, 3.0, 5.0] {
        for seed in 0..6 {
            let data = siblings_on_one_anchor(tilt, seed);
            let run = |on: bool| {
                let mut c = PipelineConfig::default();
                c.repairs.tree_ties.enabled = on;
                let m = Pipeline::from_config(&c)
                    .expect("p")
                    .run(&data.tracks)
                    .expect("d")
                    .model;
                let e = kinetree_eval::evaluate(&m, &data.truth);
                (
                    e.joints_exact,
                    m.trace
                        .iter()
                        .filter(|x| x.repair == "tree_ties")
                        .map(|x| x.outcome.clone())
                        .collect::<Vec<_>>(),
                )
            };
            println!(
                "tilt {tilt} seed {seed}: on {:?} off {:?}",
                run(true),
                run(false)
            );
        }
    }
}
