//! An interactive 3D view of a model and its tracks in one self-contained HTML file: the
//! keypoints coloured by body, the tree's links, the joints' axes and pivots, play/pause, a
//! time slider, orbit and zoom, and every joint's position over time. `kinetree view` writes
//! it.
//!
//! The page needs no network: it carries three.js (with its OrbitControls) and uPlot, bundled
//! by `crates/view/js` (npm and esbuild) into `assets/vendor.js`, then the viewer's own
//! script (`assets/viewer.js`) and the data. The data are the tracks, the model's point
//! ownership, and, from the whole-tree fit of every frame ([`kinetree_fit::observe`]), each
//! body's origin and each joint's pivot, axis and position per frame.

use base64::Engine as _;
use kinetree_core::model::JointType;
use kinetree_core::nalgebra::{Point3, Vector3};
use kinetree_core::{Error, Model, Result, Tracks};
use serde::Serialize;

/// The third-party code: three.js, its OrbitControls and uPlot (MIT licences at its end).
const VENDOR_JS: &str = include_str!("../assets/vendor.js");
/// uPlot's style sheet.
const UPLOT_CSS: &str = include_str!("../assets/uPlot.min.css");
/// Their licence texts.
const LICENSES: &str = include_str!("../assets/LICENSES.txt");
/// The viewer's own script.
const VIEWER_JS: &str = include_str!("../assets/viewer.js");
/// The page around them.
const TEMPLATE: &str = include_str!("../assets/viewer.html");

/// Default of [`ViewOptions::max_samples`].
pub const DEFAULT_MAX_SAMPLES: usize = 2_000_000;

/// What goes into the page.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewOptions {
    /// The page's title.
    pub title: String,
    /// Most keypoint samples (frames x points) carried; longer recordings keep every k-th
    /// frame so that the page stays small enough for a browser (about 16 bytes a sample).
    pub max_samples: usize,
    /// Frames per second when playing (the recording's rate when it has one).
    pub fps: Option<f64>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            title: "kinetree model".into(),
            max_samples: DEFAULT_MAX_SAMPLES,
            fps: None,
        }
    }
}

/// The page's data, read by `viewer.js`. Arrays of floats are base64 of little-endian f32,
/// NaN where unknown.
#[derive(Debug, Serialize)]
struct ViewData {
    title: String,
    /// The input frame of each frame shown.
    frames: Vec<usize>,
    n_points: usize,
    fps: f64,
    /// `frames x points x 3`.
    positions: String,
    point_body: Vec<i64>,
    point_labels: Option<Vec<String>>,
    bodies: Vec<BodyView>,
    joints: Vec<JointView>,
    /// The model's noise level, metres (the page states it).
    noise_sigma_m: f64,
}

#[derive(Debug, Serialize)]
struct BodyView {
    id: usize,
    parent: Option<usize>,
    is_static: bool,
    n_points: usize,
    /// `frames x 3`: the body frame's origin (its centroid) in the fitted configuration.
    origin: String,
}

#[derive(Debug, Serialize)]
struct JointView {
    name: String,
    #[serde(rename = "type")]
    joint_type: String,
    parent: usize,
    child: usize,
    /// `rad` or `m` (none for joints without a coordinate).
    unit: Option<&'static str>,
    /// `frames x 3`: a point of a revolute axis, in the camera frame.
    pivot: String,
    /// `frames x 3`: the unit axis in the camera frame.
    axis: String,
    /// `frames`: the joint position.
    position: String,
}

