//! Small statistical helpers shared by the stage crates.

/// Upper quantile of `chi^2_k / k` at `z` standard normal deviations (Wilson-Hilferty); `k`
/// below 1 is taken as 1.
pub fn chi2_per_dof_quantile(k: f64, z: f64) -> f64 {
    let c = 2.0 / (9.0 * k.max(1.0));
    (1.0 - c + z * c.sqrt()).powi(3)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against tabulated quantiles of chi-square: chi2_100 at p = 0.99 (z = 2.326) is 135.8,
    /// chi2_10 at p = 0.95 (z = 1.645) is 18.31.
    #[test]
    fn matches_tabulated_quantiles() {
        assert!((chi2_per_dof_quantile(100.0, 2.326) * 100.0 - 135.8).abs() < 0.3);
        assert!((chi2_per_dof_quantile(10.0, 1.645) * 10.0 - 18.31).abs() < 0.1);
    }
}
