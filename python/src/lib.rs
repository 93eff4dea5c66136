//! `kinetree._kinetree`: the compiled half of the Python package. The Python half
//! (`python/kinetree/__init__.py`) wraps these functions in the documented API: it converts
//! arrays and configs, and builds the `Model` class from the model JSON these return.
//!
//! Models cross the boundary as the JSON text the CLI writes, so a model from Python and one
//! from `kinetree discover` are the same file.

use kinetree_core::{Error, Model, Tracks};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

pyo3::create_exception!(
    _kinetree,
    KinetreeError,
    PyValueError,
    "Base of every kinetree error: bad input, configuration, files or models."
);
pyo3::create_exception!(
    _kinetree,
    InputError,
    KinetreeError,
    "Tracks that cannot be used: wrong shape or type, NaN in part of a point, infinite or \
     impossible coordinates, too few frames, points or visible samples."
);
pyo3::create_exception!(
    _kinetree,
    ConfigError,
    KinetreeError,
    "A configuration or parameter that is not valid: an unknown key, a value out of range."
);
pyo3::create_exception!(
    _kinetree,
    FileError,
    KinetreeError,
    "A file that cannot be read or written, or whose content does not follow its format."
);
pyo3::create_exception!(
    _kinetree,
    ModelError,
    KinetreeError,
    "A model that breaks the schema's rules."
);
pyo3::create_exception!(
    _kinetree,
    TooLargeError,
    KinetreeError,
    "Work whose estimated memory or size is beyond the limit; the message states both."
);

/// The Python exception for a kinetree error, carrying its message: the class follows the
/// error's kind, the innermost cause for an error inside a file.
fn to_py(e: Error) -> PyErr {
    let message = e.to_string();
    let mut kind = &e;
    while let Error::File { source, .. } = kind {
        kind = source;
    }
    match kind {
        Error::Io(_) | Error::Malformed { .. } => FileError::new_err(message),
        Error::DType { .. }
        | Error::Shape { .. }
        | Error::PartialNan { .. }
        | Error::NonFinite { .. }
        | Error::CoordinateOverflow { .. }
        | Error::TooFewFrames { .. }
        | Error::TooFewPoints { .. }
        | Error::NoVisibleData => InputError::new_err(message),
        Error::InvalidParameter { .. } | Error::Config(_) => ConfigError::new_err(message),
        Error::InvalidModel { .. } => ModelError::new_err(message),
        Error::TooLarge { .. } => TooLargeError::new_err(message),
        _ => KinetreeError::new_err(message),
    }
}

/// Tracks from a `(T, N, 3)` float64 array, NaN where a point is hidden, refused when their
/// copy would take more than `max_memory_gib`.
fn tracks_from(array: &PyReadonlyArray3<'_, f64>, max_memory_gib: f64) -> Result<Tracks, Error> {
    let shape = array.shape();
    let (t, n) = (shape[0], shape[1]);
    if shape[2] != 3 {
        return Err(Error::Shape {
            expected: "(T, N, 3)".into(),
            found: format!("({t}, {n}, {})", shape[2]),
        });
    }
    kinetree_core::limits::check_memory(
        &format!("tracks of {t} frames x {n} points"),
        kinetree_core::limits::tracks_bytes(t as u64, n as u64),
        max_memory_gib,
    )?;
    // Any strides: the values are taken in C order.
    let xyz: Vec<f64> = array.as_array().iter().copied().collect();
    Tracks::new(t, n, xyz)
}

/// A `(T, N, 3)` array of tracks, NaN where hidden.
fn tracks_array<'py>(py: Python<'py>, tracks: &Tracks) -> PyResult<Bound<'py, PyAny>> {
    let array = PyArray1::from_vec(py, tracks.raw().to_vec());
    Ok(array
        .reshape([tracks.n_frames(), tracks.n_points(), 3])?
        .into_any())
}

/// The model JSON exactly as the CLI writes it: pretty, with a final newline.
fn model_text(model: &Model) -> Result<String, Error> {
    let mut text = serde_json::to_string_pretty(model).map_err(|e| Error::Malformed {
        position: "serialisation".into(),
        message: e.to_string(),
    })?;
    text.push('\n');
    Ok(text)
}

/// A pipeline config from TOML text (the `[pipeline]` table's contents, or a whole config
/// with a `[pipeline]` table) or from JSON text of the same tables (a Python dict).
fn pipeline_config(
    toml_text: Option<&str>,
    json_text: Option<&str>,
) -> Result<kinetree_pipeline::PipelineConfig, Error> {
    let text = match (toml_text, json_text) {
        (Some(t), _) => t.to_string(),
        (None, Some(j)) => {
            let value: serde_json::Value =
                serde_json::from_str(j).map_err(|e| Error::Config(format!("config dict: {e}")))?;
            // Through TOML, so that a dict gets the same checks and messages as a file.
            let table = toml::Value::try_from(value).map_err(|e| {
                Error::Config(format!(
                    "config dict: {e} (TOML, and so a config, has no None; leave the key out)"
                ))
            })?;
            toml::to_string(&table).map_err(|e| Error::Config(format!("config dict: {e}")))?
        }
        (None, None) => return Ok(kinetree_pipeline::PipelineConfig::default()),
    };
    kinetree_pipeline::config::pipeline_from_toml(&text)
}

