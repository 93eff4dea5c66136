//! Assignment of points to rigid bodies.

use serde::{Deserialize, Serialize};

/// Which body every point belongs to; `None` for a discarded point.
///
/// Every constructor and edit numbers the bodies canonically: body 0 holds the lowest-indexed
/// assigned point, body 1 the lowest-indexed point not in body 0, and so on, so equal
/// partitions compare equal. [`Segmentation::renumbered`] alone gives another numbering: a
/// model's tree order, which a run's draft takes once it has a model.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Segmentation {
    labels: Vec<Option<usize>>,
    n_bodies: usize,
    /// Groups of points that formed clusters too small for a pose, in point order.
    pub discarded_groups: Vec<Vec<usize>>,
}

/// `new_id` with `new_id[order[k]] = k`, when `order` is a permutation of `0..n`.
pub(crate) fn inverse_permutation(order: &[usize], n: usize) -> Option<Vec<usize>> {
    if order.len() != n {
        return None;
    }
    let mut new_id = vec![usize::MAX; n];
    for (k, &old) in order.iter().enumerate() {
        if new_id.get(old) != Some(&usize::MAX) {
            return None;
        }
        new_id[old] = k;
    }
    Some(new_id)
}

/// The fewest points a body needs for a pose.
pub const MIN_BODY_POINTS: usize = 3;

impl Segmentation {
    /// Builds a canonical segmentation from raw cluster ids; clusters with fewer than
    /// `min_points` points are discarded and recorded in [`Segmentation::discarded_groups`].
    pub fn from_raw(raw: &[Option<usize>], min_points: usize) -> Self {
        let max = raw.iter().flatten().copied().max().map_or(0, |m| m + 1);
        let mut sizes = vec![0usize; max];
        for c in raw.iter().flatten() {
            sizes[*c] += 1;
        }
        let mut map: Vec<Option<usize>> = vec![None; max];
        let mut n_bodies = 0;
        let mut groups: Vec<Vec<usize>> = vec![Vec::new(); max];
        let mut labels = vec![None; raw.len()];
        for (i, c) in raw.iter().enumerate() {
            let Some(c) = *c else { continue };
            if sizes[c] < min_points {
                groups[c].push(i);
                continue;
            }
            let id = *map[c].get_or_insert_with(|| {
                n_bodies += 1;
                n_bodies - 1
            });
            labels[i] = Some(id);
        }
        let mut discarded_groups: Vec<Vec<usize>> =
            groups.into_iter().filter(|g| !g.is_empty()).collect();
        discarded_groups.sort();
        Self {
            labels,
            n_bodies,
            discarded_groups,
        }
    }

    /// Number of points.
    pub fn n_points(&self) -> usize {
        self.labels.len()
    }

    /// Number of bodies kept.
    pub fn n_bodies(&self) -> usize {
        self.n_bodies
    }

    /// Body of each point.
    pub fn labels(&self) -> &[Option<usize>] {
        &self.labels
    }

    /// Body of one point.
    pub fn body_of(&self, point: usize) -> Option<usize> {
        self.labels.get(point).copied().flatten()
    }

    /// The points of each body, in point order.
    pub fn members(&self) -> Vec<Vec<usize>> {
        let mut m = vec![Vec::new(); self.n_bodies];
        for (i, l) in self.labels.iter().enumerate() {
            if let Some(b) = l {
                m[*b].push(i);
            }
        }
        m
    }

    /// Labels as integers with -1 for discarded points (the model-file convention).
    pub fn labels_i64(&self) -> Vec<i64> {
        self.labels
            .iter()
            .map(|l| l.map_or(-1, |b| b as i64))
            .collect()
    }

    /// Merges bodies by a map `old body -> new group` (any integers) and renumbers canonically.
    pub fn merged(&self, group_of_body: &[usize]) -> Self {
        let raw: Vec<Option<usize>> = self
            .labels
            .iter()
            .map(|l| l.map(|b| group_of_body[b]))
            .collect();
        let mut out = Self::from_raw(&raw, 0);
        out.discarded_groups.clone_from(&self.discarded_groups);
        out
    }

