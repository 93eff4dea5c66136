//! Sweeps: an experiment config with a `[sweep]` table expands into a grid of runs over seeds.
//!
//! ```toml
//! [experiment]
//! name = "noise-sweep"
//!
//! [sweep]
//! seeds = 20                      # seeds 0..20 (or a list: [3, 5, 8])
//! seed_keys = ["data.seed"]       # where the seed goes (the default)
//!
//! [sweep.grid]                    # dotted paths into the config, each with a list of values
//! "data.noise_sigma_m" = [0.0001, 0.001, 0.01]
//! "pipeline.clustering" = [{ kind = "hierarchical" }, { kind = "spectral" }]
//!
//! [data]
//! kind = "random"
//! ```
//!
//! A list written where the config expects a single value is a grid axis too, with or without
//! a `[sweep]` table:
//!
//! ```toml
//! [data]
//! kind = "random"
//! noise_sigma_m = [0.0001, 0.001, 0.01]   # three grid points
//! ```
//!
//! A field that legitimately takes a list (a mechanism's axis, `[sweep] seeds`) keeps it: a
//! list becomes an axis only where the config's schema rejects it, found by deserialising with
//! the path of the first rejected field (`serde_path_to_error`) and repeating until the config
//! parses.
//!
//! Every grid point and seed becomes an ordinary experiment config (so unknown keys are
//! still errors), the runs go in parallel (rayon), and `runs.csv` gets one row per run,
//! `table.md` one row per grid point: success rates and error statistics.

use crate::config::ExperimentConfig;
use crate::experiment::run_experiment;
use kinetree_core::{Error, Result};
use kinetree_eval::JointEval;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;

/// The `[sweep]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepSpec {
    /// A number of seeds (0..n) or a list.
    #[serde(default = "default_seeds")]
    pub seeds: Seeds,
    /// Dotted paths that receive the seed.
    #[serde(default = "default_seed_keys")]
    pub seed_keys: Vec<String>,
    /// Dotted path -> values; the runs are the Cartesian product (keys in sorted order).
    #[serde(default)]
    pub grid: toml::Table,
    /// Records each run's wall time (a `seconds` column in `runs.csv`, its median and sum per
    /// grid point in `table.md`). Times depend on the machine and its load (runs go in
    /// parallel), so such files differ between sittings; compare them within one.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub timing: bool,
    /// Runs the functional methods of biomechanics on each synthetic run's true segmentation
    /// (`kinetree_eval::functional_errors`: SCoRE centres, SARA axes) and writes their worst
    /// errors beside kinetree's in the parent's frame: the columns [`FUNCTIONAL_COLUMNS`] in
    /// `runs.csv` and their medians in `table.md`.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub functional: bool,
    /// Counts the true joints of each synthetic run and those recovered (found between the
    /// right bodies with their type, as `kinetree_eval::JointEval` judges them): the columns
    /// [`PER_JOINT_COLUMNS`] in `runs.csv` and, per grid point, the share of its true joints
    /// recovered in `table.md`, with the others counted by why they were missed
    /// (`kinetree_eval::JointMiss`: wrong type, child on its grandparent or a sibling, ...).
    /// A run that misses one joint of twenty fails `joints exact` as one that misses them
    /// all; these columns tell them apart.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub per_joint: bool,
}

/// Seeds of a sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Seeds {
    /// `0..n`.
    Count(u64),
    /// These seeds.
    List(Vec<u64>),
}

/// The most seeds a grid point may ask for (`[sweep] seeds = n`): a million runs of the
/// smallest mechanism take days on a workstation, and the run list is held in memory.
const MAX_SEEDS: u64 = 1_000_000;

/// Default of the most runs (grid points x seeds) a sweep may have without the caller raising
/// the limit (`kinetree run --max-runs`): the largest committed sweep has 600 runs of about a
/// tenth of a second each, and 10 000 such runs take half an hour on two cores.
pub const DEFAULT_MAX_RUNS: u64 = 10_000;

fn default_seeds() -> Seeds {
    Seeds::Count(1)
}

fn default_seed_keys() -> Vec<String> {
    vec!["data.seed".into()]
}

/// One run of a sweep: its grid values, seed, and what was measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepRun {
    /// Index of the grid point.
    pub point: usize,
    /// The grid values, as TOML text, in key order.
    pub values: Vec<String>,
    /// Seed.
    pub seed: u64,
    /// The run's error, if it failed.
    pub error: Option<String>,
    /// Adjusted Rand index (synthetic data only).
    pub ari: Option<f64>,
    /// Adjusted Rand index over the points with an identifiable owner
    /// (`kinetree_eval::identifiable_ari`: a point whose track fits another body's true motion
    /// within noise, such as one near a joint axis, is left out).
    pub identifiable_ari: Option<f64>,
    /// Every joint found with its type.
    pub joints_exact: Option<bool>,
    /// ... and every point on its body.
    pub structure_exact: Option<bool>,
    /// Largest axis error over the joints, degrees.
    pub max_axis_error_deg: Option<f64>,
    /// Largest joint-position RMS over revolute joints, radians.
    pub max_revolute_rms_rad: Option<f64>,
    /// Largest joint-position RMS over prismatic joints, metres.
    pub max_prismatic_rms_m: Option<f64>,
    /// Largest RMS of the smoothed positions (`Joint::smoothed_positions`) over revolute
    /// joints, radians.
    pub max_revolute_smoothed_rms_rad: Option<f64>,
    /// ... over prismatic joints, metres.
    pub max_prismatic_smoothed_rms_m: Option<f64>,
    /// Largest distance from a true spherical joint's centre to the model's, in the parent's
    /// body frame aligned on its true keypoints (`JointEval::centre_error_in_parent_m`),
    /// metres.
    pub max_centre_error_m: Option<f64>,
    /// Largest axis error over the joints in units of the model's stated axis precision
    /// (`JointEval::axis_z`, the error in the parent's frame over `Joint::axis_std_deg`).
    pub max_axis_error_in_stds: Option<f64>,
    /// Largest axis error over the revolute joints in the parent's body frame aligned on its
    /// true keypoints (`JointEval::axis_error_in_parent_deg`), degrees (with `[sweep]
    /// functional = true`).
    pub max_axis_error_in_parent_deg: Option<f64>,
    /// Largest SCoRE centre error over the true spherical joints, in the same frame, metres
    /// (with `[sweep] functional = true`).
    pub functional_max_centre_error_m: Option<f64>,
    /// Largest SARA axis error over the true revolute joints, in the same frame, degrees (with
    /// `[sweep] functional = true`).
    pub functional_max_axis_error_deg: Option<f64>,
    /// True joints (synthetic data, with `[sweep] per_joint = true`).
    pub joints_true: Option<usize>,
    /// ... of which a model joint links the same two bodies with the same type.
    pub joints_right: Option<usize>,
    /// ... and the others by why they were missed, in the order of
    /// [`kinetree_eval::JointMiss::ALL`].
    pub joints_missed: Option<[usize; JOINT_MISSES]>,
    /// Bodies found.
    pub bodies: Option<usize>,
    /// Wall time of the run, seconds (with `[sweep] timing = true`).
    pub seconds: Option<f64>,
}

