//! Bodies that move rigidly together merged, when the merged body still fits as one.
//!
//! Groups come from complete linkage over the body pairs rigid within their tests' bounds (a
//! slide that stood out only against the measured noise level counts), clearest first: two
//! groups merge only when every pair across them tests rigid, so one body with poor poses (which
//! "tests rigid" against everything because its noise hides all motion) cannot chain unrelated
//! bodies together. Parts of a split (the `cannot_link` constraints) and bodies the pairwise
//! measure keeps apart never end in one group.
//!
//! The pose-based DoF test carries a slack for model error, so it can call a small, barely
//! moving body rigid to its parent; the distance F-test has no such slack and sees the motion
//! plainly (`docs/decisions.md`, `merge`). A body the clusterer split by mistake has cross
//! pairs near q = 0.5 and still merges.

use super::{
    count_in_range, in_range, mean_cross, points_fit_as_one, poses_of, rigid_within_bounds,
};
use kinetree_core::{
    DissimilarityMatrix, Draft, Edit, Error, PairDof, Proposal, Repair, RepairContext, RepairLimit,
    RepairPhase, Result, Segmentation, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`Merge`] (`[pipeline.repairs.merge]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MergeParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Merges per bodies phase (default 3).
    pub max_rounds: usize,
    /// A merged body fits as one when its median pose residual is at most this many noise
    /// std-devs (default 2.5, the split's bound).
    pub residual_in_sigma: f64,
}

impl Default for MergeParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_rounds: 3,
            residual_in_sigma: 2.5,
        }
    }
}

impl MergeParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        count_in_range("merge", "max_rounds", self.max_rounds, 0, 1000)?;
        in_range(
            "merge",
            "residual_in_sigma",
            self.residual_in_sigma,
            0.1,
            1e6,
        )
    }
}

/// Merges bodies that move rigidly together.
#[derive(Debug, Clone)]
pub struct Merge {
    params: MergeParams,
}

impl Merge {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: MergeParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

/// Pairs of bodies the pairwise measure keeps apart: the mean dissimilarity over their
/// observed cross pairs is above the measure's cut.
fn pairwise_apart(m: &DissimilarityMatrix, seg: &Segmentation) -> Vec<(usize, usize)> {
    let members = seg.members();
    let mut out = Vec::new();
    for a in 0..members.len() {
        for b in a + 1..members.len() {
            if mean_cross(m, &members[a], &members[b]).is_some_and(|d| d > m.suggested_cut) {
                out.push((a, b));
            }
        }
    }
    out
}

/// Groups of bodies to merge because they move rigidly together (complete linkage over the
/// pairs rigid within their tests' bounds, [`rigid_within_bounds`], clearest first); bodies listed together in `forbidden` never end in one
/// group. Returns a group id per body.
pub(crate) fn rigid_groups(
    n_bodies: usize,
    pairs: &[PairDof],
    forbidden: &[(usize, usize)],
) -> Vec<usize> {
    let rigid = |a: usize, b: usize| {
        pairs.iter().any(|p| {
            rigid_within_bounds(p).is_some()
                && ((p.a == Some(a) && p.b == b) || (p.a == Some(b) && p.b == a))
        })
    };
    let mut candidates: Vec<(f64, &PairDof)> = pairs
        .iter()
        .filter(|p| p.a.is_some())
        .filter_map(|p| Some((rigid_within_bounds(p)?, p)))
        .collect();
    candidates.sort_by(|(x, p), (y, q)| x.total_cmp(y).then((p.a, p.b).cmp(&(q.a, q.b))));
    let mut group: Vec<usize> = (0..n_bodies).collect();
    for (_, p) in candidates {
        let Some(a) = p.a else { continue };
        let (ga, gb) = (group[a], group[p.b]);
        if ga == gb {
            continue;
        }
        let in_a: Vec<usize> = (0..n_bodies).filter(|&b| group[b] == ga).collect();
        let in_b: Vec<usize> = (0..n_bodies).filter(|&b| group[b] == gb).collect();
        let all_rigid = in_a.iter().all(|&x| in_b.iter().all(|&y| rigid(x, y)));
        let split_before = forbidden.iter().any(|&(p, q)| {
            (in_a.contains(&p) && in_b.contains(&q)) || (in_a.contains(&q) && in_b.contains(&p))
        });
        if all_rigid && !split_before {
            for g in &mut group {
                if *g == gb {
                    *g = ga;
                }
            }
        }
    }
    group
}

impl Repair for Merge {
    fn name(&self) -> &str {
        "merge"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Edits(self.params.max_rounds)
    }

    fn needs_pair_tests(&self) -> bool {
        true
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let pairs = draft
            .pairs
            .as_ref()
            .ok_or_else(|| Error::Degenerate("repair `merge` needs the pair tests".into()))?;
        let seg = &draft.segmentation;
        let nb = seg.n_bodies();
        let mut forbidden: Vec<(usize, usize)> = draft
            .constraints
            .cannot_link
            .iter()
            .filter_map(|&(p, q)| Some((seg.body_of(p)?, seg.body_of(q)?)))
            .collect();
        forbidden.extend(pairwise_apart(ctx.dissimilarity, seg));
        // A merge stands only if the merged body still fits like one rigid body.
        let group = loop {
            let group = rigid_groups(nb, pairs, &forbidden);
            let mut rejected = false;
            for g in 0..nb {
                let members: Vec<usize> = (0..nb).filter(|&b| group[b] == g).collect();
                if members.len() < 2 {
                    continue;
                }
                let points: Vec<usize> = members
                    .iter()
                    .flat_map(|&b| poses.bodies[b].points.iter().copied())
                    .collect();
                if points_fit_as_one(ctx, &points, self.params.residual_in_sigma)? {
                    continue;
                }
                rejected = true;
                for (x, &p) in members.iter().enumerate() {
                    for &q in &members[x + 1..] {
                        forbidden.push((p, q));
                    }
                }
            }
            if !rejected {
                break group;
            }
        };
        if group.iter().enumerate().all(|(b, &g)| g == b) {
            return Ok(None);
        }
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for g in 0..nb {
            let members: Vec<usize> = (0..nb).filter(|&b| group[b] == g).collect();
            if members.len() > 1 {
                groups.extend(members.iter().map(|&b| poses.bodies[b].points.clone()));
            }
        }
        let mut p = Proposal::new(
            Edit::Segmentation(seg.merged(&group)),
            format!("{} bodies merged into fewer", groups.len()),
        );
        p.points = groups.iter().flatten().copied().collect();
        p.points.sort_unstable();
        p.warnings.push(Warning::BodiesMerged { groups });
        Ok(Some(p))
    }
}

#[cfg(test)]
mod tests {
    use super::rigid_groups;
    use kinetree_core::{JointKind, PairDof, RankTest};

    fn pair(a: usize, b: usize, joint: JointKind, fit_ratio: f64) -> PairDof {
        PairDof {
            a: Some(a),
            b,
            reference_frame: 0,
            translation: RankTest::empty(),
            rotation: RankTest::empty(),
            centre: RankTest::empty(),
            sliding: RankTest::empty(),
            centre_uncentred: RankTest::empty(),
            axes: RankTest::empty(),
            dof: usize::from(!matches!(joint, JointKind::Rigid)),
            joint,
            fit_ratio,
            distance_m: None,
            ball_fit_rms_m: None,
            ball_reach_m: None,
        }
    }

    #[test]
    fn a_poorly_posed_body_cannot_chain_moving_bodies_together() {
        // Body 1 "tests rigid" against 0 and 2 (its noise hides everything), while 0 and 2
        // clearly move relative to each other.
        let pairs = vec![
            pair(0, 1, JointKind::Rigid, 0.2),
            pair(1, 2, JointKind::Rigid, 0.5),
            pair(0, 2, JointKind::MultiDof, 0.1),
        ];
        let g = rigid_groups(3, &pairs, &[]);
        assert_eq!(g[0], g[1], "the clearest rigid pair merges");
        assert_ne!(g[0], g[2], "but 0 and 2 stay apart");
        // When every cross pair is rigid, all three merge.
        let all = vec![
            pair(0, 1, JointKind::Rigid, 0.2),
            pair(1, 2, JointKind::Rigid, 0.5),
            pair(0, 2, JointKind::Rigid, 0.1),
        ];
        let g = rigid_groups(3, &all, &[]);
        assert!(g.iter().all(|&x| x == g[0]));
        // ... unless two of them were split apart before.
        let g = rigid_groups(3, &all, &[(0, 2)]);
        assert_ne!(g[0], g[2]);
    }

    /// A slide the chi-square rule found under its bound (rank 0's residual 2.1 against a
    /// bound of 3, but twice the measured level) joins a group as a rigid pair would: two
    /// parts of one body the clustering split move apart by no more than the model error the
    /// bound allows for. A slide over its bound does not.
    #[test]
    fn a_slide_under_the_bound_merges_as_a_rigid_pair() {
        let slide = |chi2: f64| {
            let mut p = pair(
                0,
                1,
                JointKind::Prismatic {
                    axis: kinetree_core::nalgebra::Vector3::x(),
                },
                0.3,
            );
            p.translation.rank = 1;
            p.translation.chi2_per_dof = vec![chi2, 1.0, 1.0];
            p.translation.chi2_bound = vec![3.0, 3.1, 3.4];
            p
        };
        let g = rigid_groups(2, &[slide(2.1)], &[]);
        assert_eq!(g[0], g[1]);
        let g = rigid_groups(2, &[slide(3.2)], &[]);
        assert_ne!(g[0], g[1]);
    }
}
