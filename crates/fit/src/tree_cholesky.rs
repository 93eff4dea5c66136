//! Cholesky factorisation of a kinematic tree's normal matrix without fill-in.
//!
//! A frame's fit has one parameter per single-DoF joint and six per freely posed body. A
//! point depends on the parameters on its body's path from a root, so the normal matrix has
//! an entry `(i, j)` only where one of `i`, `j` lies on the other's path: "branch-induced
//! sparsity" (Featherstone, *Efficient factorization of the joint-space inertia matrix*,
//! 2005). With every parameter numbered after the ones above it, eliminating from the last
//! parameter up gives `N = L^T L`, `L` lower triangular with entries only at `(k, i)` for `i`
//! on `k`'s path: no fill-in, `sum over k of depth(k)^2 / 2` products instead of `n^3 / 6`.
//!
//! Written here rather than taken from a library: the order and the pattern are the tree's,
//! known without analysis, and the matrices have tens of rows. nalgebra's dense Cholesky took
//! most of a frame's fit (34 % of discovery on the 21-body scenes, measured with `perf`), and
//! a general sparse factorisation (faer's, behind its `sparse-linalg` feature) would add a
//! symbolic analysis and a compressed-column copy to every call (not measured). On the
//! 21-body scenes discovery took 59 s with this factorisation against 100 s with the dense
//! one.

use kinetree_core::nalgebra::{DMatrix, DVector};

/// The parameters' paths: for each parameter, the ones above it, top first. A parameter's
/// path is its parent's path followed by the parent, so the path of the `i`-th parameter on
/// `k`'s path is the first `i` entries of `k`'s: its row of the factor lines up with the start
/// of `k`'s row, and each elimination step is a run of contiguous updates.
#[derive(Debug, Clone, Default)]
pub(crate) struct TreePattern {
    /// Where each parameter's path (and its packed row) starts in `paths` (and the factor).
    start: Vec<usize>,
    /// Every parameter's path followed by the parameter itself, one after the other.
    paths: Vec<usize>,
}

impl TreePattern {
    /// The pattern of a forest given, for each parameter, the parameter above it (smaller
    /// than it); `None` when a parent does not come first.
    pub(crate) fn new(parent: &[Option<usize>]) -> Option<Self> {
        let mut start = Vec::with_capacity(parent.len() + 1);
        let mut paths = Vec::new();
        for (c, p) in parent.iter().enumerate() {
            start.push(paths.len());
            if let Some(p) = *p {
                if p >= c {
                    return None;
                }
                // p's path and p itself: c's path.
                paths.extend_from_within(start[p]..start[p + 1]);
            }
            paths.push(c);
        }
        start.push(paths.len());
        Some(Self { start, paths })
    }

    /// Number of parameters.
    pub(crate) fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// Parameter `c`'s path followed by `c`.
    fn path(&self, c: usize) -> &[usize] {
        &self.paths[self.start[c]..self.start[c + 1]]
    }
}

/// The factor `L` of `N = L^T L`: row `k` holds `L[k, i]` for the parameters `i` on `k`'s
/// path, in path order, then `L[k, k]`.
pub(crate) struct TreeCholesky<'a> {
    rows: Vec<f64>,
    pattern: &'a TreePattern,
}

impl<'a> TreeCholesky<'a> {
    /// Factors `n` with `diagonal` in place of its diagonal: only its entries `(i, k)` with
    /// `i` on `k`'s path are read (all others must be zero). `None` when the matrix is not
    /// positive definite (a pivot that is not positive and finite) or a size is not the
    /// pattern's.
    pub(crate) fn with_diagonal(
        n: &DMatrix<f64>,
        diagonal: &[f64],
        pattern: &'a TreePattern,
    ) -> Option<Self> {
        let size = pattern.len();
        if n.nrows() != size || n.ncols() != size || diagonal.len() != size {
            return None;
        }
        let mut rows = Vec::with_capacity(pattern.paths.len());
        for (k, column) in n.as_slice().chunks_exact(size.max(1)).enumerate() {
            let path = pattern.path(k);
            rows.extend(path[..path.len() - 1].iter().map(|&i| column[i]));
            rows.push(diagonal[k]);
        }
        for k in (0..size).rev() {
            let (begin, end) = (pattern.start[k], pattern.start[k + 1]);
            let depth = end - begin - 1;
            let d = rows[end - 1];
            if !(d > 0.0 && d.is_finite()) {
                return None;
            }
            let lkk = d.sqrt();
            rows[end - 1] = lkk;
            for v in &mut rows[begin..end - 1] {
                *v /= lkk;
            }
            // The Schur complement on k's path: the row of its i-th parameter `a` is the
            // first i + 1 entries of k's row (a's path, then a).
            let (before, own) = rows.split_at_mut(begin);
            let own = &own[..depth];
            for (i, &a) in pattern.path(k)[..depth].iter().enumerate() {
                let lka = own[i];
                let row_a = &mut before[pattern.start[a]..pattern.start[a] + i + 1];
                for (x, &l) in row_a.iter_mut().zip(&own[..=i]) {
                    *x -= lka * l;
                }
            }
        }
        Some(Self { rows, pattern })
    }