/// A parsed sweep: the base config (without `[sweep]`), the spec and the expanded grid.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// The config text's table without `[sweep]`.
    pub base: toml::Table,
    /// The `[sweep]` table.
    pub spec: SweepSpec,
    /// Grid keys, sorted.
    pub keys: Vec<String>,
    /// Grid points: one value per key.
    pub points: Vec<Vec<toml::Value>>,
}

/// Whether a config text is a sweep: it has a `[sweep]` table, or it is not a valid
/// experiment config as written and holds a list (which [`Sweep::from_toml`] then expands, or
/// names in its error).
pub fn is_sweep(text: &str) -> bool {
    let Ok(table) = text.parse::<toml::Table>() else {
        return false;
    };
    if table.contains_key("sweep") {
        return true;
    }
    let mut leaves = Vec::new();
    for (k, v) in &table {
        array_leaves(k, v, &mut leaves);
    }
    !leaves.is_empty() && parse_config(&table).is_err()
}

fn get_path<'a>(table: &'a toml::Table, path: &str) -> Option<&'a toml::Value> {
    let mut parts = path.split('.');
    let mut v = table.get(parts.next()?)?;
    for p in parts {
        v = v.as_table()?.get(p)?;
    }
    Some(v)
}

/// A grid axis: a dotted path and its values.
type Axis = (String, Vec<toml::Value>);

/// Parses `table` as an experiment config, naming the path of the first field it rejects.
fn parse_config(table: &toml::Table) -> std::result::Result<ExperimentConfig, (String, String)> {
    serde_path_to_error::deserialize(toml::Value::Table(table.clone())).map_err(
        |e: serde_path_to_error::Error<toml::de::Error>| {
            (e.path().to_string(), e.inner().to_string())
        },
    )
}

/// The lists in `table` that stand where the config expects one value: returns the table with
/// each such list replaced by its first element, and the lists by dotted path. A rejected field
/// that is not a non-empty list is an error naming the field.
///
/// `preset` values (the first value of every `[sweep.grid]` key and the seed) are set while
/// checking, as a grid point would have them, but are not written into the returned table.
fn inline_axes(
    table: &toml::Table,
    preset: &[(String, toml::Value)],
) -> Result<(toml::Table, Vec<Axis>)> {
    let mut out = table.clone();
    let mut trial = table.clone();
    for (k, v) in preset {
        set_path(&mut trial, k, v.clone())?;
    }
    let mut axes: Vec<Axis> = Vec::new();
    loop {
        let (path, message) = match parse_config(&trial) {
            Ok(_) => return Ok((out, axes)),
            Err(e) => e,
        };
        let fail = |extra: String| {
            let at = if path == "." || path.is_empty() {
                String::new()
            } else {
                format!("{path}: ")
            };
            // Name a grid value that the error falls under.
            let value = axes
                .iter()
                .find(|(k, _)| is_under(k, &path))
                .map(|(k, v)| format!(" (grid value {k} = {})", v[0]))
                .unwrap_or_default();
            let message = message.trim_end().replace('\n', " ");
            Error::Config(format!("{at}{message}{value}{extra}"))
        };
        // The rejected list: the field itself, or (inside an internally tagged enum, where the
        // path stops at the enum) the first list under it whose first element clears this
        // error. Anything else is the config's own error.
        // An index into a list (`pipeline.dof[0]`) points at the list.
        let field = path.split('[').next().unwrap_or(&path);
        let mut leaves = Vec::new();
        if let Some(v) = get_path(&trial, field) {
            array_leaves(field, v, &mut leaves);
        }
        let fixed = leaves.iter().find_map(|(leaf, values)| {
            let first = values.first()?;
            if axes.iter().any(|(k, _)| k == leaf) || preset.iter().any(|(k, _)| k == leaf) {
                return None;
            }
            let mut t = trial.clone();
            set_path(&mut t, leaf, first.clone()).ok()?;
            let cleared = match parse_config(&t) {
                Ok(_) => true,
                Err((p2, m2)) => p2 != path || m2 != message,
            };
            cleared.then(|| (leaf.clone(), values.clone(), t))
        });
        match fixed {
            Some((leaf, values, t)) => {
                trial = t;
                set_path(&mut out, &leaf, values[0].clone())?;
                axes.push((leaf, values));
            }
            None => {
                let empty: Vec<&str> = leaves
                    .iter()
                    .filter(|(_, v)| v.is_empty())
                    .map(|(k, _)| k.as_str())
                    .collect();
                let extra = if empty.is_empty() {
                    String::new()
                } else {
                    format!(" (an empty list at {})", empty.join(", "))
                };
                return Err(fail(extra));
            }
        }
    }
}

/// Whether dotted path `path` is `prefix` or lies under it.
fn is_under(path: &str, prefix: &str) -> bool {
    path == prefix
        || prefix == "."
        || path
            .strip_prefix(prefix)
            .is_some_and(|rest| rest.starts_with('.'))
}

/// Every list at or under `v` (found at dotted `path`), in key order.
fn array_leaves(path: &str, v: &toml::Value, out: &mut Vec<Axis>) {
    match v {
        toml::Value::Array(a) => out.push((path.to_string(), a.clone())),
        toml::Value::Table(t) => {
            for (k, v) in t {
                array_leaves(&format!("{path}.{k}"), v, out);
            }
        }
        _ => {}
    }
}

