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
    /// Points that belong to a second body as well, as `(point, body)`, ascending: a marker
    /// on a joint's axis or centre is rigid with both bodies it joins. `labels` holds each
    /// point's first body.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    shared: Vec<(usize, usize)>,
}

/// `new_id` with `new_id[order[k]] = k`, when `order` is a permutation of `0..n`.
pub fn inverse_permutation(order: &[usize], n: usize) -> Option<Vec<usize>> {
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
            shared: Vec::new(),
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

    /// The points of each body, in point order, its shared points included.
    pub fn members(&self) -> Vec<Vec<usize>> {
        let mut m = vec![Vec::new(); self.n_bodies];
        for (i, l) in self.labels.iter().enumerate() {
            if let Some(b) = l {
                m[*b].push(i);
            }
        }
        for &(p, b) in &self.shared {
            m[b].push(p);
        }
        for points in &mut m {
            points.sort_unstable();
        }
        m
    }

    /// The points that belong to a second body as well, as `(point, body)`, ascending.
    pub fn shared(&self) -> &[(usize, usize)] {
        &self.shared
    }

    /// The same partition with each `(point, body)` of `pairs` made a second membership of
    /// the point: one that names a body that does not exist, the point's own body, or a
    /// point on no body is left out.
    pub fn with_shared(&self, pairs: &[(usize, usize)]) -> Self {
        let mut out = self.clone();
        for &(p, b) in pairs {
            if b < self.n_bodies && self.body_of(p).is_some_and(|own| own != b) {
                out.shared.push((p, b));
            }
        }
        out.shared.sort_unstable();
        out.shared.dedup();
        out
    }

    /// `self`, built from `raw` (labels in `old`'s body numbering, new bodies numbered past
    /// its), with `old`'s shared points carried over to the same bodies.
    pub fn with_shared_of(mut self, old: &Segmentation, raw: &[Option<usize>]) -> Self {
        self.shared = Self::carried_shared(raw, &old.shared, &self);
        self
    }

    /// `self.shared` with each membership's body taken from `old` numbering (the bodies of
    /// `raw`, which `out` was built from) to `out`'s: each old body becomes the body of one of
    /// its first-body points in `out`. Memberships in a body left with no such point, or in
    /// the point's own body, are dropped.
    fn carried_shared(
        raw: &[Option<usize>],
        shared: &[(usize, usize)],
        out: &Self,
    ) -> Vec<(usize, usize)> {
        let new_of = |old: usize| {
            raw.iter()
                .position(|l| *l == Some(old))
                .and_then(|q| out.body_of(q))
        };
        let mut carried: Vec<(usize, usize)> = shared
            .iter()
            .filter_map(|&(p, old)| {
                let b = new_of(old)?;
                (out.body_of(p).is_some_and(|own| own != b)).then_some((p, b))
            })
            .collect();
        carried.sort_unstable();
        carried.dedup();
        carried
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
        let grouped: Vec<(usize, usize)> = self
            .shared
            .iter()
            .map(|&(p, b)| (p, group_of_body[b]))
            .collect();
        out.shared = Self::carried_shared(&raw, &grouped, &out);
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
        let mut shared: Vec<(usize, usize)> =
            self.shared.iter().map(|&(p, b)| (p, new_id[b])).collect();
        shared.sort_unstable();
        Self {
            labels: self.labels.iter().map(|l| l.map(|b| new_id[b])).collect(),
            n_bodies: self.n_bodies,
            discarded_groups: self.discarded_groups.clone(),
            shared,
        }
    }

    /// The same partition, its numbering kept, on `n_points` points: point `k` of `self`
    /// becomes point `index[k]` (its discarded groups and shared points with it), and each
    /// `(point, body)` of `extra` joins `body`. Points named by neither are on no body.
    /// `index` must hold distinct points below `n_points`, `extra` others, and every body
    /// of `extra` must exist; `None` otherwise.
    pub fn on_points(
        &self,
        n_points: usize,
        index: &[usize],
        extra: &[(usize, usize)],
    ) -> Option<Self> {
        if index.len() != self.labels.len() {
            return None;
        }
        let mut labels: Vec<Option<usize>> = vec![None; n_points];
        let mut named = vec![false; n_points];
        for (&i, &l) in index.iter().zip(&self.labels) {
            if std::mem::replace(named.get_mut(i)?, true) {
                return None;
            }
            labels[i] = l;
        }
        for &(i, b) in extra {
            if b >= self.n_bodies || std::mem::replace(named.get_mut(i)?, true) {
                return None;
            }
            labels[i] = Some(b);
        }
        let mut shared: Vec<(usize, usize)> =
            self.shared.iter().map(|&(p, b)| (index[p], b)).collect();
        shared.sort_unstable();
        let mut discarded_groups: Vec<Vec<usize>> = self
            .discarded_groups
            .iter()
            .map(|g| {
                let mut g: Vec<usize> = g.iter().map(|&p| index[p]).collect();
                g.sort_unstable();
                g
            })
            .collect();
        discarded_groups.sort();
        Some(Self {
            labels,
            n_bodies: self.n_bodies,
            discarded_groups,
            shared,
        })
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
    /// discarded groups. A shared point whose first body is dropped keeps its second as its
    /// first.
    fn keeping(&self, keep: impl Fn(usize, usize) -> bool) -> Self {
        let mut raw: Vec<Option<usize>> = self
            .labels
            .iter()
            .enumerate()
            .map(|(i, l)| l.filter(|&b| keep(i, b)))
            .collect();
        let mut second = Vec::new();
        for &(p, b) in &self.shared {
            if !keep(p, b) {
                continue;
            }
            if raw[p].is_none() {
                raw[p] = Some(b);
            } else {
                second.push((p, b));
            }
        }
        let mut out = Self::from_raw(&raw, 0);
        out.discarded_groups.clone_from(&self.discarded_groups);
        out.shared = Self::carried_shared(&raw, &second, &out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_partition_spread_over_more_points_keeps_its_numbering() {
        let mut seg = Segmentation::from_raw(&[Some(1), Some(0), Some(1), None], 1);
        seg.discarded_groups = vec![vec![3]];
        let seg = seg.with_shared(&[(2, 1)]);
        let wide = seg
            .on_points(8, &[6, 1, 3, 0], &[(5, 0), (7, 1)])
            .expect("fits");
        assert_eq!(
            wide.labels(),
            &[
                None,
                Some(1),
                None,
                Some(0),
                None,
                Some(0),
                Some(0),
                Some(1)
            ]
        );
        assert_eq!(wide.shared(), &[(3, 1)]);
        assert_eq!(wide.discarded_groups, vec![vec![0]]);
        assert!(
            seg.on_points(8, &[6, 1, 3], &[]).is_none(),
            "index too short"
        );
        assert!(
            seg.on_points(8, &[6, 1, 3, 0], &[(6, 0)]).is_none(),
            "named twice"
        );
        assert!(
            seg.on_points(8, &[6, 1, 3, 0], &[(5, 2)]).is_none(),
            "no body 2"
        );
        assert!(
            seg.on_points(4, &[6, 1, 3, 0], &[]).is_none(),
            "out of range"
        );
    }

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
    fn shared_points_follow_their_bodies_through_every_edit() {
        // Body 0: points 0-2; body 1: points 3-5; point 2 shared with body 1.
        let seg = Segmentation::from_raw(
            &[Some(0), Some(0), Some(0), Some(1), Some(1), Some(1), None],
            1,
        )
        .with_shared(&[(2, 1), (2, 0), (6, 0), (3, 7)]);
        assert_eq!(
            seg.shared(),
            &[(2, 1)],
            "own body, unassigned, unknown body left out"
        );
        assert_eq!(seg.members(), vec![vec![0, 1, 2], vec![2, 3, 4, 5]]);
        // Renumbered: body 1 first.
        let turned = seg.renumbered(&[1, 0]).expect("permutation");
        assert_eq!(turned.shared(), &[(2, 0)]);
        // Dropping body 0 keeps point 2 on body 1 as its first body.
        let dropped = seg.without_bodies(&[0]);
        assert_eq!(dropped.body_of(2), Some(0));
        assert!(dropped.shared().is_empty());
        assert_eq!(dropped.members(), vec![vec![2, 3, 4, 5]]);
        // Dropping body 1 drops the membership.
        assert!(seg.without_bodies(&[1]).shared().is_empty());
        // Taking point 2 off takes both memberships.
        let off = seg.without_points(&[2]);
        assert!(off.shared().is_empty() && off.body_of(2).is_none());
        // Merging the two bodies leaves point 2 once.
        let merged = seg.merged(&[0, 0]);
        assert!(merged.shared().is_empty());
        assert_eq!(merged.members(), vec![vec![0, 1, 2, 3, 4, 5]]);
        // Merging body 1 with a third body carries the membership to the merged body.
        let three = Segmentation::from_raw(
            &[
                Some(0),
                Some(0),
                Some(0),
                Some(1),
                Some(1),
                Some(1),
                Some(2),
            ],
            1,
        )
        .with_shared(&[(2, 1)]);
        let joined = three.merged(&[5, 9, 9]);
        assert_eq!(joined.shared(), &[(2, 1)]);
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
