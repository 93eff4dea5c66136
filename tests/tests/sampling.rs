//! Tracks with more points than `[pipeline.sampling] max_points`: the discovery runs on a
//! sample, and every other point is given to the body whose poses explain it. The structure
//! must come out as on every point, every point on its body, points that move with no body
//! left on none and named, and a body too small for the sample found by a second discovery.

use kinetree_core::{Tracks, Warning};
use kinetree_eval::evaluate;
use kinetree_pipeline::{Discovery, Pipeline, PipelineConfig};
use kinetree_synth::{ScaleParams, SynthData, scale_scenario, simulate};

fn config(max_points: usize, max_rounds: usize) -> PipelineConfig {
    let mut c = PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    };
    c.sampling.max_points = max_points;
    c.sampling.max_rounds = max_rounds;
    c
}

fn discover(tracks: &Tracks, c: &PipelineConfig) -> Discovery {
    Pipeline::from_config(c)
        .expect("pipeline")
        .run(tracks)
        .expect("discover")
}

/// The scale scenario (base and four links R-R-P-R) with `points[b]` keypoints on body `b`.
fn scale(points: [usize; 5], n_frames: usize, seed: u64) -> SynthData {
    let mut s = scale_scenario(&ScaleParams {
        n_points: 100,
        n_frames,
        seed,
        ..ScaleParams::default()
    });
    for (body, &n) in s.mechanism.bodies.iter_mut().zip(&points) {
        body.interior_points = n;
    }
    simulate(&s).expect("simulate")
}

/// `tracks` with `n` more points that wander (Lissajous curves of 5 cm over the scene, each
/// its own), rigid with nothing.
fn with_wanderers(tracks: &Tracks, n: usize) -> Tracks {
    let (t, np) = (tracks.n_frames(), tracks.n_points());
    let mut xyz = Vec::with_capacity(t * (np + n) * 3);
    for f in 0..t {
        xyz.extend_from_slice(tracks.frame_raw(f));
        for k in 0..n {
            let (f, k) = (f as f64, k as f64);
            xyz.extend_from_slice(&[
                0.05 * (0.05 * f + k).sin(),
                0.05 * (0.031 * f + 2.0 * k).sin(),
                0.3 + 0.05 * (0.043 * f + 0.5 * k).sin(),
            ]);
        }
    }
    Tracks::new(t, np + n, xyz).expect("tracks")
}

fn sampled_warning(model: &kinetree_core::Model) -> (usize, usize, Vec<usize>, usize) {
    model
        .warnings
        .iter()
        .find_map(|w| match w {
            Warning::TracksSampled {
                sampled,
                assigned,
                unexplained,
                rounds,
            } => Some((*sampled, *assigned, unexplained.clone(), *rounds)),
            _ => None,
        })
        .expect("a tracks_sampled warning")
}

#[test]
fn a_sampled_discovery_finds_the_structure_and_puts_every_point_on_its_body() {
    let data = scale([200, 200, 200, 200, 200], 150, 0);
    let wanderers = 8;
    let tracks = with_wanderers(&data.tracks, wanderers);
    let n_true = data.tracks.n_points();
    let sampled = discover(&tracks, &config(300, 2));
    let model = &sampled.model;
    model.validate().expect("a valid model");
    assert_eq!(model.n_points, n_true + wanderers);
    assert_eq!(sampled.sampled.as_ref().map(Vec::len), Some(300));
    assert_eq!(sampled.stats.n_points, 300);
    let (n_sampled, assigned, unexplained, rounds) = sampled_warning(model);
    assert_eq!((n_sampled, rounds), (300, 1));
    // Every wanderer is left on no body and named; no rigid point is.
    let wandering: Vec<usize> = (n_true..n_true + wanderers).collect();
    for &w in &wandering {
        assert_eq!(model.point_body[w], -1, "wanderer {w} is on a body");
    }
    let unexplained_rigid: Vec<&usize> = unexplained.iter().filter(|&&i| i < n_true).collect();
    assert!(unexplained_rigid.is_empty(), "{unexplained_rigid:?}");
    let on_bodies = model.point_body.iter().filter(|&&b| b >= 0).count();
    assert!(
        on_bodies >= assigned,
        "{on_bodies} on bodies, {assigned} assigned"
    );
    // The evaluation on the simulated points alone.
    let mut own = model.clone();
    own.n_points = n_true;
    own.point_body.truncate(n_true);
    for b in &mut own.bodies {
        let keep: Vec<bool> = b.points.iter().map(|&i| i < n_true).collect();
        b.points.retain(|&i| i < n_true);
        let mut k = keep.iter();
        b.shape.retain(|_| *k.next().unwrap_or(&true));
    }
    let e = evaluate(&own, &data.truth);
    assert!(e.joints_exact, "{e:?}");
    assert!(e.ari > 0.999, "ARI {}", e.ari);
    // Its joints are as precise as those found on every point.
    let full = discover(&data.tracks, &config(100_000, 2));
    let ef = evaluate(&full.model, &data.truth);
    assert!(full.sampled.is_none());
    for (s, f) in e.joints.iter().zip(&ef.joints) {
        let (sa, fa) = (
            s.axis_error_deg.expect("axis"),
            f.axis_error_deg.expect("axis"),
        );
        assert!(sa <= (3.0 * fa).max(0.1), "axis {sa} deg against {fa}");
        let (sr, fr) = (
            s.position_rms.expect("positions"),
            f.position_rms.expect("positions"),
        );
        assert!(sr <= 1.5 * fr + 1e-4, "positions {sr} against {fr}");
    }
    // The same sample and model again.
    let again = discover(&tracks, &config(300, 2));
    assert_eq!(again.sampled, sampled.sampled);
    assert_eq!(
        serde_json::to_string(&again.model).expect("json"),
        serde_json::to_string(model).expect("json")
    );
}

#[test]
fn a_body_too_small_for_the_sample_is_found_by_a_second_discovery() {
    let data = scale([400, 400, 400, 400, 16], 150, 1);
    let once = discover(&data.tracks, &config(40, 1)).model;
    let twice = discover(&data.tracks, &config(40, 2)).model;
    let (e1, e2) = (evaluate(&once, &data.truth), evaluate(&twice, &data.truth));
    let (_, _, unexplained, rounds) = sampled_warning(&once);
    assert_eq!(rounds, 1);
    assert!(!e1.joints_exact, "{e1:?}");
    assert!(unexplained.len() >= 12, "{unexplained:?}");
    let (_, _, _, rounds) = sampled_warning(&twice);
    assert_eq!(rounds, 2);
    assert!(e2.joints_exact, "{e2:?}");
    assert_eq!(e2.n_bodies_found, 5);
}

#[test]
fn sampling_parameters_out_of_range_are_errors_that_name_them() {
    for (key, value) in [
        ("max_points", "5"),
        ("max_rounds", "0"),
        ("misfit_slack", "0.5"),
    ] {
        let toml = format!("[sampling]\n{key} = {value}\n");
        let c: PipelineConfig = toml::from_str(&toml).expect("parses");
        let err = Pipeline::from_config(&c)
            .expect_err("out of range")
            .to_string();
        assert!(err.contains(&format!("pipeline.sampling.{key}")), "{err}");
    }
    let unknown: Result<PipelineConfig, _> = toml::from_str("[sampling]\nmax_point = 5\n");
    assert!(unknown.is_err_and(|e| e.to_string().contains("max_point")));
}
