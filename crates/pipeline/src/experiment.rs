//! Experiments: load data, run the pipeline, evaluate against truth, write results.

use crate::config::{DataConfig, ExperimentConfig};
use crate::report::{summary, table_markdown};
use crate::run::{Discovery, Pipeline};
use kinetree_core::{Result, Tracks};
use kinetree_eval::{Evaluation, evaluate};
use kinetree_synth::{GroundTruth, Scenario, paper_arm, random_scenario, simulate};
use std::path::{Path, PathBuf};

/// What an experiment produced.
#[derive(Debug, Clone)]
pub struct ExperimentOutcome {
    /// The input tracks.
    pub tracks: Tracks,
    /// The pipeline's output.
    pub discovery: Discovery,
    /// The truth, for synthetic data.
    pub truth: Option<GroundTruth>,
    /// The model compared with the truth, for synthetic data.
    pub evaluation: Option<Evaluation>,
}

/// The scenario behind synthetic data, `None` for files.
///
/// # Errors
/// A mechanism's parameters out of range ([`kinetree_synth::RandomParams::validate`], and the
/// same ranges of frames, dropout and noise for the paper arm), naming `data.<key>`.
pub fn scenario(data: &DataConfig) -> Result<Option<Scenario>> {
    Ok(match data {
        DataConfig::PaperArm(p) => {
            use kinetree_core::limits::{check_count, check_within};
            check_count("data.n_frames", p.n_frames, 2, 1_000_000)?;
            check_within("data.dropout", p.dropout, 0.0, 1.0)?;
            check_within("data.noise_sigma_m", p.noise_sigma_m, 0.0, 1.0)?;
            let mut s = paper_arm(p.seed);
            s.noise_sigma_m = p.noise_sigma_m;
            s.dropout = p.dropout;
            s.n_frames = p.n_frames;
            Some(s)
        }
        DataConfig::Random(p) => {
            p.validate()?;
            Some(random_scenario(p))
        }
        DataConfig::Skeleton(p) => {
            p.validate()?;
            Some(kinetree_synth::skeleton_scenario(p))
        }
        DataConfig::Gripper(p) => {
            p.validate()?;
            Some(kinetree_synth::gripper_scenario(p))
        }
        DataConfig::Hand(p) => {
            p.validate()?;
            Some(kinetree_synth::hand_scenario(p))
        }
        DataConfig::HiddenLink(p) => {
            p.validate()?;
            Some(kinetree_synth::hidden_link_arm(p))
        }
        DataConfig::SlenderArm(p) => {
            p.validate()?;
            Some(kinetree_synth::slender_arm(p))
        }
        DataConfig::Scale(p) => {
            p.validate()?;
            Some(kinetree_synth::scale_scenario(p))
        }
        DataConfig::File(_) => None,
    })
}

/// Loads (or simulates) an experiment's tracks; file paths are relative to `base_dir`. Data
/// whose estimated memory exceeds `max_memory_gib` are refused before they are read or
/// simulated.
///
/// # Errors
/// The simulator's or the reader's errors; [`kinetree_core::Error::TooLarge`].
pub fn load_data(
    data: &DataConfig,
    base_dir: &Path,
    max_memory_gib: f64,
) -> Result<(Tracks, Option<GroundTruth>)> {
    kinetree_core::limits::validate_limit("max_memory_gib", max_memory_gib)?;
    if let DataConfig::File(f) = data {
        let path: PathBuf = if f.path.is_absolute() {
            f.path.clone()
        } else {
            base_dir.join(&f.path)
        };
        let options = kinetree_io::ReadOptions {
            max_memory_gib,
            tracks_key: f.tracks_key.clone(),
            visibility_key: f.visibility_key.clone(),
            occluded_key: f.occluded_key.clone(),
        };
        return Ok((kinetree_io::read_tracks_with(&path, &options)?, None));
    }
    let s = scenario(data)?.ok_or_else(|| kinetree_core::Error::Config("no scenario".into()))?;
    let points: usize = s
        .mechanism
        .bodies
        .iter()
        .map(|b| 8 + b.extra_points + b.interior_points)
        .sum();
    // The simulator holds the tracks, their noise-free copy and every body's pose per frame.
    kinetree_core::limits::check_memory(
        &format!("simulating {} frames x {points} points", s.n_frames),
        3.0 * kinetree_core::limits::tracks_bytes(s.n_frames as u64, points as u64),
        max_memory_gib,
    )?;
    let d = simulate(&s)?;
    Ok((d.tracks, Some(d.truth)))
}

/// Runs an experiment end to end.
///
/// # Errors
/// Any stage's error.
pub fn run_experiment(cfg: &ExperimentConfig, base_dir: &Path) -> Result<ExperimentOutcome> {
    let (tracks, truth) = load_data(&cfg.data, base_dir, cfg.pipeline.max_memory_gib)?;
    let pipeline = Pipeline::from_config(&cfg.pipeline)?;
    let discovery = pipeline.run(&tracks)?;
    let evaluation = truth.as_ref().map(|t| evaluate(&discovery.model, t));
    Ok(ExperimentOutcome {
        tracks,
        discovery,
        truth,
        evaluation,
    })
}

/// The paper's Table I as printed (Sec. IV), shown beside ours for the paper arm.
const PAPER_TABLE_I: &str = "
## The paper's Table I, as printed

|   | F1 T | F1 R | F1 C | F2 T | F2 R | F2 C | F3 T | F3 R | F3 C |
|---|---|---|---|---|---|---|---|---|---|
| F0 | - | - | - | 2.9, 1.5 | 18.9 | 1.2 | 4.4, 3.1 | 19.6 | 10.2, 2.0, 0.4 |
| F1 |   |   |   | 2.9, 1.5 | 18.9 | 1.3 | 3.2, 2.8 | 19.6 | 10.1, 2.0, 0.4 |
| F2 |   |   |   |   |   |   | 6.0, 0.4 | 8.9 | 1.1 |