/// Little-endian f32 values as base64.
fn encode(values: impl IntoIterator<Item = f64>) -> String {
    let bytes: Vec<u8> = values
        .into_iter()
        .flat_map(|v| (v as f32).to_le_bytes())
        .collect();
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

fn xyz(p: Option<[f64; 3]>) -> [f64; 3] {
    p.unwrap_or([f64::NAN; 3])
}

/// Writes the page for `model` and `tracks` (of the model's points).
///
/// # Errors
/// [`Error::Shape`] when the tracks do not have the model's points,
/// [`Error::InvalidParameter`] for a `max_samples` of 0, and the whole-tree fit's errors.
pub fn to_html(model: &Model, tracks: &Tracks, options: &ViewOptions) -> Result<String> {
    if options.max_samples == 0 {
        return Err(Error::InvalidParameter {
            name: "max_samples".into(),
            message: "must be at least 1".into(),
        });
    }
    if let Some(fps) = options.fps
        && !(fps.is_finite() && fps > 0.0)
    {
        return Err(Error::InvalidParameter {
            name: "fps".into(),
            message: format!("must be a positive number, got {fps}"),
        });
    }
    let (t, n) = (tracks.n_frames(), tracks.n_points());
    let stride = (t * n).div_ceil(options.max_samples).max(1);
    let frames: Vec<usize> = (0..t).step_by(stride).collect();
    // Every frame kept: the tracks themselves, not a copy.
    let kept = if stride > 1 {
        Some(tracks.select_frames(&frames)?)
    } else {
        None
    };
    let shown = kept.as_ref().unwrap_or(tracks);
    let seen = kinetree_fit::observe(model, shown, kinetree_fit::ObserveOptions::default())?;
    let pose = |f: usize, b: usize| seen.poses[f].get(b).copied().flatten();
    let bodies = model
        .bodies
        .iter()
        .map(|b| BodyView {
            id: b.id,
            parent: b.parent,
            is_static: b.is_static,
            n_points: b.points.len(),
            origin: encode(
                (0..frames.len())
                    .flat_map(|f| xyz(pose(f, b.id).map(|p| p.translation.vector.into()))),
            ),
        })
        .collect();
    let joints = model
        .joints
        .iter()
        .zip(&seen.joint_columns)
        .map(|(j, &column)| {
            let axis = j.axis_in_parent.map(Vector3::from);
            let point = j.point_in_parent.map(Point3::from);
            let in_camera = |f: usize| {
                let p = pose(f, j.parent);
                let axis = p.zip(axis).map(|(p, a)| (p.rotation * a).into());
                let pivot = p.zip(point).map(|(p, q)| (p * q).coords.into());
                (pivot, axis)
            };
            let (pivots, axes): (Vec<_>, Vec<_>) = (0..frames.len()).map(in_camera).unzip();
            let single = matches!(j.joint_type, JointType::Revolute | JointType::Prismatic);
            // A ball joint's plot is its rotation angle, the length of its rotation vector; a
            // universal joint's its first angle.
            let position: Vec<f64> = if j.joint_type == JointType::Spherical {
                (0..frames.len())
                    .map(|f| {
                        let v: Option<Vec<f64>> =
                            (column..column + 3).map(|c| seen.positions[c][f]).collect();
                        v.map_or(f64::NAN, |v| v.iter().map(|x| x * x).sum::<f64>().sqrt())
                    })
                    .collect()
            } else {
                seen.positions[column]
                    .iter()
                    .map(|p| p.unwrap_or(f64::NAN))
                    .collect()
            };
            JointView {
                name: format!("{}_{}_{}", j.joint_type, j.parent, j.child),
                joint_type: j.joint_type.to_string(),
                parent: j.parent,
                child: j.child,
                unit: match j.joint_type {
                    JointType::Revolute | JointType::Spherical | JointType::Universal => {
                        Some("rad")
                    }
                    JointType::Prismatic => Some("m"),
                    _ => None,
                },
                pivot: encode(
                    pivots
                        .into_iter()
                        .flat_map(|p| xyz(p.filter(|_| j.joint_type == JointType::Revolute))),
                ),
                axis: encode(axes.into_iter().flat_map(|a| xyz(a.filter(|_| single)))),
                position: encode(position),
            }
        })
        .collect();
    let data = ViewData {
        title: options.title.clone(),
        fps: options
            .fps
            .or(tracks.frame_rate_hz().map(|r| r / stride as f64))
            .unwrap_or(30.0),
        frames,
        n_points: n,
        positions: encode(shown.raw().iter().copied()),
        point_body: model.point_body.clone(),
        point_labels: model.point_labels.clone(),
        bodies,
        joints,
        noise_sigma_m: model.noise.sigma_m,
    };
    let json = serde_json::to_string(&data).map_err(|e| Error::Config(e.to_string()))?;
    Ok(page(&options.title, &json))
}

/// Text safe inside an HTML element: `&`, `<` and `>` escaped.
fn escape_html(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The page: the template with the style sheets, scripts and data put in. JSON cannot end
/// its `<script>` element early, as every `</` in it is written `<\/`, and neither can the
/// scripts, which hold no `</script`.
fn page(title: &str, json: &str) -> String {
    let data = json.replace("</", "<\\/");
    // Each placeholder is replaced once, in order, so that text put in earlier is never
    // searched for the later ones.
    let mut out = String::with_capacity(TEMPLATE.len() + VENDOR_JS.len() + data.len() + 4096);
    let mut rest = TEMPLATE;
    let escaped = escape_html(title);
    for (key, value) in [
        ("{{title}}", escaped.as_str()),
        ("{{uplot_css}}", UPLOT_CSS),
        ("{{vendor_js}}", VENDOR_JS),
        ("{{licenses}}", LICENSES),
        ("{{data}}", data.as_str()),
        ("{{viewer_js}}", VIEWER_JS),
    ] {
        let (before, after) = rest.split_once(key).unwrap_or((rest, ""));
        out.push_str(before);
        out.push_str(value);
        rest = after;
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scripts_cannot_close_their_elements() {
        for (name, text) in [
            ("vendor", VENDOR_JS),
            ("viewer", VIEWER_JS),
            ("licences", LICENSES),
        ] {
            assert!(!text.to_ascii_lowercase().contains("</script"), "{name}");
        }
        // The licences sit in a comment.
        assert!(!LICENSES.contains("*/"));
        let page = page("a <b> & c", r#"{"title":"</script><script>alert(1)"}"#);
        assert_eq!(
            page.matches("</script>").count(),
            3,
            "three script elements"
        );
        assert!(page.contains("a &lt;b&gt; &amp; c"));
        for key in [
            "{{title}}",
            "{{data}}",
            "{{vendor_js}}",
            "{{licenses}}",
            "{{viewer_js}}",
        ] {
            assert!(!page.contains(key), "{key}");
        }
    }

    #[test]
    fn values_are_base64_f32() {
        let text = encode([1.0, f64::NAN]);
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(text)
            .expect("base64");
        assert_eq!(bytes.len(), 8);
        assert_eq!(f32::from_le_bytes(bytes[..4].try_into().expect("4")), 1.0);
        assert!(f32::from_le_bytes(bytes[4..].try_into().expect("4")).is_nan());
    }
}
