//! The native half of the Python package (`grainforce._native`). The Python
//! half (`grainforce/__init__.py`) turns tables into DataFrames and back; this
//! half holds scenes, runs the library with the GIL released and turns the
//! library's errors into Python exceptions.

use grainforce::error::Error;
use grainforce::infer::run::{self, Event, Source};
use grainforce::infer::InferConfig;
use grainforce::scene::{self, ForceRow, Forces};
use numpy::{
    PyArray1, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Mutex;

create_exception!(
    _native,
    InfeasibleError,
    PyValueError,
    "The constraints admit no force field (e.g. μ too small for the stresses)."
);
create_exception!(
    _native,
    SolverError,
    PyRuntimeError,
    "The solver failed; the message carries its diagnostics."
);

/// The library's error as the Python exception a user expects.
fn to_py(error: Error) -> PyErr {
    let message = error.to_string();
    match &error {
        Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(message)
        }
        Error::Io { .. } => PyOSError::new_err(message),
        Error::Data { .. } | Error::Invalid(_) => PyValueError::new_err(message),
        Error::Infeasible(_) => InfeasibleError::new_err(message),
        Error::Solver(_) => SolverError::new_err(message),
    }
}

/// A scene: one frame (static) or a sequence of frames.
#[pyclass(frozen, module = "grainforce._native")]
struct Scene {
    frames: Vec<scene::Scene>,
}

#[pymethods]
impl Scene {
    /// 2 or 3.
    #[getter]
    fn dim(&self) -> usize {
        self.frames[0].dim
    }

    /// Frame numbers (`None` for a static scene's single frame).
    #[getter]
    fn frames(&self) -> Vec<Option<i64>> {
        self.frames.iter().map(|f| f.frame).collect()
    }

    /// Grains of the first frame.
    #[getter]
    fn n_grains(&self) -> usize {
        self.frames[0].grains.len()
    }

    /// Contacts of the first frame.
    #[getter]
    fn n_contacts(&self) -> usize {
        self.frames[0].contacts.len()
    }

    /// Writes the scene folder (grains.csv, contacts.csv, walls.csv, scene.json).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| scene::write_sequence(&path, &self.frames))
            .map_err(to_py)
    }

    fn __len__(&self) -> usize {
        self.frames.len()
    }

    fn __repr__(&self) -> String {
        let f = &self.frames[0];
        let frames = if self.frames.len() > 1 {
            format!(", {} frames", self.frames.len())
        } else {
            String::new()
        };
        format!(
            "Scene({}D, {} grains, {} contacts, {} walls{frames})",
            f.dim,
            f.grains.len(),
            f.contacts.len(),
            f.walls.len()
        )
    }
}

/// Reads a scene folder: one frame, or a sequence when the files carry `frame`.
#[pyfunction]
fn read_scene(py: Python<'_>, path: PathBuf) -> PyResult<Scene> {
    let frames = py.detach(|| scene::read_sequence(&path)).map_err(to_py)?;
    Ok(Scene { frames })
}

/// One column of a table on its way to CSV.
#[derive(FromPyObject)]
enum Column<'py> {
    Float(PyReadonlyArray1<'py, f64>),
    Integer(PyReadonlyArray1<'py, i64>),
    Text(Vec<String>),
}

impl Column<'_> {
    fn len(&self) -> usize {
        match self {
            Column::Float(a) => a.len(),
            Column::Integer(a) => a.len(),
            Column::Text(v) => v.len(),
        }
    }

    fn cell(&self, row: usize) -> String {
        match self {
            // Debug is the shortest text that reads back to the same double.
            Column::Float(a) => match a.as_array()[row] {
                x if x.is_nan() => String::new(),
                x => format!("{x:?}"),
            },
            Column::Integer(a) => a.as_array()[row].to_string(),
            Column::Text(v) => v[row].clone(),
        }
    }
}

/// Writes columns (float64 or int64 arrays, or lists of text; NaN is an
/// empty cell) as a CSV table, for the library's reader to check and read.
#[pyfunction]
fn write_table(path: PathBuf, names: Vec<String>, columns: Vec<Column<'_>>) -> PyResult<()> {
    let rows = columns.first().map_or(0, Column::len);
    if names.len() != columns.len() || columns.iter().any(|c| c.len() != rows) {
        return Err(PyValueError::new_err(format!(
            "{}: every column needs a name and the same length",
            path.display()
        )));
    }
    let io = |e: csv::Error| PyOSError::new_err(format!("{}: {e}", path.display()));
    let mut out = csv::Writer::from_path(&path).map_err(io)?;
    out.write_record(&names).map_err(io)?;
    for row in 0..rows {
        out.write_record(columns.iter().map(|c| c.cell(row)))
            .map_err(io)?;
    }
    out.flush()
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))
}

