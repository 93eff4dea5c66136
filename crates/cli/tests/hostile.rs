//! The `kinetree` binary under careless use: outputs naming inputs, closed pipes, absurd thread
//! counts, experiment names that leave the results folder. Each is refused with a message or
//! survived with the files written; none panics or loses a file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn kinetree() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_kinetree"));
    c.env("RUST_BACKTRACE", "0");
    c
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "kinetree-cli-hostile-{}-{name}",
        std::process::id()
    ));
    std::fs::create_dir_all(&d).expect("dir");
    d
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Fails the test unless the command failed cleanly (exit 1, no panic) with `needle` in its
/// message.
fn refused(out: &Output, needle: &str) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(needle), "expected {needle:?} in {err}");
}

/// A simulated paper arm in `dir`, with a model discovered from it.
fn simulated(dir: &Path) -> (PathBuf, PathBuf) {
    let out = kinetree()
        .args(["simulate", "--frames", "60", "-o"])
        .arg(dir)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", stderr(&out));
    let model = dir.join("model.json");
    let out = kinetree()
        .arg("discover")
        .arg(dir.join("tracks.npy"))
        .arg("-o")
        .arg(&model)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", stderr(&out));
    (dir.join("tracks.npy"), model)
}

#[test]
fn an_output_naming_an_input_is_refused_and_the_input_kept() {
    let dir = tmp("overwrite");
    let (tracks, model) = simulated(&dir);
    let before = (
        std::fs::read(&tracks).expect("tracks"),
        std::fs::read(&model).expect("model"),
    );
    // The same file through another spelling of its path.
    let dotted = dir.join(".").join("tracks.npy");
    let cases: Vec<Vec<std::ffi::OsString>> = vec![
        vec![
            "discover".into(),
            tracks.clone().into(),
            "-o".into(),
            dotted.into(),
        ],
        vec![
            "observe".into(),
            model.clone().into(),
            tracks.clone().into(),
            "-o".into(),
            model.clone().into(),
        ],
        vec![
            "observe".into(),
            model.clone().into(),
            tracks.clone().into(),
            "-o".into(),
            tracks.clone().into(),
        ],
        vec![
            "export".into(),
            model.clone().into(),
            "--format".into(),
            "json".into(),
            "-o".into(),
            model.clone().into(),
        ],
        vec![
            "fit-track".into(),
            tracks.clone().into(),
            "--point".into(),
            "3".into(),
            "-o".into(),
            tracks.clone().into(),
        ],
    ];
    for args in cases {
        let out = kinetree().args(&args).output().expect("runs");
        refused(&out, "is the input");
    }
    let after = (
        std::fs::read(&tracks).expect("tracks"),
        std::fs::read(&model).expect("model"),
    );
    assert!(before == after, "an input changed");
}

#[test]
fn a_closed_stdout_does_not_stop_the_model_being_written() {
    let dir = tmp("pipe");
    let (tracks, _) = simulated(&dir);
    let model = dir.join("piped.json");
    let mut child = kinetree()
        .arg("discover")
        .arg(&tracks)
        .arg("-o")
        .arg(&model)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawns");
    // Close the reading end at once, as `| true` does.
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("waits");
    assert!(out.status.success(), "{}", stderr(&out));
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).expect("model written"))
            .expect("json");
    assert!(written["bodies"].as_array().is_some_and(|b| b.len() >= 2));
}

#[test]
fn thread_counts_that_are_no_count_or_beyond_the_limit_are_refused() {
    let dir = tmp("threads");
    for (value, needle) in [
        ("100000", "above the limit"),
        ("many", "not a thread count"),
        ("-3", "not a thread count"),
    ] {
        let out = kinetree()
            .env("RAYON_NUM_THREADS", value)
            .args(["simulate", "-o"])
            .arg(&dir)
            .output()
            .expect("runs");
        refused(&out, needle);
    }
    let out = kinetree()
        .env("RAYON_NUM_THREADS", "3")
        .args(["simulate", "-o"])
        .arg(&dir)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", stderr(&out));
}

#[test]
fn an_experiment_name_must_stay_inside_the_results_folder() {
    let dir = tmp("names");
    let results = dir.join("results");
    for name in ["../escaped", "/abs", "a/b", "..", ""] {
        let config = dir.join("exp.toml");
        std::fs::write(
            &config,
            format!("[experiment]\nname = {name:?}\n\n[data]\nkind = \"paper_arm\"\n"),
        )
        .expect("write");
        let out = kinetree()
            .arg("run")
            .arg(&config)
            .arg("--results")
            .arg(&results)
            .output()
            .expect("runs");
        refused(&out, "experiment.name");
    }
    assert!(!dir.join("escaped").exists());
}

#[test]
fn a_write_cut_short_by_a_file_size_limit_keeps_the_old_model() {
    let dir = tmp("fsize");
    let (tracks, model) = simulated(&dir);
    let before = std::fs::read(&model).expect("model");
    assert!(before.len() > 16 * 1024, "the model must exceed the limit");
    // `ulimit -f 8`: files of at most 8 blocks (4 or 8 KiB); the write beyond it fails.
    let out = Command::new("sh")
        .arg("-c")
        .arg("ulimit -f 8 && exec \"$0\" discover \"$1\" -o \"$2\"")
        .arg(env!("CARGO_BIN_EXE_kinetree"))
        .arg(&tracks)
        .arg(&model)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("runs");
    assert!(!out.status.success(), "the write should have failed");
    assert_eq!(
        std::fs::read(&model).expect("model"),
        before,
        "model changed"
    );
}

