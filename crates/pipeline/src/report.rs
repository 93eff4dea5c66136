//! Human-readable reports: the structure summary and the paper's Table I.

use kinetree_core::{Model, RankTest};
use std::fmt::Write;

/// The non-zero singular values of a test, or for a chi-square test without singular values
/// (the pivot test) its `chi2/dof`.
fn values(t: &RankTest) -> String {
    if t.rank == 0 {
        return "-".into();
    }
    if let Some(vals) = t.singular_values.get(..t.rank) {
        return vals
            .iter()
            .map(|v| format!("{v:.1}"))
            .collect::<Vec<_>>()
            .join(", ");
    }
    match t.chi2_per_dof.last() {
        Some(c) => format!("chi2/dof {c:.1}"),
        None => format!("rank {}", t.rank),
    }
}

/// The cells of Table I: for rows F0 (camera) .. F(n-1) and columns F1 .. Fn, the non-zero
/// (above-threshold) singular values of the translation, rotation and centre matrices.
/// Frame `F(k+1)` is model body `k`. Returns `(row, column, [t, r, c])` triples.
pub fn table_cells(model: &Model) -> Vec<(usize, usize, [String; 3])> {
    model
        .pairs
        .iter()
        .map(|p| {
            let row = p.a.map_or(0, |a| a + 1);
            (
                row,
                p.b + 1,
                [
                    values(&p.translation),
                    values(&p.rotation),
                    values(&p.centre_uncentred),
                ],
            )
        })
        .collect()
}

/// Table I as Markdown, in the paper's layout (each column Fm split into translation,
/// rotation and centre).
pub fn table_markdown(model: &Model) -> String {
    let n = model.bodies.len();
    let cells = table_cells(model);
    let mut s = String::new();
    s.push('|');
    s.push_str("   |");
    for m in 1..=n {
        let _ = write!(s, " F{m} T | F{m} R | F{m} C |");
    }
    s.push('\n');
    s.push('|');
    s.push_str("---|");
    for _ in 1..=n {
        s.push_str("---|---|---|");
    }
    s.push('\n');
    for row in 0..n {
        let _ = write!(s, "| F{row} |");
        for col in 1..=n {
            match cells.iter().find(|c| c.0 == row && c.1 == col) {
                Some((_, _, [t, r, c])) => {
                    let _ = write!(s, " {t} | {r} | {c} |");
                }
                None => s.push_str("   |   |   |"),
            }
        }
        s.push('\n');
    }
    s
}

/// Table I as aligned plain text for the terminal.
pub fn table_text(model: &Model) -> String {
    let n = model.bodies.len();
    let cells = table_cells(model);
    let width = cells
        .iter()
        .map(|c| c.2.iter().map(String::len).max().unwrap_or(1))
        .max()
        .unwrap_or(1)
        .max(4);
    let mut s = String::new();
    let _ = write!(s, "{:4}", "");
    for m in 1..=n {
        let head = format!("F{m} (T | R | C)");
        let _ = write!(s, "  {head:<w$}", w = 3 * width + 6);
    }
    s.push('\n');
    for row in 0..n {
        let _ = write!(s, "{:4}", format!("F{row}"));
        for col in 1..=n {
            let text = match cells.iter().find(|c| c.0 == row && c.1 == col) {
                Some((_, _, [t, r, c])) => format!("{t:<width$} | {r:<width$} | {c:<width$}"),
                None => String::new(),
            };
            let _ = write!(s, "  {text:<w$}", w = 3 * width + 6);
        }
        s.push('\n');
    }
    s
}

/// A readable summary of the discovered structure.
pub fn summary(model: &Model) -> String {
    let mut s = String::new();
    let n_discarded = model.point_body.iter().filter(|&&b| b < 0).count();
    let _ = writeln!(
        s,
        "{} bodies from {} points over {} frames ({} discarded); noise sigma {:.3} mm ({:?})",
        model.bodies.len(),
        model.n_points,
        model.n_frames,
        n_discarded,
        model.noise.sigma_m * 1e3,
        model.noise.source
    );
    for b in &model.bodies {
        let carried = model.joints.iter().filter(|j| j.parent == b.id).count();
        let role = if b.is_static {
            "static".to_string()
        } else if b.parent.is_none() {
            "root".to_string()
        } else if model.is_unseen_link(b.id) && carried > 1 {
            format!("a link put in, carrying {carried} bodies")
        } else if model.is_unseen_link(b.id) {
            "a link put in between two hinges".to_string()
        } else {
            "moving".to_string()
        };
        let _ = writeln!(
            s,
            "  body {} ({role}): {} points {:?}",
            b.id,
            b.points.len(),
            b.points
        );
    }
    for j in &model.joints {
        let axis = j
            .axis
            .map(|a| format!(" axis [{:.3}, {:.3}, {:.3}]", a[0], a[1], a[2]))
            .unwrap_or_default();
        let point = j
            .point
            .map(|p| format!(" through [{:.3}, {:.3}, {:.3}] m", p[0], p[1], p[2]))
            .unwrap_or_default();
        let range = j
            .range
            .map(|r| format!(" range [{:.3}, {:.3}]", r[0], r[1]))
            .unwrap_or_default();
        let _ = writeln!(
            s,
            "  joint body {} -> body {}: {}{axis}{point}{range}",
            j.parent, j.child, j.joint_type
        );
    }
    if let Some(c) = &model.chain {
        let chain: Vec<String> = c.iter().map(|b| format!("body {b}")).collect();
        let _ = writeln!(s, "  chain: {}", chain.join(" -> "));
    }
    if let Some(r) = model.reprediction_rms_in_sigma {
        let _ = writeln!(
            s,
            "  keypoints re-predicted from the joints: RMS {r:.2} sigma"
        );
    }
    for w in &model.warnings {
        // Markers left off the bodies by name, when the input named them.
        let names: Vec<&str> = model
            .point_labels
            .iter()
            .flat_map(|labels| {
                w.points_left_out()
                    .iter()
                    .filter_map(|&p| labels.get(p).map(String::as_str))
            })
            .collect();
        if names.is_empty() {
            let _ = writeln!(s, "  warning: {w}");
        } else {
            let _ = writeln!(s, "  warning: {w} (markers {})", names.join(", "));
        }
    }
    s
}