/// The rows of forces.csv as columns: frame (when framed), contact, f_x,
/// f_y[, f_z] and, after the bootstrap, sd_x, sd_y[, sd_z].
fn forces_table<'py>(py: Python<'py>, forces: &Forces) -> PyResult<Bound<'py, PyDict>> {
    let rows: &[ForceRow] = &forces.rows;
    let table = PyDict::new(py);
    if rows.iter().any(|r| r.frame.is_some()) {
        let frames: Vec<i64> = rows.iter().map(|r| r.frame.unwrap_or(0)).collect();
        table.set_item("frame", PyArray1::from_vec(py, frames))?;
    }
    let contacts: Vec<&str> = rows.iter().map(|r| r.contact.as_str()).collect();
    table.set_item("contact", contacts)?;
    for (k, name) in ["f_x", "f_y", "f_z"][..forces.dim].iter().enumerate() {
        let column: Vec<f64> = rows.iter().map(|r| r.force[k]).collect();
        table.set_item(*name, PyArray1::from_vec(py, column))?;
    }
    if rows.iter().any(|r| r.sd.is_some()) {
        for (k, name) in ["sd_x", "sd_y", "sd_z"][..forces.dim].iter().enumerate() {
            let column: Vec<f64> = rows.iter().map(|r| r.sd.unwrap_or([0.0; 3])[k]).collect();
            table.set_item(*name, PyArray1::from_vec(py, column))?;
        }
    }
    Ok(table)
}

fn to_json<T: serde::Serialize + ?Sized>(value: &T) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// A scene object, or the path of a scene folder.
#[derive(FromPyObject)]
enum SceneOrFolder<'py> {
    Scene(PyRef<'py, Scene>),
    Folder(PathBuf),
}

/// One run of the library's inference (`grainforce::infer::run`): its
/// tables, report and the files `grainforce infer` writes, byte for byte.
#[pyclass(frozen, module = "grainforce._native")]
struct Run {
    run: run::Run,
}

#[pymethods]
impl Run {
    /// forces.csv's columns.
    fn forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        forces_table(py, &self.run.forces())
    }

    /// The report as JSON, one shape for one frame or many: `frames`,
    /// `time_fit`, `uncertainty`, `impulse`, `accelerations`.
    fn report(&self) -> PyResult<String> {
        to_json(&self.run.report_uniform())
    }

    /// Frame number and error of each failed frame.
    fn failed_frames(&self) -> Vec<(i64, String)> {
        let spell = |m: &str| grainforce::infer::config::spell_fields(m, keyword);
        self.run
            .failures
            .iter()
            .map(|(k, m)| (*k, spell(m)))
            .collect()
    }

    /// The impulse check's CSV text (`infer --impulse`), when it ran.
    fn impulse_csv(&self) -> Option<String> {
        let dim = self.run.frames.first().map_or(2, |f| f.dim);
        self.run.impulse.as_ref().map(|c| run::impulse_csv(c, dim))
    }

    /// The Pareto front's CSV text (`infer --pareto`), when swept.
    fn pareto_csv(&self) -> PyResult<Option<String>> {
        self.run
            .pareto()
            .map(|f| grainforce::report::pareto::pareto_csv(&f.points, f.knee))
            .transpose()
            .map_err(to_py)
    }

    /// Writes the files `grainforce infer` writes for this run (each
    /// atomically; `None` skips one): forces.csv, the JSON report, the
    /// impulse check and the Pareto front.
    #[pyo3(signature = (forces=None, report=None, impulse=None, pareto=None))]
    fn save(
        &self,
        py: Python<'_>,
        forces: Option<PathBuf>,
        report: Option<PathBuf>,
        impulse: Option<PathBuf>,
        pareto: Option<PathBuf>,
    ) -> PyResult<()> {
        let mut pending: Vec<(PathBuf, Vec<u8>)> = Vec::new();
        if let Some(path) = report {
            let json = serde_json::to_string_pretty(&self.run.report_json())
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            pending.push((path, json.into_bytes()));
        }
        if let Some(path) = impulse {
            let text = self.impulse_csv().ok_or_else(|| {
                PyValueError::new_err("no impulse check ran: infer with impulse=True (and fps)")
            })?;
            pending.push((path, text.into_bytes()));
        }
        if let Some(path) = pareto {
            let text = self.pareto_csv()?.ok_or_else(|| {
                PyValueError::new_err(
                    "no Pareto front: infer with method dynamic or soft and pareto=True",
                )
            })?;
            pending.push((path, text.into_bytes()));
        }
        py.detach(|| {
            if let Some(path) = &forces {
                scene::write_forces(path, &self.run.forces())?;
            }
            for (path, bytes) in &pending {
                scene::write_file_atomically(path, bytes)?;
            }
            Ok::<_, Error>(())
        })
        .map_err(to_py)
    }
}

