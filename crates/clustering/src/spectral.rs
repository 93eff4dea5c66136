//! Spectral clustering on the dissimilarity matrix: affinity graph, normalised Laplacian
//! eigenvectors (faer), number of bodies from the eigengap, k-means on the embedding.

use kinetree_core::{
    Clustering, ClusteringInput, DissimilarityMatrix, Error, MIN_BODY_POINTS, Result, Segmentation,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Which k-means the spectral clusterer runs on its embedding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KMeansImpl {
    /// kinetree's own Lloyd iterations (the default; faster, the same labels on the sweeps).
    #[default]
    Kinetree,
    /// linfa-clustering's `KMeans`.
    Linfa,
}

/// Parameters of [`Spectral`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpectralParams {
    /// Dissimilarity at which the affinity is one half; `None` uses the measure's suggested cut.
    pub cut: Option<f64>,
    /// Width of the logistic step from affinity 1 to 0, as a fraction of `cut`.
    pub width: f64,
    /// Use exactly this many clusters instead of the eigengap.
    pub n_clusters: Option<usize>,
    /// The eigengap looks at most this many clusters.
    pub max_clusters: usize,
    /// The k-means implementation (default `kinetree`; `linfa` runs linfa-clustering's).
    pub kmeans: KMeansImpl,
    /// k-means restarts (k-means++ seeding each); the lowest inertia wins.
    pub kmeans_restarts: usize,
    /// A linfa k-means run stops when its centroids move less than this (default 1e-6; the
    /// rows have unit length); kinetree's stops when no label changes.
    pub kmeans_tolerance: f64,
    /// ... or after this many iterations (default 300).
    pub kmeans_max_iterations: usize,
    /// Clusters with fewer points are discarded (at least 3, the minimum for a pose).
    pub min_points: usize,
    /// Up to this many points the eigenvectors come from a dense eigendecomposition, above it
    /// from subspace iteration (default [`DENSE_LIMIT`]).
    pub dense_limit: usize,
}

impl Default for SpectralParams {
    fn default() -> Self {
        Self {
            cut: None,
            width: 0.05,
            n_clusters: None,
            max_clusters: 40,
            kmeans: KMeansImpl::Kinetree,
            kmeans_restarts: 10,
            kmeans_tolerance: 1e-6,
            kmeans_max_iterations: 300,
            min_points: MIN_BODY_POINTS,
            dense_limit: DENSE_LIMIT,
        }
    }
}

impl SpectralParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-finite or non-positive `cut` or `width`, zero
    /// clusters, `max_clusters` beyond 100000, `min_points < 3`, or restarts, tolerance or
    /// iterations out of range.
    pub fn validate(&self) -> Result<()> {
        let bad = |name: &str, message: String| {
            Err(Error::InvalidParameter {
                name: name.into(),
                message,
            })
        };
        check_embedding(&self.embedding(), self.min_points)?;
        kinetree_core::limits::check_count("kmeans_restarts", self.kmeans_restarts, 1, 10_000)?;
        if !(self.kmeans_tolerance.is_finite() && self.kmeans_tolerance > 0.0) {
            return bad(
                "kmeans_tolerance",
                format!("must be finite and positive, got {}", self.kmeans_tolerance),
            );
        }
        kinetree_core::limits::check_count(
            "kmeans_max_iterations",
            self.kmeans_max_iterations,
            1,
            1_000_000,
        )?;
        Ok(())
    }

    /// The embedding settings of these parameters.
    /// The embedding parameters among these.
    pub fn embedding(&self) -> EmbeddingParams {
        EmbeddingParams {
            cut: self.cut,
            width: self.width,
            n_clusters: self.n_clusters,
            max_clusters: self.max_clusters,
            dense_limit: self.dense_limit,
        }
    }
}