/// A readable account of a model for `kinetree inspect`: the [`summary`], then each body's
/// keypoints by label, each joint's decision (ranks, fit ratio, how the whole-tree fit treats
/// it, frames observed), the stages that produced it, and the repairs' trace.
pub fn inspect(model: &Model) -> String {
    let mut s = format!(
        "model schema {} by {}; stages: {} / {} / {} / {}\n",
        model.schema_version,
        model.generator,
        model.stages.dissimilarity,
        model.stages.clustering,
        model.stages.pose,
        model.stages.dof
    );
    s.push_str(&summary(model));
    if let Some(labels) = &model.point_labels {
        for b in &model.bodies {
            let names: Vec<&str> = b
                .points
                .iter()
                .filter_map(|&p| labels.get(p).map(String::as_str))
                .collect();
            let _ = writeln!(s, "  body {} keypoints: {}", b.id, names.join(", "));
        }
        let lost: Vec<&str> = (0..model.point_body.len())
            .filter(|&p| model.point_body[p] < 0)
            .filter_map(|p| labels.get(p).map(String::as_str))
            .collect();
        if !lost.is_empty() {
            let _ = writeln!(s, "  discarded keypoints: {}", lost.join(", "));
        }
    }
    for j in &model.joints {
        let seen = j.positions.iter().filter(|p| p.is_some()).count();
        let _ = writeln!(
            s,
            "  joint body {} -> body {}: {} DoF, ranks t{} r{} c{} s{}, fit ratio {:.2}, {:?} by the fit, observed in {seen}/{} frames",
            j.parent,
            j.child,
            j.dof,
            j.ranks.translation,
            j.ranks.rotation,
            j.ranks.centre,
            j.ranks.sliding,
            j.fit_ratio,
            j.fit,
            model.n_frames
        );
    }
    if !model.trace.is_empty() {
        let _ = writeln!(s, "repairs ({} changes):", model.trace.len());
        for e in &model.trace {
            let _ = writeln!(
                s,
                "  pass {} {:?} {} ({}): {}",
                e.pass, e.phase, e.repair, e.outcome, e.summary
            );
        }
    }
    s
}

/// A model's comparison with the simulator's truth, for a terminal: the segmentation's ARI,
/// bodies found, and for each true joint (named by its bodies) whether it was found with its
/// type, its axis and position errors, and otherwise why it was missed.
pub fn evaluation_text(
    e: &kinetree_eval::Evaluation,
    truth: &kinetree_synth::GroundTruth,
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "against the simulator's truth: ARI {:.3}, bodies {}/{}, joints exact: {}, structure exact: {}",
        e.ari, e.n_bodies_found, e.n_bodies_true, e.joints_exact, e.structure_exact
    );
    let name = |b: usize| {
        truth
            .mechanism
            .bodies
            .get(b)
            .map_or_else(|| format!("body {b}"), |s| s.name.clone())
    };
    for j in &e.joints {
        let Some(spec) = truth.mechanism.joints.get(j.joint) else {
            continue;
        };
        let _ = write!(
            s,
            "  true joint {} ({} -> {}, {}): ",
            j.joint,
            name(spec.parent),
            name(spec.child),
            format!("{:?}", spec.joint_type).to_lowercase()
        );
        match j.miss {
            None => {
                let _ = writeln!(
                    s,
                    "right, axis error {}, joint RMS {} (smoothed {})",
                    j.axis_error_deg
                        .map_or("-".into(), |v| format!("{v:.3} deg")),
                    j.position_rms.map_or("-".into(), |v| format!("{v:.4}")),
                    j.smoothed_rms.map_or("-".into(), |v| format!("{v:.4}"))
                );
            }
            Some(m) => {
                let found = j
                    .model_type
                    .map_or(String::new(), |t| format!(" (found as {})", t.as_str()));
                let _ = writeln!(s, "missed: {}{found}", m.as_str().replace('_', " "));
            }
        }
    }
    let right = e.joints.iter().filter(|j| j.miss.is_none()).count();
    let missed = kinetree_eval::JointMiss::describe(&kinetree_eval::JointMiss::tally(
        e.joints.iter().filter_map(|j| j.miss),
    ));
    let _ = writeln!(
        s,
        "  {right} of {} joints right{}{missed}",
        e.joints.len(),
        if missed.is_empty() { "" } else { "; missed: " },
    );
    s
}
