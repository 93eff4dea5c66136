//! Reading and writing tracks (`.npy`, `.npz`, `.csv`, `.c3d`) and models (JSON).
//!
//! Every error names the file (through [`Error::File`]) and, where it can, the position.

mod c3d;
pub mod export;
mod model_points;
mod npy;
mod npz;
mod trc;

pub use npz::{DEFAULT_OCCLUDED_KEY, DEFAULT_TRACKS_KEY, DEFAULT_VISIBILITY_KEY};

pub use c3d::tracks as c3d_tracks;

use kinetree_core::{Error, Model, Result, Tracks};
use npyz::WriterBuilder;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::Path;

/// Largest frame or point index accepted in a CSV file (guards against absurd allocations).
pub const MAX_CSV_INDEX: u64 = 10_000_000;

/// Reads tracks from a `.npy`, `.npz`, `.csv`, `.c3d` or `.trc` file, chosen by extension, within
/// the default memory limit ([`read_tracks_with`]).
///
/// # Errors
/// [`Error::File`] wrapping the cause: I/O, an unknown extension, the format's own errors, or
/// [`Error::TooLarge`].
pub fn read_tracks(path: &Path) -> Result<Tracks> {
    read_tracks_with(path, &ReadOptions::default())
}

/// [`read_tracks`] refusing, before allocating them, tracks whose size (as the file declares
/// it) takes more than `max_memory_gib`.
///
/// # Errors
/// As [`read_tracks`].
pub fn read_tracks_within(path: &Path, max_memory_gib: f64) -> Result<Tracks> {
    read_tracks_with(
        path,
        &ReadOptions {
            max_memory_gib,
            ..ReadOptions::default()
        },
    )
}

/// How [`read_tracks_with`] reads a tracks file.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOptions {
    /// Tracks whose size (as the file declares it) takes more memory than this are refused
    /// before they are allocated.
    pub max_memory_gib: f64,
    /// `.npz`: the name of the `(T, N, 3)` tracks array ([`DEFAULT_TRACKS_KEY`] when `None`).
    pub tracks_key: Option<String>,
    /// `.npz`: the name of a `(T, N)` array that is true (or at least 0.5) where a sample is
    /// visible. When neither this nor `occluded_key` is given, an array named
    /// [`DEFAULT_VISIBILITY_KEY`] is used if there is one, else one named
    /// [`DEFAULT_OCCLUDED_KEY`].
    pub visibility_key: Option<String>,
    /// `.npz`: the name of a `(T, N)` array that is true (or at least 0.5) where a sample is
    /// occluded, for trackers that save occlusion rather than visibility.
    pub occluded_key: Option<String>,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            max_memory_gib: kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB,
            tracks_key: None,
            visibility_key: None,
            occluded_key: None,
        }
    }
}

/// Reads tracks from a file chosen by extension:
/// - `.npy`: a float64 or float32 `(T, N, 3)` array (C or Fortran order), NaN where a point
///   is hidden;
/// - `.npz`: such an array inside a numpy archive (`np.savez` or `np.savez_compressed`), with
///   an optional visibility or occlusion array `(T, N)` (bool, integer or probability) whose
///   hidden samples are set to NaN; the arrays' names come from `options`;
/// - `.csv`: `frame,point,x,y,z` rows ([`read_csv`]);
/// - `.c3d`: motion-capture markers ([`read_c3d`]);
/// - `.trc`: OpenSim's marker text format ([`read_trc`]).
///
/// # Errors
/// [`Error::File`] wrapping the cause: I/O, an unknown extension, array names given for a
/// file that is not `.npz`, a missing array (the message lists the archive's arrays), the
/// format's own errors, or [`Error::TooLarge`].
pub fn read_tracks_with(path: &Path, options: &ReadOptions) -> Result<Tracks> {
    let inner = || -> Result<Tracks> {
        kinetree_core::limits::validate_limit("max_memory_gib", options.max_memory_gib)?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let named = [
            ("tracks", &options.tracks_key),
            ("visibility", &options.visibility_key),
            ("occluded", &options.occluded_key),
        ];
        if ext.as_deref() != Some("npz")
            && let Some((what, _)) = named.iter().find(|(_, k)| k.is_some())
        {
            return Err(Error::Config(format!(
                "a {what} array name is for .npz archives only"
            )));
        }
        let max_memory_gib = options.max_memory_gib;
        match ext.as_deref() {
            Some("npy") => read_npy_inner(path, max_memory_gib),
            Some("npz") => npz::read(path, options),
            Some("csv") => read_csv_inner(path, max_memory_gib),
            Some("c3d") => {
                let bytes = std::fs::read(path)?;
                c3d::tracks_within(&bytes, max_memory_gib)
            }
            Some("trc") => trc::tracks_within(&std::fs::read_to_string(path)?, max_memory_gib),
            _ => Err(Error::Malformed {
                position: "file name".into(),
                message: "unknown extension; expected .npy, .npz, .csv, .c3d or .trc".into(),
            }),
        }
    };
    inner().map_err(|e| e.in_file(path))
}

