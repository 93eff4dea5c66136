//! `.npz` archives as video point trackers write them: tracks under various names, float64
//! or float32, with a visibility or occlusion array, stored or deflated.

use kinetree_core::{Error, Tracks};
use kinetree_io::{ReadOptions, read_tracks, read_tracks_with, write_npy, write_npz};
use kinetree_synth::{RandomParams, random_scenario, simulate};
use npyz::WriterBuilder;
use std::io::Write;
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kinetree-npz-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).expect("dir");
    d
}

/// Simulated tracks with a fifth of the samples hidden.
fn sample_tracks(seed: u64) -> Tracks {
    simulate(&random_scenario(&RandomParams {
        n_joints: 2,
        n_frames: 40,
        dropout: 0.2,
        seed,
        ..RandomParams::default()
    }))
    .expect("simulate")
    .tracks
}

/// One npy file's bytes.
fn npy_bytes<T: npyz::AutoSerialize>(
    shape: &[u64],
    values: impl IntoIterator<Item = T>,
) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut bytes)
        .begin_nd()
        .expect("header");
    w.extend(values).expect("data");
    w.finish().expect("finish");
    bytes
}

/// An archive's entries: file name and bytes.
type Entries = Vec<(&'static str, Vec<u8>)>;

/// Writes an archive of `entries` (file name, bytes) with `method`.
fn write_zip(path: &Path, entries: &[(&str, Vec<u8>)], method: zip::CompressionMethod) {
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).expect("create"));
    let options = zip::write::SimpleFileOptions::default().compression_method(method);
    for (name, bytes) in entries {
        zip.start_file(*name, options).expect("entry");
        zip.write_all(bytes).expect("write");
    }
    zip.finish().expect("finish");
}

/// The tracks' coordinates with hidden samples at zero (as trackers store them) and their
/// visibility flags.
fn zeroed_and_visible(tracks: &Tracks) -> (Vec<f64>, Vec<bool>) {
    let visible: Vec<bool> = tracks
        .raw()
        .chunks_exact(3)
        .map(|p| !p[0].is_nan())
        .collect();
    let zeroed = tracks
        .raw()
        .iter()
        .map(|v| if v.is_nan() { 0.0 } else { *v })
        .collect();
    (zeroed, visible)
}

fn assert_same_samples(a: &Tracks, b: &Tracks) {
    assert_eq!((a.n_frames(), a.n_points()), (b.n_frames(), b.n_points()));
    for t in 0..a.n_frames() {
        for i in 0..a.n_points() {
            assert_eq!(a.get(t, i), b.get(t, i), "frame {t} point {i}");
        }
    }
}

/// A version-1 npy file of float64 data with the given shape text and data bytes.
fn raw_npy(shape: &str, data: &[u8]) -> Vec<u8> {
    let mut dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
    // The header (10 bytes of magic and length, then the dict and a newline) is padded to 64.
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    bytes.extend_from_slice(dict.as_bytes());
    bytes.extend_from_slice(data);
    bytes
}

fn message(e: &Error) -> String {
    e.to_string()
}

#[test]
fn stored_and_deflated_archives_read_as_the_npy() {
    let tracks = sample_tracks(1);
    let d = dir("same");
    let npy = d.join("tracks.npy");
    write_npy(&npy, &tracks).expect("npy");
    let from_npy = read_tracks(&npy).expect("read npy");
    let (zeroed, visible) = zeroed_and_visible(&tracks);
    let (t, n) = (tracks.n_frames() as u64, tracks.n_points() as u64);
    for (name, method) in [
        ("stored.npz", zip::CompressionMethod::Stored),
        ("deflated.npz", zip::CompressionMethod::Deflated),
    ] {
        let path = d.join(name);
        write_zip(
            &path,
            &[
                ("tracks.npy", npy_bytes(&[t, n, 3], zeroed.iter().copied())),
                (
                    "visibility.npy",
                    npy_bytes(&[t, n], visible.iter().copied()),
                ),
            ],
            method,
        );
        let from_npz = read_tracks(&path).expect("read npz");
        assert_same_samples(&from_npz, &from_npy);
    }
    // Without the visibility array the zeroed samples would read as points at the origin.
    let bare = d.join("bare.npz");
    write_zip(
        &bare,
        &[("tracks.npy", npy_bytes(&[t, n, 3], zeroed.iter().copied()))],
        zip::CompressionMethod::Stored,
    );
    let all = read_tracks(&bare).expect("read");
    assert_eq!(all.occluded_fraction(), 0.0);
    assert!(from_npy.occluded_fraction() > 0.1);
}

