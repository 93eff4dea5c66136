//! A reader for the 3D points of C3D motion-capture files (<https://www.c3d.org>).
//!
//! Our own rather than c3dio 0.8: c3dio fails on one of the five real recordings we test
//! against (Kinetics Toolkit's tennis serve, `InvalidDataType`: its parameter walk continues
//! past the zero-length name that ends the parameter list), reads the record offset as
//! unsigned, and indexes its buffers directly, so a truncated file can panic. Only what
//! kinetree needs is read: the header, the parameter section and the point samples
//! (analog samples are skipped).

use kinetree_core::{Error, Result, Tracks};
use std::collections::BTreeMap;

fn malformed(position: &str, message: impl Into<String>) -> Error {
    Error::Malformed {
        position: position.into(),
        message: message.into(),
    }
}

/// Byte order and float format, from the processor byte of the parameter section.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Processor {
    Intel,
    Dec,
    Mips,
}

impl Processor {
    fn i16(self, b: [u8; 2]) -> i16 {
        match self {
            Processor::Mips => i16::from_be_bytes(b),
            _ => i16::from_le_bytes(b),
        }
    }

    fn f32(self, b: [u8; 4]) -> f32 {
        match self {
            Processor::Intel => f32::from_le_bytes(b),
            Processor::Mips => f32::from_be_bytes(b),
            // VAX F_floating: 16-bit words high first, exponent bias 128 against 127 and a
            // hidden bit at 0.5, so the IEEE reading of the swapped words is 4x too large.
            Processor::Dec => f32::from_le_bytes([b[2], b[3], b[0], b[1]]) / 4.0,
        }
    }
}

/// One parameter: its type code (-1 char, 1 byte, 2 int16, 4 float), dimensions and raw data.
#[derive(Debug, Clone)]
struct Parameter {
    kind: i8,
    dims: Vec<usize>,
    data: Vec<u8>,
}

/// Reads `n` bytes at `at`, or a "truncated" error naming `what`.
fn slice<'a>(bytes: &'a [u8], at: usize, n: usize, what: &str) -> Result<&'a [u8]> {
    at.checked_add(n)
        .and_then(|end| bytes.get(at..end))
        .ok_or_else(|| {
            malformed(
                what,
                format!(
                    "truncated: needs bytes {at}..{} of {}",
                    at.saturating_add(n),
                    bytes.len()
                ),
            )
        })
}

fn two(bytes: &[u8], at: usize, what: &str) -> Result<[u8; 2]> {
    let s = slice(bytes, at, 2, what)?;
    Ok([s[0], s[1]])
}

fn four(bytes: &[u8], at: usize, what: &str) -> Result<[u8; 4]> {
    let s = slice(bytes, at, 4, what)?;
    Ok([s[0], s[1], s[2], s[3]])
}

/// The parameter section: `GROUP:NAME` (upper case) to parameter.
fn parameters(bytes: &[u8], start: usize, proc: Processor) -> Result<BTreeMap<String, Parameter>> {
    let n_blocks = usize::from(*bytes.get(start + 2).unwrap_or(&0)).max(1);
    let end = (start + 512 * n_blocks).min(bytes.len());
    let mut groups: BTreeMap<i8, String> = BTreeMap::new();
    let mut raw: Vec<(i8, String, Parameter)> = Vec::new();
    let mut at = start + 4;
    while at + 2 <= end {
        let name_len = usize::from((bytes[at] as i8).unsigned_abs());
        let id = bytes[at + 1] as i8;
        if name_len == 0 || id == 0 {
            break;
        }
        let name_bytes = slice(bytes, at + 2, name_len, "parameter name")?;
        let name = String::from_utf8_lossy(name_bytes)
            .trim()
            .to_ascii_uppercase();
        let p = at + 2 + name_len;
        let next = proc.i16(two(bytes, p, "parameter offset")?);
        if id < 0 {
            groups.insert(-id, name);
        } else {
            let kind = *slice(bytes, p + 2, 1, "parameter type")?
                .first()
                .unwrap_or(&0) as i8;
            let size = match kind {
                -1 | 1 => 1,
                2 => 2,
                4 => 4,
                other => {
                    return Err(malformed(
                        &format!("parameter {name}"),
                        format!("unknown data type {other}"),
                    ));
                }
            };
            let n_dims = usize::from(slice(bytes, p + 3, 1, "parameter dimensions")?[0]);
            let dims: Vec<usize> = slice(bytes, p + 4, n_dims, "parameter dimensions")?
                .iter()
                .map(|&d| usize::from(d))
                .collect();
            // Up to 255 dimensions of up to 255 each: checked, a corrupt file can overflow.
            let count = dims
                .iter()
                .try_fold(size, |acc: usize, &d| acc.checked_mul(d))
                .ok_or_else(|| malformed(&format!("parameter {name}"), "dimensions overflow"))?;
            let data = slice(bytes, p + 4 + n_dims, count, &format!("parameter {name}"))?.to_vec();
            raw.push((id, name, Parameter { kind, dims, data }));
        }
        if next <= 0 {
            break;
        }
        at = p + usize::from(next.unsigned_abs());
    }
    let mut out = BTreeMap::new();
    for (id, name, p) in raw {
        let group = groups.get(&id).cloned().unwrap_or_else(|| id.to_string());
        out.insert(format!("{group}:{name}"), p);
    }
    Ok(out)
}

