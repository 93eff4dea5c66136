//! Figures of an experiment, each as PNG and SVG: the visibility matrix (the paper's Fig. 2),
//! the distance std-dev and dissimilarity matrices (Fig. 3), the discovered kinematic tree,
//! and the joint trajectories (estimated, and true when known).
//!
//! plotters is built without its system font stack (`ab_glyph` with DejaVu Sans from the
//! `dejavu` crate), so a machine without fontconfig or freetype renders them.

use kinetree_core::model::JointType;
use kinetree_core::{Error, Model, Result, Tracks};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// What the figures are drawn from.
#[derive(Debug, Clone, Copy)]
pub struct FigureInput<'a> {
    /// The tracks.
    pub tracks: &'a Tracks,
    /// The discovered model.
    pub model: &'a Model,
    /// Std-dev of every pair's distance, metres, condensed (NaN for unknown pairs).
    pub distance_std_m: &'a [f64],
    /// The dissimilarity used, condensed (NaN for unknown pairs).
    pub dissimilarity: &'a [f64],
    /// Name of the dissimilarity measure.
    pub measure: &'a str,
    /// For each model joint, the true joint positions when known, aligned to the estimate's
    /// sign and offset.
    pub true_positions: &'a [Option<Vec<f64>>],
}

const W: u32 = 900;
const H: u32 = 800;

fn fig_err(e: impl std::fmt::Display) -> Error {
    Error::Numerical(format!("drawing a figure: {e}"))
}

/// Registers DejaVu Sans as plotters' "sans-serif" (once).
fn fonts() -> Result<()> {
    static ONCE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = ONCE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
            .is_ok()
    });
    if *ok {
        Ok(())
    } else {
        Err(Error::Numerical(
            "the embedded font could not be loaded".into(),
        ))
    }
}