/// Spectral clustering (Ng, Jordan and Weiss 2001) on the precomputed matrix.
///
/// - Affinity `w_ij = 1 / (1 + exp((d_ij - cut) / (width * cut)))`: about 1 for pairs the
///   measure calls rigid, about 0 beyond its cut, and exactly 0 from `TAIL_WIDTHS` widths
///   beyond it. Measured on 200 general-position mechanisms of 2-12 bodies (1 mm, 30 %
///   occlusion, ARI = 1): 191/200 at width 0.05 with the zero tail, 191 at 0.01 (192 at 0.05
///   without the tail, which fails on large scenes); only the wider step keeps a link that
///   swings 5 deg apart from the base (tests/tests/segmentation.rs), and 0.2 loses it again.
///   A pair never seen together has no affinity; the graph's connectivity through third
///   points does the transitive inference that [`crate::fill_unknown`] does for the
///   hierarchical clusterer.
/// - The smallest eigenvalues of the normalised Laplacian `I - D^-1/2 W D^-1/2`: a body is a
///   block of the graph, so there are as many eigenvalues near 0 as bodies, and the number of
///   clusters is where the gap between consecutive eigenvalues is largest (at most
///   `max_clusters`), unless `n_clusters` is given.
/// - k-means with k-means++ seeding on the row-normalised eigenvectors, `kmeans_restarts`
///   times from the input seed; the lowest inertia wins (kinetree's own, or with
///   `kmeans = "linfa"` linfa-clustering's `KMeans`).
///
/// Points with no affinity to anything stay unassigned. The eigenvectors come from faer: a
/// dense symmetric eigendecomposition up to `dense_limit` points, above that block subspace
/// iteration on `I + D^-1/2 W D^-1/2` (whose largest eigenvalues are the ones we need) from a
/// fixed start, so the result is deterministic.
///
/// The same embedding feeds [`crate::SpectralGmm`] and [`crate::SpectralDbscan`].
#[derive(Debug, Clone)]
pub struct Spectral {
    params: SpectralParams,
}

/// The affinity is exactly zero beyond `cut + TAIL_WIDTHS * width * cut` (where the logistic
/// is under 2 %): in a scene of thousands of points the clearly moving pairs, each with a
/// small tail value, would otherwise add up to more than a 3-point body's own degree.
const TAIL_WIDTHS: f64 = 4.0;

/// Default of [`SpectralParams::dense_limit`]: above this many points subspace iteration
/// replaces the dense eigendecomposition (measured: dense is faster at N = 1000, 0.2 s against
/// 1.7 s; `docs/decisions.md`).
pub const DENSE_LIMIT: usize = 1200;

/// Most rounds of subspace iteration.
const MAX_ROUNDS: usize = 300;

impl Spectral {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SpectralParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Clustering for Spectral {
    fn name(&self) -> &str {
        "spectral"
    }

    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
        cluster_embedding(
            input.dissimilarity,
            &self.params.embedding(),
            self.params.min_points,
            |e| {
                Ok(kmeans(e, &self.params, input.seed)?
                    .into_iter()
                    .map(Some)
                    .collect())
            },
        )
    }
}

/// The checks shared by the spectral stages' parameters: the embedding's and `min_points`.
///
/// # Errors
/// [`Error::InvalidParameter`] naming the parameter.
pub(crate) fn check_embedding(s: &EmbeddingParams, min_points: usize) -> Result<()> {
    let bad = |name: &str, message: String| {
        Err(Error::InvalidParameter {
            name: name.into(),
            message,
        })
    };
    if let Some(c) = s.cut
        && !(c.is_finite() && c > 0.0)
    {
        return bad("cut", format!("must be finite and positive, got {c}"));
    }
    if !(s.width.is_finite() && s.width > 0.0) {
        return bad(
            "width",
            format!("must be finite and positive, got {}", s.width),
        );
    }
    if s.n_clusters == Some(0) {
        return bad("n_clusters", "must be at least 1".into());
    }
    kinetree_core::limits::check_count("max_clusters", s.max_clusters, 1, 100_000)?;
    if min_points < MIN_BODY_POINTS {
        return bad(
            "min_points",
            format!("must be at least {MIN_BODY_POINTS}, got {min_points}"),
        );
    }
    Ok(())
}

/// The spectral embedding's parameters (the affinity, the eigenvectors and the eigengap),
/// shared by the spectral stages: flat in [`SpectralParams`], the `embedding` table of
/// [`crate::SpectralGmmParams`] and [`crate::SpectralDbscanParams`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmbeddingParams {
    /// As [`SpectralParams::cut`].
    pub cut: Option<f64>,
    /// As [`SpectralParams::width`] (default 0.05).
    pub width: f64,
    /// As [`SpectralParams::n_clusters`]: the embedding's dimension instead of the eigengap's
    /// count.
    pub n_clusters: Option<usize>,
    /// As [`SpectralParams::max_clusters`] (default 40).
    pub max_clusters: usize,
    /// As [`SpectralParams::dense_limit`] (default 1200).
    pub dense_limit: usize,
}