/// The options as the library's configuration: JSON of the keyword
/// arguments, unknown keys refused, every field checked.
fn config_from_json(options: &str) -> PyResult<InferConfig> {
    let config: InferConfig = serde_json::from_str(options)
        .map_err(|e| PyValueError::new_err(format!("infer options: {e}")))?;
    config
        .validate()
        .map_err(|e| PyValueError::new_err(e.spelled(keyword)))?;
    Ok(config)
}

/// The error with the configuration's fields written as keyword arguments.
fn spelled(error: Error) -> Error {
    let spell = |m: &str| grainforce::infer::config::spell_fields(m, keyword);
    match error {
        Error::Invalid(m) => Error::Invalid(spell(&m)),
        Error::Infeasible(m) => Error::Infeasible(spell(&m)),
        Error::Solver(m) => Error::Solver(spell(&m)),
        e => e,
    }
}

/// A configuration field as a keyword argument: `time_fit='joint'`.
fn keyword(field: &str, value: Option<&str>) -> String {
    match value {
        Some(v) => format!("{field}='{v}'"),
        None => field.to_owned(),
    }
}

/// The library's configuration fields and their defaults, as JSON.
#[pyfunction]
fn infer_defaults() -> PyResult<String> {
    to_json(&InferConfig::default())
}

/// Infers the contact forces of a scene, or of a scene folder (reading only
/// the frames the options need), with `options` the JSON of the library's
/// configuration. `progress(done, total)` is called with the GIL taken
/// after each frame; the first exception it raises is raised once the
/// solves end.
#[pyfunction]
#[pyo3(name = "infer", signature = (scene, options, progress=None))]
fn infer_forces(
    py: Python<'_>,
    scene: SceneOrFolder<'_>,
    options: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<Run> {
    let config = config_from_json(options)?;
    let source = match &scene {
        SceneOrFolder::Scene(s) => Source::Frames(&s.frames),
        SceneOrFolder::Folder(dir) => Source::Folder(dir),
    };
    let callback_error = Mutex::new(None);
    let events = |event: Event<'_>| {
        if let Event::Frame(p) = event {
            report_progress(progress.as_ref(), p.done, p.total, &callback_error);
        }
    };
    let outcome = py.detach(|| {
        let ran = run::run(source, &config, Some(&events));
        // One frame reports no frame events: its end is the run's.
        if let Ok(r) = &ran {
            if r.single_frame {
                report_progress(progress.as_ref(), 1, 1, &callback_error);
            }
        }
        ran
    });
    if let Some(e) = callback_error.into_inner().ok().flatten() {
        return Err(e);
    }
    let run = outcome.map_err(|e| to_py(spelled(e)))?;
    Ok(Run { run })
}

fn report_progress(
    progress: Option<&Py<PyAny>>,
    done: usize,
    total: usize,
    callback_error: &Mutex<Option<PyErr>>,
) {
    let Some(callback) = progress else { return };
    // Called from a solving thread, which holds no GIL: take it for the call.
    Python::attach(|py| {
        if let Err(e) = callback.call1(py, (done, total)) {
            if let Ok(mut slot) = callback_error.lock() {
                slot.get_or_insert(e);
            }
        }
    });
}