/// A perceptual-ish ramp from dark blue through teal and green to yellow, `t` in 0..1.
fn ramp(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.25, [59.0, 82.0, 139.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [94.0, 201.0, 98.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let k = STOPS.iter().position(|s| s.0 >= t).unwrap_or(4).max(1);
    let (a, b) = (STOPS[k - 1], STOPS[k]);
    let f = (t - a.0) / (b.0 - a.0);
    let c: [u8; 3] = std::array::from_fn(|i| (a.1[i] + f * (b.1[i] - a.1[i])).round() as u8);
    RGBColor(c[0], c[1], c[2])
}

const UNKNOWN: RGBColor = RGBColor(200, 200, 200);

/// Points in body order (discarded last), for block-structured matrices.
fn body_order(model: &Model) -> Vec<usize> {
    let mut order: Vec<usize> = model.bodies.iter().flat_map(|b| b.points.clone()).collect();
    order.extend((0..model.point_body.len()).filter(|&i| model.point_body[i] < 0));
    order
}

/// Entry `(i, j)` of a condensed matrix over `n` points: 0 on the diagonal, NaN if missing.
fn condensed(v: &[f64], n: usize, i: usize, j: usize) -> f64 {
    if i == j {
        return 0.0;
    }
    v.get(kinetree_core::condensed_index(n, i, j))
        .copied()
        .unwrap_or(f64::NAN)
}

/// Draws a heat map of `value(row, col)` (NaN grey) mapped by `scale` into 0..1.
#[allow(clippy::too_many_arguments)]
fn heatmap<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    rows: usize,
    cols: usize,
    value: &dyn Fn(usize, usize) -> f64,
    scale: &dyn Fn(f64) -> f64,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    area.fill(&WHITE).map_err(fig_err)?;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0f64..cols as f64, rows as f64..0f64)
        .map_err(fig_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(fig_err)?;
    let cells = (0..rows).flat_map(|r| (0..cols).map(move |c| (r, c)));
    chart
        .draw_series(cells.map(|(r, c)| {
            let v = value(r, c);
            let color = if v.is_nan() { UNKNOWN } else { ramp(scale(v)) };
            Rectangle::new(
                [(c as f64, r as f64), (c as f64 + 1.0, r as f64 + 1.0)],
                color.filled(),
            )
        }))
        .map_err(fig_err)?;
    Ok(())
}

/// Renders the body once to `<dir>/<name>.png` and once to `.svg`; yields both paths.
macro_rules! render {
    ($dir:expr, $name:expr, $size:expr, |$area:ident| $body:block) => {{
        let png = $dir.join(format!("{}.png", $name));
        {
            let $area = BitMapBackend::new(&png, $size).into_drawing_area();
            $body
            $area.present().map_err(fig_err)?;
        }
        let svg = $dir.join(format!("{}.svg", $name));
        {
            let $area = SVGBackend::new(&svg, $size).into_drawing_area();
            $body
            $area.present().map_err(fig_err)?;
        }
        vec![png, svg]
    }};
}

/// Writes every figure under `dir` (created if needed) and returns the files written.
///
/// # Errors
/// I/O errors naming the folder, and drawing errors.
pub fn write_figures(dir: &Path, input: &FigureInput<'_>) -> Result<Vec<PathBuf>> {
    fonts()?;
    std::fs::create_dir_all(dir).map_err(|e| Error::Io(e).in_file(dir))?;
    let mut out = Vec::new();
    let t = input.tracks;
    let (nf, np) = (t.n_frames(), t.n_points());
    let order = body_order(input.model);
    // Visibility (Fig. 2): frames binned to at most 300 rows, the fraction visible per bin.
    let bins = nf.min(300);
    let visible = |r: usize, c: usize| {
        let (f0, f1) = (r * nf / bins, ((r + 1) * nf / bins).max(r * nf / bins + 1));
        let i = order[c];
        (f0..f1).filter(|&f| t.get(f, i).is_some()).count() as f64 / (f1 - f0) as f64
    };
    out.extend(render!(dir, "visibility", (W, H), |area| {
        heatmap(
            &area,
            "Visibility (yellow: seen)",
            "point (grouped by body)",
            "frame",
            bins,
            np,
            &|r, c| visible(r, c),
            &|v| v,
        )?;
    }));
    // Distance std-dev (Fig. 3, left), log scale from 0.1 mm to 10 cm.
    let std_mm = |r: usize, c: usize| condensed(input.distance_std_m, np, order[r], order[c]) * 1e3;
    out.extend(render!(dir, "distance_std", (W, H), |area| {
        heatmap(
            &area,
            "Distance std-dev, log10 mm (0.1 mm to 100 mm)",
            "point (grouped by body)",
            "point",
            np,
            np,
            &|r, c| std_mm(r, c),
            &|v| (v.max(1e-3).log10() + 1.0) / 3.0,
        )?;
    }));
    let (lo, hi) = input
        .dissimilarity
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let diss = |r: usize, c: usize| condensed(input.dissimilarity, np, order[r], order[c]);
    let title = format!("Dissimilarity: {} ({lo:.2} to {hi:.2})", input.measure);
    out.extend(render!(dir, "dissimilarity", (W, H), |area| {
        heatmap(
            &area,
            &title,
            "point (grouped by body)",
            "point",
            np,
            np,
            &|r, c| diss(r, c),
            &|v| (v - lo) / span,
        )?;
    }));
    out.extend(render!(dir, "kinematic_graph", (W, 600), |area| {
        draw_graph(&area, input.model)?;
    }));
    if !input.model.joints.is_empty() {
        out.extend(render!(
            dir,
            "joint_trajectories",
            (W, 300 * input.model.joints.len() as u32),
            |area| {
                draw_trajectories(&area, input)?;
            }
        ));
    }
    Ok(out)
}

/// The tree: the camera on top, bodies by depth, edges labelled with the joint type.
fn draw_graph<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, model: &Model) -> Result<()>
where
    DB::ErrorType: 'static,
{
    area.fill(&WHITE).map_err(fig_err)?;
    let n = model.bodies.len();
    let mut depth = vec![0usize; n];
    for _ in 0..n {
        for b in &model.bodies {
            if let Some(p) = b.parent {
                depth[b.id] = depth[p] + 1;
            }
        }
    }
    let levels = depth.iter().copied().max().unwrap_or(0) + 2;
    let (w, h) = area.dim_in_pixel();
    let (w, h) = (f64::from(w), f64::from(h));
    let mut pos = vec![(0i32, 0i32); n];
    for d in 0..levels - 1 {
        let at: Vec<usize> = (0..n).filter(|&b| depth[b] == d).collect();
        for (k, &b) in at.iter().enumerate() {
            pos[b] = (
                (w * (k as f64 + 1.0) / (at.len() as f64 + 1.0)) as i32,
                (h * (d as f64 + 1.5) / (levels as f64 + 0.5)) as i32,
            );
        }
    }
    let camera = ((w / 2.0) as i32, (h * 0.5 / (levels as f64 + 0.5)) as i32);
    let text = ("sans-serif", 15).into_font();
    let edge = |a: (i32, i32), b: (i32, i32), label: &str, dashed: bool| -> Result<()> {
        let style = if dashed {
            BLACK.mix(0.4)
        } else {
            BLACK.mix(1.0)
        };
        area.draw(&PathElement::new(vec![a, b], style.stroke_width(2)))
            .map_err(fig_err)?;
        area.draw(&Text::new(
            label.to_string(),
            ((a.0 + b.0) / 2 + 6, (a.1 + b.1) / 2),
            text.clone(),
        ))
        .map_err(fig_err)
    };
    if let Some(root) = model.bodies.get(model.root_body) {
        let label = if root.is_static { "static" } else { "moves" };
        edge(camera, pos[root.id], label, true)?;
    }
    for j in &model.joints {
        let label = match j.range {
            Some([lo, hi]) if j.joint_type == JointType::Prismatic => {
                format!("prismatic {:.0} mm", (hi - lo) * 1e3)
            }
            Some([lo, hi]) => format!("{} {:.2} rad", j.joint_type, hi - lo),
            None => j.joint_type.to_string(),
        };
        edge(pos[j.parent], pos[j.child], &label, false)?;
    }
    let node = |p: (i32, i32), label: String, fill: RGBColor| -> Result<()> {
        area.draw(&Circle::new(p, 22, fill.filled()))
            .map_err(fig_err)?;
        area.draw(&Circle::new(p, 22, BLACK.stroke_width(1)))
            .map_err(fig_err)?;
        area.draw(&Text::new(label, (p.0 - 18, p.1 + 26), text.clone()))
            .map_err(fig_err)
    };
    node(camera, "camera".into(), RGBColor(220, 220, 220))?;
    for b in &model.bodies {
        let fill = if b.is_static {
            RGBColor(180, 180, 180)
        } else {
            ramp(0.65)
        };
        node(
            pos[b.id],
            format!("body {} ({} pts)", b.id, b.points.len()),
            fill,
        )?;
    }
    Ok(())
}

