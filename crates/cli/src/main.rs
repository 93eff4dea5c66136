//! `kinetree`: discover the kinematic structure of a mechanism from tracked 3D keypoints.

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use kinetree_pipeline::report::{summary, table_text};
use kinetree_pipeline::{
    ExperimentConfig, PAPER_EXPERIMENT_TOML, Pipeline, PipelineConfig, run_experiment,
    write_results,
};
use std::path::{Path, PathBuf};

/// mimalloc instead of the system allocator: the per-frame fits of long recordings make and
/// drop many small buffers (`docs/decisions.md`, "Long recordings: the adjusted joints'
/// frames and the allocator", has the measurement).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// `println!` through [`emit`].
macro_rules! emitln {
    ($($arg:tt)*) => {
        emit(&format!("{}\n", format!($($arg)*)))
    };
}

/// Set once stdout has failed: the rest of the report is dropped, the work goes on.
static STDOUT_GONE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Prints to stdout. A closed pipe (`kinetree discover ... | head`) or another write error
/// stops the printing but not the program, so the files it writes are still written (`print!`
/// would panic); other errors are said once on stderr.
fn emit(text: &str) {
    use std::io::Write;
    use std::sync::atomic::Ordering;
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        STDOUT_GONE.store(true, Ordering::Relaxed);
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!(
                "error writing to stdout: {e}; the report is dropped, files are still written"
            );
        }
    }
}

/// Most worker threads accepted from `RAYON_NUM_THREADS` (outputs do not depend on the count;
/// far more threads than cores only cost memory, and beyond a few thousand the system refuses
/// them mid-run).
const MAX_THREADS: usize = 1024;