    /// The same partition with body `order[k]` renumbered `k` (a model's tree order); `None`
    /// unless `order` is a permutation of the bodies. Not canonical: any edit renumbers
    /// canonically again.
    pub fn renumbered(&self, order: &[usize]) -> Option<Self> {
        Some(self.relabeled(&inverse_permutation(order, self.n_bodies)?))
    }

    /// The same partition with body `b` renumbered `new_id[b]`; `new_id` must be a
    /// permutation of the bodies ([`inverse_permutation`] of an order).
    pub(crate) fn relabeled(&self, new_id: &[usize]) -> Self {
        Self {
            labels: self.labels.iter().map(|l| l.map(|b| new_id[b])).collect(),
            n_bodies: self.n_bodies,
            discarded_groups: self.discarded_groups.clone(),
        }
    }

    /// `self.discarded_groups` without `points` (now assigned), empty groups removed.
    pub fn discarded_groups_without(&self, points: &[usize]) -> Vec<Vec<usize>> {
        self.discarded_groups
            .iter()
            .map(|g| {
                g.iter()
                    .copied()
                    .filter(|i| !points.contains(i))
                    .collect::<Vec<_>>()
            })
            .filter(|g| !g.is_empty())
            .collect()
    }

    /// Takes the listed points off their bodies (they become unassigned; a body left with
    /// none is gone) and renumbers canonically.
    pub fn without_points(&self, points: &[usize]) -> Self {
        self.keeping(|point, _| !points.contains(&point))
    }

    /// Drops the listed bodies (their points become discarded) and renumbers canonically.
    pub fn without_bodies(&self, drop: &[usize]) -> Self {
        self.keeping(|_, body| !drop.contains(&body))
    }

    /// The assignments `keep(point, body)` accepts, renumbered canonically, with the same
    /// discarded groups.
    fn keeping(&self, keep: impl Fn(usize, usize) -> bool) -> Self {
        let raw: Vec<Option<usize>> = self
            .labels
            .iter()
            .enumerate()
            .map(|(i, l)| l.filter(|&b| keep(i, b)))
            .collect();
        let mut out = Self::from_raw(&raw, 0);
        out.discarded_groups.clone_from(&self.discarded_groups);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_and_bodies_are_taken_off_and_the_rest_renumbered() {
        let mut seg = Segmentation::from_raw(&[Some(0), Some(0), Some(1), Some(2), None], 1);
        seg.discarded_groups = vec![vec![4]];
        // Point 2 was body 1's only point: body 1 is gone and body 2 becomes body 1.
        let fewer = seg.without_points(&[1, 2]);
        assert_eq!(fewer.labels(), &[Some(0), None, None, Some(1), None]);
        assert_eq!(fewer.n_bodies(), 2);
        assert_eq!(fewer.discarded_groups, vec![vec![4]]);
        let dropped = seg.without_bodies(&[0]);
        assert_eq!(dropped.labels(), &[None, None, Some(0), Some(1), None]);
        assert_eq!(dropped.discarded_groups, vec![vec![4]]);
    }

    #[test]
    fn renumbering_keeps_the_partition_and_refuses_a_non_permutation() {
        let mut seg = Segmentation::from_raw(&[Some(0), Some(1), Some(1), Some(2), None], 1);
        seg.discarded_groups = vec![vec![4]];
        // Body 2 first, then 0, then 1.
        let tree = seg.renumbered(&[2, 0, 1]).expect("a permutation");
        assert_eq!(tree.labels(), &[Some(1), Some(2), Some(2), Some(0), None]);
        assert_eq!(tree.n_bodies(), 3);
        assert_eq!(tree.discarded_groups, vec![vec![4]]);
        // An edit renumbers canonically again.
        assert_eq!(tree.without_points(&[]), seg);
        for bad in [&[0, 1][..], &[0, 1, 1], &[0, 1, 3], &[0, 1, 2, 3]] {
            assert!(seg.renumbered(bad).is_none(), "{bad:?}");
        }
    }
}