impl Default for EmbeddingParams {
    fn default() -> Self {
        SpectralParams::default().embedding()
    }
}

/// The row-normalised spectral embedding of the points with any affinity.
#[derive(Debug, Clone)]
pub(crate) struct Embedding {
    /// Points of the matrix.
    pub(crate) n_points: usize,
    /// The points embedded (the others have no affinity to anything and stay unassigned).
    pub(crate) keep: Vec<usize>,
    /// Their rows, `keep.len() x dim`, row-major, each of unit length (or zero).
    pub(crate) rows: Vec<f64>,
    /// The embedding's dimension: the number of clusters, from the eigengap or `n_clusters`.
    pub(crate) dim: usize,
}

impl Embedding {
    /// The rows as an ndarray matrix, for linfa.
    ///
    /// # Errors
    /// [`Error::Numerical`] when the rows do not fill the shape (never, by construction).
    #[cfg(feature = "linfa")]
    pub(crate) fn records(&self) -> Result<ndarray::Array2<f64>> {
        ndarray::Array2::from_shape_vec((self.keep.len(), self.dim), self.rows.clone())
            .map_err(|e| Error::Numerical(format!("spectral embedding: {e}")))
    }

    /// A label per point of the matrix from a label per embedded row (`None` for points not
    /// embedded).
    pub(crate) fn labels_of_all(
        &self,
        labels: impl Iterator<Item = Option<usize>>,
    ) -> Vec<Option<usize>> {
        let mut raw = vec![None; self.n_points];
        for (&i, l) in self.keep.iter().zip(labels) {
            raw[i] = l;
        }
        raw
    }
}

/// Clusters `m` on its spectral embedding: `label_rows` labels each embedded row (`None`:
/// unassigned), points with no affinity stay unassigned, and clusters under `min_points`
/// points are discarded.
///
/// # Errors
/// As [`embed`], and `label_rows`'s.
pub(crate) fn cluster_embedding(
    m: &DissimilarityMatrix,
    s: &EmbeddingParams,
    min_points: usize,
    label_rows: impl FnOnce(&Embedding) -> Result<Vec<Option<usize>>>,
) -> Result<Segmentation> {
    let raw = match embed(m, s)? {
        Embedded::Trivial(raw) => raw,
        Embedded::Rows(e) => {
            let labels = label_rows(&e)?;
            e.labels_of_all(labels.into_iter())
        }
    };
    Ok(Segmentation::from_raw(&raw, min_points))
}

/// The affinity graph's embedding, or the labels when at most one point has any affinity.
#[derive(Debug, Clone)]
pub(crate) enum Embedded {
    /// Labels of every point (nothing to embed).
    Trivial(Vec<Option<usize>>),
    /// The embedding.
    Rows(Embedding),
}

