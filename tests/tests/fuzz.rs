//! Random bytes and random damage to valid files for every reader: typed errors, never a
//! panic. `PROPTEST_CASES` raises the count (a deep pass of 20 000 per property was run).

use kinetree_core::Tracks;
use proptest::prelude::*;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kinetree-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("dir");
    d.join(name)
}

/// A small valid tracks set: 4 frames, 3 points, one occluded sample.
fn tracks() -> Tracks {
    let mut xyz: Vec<f64> = (0..36).map(|k| k as f64 * 0.01).collect();
    xyz[3..6].fill(f64::NAN);
    Tracks::new(4, 3, xyz).expect("valid")
}

fn valid_bytes(ext: &str) -> Vec<u8> {
    if ext == "c3d" {
        return std::fs::read(kinetree_tests::real_c3d("c3dorg-fullbody-triads")).expect("read");
    }
    let p = tmp(&format!("valid.{ext}"));
    match ext {
        "npy" => kinetree_io::write_npy(&p, &tracks()).expect("write"),
        "csv" => kinetree_io::write_csv(&p, &tracks()).expect("write"),
        _ => {
            let d = kinetree_pipeline::Pipeline::from_config(&Default::default())
                .expect("pipeline")
                .run(
                    &kinetree_synth::simulate(&kinetree_synth::paper_arm(0))
                        .expect("sim")
                        .tracks,
                )
                .expect("discover");
            kinetree_io::write_json(&p, &d.model).expect("write");
        }
    }
    std::fs::read(&p).expect("read")
}

/// Reads `bytes` as a file of type `ext`; the result is ignored, a panic fails the test.
fn read_as(ext: &str, bytes: &[u8], case: &str) {
    let p = tmp(&format!("{case}.{ext}"));
    std::fs::write(&p, bytes).expect("write");
    if ext == "json" {
        let _ = kinetree_io::read_model(&p);
    } else {
        let _ = kinetree_io::read_tracks(&p);
    }
}

fn damage(mut b: Vec<u8>, cut: usize, flips: &[(usize, u8)]) -> Vec<u8> {
    b.truncate(cut.min(b.len()));
    let len = b.len().max(1);
    for &(at, v) in flips {
        if let Some(x) = b.get_mut(at % len) {
            *x = v;
        }
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(256),
        ..ProptestConfig::default()
    })]

    #[test]
    fn random_bytes_never_panic(
        ext in prop::sample::select(vec!["npy", "csv", "json", "c3d"]),
        b in proptest::collection::vec(any::<u8>(), 0..512),
    ) {
        read_as(ext, &b, "random");
    }

    #[test]
    fn damaged_valid_files_never_panic(
        ext in prop::sample::select(vec!["npy", "csv", "json", "c3d"]),
        cut in 0usize..200_000,
        flips in proptest::collection::vec((0usize..200_000, any::<u8>()), 0..6),
    ) {
        let b = damage(valid_bytes(ext), cut, &flips);
        read_as(ext, &b, "damaged");
    }

    /// CSV rows of random text in the right shape: numbers, huge indices, NaN, text.
    #[test]
    fn random_csv_rows_never_panic(
        rows in proptest::collection::vec(
            (
                prop::sample::select(vec!["0", "1", "3", "-1", "99999999999", "x", ""]),
                prop::sample::select(vec!["0", "2", "4", "1e3", "nan"]),
                prop::sample::select(vec!["0.1", "nan", "inf", "-", "1e308", ""]),
            ),
            0..12,
        ),
    ) {
        let mut text = String::from("frame,point,x,y,z\n");
        for (f, p, v) in rows {
            text.push_str(&format!("{f},{p},{v},{v},{v}\n"));
        }
        read_as("csv", text.as_bytes(), "rows");
    }
}