/// Reads the marker trajectories of a C3D motion-capture file: one point per marker in the
/// file's order, labelled with its `POINT:LABELS` name (`point <i>` when unnamed), converted
/// to metres from `POINT:UNITS` (`mm`, `cm` or `m`; another unit is an error), at the frame
/// rate of `POINT:RATE` (else the header's). Intel, DEC and MIPS files, integer or float data.
/// Modelling outputs stored as points are left out with warnings naming them: the points that
/// `POINT:ANGLES`, `FORCES`, `MOMENTS`, `POWERS`, `SCALARS`, `REACTIONS` or a group listed in
/// `POINT:TYPE_GROUPS` name, and Plug-in Gait's segment axes.
///
/// A sample is *not visible* when its residual word is negative (the C3D convention for an
/// invalid point), when it is exactly `(0, 0, 0)` (how several writers store a missing
/// marker), or when a coordinate is not finite.
///
/// # Errors
/// [`Error::Malformed`] for a truncated or corrupt file or an unknown unit, and the
/// validation errors of [`Tracks::new`], all inside [`Error::File`].
pub fn read_c3d(path: &Path) -> Result<Tracks> {
    let bytes = std::fs::read(path).map_err(|e| Error::from(e).in_file(path))?;
    c3d::tracks(&bytes).map_err(|e| e.in_file(path))
}

/// Reads the markers of a TRC file (OpenSim's tab-separated marker format): one point per
/// marker, named from the fourth header line, converted to metres from the header's `Units`
/// (`mm`, `cm` or `m`), at the header's `DataRate`. A sample is not visible where a
/// coordinate is empty or `NaN`, or where the line ends before it.
///
/// # Errors
/// [`Error::Malformed`] naming the line for a missing header line or column, an unknown unit,
/// more names than `NumMarkers`, a field that is not a number, values beyond the markers'
/// columns, or no frames; [`Error::TooLarge`]; the validation errors of [`Tracks::new`]; all
/// inside [`Error::File`].
pub fn read_trc(path: &Path) -> Result<Tracks> {
    let inner = || -> Result<Tracks> {
        trc::tracks_within(
            &std::fs::read_to_string(path)?,
            kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB,
        )
    };
    inner().map_err(|e| e.in_file(path))
}