#[test]
fn named_float32_tracks_with_an_occlusion_probability() {
    let tracks = sample_tracks(2);
    let (zeroed, visible) = zeroed_and_visible(&tracks);
    let (t, n) = (tracks.n_frames() as u64, tracks.n_points() as u64);
    let path = dir("named").join("tracker.npz");
    // Occlusion as a probability: 0.9 where hidden, 0.1 where seen.
    let occlusion: Vec<f32> = visible.iter().map(|&v| if v { 0.1 } else { 0.9 }).collect();
    write_zip(
        &path,
        &[
            (
                "coords_3d.npy",
                npy_bytes(&[t, n, 3], zeroed.iter().map(|&v| v as f32)),
            ),
            ("occ.npy", npy_bytes(&[t, n], occlusion.iter().copied())),
            (
                "query_points.npy",
                npy_bytes(&[n, 3], vec![0.0f64; 3 * n as usize]),
            ),
        ],
        zip::CompressionMethod::Deflated,
    );
    let options = ReadOptions {
        tracks_key: Some("coords_3d".into()),
        occluded_key: Some("occ".into()),
        ..ReadOptions::default()
    };
    let read = read_tracks_with(&path, &options).expect("read");
    assert_eq!((read.n_frames(), read.n_points()), (t as usize, n as usize));
    for f in 0..tracks.n_frames() {
        for i in 0..tracks.n_points() {
            match (read.get(f, i), tracks.get(f, i)) {
                (Some(a), Some(b)) => {
                    // float32 keeps about 7 digits: 1e-7 relative, far below a 1 mm noise.
                    assert!((a - b).norm() < 1e-6 * (1.0 + b.coords.norm()), "{f} {i}");
                }
                (None, None) => {}
                other => panic!("frame {f} point {i}: {other:?}"),
            }
        }
    }
    // Without a name, the archive's arrays are listed.
    let e = read_tracks(&path).expect_err("no `tracks` array");
    let text = message(&e);
    assert!(text.contains("no array `tracks`"), "{text}");
    assert!(text.contains("coords_3d, occ, query_points"), "{text}");
    assert!(text.contains("--tracks-key"), "{text}");
}

#[test]
fn default_occlusion_and_visibility_names_are_found() {
    let tracks = sample_tracks(3);
    let (zeroed, visible) = zeroed_and_visible(&tracks);
    let (t, n) = (tracks.n_frames() as u64, tracks.n_points() as u64);
    let d = dir("defaults");
    let occluded = d.join("occluded.npz");
    write_zip(
        &occluded,
        &[
            ("tracks.npy", npy_bytes(&[t, n, 3], zeroed.iter().copied())),
            // Integer flags, 1 where hidden.
            (
                "occluded.npy",
                npy_bytes(&[t, n], visible.iter().map(|&v| i64::from(!v))),
            ),
        ],
        zip::CompressionMethod::Stored,
    );
    assert_same_samples(&read_tracks(&occluded).expect("read"), &tracks);
    // A named visibility array that is missing is an error naming it, not a silent default.
    let e = read_tracks_with(
        &occluded,
        &ReadOptions {
            visibility_key: Some("vis".into()),
            ..ReadOptions::default()
        },
    )
    .expect_err("no vis");
    assert!(message(&e).contains("no array `vis`"), "{}", message(&e));
}

#[test]
fn write_npz_round_trips() {
    let tracks = sample_tracks(4);
    let path = dir("write").join("t.npz");
    write_npz(&path, &tracks).expect("write");
    assert_same_samples(&read_tracks(&path).expect("read"), &tracks);
}

#[test]
fn bad_archives_get_errors_that_name_the_array() {
    let d = dir("bad");
    let ok_tracks = npy_bytes(&[4, 3, 3], vec![0.5f64; 36]);
    let cases: Vec<(&str, Entries, &str)> = vec![
        (
            "wrong_shape.npz",
            vec![("tracks.npy", npy_bytes(&[4, 3, 2], vec![0.5f64; 24]))],
            "(T, N, 3)",
        ),
        (
            "int_tracks.npz",
            vec![("tracks.npy", npy_bytes(&[4, 3, 3], vec![1i64; 36]))],
            "float64 ('<f8') or float32",
        ),
        (
            "vis_shape.npz",
            vec![
                ("tracks.npy", ok_tracks.clone()),
                ("visibility.npy", npy_bytes(&[4, 2], vec![true; 8])),
            ],
            "array `visibility`",
        ),
        (
            "truncated.npz",
            vec![("tracks.npy", ok_tracks[..ok_tracks.len() - 20].to_vec())],
            "array `tracks`",
        ),
        ("empty.npz", vec![], "holds no arrays"),
    ];
    for (name, entries, expected) in cases {
        let path = d.join(name);
        write_zip(&path, &entries, zip::CompressionMethod::Stored);
        let e = read_tracks(&path).expect_err(name);
        let text = message(&e);
        assert!(text.contains(name), "{name}: {text}");
        assert!(text.contains(expected), "{name}: {text}");
    }
    // A header that claims far more data than the entry holds is refused before allocation.
    let path = d.join("lying.npz");
    write_zip(
        &path,
        &[(
            "tracks.npy",
            raw_npy("(4000000000, 3000000, 3)", &[0u8; 288]),
        )],
        zip::CompressionMethod::Stored,
    );
    let text = message(&read_tracks(&path).expect_err("lying"));
    assert!(text.contains("needs more data"), "{text}");
    // Not a zip archive at all.
    let junk = d.join("junk.npz");
    std::fs::write(&junk, b"not a zip").expect("write");
    assert!(message(&read_tracks(&junk).expect_err("junk")).contains("zip"));
    // Array names are for archives only.
    let npy = d.join("t.npy");
    write_npy(&npy, &sample_tracks(5)).expect("npy");
    let e = read_tracks_with(
        &npy,
        &ReadOptions {
            tracks_key: Some("tracks".into()),
            ..ReadOptions::default()
        },
    )
    .expect_err("key for npy");
    assert!(
        message(&e).contains(".npz archives only"),
        "{}",
        message(&e)
    );
    // The memory limit applies to the declared size.
    let big = d.join("big.npz");
    write_npz(&big, &sample_tracks(6)).expect("write");
    let e = read_tracks_with(
        &big,
        &ReadOptions {
            max_memory_gib: 1e-6,
            ..ReadOptions::default()
        },
    )
    .expect_err("limit");
    assert!(message(&e).contains("GiB"), "{}", message(&e));
}
