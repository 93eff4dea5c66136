//! Invariances: the discovered structure does not depend on the camera pose, the order of
//! the points, the unit of length, the direction of time or dropping every other frame.
//! Fixed seeds of the random box mechanisms, and rates over the strategies' random
//! mechanisms (`PROPTEST_CASES` of them, 64 by default).

use kinetree_core::nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use kinetree_core::{Model, Tracks};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{RandomParams, random_scenario, simulate};
use kinetree_tests::{cases, rate_draw};

/// The structure as point sets: bodies, and joints as (parent points, child points, type).
#[derive(Debug, Clone, PartialEq, Eq)]
struct Structure {
    bodies: Vec<Vec<usize>>,
    joints: Vec<(Vec<usize>, Vec<usize>, kinetree_core::model::JointType)>,
    static_body: Option<Vec<usize>>,
}

/// `original_index[i]` is the index in the original tracks of point `i` of these tracks.
fn structure(m: &Model, original_index: &[usize]) -> Structure {
    let points = |b: usize| {
        let mut p: Vec<usize> = m.bodies[b]
            .points
            .iter()
            .map(|&i| original_index[i])
            .collect();
        p.sort_unstable();
        p
    };
    let mut bodies: Vec<Vec<usize>> = (0..m.bodies.len()).map(points).collect();
    bodies.sort();
    let mut joints: Vec<(Vec<usize>, Vec<usize>, kinetree_core::model::JointType)> = m
        .joints
        .iter()
        .map(|j| (points(j.parent), points(j.child), j.joint_type))
        .collect();
    joints.sort();
    Structure {
        bodies,
        joints,
        static_body: m.static_body.map(points),
    }
}

fn discover(tracks: &Tracks, sigma: Option<f64>) -> Model {
    Pipeline::from_config(&PipelineConfig {
        noise_sigma_m: sigma,
        ..PipelineConfig::default()
    })
    .expect("pipeline")
    .run(tracks)
    .expect("discover")
    .model
}

fn base(seed: u64) -> (Tracks, Structure) {
    let p = RandomParams {
        n_joints: 3,
        prismatic_fraction: 0.5,
        seed,
        ..RandomParams::default()
    };
    let tracks = simulate(&random_scenario(&p)).expect("simulate").tracks;
    let identity: Vec<usize> = (0..tracks.n_points()).collect();
    let s = structure(&discover(&tracks, Some(0.001)), &identity);
    (tracks, s)
}

const SEEDS: [u64; 3] = [2, 3, 5];

/// A fixed scramble of `n` points: reversed, then rotated by a third.
fn fixed_scramble(n: usize) -> Vec<usize> {
    (0..n).map(|k| (n - 1 - k + n / 3) % n).collect()
}

/// `tracks` with its points in `order` (`order[i]` is the original index of point `i`).
fn reordered(tracks: &Tracks, order: &[usize]) -> Tracks {
    let frames: Vec<Vec<Option<Point3<f64>>>> = (0..tracks.n_frames())
        .map(|t| order.iter().map(|&i| tracks.get(t, i)).collect())
        .collect();
    Tracks::from_points(&frames).expect("reordered")
}

#[test]
fn moving_the_camera_changes_nothing() {
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        let motion = Isometry3::from_parts(
            Translation3::new(0.7, -1.2, 0.4),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.1, 0.8)),
        );
        let moved = tracks.map_points(|p| motion * p).expect("moved");
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        assert_eq!(
            structure(&discover(&moved, Some(0.001)), &identity),
            expected,
            "seed {seed}"
        );
    }
}

#[test]
fn permuting_the_points_permutes_the_result() {
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        let order = fixed_scramble(tracks.n_points());
        let permuted = reordered(&tracks, &order);
        assert_eq!(
            structure(&discover(&permuted, Some(0.001)), &order),
            expected,
            "seed {seed}"
        );
    }
}

