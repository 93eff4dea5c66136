//! Sweeps split into shards for a cluster's job array, and merged back into the files an
//! unsharded run writes.

use kinetree_pipeline::sweep::{
    Shard, Sweep, SweepOptions, merge_shards, parse_runs_csv, run_sweep, runs_csv,
};
use std::path::{Path, PathBuf};

/// Five grid points (an inline list and a grid key) over two seeds, one of them an inline
/// axis, so that shards of 2 and 3 split the points unevenly.
const SWEEP: &str = r#"
[experiment]
name = "sharded"

[sweep]
seeds = [3, 7]

[sweep.grid]
"data.noise_sigma_m" = [0.0005, 0.001, 0.002, 0.003, 0.004]

[data]
kind = "random"
n_joints = 1
n_frames = [50]
"#;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kinetree-shards-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("dir");
    d
}

fn run(sweep: &Sweep, dir: &Path, shard: Option<Shard>) -> usize {
    run_sweep(
        sweep,
        Path::new("."),
        dir,
        &|_, _| {},
        SweepOptions {
            resume: false,
            shard,
        },
    )
    .expect("runs")
    .len()
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn message(e: &kinetree_core::Error) -> String {
    e.to_string()
}

#[test]
fn shard_text_is_checked() {
    let s: Shard = "3/16".parse().expect("3/16");
    assert_eq!((s.index, s.count), (3, 16));
    assert!(s.holds(3) && s.holds(19) && !s.holds(4));
    assert_eq!(s.folder(), "shard-3-of-16");
    assert_eq!(Shard::from_folder("shard-3-of-16"), Some(s));
    for bad in ["16/16", "0/0", "a/b", "3", "-1/4", "1/1000000000"] {
        let e = bad.parse::<Shard>().expect_err(bad);
        assert!(message(&e).contains("shard"), "{bad}: {e}");
    }
    for bad in ["shard-3-of-3", "shard-03-of-16", "shard-1-of-", "results"] {
        assert_eq!(Shard::from_folder(bad), None, "{bad}");
    }
}

#[test]
fn the_sweep_text_reads_back_as_the_same_sweep() {
    let sources: Vec<String> = std::iter::once(SWEEP.to_string())
        .chain(
            std::fs::read_dir(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../experiments/sweeps"
            ))
            .expect("sweeps")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .map(|p| read(&p)),
        )
        .collect();
    assert!(sources.len() >= 5);
    for text in sources {
        let sweep = Sweep::from_toml(&text).expect("parses");
        let again = Sweep::from_toml(&sweep.to_toml().expect("to_toml")).expect("reads back");
        assert_eq!(again.keys, sweep.keys);
        assert_eq!(again.points, sweep.points);
        assert_eq!(again.seeds(), sweep.seeds());
        for p in 0..sweep.points.len() {
            for &seed in &sweep.seeds() {
                assert_eq!(
                    again.config(p, seed).expect("config"),
                    sweep.config(p, seed).expect("config")
                );
            }
        }
    }
}

#[test]
fn merged_shards_are_byte_identical_to_the_unsharded_sweep() {
    let sweep = Sweep::from_toml(SWEEP).expect("parses");
    assert_eq!(sweep.points.len(), 5);
    let whole = tmp("whole");
    assert_eq!(run(&sweep, &whole, None), 10);
    // Eight shards of five grid points: three shards have no runs.
    for count in [2, 3, 8] {
        let dir = tmp(&format!("split-{count}"));
        let mut total = 0;
        for index in 0..count {
            let shard = Shard { index, count };
            let n = run(&sweep, &dir, Some(shard));
            assert_eq!(n, sweep.jobs(Some(shard)).len());
            total += n;
            // A shard writes only its own folder.
            assert!(!dir.join("runs.csv").exists());
            let rows = read(&dir.join(shard.folder()).join("runs.csv"));
            assert_eq!(rows.lines().count(), n + 1, "{rows}");
        }
        assert_eq!(total, 10);
        let (name, _, runs) = merge_shards(&dir).expect("merges");
        assert_eq!((name.as_str(), runs.len()), ("sharded", 10));
        for file in ["runs.csv", "table.md", "resolved.toml"] {
            assert_eq!(
                read(&dir.join(file)),
                read(&whole.join(file)),
                "{file} from {count} shards"
            );
        }
    }
}