    /// Solves `N x = b`.
    pub(crate) fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let mut x = b.clone();
        self.solve_mut(x.as_mut_slice());
        x
    }

    /// Solves `N x = b` in place (`x` holds `b` on entry), through `L^T y = b`
    /// ([`TreeCholesky::half_solve_mut`]), then `L x = y` from the first parameter down.
    pub(crate) fn solve_mut(&self, x: &mut [f64]) {
        self.half_solve_mut(x);
        let size = self.pattern.len();
        for k in 0..size {
            let (path, row) = self.row(k);
            let dot: f64 = path.iter().zip(row).map(|(&a, &l)| l * x[a]).sum();
            x[k] = (x[k] - dot) / row[path.len()];
        }
    }

    /// Solves `L^T y = b` in place (`y` holds `b` on entry), from the last parameter up:
    /// `b^T N^-1 c = y_b . y_c`. A zero entry changes nothing up its path, so it is passed
    /// over: the bundle adjustment's columns are zero off the parameters that move with
    /// their joint.
    pub(crate) fn half_solve_mut(&self, y: &mut [f64]) {
        for k in (0..self.pattern.len()).rev() {
            let (path, row) = self.row(k);
            let yk = y[k] / row[path.len()];
            y[k] = yk;
            if yk == 0.0 {
                continue;
            }
            for (&a, &l) in path.iter().zip(row) {
                y[a] -= l * yk;
            }
        }
    }

    /// [`TreeCholesky::half_solve_mut`] on every column of `b`.
    pub(crate) fn half_solve_columns_mut(&self, b: &mut DMatrix<f64>) {
        let rows = b.nrows();
        if rows == 0 {
            return;
        }
        for column in b.as_mut_slice().chunks_exact_mut(rows) {
            self.half_solve_mut(column);
        }
    }

    /// Parameter `k`'s path (without `k`) and its row of the factor (with `L[k, k]` last).
    fn row(&self, k: usize) -> (&[usize], &[f64]) {
        let (begin, end) = (self.pattern.start[k], self.pattern.start[k + 1]);
        (&self.pattern.paths[begin..end - 1], &self.rows[begin..end])
    }

    /// The rows of `L^-1`, from which the entries of `N^-1 = L^-1 L^-T` on the pattern
    /// follow ([`TreeInverse`]).
    ///
    /// `L^-1` has `L`'s pattern (a parameter's path is closed under taking paths), so row `i`
    /// is `L^T y = e_i` solved on `i`'s path alone, from `i` up: `depth(i)^2 / 2` products,
    /// the factorisation's cost in all, where a dense inverse takes `n^3 / 3`. The dense
    /// inverse made a frame's fit cubic in the number of bodies: with 2000 keypoints over
    /// five frames split into 334 bodies, it and its factorisation took 93 % of the
    /// discovery's time (`perf`).
    pub(crate) fn inverse(&self) -> TreeInverse<'a> {
        let mut rows = vec![0.0; self.rows.len()];
        for i in 0..self.pattern.len() {
            let path = self.pattern.path(i);
            let z = &mut rows[self.pattern.start[i]..self.pattern.start[i + 1]];
            z[path.len() - 1] = 1.0;
            // Position p on i's path is parameter path[p], whose row of L holds L[path[p],
            // path[q]] for q < p at index q, then its diagonal at index p.
            for (p, &a) in path.iter().enumerate().rev() {
                let row_a = &self.rows[self.pattern.start[a]..self.pattern.start[a + 1]];
                let zp = z[p] / row_a[p];
                z[p] = zp;
                for (x, &l) in z[..p].iter_mut().zip(&row_a[..p]) {
                    *x -= l * zp;
                }
            }
        }
        TreeInverse {
            rows,
            pattern: self.pattern,
        }
    }
}

/// The rows of `L^-1` for a [`TreeCholesky`] factor `N = L^T L`, packed as the factor's: the
/// entries of `N^-1` between a parameter and those on its path.
pub(crate) struct TreeInverse<'a> {
    rows: Vec<f64>,
    pattern: &'a TreePattern,
}

