//! A reader for TRC marker files (OpenSim's and Motion Analysis' tab-separated text format).
//!
//! Written here: the format is five header lines and a table of numbers, and no maintained
//! Rust crate reads it. The layout:
//!
//! ```text
//! PathFileType  4  (X/Y/Z)  walk.trc
//! DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
//! 100       100         500        30          mm     100           1                   500
//! Frame#  Time  RASI        LASI        ...
//!               X1  Y1  Z1  X2  Y2  Z2  ...
//! 1       0.00  ...
//! ```
//!
//! A missing sample is an empty field, `NaN`, or a line that ends early.

use kinetree_core::{Error, Result, Tracks};

fn malformed(position: impl Into<String>, message: impl Into<String>) -> Error {
    Error::Malformed {
        position: position.into(),
        message: message.into(),
    }
}

/// The fields of a header or data line: tab-separated (empty fields kept: a missing sample),
/// or whitespace-separated for a line without tabs (some writers pad with spaces);
/// surrounding blanks trimmed.
fn fields(line: &str) -> Vec<&str> {
    if line.contains('\t') {
        line.split('\t').map(str::trim).collect()
    } else {
        line.split_whitespace().collect()
    }
}

/// Tracks from the text of a TRC file; see [`crate::read_trc`].
///
/// # Errors
/// As [`crate::read_trc`].
pub(crate) fn tracks_within(text: &str, max_memory_gib: f64) -> Result<Tracks> {
    let lines: Vec<&str> = text.lines().collect();
    let line = |k: usize| -> Result<&str> {
        lines.get(k).copied().ok_or_else(|| {
            malformed(
                format!("line {}", k + 1),
                "missing: the header has five lines",
            )
        })
    };
    if !line(0)?.trim_start().starts_with("PathFileType") {
        return Err(malformed(
            "line 1",
            "does not start with `PathFileType`: not a TRC file",
        ));
    }
    let keys = fields(line(1)?);
    let values = fields(line(2)?);
    let value = |key: &str| -> Result<&str> {
        let at = keys
            .iter()
            .position(|k| k.eq_ignore_ascii_case(key))
            .ok_or_else(|| malformed("line 2", format!("no `{key}` column in the header")))?;
        values
            .get(at)
            .copied()
            .filter(|v| !v.is_empty())
            .ok_or_else(|| malformed("line 3", format!("no value under `{key}`")))
    };
    let number = |key: &str| -> Result<f64> {
        let v = value(key)?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| malformed("line 3", format!("`{key}` is {v:?}, not a number")))
    };
    let n_markers = number("NumMarkers")?;
    if !(n_markers >= 1.0 && n_markers.fract() == 0.0) {
        return Err(malformed(
            "line 3",
            format!("`NumMarkers` is {n_markers}; a positive whole number is needed"),
        ));
    }
    let n_points = n_markers as usize;
    let units = value("Units")?;
    let to_m = match units.to_ascii_lowercase().as_str() {
        "mm" => 1e-3,
        "cm" => 1e-2,
        "m" => 1.0,
        other => {
            return Err(malformed(
                "line 3",
                format!("unknown `Units` {other:?}; expected mm, cm or m"),
            ));
        }
    };
    let rate = number("DataRate")?;
    // Marker names: every non-empty field after `Frame#` and `Time`.
    let names: Vec<String> = fields(line(3)?)
        .iter()
        .skip(2)
        .filter(|f| !f.is_empty())
        .map(|f| (*f).to_string())
        .collect();
    if names.len() > n_points {
        return Err(malformed(
            "line 4",
            format!("names {} markers; `NumMarkers` is {n_points}", names.len()),
        ));
    }
    let labels: Vec<String> = (0..n_points)
        .map(|i| {
            names
                .get(i)
                .cloned()
                .unwrap_or_else(|| format!("point {i}"))
        })
        .collect();
    let data: Vec<(usize, &str)> = lines
        .iter()
        .enumerate()
        .skip(5)
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(k, l)| (k, *l))
        .collect();
    if data.is_empty() {
        return Err(malformed("line 6", "no frames after the header"));
    }
    // Exports from Vicon keep Plug-in Gait's segment axes beside the markers: their columns
    // are read and checked like the others, and not stored.
    let model_at = crate::model_points::segment_axes(&labels);
    if model_at.len() == n_points {
        return Err(malformed(
            "line 4",
            "every marker is a Plug-in Gait segment axis or centre of mass, a model's output; no markers",
        ));
    }
    let n_kept = n_points - model_at.len();
    crate::check_size(data.len() as u64, n_kept as u64, max_memory_gib)?;
    let mut xyz = Vec::with_capacity(data.len() * n_kept * 3);
    // The most decimals any coordinate is written with: the grid the writer rounded to
    // (none when a coordinate has an exponent).
    let mut decimals: Option<usize> = Some(0);
    for (k, text) in &data {
        let row = fields(text);
        let extra = row.iter().skip(2 + 3 * n_points).find(|f| !f.is_empty());
        if let Some(f) = extra {
            return Err(malformed(
                format!("line {}", k + 1),
                format!("{f:?} beyond the {n_points} markers' coordinates"),
            ));
        }
        for (i, label) in labels.iter().enumerate() {
            let mut p = [f64::NAN; 3];
            let mut seen = true;
            for (c, slot) in p.iter_mut().enumerate() {
                let f = row.get(2 + 3 * i + c).copied().unwrap_or("");
                if f.is_empty() || f.eq_ignore_ascii_case("nan") {
                    seen = false;
                    continue;
                }
                *slot = f.parse::<f64>().map_err(|_| {
                    malformed(
                        format!("line {}", k + 1),
                        format!("{f:?} is not a number (marker {label})"),
                    )
                })? * to_m;
                decimals = match (decimals, f.contains(['e', 'E'])) {
                    (Some(d), false) => Some(d.max(f.find('.').map_or(0, |at| f.len() - at - 1))),
                    _ => None,
                };
            }
            if model_at.binary_search(&i).is_ok() {
                continue;
            }
            if seen && p.iter().all(|v| v.is_finite()) {
                xyz.extend(p);
            } else {
                xyz.extend([f64::NAN; 3]);
            }
        }
    }
    let (mut model_points, mut kept_labels) = (Vec::new(), Vec::new());
    for (i, label) in labels.into_iter().enumerate() {
        if model_at.binary_search(&i).is_ok() {
            model_points.push(label);
        } else {
            kept_labels.push(label);
        }
    }
    let mut tracks = Tracks::new(data.len(), n_kept, xyz)?.with_labels(kept_labels)?;
    let step = decimals
        .and_then(|d| i32::try_from(d).ok())
        .map(|d| 10f64.powi(-d) * to_m);
    if let Some(step) = step.filter(|s| s.is_normal()) {
        tracks = tracks.with_precision(step)?;
    }
    if !model_points.is_empty() {
        tracks = tracks.with_warnings(vec![kinetree_core::Warning::ModelPointsSkipped {
            labels: model_points,
        }]);
    }
    if rate > 0.0 {
        tracks.with_frame_rate(rate)
    } else {
        Ok(tracks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WALK: &str = "PathFileType\t4\t(X/Y/Z)\twalk.trc\n\
DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n\
100\t100\t3\t3\tmm\t100\t1\t3\n\
Frame#\tTime\tRASI\t\t\tLASI\t\t\tC7\t\t\n\
\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\n\
\n\
1\t0.00\t100\t200\t300\t400\t500\t600\t700\t800\t900\n\
2\t0.01\t101\t201\t301\t\t\t\t701\t801\tNaN\n\
3\t0.02\t102\t202\t302\n";

    #[test]
    fn a_trc_file_reads_in_metres_with_its_names_rate_and_gaps() {
        let t = tracks_within(WALK, 1.0).expect("read");
        assert_eq!((t.n_frames(), t.n_points()), (3, 3));
        let p = t.get(0, 1).expect("seen");
        assert!((p.x - 0.4).abs() < 1e-12 && (p.z - 0.6).abs() < 1e-12);
        assert!((t.get(2, 0).expect("seen").y - 0.202).abs() < 1e-12);
        // An empty field, a NaN, and a line that ends early hide the sample.
        assert!(t.get(1, 1).is_none() && t.get(1, 2).is_none());
        assert!(t.get(2, 1).is_none() && t.get(2, 2).is_none());
        assert_eq!(t.labels().expect("labels"), ["RASI", "LASI", "C7"]);
        assert_eq!(t.frame_rate_hz(), Some(100.0));
        // Whole millimetres: a grid of 1 mm; a coordinate with more decimals sets a finer one,
        // and one with an exponent leaves the grid unknown.
        assert_eq!(t.precision_m(), Some(1e-3));
        let finer = tracks_within(&WALK.replace("\t202\t", "\t202.25\t"), 1.0).expect("read");
        assert!((finer.precision_m().expect("grid") - 1e-5).abs() < 1e-18);
        let exponent = tracks_within(&WALK.replace("\t202\t", "\t2.02e2\t"), 1.0).expect("read");
        assert_eq!(exponent.precision_m(), None);
    }

    #[test]
    fn plug_in_gait_segment_axes_are_left_out_with_a_warning() {
        // Two frames of these markers, coordinate k of a frame f at 10 k + f millimetres.
        let trc = |names: &[&str]| {
            let mut text = format!(
                "PathFileType\t4\t(X/Y/Z)\tpig.trc\n\
DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n100\t100\t2\t{}\tmm\n\
Frame#\tTime\t{}\n\n",
                names.len(),
                names.join("\t\t\t")
            );
            for f in 0..2 {
                let xyz: Vec<String> = (0..3 * names.len())
                    .map(|k| format!("{}", 10 * k + f))
                    .collect();
                text += &format!("{}\t{}\t{}\n", f + 1, f as f64 / 100.0, xyz.join("\t"));
            }
            text
        };
        let text = trc(&["RASI", "PELO", "PELA", "PELL", "PELP", "LASI", "C7"]);
        let t = tracks_within(&text, 1.0).expect("read");
        assert_eq!(t.labels().expect("labels"), ["RASI", "LASI", "C7"]);
        // LASI, the file's sixth marker, keeps its own columns (15-17).
        assert!((t.get(1, 1).expect("seen").x - 0.151).abs() < 1e-12);
        assert_eq!(t.frame_rate_hz(), Some(100.0));
        assert_eq!(
            t.warnings(),
            [kinetree_core::Warning::ModelPointsSkipped {
                labels: ["PELO", "PELA", "PELL", "PELP"].map(String::from).to_vec(),
            }]
        );
        // A file of nothing but segment axes has no markers: an error naming the line.
        let e =
            tracks_within(&trc(&["PELO", "PELA", "PELL", "PELP"]), 1.0).expect_err("no markers");
        assert!(
            e.to_string().contains("line 4") && e.to_string().contains("segment axis"),
            "{e}"
        );
    }

    #[test]
    fn damaged_trc_files_are_typed_errors_naming_the_line() {
        let cases = [
            ("no header", "1\t2\t3\n"),
            ("inches", &*WALK.replace("\tmm\t", "\tin\t")),
            ("text", &*WALK.replace("\t101\t", "\tabc\t")),
            ("too many names", &*WALK.replace("LASI", "LASI\tRPSI")),
            (
                "extra column",
                &*WALK.replace("302\n", "302\t1\t2\t3\t4\t5\t6\t7\n"),
            ),
            ("no frames", &WALK[..WALK.find("1\t0.00").expect("data")]),
        ];
        for (what, text) in cases {
            match tracks_within(text, 1.0) {
                Err(Error::Malformed { position, .. }) => {
                    assert!(position.starts_with("line"), "{what}: {position}");
                }
                other => panic!("{what}: {other:?}"),
            }
        }
    }
}
