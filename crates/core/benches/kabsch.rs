//! Kabsch-Umeyama fits, in fits per second: the whole fit of eight point pairs
//! (`kabsch_8_points`), and the rotation alone from the same fits' cross-covariances by
//! Newton's polar iteration (`rotation/polar`, what `kabsch` uses) and by nalgebra's SVD
//! (`rotation/svd`, its fallback).
//!
//! Run with `cargo bench -p kinetree-core`. Data: 1000 sets of eight points in a 10 cm box,
//! each turned by a random rotation, shifted and given 1 mm of noise, from a fixed seed.

use kinetree_core::geom::{kabsch, kabsch_rotation_by_svd, proper_rotation_of};
use kinetree_core::nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

fn main() {
    divan::main();
}

const SETS: usize = 1000;

type PointSets = Vec<(Vec<Point3<f64>>, Vec<Point3<f64>>)>;

fn point_sets() -> PointSets {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
    (0..SETS)
        .map(|_| {
            let src: Vec<Point3<f64>> = (0..8)
                .map(|_| Point3::new(normal(), normal(), normal()) * 0.05)
                .collect();
            let rot = UnitQuaternion::from_scaled_axis(Vector3::new(normal(), normal(), normal()));
            let shift = Vector3::new(normal(), normal(), normal());
            let dst = src
                .iter()
                .map(|p| rot * p + shift + Vector3::new(normal(), normal(), normal()) * 1e-3)
                .collect();
            (src, dst)
        })
        .collect()
}

fn cross_covariances(sets: &PointSets) -> Vec<Matrix3<f64>> {
    sets.iter()
        .map(|(src, dst)| {
            let n = src.len() as f64;
            let cs = src.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
            let cd = dst.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
            src.iter()
                .zip(dst)
                .map(|(s, d)| (s.coords - cs) * (d.coords - cd).transpose())
                .sum()
        })
        .collect()
}

#[divan::bench]
fn kabsch_8_points(bencher: divan::Bencher) {
    let sets = point_sets();
    bencher
        .counter(divan::counter::ItemsCount::new(SETS))
        .bench(|| {
            sets.iter()
                .filter(|(s, d)| kabsch(divan::black_box(s), d).is_some())
                .count()
        });
}

/// The rotation alone, by `polar` (Newton's iteration) or `svd` (nalgebra's SVD).
#[divan::bench(args = ["polar", "svd"])]
fn rotation(bencher: divan::Bencher, method: &str) {
    let hs = cross_covariances(&point_sets());
    let solve: fn(&Matrix3<f64>) -> Option<Matrix3<f64>> = match method {
        "polar" => proper_rotation_of,
        _ => |h| kabsch_rotation_by_svd(h, 0.0),
    };
    bencher
        .counter(divan::counter::ItemsCount::new(SETS))
        .bench(|| {
            hs.iter()
                .filter_map(|h| solve(divan::black_box(h)))
                .map(|r| r[(0, 0)])
                .sum::<f64>()
        });
}