#[test]
fn merge_refuses_missing_unfinished_mixed_and_foreign_shards() {
    let sweep = Sweep::from_toml(SWEEP).expect("parses");
    let dir = tmp("bad");
    let e = merge_shards(&dir).expect_err("no shards");
    assert!(message(&e).contains("no shard folders"), "{e}");
    let s0 = Shard { index: 0, count: 3 };
    let s2 = Shard { index: 2, count: 3 };
    run(&sweep, &dir, Some(s0));
    run(&sweep, &dir, Some(s2));
    let e = merge_shards(&dir).expect_err("shard 1 missing");
    assert!(message(&e).contains("shards 1 of 3 have not run"), "{e}");
    // Shard 1 cut short: its last row is lost.
    let s1 = Shard { index: 1, count: 3 };
    run(&sweep, &dir, Some(s1));
    let csv = dir.join(s1.folder()).join("runs.csv");
    let text = read(&csv);
    let cut: Vec<&str> = text.lines().collect();
    std::fs::write(&csv, cut[..cut.len() - 1].join("\n") + "\n").expect("write");
    let e = merge_shards(&dir).expect_err("unfinished");
    assert!(
        message(&e).contains("1/3 (3 of 4 runs)") && message(&e).contains("--resume"),
        "{e}"
    );
    // Resuming the shard finishes it, and the merge goes through.
    run_sweep(
        &sweep,
        Path::new("."),
        &dir,
        &|_, _| {},
        SweepOptions {
            resume: true,
            shard: Some(s1),
        },
    )
    .expect("resumes");
    merge_shards(&dir).expect("merges");
    // Another shard's rows in a shard's file.
    std::fs::copy(dir.join(s0.folder()).join("runs.csv"), &csv).expect("copy");
    let e = merge_shards(&dir).expect_err("foreign rows");
    assert!(message(&e).contains("belongs to another shard"), "{e}");
    run(&sweep, &dir, Some(s1));
    // A shard of another split beside them.
    run(&sweep, &dir, Some(Shard { index: 0, count: 2 }));
    let e = merge_shards(&dir).expect_err("two splits");
    assert!(message(&e).contains("of 2 and of 3 parts"), "{e}");
    std::fs::remove_dir_all(dir.join("shard-0-of-2")).expect("rm");
    // A shard of another sweep.
    let other = Sweep::from_toml(&SWEEP.replace("0.004", "0.005")).expect("parses");
    run(&other, &dir, Some(s2));
    let e = merge_shards(&dir).expect_err("other sweep");
    assert!(message(&e).contains("different sweeps"), "{e}");
}

/// Runs `sweep` (of `runs` runs) whole and in two shards merged, checks that both write the
/// same `runs.csv` and `table.md`, and returns the whole run's folder.
fn run_whole_and_merged(sweep: &Sweep, name: &str, runs: usize) -> PathBuf {
    let whole = tmp(&format!("{name}-whole"));
    assert_eq!(run(sweep, &whole, None), runs);
    let dir = tmp(&format!("{name}-split"));
    for index in 0..2 {
        run(sweep, &dir, Some(Shard { index, count: 2 }));
    }
    merge_shards(&dir).expect("merges");
    for file in ["runs.csv", "table.md"] {
        assert_eq!(read(&dir.join(file)), read(&whole.join(file)), "{file}");
    }
    whole
}

/// A sweep with the functional methods' columns reads back through a merge: the same files as
/// unsharded, the columns filled.
#[test]
fn functional_columns_read_back_through_a_merge() {
    let sweep = Sweep::from_toml(
        r#"
[experiment]
name = "functional"

[sweep]
seeds = [1, 2, 3]
functional = true

[sweep.grid]
"data.n_joints" = [2, 3]

[data]
kind = "random"
prismatic_fraction = 0.0
spherical_fraction = 0.5
n_frames = 150
"#,
    )
    .expect("parses");
    let whole = run_whole_and_merged(&sweep, "functional", 6);
    let csv = read(&whole.join("runs.csv"));
    let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
    let column = |name: &str| {
        let k = header.iter().position(|h| *h == name).expect(name);
        csv.lines()
            .skip(1)
            .filter(|l| {
                l.split(',')
                    .nth(k)
                    .is_some_and(|v| v.parse::<f64>().is_ok())
            })
            .count()
    };
    assert!(column("functional_max_axis_error_deg") > 0, "{csv}");
    assert!(column("functional_max_centre_error_m") > 0, "{csv}");
    assert!(column("max_axis_error_in_parent_deg") > 0, "{csv}");
    assert!(read(&whole.join("table.md")).contains("SCoRE"));
}

/// A sweep that counts each run's joints writes the counts, reads them back through a merge
/// and a resume, and agrees with its own `joints_exact`: a run with every joint right has
/// every true joint counted right, and no run counts more right than true.
#[test]
fn per_joint_counts_read_back_and_agree_with_joints_exact() {
    let text = r#"
[experiment]
name = "per-joint"

[sweep]
seeds = [1, 2, 3]
per_joint = true

[sweep.grid]
"data.n_joints" = [2, 4]

[data]
kind = "random"
prismatic_fraction = 0.3
n_frames = 150
"#;
    let sweep = Sweep::from_toml(text).expect("parses");
    let whole = run_whole_and_merged(&sweep, "per-joint", 6);
    let csv = read(&whole.join("runs.csv"));
    let runs = parse_runs_csv(&sweep, &csv).expect("reads back");
    assert_eq!(runs_csv(&sweep, &runs), csv, "written as read");
    assert_eq!(runs.len(), 6);
    for r in &runs {
        let n_joints: usize = r.values[0].parse().expect("n_joints");
        let (Some(true_joints), Some(right)) = (r.joints_true, r.joints_right) else {
            panic!("seed {} of {n_joints} joints has no counts: {csv}", r.seed);
        };
        assert_eq!(true_joints, n_joints, "{csv}");
        assert!(right <= true_joints, "{csv}");
        if r.joints_exact == Some(true) {
            assert_eq!(right, true_joints, "{csv}");
        }
    }
    let table = read(&whole.join("table.md"));
    let right: usize = runs.iter().filter_map(|r| r.joints_right).sum();
    assert!(
        table.contains("joints right") && table.contains(&format!("/{} (", 3 * 2)),
        "{table}"
    );
    assert!(right > 0, "{csv}");
}
