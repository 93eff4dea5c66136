//! The spanning tree's preferences among pairs that pass the DoF test equally, and where it
//! hangs a subject that moves freely past a static scene (`[pipeline.tree]`).

use serde::{Deserialize, Serialize};

/// How the spanning tree weighs a pair beyond its DoF test: the distance between the two
/// bodies, and how close a grandparent's pair must fit for an exact tie (`docs/decisions.md`
/// has the measurements behind each default).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TreeCosts {
    /// Weight of a pair's distance in its edge cost: the distance between the two bodies'
    /// centroids over the median of every body pair's, capped at `adjacency_cap`, times this
    /// (default 0.2). A joint joins neighbours: on skin markers many far pairs pass a loose
    /// test as hinges. 0 leaves the distance out.
    pub adjacency_weight: f64,
    /// Largest relative distance the weight counts (default 2), so a far pair costs at most
    /// `adjacency_weight * adjacency_cap` more: less than a single-DoF edge's lead over a
    /// multi-DoF one (1).
    pub adjacency_cap: f64,
    /// How much worse, in fit ratio, a body's single-DoF pair with its grandparent may fit than
    /// its pair with its parent for the two to count as an exact tie (three hinges or three
    /// slides), which hangs it on the grandparent (default 0.3). Ties beyond it are left to a
    /// whole-tree fit (the `sibling_ties` repair).
    pub tie_fit_margin: f64,
    /// Base cost of a universal edge (default 2.5); its fit ratio and missed share add up to
    /// one more, as on a single-DoF edge, so it costs 2.5-3.5: above every single-DoF edge
    /// (1-2) and below the untyped multi-DoF edges of two DoF (3-4). A typed joint to its true
    /// parent then wins over a two-DoF pair with a body of another branch whose axes are
    /// parallel to its own (the fingers of a hand).
    pub universal_cost: f64,
    /// Bodies whose pairs with the static root are all of no joint type and of at least this
    /// many DoF are a subject moving freely past the scene, which the tree hangs by its own
    /// root, as it would with nothing static (default 5: a noisy arm's first link can test at
    /// four DoF against its base, a walking pelvis at five). Above 6 turns the rule off.
    pub min_free_dof: usize,
    /// Multi-DoF pairs of at least this many DoF, `n`, and ball-typed pairs when `n` is 3,
    /// cost the same whatever their DoF, plus how far they are from a ball joint and how
    /// far its centre lies from the farther body: `1 + n + r / (r + m)` plus the
    /// adjacency term of `ball_reach_m` (`r` the pair's `ball_fit_rms_m`, `m` its median over
    /// the pairs of moving bodies); a pair with a static body keeps its cost by DoF. Default
    /// 7, which no pair reaches: every pair is ranked by its DoF. The motion-capture preset
    /// sets 3: on skin markers no joint type explains a multi-DoF pair and the rank tests'
    /// four, five or six DoF say little, while a ball fit's residual is a few millimetres
    /// between neighbouring segments and a limb's swing between a segment and the next but
    /// one; and a ball typing does not tell a neighbour from a body rigid with it, while the
    /// centre's distance does (`docs/decisions.md`, `tree.ball_fit_from_dof`).
    pub ball_fit_from_dof: usize,
}

impl Default for TreeCosts {
    fn default() -> Self {
        Self {
            adjacency_weight: 0.2,
            adjacency_cap: 2.0,
            tie_fit_margin: 0.3,
            universal_cost: 2.5,
            min_free_dof: 5,
            ball_fit_from_dof: 7,
        }
    }
}

impl TreeCosts {
    /// Checks the ranges; `section` names the config section in the error.
    ///
    /// # Errors
    /// [`crate::Error::InvalidParameter`] naming `<section>.<parameter>`.
    pub fn validate(&self, section: &str) -> crate::Result<()> {
        for (field, v, max) in [
            ("adjacency_weight", self.adjacency_weight, 1e3),
            ("adjacency_cap", self.adjacency_cap, 1e6),
            ("tie_fit_margin", self.tie_fit_margin, 1e3),
            ("universal_cost", self.universal_cost, 1e3),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(crate::Error::InvalidParameter {
                    name: format!("{section}.{field}"),
                    message: format!("must be within [0, {max}], got {v}"),
                });
            }
        }
        crate::limits::check_count(&format!("{section}.min_free_dof"), self.min_free_dof, 1, 7)?;
        crate::limits::check_count(
            &format!("{section}.ball_fit_from_dof"),
            self.ball_fit_from_dof,
            2,
            7,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_range_costs_are_named() {
        assert!(TreeCosts::default().validate("pipeline.tree").is_ok());
        let weight = TreeCosts {
            adjacency_weight: -0.1,
            ..TreeCosts::default()
        };
        let margin = TreeCosts {
            tie_fit_margin: f64::NAN,
            ..TreeCosts::default()
        };
        let universal = TreeCosts {
            universal_cost: f64::INFINITY,
            ..TreeCosts::default()
        };
        let ball = TreeCosts {
            ball_fit_from_dof: 1,
            ..TreeCosts::default()
        };
        for (bad, key) in [
            (ball, "pipeline.tree.ball_fit_from_dof"),
            (weight, "pipeline.tree.adjacency_weight"),
            (margin, "pipeline.tree.tie_fit_margin"),
            (universal, "pipeline.tree.universal_cost"),
        ] {
            let e = bad
                .validate("pipeline.tree")
                .expect_err("invalid")
                .to_string();
            assert!(e.contains(key), "{e}");
        }
    }
}
