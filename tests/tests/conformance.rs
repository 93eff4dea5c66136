//! Every built-in stage through the conformance checks of `kinetree_eval::conformance`.

use kinetree_clustering::{Hierarchical, HierarchicalParams, Linkage};
use kinetree_core::{
    Dissimilarity, DissimilarityInput, DissimilarityMatrix, PoseEstimator, PoseInput, Segmentation,
    Tracks,
};
use kinetree_dissimilarity::{
    DistanceStd, DistanceVariance, FTest, FTestParams, LogPValue, LogPValueParams, SpreadParams,
    pair_stats,
};
use kinetree_dof::{Chi2Rank, Chi2RankParams, SvdRank, SvdRankParams};
use kinetree_eval::conformance::{check_clustering, check_dissimilarity, check_dof, check_pose};
use kinetree_pose::{KabschParams, KabschPoses};

fn q_matrix(tracks: &Tracks) -> DissimilarityMatrix {
    let stats = pair_stats(tracks);
    FTest::new(FTestParams::default())
        .and_then(|f| {
            f.compute(&DissimilarityInput {
                tracks,
                stats: &stats,
                noise_sigma_m: 0.001,
            })
        })
        .expect("q")
}

fn kabsch_poses(tracks: &Tracks, seg: &Segmentation) -> kinetree_core::BodyPoses {
    KabschPoses::new(KabschParams::default())
        .and_then(|k| {
            k.estimate(&PoseInput {
                tracks,
                segmentation: seg,
                noise_sigma_m: 0.001,
            })
        })
        .expect("poses")
}

#[test]
fn dissimilarities_conform() {
    let stages: Vec<Box<dyn Dissimilarity>> = vec![
        Box::new(FTest::new(FTestParams::default()).expect("params")),
        Box::new(LogPValue::new(LogPValueParams::default()).expect("params")),
        Box::new(DistanceStd::new(SpreadParams::default()).expect("params")),
        Box::new(DistanceVariance::new(SpreadParams::default()).expect("params")),
    ];
    for s in &stages {
        let v = check_dissimilarity(s.as_ref(), &pair_stats);
        assert!(v.is_empty(), "{}: {v:?}", s.name());
    }
}

#[test]
fn clusterers_conform() {
    for linkage in [
        Linkage::Single,
        Linkage::Complete,
        Linkage::Average,
        Linkage::Weighted,
        Linkage::Ward,
    ] {
        let stage = Hierarchical::new(HierarchicalParams {
            linkage,
            ..HierarchicalParams::default()
        })
        .expect("params");
        let v = check_clustering(&stage, &q_matrix);
        assert!(v.is_empty(), "{linkage:?}: {v:?}");
    }
    let dbscan = kinetree_clustering::Dbscan::new(kinetree_clustering::DbscanParams::default())
        .expect("params");
    let v = check_clustering(&dbscan, &q_matrix);
    assert!(v.is_empty(), "dbscan: {v:?}");
    let spectral =
        kinetree_clustering::Spectral::new(kinetree_clustering::SpectralParams::default())
            .expect("params");
    let v = check_clustering(&spectral, &q_matrix);
    assert!(v.is_empty(), "spectral: {v:?}");
    let linfa_kmeans = kinetree_clustering::Spectral::new(kinetree_clustering::SpectralParams {
        kmeans: kinetree_clustering::KMeansImpl::Linfa,
        ..Default::default()
    })
    .expect("params");
    let v = check_clustering(&linfa_kmeans, &q_matrix);
    assert!(v.is_empty(), "spectral with linfa's k-means: {v:?}");
    let gmm = kinetree_clustering::SpectralGmm::new(Default::default()).expect("params");
    let v = check_clustering(&gmm, &q_matrix);
    assert!(v.is_empty(), "spectral_gmm: {v:?}");
    let dbscan = kinetree_clustering::SpectralDbscan::new(Default::default()).expect("params");
    let v = check_clustering(&dbscan, &q_matrix);
    assert!(v.is_empty(), "spectral_dbscan: {v:?}");
}

#[test]
fn pose_estimators_conform() {
    let v = check_pose(&KabschPoses::new(KabschParams::default()).expect("params"));
    assert!(v.is_empty(), "{v:?}");
    let robust = KabschPoses::new(KabschParams {
        outlier_in_sigma: Some(5.0),
        ..KabschParams::default()
    })
    .expect("params");
    let v = check_pose(&robust);
    assert!(v.is_empty(), "{v:?}");
}

#[test]
fn dof_testers_conform() {
    let svd = SvdRank::new(SvdRankParams::default()).expect("params");
    let v = check_dof(&svd, &kabsch_poses);
    assert!(v.is_empty(), "svd_rank: {v:?}");
    let chi2 = Chi2Rank::new(Chi2RankParams::default()).expect("params");
    let v = check_dof(&chi2, &kabsch_poses);
    assert!(v.is_empty(), "chi2_rank: {v:?}");
}

/// A clusterer that breaks the contract in two ways: it panics on NaN, and its labels follow
/// the input order (not the geometry), so permuting the points changes the partition.
#[derive(Debug)]
struct Broken;

impl kinetree_core::Clustering for Broken {
    fn name(&self) -> &str {
        "broken"
    }

    fn cluster(
        &self,
        input: &kinetree_core::ClusteringInput<'_>,
    ) -> kinetree_core::Result<Segmentation> {
        let m = input.dissimilarity;
        assert!(m.values.iter().all(|v| !v.is_nan()), "NaN");
        let raw: Vec<Option<usize>> = (0..m.n_points).map(|i| Some(i % 2)).collect();
        Ok(Segmentation::from_raw(&raw, 1))
    }
}

#[test]
fn the_checks_catch_a_broken_clusterer() {
    let v = check_clustering(&Broken, &q_matrix);
    assert!(v.iter().any(|s| s.contains("panicked")), "{v:?}");
    assert!(v.iter().any(|s| s.contains("permuting")), "{v:?}");
    assert!(v.iter().any(|s| s.contains("wrong size")), "{v:?}");
}
