//! The conformance check any [`Repair`] (ours or a user's) can be put through.
//!
//! [`check_repair`] asks the repair on drafts of the paper arm (the fixture of
//! [`kinetree_eval::conformance`]): the clean draft of its phase, where it must leave the
//! result as it is; degenerate drafts (no bodies, every point in one body, no poses, no
//! model), where it may return an error but must not panic; and the clean draft again, where
//! it must propose the same thing. It returns every violation found (empty: it conforms).

use crate::runner::{Runner, all_pairs};
use crate::{Pipeline, PipelineConfig};
use kinetree_core::model::NoiseSource;
use kinetree_core::{Draft, Edit, ModelMaker, Proposal, Repair, RepairPhase, Result, Segmentation};
use kinetree_eval::conformance::Fixture;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// Whether a proposal leaves the result as it is: none, a noise level within 1 % that does
/// not redo the clustering, or a refit that keeps every joint's type and parent and adds no
/// warning (the bundle adjustment refines the paper arm's axes).
fn is_no_op(p: Option<&Proposal>, sigma: f64, clean: &Draft) -> bool {
    match p.map(|p| &p.edit) {
        None => true,
        Some(Edit::NoiseLevel {
            sigma_m,
            redo_clustering,
        }) => !redo_clustering && (sigma_m / sigma - 1.0).abs() < 0.01,
        Some(Edit::Fit(after)) => clean.model.as_ref().is_some_and(|before| {
            let shape = |m: &kinetree_core::Model| {
                let joints: Vec<_> = m
                    .joints
                    .iter()
                    .map(|j| (j.parent, j.child, j.joint_type))
                    .collect();
                (joints, m.warnings.len())
            };
            shape(&before.model) == shape(&after.model)
        }),
        Some(_) => false,
    }
}

/// The paper arm's draft for `phase`: its true segmentation, and for the later phases its
/// poses, pair tests and model (with the model's whole-tree fit for the points and model
/// phases).
fn clean_draft(
    runner: &Runner<'_>,
    pipeline: &Pipeline,
    fx: &Fixture,
    sigma: f64,
    phase: RepairPhase,
) -> Result<Draft> {
    let seg = fx.segmentation();
    let mut draft = Draft::new(seg.clone());
    if phase == RepairPhase::Grouping {
        return Ok(draft);
    }
    let poses = pipeline.pose.estimate(&kinetree_core::PoseInput {
        tracks: &fx.tracks,
        segmentation: &seg,
        noise_sigma_m: sigma,
    })?;
    let pairs = all_pairs(pipeline.dof.as_ref(), &poses, sigma, None)?;
    draft.poses = Some(poses);
    draft.pairs = Some(pairs);
    if phase != RepairPhase::Bodies {
        let (Some(poses), Some(pairs)) = (&draft.poses, &draft.pairs) else {
            return Ok(draft);
        };
        let mut model = if matches!(phase, RepairPhase::Tree | RepairPhase::Fit) {
            runner.assemble(&seg, poses, pairs, &[], &[], &[])?
        } else {
            runner.make(&seg, poses, pairs, &[])?
        };
        if phase == RepairPhase::Fit {
            let state = kinetree_fit::FitState::new(&model.model, &fx.tracks)?;
            model.cache = Some(std::sync::Arc::new(state));
        }
        if matches!(phase, RepairPhase::Points | RepairPhase::Model) {
            let motions = kinetree_fit::FittedMotions::new(&model.model, &fx.tracks)?;
            model.fitted = Some(motions.into_fitted());
        }
        draft.adopt(model)?;
    }
    Ok(draft)
}

/// Every contract violation of `repair` (see the module docs).
pub fn check_repair(repair: &dyn Repair) -> Vec<String> {
    let mut violations = Vec::new();
    let name = repair.name().to_owned();
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c == '_' || c.is_ascii_digit())
    {
        violations.push(format!("name `{name}`: must be non-empty snake_case"));
    }
    let fx = Fixture::new();
    let pipeline = match Pipeline::from_config(&PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    }) {
        Ok(p) => p,
        Err(e) => return vec![format!("default pipeline: {e}")],
    };
    let sigma = 0.001;
    let stats = kinetree_dissimilarity::pair_stats(&fx.tracks);
    let dmat = match crate::runner::segment(&pipeline, &fx.tracks, &stats, sigma) {
        Ok((d, _)) => d,
        Err(e) => return vec![format!("paper arm matrix: {e}")],
    };
    let runner = Runner::new(
        &pipeline,
        &fx.tracks,
        &stats,
        &dmat,
        sigma,
        NoiseSource::Given,
        Some(sigma),
        Vec::new(),
        &(),
    );
    let ctx = runner.context();
    let phase = repair.phase();
    let clean = match clean_draft(&runner, &pipeline, &fx, sigma, phase) {
        Ok(d) => d,
        Err(e) => return vec![format!("paper arm draft: {e}")],
    };
    let ask = |draft: &Draft| catch_unwind(AssertUnwindSafe(|| repair.propose(&ctx, draft)));
    let first = match ask(&clean) {
        Err(_) => {
            violations.push("clean paper arm: panicked".into());
            None
        }
        Ok(Err(e)) => {
            violations.push(format!("clean paper arm: error {e}"));
            None
        }
        Ok(Ok(p)) => {
            if !is_no_op(p.as_ref(), sigma, &clean) {
                violations.push(format!(
                    "clean paper arm: proposed a `{}` edit ({})",
                    p.as_ref().map_or("", |p| p.edit.kind()),
                    p.as_ref().map_or("", |p| p.summary.as_str())
                ));
            }
            Some(format!("{p:?}"))
        }
    };
    if let (Some(first), Ok(Ok(again))) = (first, ask(&clean))
        && first != format!("{again:?}")
    {
        violations.push("clean paper arm: a second call proposed something else".into());
    }
    let n = fx.tracks.n_points();
    let none = Segmentation::from_raw(&vec![None; n], 1);
    let one = Segmentation::from_raw(&vec![Some(0); n], 1);
    let mut degenerate = vec![
        ("no bodies, no poses", Draft::new(none.clone())),
        ("one body of every point, no poses", Draft::new(one.clone())),
    ];
    let mut bare = clean.clone();
    bare.model = None;
    bare.pairs = None;
    degenerate.push(("poses without pair tests or model", bare));
    for (seg, label) in [
        (none, "no bodies, posed"),
        (one, "one body of every point, posed"),
    ] {
        if let Ok(poses) = pipeline.pose.estimate(&kinetree_core::PoseInput {
            tracks: &fx.tracks,
            segmentation: &seg,
            noise_sigma_m: sigma,
        }) {
            let mut d = Draft::new(seg);
            d.poses = Some(poses);
            d.pairs = Some(Vec::new());
            degenerate.push((label, d));
        }
    }
    for (label, draft) in &degenerate {
        if ask(draft).is_err() {
            violations.push(format!("{label}: panicked"));
        }
    }
    violations
}