/// Runs a DEM preset. Returns the scene, its exact forces as forces.csv
/// columns and the gate report as JSON.
#[pyfunction]
#[pyo3(signature = (preset, dim=2, seed=1, grains=None, gate=None, duration=None, frames_every=None, max_steps=None, verbose=false))]
#[allow(clippy::too_many_arguments)]
fn dem<'py>(
    py: Python<'py>,
    preset: &str,
    dim: usize,
    seed: u64,
    grains: Option<usize>,
    gate: Option<f64>,
    duration: Option<f64>,
    frames_every: Option<u64>,
    max_steps: Option<u64>,
    verbose: bool,
) -> PyResult<(Scene, Bound<'py, PyDict>, String)> {
    use grainforce::dem::{self, DemConfig, Preset};
    let preset = match preset.replace('_', "-").as_str() {
        "oedometer" => Preset::Oedometer,
        "box" => Preset::Box,
        "impact" => Preset::Impact,
        "bed-impact" => Preset::BedImpact,
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown DEM preset `{other}`: expected oedometer, box, impact or bed-impact"
            )))
        }
    };
    if dim != 2 && dim != 3 {
        return Err(PyValueError::new_err(format!(
            "dim must be 2 or 3 (got {dim})"
        )));
    }
    let mut c = DemConfig::preset(preset, dim).seed(seed).verbose(verbose);
    if let Some(n) = grains {
        c.grains = n;
    }
    if let Some(g) = gate {
        c.gate = g;
    }
    if let Some(d) = duration {
        c.duration = d;
    }
    if let Some(k) = frames_every {
        if k == 0 {
            return Err(PyValueError::new_err("frames_every must be at least 1"));
        }
        c.frames_every = Some(k);
    }
    if let Some(s) = max_steps {
        c.max_steps = s;
    }
    let run = py.detach(|| dem::simulate(&c)).map_err(to_py)?;
    let mut forces = Forces {
        dim,
        rows: Vec::new(),
    };
    for (frame, f) in run.frames.iter().zip(&run.forces) {
        forces.rows.extend(Forces::from_scene(frame, f).rows);
    }
    let table = forces_table(py, &forces)?;
    let report = to_json(&run.report)?;
    Ok((Scene { frames: run.frames }, table, report))
}

/// A synthetic packing with its exact forces (the benchmark's generator):
/// the scene and the forces as forces.csv columns.
#[pyfunction]
#[pyo3(signature = (dim=2, grains=1000, seed=1))]
fn packing<'py>(
    py: Python<'py>,
    dim: usize,
    grains: usize,
    seed: u64,
) -> PyResult<(Scene, Bound<'py, PyDict>)> {
    use grainforce::bench::generate::{generate, PackingSpec};
    let mut spec = PackingSpec::new(dim, grains);
    spec.seed = seed;
    let packing = py.detach(|| generate(&spec)).map_err(to_py)?;
    let table = forces_table(py, &Forces::from_scene(&packing.scene, &packing.truth))?;
    Ok((
        Scene {
            frames: vec![packing.scene],
        },
        table,
    ))
}

/// Finds disks in a grey image (rows = y, columns = x, in pixels). Returns
/// the columns x, y, r, support, visible, contrast, rms.
#[pyfunction]
#[pyo3(signature = (image, radius_min, radius_max, polarity="bright", smoothing=None))]
fn detect<'py>(
    py: Python<'py>,
    image: PyReadonlyArray2<'py, f64>,
    radius_min: f64,
    radius_max: f64,
    polarity: &str,
    smoothing: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    use grainforce::image::{detect_disks, DetectOptions, FloatImage, Polarity};
    let view = image.as_array();
    let (height, width) = view.dim();
    if width == 0 || height == 0 {
        return Err(PyValueError::new_err("the image is empty"));
    }
    if view.iter().any(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(
            "the image holds NaN or infinite values",
        ));
    }
    let (w, h) = (
        u32::try_from(width).map_err(|_| PyValueError::new_err("the image is too wide"))?,
        u32::try_from(height).map_err(|_| PyValueError::new_err("the image is too tall"))?,
    );
    let picture = FloatImage::from_fn(w, h, |x, y| {
        ::image::Luma([view[[y as usize, x as usize]] as f32])
    });
    let mut options = DetectOptions::new(radius_min, radius_max);
    options.polarity = match polarity {
        "bright" => Polarity::Bright,
        "dark" => Polarity::Dark,
        "either" => Polarity::Either,
        other => {
            return Err(PyValueError::new_err(format!(
                "polarity must be 'bright', 'dark' or 'either', not '{other}'"
            )))
        }
    };
    options.smoothing_px = smoothing;
    let disks = py
        .detach(|| detect_disks(&picture, &options))
        .map_err(to_py)?;
    let table = PyDict::new(py);
    type Field = fn(&grainforce::image::Disk) -> f64;
    let fields: [(&str, Field); 7] = [
        ("x", |d| d.x),
        ("y", |d| d.y),
        ("r", |d| d.r),
        ("support", |d| d.support),
        ("visible", |d| d.visible),
        ("contrast", |d| d.contrast),
        ("rms", |d| d.rms),
    ];
    for (name, field) in fields {
        let column: Vec<f64> = disks.iter().map(field).collect();
        table.set_item(name, PyArray1::from_vec(py, column))?;
    }
    Ok(table)
}