/// The affinity of every pair, the normalised Laplacian's smallest eigenvectors, the number of
/// clusters (eigengap, or `n_clusters`), and the row-normalised embedding on that many
/// eigenvectors.
///
/// # Errors
/// The matrix checks' errors; [`Error::InvalidParameter`] for a cut that cannot scale the
/// affinity; [`Error::Degenerate`] when the eigenvectors cannot be found.
pub(crate) fn embed(m: &DissimilarityMatrix, s: &EmbeddingParams) -> Result<Embedded> {
    let n = m.n_points;
    crate::check_matrix(m)?;
    let cut = s.cut.unwrap_or(m.suggested_cut);
    if !(cut.is_finite() && cut > 0.0) {
        return Err(Error::InvalidParameter {
            name: "cut".into(),
            message: format!(
                "the measure's suggested cut {cut} cannot scale an affinity; set `cut`"
            ),
        });
    }
    let width = s.width * cut;
    // Dense affinity over all points, then restricted to those with any affinity.
    let mut w = vec![0.0f64; n * n];
    for i in 0..n {
        for j in i + 1..n {
            if let Some(d) = m.get(i, j)
                && d < cut + TAIL_WIDTHS * width
            {
                let a = 1.0 / (1.0 + ((d - cut) / width).exp());
                w[i * n + j] = a;
                w[j * n + i] = a;
            }
        }
    }
    let degree: Vec<f64> = (0..n).map(|i| w[i * n..(i + 1) * n].iter().sum()).collect();
    let keep: Vec<usize> = (0..n).filter(|&i| degree[i] > 1e-9).collect();
    let k_pts = keep.len();
    if k_pts <= 1 {
        let mut raw = vec![None; n];
        if let Some(&i) = keep.first() {
            raw[i] = Some(0);
        }
        return Ok(Embedded::Trivial(raw));
    }
    let inv_sqrt: Vec<f64> = keep.iter().map(|&i| 1.0 / degree[i].sqrt()).collect();
    // Shifted normalised affinity I + D^-1/2 W D^-1/2: eigenvalues in [0, 2], the
    // Laplacian's smallest at the top.
    let shifted = faer::Mat::<f64>::from_fn(k_pts, k_pts, |a, b| {
        let v = w[keep[a] * n + keep[b]] * inv_sqrt[a] * inv_sqrt[b];
        if a == b { 1.0 + v } else { v }
    });
    drop(w);
    let n_eig = (s.n_clusters.unwrap_or(s.max_clusters) + 1).min(k_pts);
    let (lap_values, vectors) = smallest_laplacian_eigen(&shifted, n_eig, s.dense_limit)?;
    let dim = match s.n_clusters {
        Some(c) => c.min(k_pts),
        None => eigengap(&lap_values),
    };
    // Row-normalised embedding on the first `dim` eigenvectors.
    let mut rows = vec![0.0f64; k_pts * dim];
    for a in 0..k_pts {
        let row = &mut rows[a * dim..(a + 1) * dim];
        for (c, x) in row.iter_mut().enumerate() {
            *x = vectors[c][a];
        }
        let norm = row.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > 0.0 {
            row.iter_mut().for_each(|x| *x /= norm);
        }
    }
    Ok(Embedded::Rows(Embedding {
        n_points: n,
        keep,
        rows,
        dim,
    }))
}

/// The `count` smallest eigenvalues of the Laplacian `2 I - shifted` (ascending) and their
/// eigenvectors (one `Vec` per eigenvalue).
fn smallest_laplacian_eigen(
    shifted: &faer::Mat<f64>,
    count: usize,
    dense_limit: usize,
) -> Result<(Vec<f64>, Vec<Vec<f64>>)> {
    let n = shifted.nrows();
    let failed = |what: &str| Error::Degenerate(format!("spectral clustering: {what}"));
    let mut pairs: Vec<(f64, Vec<f64>)> = if n <= dense_limit {
        let evd = shifted
            .self_adjoint_eigen(faer::Side::Lower)
            .map_err(|e| failed(&format!("eigendecomposition failed ({e:?})")))?;
        let s = evd.S().column_vector();
        let u = evd.U();
        (0..n)
            .map(|c| (2.0 - s[c], (0..n).map(|r| u[(r, c)]).collect()))
            .collect()
    } else {
        subspace_iteration(shifted, count)?
            .into_iter()
            .map(|(v, x)| (2.0 - v, x))
            .collect()
    };
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    pairs.truncate(count);
    Ok(pairs.into_iter().unzip())
}