/// Runs `kinetree observe` and returns its stderr and each row's residual.
fn observe_residuals(model: &Path, tracks: &Path, csv: &Path) -> (String, Vec<f64>) {
    let out = kinetree()
        .arg("observe")
        .arg(model)
        .arg(tracks)
        .arg("-o")
        .arg(csv)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(csv).expect("csv");
    let mut lines = text.lines();
    assert!(
        lines
            .next()
            .is_some_and(|h| h.ends_with(",residual_in_sigma"))
    );
    let residuals = lines
        .map(|l| {
            l.rsplit(',')
                .next()
                .and_then(|v| v.parse().ok())
                .unwrap_or(f64::NAN)
        })
        .collect();
    (stderr(&out), residuals)
}

#[test]
fn observe_flags_the_frames_the_model_does_not_explain() {
    let dir = tmp("observe-fit");
    let (_, model) = simulated(&dir);
    // The same mechanism recorded again (other noise): explained.
    let again = dir.join("again");
    let out = kinetree()
        .args(["simulate", "--seed", "7", "--frames", "60", "-o"])
        .arg(&again)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", stderr(&out));
    let tracks = again.join("tracks.npy");
    let (err, residuals) = observe_residuals(&model, &tracks, &dir.join("again.csv"));
    assert!(!err.contains("not explained"), "{err}");
    assert!(residuals.iter().all(|r| *r < 3.0), "{residuals:?}");
    // Millimetres instead of metres, pure noise, and the two links' points swapped.
    let t = kinetree_io::read_tracks(&tracks).expect("tracks");
    let (nf, np) = (t.n_frames(), t.n_points());
    let mm = t
        .map_points(|p| kinetree_core::nalgebra::Point3::from(p.coords * 1000.0))
        .expect("mm");
    let noise: Vec<f64> = (0..nf * np * 3)
        .map(|k| ((k * 7919) % 1000) as f64 * 1e-3 - 0.5)
        .collect();
    let noise = kinetree_core::Tracks::new(nf, np, noise).expect("noise");
    let model_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).expect("model")).expect("json");
    let body = |b: i64| -> Vec<usize> {
        model_json["point_body"]
            .as_array()
            .expect("point_body")
            .iter()
            .enumerate()
            .filter(|(_, v)| v.as_i64() == Some(b))
            .map(|(i, _)| i)
            .collect()
    };
    let (a, b) = (body(1), body(2));
    let mut order: Vec<usize> = (0..np).collect();
    for (x, y) in a.iter().zip(&b) {
        order.swap(*x, *y);
    }
    let frames: Vec<Vec<Option<kinetree_core::nalgebra::Point3<f64>>>> = (0..nf)
        .map(|f| order.iter().map(|&i| t.get(f, i)).collect())
        .collect();
    let swapped = kinetree_core::Tracks::from_points(&frames).expect("swapped");
    for (what, bad) in [("mm", mm), ("noise", noise), ("swapped", swapped)] {
        let path = dir.join(format!("{what}.npy"));
        kinetree_io::write_npy(&path, &bad).expect("write");
        let (err, residuals) = observe_residuals(&model, &path, &dir.join(format!("{what}.csv")));
        assert!(
            err.contains(&format!("{nf} of {nf} frames are not explained")),
            "{what}: {err}"
        );
        assert!(residuals.iter().all(|r| *r > 10.0), "{what}: {residuals:?}");
    }
}

#[test]
fn max_minutes_bounds_the_estimated_work_of_a_discovery() {
    let dir = tmp("minutes");
    let (tracks, _) = simulated(&dir);
    let model = dir.join("limited.json");
    let out = kinetree()
        .args(["discover", "--quiet", "--max-minutes", "0.00001"])
        .arg(&tracks)
        .arg("-o")
        .arg(&model)
        .output()
        .expect("runs");
    refused(&out, "bodies over 60 frames");
    refused(&out, "--max-minutes");
    assert!(!model.exists(), "a refused discovery writes no model");
    let out = kinetree()
        .args(["discover", "--max-minutes", "nan"])
        .arg(&tracks)
        .arg("-o")
        .arg(&model)
        .output()
        .expect("runs");
    refused(&out, "--max-minutes");
}

#[test]
fn simulate_names_the_option_a_value_out_of_range_came_from() {
    let dir = tmp("simulate-range");
    for (args, flag) in [
        (vec!["--frames", "1000000000000"], "`--frames`"),
        (
            vec!["--mechanism", "random", "--joints", "100000"],
            "`--joints`",
        ),
        (vec!["--noise-sigma", "nan"], "`--noise-sigma`"),
        (
            vec!["--mechanism", "random", "--dropout", "2"],
            "`--dropout`",
        ),
    ] {
        let out = kinetree()
            .arg("simulate")
            .args(&args)
            .arg("-o")
            .arg(&dir)
            .output()
            .expect("runs");
        refused(&out, flag);
    }
}