/// Reads the visible samples of one point's track, in metres:
/// - a float `.npy` array of shape `(T, 3)`, `(T, 1, 3)`, or `(T, N, 3)` with `point` (NaN
///   rows are hidden samples);
/// - any other tracks file ([`read_tracks_with`] and `options`: `.npz`, `.csv`, `.c3d`,
///   `.trc`) with `point`;
/// - otherwise plain text, one sample `x y z` per line ([`read_point_track`]), `point` then
///   being `None` or 0.
///
/// # Errors
/// [`Error::Config`] for a missing `point` where the file holds several, or a `point` beyond
/// them; [`Error::Shape`] or [`Error::DType`] for another array; the readers' errors; all
/// inside [`Error::File`].
pub fn read_one_track(
    path: &Path,
    point: Option<usize>,
    options: &ReadOptions,
) -> Result<Vec<kinetree_core::nalgebra::Point3<f64>>> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let pick = |n_points: usize| -> Result<usize> {
        match point {
            Some(i) if i < n_points => Ok(i),
            Some(i) => Err(Error::Config(format!(
                "point {i} does not exist: the file holds {n_points} point(s)"
            ))),
            None if n_points == 1 => Ok(0),
            None => Err(Error::Config(format!(
                "the file holds {n_points} points; choose one (`--point`)"
            ))),
        }
    };
    match ext.as_deref() {
        Some("npy") => {
            let inner = || -> Result<Vec<kinetree_core::nalgebra::Point3<f64>>> {
                let file_len = std::fs::metadata(path)?.len();
                let file = BufReader::new(File::open(path)?);
                let array = npy::read_array(file, file_len, |shape, dtype| {
                    check_float_dtype(dtype)?;
                    let one = matches!(shape, [_, 3] | [_, _, 3]);
                    if !one {
                        return Err(Error::Shape {
                            expected: "(T, 3), (T, 1, 3) or (T, N, 3)".into(),
                            found: format!("{shape:?}"),
                        });
                    }
                    let n_points = if shape.len() == 3 { shape[1] } else { 1 };
                    check_size(shape[0], n_points, options.max_memory_gib)
                })?;
                let n_points = if array.shape.len() == 3 {
                    array.shape[1] as usize
                } else {
                    1
                };
                let i = pick(n_points)?;
                Ok(array
                    .values
                    .chunks_exact(3 * n_points)
                    .map(|frame| &frame[3 * i..3 * i + 3])
                    .filter(|p| p.iter().all(|v| v.is_finite()))
                    .map(|p| kinetree_core::nalgebra::Point3::new(p[0], p[1], p[2]))
                    .collect())
            };
            inner().map_err(|e| e.in_file(path))
        }
        Some("npz" | "csv" | "c3d" | "trc") => {
            let tracks = read_tracks_with(path, options)?;
            let i = pick(tracks.n_points()).map_err(|e| e.in_file(path))?;
            Ok((0..tracks.n_frames())
                .filter_map(|f| tracks.get(f, i))
                .collect())
        }
        _ => match point {
            Some(i) if i > 0 => Err(Error::Config(format!(
                "point {i} does not exist: a text track holds one point"
            ))
            .in_file(path)),
            _ => read_point_track(path),
        },
    }
}

/// Reads one point's track from plain text, one sample `x y z` (metres) per line separated by
/// spaces, tabs or commas; blank lines are skipped. The format of the door and drawer tracks
/// in experiments/real/data/sturm-door-drawer.
///
/// # Errors
/// [`Error::Malformed`] naming the line for a line without three finite numbers, inside
/// [`Error::File`].
pub fn read_point_track(path: &Path) -> Result<Vec<kinetree_core::nalgebra::Point3<f64>>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::from(e).in_file(path))?;
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|f| !f.is_empty())
            .collect();
        if fields.is_empty() {
            continue;
        }
        let values: Vec<f64> = fields.iter().filter_map(|f| f.parse().ok()).collect();
        if fields.len() != 3 || values.len() != 3 || !values.iter().all(|v| v.is_finite()) {
            return Err(Error::Malformed {
                position: format!("line {}", k + 1),
                message: format!("expected three finite numbers `x y z`, got {line:?}"),
            }
            .in_file(path));
        }
        out.push(kinetree_core::nalgebra::Point3::new(
            values[0], values[1], values[2],
        ));
    }
    Ok(out)
}

/// Reads a float64 or float32 `(T, N, 3)` `.npy` array, NaN for occluded points (C or
/// Fortran order).
///
/// # Errors
/// [`Error::DType`] for another element type, [`Error::Shape`] for another shape, and the
/// validation errors of [`Tracks::new`], all inside [`Error::File`].
pub fn read_npy(path: &Path) -> Result<Tracks> {
    read_npy_inner(path, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB).map_err(|e| e.in_file(path))
}

/// Checks a declared `n_frames x n_points` against the memory limit before it is allocated.
pub(crate) fn check_size(n_frames: u64, n_points: u64, max_memory_gib: f64) -> Result<()> {
    kinetree_core::limits::check_memory(
        &format!("reading {n_frames} frames x {n_points} points"),
        kinetree_core::limits::tracks_bytes(n_frames, n_points),
        max_memory_gib,
    )
}

/// Refuses an array whose elements are not float64 or float32 (little-endian).
fn check_float_dtype(dtype: &str) -> Result<()> {
    if dtype != "<f8" && dtype != "<f4" {
        return Err(Error::DType {
            expected: "float64 ('<f8') or float32 ('<f4')".into(),
            found: dtype.into(),
        });
    }
    Ok(())
}