fn set_path(table: &mut toml::Table, path: &str, value: toml::Value) -> Result<()> {
    let parts: Vec<&str> = path.split('.').collect();
    let (last, head) = parts
        .split_last()
        .ok_or_else(|| Error::Config(format!("empty sweep key {path:?}")))?;
    let mut t = table;
    for p in head {
        let entry = t
            .entry((*p).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        t = entry
            .as_table_mut()
            .ok_or_else(|| Error::Config(format!("sweep key {path:?}: {p:?} is not a table")))?;
    }
    t.insert((*last).to_string(), value);
    Ok(())
}

impl Sweep {
    /// Parses a config with a `[sweep]` table.
    ///
    /// # Errors
    /// [`Error::Config`] for bad TOML, a bad `[sweep]` table, a grid value that is not a
    /// non-empty list, or a grid point that is not a valid experiment config (unknown keys
    /// included).
    pub fn from_toml(text: &str) -> Result<Self> {
        Self::from_toml_within(text, DEFAULT_MAX_RUNS)
    }

    /// [`Sweep::from_toml`] refusing, before the grid is expanded, a sweep of more than
    /// `max_runs` runs.
    ///
    /// # Errors
    /// As [`Sweep::from_toml`]; [`Error::TooLarge`] with the run count and the limit.
    pub fn from_toml_within(text: &str, max_runs: u64) -> Result<Self> {
        let mut base: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| Error::Config(e.to_string()))?;
        let has_sweep_table = base.contains_key("sweep");
        let mut spec: SweepSpec = match base.remove("sweep") {
            Some(v) => v
                .try_into()
                .map_err(|e: toml::de::Error| Error::Config(format!("[sweep]: {e}")))?,
            // Only inline lists: each grid point runs once with the config's own seed.
            None => SweepSpec {
                seeds: Seeds::List(vec![
                    get_path(&base, "data.seed")
                        .and_then(toml::Value::as_integer)
                        .and_then(|s| u64::try_from(s).ok())
                        .unwrap_or(0),
                ]),
                seed_keys: Vec::new(),
                grid: toml::Table::new(),
                timing: false,
                functional: false,
                per_joint: false,
            },
        };
        if let Seeds::Count(n) = spec.seeds
            && n > MAX_SEEDS
        {
            return Err(Error::InvalidParameter {
                name: "sweep.seeds".into(),
                message: format!("at most {MAX_SEEDS} seeds a grid point, got {n}"),
            });
        }
        let mut preset: Vec<(String, toml::Value)> = spec
            .grid
            .iter()
            .filter_map(|(k, v)| Some((k.clone(), v.as_array()?.first()?.clone())))
            .collect();
        for k in &spec.seed_keys {
            preset.push((k.clone(), toml::Value::Integer(0)));
        }
        for (k, first) in &preset {
            if get_path(&base, k).is_some_and(toml::Value::is_array) && !first.is_array() {
                return Err(Error::Config(format!(
                    "{k:?} is a list in the config and a key of [sweep.grid]; it must be given once"
                )));
            }
        }
        let (stripped, axes) = inline_axes(&base, &preset)?;
        for (path, values) in axes {
            if spec.grid.contains_key(&path) {
                return Err(Error::Config(format!(
                    "{path:?} is a list in the config and a key of [sweep.grid]; it must be given once"
                )));
            }
            spec.grid.insert(path, toml::Value::Array(values));
        }
        base = stripped;
        if spec.grid.is_empty() && !has_sweep_table {
            return Err(Error::Config(
                "no [sweep] table and no list-valued field".into(),
            ));
        }
        let keys: Vec<String> = spec.grid.keys().cloned().collect();
        let n_seeds = match &spec.seeds {
            Seeds::Count(n) => u128::from(*n),
            Seeds::List(v) => v.len() as u128,
        };
        let n_points: u128 = keys
            .iter()
            .map(|k| spec.grid[k].as_array().map_or(1, |a| a.len() as u128))
            .product();
        let n_runs = n_points.saturating_mul(n_seeds);
        if n_runs > u128::from(max_runs) {
            return Err(Error::TooLarge {
                what: format!("a sweep of {n_points} grid points x {n_seeds} seeds"),
                estimate: format!("{n_runs} runs"),
                limit: format!("{max_runs} runs"),
                hint: "raise it with --max-runs <n> if the sweep is meant to be this large".into(),
            });
        }
        let mut points: Vec<Vec<toml::Value>> = vec![Vec::new()];
        for k in &keys {
            let values = spec.grid[k]
                .as_array()
                .filter(|a| !a.is_empty())
                .ok_or_else(|| {
                    Error::Config(format!("[sweep.grid] {k:?} must be a non-empty list"))
                })?;
            points = points
                .iter()
                .flat_map(|p| {
                    values.iter().map(move |v| {
                        let mut q = p.clone();
                        q.push(v.clone());
                        q
                    })
                })
                .collect();
        }
        let sweep = Self {
            base,
            spec,
            keys,
            points,
        };
        // Every grid point must be a valid config: fail before running anything.
        for p in 0..sweep.points.len() {
            sweep.config(p, 0)?;
        }
        Ok(sweep)
    }

    /// The experiment's name (`[experiment] name`), where its results go.
    ///
    /// # Errors
    /// As [`Sweep::config`] (never after [`Sweep::from_toml`] succeeded).
    pub fn name(&self) -> Result<String> {
        Ok(self.config(0, 0)?.experiment.name)
    }

    /// The seeds.
    pub fn seeds(&self) -> Vec<u64> {
        match &self.spec.seeds {
            Seeds::Count(n) => (0..*n).collect(),
            Seeds::List(v) => v.clone(),
        }
    }

    /// The experiment config of grid point `p` with `seed`.
    ///
    /// # Errors
    /// [`Error::Config`] when it is not a valid experiment config.
    pub fn config(&self, p: usize, seed: u64) -> Result<ExperimentConfig> {
        let mut t = self.base.clone();
        for (k, v) in self.keys.iter().zip(&self.points[p]) {
            set_path(&mut t, k, v.clone())?;
        }
        for k in &self.spec.seed_keys {
            set_path(
                &mut t,
                k,
                toml::Value::Integer(i64::try_from(seed).unwrap_or(i64::MAX)),
            )?;
        }
        toml::Value::Table(t)
            .try_into()
            .map_err(|e: toml::de::Error| Error::Config(format!("sweep point {p}: {e}")))
    }

    /// Runs every grid point with every seed in parallel; `progress` is called after each
    /// run with (done, total).
    pub fn run(&self, base_dir: &Path, progress: &(dyn Fn(usize, usize) + Sync)) -> Vec<SweepRun> {
        self.run_remaining(base_dir, &[], progress, &|_| {})
    }

    /// The number of runs: grid points times seeds.
    pub fn n_runs(&self) -> usize {
        self.points.len() * self.seeds().len()
    }

    /// The (grid point, seed) pairs of `shard` (all of them for `None`), grid point by grid
    /// point.
    pub fn jobs(&self, shard: Option<Shard>) -> Vec<(usize, u64)> {
        let seeds = self.seeds();
        (0..self.points.len())
            .filter(|&p| shard.is_none_or(|s| s.holds(p)))
            .flat_map(|p| seeds.iter().map(move |&s| (p, s)))
            .collect()
    }

    /// The sweep as a config text that [`Sweep::from_toml`] reads back into the same grid,
    /// seeds and runs: the base config with every grid axis (inline lists included) under
    /// `[sweep.grid]`.
    ///
    /// # Errors
    /// [`Error::Config`] when the tables cannot be written as TOML.
    pub fn to_toml(&self) -> Result<String> {
        let mut table = self.base.clone();
        table.insert(
            "sweep".into(),
            toml::Value::try_from(&self.spec).map_err(|e| Error::Config(e.to_string()))?,
        );
        toml::to_string(&table).map_err(|e| Error::Config(e.to_string()))
    }

    /// Runs the (grid point, seed) pairs not in `done` in parallel, calling `finished` with
    /// each run as it ends and `progress` with (runs done, all runs, `done` included).
    pub fn run_remaining(
        &self,
        base_dir: &Path,
        done: &[(usize, u64)],
        progress: &(dyn Fn(usize, usize) + Sync),
        finished: &(dyn Fn(&SweepRun) + Sync),
    ) -> Vec<SweepRun> {
        self.run_share(base_dir, None, done, progress, finished)
    }

    /// [`Sweep::run_remaining`] over the runs of `shard` only; `progress` counts those.
    pub fn run_share(
        &self,
        base_dir: &Path,
        shard: Option<Shard>,
        done: &[(usize, u64)],
        progress: &(dyn Fn(usize, usize) + Sync),
        finished: &(dyn Fn(&SweepRun) + Sync),
    ) -> Vec<SweepRun> {
        let skip: std::collections::BTreeSet<(usize, u64)> = done.iter().copied().collect();
        let all = self.jobs(shard);
        let total = all.len();
        let jobs: Vec<(usize, u64)> = all.into_iter().filter(|job| !skip.contains(job)).collect();
        let count = std::sync::atomic::AtomicUsize::new(total - jobs.len());
        jobs.par_iter()
            .map(|&(p, seed)| {
                let run = self.run_one(p, seed, base_dir);
                finished(&run);
                let n = count.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(n, total);
                run
            })
            .collect()
    }

    fn run_one(&self, p: usize, seed: u64, base_dir: &Path) -> SweepRun {
        let mut run = SweepRun {
            point: p,
            values: self.points[p].iter().map(|v| v.to_string()).collect(),
            seed,
            error: None,
            ari: None,
            identifiable_ari: None,
            joints_exact: None,
            structure_exact: None,
            max_axis_error_deg: None,
            max_axis_error_in_stds: None,
            max_revolute_rms_rad: None,
            max_prismatic_rms_m: None,
            max_revolute_smoothed_rms_rad: None,
            max_prismatic_smoothed_rms_m: None,
            max_centre_error_m: None,
            max_axis_error_in_parent_deg: None,
            functional_max_centre_error_m: None,
            functional_max_axis_error_deg: None,
            joints_true: None,
            joints_right: None,
            joints_missed: None,
            bodies: None,
            seconds: None,
        };
        let started = std::time::Instant::now();
        let outcome = self.config(p, seed).and_then(|c| {
            let sigma = crate::experiment::scenario(&c.data)?.map(|s| s.noise_sigma_m);
            let o = run_experiment(&c, base_dir)?;
            let functional = match (&o.truth, self.spec.functional) {
                (Some(truth), true) => {
                    let pose = c.pipeline.pose.build()?;
                    let sigma = sigma.unwrap_or(o.discovery.model.noise.sigma_m);
                    Some(kinetree_eval::functional_errors(
                        &o.tracks,
                        truth,
                        pose.as_ref(),
                        sigma,
                    )?)
                }
                _ => None,
            };
            Ok((o, sigma, functional))
        });
        if self.spec.timing {
            run.seconds = Some(started.elapsed().as_secs_f64());
        }
        match outcome {
            Err(e) => run.error = Some(e.to_string()),
            Ok((o, sigma, functional)) => {
                run.bodies = Some(o.discovery.model.bodies.len());
                if let (Some(e), Some(truth)) = (&o.evaluation, &o.truth) {
                    run.ari = Some(e.ari);
                    run.identifiable_ari = sigma.map(|sigma| {
                        let amb = kinetree_eval::ambiguous_points(&o.tracks, truth, sigma);
                        kinetree_eval::identifiable_ari(&o.discovery.model, truth, &amb)
                    });
                    run.joints_exact = Some(e.joints_exact);
                    run.structure_exact = Some(e.structure_exact);
                    if self.spec.per_joint {
                        run.joints_true = Some(e.joints.len());
                        run.joints_right =
                            Some(e.joints.iter().filter(|j| j.found && j.type_ok).count());
                        run.joints_missed = Some(kinetree_eval::JointMiss::tally(
                            e.joints.iter().filter_map(|j| j.miss),
                        ));
                    }
                    let max = |v: Vec<f64>| v.into_iter().reduce(f64::max);
                    run.max_axis_error_deg =
                        max(e.joints.iter().filter_map(|j| j.axis_error_deg).collect());
                    run.max_axis_error_in_stds =
                        max(e.joints.iter().filter_map(|j| j.axis_z).collect());
                    let revolute = |k: usize| {
                        truth.mechanism.joints[k].joint_type == kinetree_synth::JointType::Revolute
                    };
                    let worst = |of_revolute: bool, rms: fn(&JointEval) -> Option<f64>| {
                        max(e
                            .joints
                            .iter()
                            .filter(|j| revolute(j.joint) == of_revolute)
                            .filter_map(rms)
                            .collect())
                    };
                    run.max_revolute_rms_rad = worst(true, |j| j.position_rms);
                    run.max_prismatic_rms_m = worst(false, |j| j.position_rms);
                    run.max_revolute_smoothed_rms_rad = worst(true, |j| j.smoothed_rms);
                    run.max_prismatic_smoothed_rms_m = worst(false, |j| j.smoothed_rms);
                    run.max_centre_error_m = max(e
                        .joints
                        .iter()
                        .filter_map(|j| j.centre_error_in_parent_m)
                        .collect());
                    if let Some(f) = functional {
                        run.max_axis_error_in_parent_deg =
                            worst(true, |j| j.axis_error_in_parent_deg);
                        run.functional_max_centre_error_m = max(f
                            .iter()
                            .filter_map(|j| j.centre_error_in_parent_m)
                            .collect());
                        run.functional_max_axis_error_deg = max(f
                            .iter()
                            .filter_map(|j| j.axis_error_in_parent_deg)
                            .collect());
                    }
                }
            }
        }
        run
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x}"))
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The columns of `runs.csv` after the grid keys.
const RUN_COLUMNS: [&str; 14] = [
    "seed",
    "error",
    "bodies",
    "ari",
    "identifiable_ari",
    "joints_exact",
    "structure_exact",
    "max_axis_error_deg",
    "max_revolute_rms_rad",
    "max_prismatic_rms_m",
    "max_revolute_smoothed_rms_rad",
    "max_prismatic_smoothed_rms_m",
    "max_centre_error_m",
    "max_axis_error_in_stds",
];

/// The columns of `runs.csv` after the standard ones with `[sweep] functional = true`.
pub const FUNCTIONAL_COLUMNS: [&str; 3] = [
    "max_axis_error_in_parent_deg",
    "functional_max_centre_error_m",
    "functional_max_axis_error_deg",
];

/// The classes of [`kinetree_eval::JointMiss`].
pub const JOINT_MISSES: usize = kinetree_eval::JointMiss::COUNT;

/// The columns of `runs.csv` after the standard and functional ones with `[sweep] per_joint =
/// true`: the true joints, those right, and the others by why they were missed
/// (`missed_` and [`kinetree_eval::JointMiss::as_str`], in the order of
/// [`kinetree_eval::JointMiss::ALL`]).
pub const PER_JOINT_COLUMNS: [&str; 2 + JOINT_MISSES] = [
    "joints_true",
    "joints_right",
    "missed_wrong_type",
    "missed_child_missing",
    "missed_parent_missing",
    "missed_reversed",
    "missed_child_split",
    "missed_child_is_root",
    "missed_on_grandparent",
    "missed_on_sibling",
    "missed_on_descendant",
    "missed_on_other",
    "missed_root_not_free",
];

/// The header line of `runs.csv`.
fn csv_header(sweep: &Sweep) -> String {
    let mut s = String::new();
    for k in &sweep.keys {
        s.push_str(&csv_field(k));
        s.push(',');
    }
    s.push_str(&RUN_COLUMNS.join(","));
    if sweep.spec.functional {
        s.push(',');
        s.push_str(&FUNCTIONAL_COLUMNS.join(","));
    }
    if sweep.spec.per_joint {
        s.push(',');
        s.push_str(&PER_JOINT_COLUMNS.join(","));
    }
    s.push_str(if sweep.spec.timing {
        ",seconds\n"
    } else {
        "\n"
    });
    s
}

/// One run's line of `runs.csv`.
fn csv_row(sweep: &Sweep, r: &SweepRun) -> String {
    let mut s = String::new();
    for v in &r.values {
        s.push_str(&csv_field(v));
        s.push(',');
    }
    let _ = write!(
        s,
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        r.seed,
        csv_field(r.error.as_deref().unwrap_or("")),
        r.bodies.map_or(String::new(), |b| b.to_string()),
        opt(r.ari),
        opt(r.identifiable_ari),
        r.joints_exact.map_or(String::new(), |b| b.to_string()),
        r.structure_exact.map_or(String::new(), |b| b.to_string()),
        opt(r.max_axis_error_deg),
        opt(r.max_revolute_rms_rad),
        opt(r.max_prismatic_rms_m),
        opt(r.max_revolute_smoothed_rms_rad),
        opt(r.max_prismatic_smoothed_rms_m),
        opt(r.max_centre_error_m),
        opt(r.max_axis_error_in_stds),
    );
    if sweep.spec.functional {
        let _ = write!(
            s,
            ",{},{},{}",
            opt(r.max_axis_error_in_parent_deg),
            opt(r.functional_max_centre_error_m),
            opt(r.functional_max_axis_error_deg)
        );
    }
    if sweep.spec.per_joint {
        let count = |c: Option<usize>| c.map_or(String::new(), |c| c.to_string());
        let _ = write!(s, ",{},{}", count(r.joints_true), count(r.joints_right));
        for k in 0..JOINT_MISSES {
            let _ = write!(s, ",{}", count(r.joints_missed.map(|m| m[k])));
        }
    }
    if sweep.spec.timing {
        let _ = write!(s, ",{:.3}", r.seconds.unwrap_or(f64::NAN));
    }
    s.push('\n');
    s
}

/// `runs.csv`: one row per run, sorted by grid point and seed.
pub fn runs_csv(sweep: &Sweep, runs: &[SweepRun]) -> String {
    let mut runs: Vec<&SweepRun> = runs.iter().collect();
    runs.sort_by_key(|r| (r.point, r.seed));
    let mut s = csv_header(sweep);
    for r in runs {
        s.push_str(&csv_row(sweep, r));
    }
    s
}

/// The runs of `sweep` already in a `runs.csv` (complete, or cut short while its rows were
/// appended), for `--resume`. A row of another grid point or seed, or a file with other
/// columns, is an error: the file belongs to another sweep.
///
/// # Errors
/// [`Error::Malformed`] naming the line.
pub fn parse_runs_csv(sweep: &Sweep, text: &str) -> Result<Vec<SweepRun>> {
    let bad = |line: usize, message: String| Error::Malformed {
        position: format!("line {line}"),
        message,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(text.as_bytes());
    let mut records = reader.records();
    let header: Vec<String> = match records.next() {
        Some(Ok(h)) => h.iter().map(str::to_string).collect(),
        Some(Err(e)) => return Err(bad(1, e.to_string())),
        None => return Ok(Vec::new()),
    };
    if header.join(",") + "\n" != csv_header(sweep) {
        return Err(bad(
            1,
            format!(
                "the columns {header:?} are not this sweep's; resume in the folder the sweep wrote"
            ),
        ));
    }
    let nk = sweep.keys.len();
    // Each grid point by its values as `runs.csv` writes them, and the seeds, looked up per row.
    let mut point_of: std::collections::BTreeMap<Vec<String>, usize> = Default::default();
    for (k, p) in sweep.points.iter().enumerate().rev() {
        // Walked from the end, so a repeated grid point maps to its first index.
        point_of.insert(p.iter().map(ToString::to_string).collect(), k);
    }
    let seeds: std::collections::BTreeSet<u64> = sweep.seeds().into_iter().collect();
    // The functional methods' columns, when the sweep has them, follow the standard ones.
    let functional = sweep.spec.functional.then_some(RUN_COLUMNS.len());
    // Then the per-joint counts, when the sweep has them.
    let per_joint = sweep
        .spec
        .per_joint
        .then(|| functional.map_or(RUN_COLUMNS.len(), |i| i + FUNCTIONAL_COLUMNS.len()));
    let mut runs = Vec::new();
    for (k, record) in records.enumerate() {
        let line = k + 2;
        let record = match record {
            Ok(r) => r,
            // A line cut by an interrupted append is dropped; the run is done again.
            Err(_) => continue,
        };
        if record.len() != header.len() {
            continue;
        }
        let f: Vec<&str> = record.iter().collect();
        let values: Vec<String> = f[..nk].iter().map(|v| (*v).to_string()).collect();
        let point = *point_of
            .get(&values)
            .ok_or_else(|| bad(line, format!("grid values {values:?} are not this sweep's")))?;
        let rest = &f[nk..];
        let num = |i: usize| -> Result<Option<f64>> {
            let v = rest[i];
            if v.is_empty() {
                return Ok(None);
            }
            v.parse()
                .map(Some)
                .map_err(|_| bad(line, format!("{} `{v}` is not a number", header[nk + i])))
        };
        let count = |i: usize| -> Result<Option<usize>> {
            let v = rest[i];
            if v.is_empty() {
                return Ok(None);
            }
            v.parse()
                .map(Some)
                .map_err(|_| bad(line, format!("{} `{v}` is not a count", header[nk + i])))
        };
        let flag = |i: usize| -> Result<Option<bool>> {
            match rest[i] {
                "" => Ok(None),
                "true" => Ok(Some(true)),
                "false" => Ok(Some(false)),
                v => Err(bad(
                    line,
                    format!("{} `{v}` is not true or false", header[nk + i]),
                )),
            }
        };
        let seed: u64 = rest[0]
            .parse()
            .map_err(|_| bad(line, format!("seed `{}` is not a seed", rest[0])))?;
        if !seeds.contains(&seed) {
            return Err(bad(line, format!("seed {seed} is not one of this sweep's")));
        }
        runs.push(SweepRun {
            point,
            values,
            seed,
            error: (!rest[1].is_empty()).then(|| rest[1].to_string()),
            bodies: num(2)?.map(|b| b as usize),
            ari: num(3)?,
            identifiable_ari: num(4)?,
            joints_exact: flag(5)?,
            structure_exact: flag(6)?,
            max_axis_error_deg: num(7)?,
            max_revolute_rms_rad: num(8)?,
            max_prismatic_rms_m: num(9)?,
            max_revolute_smoothed_rms_rad: num(10)?,
            max_prismatic_smoothed_rms_m: num(11)?,
            max_centre_error_m: num(12)?,
            max_axis_error_in_stds: num(13)?,
            max_axis_error_in_parent_deg: functional.map(num).transpose()?.flatten(),
            functional_max_centre_error_m: functional.map(|i| num(i + 1)).transpose()?.flatten(),
            functional_max_axis_error_deg: functional.map(|i| num(i + 2)).transpose()?.flatten(),
            joints_true: per_joint.map(count).transpose()?.flatten(),
            joints_right: per_joint.map(|i| count(i + 1)).transpose()?.flatten(),
            joints_missed: match per_joint {
                Some(i) => {
                    let mut missed = [0; JOINT_MISSES];
                    let mut all = true;
                    for (k, m) in missed.iter_mut().enumerate() {
                        match count(i + 2 + k)? {
                            Some(c) => *m = c,
                            None => all = false,
                        }
                    }
                    all.then_some(missed)
                }
                None => None,
            },
            seconds: if sweep.spec.timing {
                rest[RUN_COLUMNS.len()
                    + functional.map_or(0, |_| FUNCTIONAL_COLUMNS.len())
                    + per_joint.map_or(0, |_| PER_JOINT_COLUMNS.len())]
                .parse()
                .ok()
            } else {
                None
            },
        });
    }
    runs.sort_by_key(|r| (r.point, r.seed));
    runs.dedup_by_key(|r| (r.point, r.seed));
    Ok(runs)
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// `table.md`: one row per grid point.
pub fn table_markdown(name: &str, sweep: &Sweep, runs: &[SweepRun]) -> String {
    let mut s = format!(
        "# {name}: sweep\n\n{} grid point(s) x {} seed(s). Rates over the runs of each point; medians over its runs that produced the value; errors count failed runs. Structure exact: every joint right and every point on its body (ARI 1); identifiable ARI 1: every point with an identifiable owner on its body (a point near a joint axis, say, fits two bodies within noise and is left out).\n\n",
        sweep.points.len(),
        sweep.seeds().len()
    );
    let head: Vec<String> = sweep.keys.iter().map(|k| format!("`{k}`")).collect();
    let _ = writeln!(
        s,
        "| {}{}runs | errors | joints exact | structure exact | identifiable ARI 1 | mean ARI | median max axis error (deg) | median max revolute RMS (rad) | median max prismatic RMS (mm) | smoothed: revolute (rad) | smoothed: prismatic (mm) | median max centre error (mm) | median max axis error (stds) |{}{}{}",
        head.join(" | "),
        if head.is_empty() { "" } else { " | " },
        if sweep.spec.functional {
            " median max axis error in parent (deg) | SCoRE: median max centre error (mm) | SARA: median max axis error (deg) |"
        } else {
            ""
        },
        if sweep.spec.per_joint {
            " joints right | joints missed, by why |"
        } else {
            ""
        },
        if sweep.spec.timing {
            " median s | total s |"
        } else {
            ""
        }
    );
    let timing_cols = if sweep.spec.timing { 2 } else { 0 };
    let functional_cols = if sweep.spec.functional {
        FUNCTIONAL_COLUMNS.len()
    } else {
        0
    };
    let per_joint_cols = 2 * usize::from(sweep.spec.per_joint);
    let _ = writeln!(
        s,
        "|{}",
        "---|".repeat(sweep.keys.len() + 13 + functional_cols + per_joint_cols + timing_cols)
    );
    for p in 0..sweep.points.len() {
        let rs: Vec<&SweepRun> = runs.iter().filter(|r| r.point == p).collect();
        let n = rs.len();
        let rate = |f: &dyn Fn(&SweepRun) -> Option<bool>| {
            let v: Vec<bool> = rs.iter().filter_map(|r| f(r)).collect();
            if v.is_empty() {
                "-".to_string()
            } else {
                format!("{}/{}", v.iter().filter(|&&b| b).count(), n)
            }
        };
        let fmt =
            |v: Option<f64>, scale: f64| v.map_or("-".into(), |x| format!("{:.3}", x * scale));
        let aris: Vec<f64> = rs.iter().filter_map(|r| r.ari).collect();
        let mean_ari = (!aris.is_empty()).then(|| aris.iter().sum::<f64>() / aris.len() as f64);
        let values: Vec<String> = sweep.points[p].iter().map(|v| format!("`{v}`")).collect();
        let _ = write!(
            s,
            "| {}{}{n} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            values.join(" | "),
            if values.is_empty() { "" } else { " | " },
            rs.iter().filter(|r| r.error.is_some()).count(),
            rate(&|r| r.joints_exact),
            rate(&|r| r.structure_exact),
            rate(&|r| r.identifiable_ari.map(|a| a > 1.0 - 1e-12)),
            fmt(mean_ari, 1.0),
            fmt(
                median(rs.iter().filter_map(|r| r.max_axis_error_deg).collect()),
                1.0
            ),
            fmt(
                median(rs.iter().filter_map(|r| r.max_revolute_rms_rad).collect()),
                1.0
            ),
            fmt(
                median(rs.iter().filter_map(|r| r.max_prismatic_rms_m).collect()),
                1e3
            ),
            fmt(
                median(
                    rs.iter()
                        .filter_map(|r| r.max_revolute_smoothed_rms_rad)
                        .collect()
                ),
                1.0
            ),
            fmt(
                median(
                    rs.iter()
                        .filter_map(|r| r.max_prismatic_smoothed_rms_m)
                        .collect()
                ),
                1e3
            ),
            fmt(
                median(rs.iter().filter_map(|r| r.max_centre_error_m).collect()),
                1e3
            ),
            fmt(
                median(rs.iter().filter_map(|r| r.max_axis_error_in_stds).collect()),
                1.0
            ),
        );
        if sweep.spec.functional {
            let column = |f: fn(&SweepRun) -> Option<f64>, scale: f64| {
                fmt(median(rs.iter().filter_map(|r| f(r)).collect()), scale)
            };
            let _ = write!(
                s,
                " {} | {} | {} |",
                column(|r| r.max_axis_error_in_parent_deg, 1.0),
                column(|r| r.functional_max_centre_error_m, 1e3),
                column(|r| r.functional_max_axis_error_deg, 1.0)
            );
        }
        if sweep.spec.per_joint {
            // Over the runs that counted their joints (a failed run counts none).
            let (right, total) = rs
                .iter()
                .filter_map(|r| Some((r.joints_right?, r.joints_true?)))
                .fold((0, 0), |(a, b), (r, t)| (a + r, b + t));
            if total == 0 {
                s.push_str(" - |");
            } else {
                let _ = write!(
                    s,
                    " {right}/{total} ({:.0} %) |",
                    100.0 * right as f64 / total as f64
                );
            }
            let mut missed = [0; JOINT_MISSES];
            for m in rs.iter().filter_map(|r| r.joints_missed) {
                for (sum, c) in missed.iter_mut().zip(m) {
                    *sum += c;
                }
            }
            let classes = kinetree_eval::JointMiss::describe(&missed);
            let _ = write!(s, " {} |", if classes.is_empty() { "-" } else { &classes });
        }
        if sweep.spec.timing {
            let times: Vec<f64> = rs.iter().filter_map(|r| r.seconds).collect();
            let total: f64 = times.iter().sum();
            let _ = write!(s, " {} | {total:.1} |", fmt(median(times), 1.0));
        }
        s.push('\n');
    }
    s
}

/// How [`run_sweep`] runs a sweep.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SweepOptions {
    /// Keep the runs already in `runs.csv` and run only the others.
    pub resume: bool,
    /// Run one shard of the grid points only, into its own folder (see [`Shard`]).
    pub shard: Option<Shard>,
}

/// One of `count` parts of a sweep, for a cluster's job array: shard `index` runs the grid
/// points `index`, `index + count`, `index + 2 count`, ... with every seed. Written `I/N` on
/// the command line (`--shard 3/16`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// This shard, `0..count`.
    pub index: usize,
    /// How many shards the sweep is split into.
    pub count: usize,
}

/// The most shards a sweep may be split into (as many as the largest job arrays clusters
/// accept by default).
pub const MAX_SHARDS: usize = 100_000;

impl Shard {
    /// Whether grid point `p` belongs to this shard.
    pub fn holds(&self, p: usize) -> bool {
        p % self.count == self.index
    }

    /// The shard's folder inside the sweep's result folder: `shard-<I>-of-<N>`.
    pub fn folder(&self) -> String {
        format!("shard-{}-of-{}", self.index, self.count)
    }

    /// Reads a folder name written by [`Shard::folder`]; `None` for any other name.
    pub fn from_folder(name: &str) -> Option<Self> {
        let (i, n) = name.strip_prefix("shard-")?.split_once("-of-")?;
        let shard = Self {
            index: i.parse().ok()?,
            count: n.parse().ok()?,
        };
        (shard.to_string() == format!("{i}/{n}") && shard.check().is_ok()).then_some(shard)
    }

    fn check(&self) -> Result<()> {
        if self.count == 0 || self.count > MAX_SHARDS || self.index >= self.count {
            return Err(Error::InvalidParameter {
                name: "shard".into(),
                message: format!(
                    "{self} is not a shard: I/N needs 1 <= N <= {MAX_SHARDS} and 0 <= I < N"
                ),
            });
        }
        Ok(())
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = Error;

    fn from_str(text: &str) -> Result<Self> {
        let bad = || Error::InvalidParameter {
            name: "shard".into(),
            message: format!("`{text}` is not I/N (shard I of N, counted from 0, e.g. 3/16)"),
        };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let shard = Self {
            index: i.trim().parse().map_err(|_| bad())?,
            count: n.trim().parse().map_err(|_| bad())?,
        };
        shard.check()?;
        Ok(shard)
    }
}

/// The file in a shard's folder that holds the sweep it belongs to ([`Sweep::to_toml`]).
pub const SHARD_SWEEP_FILE: &str = "sweep.toml";

/// Runs a parsed sweep and writes `resolved.toml` (the first run's config with every default
/// filled in, and the `[sweep]` table), `runs.csv` and `table.md` under `dir`. Returns the
/// runs.
///
/// Each run's row is appended to `runs.csv` as it ends, so an interrupted sweep leaves the
/// runs it finished; with `options.resume`, the runs already in `runs.csv` are kept and not
/// run again ([`parse_runs_csv`]). At the end `runs.csv` is rewritten sorted.
///
/// With `options.shard`, only that shard's runs are made, and they go to
/// `dir/shard-<I>-of-<N>/`: its `runs.csv` and [`SHARD_SWEEP_FILE`], from which
/// [`merge_shards`] builds the sweep's files once every shard has run.
///
/// # Errors
/// [`Error::Config`] when the resolved config cannot be written, I/O errors naming the file,
/// and [`parse_runs_csv`]'s errors when resuming (a row of another shard among them).
pub fn run_sweep(
    sweep: &Sweep,
    base_dir: &Path,
    dir: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
    options: SweepOptions,
) -> Result<Vec<SweepRun>> {
    use std::io::Write as _;
    let name = sweep.name()?;
    let out_dir = match options.shard {
        Some(s) => dir.join(s.folder()),
        None => dir.to_path_buf(),
    };
    std::fs::create_dir_all(&out_dir).map_err(|e| Error::Io(e).in_file(&out_dir))?;
    let csv_path = out_dir.join("runs.csv");
    let mut runs = if options.resume && csv_path.exists() {
        let text =
            std::fs::read_to_string(&csv_path).map_err(|e| Error::Io(e).in_file(&csv_path))?;
        let runs = parse_runs_csv(sweep, &text).map_err(|e| e.in_file(&csv_path))?;
        if let Some(shard) = options.shard {
            check_share(&runs, shard).map_err(|e| e.in_file(&csv_path))?;
        }
        runs
    } else {
        Vec::new()
    };
    if options.shard.is_some() {
        kinetree_io::write_text(&out_dir.join(SHARD_SWEEP_FILE), &sweep.to_toml()?)?;
    }
    // The journal starts as the runs kept, then takes each run's row as it ends.
    kinetree_io::write_text(&csv_path, &runs_csv(sweep, &runs))?;
    let journal = std::sync::Mutex::new(
        std::fs::OpenOptions::new()
            .append(true)
            .open(&csv_path)
            .map_err(|e| Error::Io(e).in_file(&csv_path))?,
    );
    let journal_error = std::sync::Mutex::new(None::<std::io::Error>);
    let done: Vec<(usize, u64)> = runs.iter().map(|r| (r.point, r.seed)).collect();
    let append = |run: &SweepRun| {
        let row = csv_row(sweep, run);
        if let Ok(mut f) = journal.lock()
            && let Err(e) = f.write_all(row.as_bytes()).and_then(|()| f.flush())
            && let Ok(mut slot) = journal_error.lock()
        {
            slot.get_or_insert(e);
        }
    };
    runs.extend(sweep.run_share(base_dir, options.shard, &done, progress, &append));
    if let Some(e) = journal_error.into_inner().ok().flatten() {
        return Err(Error::Io(e).in_file(&csv_path));
    }
    runs.sort_by_key(|r| (r.point, r.seed));
    if options.shard.is_some() {
        kinetree_io::write_text(&csv_path, &runs_csv(sweep, &runs))?;
    } else {
        write_outputs(&name, sweep, &runs, dir)?;
    }
    Ok(runs)
}

/// Refuses runs that are not all of `shard`'s grid points.
fn check_share(runs: &[SweepRun], shard: Shard) -> Result<()> {
    match runs.iter().find(|r| !shard.holds(r.point)) {
        Some(r) => Err(Error::Config(format!(
            "grid point {} (seed {}) belongs to another shard than {shard}",
            r.point, r.seed
        ))),
        None => Ok(()),
    }
}

/// Writes a whole sweep's `resolved.toml`, `runs.csv` and `table.md` under `dir`.
fn write_outputs(name: &str, sweep: &Sweep, runs: &[SweepRun], dir: &Path) -> Result<()> {
    let write = |file: &str, body: &str| kinetree_io::write_text(&dir.join(file), body);
    let first = sweep.config(0, sweep.seeds().first().copied().unwrap_or(0))?;
    let mut resolved: toml::Table = first
        .resolved_toml()?
        .parse()
        .map_err(|e: toml::de::Error| Error::Config(e.to_string()))?;
    resolved.insert(
        "sweep".into(),
        toml::Value::try_from(&sweep.spec).map_err(|e| Error::Config(e.to_string()))?,
    );
    write(
        "resolved.toml",
        &toml::to_string(&resolved).map_err(|e| Error::Config(e.to_string()))?,
    )?;
    write("runs.csv", &runs_csv(sweep, runs))?;
    write("table.md", &table_markdown(name, sweep, runs))?;
    Ok(())
}

/// Builds a sharded sweep's `resolved.toml`, `runs.csv` and `table.md` in `dir` (the sweep's
/// result folder) from its `shard-<I>-of-<N>/` folders, byte for byte as the unsharded sweep
/// writes them (but for the `seconds` column of a timed sweep). Returns the sweep's name, the
/// sweep and its runs.
///
/// # Errors
/// [`Error::Config`] when there are no shard folders, when they split the sweep in different
/// numbers of parts, when a shard is missing or has not finished its runs (the message says
/// which and how many runs are missing), when shards hold different sweeps, or when a shard
/// holds another shard's rows; the errors of reading a shard's files, naming the file.
pub fn merge_shards(dir: &Path) -> Result<(String, Sweep, Vec<SweepRun>)> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::Io(e).in_file(dir))?;
    let mut shards: Vec<Shard> = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::Io(e).in_file(dir))?;
        if let Some(shard) = entry.file_name().to_str().and_then(Shard::from_folder)
            && entry.path().is_dir()
        {
            shards.push(shard);
        }
    }
    shards.sort_by_key(|s| (s.count, s.index));
    let Some(first) = shards.first().copied() else {
        return Err(Error::Config(format!(
            "{} has no shard folders (shard-<I>-of-<N>, written by `kinetree run --shard I/N`)",
            dir.display()
        )));
    };
    if let Some(other) = shards.iter().find(|s| s.count != first.count) {
        return Err(Error::Config(format!(
            "{} holds shards of {} and of {} parts; keep one split",
            dir.display(),
            first.count,
            other.count
        )));
    }
    let missing: Vec<String> = (0..first.count)
        .filter(|&i| !shards.iter().any(|s| s.index == i))
        .map(|i| i.to_string())
        .collect();
    if !missing.is_empty() {
        return Err(Error::Config(format!(
            "shards {} of {} have not run in {}",
            list_some(&missing),
            first.count,
            dir.display()
        )));
    }
    let read = |shard: &Shard, file: &str| {
        let path = dir.join(shard.folder()).join(file);
        std::fs::read_to_string(&path).map_err(|e| Error::Io(e).in_file(&path))
    };
    // Every shard holds the sweep it belongs to; the first one's is parsed, the others'
    // must be the same text.
    let sweep_text = read(&first, SHARD_SWEEP_FILE)?;
    let sweep = Sweep::from_toml_within(&sweep_text, u64::MAX)
        .map_err(|e| e.in_file(dir.join(first.folder()).join(SHARD_SWEEP_FILE)))?;
    let mut runs = Vec::new();
    let mut unfinished = Vec::new();
    for shard in &shards {
        if *shard != first && read(shard, SHARD_SWEEP_FILE)? != sweep_text {
            return Err(Error::Config(format!(
                "shards {first} and {shard} in {} belong to different sweeps",
                dir.display()
            )));
        }
        let csv_path = dir.join(shard.folder()).join("runs.csv");
        let these =
            parse_runs_csv(&sweep, &read(shard, "runs.csv")?).map_err(|e| e.in_file(&csv_path))?;
        check_share(&these, *shard).map_err(|e| e.in_file(&csv_path))?;
        let expected = sweep.jobs(Some(*shard)).len();
        if these.len() < expected {
            unfinished.push(format!("{shard} ({} of {expected} runs)", these.len()));
        }
        runs.extend(these);
    }
    if !unfinished.is_empty() {
        return Err(Error::Config(format!(
            "shards not finished in {}: {}; run them again with --resume",
            dir.display(),
            list_some(&unfinished)
        )));
    }
    runs.sort_by_key(|r| (r.point, r.seed));
    let name = sweep.name()?;
    write_outputs(&name, &sweep, &runs, dir)?;
    Ok((name, sweep, runs))
}

/// The first items of a list, and how many more there are.
fn list_some(items: &[String]) -> String {
    const SHOWN: usize = 10;
    let mut s = items
        .iter()
        .take(SHOWN)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if items.len() > SHOWN {
        let _ = write!(s, " and {} more", items.len() - SHOWN);
    }
    s
}
