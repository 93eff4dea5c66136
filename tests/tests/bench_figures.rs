//! The scaling figure of `docs/benchmarks.md`: discovery time of the scale scenario against
//! the number of keypoints and of frames, drawn from the medians in
//! `docs/figures/scaling.csv` (one `cargo bench -p kinetree-pipeline --bench discovery -- rrpr`
//! run). `KINETREE_WRITE_FIGURES=1 cargo test -p kinetree-tests --test bench_figures` redraws
//! `docs/figures/scaling.svg` after the table is updated.

use kinetree_figures::{ScalingPanel, write_scaling_plot};
use std::path::{Path, PathBuf};

fn docs() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs")
}

/// The two panels from the table: time against keypoints (1000 frames) and against frames
/// (1000 keypoints).
fn panels() -> Vec<ScalingPanel> {
    let text = std::fs::read_to_string(docs().join("figures/scaling.csv")).expect("scaling.csv");
    let mut rows = text.lines();
    assert_eq!(rows.next(), Some("axis,size,seconds"), "header");
    let mut points = (Vec::new(), Vec::new());
    for row in rows {
        let f: Vec<&str> = row.split(',').collect();
        assert_eq!(f.len(), 3, "row `{row}`");
        let p = (
            f[1].parse::<f64>().expect("size"),
            f[2].parse::<f64>().expect("seconds"),
        );
        match f[0] {
            "points" => points.0.push(p),
            "frames" => points.1.push(p),
            other => panic!("unknown axis `{other}`"),
        }
    }
    vec![
        ScalingPanel {
            title: "1000 frames".into(),
            size: "keypoints N".into(),
            points: points.0,
        },
        ScalingPanel {
            title: "1000 keypoints".into(),
            size: "frames T".into(),
            points: points.1,
        },
    ]
}

#[test]
fn the_scaling_figure_draws_both_series_from_the_table() {
    let panels = panels();
    assert!(panels.iter().all(|p| p.points.len() >= 3), "{panels:?}");
    let dir = std::env::temp_dir().join(format!("kinetree-scaling-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("scaling.svg");
    write_scaling_plot(&path, &panels).expect("draw");
    let svg = std::fs::read_to_string(&path).expect("svg");
    for needle in [
        "1000 frames",
        "1000 keypoints",
        "keypoints N",
        "frames T",
        "quadratic",
    ] {
        assert!(svg.contains(needle), "the figure lacks `{needle}`");
    }
    // One marker per measured point.
    let markers = svg.matches("<circle").count();
    let expected: usize = panels.iter().map(|p| p.points.len()).sum();
    assert_eq!(markers, expected);
    std::fs::remove_dir_all(&dir).ok();
    if std::env::var_os("KINETREE_WRITE_FIGURES").is_some() {
        write_scaling_plot(&docs().join("figures/scaling.svg"), &panels).expect("write");
    }
}

#[test]
fn a_panel_without_positive_times_is_refused_by_name() {
    let panel = ScalingPanel {
        title: "broken".into(),
        size: "N".into(),
        points: vec![(100.0, 0.0)],
    };
    let path = std::env::temp_dir().join("kinetree-never-written.svg");
    let err = write_scaling_plot(&path, &[panel]).expect_err("refused");
    assert!(err.to_string().contains("broken"), "{err}");
    assert!(!path.exists());
}