/// One panel per joint: the estimated positions (and the true ones when known) over frames.
fn draw_trajectories<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    input: &FigureInput<'_>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    area.fill(&WHITE).map_err(fig_err)?;
    let joints = &input.model.joints;
    let panels = area.split_evenly((joints.len(), 1));
    for (k, (j, panel)) in joints.iter().zip(&panels).enumerate() {
        let est: Vec<(f64, f64)> = j
            .positions
            .iter()
            .enumerate()
            .filter_map(|(t, p)| p.map(|p| (t as f64, p)))
            .collect();
        let truth: Vec<(f64, f64)> = input
            .true_positions
            .get(k)
            .and_then(|t| t.as_ref())
            .map(|v| v.iter().enumerate().map(|(t, &p)| (t as f64, p)).collect())
            .unwrap_or_default();
        let all = est.iter().chain(&truth).map(|p| p.1);
        let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
        let (lo, hi) = if lo.is_finite() && hi > lo {
            (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        } else {
            (-1.0, 1.0)
        };
        let unit = if j.joint_type == JointType::Prismatic {
            "m"
        } else {
            "rad"
        };
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!(
                    "joint body {} -> body {} ({})",
                    j.parent, j.child, j.joint_type
                ),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..input.model.n_frames.max(1) as f64, lo..hi)
            .map_err(fig_err)?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc(unit)
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(fig_err)?;
        if !truth.is_empty() {
            chart
                .draw_series(LineSeries::new(truth, BLACK.mix(0.5).stroke_width(4)))
                .map_err(fig_err)?
                .label("true")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
        }
        chart
            .draw_series(LineSeries::new(est, ramp(0.3).stroke_width(2)))
            .map_err(fig_err)?
            .label("estimated")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], ramp(0.3)));
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(fig_err)?;
    }
    Ok(())
}