/// The `count` largest eigenpairs of the symmetric positive semi-definite `a` by block subspace
/// iteration with a Rayleigh-Ritz step each round.
///
/// A body is a block of the affinity graph, so the eigenvalues we need come in near-exact
/// multiples (one per body). A single-vector Krylov method (faer's
/// `partial_self_adjoint_eigen`) resolves such clusters only through rounding: on 9 blocks of
/// 3-100 points it ran for over ten minutes. A block of `count + 8` vectors sees the whole
/// cluster at once. Convergence goes as the ratio of the bulk eigenvalues (about 1 for
/// `I + D^-1/2 W D^-1/2`) to the body ones (about 2), so a few dozen rounds.
fn subspace_iteration(a: &faer::Mat<f64>, count: usize) -> Result<Vec<(f64, Vec<f64>)>> {
    let n = a.nrows();
    let b = (count + 8).min(n);
    // A fixed pseudo-random start: deterministic, and in general position to every block.
    let mut q = faer::Mat::<f64>::from_fn(n, b, |i, j| {
        let h = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64 + 1).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        (h >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    })
    .qr()
    .compute_thin_Q();
    let mut previous = vec![f64::INFINITY; count];
    for _ in 0..MAX_ROUNDS {
        // One product per round: Ritz pairs of span(q) from z = A q, then q <- orth(z u).
        let z = a * &q;
        let h = q.transpose() * &z;
        let evd = h.self_adjoint_eigen(faer::Side::Lower).map_err(|e| {
            Error::Degenerate(format!("spectral clustering: Ritz step failed ({e:?})"))
        })?;
        let s = evd.S().column_vector();
        // faer sorts ascending; the largest first here.
        let order: Vec<usize> = (0..b).rev().take(count).collect();
        let ritz: Vec<f64> = order.iter().map(|&c| s[c]).collect();
        // Body eigenvalues (above 1.5, a Laplacian eigenvalue under 0.5) must settle tightly;
        // the bulk near 1 converges slowly and only has to be told apart from them.
        let converged = ritz.iter().zip(&previous).all(|(x, y)| {
            let tol = if *x > 1.5 { 1e-10 } else { 1e-4 };
            (x - y).abs() <= tol
        });
        previous = ritz;
        let u = evd.U();
        if converged {
            let x = &q * u;
            return Ok(order
                .iter()
                .map(|&c| (s[c], (0..n).map(|r| x[(r, c)]).collect()))
                .collect());
        }
        q = (&z * u).qr().compute_thin_Q();
    }
    Err(Error::Degenerate(format!(
        "spectral clustering: the eigenvectors did not converge in {MAX_ROUNDS} rounds"
    )))
}

/// Number of clusters from ascending Laplacian eigenvalues: `k` maximising
/// `lambda_k - lambda_{k-1}` (0-based), so that `k` eigenvalues lie below the largest gap.
/// With a single eigenvalue, one cluster.
fn eigengap(values: &[f64]) -> usize {
    let mut best = (1, f64::NEG_INFINITY);
    for k in 1..values.len() {
        let gap = values[k] - values[k - 1];
        if gap > best.1 {
            best = (k, gap);
        }
    }
    best.0
}

/// k-means on the embedding's rows into `dim` clusters (at most one per row) with the
/// implementation `p.kmeans` names. Returns a label per row.
///
/// # Errors
/// [`Error::Numerical`] when linfa's fit fails.
pub(crate) fn kmeans(e: &Embedding, p: &SpectralParams, seed: u64) -> Result<Vec<usize>> {
    let n = e.keep.len();
    let k = e.dim.min(n);
    if k <= 1 {
        return Ok(vec![0; n]);
    }
    match p.kmeans {
        KMeansImpl::Kinetree => Ok(kmeans_kinetree(
            &e.rows,
            e.dim,
            k,
            p.kmeans_restarts,
            p.kmeans_max_iterations,
            seed,
        )),
        #[cfg(feature = "linfa")]
        KMeansImpl::Linfa => kmeans_linfa(
            e,
            k,
            p.kmeans_restarts,
            p.kmeans_tolerance,
            p.kmeans_max_iterations,
            seed,
        ),
        #[cfg(not(feature = "linfa"))]
        KMeansImpl::Linfa => Err(Error::Config(
            "clustering.kmeans = \"linfa\" needs kinetree-clustering's `linfa` feature".into(),
        )),
    }
}