impl Parameter {
    fn int(&self, proc: Processor) -> Option<i64> {
        match self.kind {
            2 if self.data.len() >= 2 => Some(i64::from(proc.i16([self.data[0], self.data[1]]))),
            1 if !self.data.is_empty() => Some(i64::from(self.data[0])),
            4 if self.data.len() >= 4 => {
                let v = proc.f32([self.data[0], self.data[1], self.data[2], self.data[3]]);
                v.is_finite().then_some(v as i64)
            }
            _ => None,
        }
    }

    fn float(&self, proc: Processor) -> Option<f64> {
        match self.kind {
            4 if self.data.len() >= 4 => Some(f64::from(proc.f32([
                self.data[0],
                self.data[1],
                self.data[2],
                self.data[3],
            ]))),
            _ => self.int(proc).map(|v| v as f64),
        }
    }

    /// A char array as strings: dims `[length, count]` (or `[length]` for one string).
    fn strings(&self) -> Vec<String> {
        if self.kind != -1 || self.dims.is_empty() {
            return Vec::new();
        }
        let len = self.dims[0].max(1);
        self.data
            .chunks(len)
            .map(|c| {
                String::from_utf8_lossy(c)
                    .trim_end_matches(['\0', ' '])
                    .trim()
                    .to_string()
            })
            .collect()
    }
}

/// The `POINT` parameters in which modelling programs (Vicon Nexus, Plug-in Gait) name the
/// points that hold their outputs (joint angles, forces, moments, powers, other scalars)
/// rather than markers.
const OUTPUT_GROUPS: [&str; 6] = [
    "ANGLES",
    "FORCES",
    "MOMENTS",
    "POWERS",
    "SCALARS",
    "REACTIONS",
];

/// Tracks from the bytes of a C3D file; see [`crate::read_c3d`].
///
/// # Errors
/// As [`crate::read_c3d`].
pub fn tracks(bytes: &[u8]) -> Result<Tracks> {
    tracks_within(bytes, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB)
}

