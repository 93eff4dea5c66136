//! Links that no keypoint shows well enough to pose (an arm's wrist link buried between its
//! neighbours, or seen by a few keypoints in a few frames): after the discovery, a
//! multi-DoF or universal joint the whole-tree fit follows as two hinges through a body
//! gets that body, with the keypoints its motion explains ([`kinetree_fit::unseen_links`]);
//! so does a link carrying several children whose joints meet, which the tree takes for a
//! universal joint between two of them ([`kinetree_fit::unseen_hubs`]). The positions are
//! then written from the new model's fit.

use crate::run::Pipeline;
use kinetree_core::limits::{check_count, check_within};
use kinetree_core::{Model, Result, Tracks};
use kinetree_fit::{BundleLimits, UnseenLinkLimits};
use serde::{Deserialize, Serialize};

/// `[pipeline.unseen_links]`: when a link too little seen to pose is put between two bodies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UnseenLinksParams {
    /// Whether multi-DoF and universal joints are tried as two hinges through an unseen link
    /// (default true).
    pub enabled: bool,
    /// Frames in which the whole-tree fit poses both bodies, at least (default 30).
    pub min_frames: usize,
    /// The start's RMS miss of the child's keypoints, in noise standard deviations, above
    /// which the pair is not tried further (default 20).
    pub max_start_rms_in_sigma: f64,
    /// The child's joint excess after the bundle adjustment must be within this (default 3,
    /// as `type_by_fit.max_excess`) ...
    pub max_excess: f64,
    /// ... and every other joint's within this (default 30, the freeing bound).
    pub others_max_excess: f64,
    /// The two hinge axes must pass at least this many noise standard deviations apart
    /// (default 3): nearer, the pair is a universal joint.
    pub min_offset_in_sigma: f64,
    /// ... and be at least this many degrees apart (default 10).
    pub min_axes_angle_deg: f64,
    /// A universal joint becomes two hinges when they lower the fit's squared residual by
    /// more than this many noise variances (default 100).
    pub min_gain_over_universal: f64,
    /// Whether a universal joint whose cross moves against another body about one hinge or
    /// slide is read as a link carrying both bodies ([`kinetree_fit::unseen_hubs`]; default
    /// true).
    pub hubs: bool,
    /// Whether the children of a hidden link that the tree hung elsewhere are moved (default
    /// true): a multi-DoF joint that is not two hinges is tried with its child on the other
    /// body whose two hinges carry its keypoints best, the bodies hung by doubtful joints are
    /// tried on each link put in by one hinge or slide, and the children of the multi-DoF
    /// joints left on the body the fit moves them against by one hinge or slide.
    pub rehang: bool,
}

impl Default for UnseenLinksParams {
    fn default() -> Self {
        let l = UnseenLinkLimits::default();
        Self {
            enabled: true,
            min_frames: l.min_frames,
            max_start_rms_in_sigma: l.max_start_rms_in_sigma,
            max_excess: l.max_excess,
            others_max_excess: l.others_max_excess,
            min_offset_in_sigma: l.min_offset_in_sigma,
            min_axes_angle_deg: l.min_axes_angle_deg,
            min_gain_over_universal: l.min_gain_over_universal,
            hubs: true,
            rehang: l.rehang,
        }
    }
}

impl UnseenLinksParams {
    /// Checks the ranges: `min_frames` 8 to 10^9, the bounds positive and finite, the angle
    /// below 90 degrees.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `pipeline.unseen_links.<key>`.
    pub fn validate(&self) -> Result<()> {
        const AT: &str = "pipeline.unseen_links";
        check_count(
            &format!("{AT}.min_frames"),
            self.min_frames,
            8,
            1_000_000_000,
        )?;
        for (key, value) in [
            ("max_start_rms_in_sigma", self.max_start_rms_in_sigma),
            ("max_excess", self.max_excess),
            ("others_max_excess", self.others_max_excess),
            ("min_offset_in_sigma", self.min_offset_in_sigma),
            ("min_gain_over_universal", self.min_gain_over_universal),
        ] {
            check_within(&format!("{AT}.{key}"), value, 0.0, 1e12)?;
        }
        check_within(
            &format!("{AT}.min_axes_angle_deg"),
            self.min_axes_angle_deg,
            0.0,
            89.0,
        )
    }

    fn limits(&self) -> UnseenLinkLimits {
        UnseenLinkLimits {
            min_frames: self.min_frames,
            max_start_rms_in_sigma: self.max_start_rms_in_sigma,
            max_excess: self.max_excess,
            others_max_excess: self.others_max_excess,
            min_offset_in_sigma: self.min_offset_in_sigma,
            min_axes_angle_deg: self.min_axes_angle_deg,
            min_gain_over_universal: self.min_gain_over_universal,
            rehang: self.rehang,
            bundle: BundleLimits::default(),
        }
    }
}

/// Puts the unseen links `pipeline` asks for into `model` (discovered on `tracks`) and, when
/// there are any, writes the positions, their precision and the re-prediction from the new
/// model's fit.
///
/// # Errors
/// As [`kinetree_fit::unseen_links`] and the positions' writing.
pub(crate) fn put_unseen_links(
    pipeline: &Pipeline,
    model: &mut Model,
    tracks: &Tracks,
) -> Result<()> {
    if !pipeline.unseen_links.enabled {
        return Ok(());
    }
    let limits = pipeline.unseen_links.limits();
    let tree = |m: &Model| -> Vec<(usize, usize)> {
        m.joints.iter().map(|j| (j.parent, j.child)).collect()
    };
    let before = tree(model);
    // Links read from universal joints first: a hub's children, each taken alone, would each
    // get a link of their own between two hinges.
    let mut added = if pipeline.unseen_links.hubs {
        kinetree_fit::unseen_hubs(model, tracks, &limits)?
    } else {
        Vec::new()
    };
    added.extend(kinetree_fit::unseen_links(model, tracks, &limits)?);
    // `rehang` moves children without putting a link in.
    if added.is_empty() && tree(model) == before {
        return Ok(());
    }
    let state = kinetree_fit::FitState::new(model, tracks)?;
    crate::runner::write_fit(pipeline, model, &state, tracks)
}
