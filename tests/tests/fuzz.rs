//! Random bytes and random damage to valid files for every reader, and structure-aware
//! mutations of the fields readers trust (npy header dimensions, the CSV size line, C3D
//! parameters, model JSON fields): typed errors, never a panic or an abort. `PROPTEST_CASES`
//! raises the count (a deep pass of 20 000 per property was run).

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

/// The valid file of type `ext`, made once (the model needs a discovery).
fn valid_bytes(ext: &str) -> Vec<u8> {
    static CACHE: std::sync::OnceLock<std::collections::BTreeMap<&'static str, Vec<u8>>> =
        std::sync::OnceLock::new();
    CACHE.get_or_init(|| {
        ["npy", "npz", "csv", "json", "c3d"]
            .into_iter()
            .map(|e| (e, make_valid_bytes(e)))
            .collect()
    })[ext]
        .clone()
}

fn make_valid_bytes(ext: &str) -> Vec<u8> {
    if ext == "c3d" {
        return std::fs::read(kinetree_tests::real_c3d("c3dorg-fullbody-triads")).expect("read");
    }
    let p = tmp(&format!("valid.{ext}"));
    match ext {
        "npy" => kinetree_io::write_npy(&p, &tracks()).expect("write"),
        "npz" => kinetree_io::write_npz(&p, &tracks()).expect("write"),
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
/// Reads `bytes` as a file of type `ext`; a model that reads is also exported, inspected and
/// given to the observer. Results are ignored; a panic fails the test.
fn read_as(ext: &str, bytes: &[u8], case: &str) {
    let p = tmp(&format!("{case}.{ext}"));
    std::fs::write(&p, bytes).expect("write");
    if ext == "json" {
        if let Ok(m) = kinetree_io::read_model(&p) {
            let _ = kinetree_io::export::to_urdf(&m);
            let _ = kinetree_io::export::to_dot(&m);
            let _ = kinetree_pipeline::report::inspect(&m);
            let _ = kinetree_fit::Observer::new(&m);
        }
    } else {
        let _ = kinetree_io::read_tracks(&p);
    }
}

/// An npy file whose header declares `shape` (any text) over `payload` bytes of data.
fn npy_with_shape(shape: &str, payload: usize) -> Vec<u8> {
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({shape}), }}");
    let mut header = dict.into_bytes();
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(b' ');
    }
    header.push(b'\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(
        &u16::try_from(header.len())
            .unwrap_or(u16::MAX)
            .to_le_bytes(),
    );
    b.extend_from_slice(&header);
    b.extend((0..payload).map(|k| (k % 251) as u8));
    b
}

/// Dimension text for a header: ordinary, zero, huge, negative or not a number.
fn dim() -> impl Strategy<Value = String> {
    prop_oneof![
        (0u64..6).prop_map(|d| d.to_string()),
        Just("3".to_string()),
        Just("4294967296".to_string()),
        Just("18446744073709551615".to_string()),
        Just("-1".to_string()),
        Just("x".to_string()),
    ]
}

/// Offsets of the data of the C3D parameters named `name` (`POINT:<name>`): after the
/// name, a 2-byte offset, the type, the dimension count and the dimensions.
fn c3d_parameter_data(bytes: &[u8], name: &[u8]) -> Vec<usize> {
    let mut out = Vec::new();
    for at in 0..bytes.len().saturating_sub(name.len() + 4) {
        if &bytes[at..at + name.len()] == name && at > 0 && usize::from(bytes[at - 2]) == name.len()
        {
            let dims_at = at + name.len() + 3;
            let n_dims = usize::from(bytes[dims_at]);
            out.push(dims_at + 1 + n_dims);
        }
    }
    out
}

/// Paths of model fields readers index with, and values to put there.
const MODEL_FIELDS: [&str; 14] = [
    "/schema_version",
    "/n_frames",
    "/n_points",
    "/root_body",
    "/static_body",
    "/bodies/1/id",
    "/bodies/1/parent",
    "/bodies/2/points/0",
    "/joints/0/child",
    "/joints/0/parent",
    "/joints/0/axis_in_parent",
    "/joints/0/range",
    "/joints/1/reference_frame",
    "/point_body/3",
];

