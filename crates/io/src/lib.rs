//! Reading and writing tracks (`.npy`, `.csv`) and models (JSON).
//!
//! Every error names the file (through [`Error::File`]) and, where it can, the position.

mod c3d;
pub mod export;

pub use c3d::tracks as c3d_tracks;

use kinetree_core::{Error, Model, Result, Tracks};
use npyz::WriterBuilder;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::Path;

/// Largest frame or point index accepted in a CSV file (guards against absurd allocations).
pub const MAX_CSV_INDEX: u64 = 10_000_000;

/// Reads tracks from a `.npy`, `.csv` or `.c3d` file, chosen by extension, within the default
/// memory limit ([`read_tracks_within`]).
///
/// # Errors
/// [`Error::File`] wrapping the cause: I/O, an unknown extension, the format's own errors, or
/// [`Error::TooLarge`].
pub fn read_tracks(path: &Path) -> Result<Tracks> {
    read_tracks_within(path, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB)
}

/// [`read_tracks`] refusing, before allocating them, tracks whose size (as the file declares
/// it) takes more than `max_memory_gib`.
///
/// # Errors
/// As [`read_tracks`].
pub fn read_tracks_within(path: &Path, max_memory_gib: f64) -> Result<Tracks> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("npy") => read_npy_inner(path, max_memory_gib).map_err(|e| e.in_file(path)),
        Some("csv") => read_csv_inner(path, max_memory_gib).map_err(|e| e.in_file(path)),
        Some("c3d") => {
            let bytes = std::fs::read(path).map_err(|e| Error::from(e).in_file(path))?;
            c3d::tracks_within(&bytes, max_memory_gib).map_err(|e| e.in_file(path))
        }
        _ => Err(Error::Malformed {
            position: "file name".into(),
            message: "unknown extension; expected .npy, .csv or .c3d".into(),
        }
        .in_file(path)),
    }
}

/// Reads the marker trajectories of a C3D motion-capture file: one point per marker in the
/// file's order, labelled with its `POINT:LABELS` name (`point <i>` when unnamed), converted
/// to metres from `POINT:UNITS` (`mm`, `cm` or `m`; another unit is an error). Intel, DEC and
/// MIPS files, integer or float data.
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

/// Reads a float64 `(T, N, 3)` `.npy` array, NaN for occluded points (C or Fortran order).
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

/// The `shape` an npy header declares, read before npyz sees the file: npyz multiplies the
/// dimensions unchecked (a panic in debug builds, a wrapped count in release ones), so a
/// hostile header must be refused first. `None` when the header cannot be read this way;
/// npyz then reports what is wrong with it.
fn npy_declared_shape(path: &Path) -> Result<Option<Vec<u128>>> {
    use std::io::Read;
    let mut file = File::open(path)?;
    let mut start = [0u8; 12];
    if file.read_exact(&mut start).is_err() || &start[..6] != b"\x93NUMPY" {
        return Ok(None);
    }
    let (len, skip) = match start[6] {
        1 => (usize::from(u16::from_le_bytes([start[8], start[9]])), 10),
        _ => (
            u32::from_le_bytes([start[8], start[9], start[10], start[11]]) as usize,
            12,
        ),
    };
    // Headers are a few hundred bytes; a longer one is left to npyz.
    if len > 1 << 16 {
        return Ok(None);
    }
    let mut header = start[skip..].to_vec();
    header.resize(len, 0);
    if file.read_exact(&mut header[12 - skip..]).is_err() {
        return Ok(None);
    }
    let text = String::from_utf8_lossy(&header);
    let Some(after) = text.split_once("'shape'").map(|(_, a)| a) else {
        return Ok(None);
    };
    let Some(inside) = after
        .split_once('(')
        .and_then(|(_, a)| a.split_once(')'))
        .map(|(i, _)| i)
    else {
        return Ok(None);
    };
    let dims: Option<Vec<u128>> = inside
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.trim_end_matches('L').parse().ok())
        .collect();
    Ok(dims)
}

