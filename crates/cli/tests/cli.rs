//! The `kinetree` binary: the README's run command, and simulate -> discover.

use std::path::Path;
use std::process::Command;

fn kinetree() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kinetree"))
}

/// Runs the command and returns its stdout, failing the test with its stderr if it fails.
fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn read_json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read")).expect("json")
}

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("kinetree-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).expect("dir");
    d
}

/// `kinetree simulate` (the paper arm) and `kinetree discover` into a fresh folder: the
/// folder and the model's path.
fn discovered_paper_arm(name: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = tmp(name);
    run_ok(kinetree().args(["simulate", "-o"]).arg(&dir));
    let model = dir.join("model.json");
    run_ok(
        kinetree()
            .arg("discover")
            .arg(dir.join("tracks.npy"))
            .arg("-o")
            .arg(&model),
    );
    (dir, model)
}

#[test]
fn run_without_argument_prints_the_paper_structure_and_table() {
    let results = tmp("results");
    let out = kinetree()
        .args(["run", "--results"])
        .arg(&results)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("3 bodies"), "{stdout}");
    assert!(
        stdout.contains("chain: body 0 -> body 1 -> body 2"),
        "{stdout}"
    );
    assert_eq!(stdout.matches(": revolute").count(), 2, "{stdout}");
    assert!(stdout.contains("Table I"), "{stdout}");
    for row in ["F0", "F1", "F2"] {
        assert!(
            stdout.lines().any(|l| l.starts_with(row)),
            "row {row} in {stdout}"
        );
    }
    assert!(stdout.contains("structure exact: true"), "{stdout}");
    let dir = results.join("paper-table1");
    for f in ["model.json", "table.md", "resolved.toml", "evaluation.json"] {
        assert!(dir.join(f).is_file(), "{f} written");
    }
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("model.json")).expect("read"))
            .expect("json");
    assert_eq!(model["bodies"].as_array().map(Vec::len), Some(3));
    // Figures: PNG and SVG of each, rendered without system fonts.
    for name in [
        "visibility",
        "distance_std",
        "dissimilarity",
        "kinematic_graph",
        "joint_trajectories",
    ] {
        let png = std::fs::read(dir.join("figures").join(format!("{name}.png"))).expect("png");
        assert!(
            png.starts_with(b"\x89PNG") && png.len() > 5000,
            "{name}.png"
        );
        let svg =
            std::fs::read_to_string(dir.join("figures").join(format!("{name}.svg"))).expect("svg");
        assert!(svg.contains("<svg") && svg.contains("<text"), "{name}.svg");
    }
    let traj = std::fs::read_to_string(dir.join("figures/joint_trajectories.svg")).expect("svg");
    assert!(
        traj.contains("estimated") && traj.contains("true"),
        "legend"
    );
}

#[test]
fn simulate_then_discover_npy_and_csv() {
    let dir = tmp("sim");
    run_ok(
        kinetree()
            .args([
                "simulate",
                "--mechanism",
                "random",
                "--joints",
                "3",
                "--seed",
                "4",
                "-o",
            ])
            .arg(&dir),
    );
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).expect("truth"))
            .expect("json");
    let n_bodies = truth["mechanism"]["bodies"]
        .as_array()
        .map(Vec::len)
        .expect("bodies");
    for file in ["tracks.npy", "tracks.npz", "tracks.csv"] {
        let model_path = dir.join(format!("{file}.model.json"));
        run_ok(
            kinetree()
                .arg("discover")
                .arg(dir.join(file))
                .arg("-o")
                .arg(&model_path),
        );
        let model: serde_json::Value = read_json(&model_path);
        assert_eq!(
            model["bodies"].as_array().map(Vec::len),
            Some(n_bodies),
            "{file}"
        );
        assert_eq!(
            model["joints"].as_array().map(Vec::len),
            Some(n_bodies - 1),
            "{file}"
        );
    }
    // The archive holds the same samples as the .npy, so the same model comes out (each
    // naming its own poses file) with the same poses.
    let without_poses_file = |file: &str| {
        let mut model = read_json(&dir.join(file));
        model
            .as_object_mut()
            .expect("object")
            .remove("body_poses_file")
            .expect("a poses file");
        model
    };
    assert_eq!(
        without_poses_file("tracks.npy.model.json"),
        without_poses_file("tracks.npz.model.json")
    );
    assert_eq!(
        std::fs::read(dir.join("tracks.npy.model.poses.npy")).expect("npy poses"),
        std::fs::read(dir.join("tracks.npz.model.poses.npy")).expect("npz poses")
    );
    let out = kinetree()
        .arg("discover")
        .arg(dir.join("tracks.npz"))
        .args(["--tracks-key", "points"])
        .arg("-o")
        .arg(dir.join("none.json"))
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("no array `points`") && err.contains("tracks, visibility"),
        "{err}"
    );
}