/// [`tracks`] refusing tracks above `max_memory_gib` before allocating them.
pub(crate) fn tracks_within(bytes: &[u8], max_memory_gib: f64) -> Result<Tracks> {
    let header = slice(bytes, 0, 512, "header")?;
    if header[1] != 0x50 {
        return Err(malformed(
            "header",
            format!("byte 2 is {:#04x}, not the C3D key 0x50", header[1]),
        ));
    }
    let param_start = usize::from(header[0]).max(1).saturating_sub(1) * 512;
    let proc = match slice(bytes, param_start, 4, "parameter section")?[3] {
        84 => Processor::Intel,
        85 => Processor::Dec,
        86 => Processor::Mips,
        other => {
            return Err(malformed(
                "parameter section",
                format!("unknown processor type {other} (84, 85 or 86 expected)"),
            ));
        }
    };
    let word = |i: usize| proc.i16([header[2 * i], header[2 * i + 1]]);
    let params = parameters(bytes, param_start, proc)?;
    let get = |k: &str| params.get(k);
    let header_points = usize::from(word(1).cast_unsigned());
    let n_points = match get("POINT:USED").and_then(|p| p.int(proc)) {
        Some(n) => usize::try_from(n & 0xFFFF).unwrap_or(0),
        None => header_points,
    };
    // The stride of the data follows from the point count: two counts that disagree leave
    // it unknown.
    if n_points != header_points {
        return Err(malformed(
            "POINT:USED",
            format!(
                "is {n_points}, but the header counts {header_points} points a frame; the file is inconsistent"
            ),
        ));
    }
    let analog_per_frame = usize::from(word(2).cast_unsigned());
    let (first, last) = (word(3).cast_unsigned(), word(4).cast_unsigned());
    let mut n_frames = usize::from(last.saturating_sub(first)) + 1;
    if let Some(f) = get("POINT:FRAMES").and_then(|p| p.int(proc)) {
        // Stored as int16; files over 32767 frames wrap negative.
        n_frames = n_frames.max(usize::try_from(f & 0xFFFF).unwrap_or(0));
    }
    let scale_header = proc.f32(four(header, 12, "header scale")?);
    let scale = get("POINT:SCALE")
        .and_then(|p| p.float(proc))
        .unwrap_or(f64::from(scale_header));
    let is_float = scale < 0.0;
    let data_block = get("POINT:DATA_START")
        .and_then(|p| p.int(proc))
        .and_then(|b| usize::try_from(b & 0xFFFF).ok())
        .filter(|&b| b > 0)
        .unwrap_or(usize::from(word(8).cast_unsigned()));
    if data_block == 0 {
        return Err(malformed("header", "no data start block"));
    }
    let units: String = get("POINT:UNITS")
        .map(|p| p.strings().concat())
        .unwrap_or_else(|| "mm".into())
        .to_ascii_lowercase();
    let to_m = match units.trim() {
        "mm" => 1e-3,
        "cm" => 1e-2,
        "m" => 1.0,
        other => {
            return Err(malformed(
                "POINT:UNITS",
                format!("unknown unit {other:?}; expected mm, cm or m"),
            ));
        }
    };
    let mut labels: Vec<String> = Vec::new();
    for key in [
        "POINT:LABELS",
        "POINT:LABELS2",
        "POINT:LABELS3",
        "POINT:LABELS4",
    ] {
        if let Some(p) = get(key) {
            labels.extend(p.strings());
        }
    }
    // Writers may name more markers than they store (unused label slots); the names beyond
    // POINT:USED are reported in the tracks' warnings.
    let unused: Vec<String> = labels
        .get(n_points..)
        .unwrap_or_default()
        .iter()
        .map(|l| l.trim().to_string())
        .filter(|l| !l.is_empty())
        .collect();
    labels.resize(n_points, String::new());
    // A modelling program's outputs stored as points, named by these groups, and by the
    // groups that `POINT:TYPE_GROUPS` lists (Vicon's `MODELED_MARKERS`, ...): not markers.
    // Markers themselves are in no type group.
    let mut groups: Vec<String> = OUTPUT_GROUPS.iter().map(|g| (*g).to_string()).collect();
    for g in get("POINT:TYPE_GROUPS")
        .map(Parameter::strings)
        .unwrap_or_default()
    {
        let g = g.trim().to_ascii_uppercase();
        let names_markers = g.starts_with("LABELS") || g.starts_with("DESCRIPTIONS");
        if !g.is_empty() && !names_markers && !groups.contains(&g) {
            groups.push(g);
        }
    }
    let mut outputs: Vec<(String, Vec<String>)> = Vec::new();
    for group in &groups {
        let names: Vec<String> = get(&format!("POINT:{group}"))
            .map(Parameter::strings)
            .unwrap_or_default()
            .into_iter()
            .map(|n| n.trim().to_string())
            .filter(|n| !n.is_empty())
            .collect();
        if !names.is_empty() {
            outputs.push((group.to_string(), names));
        }
    }
    let is_output = |label: &str| {
        let label = label.trim();
        outputs
            .iter()
            .any(|(_, names)| names.iter().any(|n| n == label))
    };
    let (candidates, outputs_at): (Vec<usize>, Vec<usize>) =
        (0..n_points).partition(|&i| !is_output(&labels[i]));
    let skipped: Vec<String> = outputs_at
        .iter()
        .map(|&i| labels[i].trim().to_string())
        .collect();
    let candidate_labels: Vec<String> = candidates.iter().map(|&i| labels[i].clone()).collect();
    let model_at = crate::model_points::segment_axes(&candidate_labels);
    let model_points: Vec<String> = model_at
        .iter()
        .map(|&k| candidate_labels[k].trim().to_string())
        .collect();
    let kept: Vec<usize> = candidates
        .iter()
        .enumerate()
        .filter(|(k, _)| model_at.binary_search(k).is_err())
        .map(|(_, &i)| i)
        .collect();
    if kept.is_empty() {
        let mut named: Vec<String> = outputs.iter().map(|(g, _)| format!("POINT:{g}")).collect();
        if !model_points.is_empty() {
            named.push("Plug-in Gait's segment axes".into());
        }
        return Err(malformed(
            "POINT:LABELS",
            format!(
                "every one of the {n_points} points is a modelling output ({}); no markers",
                named.join(", ")
            ),
        ));
    }
    let labels: Vec<String> = labels
        .into_iter()
        .enumerate()
        .map(|(i, l)| {
            if l.is_empty() {
                format!("point {i}")
            } else {
                l
            }
        })
        .collect();
    let value_size = if is_float { 4 } else { 2 };
    let frame_bytes = (4 * n_points + analog_per_frame) * value_size;
    let start = (data_block - 1) * 512;
    let needed = n_frames
        .checked_mul(frame_bytes)
        .and_then(|b| b.checked_add(start))
        .ok_or_else(|| malformed("header", "frame count overflows"))?;
    if needed > bytes.len() {
        return Err(malformed(
            "point data",
            format!(
                "truncated: {n_frames} frames of {n_points} points need {needed} bytes, the file has {}",
                bytes.len()
            ),
        ));
    }
    crate::check_size(n_frames as u64, kept.len() as u64, max_memory_gib)?;
    let point_scale = if is_float { 1.0 } else { scale.abs() };
    let mut xyz = Vec::with_capacity(n_frames * kept.len() * 3);
    for t in 0..n_frames {
        let frame = &bytes[start + t * frame_bytes..start + (t + 1) * frame_bytes];
        for &i in &kept {
            let v = |k: usize| -> f64 {
                let at = (4 * i + k) * value_size;
                if is_float {
                    f64::from(proc.f32([frame[at], frame[at + 1], frame[at + 2], frame[at + 3]]))
                } else {
                    f64::from(proc.i16([frame[at], frame[at + 1]]))
                }
            };
            let p = [v(0), v(1), v(2)].map(|c| c * point_scale * to_m);
            // The fourth word: cameras in the high byte, residual in the low byte; negative
            // marks an invalid sample.
            let missing = v(3) < 0.0 || p == [0.0; 3] || !p.iter().all(|c| c.is_finite());
            if missing {
                xyz.extend([f64::NAN; 3]);
            } else {
                xyz.extend(p);
            }
        }
    }
    let labels: Vec<String> = kept.iter().map(|&i| labels[i].clone()).collect();
    let mut tracks = Tracks::new(n_frames, kept.len(), xyz)?.with_labels(labels)?;
    // The point rate: `POINT:RATE`, else the header's (a float at byte 21).
    let rate = get("POINT:RATE")
        .and_then(|p| p.float(proc))
        .unwrap_or(f64::from(proc.f32(four(header, 20, "header rate")?)));
    if rate.is_finite() && rate > 0.0 {
        tracks = tracks.with_frame_rate(rate)?;
    }
    // Integer samples lie on a grid of the scale's step; float samples carry f32's relative
    // rounding instead, which has no one step.
    if !is_float && point_scale > 0.0 {
        tracks = tracks.with_precision(point_scale * to_m)?;
    }
    let mut warnings = Vec::new();
    if !unused.is_empty() {
        warnings.push(kinetree_core::Warning::C3dLabelsUnused {
            points_used: n_points,
            labels: unused,
        });
    }
    if !skipped.is_empty() {
        warnings.push(kinetree_core::Warning::C3dOutputsSkipped {
            groups: outputs.into_iter().map(|(g, _)| g).collect(),
            labels: skipped,
        });
    }
    if !model_points.is_empty() {
        warnings.push(kinetree_core::Warning::ModelPointsSkipped {
            labels: model_points,
        });
    }
    Ok(if warnings.is_empty() {
        tracks
    } else {
        tracks.with_warnings(warnings)
    })
}