/// Refuses a tracks array that is not float `(T, N, 3)` or does not fit the memory limit.
pub(crate) fn check_tracks_array(shape: &[u64], dtype: &str, max_memory_gib: f64) -> Result<()> {
    check_float_dtype(dtype)?;
    if shape.len() != 3 || shape[2] != 3 {
        return Err(Error::Shape {
            expected: "(T, N, 3)".into(),
            found: format!("{shape:?}"),
        });
    }
    check_size(shape[0], shape[1], max_memory_gib)
}

fn read_npy_inner(path: &Path, max_memory_gib: f64) -> Result<Tracks> {
    let file_len = std::fs::metadata(path)?.len();
    let file = BufReader::new(File::open(path)?);
    let array = npy::read_array(file, file_len, |shape, dtype| {
        check_tracks_array(shape, dtype, max_memory_gib)
    })?;
    Tracks::new(
        array.shape[0] as usize,
        array.shape[1] as usize,
        array.values,
    )
}

/// Writes a file all at once or not at all: `write` fills a temporary file beside `path`,
/// which is then renamed over it. A failed write (disk full, a file-size limit, an error in
/// `write`) leaves any file already at `path` as it was. A `path` that is a device or a pipe
/// (`/dev/null`, `/dev/stdout`, a FIFO) is written in place: a file renamed over it would
/// replace the device node itself.
///
/// # Errors
/// [`Error::File`] naming `path`, wrapping the I/O error or `write`'s own.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
) -> Result<()> {
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir()) {
        let in_place = || -> Result<()> {
            let mut file = std::fs::OpenOptions::new().write(true).open(path)?;
            let mut w = BufWriter::new(&mut file);
            write(&mut w)?;
            w.flush()?;
            Ok(())
        };
        return in_place().map_err(|e| e.in_file(path));
    }
    let inner = || -> Result<()> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let mut builder = tempfile::Builder::new();
        builder.prefix(".kinetree-").suffix(".part");
        // A temporary file is private (0600); the result is an ordinary output file.
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o644));
        let mut temp = builder.tempfile_in(dir)?;
        {
            let mut w = BufWriter::new(temp.as_file_mut());
            write(&mut w)?;
            w.flush()?;
        }
        temp.as_file().sync_all()?;
        temp.persist(path).map_err(|e| Error::Io(e.error))?;
        Ok(())
    };
    inner().map_err(|e| e.in_file(path))
}

/// Writes `text` to `path` with [`write_atomically`].
///
/// # Errors
/// As [`write_atomically`].
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomically(path, |w| Ok(w.write_all(text.as_bytes())?))
}

/// Writes tracks as a float64 `(T, N, 3)` `.npy` array (C order, NaN for occluded points),
/// atomically.
///
/// # Errors
/// [`Error::File`] wrapping the I/O error.
pub fn write_npy(path: &Path, tracks: &Tracks) -> Result<()> {
    write_array_npy(
        path,
        &[tracks.n_frames(), tracks.n_points(), 3],
        tracks.raw(),
    )
}

/// Writes `values` as a float64 `.npy` array of `shape` (C order), atomically.
///
/// # Errors
/// [`Error::Shape`] when `values` does not hold the product of `shape`; [`Error::File`]
/// wrapping the I/O error.
pub fn write_array_npy(path: &Path, shape: &[usize], values: &[f64]) -> Result<()> {
    if shape.iter().product::<usize>() != values.len() {
        return Err(Error::Shape {
            expected: format!(
                "{} values for an array of shape {shape:?}",
                shape.iter().product::<usize>()
            ),
            found: format!("{} values", values.len()),
        }
        .in_file(path));
    }
    let dims: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    write_atomically(path, |file| {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&dims)
            .writer(file)
            .begin_nd()?;
        w.extend(values.iter().copied())?;
        w.finish()?;
        Ok(())
    })
}