/// Refuses an npy shape whose float64 data would not fit in the file's `file_len` bytes, or
/// whose strides (npyz multiplies the dimensions, zero-sized ones left out) overflow 64 bits.
fn check_npy_shape(dims: &[u128], file_len: u64) -> Result<()> {
    let bytes = dims
        .iter()
        .try_fold(8u128, |acc, &d| acc.checked_mul(d))
        .filter(|&b| b <= u128::from(file_len));
    let strides_fit = dims
        .iter()
        .try_fold(8u128, |acc, &d| acc.checked_mul(d.max(1)))
        .is_some_and(|b| b <= u128::from(u64::MAX));
    if bytes.is_none() || !strides_fit {
        return Err(Error::Malformed {
            position: "header".into(),
            message: format!(
                "shape {dims:?} needs more float64 data than the file's {file_len} bytes"
            ),
        });
    }
    Ok(())
}

fn read_npy_inner(path: &Path, max_memory_gib: f64) -> Result<Tracks> {
    let file_len = std::fs::metadata(path)?.len();
    if let Some(dims) = npy_declared_shape(path)? {
        check_npy_shape(&dims, file_len)?;
    }
    let file = File::open(path)?;
    let npy = npyz::NpyFile::new(BufReader::new(file)).map_err(|e| Error::Malformed {
        position: "header".into(),
        message: e.to_string(),
    })?;
    let dtype = npy.dtype();
    let type_str = match &dtype {
        npyz::DType::Plain(t) => t.to_string(),
        other => format!("{other:?}"),
    };
    if type_str != "<f8" {
        return Err(Error::DType {
            expected: "float64 ('<f8')".into(),
            found: type_str,
        });
    }
    let shape: Vec<u64> = npy.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 {
        return Err(Error::Shape {
            expected: "(T, N, 3)".into(),
            found: format!("{shape:?}"),
        });
    }
    // A header may claim any shape: the data must be in the file, and fit the limit, before
    // they are allocated.
    let dims: Vec<u128> = shape.iter().map(|&d| u128::from(d)).collect();
    check_npy_shape(&dims, file_len)?;
    check_size(shape[0], shape[1], max_memory_gib)?;
    let (t, n) = (shape[0] as usize, shape[1] as usize);
    let order = npy.order();
    let data: Vec<f64> = npy.into_vec::<f64>().map_err(|e| Error::Malformed {
        position: "data".into(),
        message: e.to_string(),
    })?;
    let xyz = if order == npyz::Order::Fortran {
        // Element (i, j, k) sits at i + T j + T N k in Fortran order.
        let mut c = vec![0.0; data.len()];
        for i in 0..t {
            for j in 0..n {
                for k in 0..3 {
                    c[(i * n + j) * 3 + k] = data[i + t * j + t * n * k];
                }
            }
        }
        c
    } else {
        data
    };
    Tracks::new(t, n, xyz)
}

/// Writes a file all at once or not at all: `write` fills a temporary file beside `path`,
/// which is then renamed over it. A failed write (disk full, a file-size limit, an error in
/// `write`) leaves any file already at `path` as it was.
///
/// # Errors
/// [`Error::File`] naming `path`, wrapping the I/O error or `write`'s own.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
) -> Result<()> {
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
    write_atomically(path, |file| {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[tracks.n_frames() as u64, tracks.n_points() as u64, 3])
            .writer(file)
            .begin_nd()?;
        w.extend(tracks.raw().iter().copied())?;
        w.finish()?;
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

/// Reads a model JSON file and checks it with [`Model::validate`].
///
/// # Errors
/// [`Error::File`] wrapping the I/O error, [`Error::Malformed`] with the line and column, or
/// [`Error::InvalidModel`] naming the field that breaks the schema's rules.
pub fn read_model(path: &Path) -> Result<Model> {
    let inner = || -> Result<Model> {
        let reader = BufReader::new(File::open(path)?);
        let model: Model = serde_json::from_reader(reader).map_err(|e| Error::Malformed {
            position: format!("line {}, column {}", e.line(), e.column()),
            message: e.to_string(),
        })?;
        model.validate()?;
        Ok(model)
    };
    inner().map_err(|e| e.in_file(path))
}