impl TreeInverse<'_> {
    /// `N^-1[c, d]` for `c` on `d`'s path or `c == d`: row `c` of `L^-1` lies on the first
    /// `depth(c) + 1` entries of `d`'s path, so the entry is their dot product there. `None`
    /// when `c` is neither.
    pub(crate) fn entry(&self, c: usize, d: usize) -> Option<f64> {
        let (c, d) = if c <= d { (c, d) } else { (d, c) };
        let row_c = self.row(c);
        let depth = row_c.len() - 1;
        if self.pattern.path(d).get(depth) != Some(&c) {
            return None;
        }
        Some(row_c.iter().zip(self.row(d)).map(|(a, b)| a * b).sum())
    }

    /// `N^-1[i, i]`.
    pub(crate) fn diagonal(&self, i: usize) -> f64 {
        self.row(i).iter().map(|x| x * x).sum()
    }

    /// Row `i` of `L^-1`, on `i`'s path and `i`.
    fn row(&self, i: usize) -> &[f64] {
        &self.rows[self.pattern.start[i]..self.pattern.start[i + 1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random tree-sparse positive definite matrix: the sum of `J^T J` over "points" that
    /// each depend on one parameter's path, plus a diagonal.
    fn tree_matrix(parent: &[Option<usize>], seed: u64) -> DMatrix<f64> {
        let n = parent.len();
        let mut state = seed;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let mut m = DMatrix::<f64>::zeros(n, n);
        for owner in 0..n {
            for _ in 0..3 {
                let mut row = DVector::<f64>::zeros(n);
                let mut i = Some(owner);
                while let Some(a) = i {
                    row[a] = next();
                    i = parent[a];
                }
                m += &row * row.transpose();
            }
        }
        for i in 0..n {
            m[(i, i)] += 0.1;
        }
        m
    }

    /// A root pose's six parameters, two branches of joints below it and a second free body.
    fn forest() -> Vec<Option<usize>> {
        vec![
            None,
            Some(0),
            Some(1),
            Some(2),
            Some(3),
            Some(4),
            Some(5),
            Some(5),
            Some(6),
            Some(7),
            Some(7),
            None,
            Some(11),
            Some(12),
            Some(13),
            Some(14),
            Some(15),
            Some(16),
        ]
    }

    #[test]
    fn solves_as_the_dense_factorisation_does() {
        let parent = forest();
        let pattern = TreePattern::new(&parent).expect("parents first");
        for seed in 0..20 {
            let m = tree_matrix(&parent, seed);
            let b = DVector::from_fn(parent.len(), |i, _| (i as f64 * 0.37 + seed as f64).sin());
            let dense = m.clone().cholesky().expect("positive definite").solve(&b);
            let factor = TreeCholesky::with_diagonal(&m, m.diagonal().as_slice(), &pattern)
                .expect("positive definite");
            let tree = factor.solve(&b);
            assert!(
                (&dense - &tree).amax() < 1e-9 * dense.amax().max(1.0),
                "seed {seed}: {} apart",
                (&dense - &tree).amax()
            );
            // The residual itself, not only agreement with nalgebra.
            assert!((&m * &tree - &b).amax() < 1e-9);
            // Half solves: y_b . y_c = b^T N^-1 c, here with c = 2 b and a column that is
            // zero above the second free body's parameters.
            let c = DVector::from_fn(
                parent.len(),
                |i, _| if i >= 11 { (i as f64).cos() } else { 0.0 },
            );
            let mut halves = DMatrix::from_columns(&[b.clone(), b.map(|v| 2.0 * v), c.clone()]);
            factor.half_solve_columns_mut(&mut halves);
            let bb = b.dot(&tree);
            let bc = c.dot(&tree);
            assert!((halves.column(0).dot(&halves.column(1)) - 2.0 * bb).abs() < 1e-9 * bb.abs());
            assert!((halves.column(0).dot(&halves.column(2)) - bc).abs() < 1e-9 * bb.abs());
        }
    }

    /// The inverse's entries on the pattern agree with nalgebra's dense inverse, and entries
    /// off the pattern are refused.
    #[test]
    fn inverse_entries_on_the_pattern_are_the_dense_inverse() {
        let parent = forest();
        let pattern = TreePattern::new(&parent).expect("parents first");
        for seed in 0..20 {
            let m = tree_matrix(&parent, seed);
            let dense = m.clone().cholesky().expect("positive definite").inverse();
            let factor = TreeCholesky::with_diagonal(&m, m.diagonal().as_slice(), &pattern)
                .expect("positive definite");
            let inverse = factor.inverse();
            let scale = dense.amax();
            for d in 0..parent.len() {
                let got = inverse.diagonal(d);
                assert!(
                    (got - dense[(d, d)]).abs() < 1e-9 * scale,
                    "seed {seed}: ({d}, {d})"
                );
                for c in 0..parent.len() {
                    let on_path = pattern.path(d).contains(&c) || pattern.path(c).contains(&d);
                    match inverse.entry(c, d) {
                        Some(v) => {
                            assert!(on_path, "({c}, {d}) is off the pattern");
                            assert!((v - dense[(c, d)]).abs() < 1e-9 * scale, "({c}, {d})");
                        }
                        None => assert!(!on_path, "({c}, {d}) is on the pattern"),
                    }
                }
            }
        }
    }

    #[test]
    fn refuses_what_it_cannot_factor() {
        let parent = forest();
        let pattern = TreePattern::new(&parent).expect("parents first");
        let mut m = tree_matrix(&parent, 1);
        m[(4, 4)] = -1.0;
        assert!(TreeCholesky::with_diagonal(&m, m.diagonal().as_slice(), &pattern).is_none());
        m[(4, 4)] = f64::NAN;
        assert!(TreeCholesky::with_diagonal(&m, m.diagonal().as_slice(), &pattern).is_none());
        let small = TreePattern::new(&[None, Some(0)]).expect("parents first");
        assert!(TreeCholesky::with_diagonal(&DMatrix::identity(3, 3), &[1.0; 3], &small).is_none());
        assert!(TreePattern::new(&[None, Some(2), Some(1)]).is_none());
    }
}