/// Writes tracks as an `.npz` archive (deflated, as `np.savez_compressed`) of a float64
/// `(T, N, 3)` array [`DEFAULT_TRACKS_KEY`], NaN for occluded points, and a bool `(T, N)`
/// array [`DEFAULT_VISIBILITY_KEY`], atomically.
///
/// # Errors
/// [`Error::File`] wrapping the I/O or archive error.
pub fn write_npz(path: &Path, tracks: &Tracks) -> Result<()> {
    let (t, n) = (tracks.n_frames() as u64, tracks.n_points() as u64);
    let zip_error = |e: zip::result::ZipError| Error::Malformed {
        position: "archive".into(),
        message: e.to_string(),
    };
    write_atomically(path, |file| {
        let mut zip = zip::ZipWriter::new(file);
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated)
            // Archives of any size: the zip64 sizes cost a few bytes.
            .large_file(true);
        zip.start_file(format!("{DEFAULT_TRACKS_KEY}.npy"), options)
            .map_err(zip_error)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[t, n, 3])
            .writer(&mut zip)
            .begin_nd()?;
        w.extend(tracks.raw().iter().copied())?;
        w.finish()?;
        zip.start_file(format!("{DEFAULT_VISIBILITY_KEY}.npy"), options)
            .map_err(zip_error)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[t, n])
            .writer(&mut zip)
            .begin_nd()?;
        w.extend(tracks.raw().chunks_exact(3).map(|p| !p[0].is_nan()))?;
        w.finish()?;
        zip.finish().map_err(zip_error)?;
        Ok(())
    })
}

/// Reads `frame,point,x,y,z` rows (header required; one row per visible observation;
/// indices 0-based); a (frame, point) without a row is occluded. An optional comment line
/// before the header, `# frames=T points=N`, fixes the size (so points or frames that are
/// never visible at the end are kept); without it `T` and `N` are one more than the largest
/// indices.
///
/// # Errors
/// [`Error::Malformed`] naming the line for a bad header, a wrong number of fields, a
/// non-integer or out-of-range index, a non-numeric coordinate or a duplicate row;
/// [`Error::NonFinite`] for inf or NaN coordinates; then the errors of [`Tracks::new`].
pub fn read_csv(path: &Path) -> Result<Tracks> {
    read_csv_inner(path, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB).map_err(|e| e.in_file(path))
}

fn read_csv_inner(path: &Path, max_memory_gib: f64) -> Result<Tracks> {
    let reader = BufReader::new(File::open(path)?);
    let mut rows: Vec<(usize, usize, [f64; 3])> = Vec::new();
    let mut header_seen = false;
    let mut declared: (Option<usize>, Option<usize>) = (None, None);
    for (k, line) in reader.lines().enumerate() {
        let line = line?;
        let lineno = k + 1;
        let trimmed = line.trim();
        if let Some(comment) = trimmed.strip_prefix('#') {
            if !header_seen {
                for token in comment.split_whitespace() {
                    let parse = |v: &str| -> Result<usize> {
                        v.parse::<usize>()
                            .ok()
                            .filter(|&x| x as u64 <= MAX_CSV_INDEX)
                            .ok_or_else(|| Error::Malformed {
                                position: format!("line {lineno}"),
                                message: format!("bad size declaration `{token}`"),
                            })
                    };
                    if let Some(v) = token.strip_prefix("frames=") {
                        declared.0 = Some(parse(v)?);
                    } else if let Some(v) = token.strip_prefix("points=") {
                        declared.1 = Some(parse(v)?);
                    }
                }
            }
            continue;
        }
        if trimmed.is_empty() {
            continue;
        }
        let fields: Vec<&str> = trimmed.split(',').map(str::trim).collect();
        if !header_seen {
            if fields != ["frame", "point", "x", "y", "z"] {
                return Err(Error::Malformed {
                    position: format!("line {lineno}"),
                    message: format!("expected header `frame,point,x,y,z`, found `{trimmed}`"),
                });
            }
            header_seen = true;
            continue;
        }
        let bad = |message: String| Error::Malformed {
            position: format!("line {lineno}"),
            message,
        };
        if fields.len() != 5 {
            return Err(bad(format!("expected 5 fields, found {}", fields.len())));
        }
        let index = |name: &str, s: &str| -> Result<usize> {
            let v: u64 = s
                .parse()
                .map_err(|_| bad(format!("{name} `{s}` is not a non-negative integer")))?;
            if v > MAX_CSV_INDEX {
                return Err(bad(format!(
                    "{name} {v} out of range (max {MAX_CSV_INDEX})"
                )));
            }
            Ok(v as usize)
        };
        let frame = index("frame", fields[0])?;
        let point = index("point", fields[1])?;
        for (name, v, limit) in [("frame", frame, declared.0), ("point", point, declared.1)] {
            if let Some(limit) = limit
                && v >= limit
            {
                return Err(bad(format!(
                    "{name} {v} out of range (the file declares {limit})"
                )));
            }
        }
        let mut xyz = [0.0; 3];
        for (c, s) in fields[2..].iter().enumerate() {
            let v: f64 = s
                .parse()
                .map_err(|_| bad(format!("coordinate `{s}` is not a number")))?;
            if !v.is_finite() {
                return Err(Error::Malformed {
                    position: format!("line {lineno}"),
                    message: format!(
                        "frame {frame}, point {point}: non-finite coordinate `{s}` (leave occluded observations out)"
                    ),
                });
            }
            xyz[c] = v;
        }
        rows.push((frame, point, xyz));
    }
    if !header_seen {
        return Err(Error::Malformed {
            position: "line 1".into(),
            message: "empty file; expected header `frame,point,x,y,z`".into(),
        });
    }
    if rows.is_empty() {
        return Err(Error::NoVisibleData);
    }
    let t = declared
        .0
        .unwrap_or_else(|| rows.iter().map(|r| r.0).max().unwrap_or(0) + 1);
    let n = declared
        .1
        .unwrap_or_else(|| rows.iter().map(|r| r.1).max().unwrap_or(0) + 1);
    check_size(t as u64, n as u64, max_memory_gib)?;
    let total = t * n;
    let mut xyz = vec![f64::NAN; total * 3];
    let mut seen = vec![false; total];
    for (line, (frame, point, p)) in rows.iter().enumerate() {
        let k = frame * n + point;
        if seen[k] {
            return Err(Error::Malformed {
                position: format!("data row {}", line + 1),
                message: format!("duplicate row for frame {frame}, point {point}"),
            });
        }
        seen[k] = true;
        xyz[k * 3..k * 3 + 3].copy_from_slice(p);
    }
    Tracks::new(t, n, xyz)
}