The same cells are empty in both tables. Our C cells, like the paper's, are the centre
estimates themselves (not centred): one value for the revolute pairs (the fixed centre's
distance from the link's centroid times sqrt(T)), more where the centre moves; ours have at
most two, since a centre is taken in the plane perpendicular to the axis. Our T and R come from
centred matrices, so values differ in size; the rotation values (one per moving pair) are of
the same order: 18.9, 19.6 and 8.9
in the paper. See experiments/paper-table1/README.md.
";

/// Writes `resolved.toml`, `model.json`, `table.md` (with the paper's printed Table I for the
/// paper arm), `figures/` (with the `figures` feature, `kinetree_figures::write_figures`)
/// and, for synthetic data, `evaluation.json` under `dir`.
///
/// # Errors
/// I/O errors, naming the file.
pub fn write_results(
    cfg: &ExperimentConfig,
    outcome: &ExperimentOutcome,
    dir: &Path,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| kinetree_core::Error::Io(e).in_file(dir))?;
    let write = |name: &str, text: &str| kinetree_io::write_text(&dir.join(name), text);
    write("resolved.toml", &cfg.resolved_toml()?)?;
    kinetree_io::write_json(&dir.join("model.json"), &outcome.discovery.model)?;
    let model = &outcome.discovery.model;
    let mut table = format!(
        "# {}: Table I\n\nNon-zero singular values of the relative translation (T, metres), rotation (R, radians) and centre-of-rotation (C, metres) matrices. F0 is the camera frame, F1.. the discovered bodies in tree order.\n\n",
        cfg.experiment.name
    );
    table.push_str(&table_markdown(model));
    if matches!(cfg.data, DataConfig::PaperArm(_)) {
        table.push_str(PAPER_TABLE_I);
    }
    table.push_str("\n## Structure\n\n```\n");
    table.push_str(&summary(model));
    table.push_str("```\n");
    write("table.md", &table)?;
    if let Some(e) = &outcome.evaluation {
        kinetree_io::write_json(&dir.join("evaluation.json"), e)?;
    }
    #[cfg(feature = "figures")]
    write_figures(outcome, dir)?;
    Ok(())
}

/// The experiment's figures under `dir/figures`.
#[cfg(feature = "figures")]
fn write_figures(outcome: &ExperimentOutcome, dir: &Path) -> Result<()> {
    // The pair statistics of a sampled discovery cover its sample alone: its figures show
    // the sample's points, renumbered as the statistics number them.
    let sampled = match &outcome.discovery.sampled {
        Some(sample) => Some((
            outcome.tracks.select_points(sample)?,
            sample_model(&outcome.discovery.model, sample),
        )),
        None => None,
    };
    let (tracks, model) = match &sampled {
        Some((t, m)) => (t, m),
        None => (&outcome.tracks, &outcome.discovery.model),
    };
    let std_m: Vec<f64> = outcome
        .discovery
        .stats
        .var_m2
        .iter()
        .zip(&outcome.discovery.stats.count)
        .map(|(v, &c)| if c >= 2 { v.max(0.0).sqrt() } else { f64::NAN })
        .collect();
    let truth_positions: Vec<Option<Vec<f64>>> = match &outcome.truth {
        Some(t) => {
            let map = kinetree_eval::body_map(model, t);
            model
                .joints
                .iter()
                .map(|j| true_joint_positions(t, &map, j))
                .collect()
        }
        None => vec![None; model.joints.len()],
    };
    kinetree_figures::write_figures(
        &dir.join("figures"),
        &kinetree_figures::FigureInput {
            tracks,
            model,
            distance_std_m: &std_m,
            dissimilarity: &outcome.discovery.dissimilarity.values,
            measure: &outcome.discovery.dissimilarity.measure,
            true_positions: &truth_positions,
        },
    )?;
    Ok(())
}

/// `model` on the points of `sample` alone, point `sample[k]` renumbered `k`.
#[cfg(feature = "figures")]
fn sample_model(model: &kinetree_core::Model, sample: &[usize]) -> kinetree_core::Model {
    let mut m = model.clone();
    let mut index = vec![None; model.n_points];
    for (k, &i) in sample.iter().enumerate() {
        index[i] = Some(k);
    }
    m.n_points = sample.len();
    m.point_body = sample.iter().map(|&i| model.point_body[i]).collect();
    for b in &mut m.bodies {
        let kept: Vec<(usize, Option<[f64; 3]>)> = b
            .points
            .iter()
            .enumerate()
            .filter_map(|(j, &i)| Some((index[i]?, b.shape.get(j).copied().flatten())))
            .collect();
        b.points = kept.iter().map(|e| e.0).collect();
        b.shape = kept.into_iter().map(|e| e.1).collect();
    }
    m
}

#[cfg(feature = "figures")]
/// The true positions of the joint that carries the true body holding most of `j.child`'s
/// points (`map`, from [`kinetree_eval::body_map`]), put on the estimate's sign and offset.
fn true_joint_positions(
    truth: &GroundTruth,
    map: &[usize],
    j: &kinetree_core::model::Joint,
) -> Option<Vec<f64>> {
    let body = *map.get(j.child)?;
    let k = truth
        .mechanism
        .joints
        .iter()
        .position(|tj| tj.child == body)?;
    let q = truth.single_positions(k)?;
    // truth ~ sign * estimate + offset, so estimate ~ sign * (truth - offset).
    let a = kinetree_eval::alignment(&j.positions, q)?;
    Some(q.iter().map(|t| a.sign * (t - a.offset)).collect())
}