fn model_value() -> impl Strategy<Value = serde_json::Value> {
    use serde_json::json;
    prop::sample::select(vec![
        json!(-1),
        json!(0),
        json!(1),
        json!(2),
        json!(99),
        json!(1e308),
        json!(18446744073709551615u64),
        json!(null),
        json!([]),
        json!("x"),
        json!([0.0, 0.0, 0.0]),
        json!([1e300, 0.0, 0.0]),
        json!([1.0, -1.0]),
        json!([0.0, 1.0, 0.0]),
    ])
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
        ext in prop::sample::select(vec!["npy", "npz", "csv", "json", "c3d"]),
        b in proptest::collection::vec(any::<u8>(), 0..512),
    ) {
        read_as(ext, &b, "random");
    }

    #[test]
    fn damaged_valid_files_never_panic(
        ext in prop::sample::select(vec!["npy", "npz", "csv", "json", "c3d"]),
        cut in 0usize..200_000,
        flips in proptest::collection::vec((0usize..200_000, any::<u8>()), 0..6),
    ) {
        let b = damage(valid_bytes(ext), cut, &flips);
        read_as(ext, &b, "damaged");
    }

    /// npy headers declaring any dimensions over any amount of data.
    #[test]
    fn npy_header_dimensions_never_panic(
        dims in proptest::collection::vec(dim(), 0..5),
        payload in prop::sample::select(vec![0usize, 8, 72, 288, 4096]),
    ) {
        let shape = if dims.len() == 1 { format!("{},", dims[0]) } else { dims.join(", ") };
        read_as("npy", &npy_with_shape(&shape, payload), "dims");
    }

    /// The same headers as the tracks array of an `.npz` archive.
    #[test]
    fn npz_entry_dimensions_never_panic(
        dims in proptest::collection::vec(dim(), 0..5),
        payload in prop::sample::select(vec![0usize, 8, 72, 288, 4096]),
    ) {
        use std::io::Write;
        let shape = if dims.len() == 1 { format!("{},", dims[0]) } else { dims.join(", ") };
        let mut bytes = std::io::Cursor::new(Vec::new());
        let mut zip = zip::ZipWriter::new(&mut bytes);
        zip.start_file("tracks.npy", zip::write::SimpleFileOptions::default())
            .expect("entry");
        zip.write_all(&npy_with_shape(&shape, payload)).expect("write");
        zip.finish().expect("finish");
        read_as("npz", &bytes.into_inner(), "npz-dims");
    }

    /// A CSV size line of any declared size over the valid rows.
    #[test]
    fn csv_size_lines_never_panic(frames in dim(), points in dim()) {
        let valid = String::from_utf8(valid_bytes("csv")).expect("text");
        let body = valid.split_once('\n').map_or("", |(_, rest)| rest);
        let text = format!("# frames={frames} points={points}\n{body}");
        read_as("csv", text.as_bytes(), "size");
    }

    /// The C3D header's counts and the POINT parameters that size the data, set to any value.
    #[test]
    fn c3d_parameter_fields_never_panic(
        header_word in prop::sample::select(vec![1usize, 2, 3, 4, 9]),
        header_value in any::<i16>(),
        parameter in prop::sample::select(vec![&b"USED"[..], b"FRAMES", b"SCALE", b"DATA_START", b"LABELS", b"UNITS"]),
        value in any::<[u8; 4]>(),
    ) {
        let mut b = valid_bytes("c3d");
        b[2 * (header_word - 1) + 2..2 * (header_word - 1) + 4].copy_from_slice(&header_value.to_le_bytes());
        for at in c3d_parameter_data(&b, parameter) {
            let end = (at + 4).min(b.len());
            let n = end.saturating_sub(at);
            b[at..end].copy_from_slice(&value[..n]);
        }
        read_as("c3d", &b, "params");
    }

    /// A model with up to three of its index and axis fields set to any value.
    #[test]
    fn model_fields_never_panic(
        edits in proptest::collection::vec((prop::sample::select(MODEL_FIELDS.to_vec()), model_value()), 1..4),
    ) {
        let mut m: serde_json::Value = serde_json::from_slice(&valid_bytes("json")).expect("json");
        for (path, value) in edits {
            if let Some(slot) = m.pointer_mut(path) {
                *slot = value;
            }
        }
        read_as("json", serde_json::to_string(&m).expect("json").as_bytes(), "fields");
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