/// Discovers the structure in `tracks`; returns the model JSON.
#[pyfunction]
#[pyo3(signature = (tracks, noise_sigma=None, config_toml=None, config_json=None, max_memory_gib=None))]
fn discover(
    py: Python<'_>,
    tracks: PyReadonlyArray3<'_, f64>,
    noise_sigma: Option<f64>,
    config_toml: Option<&str>,
    config_json: Option<&str>,
    max_memory_gib: Option<f64>,
) -> PyResult<String> {
    let mut cfg = pipeline_config(config_toml, config_json).map_err(to_py)?;
    if noise_sigma.is_some() {
        cfg.noise_sigma_m = noise_sigma;
    }
    if let Some(m) = max_memory_gib {
        cfg.max_memory_gib = m;
    }
    let tracks = tracks_from(&tracks, cfg.max_memory_gib).map_err(to_py)?;
    // Discovery takes seconds to minutes: other Python threads run meanwhile.
    py.detach(move || {
        let pipeline = kinetree_pipeline::Pipeline::from_config(&cfg)?;
        let found = pipeline.run(&tracks)?;
        model_text(&found.model)
    })
    .map_err(to_py)
}

/// A model from JSON text, checked by [`Model::validate`].
fn parse_model(text: &str) -> PyResult<Model> {
    let model: Model = serde_json::from_str(text)
        .map_err(|e| Error::Malformed {
            position: format!("line {}, column {}", e.line(), e.column()),
            message: e.to_string(),
        })
        .map_err(to_py)?;
    model.validate().map_err(to_py)?;
    Ok(model)
}

/// Reads and validates model JSON text; returns it as the CLI writes it.
#[pyfunction]
fn model_json(text: &str) -> PyResult<String> {
    model_text(&parse_model(text)?).map_err(to_py)
}

/// A model exported as `urdf`, `mjcf` or `dot` text.
#[pyfunction]
fn export_model(text: &str, format: &str) -> PyResult<String> {
    let model = parse_model(text)?;
    match format {
        "urdf" => kinetree_io::export::to_urdf(&model).map_err(to_py),
        "mjcf" => kinetree_io::export::to_mjcf(&model).map_err(to_py),
        "dot" => Ok(kinetree_io::export::to_dot(&model)),
        other => Err(to_py(kinetree_core::Error::InvalidParameter {
            name: "format".into(),
            message: format!("unknown export format `{other}`; use urdf, mjcf or dot"),
        })),
    }
}

/// Joint positions of `tracks` from a model: (joint names, positions (T, J), standard
/// deviations (T, J), residual in sigma (T,), unexplained frames, their bound, body poses
/// (T, B, 4, 4), their standard deviations (T, B, 2): rotation and origin), NaN where
/// unknown.
#[pyfunction]
#[pyo3(signature = (model_text, tracks, smooth=false, unexplained_factor=kinetree_fit::DEFAULT_UNEXPLAINED_FACTOR))]
#[allow(clippy::type_complexity)]
fn observe<'py>(
    py: Python<'py>,
    model_text: &str,
    tracks: PyReadonlyArray3<'py, f64>,
    smooth: bool,
    unexplained_factor: f64,
) -> PyResult<(
    Vec<String>,
    Bound<'py, PyAny>,
    Bound<'py, PyAny>,
    Bound<'py, PyAny>,
    Vec<usize>,
    f64,
    Bound<'py, PyAny>,
    Bound<'py, PyAny>,
)> {
    let model = parse_model(model_text)?;
    let tracks =
        tracks_from(&tracks, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB).map_err(to_py)?;
    let options = kinetree_fit::ObserveOptions {
        smooth,
        unexplained_factor,
    };
    let seen = py
        .detach(|| kinetree_fit::observe(&model, &tracks, options))
        .map_err(to_py)?;
    let (t, j, b) = (
        tracks.n_frames(),
        seen.joint_names.len(),
        model.bodies.len(),
    );
    let by_frame = |columns: &[Vec<Option<f64>>]| -> PyResult<Bound<'py, PyAny>> {
        let mut v = Vec::with_capacity(t * j);
        for f in 0..t {
            v.extend(columns.iter().map(|c| c[f].unwrap_or(f64::NAN)));
        }
        Ok(PyArray1::from_vec(py, v).reshape([t, j])?.into_any())
    };
    let positions = by_frame(&seen.positions)?;
    let std = by_frame(&seen.std)?;
    let residual = PyArray1::from_vec(
        py,
        seen.residual_in_sigma
            .iter()
            .map(|r| r.unwrap_or(f64::NAN))
            .collect(),
    )
    .into_any();
    let mut poses = Vec::with_capacity(t * b * 16);
    for frame in &seen.poses {
        for pose in frame {
            match pose {
                Some(p) => {
                    let m = p.to_homogeneous();
                    for r in 0..4 {
                        poses.extend((0..4).map(|c| m[(r, c)]));
                    }
                }
                None => poses.extend([f64::NAN; 16]),
            }
        }
    }
    let poses = PyArray1::from_vec(py, poses)
        .reshape([t, b, 4, 4])?
        .into_any();
    let pose_std: Vec<f64> = seen
        .pose_std
        .iter()
        .flatten()
        .flat_map(|s| s.unwrap_or([f64::NAN; 2]))
        .collect();
    let pose_std = PyArray1::from_vec(py, pose_std)
        .reshape([t, b, 2])?
        .into_any();
    Ok((
        seen.joint_names,
        positions,
        std,
        residual,
        seen.unexplained,
        seen.unexplained_bound,
        poses,
        pose_std,
    ))
}

