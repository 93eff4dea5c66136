//! Tracks from an `.npz` archive, the form in which video point trackers save dense 3D tracks:
//! a `(T, N, 3)` array and optionally a `(T, N)` visibility (or occlusion) array.

use crate::{ReadOptions, check_tracks_array, npy};
use kinetree_core::{Error, Result, Tracks};
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;

/// The tracks array's name when none is given.
pub const DEFAULT_TRACKS_KEY: &str = "tracks";
/// The visibility array's name looked for when none is given.
pub const DEFAULT_VISIBILITY_KEY: &str = "visibility";
/// The occlusion array's name looked for when neither array is named nor `visibility` found.
pub const DEFAULT_OCCLUDED_KEY: &str = "occluded";

/// A flag value at or above this counts as true: booleans and 0/1 integers read as such,
/// float arrays as probabilities.
const FLAG_THRESHOLD: f64 = 0.5;

fn archive_error(message: String) -> Error {
    Error::Malformed {
        position: "archive".into(),
        message,
    }
}

/// The arrays an archive holds, by name (`x.npy` holds array `x`), in the archive's order.
fn array_names<R: Read + Seek>(archive: &zip::ZipArchive<R>) -> Vec<String> {
    archive
        .file_names()
        // A name that is not valid text cannot be asked for, so it is not listed.
        .filter_map(|f| f.ok()?.strip_suffix(".npy").map(str::to_string))
        .collect()
}

/// Reads array `key` of the archive, after `check` has seen its shape and type.
fn read_entry<R: Read + Seek>(
    archive: &mut zip::ZipArchive<R>,
    key: &str,
    check: impl FnOnce(&[u64], &str) -> Result<()>,
) -> Result<npy::Array> {
    let entry = archive
        .by_name(&format!("{key}.npy"))
        .map_err(|e| archive_error(format!("array `{key}`: {e}")))?;
    let size = entry.size();
    npy::read_array(BufReader::new(entry), size, check).map_err(|e| match e {
        Error::Malformed { position, message } => Error::Malformed {
            position: format!("array `{key}`, {position}"),
            message,
        },
        Error::DType { expected, found } => Error::DType {
            expected: format!("{expected} for array `{key}`"),
            found,
        },
        Error::Shape { expected, found } => Error::Shape {
            expected: format!("{expected} for array `{key}`"),
            found,
        },
        other => other,
    })
}

/// Reads tracks from an `.npz` archive (see [`crate::read_tracks_with`]).
pub(crate) fn read(path: &Path, options: &ReadOptions) -> Result<Tracks> {
    let file = BufReader::new(File::open(path)?);
    let mut archive = zip::ZipArchive::new(file)
        .map_err(|e| archive_error(format!("not a readable .npz (zip) archive: {e}")))?;
    let names = array_names(&archive);
    let listed = || {
        if names.is_empty() {
            "no arrays".to_string()
        } else {
            format!("the arrays {}", names.join(", "))
        }
    };
    let tracks_key = options.tracks_key.as_deref().unwrap_or(DEFAULT_TRACKS_KEY);
    if !names.iter().any(|n| n == tracks_key) {
        return Err(archive_error(format!(
            "no array `{tracks_key}`; the archive holds {}. Name the (T, N, 3) tracks array \
             with --tracks-key (`tracks_key` in a config)",
            listed()
        )));
    }
    if options.visibility_key.is_some() && options.occluded_key.is_some() {
        return Err(Error::Config(
            "name a visibility array or an occlusion array, not both".into(),
        ));
    }
    let has = |k: &str| names.iter().any(|n| n == k);
    // The flag array and whether it marks visible (true) or occluded (false) samples.
    let flags: Option<(&str, bool)> = match (&options.visibility_key, &options.occluded_key) {
        (Some(v), _) => Some((v, true)),
        (_, Some(o)) => Some((o, false)),
        _ if has(DEFAULT_VISIBILITY_KEY) => Some((DEFAULT_VISIBILITY_KEY, true)),
        _ if has(DEFAULT_OCCLUDED_KEY) => Some((DEFAULT_OCCLUDED_KEY, false)),
        _ => None,
    };
    if let Some((key, _)) = flags
        && !has(key)
    {
        return Err(archive_error(format!(
            "no array `{key}`; the archive holds {}",
            listed()
        )));
    }
    let max_memory_gib = options.max_memory_gib;
    let tracks = read_entry(&mut archive, tracks_key, |shape, dtype| {
        check_tracks_array(shape, dtype, max_memory_gib)
    })?;
    let (t, n) = (tracks.shape[0], tracks.shape[1]);
    let mut xyz = tracks.values;
    if let Some((key, marks_visible)) = flags {
        let flag = read_entry(&mut archive, key, |shape, _| {
            if shape != [t, n] {
                return Err(Error::Shape {
                    expected: format!("(T, N) = ({t}, {n}), as the tracks"),
                    found: format!("{shape:?}"),
                });
            }
            Ok(())
        })?;
        for (k, &v) in flag.values.iter().enumerate() {
            // NaN compares false, so a NaN flag never marks a sample visible.
            let visible = if marks_visible {
                v >= FLAG_THRESHOLD
            } else {
                v < FLAG_THRESHOLD
            };
            if !visible {
                xyz[k * 3..k * 3 + 3].fill(f64::NAN);
            }
        }
    }
    Tracks::new(t as usize, n as usize, xyz)
}