/// A label volume as NumPy holds it: any integer type a segmentation writes.
#[derive(FromPyObject)]
enum LabelArray<'py> {
    U8(PyReadonlyArray3<'py, u8>),
    U16(PyReadonlyArray3<'py, u16>),
    U32(PyReadonlyArray3<'py, u32>),
    U64(PyReadonlyArray3<'py, u64>),
    I8(PyReadonlyArray3<'py, i8>),
    I16(PyReadonlyArray3<'py, i16>),
    I32(PyReadonlyArray3<'py, i32>),
    I64(PyReadonlyArray3<'py, i64>),
}

/// A label import: the scene, every touching zone's measurements and,
/// with stresses attached, the match.
#[pyclass(frozen, module = "grainforce._native")]
struct LabelImport {
    imported: grainforce::import::labels::LabelScene,
    matched: Option<grainforce::import::register::StressMatch>,
}

#[pymethods]
impl LabelImport {
    fn scene(&self) -> Scene {
        Scene {
            frames: vec![self.imported.scene.clone()],
        }
    }

    /// contacts_quality.csv's text.
    fn quality_csv(&self) -> String {
        self.imported.quality_csv()
    }

    #[getter]
    fn rattlers(&self) -> Vec<String> {
        self.imported.rattlers.clone()
    }

    #[getter]
    fn cut(&self) -> Vec<String> {
        self.imported.cut.clone()
    }

    #[getter]
    fn warnings(&self) -> Vec<String> {
        let mut w = self.imported.warnings.clone();
        if let Some(m) = &self.matched {
            w.extend(m.warnings.iter().cloned());
        }
        w
    }

    /// stress_match.csv and stress_match.json's texts, when stresses were attached.
    fn stress_match(&self) -> Option<(String, String)> {
        self.matched.as_ref().map(|m| m.texts())
    }

    /// Writes the folder `grainforce import labels` writes.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| {
            self.imported.write(&path)?;
            if let Some(m) = &self.matched {
                m.write(&path)?;
            }
            Ok::<_, Error>(())
        })
        .map_err(to_py)
    }
}

/// Imports a labelled volume (z, y, x) into grains and contacts
/// (`grainforce import labels`), optionally attaching per-grain stresses
/// from a scene folder or CSV by position.
#[pyfunction]
#[pyo3(signature = (volume, voxel_size, origin=None, grey=None, walls=Vec::new(), container=None, density=None, normals="fit", max_gap=None, min_grey=0.9, stresses=None, match_distance=None, match_transform="rigid"))]
#[allow(clippy::too_many_arguments)]
fn import_labels(
    py: Python<'_>,
    volume: LabelArray<'_>,
    voxel_size: f64,
    origin: Option<[f64; 3]>,
    grey: Option<PyReadonlyArray3<'_, f32>>,
    walls: Vec<String>,
    container: Option<u32>,
    density: Option<f64>,
    normals: &str,
    max_gap: Option<f64>,
    min_grey: f64,
    stresses: Option<PathBuf>,
    match_distance: Option<f64>,
    match_transform: &str,
) -> PyResult<LabelImport> {
    use grainforce::import::labels::{self, NormalMethod, Options, WallPlane};
    use grainforce::import::register::{self, MatchOptions, TransformModel};
    let walls = walls
        .iter()
        .map(|w| WallPlane::parse(w))
        .collect::<grainforce::Result<Vec<_>>>()
        .map_err(to_py)?;
    let options = Options {
        voxel_size,
        origin: origin.unwrap_or([0.0; 3]),
        walls,
        container,
        normals: NormalMethod::parse(normals).map_err(to_py)?,
        density,
        max_gap,
        min_grey,
        ..Options::default()
    };
    let transform = TransformModel::parse(match_transform).map_err(to_py)?;
    let source = match &stresses {
        Some(p) => Some(
            py.detach(|| register::read_stressed_grains(p))
                .map_err(to_py)?,
        ),
        None => None,
    };
    let not_contiguous =
        |_| PyValueError::new_err("the volume must be a C-contiguous array (np.ascontiguousarray)");
    let grey_data = match &grey {
        Some(g) => Some((g.as_slice().map_err(not_contiguous)?, g.shape().to_vec())),
        None => None,
    };
    macro_rules! run {
        ($a:expr) => {{
            let shape = $a.shape().to_vec();
            let data = $a.as_slice().map_err(not_contiguous)?;
            if let Some((_, gs)) = &grey_data {
                if *gs != shape {
                    return Err(PyValueError::new_err(format!(
                        "grey has shape {gs:?}, the volume {shape:?}"
                    )));
                }
            }
            let g = grey_data.as_ref().map(|(g, _)| *g);
            py.detach(|| labels::import_array(data, [shape[0], shape[1], shape[2]], g, &options))
        }};
    }
    let mut imported = match &volume {
        LabelArray::U8(a) => run!(a),
        LabelArray::U16(a) => run!(a),
        LabelArray::U32(a) => run!(a),
        LabelArray::U64(a) => run!(a),
        LabelArray::I8(a) => run!(a),
        LabelArray::I16(a) => run!(a),
        LabelArray::I32(a) => run!(a),
        LabelArray::I64(a) => run!(a),
    }
    .map_err(to_py)?;
    let matched = match &source {
        Some(source) => {
            let options = MatchOptions {
                max_distance: match_distance,
                transform,
                ..MatchOptions::default()
            };
            Some(
                py.detach(|| register::attach_stresses(&mut imported.scene, source, &options))
                    .map_err(to_py)?,
            )
        }
        None => None,
    };
    Ok(LabelImport { imported, matched })
}

/// Imports an ImageD11 grain map (`.map`/`.ubi` or HDF5) into a 3D scene with
/// sample-frame stresses (`grainforce import imaged11`).
#[pyfunction]
#[pyo3(signature = (path, cell, stiffness, grain_volume=None, contacts=None, phase=None))]
fn import_imaged11(
    py: Python<'_>,
    path: PathBuf,
    cell: [f64; 6],
    stiffness: &str,
    grain_volume: Option<f64>,
    contacts: Option<PathBuf>,
    phase: Option<String>,
) -> PyResult<Scene> {
    use grainforce::import::{imaged11, stiffness::Stiffness};
    let options = imaged11::Options {
        cell,
        stiffness: Stiffness::parse(stiffness).map_err(to_py)?,
        grain_volume,
        phase,
    };
    let imported = py
        .detach(|| imaged11::import(&path, contacts.as_deref(), &options))
        .map_err(to_py)?;
    Ok(Scene {
        frames: imported.frames,
    })
}

/// A photoelastic fit (`grainforce::image::fringe_run`): forces, report,
/// overlay and the files `grainforce photoelastic` writes.
#[pyclass(frozen, module = "grainforce._native")]
struct Photoelastic {
    run: grainforce::image::fringe_run::PhotoelasticRun,
}

#[pymethods]
impl Photoelastic {
    /// forces.csv's columns.
    fn forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        forces_table(py, &self.run.forces())
    }

    /// The report as `--report` writes it (JSON).
    fn report(&self) -> String {
        self.run.report_text()
    }

    /// The photograph (left) and the fitted fringes (right) side by side,
    /// rows = y down, intensities in [0, 1].
    fn overlay<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
        let both = py.detach(|| self.run.overlay()).map_err(to_py)?;
        let (w, h) = both.dimensions();
        let array =
            numpy::ndarray::Array2::from_shape_vec((h as usize, w as usize), both.into_raw())
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(numpy::PyArray2::from_owned_array(py, array))
    }

    /// Writes what `grainforce photoelastic -o FORCES --report REPORT
    /// --overlay OVERLAY` writes (`None` skips one).
    #[pyo3(signature = (forces=None, report=None, overlay=None))]
    fn save(
        &self,
        py: Python<'_>,
        forces: Option<PathBuf>,
        report: Option<PathBuf>,
        overlay: Option<PathBuf>,
    ) -> PyResult<()> {
        py.detach(|| {
            self.run
                .write(forces.as_deref(), report.as_deref(), overlay.as_deref())
        })
        .map_err(to_py)
    }
}

/// Contact forces fitted to a photoelastic photograph's fringes, all disks
/// at once under balance and friction (`grainforce photoelastic`). `None`
/// keeps the CLI's default.
#[pyfunction]
#[pyo3(signature = (image, scene, fsigma=None, thickness=None, scale=None, channel=None, mu=None, balance_weight=None, blur=None, edge=None, iterations=None, per_disk=false, contacts=None, candidates=None, sparsity=None, wall_mu=None, polariscope=None, lighting=false, penalty_start=None, narrow_start=None, local_starts=None))]
#[allow(clippy::too_many_arguments)]
fn photoelastic(
    py: Python<'_>,
    image: PathBuf,
    scene: PathBuf,
    fsigma: Option<f64>,
    thickness: Option<f64>,
    scale: Option<f64>,
    channel: Option<&str>,
    mu: Option<f64>,
    balance_weight: Option<f64>,
    blur: Option<f64>,
    edge: Option<f64>,
    iterations: Option<usize>,
    per_disk: bool,
    contacts: Option<&str>,
    candidates: Option<f64>,
    sparsity: Option<f64>,
    wall_mu: Option<f64>,
    polariscope: Option<&str>,
    lighting: bool,
    penalty_start: Option<f64>,
    narrow_start: Option<f64>,
    local_starts: Option<usize>,
) -> PyResult<Photoelastic> {
    use grainforce::image::fringe_run::{self, ContactChoice, PhotoelasticConfig};
    // Fields a caller leaves out keep the library's defaults (the CLI's).
    let mut config = PhotoelasticConfig {
        fsigma,
        thickness,
        scale,
        balance_weight,
        per_disk,
        candidate_gap: candidates,
        wall_mu,
        lighting,
        ..PhotoelasticConfig::default()
    };
    if let Some(name) = polariscope {
        config.polariscope = name.parse().map_err(PyValueError::new_err)?;
    }
    if let Some(name) = channel {
        config.channel = grainforce::image::Channel::parse(name).map_err(to_py)?;
    }
    config.contacts = match contacts {
        None => config.contacts,
        Some("all") => ContactChoice::All,
        Some("evidence") => ContactChoice::Evidence,
        Some(other) => {
            return Err(PyValueError::new_err(format!(
                "contacts must be 'all' or 'evidence', not '{other}'"
            )))
        }
    };
    config.mu = mu.unwrap_or(config.mu);
    config.blur = blur.unwrap_or(config.blur);
    config.edge = edge.unwrap_or(config.edge);
    config.iterations = iterations.unwrap_or(config.iterations);
    config.sparsity = sparsity.unwrap_or(config.sparsity);
    config.penalty_start = penalty_start.unwrap_or(config.penalty_start);
    config.narrow_start = narrow_start.unwrap_or(config.narrow_start);
    config.local_starts = local_starts.unwrap_or(config.local_starts);
    let run = py
        .detach(|| fringe_run::run(&image, &scene, &config))
        .map_err(to_py)?;
    Ok(Photoelastic { run })
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Scene>()?;
    m.add_function(wrap_pyfunction!(read_scene, m)?)?;
    m.add_class::<Run>()?;
    m.add_function(wrap_pyfunction!(infer_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(infer_forces, m)?)?;
    m.add_function(wrap_pyfunction!(dem, m)?)?;
    m.add_function(wrap_pyfunction!(detect, m)?)?;
    m.add_function(wrap_pyfunction!(packing, m)?)?;
    m.add_function(wrap_pyfunction!(write_table, m)?)?;
    m.add_class::<LabelImport>()?;
    m.add_function(wrap_pyfunction!(import_labels, m)?)?;
    m.add_function(wrap_pyfunction!(import_imaged11, m)?)?;
    m.add_class::<Photoelastic>()?;
    m.add_function(wrap_pyfunction!(photoelastic, m)?)?;
    m.add("InfeasibleError", m.py().get_type::<InfeasibleError>())?;
    m.add("SolverError", m.py().get_type::<SolverError>())?;
    Ok(())
}