/// One panel of [`write_scaling_plot`]: a measured time against a size.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalingPanel {
    /// The panel's title.
    pub title: String,
    /// What the size is (the x axis' label).
    pub size: String,
    /// `(size, seconds)`, each positive.
    pub points: Vec<(f64, f64)>,
}

/// Draws time against size on log-log axes, one panel per [`ScalingPanel`] side by side,
/// with a dashed line of slope one (linear cost) and one of slope two through each panel's
/// first point, into `path` (SVG).
///
/// # Errors
/// [`Error::InvalidParameter`] for a panel without points or with a size or time that is not
/// positive and finite; I/O and drawing errors.
pub fn write_scaling_plot(path: &Path, panels: &[ScalingPanel]) -> Result<()> {
    for p in panels {
        let bad = p
            .points
            .iter()
            .any(|&(x, y)| !(x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0));
        if p.points.is_empty() || bad {
            return Err(Error::InvalidParameter {
                name: format!("scaling panel `{}`", p.title),
                message: "needs points of positive, finite size and time".into(),
            });
        }
    }
    fonts()?;
    let width = 520 * panels.len().max(1) as u32;
    let area = SVGBackend::new(path, (width, 440)).into_drawing_area();
    area.fill(&WHITE).map_err(fig_err)?;
    for (panel, p) in area
        .split_evenly((1, panels.len().max(1)))
        .iter()
        .zip(panels)
    {
        let (x0, x1) = p.points.iter().fold((f64::INFINITY, 0.0f64), |(l, h), q| {
            (l.min(q.0), h.max(q.0))
        });
        let (y0, y1) = p.points.iter().fold((f64::INFINITY, 0.0f64), |(l, h), q| {
            (l.min(q.1), h.max(q.1))
        });
        let (lo, hi) = (x0 / 1.3, x1 * 1.3);
        let mut chart = ChartBuilder::on(panel)
            .caption(&p.title, ("sans-serif", 18))
            .margin(14)
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d((lo..hi).log_scale(), (y0 / 2.0..y1 * 2.0).log_scale())
            .map_err(fig_err)?;
        chart
            .configure_mesh()
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.2}"))
            .x_desc(&p.size)
            .y_desc("seconds")
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(fig_err)?;
        let (fx, fy) = p.points[0];
        for (power, label) in [(1.0, "linear"), (2.0, "quadratic")] {
            // Sampled and cut at the panel's top and bottom: plotters would clamp an end
            // beyond them and bend the line.
            let line: Vec<(f64, f64)> = (0..=64)
                .map(|i| {
                    let x = lo * (hi / lo).powf(i as f64 / 64.0);
                    (x, fy * (x / fx).powf(power))
                })
                .filter(|&(_, y)| y >= y0 / 2.0 && y <= y1 * 2.0)
                .collect();
            let style = BLACK.mix(0.35).stroke_width(1);
            chart
                .draw_series(DashedLineSeries::new(line, 6, 4, style))
                .map_err(fig_err)?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        chart
            .draw_series(LineSeries::new(p.points.clone(), ramp(0.3).stroke_width(2)))
            .map_err(fig_err)?
            .label("measured")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], ramp(0.3)));
        chart
            .draw_series(
                p.points
                    .iter()
                    .map(|&q| Circle::new(q, 4, ramp(0.3).filled())),
            )
            .map_err(fig_err)?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(fig_err)?;
    }
    area.present().map_err(fig_err)
}