/// A random tree in which one body is posed in only two frames: its pair tests over one
/// centred column came out rigid or revolute with the rounding of sums over its points, and
/// the point order then changed the joints and the root.
#[test]
fn a_tree_with_a_briefly_posed_body_does_not_depend_on_the_point_order() {
    let p = RandomParams {
        n_joints: 8,
        tree: true,
        prismatic_fraction: 0.3,
        n_frames: 200,
        noise_sigma_m: 0.001,
        seed: 10,
        ..RandomParams::default()
    };
    let tracks = simulate(&random_scenario(&p)).expect("simulate").tracks;
    let n = tracks.n_points();
    let identity: Vec<usize> = (0..n).collect();
    let expected = structure(&discover(&tracks, Some(0.001)), &identity);
    let reversed: Vec<usize> = (0..n).rev().collect();
    for order in [reversed, fixed_scramble(n)] {
        let permuted = reordered(&tracks, &order);
        assert_eq!(
            structure(&discover(&permuted, Some(0.001)), &order),
            expected
        );
    }
}

#[test]
fn millimetres_with_sigma_scaled_give_the_same_structure() {
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        let mm = tracks
            .map_points(|p| Point3::from(p.coords * 1000.0))
            .expect("mm");
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        assert_eq!(
            structure(&discover(&mm, Some(1.0)), &identity),
            expected,
            "seed {seed} given sigma"
        );
        assert_eq!(
            structure(&discover(&mm, None), &identity),
            expected,
            "seed {seed} estimated sigma"
        );
    }
}

#[test]
fn reversing_time_gives_the_same_structure() {
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        let reversed: Vec<usize> = (0..tracks.n_frames()).rev().collect();
        let r = tracks.select_frames(&reversed).expect("reversed");
        assert_eq!(
            structure(&discover(&r, Some(0.001)), &identity),
            expected,
            "seed {seed}"
        );
    }
}

/// Seed 3 at T = 100 needs two of the model phase's rules: a point of the last link seen in
/// 16 frames is clustered with the first link, whose fitted poses it spoils so that it may
/// leave only as an outlier (see `kinetree_fit::OUTLIER_RATIO`), and three points seen in 6-7
/// frames are placed only because 5 frames suffice (`MIN_FRAMES_TO_PLACE`).
#[test]
fn dropping_every_other_frame_gives_the_same_structure() {
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        let halved: Vec<usize> = (0..tracks.n_frames()).step_by(2).collect();
        let h = tracks.select_frames(&halved).expect("halved");
        assert_eq!(
            structure(&discover(&h, Some(0.001)), &identity),
            expected,
            "seed {seed}"
        );
    }
}

#[test]
fn a_moving_camera_gives_the_same_joints_and_no_static_body() {
    use kinetree_core::Warning;
    for seed in SEEDS {
        let (tracks, expected) = base(seed);
        // A different rigid motion of the whole scene in every frame: nothing is static.
        let frames: Vec<Vec<Option<Point3<f64>>>> = (0..tracks.n_frames())
            .map(|t| {
                let s = t as f64 * 0.05;
                let camera = Isometry3::from_parts(
                    Translation3::new(0.3 * s.sin(), 0.2 * (0.7 * s).cos(), 0.1 * s),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.2 * s.sin(), 0.4 * s, 0.1)),
                );
                (0..tracks.n_points())
                    .map(|i| tracks.get(t, i).map(|p| camera * p))
                    .collect()
            })
            .collect();
        let moving = Tracks::from_points(&frames).expect("moving camera");
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        let m = discover(&moving, Some(0.001));
        let got = structure(&m, &identity);
        assert_eq!(got.bodies, expected.bodies, "seed {seed}");
        assert!(m.static_body.is_none(), "seed {seed}");
        assert!(
            m.warnings
                .iter()
                .any(|w| matches!(w, Warning::NoStaticBody { .. }))
        );
        // Same joints up to direction (the root may be another body now).
        let undirected = |s: &Structure| {
            let mut j: Vec<(Vec<usize>, Vec<usize>, kinetree_core::model::JointType)> = s
                .joints
                .iter()
                .map(|(a, b, t)| {
                    if a < b {
                        (a.clone(), b.clone(), *t)
                    } else {
                        (b.clone(), a.clone(), *t)
                    }
                })
                .collect();
            j.sort();
            j
        };
        assert_eq!(undirected(&got), undirected(&expected), "seed {seed}");
    }
}