/// Writes tracks as `frame,point,x,y,z` rows, one per visible observation, after a
/// `# frames=T points=N` size line, atomically.
///
/// # Errors
/// [`Error::File`] wrapping the I/O error.
pub fn write_csv(path: &Path, tracks: &Tracks) -> Result<()> {
    write_atomically(path, |w| {
        writeln!(
            w,
            "# frames={} points={}",
            tracks.n_frames(),
            tracks.n_points()
        )?;
        writeln!(w, "frame,point,x,y,z")?;
        for t in 0..tracks.n_frames() {
            for i in 0..tracks.n_points() {
                if let Some(p) = tracks.get(t, i) {
                    writeln!(w, "{t},{i},{:?},{:?},{:?}", p.x, p.y, p.z)?;
                }
            }
        }
        Ok(())
    })
}

/// Writes any serialisable value as pretty JSON, atomically.
///
/// # Errors
/// [`Error::File`] wrapping the I/O or serialisation error.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    write_atomically(path, |w| {
        serde_json::to_writer_pretty(&mut *w, value).map_err(|e| Error::Malformed {
            position: "serialisation".into(),
            message: e.to_string(),
        })?;
        w.write_all(b"\n")?;
        Ok(())
    })
}

/// Reads a JSON file into `T` (a simulator's `truth.json`, say).
///
/// # Errors
/// [`Error::File`] around an I/O error or [`Error::Malformed`] with the line and column
/// where the JSON does not parse or does not fit `T`.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let inner = || -> Result<T> {
        let reader = BufReader::new(File::open(path)?);
        serde_json::from_reader(reader).map_err(|e| Error::Malformed {
            position: format!("line {}, column {}", e.line(), e.column()),
            message: e.to_string(),
        })
    };
    inner().map_err(|e| e.in_file(path))
}

/// Reads a model JSON file and checks it with [`Model::validate`].
///
/// # Errors
/// [`Error::File`] wrapping the I/O error, [`Error::Malformed`] with the line and column, or
/// [`Error::InvalidModel`] naming the field that breaks the schema's rules.
pub fn read_model(path: &Path) -> Result<Model> {
    let model: Model = read_json(path)?;
    model.validate().map_err(|e| e.in_file(path))?;
    Ok(model)
}