/// Sets up the worker pool from `RAYON_NUM_THREADS` (unset or 0: one per core), refusing a
/// value that is not a count or is above [`MAX_THREADS`] instead of failing inside the pool.
fn configure_threads() -> Result<()> {
    let threads = match std::env::var("RAYON_NUM_THREADS") {
        Err(std::env::VarError::NotPresent) => 0,
        Err(std::env::VarError::NotUnicode(v)) => {
            bail!("RAYON_NUM_THREADS={v:?} is not a thread count")
        }
        Ok(v) => match v.trim().parse::<usize>() {
            Ok(n) if n <= MAX_THREADS => n,
            Ok(n) => bail!("RAYON_NUM_THREADS={n} is above the limit of {MAX_THREADS} threads"),
            Err(_) => bail!("RAYON_NUM_THREADS={v:?} is not a thread count (0 for one per core)"),
        },
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")
}

/// The companion poses file of the model file `model`: `<stem>.poses.npy` beside it.
fn poses_beside(model: &Path) -> PathBuf {
    let stem = model
        .file_stem()
        .map_or_else(|| "model".into(), |s| s.to_string_lossy().into_owned());
    model.with_file_name(format!("{stem}.poses.npy"))
}

/// Refuses an output path that names one of the inputs: writing it would destroy the input.
fn refuse_overwriting(output: &Path, inputs: &[&Path]) -> Result<()> {
    let Ok(out) = std::fs::canonicalize(output) else {
        // No file there yet, so it is none of the inputs.
        return Ok(());
    };
    for input in inputs {
        if std::fs::canonicalize(input).is_ok_and(|i| i == out) {
            bail!(
                "the output {} is the input {}; choose another output with -o",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// How a tracks file is read: the array names of an `.npz` archive.
#[derive(Debug, Clone, clap::Args)]
struct TrackArgs {
    /// `.npz` tracks: the name of the (T, N, 3) array [default: tracks].
    #[arg(long, value_name = "NAME")]
    tracks_key: Option<String>,
    /// `.npz` tracks: the name of a (T, N) array, true (or at least 0.5) where a sample is
    /// visible [default: `visibility` if the archive has it].
    #[arg(long, value_name = "NAME", conflicts_with = "occluded_key")]
    visibility_key: Option<String>,
    /// `.npz` tracks: the name of a (T, N) array, true (or at least 0.5) where a sample is
    /// occluded [default: `occluded` if the archive has it and no `visibility`].
    #[arg(long, value_name = "NAME")]
    occluded_key: Option<String>,
}

impl TrackArgs {
    fn options(&self, max_memory_gib: f64) -> kinetree_io::ReadOptions {
        kinetree_io::ReadOptions {
            max_memory_gib,
            tracks_key: self.tracks_key.clone(),
            visibility_key: self.visibility_key.clone(),
            occluded_key: self.occluded_key.clone(),
        }
    }
}

/// Formats of `kinetree export`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ExportFormat {
    Urdf,
    Mjcf,
    Dot,
    Json,
}

#[derive(Debug, Parser)]
#[command(
    name = "kinetree",
    version,
    about = "Discover rigid bodies, joints and kinematic trees from tracked 3D keypoints"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Memory limit in GiB (default 8): tracks, simulations and discoveries whose estimated
    /// memory exceeds it are refused before they are allocated. For `run`, it replaces the
    /// experiment's `pipeline.max_memory_gib`.
    #[arg(long, global = true, value_name = "GIB")]
    max_memory: Option<f64>,
    /// Work limit in estimated minutes (default 30): a discovery whose pair statistics, or
    /// whose bodies and model phases once the clustering has found its bodies, are estimated
    /// to take longer is refused before they start. For `run`, it replaces the experiment's `pipeline.max_minutes`.
    #[arg(long, global = true, value_name = "MINUTES")]
    max_minutes: Option<f64>,
    /// No progress display: neither `discover`'s stage display (drawn on a terminal once a
    /// discovery has run for a second) nor a sweep's progress bar.
    #[arg(long, short, global = true)]
    quiet: bool,
}

/// How long a discovery runs before its stages are shown.
const PROGRESS_DELAY: std::time::Duration = std::time::Duration::from_secs(1);

/// Shows a discovery's stages on stderr: a spinner with the stage's name, the last change a
/// repair made and the elapsed time, drawn once the discovery has run for
/// [`PROGRESS_DELAY`], and only when stderr is a terminal (so logs and pipes get nothing).
struct StageDisplay {
    bar: indicatif::ProgressBar,
    stage: std::sync::Mutex<String>,
}

impl kinetree_pipeline::DiscoveryObserver for StageDisplay {
    fn stage(&self, name: &str) {
        if let Ok(mut s) = self.stage.lock() {
            *s = name.to_string();
        }
        self.bar.set_message(name.to_string());
    }

    fn trace(&self, entry: &kinetree_core::TraceEntry) {
        let stage = self.stage.lock().map(|s| s.clone()).unwrap_or_default();
        self.bar
            .set_message(format!("{stage} - {}: {}", entry.repair, entry.summary));
    }
}

/// The stages' wall-clock times as `discover --timings` prints them: one line a stage, its
/// seconds, its share of the whole and, when it ran more than once, how many times.
fn stage_table(times: &[kinetree_pipeline::StageTime]) -> String {
    let total: f64 = times.iter().map(|s| s.seconds).sum();
    let width = times.iter().map(|s| s.stage.len()).max().unwrap_or(0);
    let mut out = format!("stage times (wall clock, {total:.3} s in all):\n");
    for s in times {
        let share = if total > 0.0 {
            100.0 * s.seconds / total
        } else {
            0.0
        };
        out.push_str(&format!(
            "  {:width$}  {:>9.3} s  {share:>5.1} %",
            s.stage, s.seconds
        ));
        if s.starts > 1 {
            out.push_str(&format!("  ({} times)", s.starts));
        }
        out.push('\n');
    }
    out
}

/// The repairs' wall-clock times as `discover --timings` prints them after the stages':
/// one line a repair, longest first, with its seconds and number of calls.
fn repair_table(times: &[kinetree_pipeline::RepairTime]) -> String {
    let width = times.iter().map(|r| r.repair.len()).max().unwrap_or(0);
    let mut out = String::from(
        "repair times (wall clock, summed over their calls; a call's time includes the models \
         it had built and the repairs those ran):\n",
    );
    for r in times {
        out.push_str(&format!(
            "  {:width$}  {:>9.3} s  {:>5} call(s)\n",
            r.repair, r.seconds, r.calls
        ));
    }
    out
}

/// `--timings`' account of the memo of pair tests and hinge fits.
fn memo_line(m: &kinetree_core::memo::MemoUsage) -> String {
    format!(
        "memo: {} of {} pair tests and hinge fits answered from {} kept results ({:.1} MiB)",
        m.hits,
        m.hits + m.misses,
        m.kept,
        m.bytes as f64 / f64::from(1u32 << 20)
    )
}

/// Runs `work` with a [`StageDisplay`] (none when `quiet`), cleared when it ends.
fn with_stage_display<T>(
    quiet: bool,
    work: impl FnOnce(&dyn kinetree_pipeline::DiscoveryObserver) -> T,
) -> T {
    use std::io::IsTerminal;
    if quiet || !std::io::stderr().is_terminal() {
        return work(&());
    }
    let bar =
        indicatif::ProgressBar::with_draw_target(None, indicatif::ProgressDrawTarget::hidden());
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("{spinner} discover [{elapsed}] {wide_msg}")
    {
        bar.set_style(style);
    }
    let display = StageDisplay {
        bar: bar.clone(),
        stage: std::sync::Mutex::new(String::new()),
    };
    let (done, wait) = std::sync::mpsc::channel::<()>();
    let shower = std::thread::spawn(move || {
        if wait.recv_timeout(PROGRESS_DELAY).is_err() {
            bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            bar.enable_steady_tick(std::time::Duration::from_millis(120));
        }
    });
    let out = work(&display);
    let _ = done.send(());
    let _ = shower.join();
    display.bar.finish_and_clear();
    out
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run an experiment config (with no argument: the embedded paper experiment).
    Run {
        /// Experiment TOML file.
        config: Option<PathBuf>,
        /// Folder under which `<experiment name>/` is written.
        #[arg(long, default_value = "results")]
        results: PathBuf,
        /// Sweeps: keep the runs already in `<results>/<name>/runs.csv` (a sweep appends each
        /// run there as it ends) and run only the others.
        #[arg(long)]
        resume: bool,
        /// Sweeps: the most runs (grid points x seeds) accepted.
        #[arg(long, default_value_t = kinetree_pipeline::sweep::DEFAULT_MAX_RUNS)]
        max_runs: u64,
        /// Sweeps: run shard I of N only (grid points I, I+N, I+2N, ..., every seed), into
        /// `<results>/<name>/shard-I-of-N/`; `kinetree merge` joins the shards. For a
        /// cluster's job array: `--shard $SLURM_ARRAY_TASK_ID/16`.
        #[arg(long, value_name = "I/N")]
        shard: Option<kinetree_pipeline::sweep::Shard>,
    },
    /// Print a shell completion script for bash, zsh, fish, elvish or powershell.
    ///
    /// bash: `kinetree completions bash > ~/.local/share/bash-completion/completions/kinetree`;
    /// zsh: save it as `_kinetree` in a folder on `$fpath`; fish: save it as
    /// `~/.config/fish/completions/kinetree.fish`.
    Completions {
        /// bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
    /// Join the shards of a sweep (`run --shard I/N`) into its runs.csv, table.md and
    /// resolved.toml, the same files an unsharded run writes.
    Merge {
        /// The sweep's result folder, `<results>/<name>`, holding `shard-I-of-N/` folders.
        dir: PathBuf,
    },
    /// Discover the structure in a tracks file (.npy, .npz, .csv, .c3d or .trc) and write the model
    /// JSON.
    Discover {
        /// Tracks file: float (T, N, 3) .npy with NaN for occluded points, .npz from a point
        /// tracker (see --tracks-key), frame,point,x,y,z .csv, or a C3D motion-capture file
        /// (marker labels are kept).
        tracks: PathBuf,
        #[command(flatten)]
        keys: TrackArgs,
        /// Per-coordinate noise std-dev in metres; estimated from the data when absent.
        #[arg(long)]
        noise_sigma: Option<f64>,
        /// Pipeline config (TOML, the `[pipeline]` table's contents) to swap stages; it
        /// replaces the preset.
        #[arg(long)]
        pipeline: Option<PathBuf>,
        /// The settings without `--pipeline`: `motion-capture` (for markers on skin: the
        /// noise from each marker's most rigid partners, the distance std-dev as
        /// dissimilarity, 3 mm / 0.02 rad of joint model error; `experiments/real/README.md`),
        /// `default` (the defaults, for rigid bodies), or `auto`: `motion-capture` for C3D
        /// and TRC files, `default` otherwise.
        #[arg(long, value_enum, default_value_t = Preset::Auto)]
        preset: Preset,
        /// Output model JSON.
        #[arg(short, long, default_value = "model.json")]
        output: PathBuf,
        /// Do not write the companion `<output stem>.poses.npy` with every body's fitted pose
        /// in every frame (a float64 (T, B, 9) array: quaternion x, y, z, w, origin x, y, z,
        /// rotation and origin standard deviations; NaN where unknown).
        #[arg(long)]
        no_poses: bool,
        /// When the discovery ends, print each stage's wall-clock time on stderr (`setup`,
        /// `pair statistics`, `clustering`, then each model pass's `bodies`, `tree`,
        /// `whole-tree fit`, `points`, ...), then each repair's: where the time goes on these
        /// tracks.
        #[arg(long)]
        timings: bool,
    },
    /// Estimate joint positions of (new) frames from a discovered model: one CSV column per
    /// joint (three per spherical joint, `_rx`, `_ry`, `_rz`: its rotation vector; two per
    /// universal joint, `_q1`, `_q2`: its angles), after the root's pose (six columns) when
    /// the root is not static; angles unwrapped over the frames, empty where unknown.
    Observe {
        /// Model JSON written by `discover` or `run`.
        model: PathBuf,
        /// Tracks (.npy, .npz, .csv, .c3d or .trc) with the model's points.
        tracks: PathBuf,
        #[command(flatten)]
        keys: TrackArgs,
        /// Output CSV.
        #[arg(short, long, default_value = "config.csv")]
        output: PathBuf,
        /// Write the positions smoothed over the frames (a constant-velocity Kalman smoother
        /// weighting each frame's position by its standard deviation, as the model's
        /// `smoothed_positions`) instead of each frame's own estimate.
        #[arg(long)]
        smooth: bool,
        /// A frame is flagged as not explained by the model when its residual (the
        /// `residual_in_sigma` column: RMS distance of its keypoints from the fitted model, in
        /// units of the model's noise) exceeds this many times the model's own re-prediction
        /// RMS.
        #[arg(long, default_value_t = kinetree_fit::DEFAULT_UNEXPLAINED_FACTOR)]
        unexplained_factor: f64,
        /// Also write every body's fitted pose in every frame to this `.npy`, laid out as
        /// `discover`'s companion poses file.
        #[arg(long, value_name = "FILE")]
        poses: Option<PathBuf>,
    },
    /// Export a model: URDF (links, joints with origin, axis and observed limits), MJCF
    /// (MuJoCo: hinge, slide, ball and free joints), DOT (the kinematic graph) or JSON (the
    /// model, re-validated, with its schema version).
    Export {
        /// Model JSON written by `discover` or `run`.
        model: PathBuf,
        /// `urdf`, `mjcf`, `dot` or `json`.
        #[arg(long, value_enum)]
        format: ExportFormat,
        /// Output file.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Write an interactive 3D view of a model and its tracks as one self-contained HTML
    /// file (no network needed): keypoints coloured by body, links, joint axes and pivots,
    /// play/pause, a time slider, orbit/zoom, and the joint positions over time.
    View {
        /// Model JSON written by `discover` or `run`.
        model: PathBuf,
        /// Tracks (.npy, .npz, .csv, .c3d or .trc) of the model's points: the ones it was
        /// discovered on, or new frames.
        tracks: PathBuf,
        #[command(flatten)]
        keys: TrackArgs,
        /// Output HTML file.
        #[arg(short, long, default_value = "view.html")]
        output: PathBuf,
        /// The page's title [default: the model file's name].
        #[arg(long)]
        title: Option<String>,
        /// Most keypoint samples (frames x points) in the page; a longer recording keeps
        /// every k-th frame.
        #[arg(long, default_value_t = kinetree_view::DEFAULT_MAX_SAMPLES)]
        max_samples: usize,
        /// Playback rate in frames per second [default: the recording's, else 30].
        #[arg(long)]
        fps: Option<f64>,
    },
    /// Print a readable summary of a model: bodies with their keypoints, joints, warnings.
    Inspect {
        /// Model JSON written by `discover` or `run`.
        model: PathBuf,
    },
    /// Compare a model with the simulator's truth (`truth.json` beside the tracks `simulate`
    /// wrote): the segmentation's ARI, the bodies, and each true joint found with its type,
    /// its errors, or why it was missed (wrong type, child missing or split, reversed, on its
    /// grandparent, a sibling or another body).
    Evaluate {
        /// Model JSON written by `discover` or `run`.
        model: PathBuf,
        /// The truth: `truth.json` written by `simulate`.
        #[arg(long)]
        truth: PathBuf,
        /// Also write the comparison as JSON (the `kinetree_eval::Evaluation` fields).
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    /// Fit a joint to one point's track (a door or drawer handle): revolute (axis, centre,
    /// radius) or prismatic (axis), printed and written as JSON.
    FitTrack {
        /// Text file of `x y z` lines, a `.npy` of one point (`(T, 3)` or `(T, 1, 3)`), or
        /// a tracks file (.npy, .npz, .csv, .c3d, .trc) with `--point`.
        track: PathBuf,
        #[command(flatten)]
        keys: TrackArgs,
        /// Point index in a tracks file.
        #[arg(long)]
        point: Option<usize>,
        /// The circle (revolute) is taken when the line's extra residual is less probable
        /// than this under noise alone (an F-test, or a chi-square test with
        /// `--noise-sigma`).
        #[arg(long, default_value_t = kinetree_dof::TRACK_SIGNIFICANCE)]
        significance: f64,
        /// ... and when it sweeps at least this angle, degrees.
        #[arg(long, default_value_t = kinetree_dof::TRACK_MIN_ARC_DEG)]
        min_arc_deg: f64,
        /// Per-coordinate noise of the samples, metres (default: estimated from the
        /// circle's residual).
        #[arg(long)]
        noise_sigma: Option<f64>,
        /// Output JSON.
        #[arg(short, long, default_value = "track-joint.json")]
        output: PathBuf,
    },
    /// Write a synthetic data set: tracks.npy, tracks.csv, tracks.npz and truth.json.
    Simulate {
        /// Output folder.
        #[arg(short, long, default_value = "sim")]
        output: PathBuf,
        /// Mechanism: `paper-arm`, `skeleton` (a human-like skeleton of ball joints and
        /// hinges), `skeleton-universal` (the same with universal wrists and ankles),
        /// `skeleton-floating` (the same with a freely moving pelvis and nothing static),
        /// `skeleton-clinical` (the floating skeleton with a clinical marker set: two markers
        /// a limb segment, four on the pelvis, torso and head, two on each elbow, knee, wrist
        /// and ankle axis), `gripper-parallel` or `gripper-angular` (an arm with two fingers that slide along,
        /// or turn about, one axis), `hand` (a palm with four fingers and a thumb),
        /// `hand-knuckles` (the same with a knuckle body between two hinges at each finger's
        /// base), `hidden-link` (an arm whose wrist link is seen in part of the frames),
        /// `slender-planar` or `slender` (an arm of rods a few millimetres thick turning about
        /// parallel, or random, axes; `--joints` of them), `scale` (a base and four links
        /// R-R-P-R with `--points` keypoints inside them, as dense tracks), or `random` with
        /// the options below.
        #[arg(long, default_value = "paper-arm")]
        mechanism: String,
        /// Seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Number of joints (random mechanisms and slender arms).
        #[arg(long, default_value_t = 3)]
        joints: usize,
        /// Attach bodies as a tree rather than a chain (random mechanisms).
        #[arg(long)]
        tree: bool,
        /// Probability that a joint is prismatic (random mechanisms).
        #[arg(long, default_value_t = 0.3)]
        prismatic_fraction: f64,
        /// Probability that a joint that is not prismatic is a ball joint (random mechanisms).
        #[arg(long, default_value_t = 0.0)]
        spherical_fraction: f64,
        /// Per-coordinate noise, metres.
        #[arg(long, default_value_t = 0.001)]
        noise_sigma: f64,
        /// Extra random occlusion fraction.
        #[arg(long, default_value_t = 0.0)]
        dropout: f64,
        /// Number of frames (default: 100 for the paper arm, 200 for random mechanisms).
        #[arg(long)]
        frames: Option<usize>,
        /// Number of keypoints (the scale scenario; default 1000).
        #[arg(long)]
        points: Option<usize>,
        /// Soft-tissue artefact of the skeletons, metres: each marker drifts from its place
        /// by a slow offset of at most this much per coordinate (default 0).
        #[arg(long, value_name = "M")]
        soft_tissue: Option<f64>,
    },
}

/// How `kinetree run` treats a sweep.
struct SweepFlags {
    quiet: bool,
    resume: bool,
    max_runs: u64,
    shard: Option<kinetree_pipeline::sweep::Shard>,
}

/// The limits given on the command line, which replace a configuration's.
#[derive(Debug, Clone, Copy)]
struct Limits {
    memory_gib: Option<f64>,
    minutes: Option<f64>,
}

impl Limits {
    /// Puts the limits given into `cfg`.
    fn apply(&self, cfg: &mut PipelineConfig) {
        if let Some(m) = self.memory_gib {
            cfg.max_memory_gib = m;
        }
        if let Some(m) = self.minutes {
            cfg.max_minutes = m;
        }
    }
}

fn run(config: Option<PathBuf>, results: &Path, limits: Limits, flags: &SweepFlags) -> Result<()> {
    let (text, base) = match &config {
        Some(p) => (
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            p.parent().map(Path::to_path_buf).unwrap_or_default(),
        ),
        None => (PAPER_EXPERIMENT_TOML.to_string(), PathBuf::from(".")),
    };
    if kinetree_pipeline::sweep::is_sweep(&text) {
        if limits.memory_gib.is_some() {
            bail!(
                "--max-memory is not taken by a sweep; set `pipeline.max_memory_gib` in its config"
            );
        }
        if limits.minutes.is_some() {
            bail!(
                "--max-minutes is not taken by a sweep; set `pipeline.max_minutes` in its config"
            );
        }
        return sweep(&text, config.as_deref(), &base, results, flags);
    }
    if flags.resume || flags.shard.is_some() {
        bail!(
            "--{} is for sweeps; {} is a single experiment",
            if flags.resume { "resume" } else { "shard" },
            where_config(config.as_deref())
        );
    }
    let mut cfg = ExperimentConfig::from_toml(&text)
        .with_context(|| format!("in {}", where_config(config.as_deref())))?;
    limits.apply(&mut cfg.pipeline);
    let outcome = run_experiment(&cfg, &base)
        .with_context(|| format!("in {}", where_config(config.as_deref())))?;
    let model = &outcome.discovery.model;
    emitln!(
        "experiment {}: {}",
        cfg.experiment.name,
        cfg.experiment.description
    );
    emit(&summary(model));
    emitln!(
        "\nTable I: non-zero singular values of translation (T, m), rotation (R, rad) and centre (C, m)"
    );
    emit(&table_text(model));
    if let (Some(e), Some(truth)) = (&outcome.evaluation, &outcome.truth) {
        emit("\n");
        emit(&kinetree_pipeline::report::evaluation_text(e, truth));
    }
    let dir = results.join(&cfg.experiment.name);
    write_results(&cfg, &outcome, &dir)?;
    emitln!("\nwrote {}", dir.display());
    Ok(())
}

/// Runs a sweep config: a progress bar on stderr, then `runs.csv`, `table.md` and
/// `resolved.toml` under `results/<name>/`.
fn where_config(config: Option<&Path>) -> String {
    config.map_or("the embedded paper experiment".into(), |p| {
        p.display().to_string()
    })
}

fn sweep(
    text: &str,
    config: Option<&Path>,
    base: &Path,
    results: &Path,
    flags: &SweepFlags,
) -> Result<()> {
    use std::io::Write;
    let parsed = kinetree_pipeline::sweep::Sweep::from_toml_within(text, flags.max_runs)
        .with_context(|| format!("in {}", where_config(config)))?;
    let name = parsed.name()?;
    let dir = results.join(&name);
    match flags.shard {
        None => eprintln!(
            "sweep {name}: {} grid point(s) x {} seed(s) = {} runs, into {}",
            parsed.points.len(),
            parsed.seeds().len(),
            parsed.n_runs(),
            dir.display()
        ),
        Some(shard) => eprintln!(
            "sweep {name}, shard {shard}: {} of {} runs, into {}",
            parsed.jobs(Some(shard)).len(),
            parsed.n_runs(),
            dir.join(shard.folder()).display()
        ),
    }
    let progress = |done: usize, total: usize| {
        if flags.quiet {
            return;
        }
        let width = 40;
        let filled = done * width / total.max(1);
        let mut err = std::io::stderr().lock();
        let _ = write!(
            err,
            "\r[{}{}] {done}/{total} runs",
            "#".repeat(filled),
            " ".repeat(width - filled)
        );
        if done == total {
            let _ = writeln!(err);
        }
        let _ = err.flush();
    };
    let options = kinetree_pipeline::sweep::SweepOptions {
        resume: flags.resume,
        shard: flags.shard,
    };
    let runs = kinetree_pipeline::sweep::run_sweep(&parsed, base, &dir, &progress, options)?;
    match flags.shard {
        None => {
            emit(&kinetree_pipeline::sweep::table_markdown(
                &name, &parsed, &runs,
            ));
            emitln!("wrote {}", dir.display());
        }
        Some(shard) => emitln!(
            "wrote {} runs to {}; `kinetree merge {}` joins the shards once all have run",
            runs.len(),
            dir.join(shard.folder()).display(),
            dir.display()
        ),
    }
    Ok(())
}

/// `kinetree merge`: a sharded sweep's files from its shards.
fn merge(dir: &Path) -> Result<()> {
    let (name, sweep, runs) = kinetree_pipeline::sweep::merge_shards(dir)?;
    emit(&kinetree_pipeline::sweep::table_markdown(
        &name, &sweep, &runs,
    ));
    emitln!("merged {} runs into {}", runs.len(), dir.display());
    Ok(())
}

/// Runs the command; an error is printed as its message and the causes that message does not
/// already contain (a file error's message quotes its cause), and the exit code is 1.
fn main() -> std::process::ExitCode {
    match run_command() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let mut shown: Vec<String> = Vec::new();
            for cause in e.chain() {
                let text = cause.to_string();
                if !shown.iter().any(|s| s.contains(&text)) {
                    shown.push(text);
                }
            }
            eprintln!("error: {}", shown[0]);
            for cause in &shown[1..] {
                eprintln!("  caused by: {cause}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

fn run_command() -> Result<()> {
    let cli = Cli::parse();
    configure_threads()?;
    let max_memory = cli.max_memory;
    let limits = Limits {
        memory_gib: max_memory,
        minutes: cli.max_minutes,
    };
    if let Some(m) = limits.minutes {
        kinetree_core::limits::validate_minutes("--max-minutes", m)?;
    }
    let quiet = cli.quiet;
    let memory = max_memory.unwrap_or(kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB);
    kinetree_core::limits::validate_limit("--max-memory", memory)?;
    let read_tracks =
        |path: &Path, keys: &TrackArgs| kinetree_io::read_tracks_with(path, &keys.options(memory));
    match cli.command {
        Command::Run {
            config,
            results,
            resume,
            max_runs,
            shard,
        } => run(
            config,
            &results,
            limits,
            &SweepFlags {
                quiet,
                resume,
                max_runs,
                shard,
            },
        ),
        Command::Merge { dir } => merge(&dir),
        Command::Completions { shell } => {
            let mut script = Vec::new();
            clap_complete::generate(
                shell,
                &mut <Cli as clap::CommandFactory>::command(),
                "kinetree",
                &mut script,
            );
            emit(&String::from_utf8_lossy(&script));
            Ok(())
        }
        Command::Discover {
            tracks,
            keys,
            noise_sigma,
            pipeline,
            preset,
            output,
            no_poses,
            timings,
        } => {
            let mut cfg = match &pipeline {
                Some(p) => {
                    let text = std::fs::read_to_string(p)
                        .with_context(|| format!("reading {}", p.display()))?;
                    toml_pipeline(&text).with_context(|| format!("in {}", p.display()))?
                }
                None => preset_config(preset, &tracks),
            };
            if noise_sigma.is_some() {
                cfg.noise_sigma_m = noise_sigma;
            }
            limits.apply(&mut cfg);
            let mut inputs = vec![tracks.as_path()];
            inputs.extend(pipeline.as_deref());
            refuse_overwriting(&output, &inputs)?;
            let poses_path = (!no_poses).then(|| poses_beside(&output));
            if let Some(p) = &poses_path {
                refuse_overwriting(p, &inputs)?;
            }
            let built = Pipeline::from_config(&cfg).with_context(|| match &pipeline {
                Some(p) => format!("in {}", p.display()),
                None => "in the pipeline options".into(),
            })?;
            let t = read_tracks(&tracks, &keys)?;
            let mut d = with_stage_display(quiet, |observer| {
                let timer = kinetree_pipeline::StageTimes::new(observer);
                let d = built.run_observed(&t, &timer);
                if timings {
                    eprint!("{}", stage_table(&timer.totals()));
                    eprint!("{}", repair_table(&timer.repair_totals()));
                    eprintln!("{}", memo_line(&timer.memo_usage()));
                }
                d
            })?;
            emit(&summary(&d.model));
            if let Some(p) = &poses_path {
                let seen = kinetree_fit::observe(&d.model, &t, Default::default())?;
                let (values, shape) = seen.pose_table();
                kinetree_io::write_array_npy(p, &shape, &values)?;
                d.model.body_poses_file = p.file_name().map(|n| n.to_string_lossy().into_owned());
                emitln!("wrote {}", p.display());
            }
            kinetree_io::write_json(&output, &d.model)?;
            emitln!("wrote {}", output.display());
            Ok(())
        }
        Command::Observe {
            model,
            tracks,
            keys,
            output,
            smooth,
            unexplained_factor,
            poses,
        } => observe(
            &model,
            &tracks,
            &output,
            &ObserveOptions {
                smooth,
                unexplained_factor,
                read: keys.options(memory),
                poses,
            },
        ),
        Command::Export {
            model,
            format,
            output,
        } => {
            refuse_overwriting(&output, &[&model])?;
            let m = kinetree_io::read_model(&model)?;
            let text = match format {
                ExportFormat::Urdf => kinetree_io::export::to_urdf(&m)
                    .with_context(|| format!("exporting {}", model.display()))?,
                ExportFormat::Mjcf => kinetree_io::export::to_mjcf(&m)
                    .with_context(|| format!("exporting {}", model.display()))?,
                ExportFormat::Dot => kinetree_io::export::to_dot(&m),
                ExportFormat::Json => serde_json::to_string_pretty(&m)?,
            };
            kinetree_io::write_text(&output, &text)?;
            emitln!("wrote {}", output.display());
            Ok(())
        }
        Command::View {
            model,
            tracks,
            keys,
            output,
            title,
            max_samples,
            fps,
        } => {
            refuse_overwriting(&output, &[&model, &tracks])?;
            let (m, t) = model_and_tracks(&model, &tracks, &keys.options(memory))?;
            let options = kinetree_view::ViewOptions {
                title: title.unwrap_or_else(|| format!("kinetree: {}", model.display())),
                max_samples,
                fps,
            };
            let html = kinetree_view::to_html(&m, &t, &options)
                .with_context(|| format!("viewing {}", model.display()))?;
            kinetree_io::write_text(&output, &html)?;
            emitln!("wrote {} ({} KiB)", output.display(), html.len() / 1024);
            Ok(())
        }
        Command::Evaluate {
            model,
            truth,
            output,
        } => {
            if let Some(out) = &output {
                refuse_overwriting(out, &[&model, &truth])?;
            }
            let m = kinetree_io::read_model(&model)?;
            let t: kinetree_synth::GroundTruth = kinetree_io::read_json(&truth)?;
            kinetree_eval::check_comparable(&m, &t).map_err(|e| e.in_file(&truth))?;
            let e = kinetree_eval::evaluate(&m, &t);
            emit(&kinetree_pipeline::report::evaluation_text(&e, &t));
            if let Some(out) = &output {
                kinetree_io::write_json(out, &e)?;
                emitln!("wrote {}", out.display());
            }
            Ok(())
        }
        Command::Inspect { model } => {
            let m = kinetree_io::read_model(&model)?;
            emit(&kinetree_pipeline::report::inspect(&m));
            Ok(())
        }
        Command::FitTrack {
            track,
            keys,
            point,
            significance,
            min_arc_deg,
            noise_sigma,
            output,
        } => {
            refuse_overwriting(&output, &[&track])?;
            let samples = kinetree_io::read_one_track(&track, point, &keys.options(memory))?;
            let params = kinetree_dof::TrackFitParams {
                noise_sigma_m: noise_sigma,
                significance,
                min_arc_deg,
            };
            let fit = kinetree_dof::fit_point_track(&samples, &params)
                .with_context(|| format!("fitting {}", track.display()))?;
            emitln!(
                "{} samples; line RMS {:.2} mm, circle RMS {:.2} mm, noise {:.2} mm, p = {:.2e}",
                samples.len(),
                fit.line_rms_m * 1e3,
                fit.circle_rms_m * 1e3,
                fit.noise_sigma_m * 1e3,
                fit.p_value
            );
            emitln!("{}", serde_json::to_string(&fit.joint)?);
            kinetree_io::write_json(&output, &fit)?;
            emitln!("wrote {}", output.display());
            Ok(())
        }
        Command::Simulate {
            output,
            mechanism,
            seed,
            joints,
            tree,
            prismatic_fraction,
            spherical_fraction,
            noise_sigma,
            dropout,
            frames,
            points,
            soft_tissue,
        } => {
            let data = kinetree_pipeline::config::SimulationRequest {
                mechanism,
                seed,
                joints,
                tree,
                prismatic_fraction,
                spherical_fraction,
                noise_sigma_m: noise_sigma,
                dropout,
                n_frames: frames,
                n_points: points,
                soft_tissue_m: soft_tissue,
            }
            .data()
            .map_err(simulate_flag)?;
            let (tracks, truth) = kinetree_pipeline::load_data(&data, Path::new("."), memory)
                .map_err(simulate_flag)?;
            std::fs::create_dir_all(&output)
                .with_context(|| format!("creating {}", output.display()))?;
            kinetree_io::write_npy(&output.join("tracks.npy"), &tracks)?;
            kinetree_io::write_csv(&output.join("tracks.csv"), &tracks)?;
            kinetree_io::write_npz(&output.join("tracks.npz"), &tracks)?;
            if let Some(t) = truth {
                kinetree_io::write_json(&output.join("truth.json"), &t)?;
            }
            emitln!(
                "wrote {} frames x {} points ({:.0} % occluded) to {}",
                tracks.n_frames(),
                tracks.n_points(),
                100.0 * tracks.occluded_fraction(),
                output.display()
            );
            Ok(())
        }
    }
}

/// A simulation parameter's error named by the `simulate` option it came from.
fn simulate_flag(e: kinetree_core::Error) -> kinetree_core::Error {
    match e {
        kinetree_core::Error::InvalidParameter { name, message } => {
            let flag = match name.as_str() {
                "data.n_frames" => "--frames",
                "data.n_points" => "--points",
                "data.soft_tissue_m" => "--soft-tissue",
                "data.n_joints" => "--joints",
                "data.prismatic_fraction" => "--prismatic-fraction",
                "data.spherical_fraction" => "--spherical-fraction",
                "data.noise_sigma_m" => "--noise-sigma",
                "data.dropout" => "--dropout",
                "data.seed" => "--seed",
                _ => return kinetree_core::Error::InvalidParameter { name, message },
            };
            kinetree_core::Error::InvalidParameter {
                name: flag.into(),
                message,
            }
        }
        other => other,
    }
}

/// A model and tracks of its points (`observe`, `view`), refused when the point counts
/// differ.
fn model_and_tracks(
    model_path: &Path,
    tracks_path: &Path,
    read: &kinetree_io::ReadOptions,
) -> Result<(kinetree_core::Model, kinetree_core::Tracks)> {
    let model = kinetree_io::read_model(model_path)?;
    let tracks = kinetree_io::read_tracks_with(tracks_path, read)?;
    if tracks.n_points() != model.n_points {
        bail!(
            "{} has {} points but the model {} was discovered on {}",
            tracks_path.display(),
            tracks.n_points(),
            model_path.display(),
            model.n_points
        );
    }
    Ok((model, tracks))
}

/// How `kinetree observe` reports.
struct ObserveOptions {
    smooth: bool,
    unexplained_factor: f64,
    read: kinetree_io::ReadOptions,
    poses: Option<PathBuf>,
}

fn observe(
    model_path: &Path,
    tracks_path: &Path,
    output: &Path,
    options: &ObserveOptions,
) -> Result<()> {
    use std::io::Write;
    let fit_options = kinetree_fit::ObserveOptions {
        smooth: options.smooth,
        unexplained_factor: options.unexplained_factor,
    };
    if !(fit_options.unexplained_factor.is_finite() && fit_options.unexplained_factor >= 1.0) {
        bail!(
            "--unexplained-factor must be a finite number of at least 1, got {}",
            fit_options.unexplained_factor
        );
    }
    refuse_overwriting(output, &[model_path, tracks_path])?;
    if let Some(p) = &options.poses {
        if p == output {
            bail!("--poses and -o name one file, {}; choose two", p.display());
        }
        refuse_overwriting(p, &[model_path, tracks_path, output])?;
    }
    let (model, tracks) = model_and_tracks(model_path, tracks_path, &options.read)?;
    let seen = kinetree_fit::observe(&model, &tracks, fit_options)?;
    if let Some(p) = &options.poses {
        let (values, shape) = seen.pose_table();
        kinetree_io::write_array_npy(p, &shape, &values)?;
        emitln!("wrote {}", p.display());
    }
    let mut header = seen.joint_names.clone();
    header.push("residual_in_sigma".into());
    kinetree_io::write_atomically(output, |w| {
        writeln!(w, "frame,{}", header.join(","))?;
        for t in 0..tracks.n_frames() {
            let mut row: Vec<String> = seen
                .positions
                .iter()
                .map(|c| c[t].map(|v| format!("{v:?}")).unwrap_or_default())
                .collect();
            row.push(
                seen.residual_in_sigma[t]
                    .map(|r| format!("{r:.3}"))
                    .unwrap_or_default(),
            );
            writeln!(w, "{t},{}", row.join(","))?;
        }
        Ok(())
    })?;
    let unexplained = &seen.unexplained;
    if !unexplained.is_empty() {
        let listed: Vec<String> = unexplained.iter().take(20).map(usize::to_string).collect();
        eprintln!(
            "warning: {} of {} frames are not explained by the model: their residual exceeds \
             {:.2} sigma ({} x the model's own {:.2}); frames {}{}. \
             Their joint positions are not to be trusted: check that the tracks are in metres, \
             in the model's point order, and of this mechanism.",
            unexplained.len(),
            tracks.n_frames(),
            seen.unexplained_bound,
            fit_options.unexplained_factor,
            seen.own_rms_in_sigma,
            listed.join(", "),
            if unexplained.len() > listed.len() {
                ", ..."
            } else {
                ""
            }
        );
    }
    emitln!(
        "wrote {} frames x {} joints to {} ({} frames not explained by the model)",
        tracks.n_frames(),
        seen.joint_names.len(),
        output.display(),
        unexplained.len()
    );
    Ok(())
}

/// The settings `kinetree discover` starts from without `--pipeline`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Preset {
    /// `motion-capture` for C3D and TRC files, `default` otherwise.
    Auto,
    /// The defaults, for rigid bodies.
    Default,
    /// The motion-capture settings, for markers on skin.
    MotionCapture,
}

/// The pipeline of `preset` for the tracks file `tracks`; says so when `auto` took the
/// motion-capture one.
fn preset_config(preset: Preset, tracks: &Path) -> PipelineConfig {
    let motion_capture = kinetree_pipeline::config::is_motion_capture_file(tracks);
    match preset {
        Preset::Default => PipelineConfig::default(),
        Preset::MotionCapture => PipelineConfig::motion_capture(),
        Preset::Auto if motion_capture => {
            eprintln!(
                "note: motion-capture file: using the motion-capture settings (markers on skin; \
                 --preset default for rigid bodies, --pipeline FILE for your own)"
            );
            PipelineConfig::motion_capture()
        }
        Preset::Auto => PipelineConfig::default(),
    }
}

fn toml_pipeline(text: &str) -> Result<PipelineConfig> {
    Ok(kinetree_pipeline::config::pipeline_from_toml(text)?)
}
