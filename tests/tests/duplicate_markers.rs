//! Markers stored twice: a laboratory's export that keeps each marker under its own label and
//! under a model's label, the two tracks within rounding of each other
//! (`[pipeline.duplicates]`).

use kinetree_core::nalgebra::{Point3, Vector3};
use kinetree_core::{Tracks, Warning};
use kinetree_pipeline::PipelineConfig;
use kinetree_synth::{SkeletonParams, SynthData, simulate, skeleton_scenario};

fn skeleton(seed: u64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        plug_in_gait_markers: true,
        floating_pelvis: true,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

/// `tracks` with a copy of every point in `copied` appended, each sample off by a few
/// hundredths of a millimetre (a file's rounding), seen where the original is.
fn with_copies(tracks: &Tracks, copied: &[usize]) -> Tracks {
    let frames: Vec<Vec<Option<Point3<f64>>>> = (0..tracks.n_frames())
        .map(|t| {
            let mut row: Vec<Option<Point3<f64>>> =
                (0..tracks.n_points()).map(|i| tracks.get(t, i)).collect();
            row.extend(copied.iter().enumerate().map(|(k, &i)| {
                let off = 2e-5 * ((3 * t + 5 * k) as f64).sin();
                tracks.get(t, i).map(|p| p + Vector3::new(off, -off, off))
            }));
            row
        })
        .collect();
    Tracks::from_points(&frames).expect("tracks")
}

/// With every marker of the limbs stored twice, the motion-capture pipeline leaves the copies
/// out, names each and the marker it repeats, and finds the model it finds without them (the
/// same body for every marker). With the check off the copies join bodies, each counting its
/// marker twice in every fit.
#[test]
fn markers_stored_twice_are_left_out_and_named() {
    for seed in 0..3 {
        let data = skeleton(seed);
        let n = data.tracks.n_points();
        let copied: Vec<usize> = (12..n).collect();
        let doubled = with_copies(&data.tracks, &copied);
        let config = PipelineConfig::motion_capture();
        let plain = kinetree_tests::discover_with(&data.tracks, &config);
        let model = kinetree_tests::discover_with(&doubled, &config);
        let named = model.warnings.iter().find_map(|w| match w {
            Warning::PointsDuplicated { points, of, .. } => Some((points.clone(), of.clone())),
            _ => None,
        });
        let (points, of) = named.expect("a duplicates warning");
        assert_eq!(points, (n..n + copied.len()).collect::<Vec<_>>());
        assert_eq!(of, copied);
        assert!(
            !model
                .warnings
                .iter()
                .any(|w| matches!(w, Warning::PointNeverVisible { point } if *point >= n)),
            "a copy also reported as never visible"
        );
        assert!(
            model.point_body[n..].iter().all(|&b| b < 0),
            "a copy on a body"
        );
        assert_eq!(&model.point_body[..n], &plain.point_body[..], "seed {seed}");
        assert_eq!(model.joints.len(), plain.joints.len(), "seed {seed}");
        let mut off = config.clone();
        off.duplicates.enabled = false;
        let kept = kinetree_tests::discover_with(&doubled, &off);
        assert!(
            kept.point_body[n..].iter().any(|&b| b >= 0),
            "seed {seed}: with the check off no copy joins a body"
        );
    }
}