#[test]
fn discover_reports_bad_files_without_panicking() {
    let dir = tmp("bad");
    let p = dir.join("bad.csv");
    std::fs::write(&p, "frame,point,x,y,z\n0,0,1,2\n").expect("write");
    let out = kinetree().arg("discover").arg(&p).output().expect("runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("line 2") && stderr.contains("bad.csv"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// `kinetree observe MODEL TRACKS -o CSV` with `extra` arguments: the CSV's header and its
/// rows, one value or `None` per joint.
fn observed(
    model: &Path,
    tracks: &Path,
    csv: &Path,
    extra: &[&str],
) -> (String, Vec<Vec<Option<f64>>>) {
    run_ok(
        kinetree()
            .arg("observe")
            .arg(model)
            .arg(tracks)
            .args(extra)
            .arg("-o")
            .arg(csv),
    );
    let text = std::fs::read_to_string(csv).expect("csv");
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default().to_string();
    let rows = lines
        .map(|l| l.split(',').skip(1).map(|v| v.parse().ok()).collect())
        .collect();
    (header, rows)
}

/// Asserts that each joint's column of `rows` is the model's `field` (a per-frame array of
/// its joints) up to one offset in every frame, a whole number of turns, on over 90 frames.
fn assert_columns_are_the_models(
    rows: &[Vec<Option<f64>>],
    model: &serde_json::Value,
    field: &str,
) {
    for (k, joint) in model["joints"]
        .as_array()
        .expect("joints")
        .iter()
        .enumerate()
    {
        let batch: Vec<Option<f64>> = joint[field]
            .as_array()
            .expect(field)
            .iter()
            .map(serde_json::Value::as_f64)
            .collect();
        let offsets: Vec<f64> = rows
            .iter()
            .zip(&batch)
            .filter_map(|(r, b)| Some(b.as_ref()? - r[k].as_ref()?))
            .collect();
        assert!(
            offsets.len() > 90,
            "{field}, joint {k}: {} common frames",
            offsets.len()
        );
        let turns = (offsets[0] / std::f64::consts::TAU).round() * std::f64::consts::TAU;
        assert!(
            offsets.iter().all(|o| (o - turns).abs() < 1e-6),
            "{field}, joint {k}: offsets {offsets:?}"
        );
    }
}

#[test]
fn observe_writes_one_column_per_joint() {
    let dir = tmp("observe");
    let out = kinetree()
        .args(["simulate", "--seed", "2", "-o"])
        .arg(&dir)
        .output()
        .expect("simulate");
    assert!(out.status.success());
    let model = dir.join("model.json");
    run_ok(
        kinetree()
            .arg("discover")
            .arg(dir.join("tracks.npy"))
            .args(["--noise-sigma", "0.001", "-o"])
            .arg(&model),
    );
    let tracks = dir.join("tracks.csv");
    let (header, rows) = observed(&model, &tracks, &dir.join("config.csv"), &[]);
    assert_eq!(header, "frame,revolute_0_1,revolute_1_2,residual_in_sigma");
    // `discover` wrote every body's poses beside the model and named the file; `observe
    // --poses` on the same frames writes the same array: (100, 3, 9) float64.
    let json = read_json(&model);
    assert_eq!(json["body_poses_file"], "model.poses.npy");
    let companion = std::fs::read(dir.join("model.poses.npy")).expect("poses");
    observed(
        &model,
        &dir.join("tracks.npy"),
        &dir.join("config-npy.csv"),
        &[
            "--poses",
            dir.join("observed.poses.npy").to_str().expect("path"),
        ],
    );
    assert_eq!(
        std::fs::read(dir.join("observed.poses.npy")).expect("observed poses"),
        companion
    );
    let header_len = usize::from(companion[8]) + 256 * usize::from(companion[9]) + 10;
    let npy_header = String::from_utf8_lossy(&companion[..header_len]);
    assert!(npy_header.contains("(100, 3, 9, )"), "{npy_header}");
    assert_eq!(companion.len() - header_len, 100 * 3 * 9 * 8);
    run_ok(
        kinetree()
            .arg("discover")
            .arg(dir.join("tracks.npy"))
            .args(["--noise-sigma", "0.001", "--no-poses", "-o"])
            .arg(dir.join("bare.json")),
    );
    assert!(
        read_json(&dir.join("bare.json"))
            .get("body_poses_file")
            .is_none()
    );
    assert!(!dir.join("bare.poses.npy").exists());
    assert_eq!(rows.len(), 100);
    // On the frames it was discovered from, the observed columns are the model's positions
    // up to the same offset in every frame (a whole number of turns): both come from the
    // same warm-started fit, unwrapped.
    assert_columns_are_the_models(&rows, &json, "positions");
    // `--smooth`: the model's smoothed positions, up to the same offsets, and not the
    // per-frame ones.
    let (_, smoothed) = observed(&model, &tracks, &dir.join("smoothed.csv"), &["--smooth"]);
    assert_columns_are_the_models(&smoothed, &json, "smoothed_positions");
    for k in 0..2 {
        let moved = smoothed
            .iter()
            .zip(&rows)
            .filter(|(s, r)| s[k].zip(r[k]).is_some_and(|(s, r)| (s - r).abs() > 1e-9))
            .count();
        assert!(
            moved > 50,
            "joint {k}: only {moved} frames changed by smoothing"
        );
    }
}

#[test]
fn export_and_inspect_a_discovered_model() {
    let (d, model) = discovered_paper_arm("export");
    for (format, file, start) in [
        ("urdf", "arm.urdf", "<?xml"),
        ("dot", "arm.dot", "digraph"),
        ("json", "arm.json", "{"),
    ] {
        let out = d.join(file);
        run_ok(
            kinetree()
                .arg("export")
                .arg(&model)
                .args(["--format", format, "-o"])
                .arg(&out),
        );
        let text = std::fs::read_to_string(&out).expect("written");
        assert!(text.starts_with(start), "{format}: {}", &text[..40]);
    }
    // The JSON export is the model itself.
    assert_eq!(read_json(&d.join("arm.json")), read_json(&model));
    let urdf = std::fs::read_to_string(d.join("arm.urdf")).expect("urdf");
    assert_eq!(urdf.matches("<joint ").count(), 2, "{urdf}");
    assert_eq!(urdf.matches("type=\"revolute\"").count(), 2, "{urdf}");
    let text = run_ok(kinetree().arg("inspect").arg(&model));
    assert!(text.contains("3 bodies"), "{text}");
    assert!(text.contains("joint body 0 -> body 1: 1 DoF"), "{text}");
    assert!(text.contains("Followed by the fit"), "{text}");
    // The repairs' trace: the joints are bundle-adjusted on every discovery of the arm.
    assert!(
        text.contains("repairs (") && text.contains("Fit bundle_adjust (applied)"),
        "{text}"
    );
    // A bad format and a bad model are clean errors.
    let out = kinetree()
        .arg("export")
        .arg(&model)
        .args(["--format", "sdf", "-o"])
        .arg(d.join("x"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    std::fs::write(d.join("bad.json"), "{\"schema_version\": 1}").expect("write");
    let out = kinetree()
        .arg("inspect")
        .arg(d.join("bad.json"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bad.json"));
}

#[test]
fn discover_reads_c3d_and_fit_track_reads_a_handle() {
    let d = tmp("c3d");
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments/real/data");
    let model = d.join("triads.json");
    let out = run_ok(
        kinetree()
            .arg("discover")
            .arg(data.join("c3dorg-fullbody-triads/pc_real.c3d"))
            .args(["--pipeline"])
            .arg(data.join("../pipeline.toml"))
            .arg("-o")
            .arg(&model),
    );
    assert!(out.contains("12 bodies"), "{out}");
    let labels = read_json(&model)["point_labels"].clone();
    assert_eq!(labels.as_array().map(Vec::len), Some(36), "{labels}");
    // Without a config a C3D file gets the motion-capture settings, which are that file's;
    // the defaults (for rigid bodies) merge the segments.
    let (auto, rigid) = (d.join("auto.json"), d.join("rigid.json"));
    for (model, preset) in [(&auto, None), (&rigid, Some("default"))] {
        let mut command = kinetree();
        command
            .arg("discover")
            .arg(data.join("c3dorg-fullbody-triads/pc_real.c3d"))
            .args(["-q", "--no-poses", "-o"])
            .arg(model);
        if let Some(p) = preset {
            command.args(["--preset", p]);
        }
        let out = command.output().expect("runs");
        assert!(out.status.success(), "{out:?}");
        let said = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            said.contains("motion-capture settings"),
            preset.is_none(),
            "{said}"
        );
    }
    assert_eq!(
        read_json(&auto)["point_body"],
        read_json(&model)["point_body"]
    );
    let bodies = |m: &std::path::Path| read_json(m)["bodies"].as_array().map_or(0, Vec::len);
    assert!(
        bodies(&rigid) < 12,
        "{} bodies with the defaults",
        bodies(&rigid)
    );
    let joint = d.join("door.json");
    let out = run_ok(
        kinetree()
            .arg("fit-track")
            .arg(data.join("sturm-door-drawer/right_door_001/001.log"))
            .arg("-o")
            .arg(&joint),
    );
    assert!(out.contains("\"type\":\"revolute\""), "{out}");
    assert_eq!(read_json(&joint)["joint"]["type"], "revolute");
}

#[test]
fn a_sweep_run_in_shards_merges_into_the_unsharded_files() {
    let dir = tmp("shards");
    let config = dir.join("sweep.toml");
    std::fs::write(
        &config,
        r#"
[experiment]
name = "split"

[sweep]
seeds = 2

[data]
kind = "random"
n_joints = 1
n_frames = 50
noise_sigma_m = [0.001, 0.002, 0.003]
"#,
    )
    .expect("write");
    let whole = dir.join("whole");
    let split = dir.join("split");
    run_ok(
        kinetree()
            .arg("run")
            .arg(&config)
            .arg("--results")
            .arg(&whole),
    );
    for shard in ["0/2", "1/2"] {
        let out = run_ok(
            kinetree()
                .arg("run")
                .arg(&config)
                .arg("--results")
                .arg(&split)
                .args(["--shard", shard]),
        );
        assert!(out.contains("kinetree merge"), "{out}");
    }
    let out = run_ok(kinetree().arg("merge").arg(split.join("split")));
    assert!(out.contains("merged 6 runs"), "{out}");
    for file in ["runs.csv", "table.md", "resolved.toml"] {
        assert_eq!(
            std::fs::read(split.join("split").join(file)).expect("merged"),
            std::fs::read(whole.join("split").join(file)).expect("whole"),
            "{file}"
        );
    }
    // A single experiment has no shards; a bad shard text is named.
    for (args, needle) in [
        (vec!["run", "--shard", "0/2"], "--shard is for sweeps"),
        (vec!["run", "--shard", "2/2"], "is not a shard"),
    ] {
        let out = kinetree()
            .args(&args)
            .arg("--results")
            .arg(dir.join("none"))
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(needle),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn the_bash_completion_script_completes_subcommands_and_flags() {
    let script = run_ok(kinetree().args(["completions", "bash"]));
    let dir = tmp("completions");
    let path = dir.join("kinetree.bash");
    std::fs::write(&path, &script).expect("write");
    // Ask the completion function what follows `kinetree me` and `kinetree run --sh`.
    let probe = format!(
        "source {}; \
         COMP_WORDS=(kinetree me); COMP_CWORD=1; _kinetree kinetree me kinetree; echo \"${{COMPREPLY[@]}}\"; \
         COMP_WORDS=(kinetree run --sh); COMP_CWORD=2; _kinetree kinetree --sh run; echo \"${{COMPREPLY[@]}}\"",
        path.display()
    );
    let out = run_ok(Command::new("bash").args(["-c", &probe]));
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines, ["merge", "--shard"], "{out}");
    for shell in ["zsh", "fish", "powershell", "elvish"] {
        let script = run_ok(kinetree().args(["completions", shell]));
        assert!(
            script.contains("discover") && script.contains("merge"),
            "{shell}"
        );
    }
}

#[test]
fn view_writes_one_self_contained_page() {
    let (dir, model) = discovered_paper_arm("view");
    let page = dir.join("view.html");
    run_ok(
        kinetree()
            .arg("view")
            .arg(&model)
            .arg(dir.join("tracks.csv"))
            .arg("-o")
            .arg(&page),
    );
    let html = std::fs::read_to_string(&page).expect("page");
    assert!(html.starts_with("<!doctype html>"), "{}", &html[..40]);
    // Self-contained: no script, style sheet or image is loaded from elsewhere (the
    // browser test watches the page's requests too).
    for needle in ["<script src", "<link", "<img", "@import", "url(http"] {
        assert!(!html.contains(needle), "{needle}");
    }
    assert!(html.contains("KinetreeVendor") && html.contains("kinetree-data"));
    // The model as the output, or tracks of other points, are refused.
    let out = kinetree()
        .arg("view")
        .arg(&model)
        .arg(dir.join("tracks.npy"))
        .arg("-o")
        .arg(&model)
        .output()
        .expect("runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("is the input"));
}

/// Runs `kinetree <args>` with a terminal as its stdout and stderr (util-linux `script`),
/// returning all it wrote there.
fn on_a_terminal(args: &str) -> String {
    let command = format!("{} {args}", env!("CARGO_BIN_EXE_kinetree"));
    let out = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .output()
        .expect("script (util-linux) runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn discover_shows_its_stages_on_a_terminal_unless_quiet() {
    let dir = tmp("progress");
    // A discovery of several seconds: the display appears after one.
    run_ok(
        kinetree()
            .args([
                "simulate",
                "--mechanism",
                "random",
                "--joints",
                "8",
                "--tree",
                "--frames",
                "3000",
                "--seed",
                "1",
                "-o",
            ])
            .arg(&dir),
    );
    let tracks = dir.join("tracks.npy");
    let model = dir.join("model.json");
    let args = format!("discover {} -o {}", tracks.display(), model.display());
    let shown = on_a_terminal(&args);
    assert!(shown.contains("discover ["), "{shown}");
    for stage in ["bodies", "whole-tree fit"] {
        assert!(shown.contains(stage), "stage {stage} in {shown}");
    }
    assert!(shown.contains("wrote"), "{shown}");
    let quiet = on_a_terminal(&format!("--quiet {args}"));
    assert!(!quiet.contains("discover ["), "{quiet}");
    assert!(quiet.contains("wrote"), "{quiet}");
    // Without a terminal (a pipe here) nothing is drawn either.
    let out = kinetree().args(args.split(' ')).output().expect("runs");
    assert!(out.status.success());
    assert!(!String::from_utf8_lossy(&out.stderr).contains("discover ["));
}

/// `discover --timings` prints each stage's time on stderr, and the rows add up to the total
/// it states; then each repair's, longest first, and how often the memo answered; without the
/// flag nothing of it is printed.
#[test]
fn discover_prints_its_stage_times_when_asked() {
    let (dir, _) = discovered_paper_arm("timings");
    let discover = |timings: bool| {
        let mut cmd = kinetree();
        cmd.args(["discover", "-q"])
            .arg(dir.join("tracks.npy"))
            .arg("-o")
            .arg(dir.join("timed.json"));
        if timings {
            cmd.arg("--timings");
        }
        let out = cmd.output().expect("runs");
        assert!(out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = discover(true);
    let mut lines = err.lines();
    let head = lines.next().expect("a heading");
    let total: f64 = head
        .split(", ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("total in {head}"));
    let row = |l: &str| {
        let (name, rest) = l.trim().split_once("  ").expect("name and time");
        let seconds = rest.split_whitespace().next().expect("seconds");
        (name.to_string(), seconds.parse::<f64>().expect("a number"))
    };
    let rows: Vec<(String, f64)> = lines
        .by_ref()
        .take_while(|l| !l.starts_with("repair times"))
        .map(row)
        .collect();
    for stage in ["setup", "pair statistics", "clustering", "bodies", "tree"] {
        assert!(rows.iter().any(|(n, _)| n == stage), "{stage} in {err}");
    }
    let sum: f64 = rows.iter().map(|(_, s)| s).sum();
    assert!((sum - total).abs() <= 0.001 * rows.len() as f64, "{err}");
    // The repairs' table: every fit-phase repair of the defaults ran, longest first.
    let repairs: Vec<(String, f64)> = lines.take_while(|l| l.starts_with("  ")).map(row).collect();
    for repair in ["free_joints", "bundle_adjust"] {
        assert!(
            repairs.iter().any(|(n, _)| n == repair),
            "{repair} in {err}"
        );
    }
    assert!(repairs.windows(2).all(|w| w[0].1 >= w[1].1), "{err}");
    // Then the memo: every pair test of the run went through it.
    let memo = err
        .lines()
        .find(|l| l.starts_with("memo: "))
        .unwrap_or_else(|| panic!("a memo line in {err}"));
    let lookups: usize = memo
        .split_whitespace()
        .nth(3)
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("lookups in {memo}"));
    assert!(lookups > 0, "{memo}");
    let plain = discover(false);
    assert!(!plain.contains("stage times") && !plain.contains("repair times"));
    assert!(!plain.contains("memo: "));
}

/// `fit-track` takes a `.npy` of one point, `(T, 3)` or `(T, 1, 3)`, and a `(T, N, 3)` one
/// with `--point`; without it, or with a point beyond the file's, it stops with a message
/// that names the choice.
#[test]
fn fit_track_reads_one_point_arrays() {
    let d = tmp("one-point");
    let data = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../experiments/real/data/sturm-door-drawer/right_door_001/001.log");
    let door = kinetree_io::read_point_track(&data).expect("door");
    let flat: Vec<f64> = door.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let t = door.len();
    let one = d.join("one.npy");
    let nested = d.join("nested.npy");
    kinetree_io::write_array_npy(&one, &[t, 3], &flat).expect("write");
    kinetree_io::write_array_npy(&nested, &[t, 1, 3], &flat).expect("write");
    for (file, point) in [(&one, None), (&nested, None), (&nested, Some("0"))] {
        let mut cmd = kinetree();
        cmd.arg("fit-track")
            .arg(file)
            .arg("-o")
            .arg(d.join("joint.json"));
        if let Some(p) = point {
            cmd.args(["--point", p]);
        }
        run_ok(&mut cmd);
        assert_eq!(
            read_json(&d.join("joint.json"))["joint"]["type"],
            "revolute"
        );
    }
    // Three points a frame: the door's, and two others.
    let many: Vec<f64> = flat
        .chunks(3)
        .flat_map(|p| [p[0], p[1], p[2], 0.0, 0.0, 1.0, p[0], p[1], p[2] + 0.1])
        .collect();
    let three = d.join("three.npy");
    kinetree_io::write_array_npy(&three, &[t, 3, 3], &many).expect("write");
    run_ok(
        kinetree()
            .arg("fit-track")
            .arg(&three)
            .args(["--point", "2", "-o"])
            .arg(d.join("joint.json")),
    );
    assert_eq!(
        read_json(&d.join("joint.json"))["joint"]["type"],
        "revolute"
    );
    for (args, says) in [
        (vec![], "choose one (`--point`)"),
        (vec!["--point", "3"], "point 3 does not exist"),
    ] {
        let out = kinetree()
            .arg("fit-track")
            .arg(&three)
            .args(&args)
            .arg("-o")
            .arg(d.join("joint.json"))
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(says), "{err}");
    }
    let wrong = d.join("wrong.npy");
    kinetree_io::write_array_npy(&wrong, &[t, 2], &flat[..2 * t]).expect("write");
    let out = kinetree()
        .arg("fit-track")
        .arg(&wrong)
        .arg("-o")
        .arg(d.join("joint.json"))
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("(T, 3)"), "{err}");
}

/// A TRC file (OpenSim's marker format, here in millimetres) of a simulated arm discovers
/// the same bodies as its `.npy`, with the marker names it gives.
#[test]
fn discover_reads_trc_files() {
    let dir = tmp("trc");
    run_ok(kinetree().args(["simulate", "-o"]).arg(&dir));
    let tracks = kinetree_io::read_npy(&dir.join("tracks.npy")).expect("npy");
    let n = tracks.n_points();
    let mut text = format!(
        "PathFileType\t4\t(X/Y/Z)\tarm.trc\n\
         DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n\
         30\t30\t{t}\t{n}\tmm\t30\t1\t{t}\n\
         Frame#\tTime",
        t = tracks.n_frames()
    );
    for i in 0..n {
        text.push_str(&format!("\tM{i}\t\t"));
    }
    text.push_str("\n\t");
    for i in 0..n {
        text.push_str(&format!("\tX{k}\tY{k}\tZ{k}", k = i + 1));
    }
    text.push_str("\n\n");
    for f in 0..tracks.n_frames() {
        text.push_str(&format!("{}\t{:.4}", f + 1, f as f64 / 30.0));
        for i in 0..n {
            match tracks.get(f, i) {
                Some(p) => text.push_str(&format!(
                    "\t{:.6}\t{:.6}\t{:.6}",
                    p.x * 1e3,
                    p.y * 1e3,
                    p.z * 1e3
                )),
                None => text.push_str("\t\t\t"),
            }
        }
        text.push('\n');
    }
    let trc = dir.join("arm.trc");
    std::fs::write(&trc, text).expect("write");
    let (from_npy, from_trc) = (dir.join("npy.json"), dir.join("trc.json"));
    for (input, model) in [(dir.join("tracks.npy"), &from_npy), (trc, &from_trc)] {
        run_ok(
            kinetree()
                .arg("discover")
                .arg(input)
                .args(["-q", "--no-poses", "--preset", "default", "-o"])
                .arg(model),
        );
    }
    let (a, b) = (read_json(&from_npy), read_json(&from_trc));
    assert_eq!(a["point_body"], b["point_body"]);
    assert_eq!(b["point_labels"][0], "M0");
    assert_eq!(
        a["joints"].as_array().map(Vec::len),
        b["joints"].as_array().map(Vec::len)
    );
}

#[test]
fn dense_tracks_are_discovered_on_a_sample_and_every_point_gets_its_body() {
    let dir = tmp("dense");
    run_ok(
        kinetree()
            .args([
                "simulate",
                "--mechanism",
                "scale",
                "--points",
                "1200",
                "--frames",
                "120",
                "-o",
            ])
            .arg(&dir),
    );
    let model_path = dir.join("model.json");
    run_ok(
        kinetree()
            .arg("discover")
            .arg(dir.join("tracks.npy"))
            .args(["--noise-sigma", "0.001", "-q", "-o"])
            .arg(&model_path),
    );
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model_path).expect("model")).expect("json");
    let point_body = model["point_body"].as_array().expect("point_body");
    assert_eq!(point_body.len(), 1200);
    assert_eq!(model["bodies"].as_array().map(Vec::len), Some(5));
    let sampled = model["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .find(|w| w["kind"] == "tracks_sampled")
        .expect("a tracks_sampled warning");
    assert_eq!(sampled["sampled"], 500);
    let on_bodies = point_body.iter().filter(|b| b.as_i64() >= Some(0)).count();
    assert!(on_bodies >= 1190, "{on_bodies} of 1200 points on bodies");
    // Only the scale scenario takes a number of keypoints.
    simulate_refused(&dir, &["--points", "50"], "--points");
}

/// Asserts that `kinetree simulate` with `args` fails and names `flag`.
fn simulate_refused(dir: &std::path::Path, args: &[&str], flag: &str) {
    let out = kinetree()
        .arg("simulate")
        .args(args)
        .arg("-o")
        .arg(dir.join("refused"))
        .output()
        .expect("runs");
    assert!(!out.status.success(), "{args:?} accepted");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(flag),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn skeletons_are_simulated_with_soft_tissue_and_other_mechanisms_refuse_it() {
    let dir = tmp("soft-tissue");
    let simulate = |name: &str, extra: &[&str]| {
        kinetree()
            .args([
                "simulate",
                "--mechanism",
                "skeleton-clinical",
                "--frames",
                "40",
            ])
            .args(extra)
            .arg("-o")
            .arg(dir.join(name))
            .output()
            .expect("runs")
    };
    assert!(simulate("rigid", &[]).status.success());
    assert!(
        simulate("skin", &["--soft-tissue", "0.01"])
            .status
            .success()
    );
    let read = |name: &str| std::fs::read(dir.join(name).join("tracks.npy")).expect("tracks");
    assert_eq!(read("rigid").len(), read("skin").len());
    assert_ne!(read("rigid"), read("skin"), "the markers drift");
    // Beyond the skeleton's range, and on a mechanism without skin, the flag is named.
    let far = ["--mechanism", "skeleton-clinical", "--soft-tissue", "0.5"];
    simulate_refused(&dir, &far, "--soft-tissue");
    simulate_refused(&dir, &["--soft-tissue", "0.005"], "--soft-tissue");
}

/// `kinetree evaluate` compares a discovered model with `simulate`'s truth: every joint of
/// the paper arm right, and its JSON the same verdicts; a truth of other keypoints, or one that
/// is not JSON, is refused with the field or the line named and no output written.
#[test]
fn evaluate_compares_a_model_with_the_truth_and_refuses_another_mechanisms() {
    let (dir, model) = discovered_paper_arm("evaluate");
    let json = dir.join("evaluation.json");
    let out = run_ok(
        kinetree()
            .arg("evaluate")
            .arg(&model)
            .arg("--truth")
            .arg(dir.join("truth.json"))
            .arg("-o")
            .arg(&json),
    );
    assert!(out.contains("joints exact: true"), "{out}");
    assert!(out.contains("2 of 2 joints right"), "{out}");
    let e = read_json(&json);
    let joints = e["joints"].as_array().expect("joints");
    assert_eq!(joints.len(), 2);
    assert!(
        joints
            .iter()
            .all(|j| j["miss"].is_null() && j["found"] == true)
    );

    // A hand's truth: other keypoints.
    let hand = tmp("evaluate-hand");
    run_ok(
        kinetree()
            .args(["simulate", "--mechanism", "hand", "--frames", "100", "-o"])
            .arg(&hand),
    );
    let refused = dir.join("refused.json");
    let out = kinetree()
        .arg("evaluate")
        .arg(&model)
        .arg("--truth")
        .arg(hand.join("truth.json"))
        .arg("-o")
        .arg(&refused)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("truth.json") && stderr.contains("point_body"),
        "{stderr}"
    );
    assert!(!refused.exists());

    let broken = dir.join("broken.json");
    std::fs::write(&broken, "{\"point_body\": [0, 1,").expect("write");
    let out = kinetree()
        .arg("evaluate")
        .arg(&model)
        .arg("--truth")
        .arg(&broken)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("broken.json") && stderr.contains("line 1"),
        "{stderr}"
    );
}