/// Simulates a mechanism; returns the tracks (T, N, 3) and the truth JSON.
#[pyfunction]
#[pyo3(signature = (mechanism="paper-arm", seed=0, joints=3, tree=false, prismatic_fraction=0.3, spherical_fraction=0.0, noise_sigma=0.001, dropout=0.0, frames=None, points=None, soft_tissue=None))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    mechanism: &str,
    seed: u64,
    joints: usize,
    tree: bool,
    prismatic_fraction: f64,
    spherical_fraction: f64,
    noise_sigma: f64,
    dropout: f64,
    frames: Option<usize>,
    points: Option<usize>,
    soft_tissue: Option<f64>,
) -> PyResult<(Bound<'py, PyAny>, Option<String>)> {
    let data = kinetree_pipeline::config::SimulationRequest {
        mechanism: mechanism.to_string(),
        seed,
        joints,
        tree,
        prismatic_fraction,
        spherical_fraction,
        noise_sigma_m: noise_sigma,
        dropout,
        n_frames: frames,
        n_points: points,
        soft_tissue_m: soft_tissue,
    }
    .data()
    .map_err(to_py)?;
    let (tracks, truth) = py
        .detach(|| {
            kinetree_pipeline::load_data(
                &data,
                std::path::Path::new("."),
                kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB,
            )
        })
        .map_err(to_py)?;
    let truth = truth
        .map(|t| serde_json::to_string(&t))
        .transpose()
        .map_err(|e| KinetreeError::new_err(e.to_string()))?;
    Ok((tracks_array(py, &tracks)?, truth))
}

/// Reads a tracks file (.npy, .npz, .csv, .c3d); returns the (T, N, 3) array and the point
/// labels, if the file has them.
#[pyfunction]
#[pyo3(signature = (path, tracks_key=None, visibility_key=None, occluded_key=None, max_memory_gib=kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB))]
fn read_tracks<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
    tracks_key: Option<String>,
    visibility_key: Option<String>,
    occluded_key: Option<String>,
    max_memory_gib: f64,
) -> PyResult<(Bound<'py, PyAny>, Option<Vec<String>>)> {
    let options = kinetree_io::ReadOptions {
        max_memory_gib,
        tracks_key,
        visibility_key,
        occluded_key,
    };
    let tracks = py
        .detach(|| kinetree_io::read_tracks_with(&path, &options))
        .map_err(to_py)?;
    let labels = tracks.labels().map(<[String]>::to_vec);
    Ok((tracks_array(py, &tracks)?, labels))
}

/// The interactive HTML view of a model and tracks of its points (as `kinetree view`).
#[pyfunction]
#[pyo3(signature = (model_text, tracks, title, max_samples=kinetree_view::DEFAULT_MAX_SAMPLES, fps=None))]
fn view_html(
    py: Python<'_>,
    model_text: &str,
    tracks: PyReadonlyArray3<'_, f64>,
    title: String,
    max_samples: usize,
    fps: Option<f64>,
) -> PyResult<String> {
    let model = parse_model(model_text)?;
    let tracks =
        tracks_from(&tracks, kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB).map_err(to_py)?;
    let options = kinetree_view::ViewOptions {
        title,
        max_samples,
        fps,
    };
    py.detach(|| kinetree_view::to_html(&model, &tracks, &options))
        .map_err(to_py)
}

/// The library's version.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _kinetree(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("KinetreeError", py.get_type::<KinetreeError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add("TooLargeError", py.get_type::<TooLargeError>())?;
    m.add(
        "MOTION_CAPTURE",
        kinetree_pipeline::config::MOTION_CAPTURE_TOML,
    )?;
    m.add_function(wrap_pyfunction!(discover, m)?)?;
    m.add_function(wrap_pyfunction!(model_json, m)?)?;
    m.add_function(wrap_pyfunction!(export_model, m)?)?;
    m.add_function(wrap_pyfunction!(observe, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(read_tracks, m)?)?;
    m.add_function(wrap_pyfunction!(view_html, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