/// The structure found on `tracks` with the default pipeline (noise estimated), or the error's
/// text; `original_index` as in [`structure`].
fn found(tracks: &Tracks, original_index: &[usize]) -> std::result::Result<Structure, String> {
    Pipeline::from_config(&PipelineConfig::default())
        .and_then(|p| p.run(tracks))
        .map(|d| structure(&d.model, original_index))
        .map_err(|e| e.to_string())
}

/// The order `order[i]` = original index of point `i`, shuffled by `rng`.
fn shuffled(n: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<usize> {
    use rand::seq::SliceRandom;
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(rng);
    order
}

/// The five transforms of the invariance rate test, in its order.
const TRANSFORMS: [&str; 5] = [
    "camera moved",
    "points permuted",
    "millimetres",
    "time reversed",
    "every other frame dropped",
];

/// Each transform of a mechanism's tracks with the original index of each of its points: a
/// rigid motion of the whole scene and a permutation of the points (both drawn from `rng`),
/// millimetres instead of metres, time reversed, every other frame dropped.
fn transformed(tracks: &Tracks, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<(Tracks, Vec<usize>)> {
    use rand::Rng;
    let n = tracks.n_points();
    let identity: Vec<usize> = (0..n).collect();
    let mut draw = |scale: f64| Vector3::from_fn(|_, _| rng.random_range(-scale..scale));
    let motion = Isometry3::from_parts(
        Translation3::from(draw(2.0)),
        UnitQuaternion::from_scaled_axis(draw(3.0)),
    );
    let order = shuffled(n, rng);
    let reversed: Vec<usize> = (0..tracks.n_frames()).rev().collect();
    let halved: Vec<usize> = (0..tracks.n_frames()).step_by(2).collect();
    vec![
        (
            tracks.map_points(|p| motion * p).expect("moved"),
            identity.clone(),
        ),
        (reordered(tracks, &order), order),
        (
            tracks
                .map_points(|p| Point3::from(p.coords * 1000.0))
                .expect("mm"),
            identity.clone(),
        ),
        (
            tracks.select_frames(&reversed).expect("reversed"),
            identity.clone(),
        ),
        (tracks.select_frames(&halved).expect("halved"), identity),
    ]
}

/// Invariances over the strategies' random mechanisms (1-8 joints, 2-50 cm bodies, 0-5 mm
/// noise, 0-40 % occlusion): on `cases()` mechanisms of the rate test's deterministic draw,
/// the structure found (bodies as point sets, joints with their types, the default pipeline
/// with the noise estimated) after each of [`TRANSFORMS`] equals the original one.
///
/// Exact equality cannot hold for every mechanism: the transforms change the rounding of
/// every computation, and a 4-point body with three visible points nearly collinear amplifies
/// it (its poses differed by 1e-8 between metres and millimetres), so a decision that sits on
/// its threshold can go either way; dropping frames halves the data. So each is a rate.
/// Measured on 640 draws (`PROPTEST_CASES=640`): 640 the same with the camera moved, 639
/// with the points permuted (the miss a mechanism the rate test also fails), 640 in
/// millimetres and with time reversed, 619 with every other frame dropped. Decisions that
/// could depend on the numbering, the unit or the direction of time are made independent of
/// them: the pair tests take the better-posed body as the frame (`docs/decisions.md`,
/// `kinetree_pipeline::all_pairs`), the noise-free floor sits above the later iterations'
/// precision (`kinetree_dissimilarity::estimate_noise_sigma`), and the whole-tree fit's
/// tolerances follow the noise level rather than metres. Required: the measured rates less a
/// case per 64 (two for the dropped frames).
#[test]
fn invariances_hold_on_most_mechanisms() {
    use rand::SeedableRng;
    let n = cases() as usize;
    let mut differ: Vec<Vec<usize>> = vec![Vec::new(); TRANSFORMS.len()];
    for (case, spec) in rate_draw(n).iter().enumerate() {
        let tracks = simulate(&spec.scenario()).expect("simulate").tracks;
        let identity: Vec<usize> = (0..tracks.n_points()).collect();
        let expected = found(&tracks, &identity);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(case as u64);
        for (k, (t, index)) in transformed(&tracks, &mut rng).iter().enumerate() {
            if found(t, index) != expected {
                differ[k].push(case);
            }
        }
    }
    for (k, name) in TRANSFORMS.iter().enumerate() {
        eprintln!("{name}: {} of {n} differ {:?}", differ[k].len(), differ[k]);
    }
    for (k, name) in TRANSFORMS.iter().enumerate() {
        let same = n - differ[k].len();
        let required = n * if k == 4 { 58 } else { 63 } / 64;
        assert!(
            same >= required,
            "{name}: {same} of {n} the same, {required} required; differ: {:?}",
            differ[k]
        );
    }
}

/// Two mechanisms of the rate test's draw whose tree changes when their points are permuted
/// (reversed, then rotated by a third) if the pair tests take the lower-numbered body as the
/// frame: a pair's test of `b` in `a`'s frame is not that of `a` in `b`'s, and the numbering
/// follows the points. The pair tests take the better-posed body as the frame.
#[test]
fn permuting_the_points_of_drawn_mechanisms_permutes_the_result() {
    let specs = rate_draw(101);
    for case in [81, 100] {
        let tracks = simulate(&specs[case].scenario()).expect("simulate").tracks;
        let n = tracks.n_points();
        let order = fixed_scramble(n);
        let permuted = reordered(&tracks, &order);
        let identity: Vec<usize> = (0..n).collect();
        assert_eq!(
            found(&permuted, &order),
            found(&tracks, &identity),
            "case {case}"
        );
    }
}

/// The model does not depend on the number of threads: the fit's parallel parts (the
/// bundle adjustment's per-frame terms and refits, the joint-freeing round's candidates, the
/// typing and readmitting trials, made as many at a time as there are threads) are combined
/// in a fixed order. Random 10-joint trees: seed 10 frees joints on its way (the trace shows
/// `free_joints`), so every parallel part runs; seed 30 readmits a freed joint and types two
/// joints in one call, so trials after an accepted one are made again on the new fit.
/// Compared bit for bit through the model's JSON.
#[test]
fn the_model_does_not_depend_on_the_number_of_threads() {
    let pipeline = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    let json = |m: &Model| serde_json::to_string(m).expect("json");
    for seed in [10, 30] {
        let p = RandomParams {
            n_joints: 10,
            tree: true,
            seed,
            ..RandomParams::default()
        };
        let data = simulate(&random_scenario(&p)).expect("simulate");
        let run_with = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            pool.install(|| pipeline.run(&data.tracks).expect("discover").model)
        };
        let one = run_with(1);
        let applied = |repair: &str, summary: &str| {
            one.trace.iter().any(|t| {
                t.repair == repair && t.outcome == "applied" && t.summary.starts_with(summary)
            })
        };
        let wanted = if seed == 10 {
            applied("free_joints", "")
        } else {
            applied("readmit_joints", "") && applied("type_by_fit", "2 joint(s)")
        };
        assert!(
            wanted,
            "seed {seed}: the scene no longer shows its repairs; pick another"
        );
        for threads in [2, 3] {
            assert!(
                json(&run_with(threads)) == json(&one),
                "seed {seed}, {threads} threads"
            );
        }
    }
}