/// k-means (Lloyd) into `k` clusters of rows of dimension `dim` stored row-major, with
/// k-means++ seeding, `restarts` runs from a `ChaCha8` stream seeded by `seed`, each until no
/// label changes or `max_iterations`; the lowest inertia wins (ties to the earliest run).
/// Returns a label per row.
///
/// Written here although linfa-clustering has `KMeans` ([`kmeans_linfa`]): in one run of the
/// clustering bench the spectral stage took 2.0 times as long with linfa's at 1000 points and
/// 1.27 times at 3000, with the same labels on every run of the noise-and-clusterers sweep
/// (`docs/decisions.md`, `clustering.spectral.kmeans`).
fn kmeans_kinetree(
    rows: &[f64],
    dim: usize,
    k: usize,
    restarts: usize,
    max_iterations: usize,
    seed: u64,
) -> Vec<usize> {
    let n = rows.len() / dim.max(1);
    if k <= 1 || n <= 1 {
        return vec![0; n];
    }
    let row = |i: usize| &rows[i * dim..(i + 1) * dim];
    let dist2 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut best: Option<(f64, Vec<usize>)> = None;
    for _ in 0..restarts {
        // k-means++ seeding.
        let mut centres: Vec<f64> = Vec::with_capacity(k * dim);
        centres.extend_from_slice(row(rng.random_range(0..n)));
        let mut nearest: Vec<f64> = (0..n).map(|i| dist2(row(i), &centres[..dim])).collect();
        for c in 1..k.min(n) {
            let total: f64 = nearest.iter().sum();
            let pick = if total > 0.0 {
                let mut target = rng.random::<f64>() * total;
                let mut chosen = n - 1;
                for (i, &d) in nearest.iter().enumerate() {
                    if target < d {
                        chosen = i;
                        break;
                    }
                    target -= d;
                }
                chosen
            } else {
                rng.random_range(0..n)
            };
            centres.extend_from_slice(row(pick));
            let new = &centres[c * dim..(c + 1) * dim];
            for (i, d) in nearest.iter_mut().enumerate() {
                *d = d.min(dist2(row(i), new));
            }
        }
        let kc = centres.len() / dim;
        let mut labels = vec![0usize; n];
        let mut inertia = f64::INFINITY;
        for _ in 0..max_iterations {
            let mut changed = false;
            inertia = 0.0;
            for (i, l) in labels.iter_mut().enumerate() {
                let (arg, d) = (0..kc)
                    .map(|c| (c, dist2(row(i), &centres[c * dim..(c + 1) * dim])))
                    .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
                if arg != *l {
                    *l = arg;
                    changed = true;
                }
                inertia += d;
            }
            let mut sums = vec![0.0f64; kc * dim];
            let mut counts = vec![0usize; kc];
            for (i, &l) in labels.iter().enumerate() {
                counts[l] += 1;
                for (s, x) in sums[l * dim..(l + 1) * dim].iter_mut().zip(row(i)) {
                    *s += x;
                }
            }
            for c in 0..kc {
                if counts[c] > 0 {
                    for t in 0..dim {
                        centres[c * dim + t] = sums[c * dim + t] / counts[c] as f64;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        if best.as_ref().is_none_or(|b| inertia < b.0) {
            best = Some((inertia, labels));
        }
    }
    best.map(|b| b.1).unwrap_or_else(|| vec![0; n])
}

/// k-means with linfa-clustering's `KMeans` into `k` clusters of the embedding's rows:
/// k-means++ seeding, `restarts` runs from a `Xoshiro256Plus` stream seeded by `seed`, the
/// lowest inertia wins; each run stops when the centroids move less than `tolerance` or after
/// `max_iterations`. Returns a label per row.
///
/// # Errors
/// [`Error::Numerical`] with linfa's error when the fit fails.
#[cfg(feature = "linfa")]
fn kmeans_linfa(
    e: &Embedding,
    k: usize,
    restarts: usize,
    tolerance: f64,
    max_iterations: usize,
    seed: u64,
) -> Result<Vec<usize>> {
    use linfa::prelude::{Fit, Predict};
    use rand_xoshiro::rand_core::SeedableRng;
    let data = linfa::DatasetBase::from(e.records()?);
    let model = linfa_clustering::KMeans::params_with_rng(
        k,
        rand_xoshiro::Xoshiro256Plus::seed_from_u64(seed),
    )
    .n_runs(restarts)
    .tolerance(tolerance)
    .max_n_iterations(max_iterations as u64)
    .init_method(linfa_clustering::KMeansInit::KMeansPlusPlus)
    .fit(&data)
    .map_err(|err| Error::Numerical(format!("spectral clustering's k-means: {err}")))?;
    Ok(model.predict(data.records()).to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{blocks, same_partition};

    #[test]
    fn subspace_iteration_matches_the_dense_eigendecomposition() {
        // Nine blocks: nine eigenvalues near 2, which a single-vector Krylov method misses.
        let (m, _) = blocks(&[3, 10, 30, 60, 80, 90, 100, 70, 57]);
        let n = m.n_points;
        let w = |i: usize, j: usize| {
            m.get(i, j)
                .map_or(0.0, |d| 1.0 / (1.0 + ((d - 0.8) / 0.04).exp()))
        };
        let degree: Vec<f64> = (0..n)
            .map(|i| (0..n).filter(|&j| j != i).map(|j| w(i, j)).sum())
            .collect();
        let shifted = faer::Mat::<f64>::from_fn(n, n, |a, b| {
            if a == b {
                1.0
            } else {
                w(a, b) / (degree[a] * degree[b]).sqrt()
            }
        });
        let count = 12;
        let fast = subspace_iteration(&shifted, count).expect("converges");
        let dense = shifted.self_adjoint_eigen(faer::Side::Lower).expect("evd");
        let s = dense.S().column_vector();
        for (c, (value, vector)) in fast.iter().enumerate() {
            let truth = s[n - 1 - c];
            // Body eigenvalues tightly; the bulk only well enough to see the gap.
            let tol = if truth > 1.5 { 1e-8 } else { 1e-2 };
            assert!(
                (value - truth).abs() < tol,
                "eigenvalue {c}: {value} vs {truth}"
            );
            if truth > 1.5 {
                // The vector lies in the dense solution's top-9 space.
                let u = dense.U();
                let proj: f64 = (n - 9..n)
                    .map(|k| (0..n).map(|r| u[(r, k)] * vector[r]).sum::<f64>().powi(2))
                    .sum();
                assert!(
                    proj > 1.0 - 1e-6,
                    "vector {c} outside the body space: {proj}"
                );
            }
        }
    }

    /// With the dense eigendecomposition and, `dense_limit = 0`, with subspace iteration; with
    /// kinetree's k-means and linfa's.
    #[test]
    fn eigengap_finds_the_number_of_blocks() {
        for sizes in [
            vec![3, 5, 8, 13, 21, 40],
            vec![3, 10, 30, 60, 80, 90, 100, 70, 57],
        ] {
            let (m, truth) = blocks(&sizes);
            for (dense_limit, kmeans) in [
                (DENSE_LIMIT, KMeansImpl::Kinetree),
                (0, KMeansImpl::Kinetree),
                (DENSE_LIMIT, KMeansImpl::Linfa),
            ] {
                let s = Spectral::new(SpectralParams {
                    dense_limit,
                    kmeans,
                    ..SpectralParams::default()
                })
                .expect("params");
                let seg = s
                    .cluster(&ClusteringInput {
                        dissimilarity: &m,
                        seed: 1,
                        pair_frames: None,
                    })
                    .expect("clusters");
                assert_eq!(
                    seg.n_bodies(),
                    sizes.len(),
                    "sizes {sizes:?}, {dense_limit}"
                );
                assert!(
                    same_partition(&seg, &truth),
                    "sizes {sizes:?}, {dense_limit}"
                );
            }
        }
    }

    #[test]
    fn kmeans_separates_three_groups_and_depends_only_on_the_seed() {
        // Three groups in three dimensions (the embedding's dimension is the cluster count).
        let rows: Vec<f64> = (0..30)
            .flat_map(|i| {
                let c = (i % 3) as f64 * 10.0;
                [c + (i as f64 * 0.01), -c, 0.0]
            })
            .collect();
        let e = Embedding {
            n_points: 30,
            keep: (0..30).collect(),
            rows,
            dim: 3,
        };
        for kmeans_impl in [KMeansImpl::Kinetree, KMeansImpl::Linfa] {
            let p = SpectralParams {
                kmeans: kmeans_impl,
                kmeans_restarts: 5,
                ..SpectralParams::default()
            };
            let l = kmeans(&e, &p, 3).expect("fits");
            assert_eq!(
                l,
                kmeans(&e, &p, 3).expect("fits"),
                "same seed, same labels"
            );
            for i in 0..30 {
                for j in 0..30 {
                    assert_eq!(
                        l[i] == l[j],
                        i % 3 == j % 3,
                        "{kmeans_impl:?}: rows {i} {j}"
                    );
                }
            }
        }
    }

    #[test]
    fn invalid_parameters_are_typed_errors() {
        for p in [
            SpectralParams {
                width: 0.0,
                ..Default::default()
            },
            SpectralParams {
                cut: Some(f64::NAN),
                ..Default::default()
            },
            SpectralParams {
                n_clusters: Some(0),
                ..Default::default()
            },
            SpectralParams {
                min_points: 2,
                ..Default::default()
            },
        ] {
            assert!(matches!(
                Spectral::new(p),
                Err(Error::InvalidParameter { .. })
            ));
        }
    }
}
