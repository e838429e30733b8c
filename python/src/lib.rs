//! `mlod._mlod`: the native half of the Python package. Every function here calls the same library
//! functions as the CLI (`mlod fuse`/`export`, `detect`, `eval`, `calibrate`), so the numbers are
//! the CLI's by construction. The pure-Python half (`python/mlod/__init__.py`) checks dtypes and
//! shapes and documents the API; this half releases the GIL while Rust works, turns every error
//! (and any panic) into `mlod.MlodError`, and hands arrays to numpy without copying them.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::{Matrix3, Vector3};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2};
use pyo3::create_exception;
use pyo3::prelude::*;
use pyo3::types::PyList;
use rayon::prelude::*;

use mlod::calib::report::CalibrationRun;
use mlod::calib::{IcpConfig, OcPrior};
use mlod::cases::run::{detections_json, RunOptions};
use mlod::dataset::{Frame, LidarChannel};
use mlod::detect::Case;
use mlod::geometry::Pose;
use mlod::pipeline::{self, FuseParams};
use mlod::uncertainty::{Perturbation, TraceKernel};

create_exception!(
    _mlod,
    MlodError,
    pyo3::exceptions::PyException,
    "An error of mlod: a missing or corrupt file, an unknown sample or case, a bad argument. The message names what is wrong."
);

/// Runs `f` without the GIL; its error, or a panic, becomes `MlodError`.
fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> Result<T, String> + Send) -> PyResult<T> {
    let out = py.detach(|| catch_unwind(AssertUnwindSafe(f)));
    match out {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(msg)) => Err(MlodError::new_err(msg)),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown".into());
            Err(MlodError::new_err(format!(
                "internal error (a bug in mlod, please report it): {what}"
            )))
        }
    }
}

/// An error with its causes, as the CLI prints them.
fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut src = e.source();
    while let Some(c) = src {
        let m = c.to_string();
        if !s.contains(&m) {
            s.push_str(": ");
            s.push_str(&m);
        }
        src = c.source();
    }
    s
}

fn msg<E: std::error::Error>(e: E) -> String {
    chain(&e)
}

/// A JSON value as the Python objects `json.loads` makes of it (what the CLI's `--json` prints).
fn to_py(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(v).map_err(|e| MlodError::new_err(e.to_string()))?;
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

/// A 4×4 homogeneous matrix (row-major) of a pose.
fn pose_matrix(p: &Pose) -> Vec<f64> {
    let m = p.to_homogeneous();
    (0..4).flat_map(|i| (0..4).map(move |j| m[(i, j)])).collect()
}

/// The rotation block and translation of a 4×4 extrinsic, checked: finite, a rotation (RᵀR = I
/// within 1e-6, det +1), last row [0, 0, 0, 1].
fn extrinsic_parts(m: &[f64]) -> Result<(Matrix3<f64>, Vector3<f64>), String> {
    if m.len() != 16 {
        return Err(format!("extrinsic: expected 4x4 values, got {}", m.len()));
    }
    if let Some(i) = m.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "extrinsic: entry [{}, {}] is not finite ({})",
            i / 4,
            i % 4,
            m[i]
        ));
    }
    let r = Matrix3::from_fn(|i, j| m[4 * i + j]);
    let t = Vector3::new(m[3], m[7], m[11]);
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if off > 1e-6 || r.determinant() < 0.0 {
        return Err(format!(
            "extrinsic: the 3x3 block is not a rotation (|RᵀR − I| = {off:.2e}, det {:.3})",
            r.determinant()
        ));
    }
    if (m[12], m[13], m[14], m[15]) != (0.0, 0.0, 0.0, 1.0) {
        return Err("extrinsic: the last row must be [0, 0, 0, 1]".into());
    }
    Ok((r, t))
}

fn channel(name: &str) -> Result<LidarChannel, String> {
    LidarChannel::from_channel(name).ok_or_else(|| {
        let names: Vec<&str> = LidarChannel::ALL.iter().map(|c| c.as_str()).collect();
        format!("{name}: not a LiDAR channel (one of {})", names.join(", "))
    })
}

fn case(name: &str) -> Result<Case, String> {
    name.parse::<Case>().map_err(|e| format!("case {name}: {e}"))
}

fn fuse_params(alpha: f64, seed: u64) -> Result<FuseParams, String> {
    Ok(FuseParams {
        perturbation: Perturbation::new(alpha, seed).map_err(|e| format!("alpha {alpha}: {}", msg(e)))?,
        ..Default::default()
    })
}

/// The perturbed extrinsic of one auxiliary LiDAR: the draw `Dataset.fuse` applies to it.
#[pyfunction]
#[pyo3(signature = (extrinsic, alpha, seed, lidar))]
fn perturb<'py>(
    py: Python<'py>,
    extrinsic: PyReadonlyArray2<'py, f64>,
    alpha: f64,
    seed: u64,
    lidar: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let m = extrinsic
        .as_slice()
        .map_err(|e| MlodError::new_err(e.to_string()))?
        .to_vec();
    let lidar = lidar.to_string();
    let out = run(py, move || {
        let ch = channel(&lidar)?;
        if ch == LidarChannel::Top {
            return Err("LIDAR_TOP is the primary LiDAR: it is never perturbed".into());
        }
        let (r, t) = extrinsic_parts(&m)?;
        let nominal = Pose::from_parts(
            nalgebra::Translation3::from(t),
            nalgebra::UnitQuaternion::from_matrix(&r),
        );
        let params = fuse_params(alpha, seed)?;
        let noise = params.noise_for(ch).map_err(msg)?;
        Ok(pose_matrix(&noise.apply(&nominal)))
    })?;
    PyArray1::from_vec(py, out).reshape([4, 4])
}

/// Ξ and tr(Ξ) as numpy arrays.
type XiAndTrace<'py> = (Bound<'py, PyArray3<f32>>, Bound<'py, PyArray1<f32>>);

/// Ξ (N×3×3) and tr(Ξ) (N) of points (N×3, float32, sensor frame) of an auxiliary LiDAR at
/// `extrinsic` under Θ(α) (eq. 9 prior, the pipeline's linearisation).
#[pyfunction]
fn propagate<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f32>,
    extrinsic: PyReadonlyArray2<'py, f64>,
    alpha: f64,
) -> PyResult<XiAndTrace<'py>> {
    let m = extrinsic
        .as_slice()
        .map_err(|e| MlodError::new_err(e.to_string()))?
        .to_vec();
    let p = points.as_slice().map_err(|e| MlodError::new_err(e.to_string()))?;
    let n = p.len() / 3;
    let (xi, trace) = run(py, || {
        let (r, t) = extrinsic_parts(&m)?;
        if let Some(i) = p.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "points: row {} holds a non-finite value ({})",
                i / 3,
                p[i]
            ));
        }
        let params = fuse_params(alpha, 0)?;
        let prior = params
            .prior
            .scaled(alpha)
            .map_err(|e| format!("alpha {alpha}: {}", msg(e)))?;
        let kernel = TraceKernel::new(&r, &t, &prior, params.linearization);
        // One parallel pass over the interleaved points: tr(Ξ) and Ξ's nine entries (row-major,
        // from its six unique ones xx, yy, zz, xy, xz, yz), the kernel the pipeline runs.
        let mut trace = vec![0.0f32; n];
        let mut xi = vec![0.0f32; 9 * n];
        const CHUNK: usize = 4096;
        trace
            .par_chunks_mut(CHUNK)
            .zip(xi.par_chunks_mut(9 * CHUNK))
            .zip(p.par_chunks(3 * CHUNK))
            .for_each(|((tr, xi), pts)| {
                for ((t, m), q) in tr.iter_mut().zip(xi.chunks_exact_mut(9)).zip(pts.chunks_exact(3)) {
                    *t = kernel.trace(q[0], q[1], q[2]);
                    let c = kernel.covariance6(q[0], q[1], q[2]);
                    m.copy_from_slice(&[c[0], c[3], c[4], c[3], c[1], c[5], c[4], c[5], c[2]]);
                }
            });
        Ok((xi, trace))
    })?;
    Ok((
        PyArray1::from_vec(py, xi).reshape([n, 3, 3])?,
        PyArray1::from_vec(py, trace),
    ))
}

/// The prior Θ(α) of eq. 9 scaled by α: P (translation), Φ (rotation) and Z (measurement), each
/// 3×3 — what `perturb` draws from and `propagate` propagates.
#[pyfunction]
fn prior<'py>(py: Python<'py>, alpha: f64) -> PyResult<[Bound<'py, PyArray2<f64>>; 3]> {
    let p = run(py, || {
        fuse_params(alpha, 0)?
            .prior
            .scaled(alpha)
            .map_err(|e| format!("alpha {alpha}: {}", msg(e)))
    })?;
    let m = |x: &Matrix3<f64>| -> PyResult<Bound<'py, PyArray2<f64>>> {
        let v: Vec<f64> = (0..3).flat_map(|i| (0..3).map(move |j| x[(i, j)])).collect();
        PyArray1::from_vec(py, v).reshape([3, 3])
    };
    Ok([m(&p.p)?, m(&p.phi)?, m(&p.z)?])
}

/// Defines an external detector (`ext:NAME`, `mlod-ext:NAME`) for this process, as the CLI's
/// `--detector NAME=COMMAND`.
#[pyfunction]
fn define_detector(name: &str, command: &str) -> PyResult<()> {
    let spec = mlod::external::ExternalSpec::parse_arg(&format!("{name}={command}"))
        .map_err(|e| MlodError::new_err(msg(e)))?;
    mlod::external::define(spec).map_err(|e| MlodError::new_err(msg(e)))
}

/// An opened dataset (any format the reader opens) and the models folder its detectors load from.
#[pyclass(frozen, module = "mlod._mlod")]
struct Dataset {
    inner: Arc<mlod::dataset::Dataset>,
    path: PathBuf,
    models: PathBuf,
}

impl Dataset {
    fn frame(&self, sample: &str) -> Result<Frame, String> {
        self.inner
            .frame(sample)
            .map_err(|e| format!("sample {sample}: {}", msg(e)))
    }

    fn options(&self, alpha: f64, seed: u64) -> RunOptions {
        RunOptions {
            alpha,
            seed,
            models: Some(self.models.clone()),
            ..Default::default()
        }
    }
}

#[pymethods]
impl Dataset {
    #[new]
    #[pyo3(signature = (path, models=None))]
    fn new(py: Python<'_>, path: PathBuf, models: Option<PathBuf>) -> PyResult<Self> {
        let p = path.clone();
        let inner = run(py, move || {
            mlod::dataset::Dataset::open(&p)
                .map_err(|e| format!("opening dataset {}: {}", p.display(), msg(e)))
        })?;
        let models = models.unwrap_or_else(mlod::detect::weights::default_models_dir);
        Ok(Self {
            inner: Arc::new(inner),
            path,
            models,
        })
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    #[getter]
    fn models(&self) -> PathBuf {
        self.models.clone()
    }

    /// What the reader noted while opening (the split opened, unknown categories, …).
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.inner.notes()
    }

    #[getter]
    fn samples(&self) -> Vec<String> {
        mlod::dataset::list(&self.inner)
            .into_iter()
            .map(|s| s.sample_token)
            .collect()
    }

    fn frame_dict<'py>(&self, py: Python<'py>, sample: &str) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let frame = run(py, || self.frame(sample))?;
        let d = pyo3::types::PyDict::new(py);
        d.set_item("sample_token", &frame.sample_token)?;
        let lidars = PyList::empty(py);
        for scan in frame.lidars() {
            let pts = &scan.points;
            let n = pts.x.len();
            let mut flat = Vec::with_capacity(5 * n);
            for i in 0..n {
                flat.extend_from_slice(&[pts.x[i], pts.y[i], pts.z[i], pts.intensity[i], pts.ring[i]]);
            }
            let l = pyo3::types::PyDict::new(py);
            l.set_item("channel", scan.info.channel.as_str())?;
            l.set_item("points", PyArray1::from_vec(py, flat).reshape([n, 5])?)?;
            l.set_item(
                "extrinsic",
                PyArray1::from_vec(py, pose_matrix(&scan.info.extrinsic)).reshape([4, 4])?,
            )?;
            lidars.append(l)?;
        }
        d.set_item("lidars", lidars)?;
        let boxes: Vec<serde_json::Value> = frame
            .boxes
            .iter()
            .map(|b| {
                serde_json::json!({
                    "annotation_token": b.annotation_token,
                    "category": b.category,
                    "source_category": b.source_category,
                    "center": b.box3d.center,
                    "size_lwh": b.box3d.size_lwh,
                    "yaw": b.box3d.yaw,
                    "num_lidar_pts": b.num_lidar_pts,
                    "occlusion": b.occlusion,
                    "truncation": b.truncation,
                })
            })
            .collect();
        d.set_item("boxes", to_py(py, &serde_json::Value::Array(boxes))?)?;
        Ok(d)
    }

    fn fuse_dict<'py>(
        &self,
        py: Python<'py>,
        sample: &str,
        alpha: f64,
        seed: u64,
    ) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let cloud = run(py, || {
            let frame = self.frame(sample)?;
            let params = fuse_params(alpha, seed)?;
            pipeline::fuse(&frame, &params).map_err(|e| format!("fusing sample {sample}: {}", msg(e)))
        })?;
        // x, y and z end to end in x's buffer (grown once): a 3×N array whose transpose is the
        // N×3 `points` (Fortran order), without interleaving every point.
        let n = cloud.x.len();
        let mut xyz = cloud.x;
        xyz.reserve_exact(2 * n);
        xyz.extend_from_slice(&cloud.y);
        xyz.extend_from_slice(&cloud.z);
        let d = pyo3::types::PyDict::new(py);
        let channels: Vec<&str> = cloud.lidars.iter().map(|l| l.channel.as_str()).collect();
        let extrinsics = pyo3::types::PyDict::new(py);
        for l in &cloud.lidars {
            extrinsics.set_item(
                l.channel.as_str(),
                PyArray1::from_vec(py, pose_matrix(&l.applied)).reshape([4, 4])?,
            )?;
        }
        d.set_item(
            "points",
            PyArray1::from_vec(py, xyz).reshape([3, n])?.transpose()?,
        )?;
        d.set_item("trace", PyArray1::from_vec(py, cloud.trace))?;
        d.set_item("lidar", PyArray1::from_vec(py, cloud.source))?;
        d.set_item("intensity", PyArray1::from_vec(py, cloud.intensity))?;
        d.set_item("channels", channels)?;
        d.set_item("extrinsics", extrinsics)?;
        Ok(d)
    }

    fn detect_list(
        &self,
        py: Python<'_>,
        sample: &str,
        case_name: &str,
        alpha: f64,
        seed: u64,
    ) -> PyResult<Py<PyAny>> {
        let json = run(py, || {
            let c = case(case_name)?;
            let opts = self.options(alpha, seed);
            let detector = opts.load(c).map_err(msg)?;
            let mut frame = self.frame(sample)?;
            opts.apply_intensity(&mut frame);
            let params = opts.fuse_params().map_err(msg)?;
            let dets = detector
                .detect(&frame, &params)
                .map_err(|e| format!("{} on sample {sample}: {}", c.paper_name(), msg(e)))?;
            Ok(detections_json(&frame.sample_token, c, &dets))
        })?;
        let v = json.get("detections").cloned().unwrap_or_default();
        to_py(py, &v)
    }

    #[pyo3(signature = (case_name, alpha, seed, samples=None))]
    fn evaluate_dict(
        &self,
        py: Python<'_>,
        case_name: &str,
        alpha: f64,
        seed: u64,
        samples: Option<usize>,
    ) -> PyResult<Py<PyAny>> {
        let json = run(py, || {
            let c = case(case_name)?;
            let eval_opts = mlod::eval::EvalOptions {
                samples,
                ..Default::default()
            };
            let tokens = mlod::eval::sample_tokens(&self.inner, &eval_opts);
            let opts = self.options(alpha, seed);
            let detector = opts.load(c).map_err(msg)?;
            let (dets, _) = opts
                .detect_samples(&self.inner, &tokens, detector.as_ref(), c, &|| ())
                .map_err(msg)?;
            let report = mlod::eval::evaluate_detections(&self.inner, &dets, &eval_opts).map_err(msg)?;
            serde_json::to_value(&report).map_err(|e| e.to_string())
        })?;
        to_py(py, &json)
    }

    fn calibrate_list(&self, py: Python<'_>, sample: &str, alpha: f64, seed: u64) -> PyResult<Py<PyAny>> {
        let json = run(py, || {
            let frame = self.frame(sample)?;
            let params = fuse_params(alpha, seed)?;
            let cal = pipeline::calibrate(&frame, &params, &IcpConfig::default(), OcPrior::Icp)
                .map_err(|e| format!("calibrating sample {sample}: {}", msg(e)))?;
            let mut runs = Vec::new();
            for l in &cal.lidars {
                let truth = frame
                    .lidar(l.channel)
                    .map(|s| s.info.extrinsic)
                    .ok_or_else(|| format!("sample {sample}: calibrated LiDAR {} missing", l.channel))?;
                runs.push(CalibrationRun::new(&frame.sample_token, seed, l, &truth, None));
            }
            serde_json::to_value(&runs).map_err(|e| e.to_string())
        })?;
        to_py(py, &json)
    }
}

#[pymodule]
fn _mlod(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("MlodError", m.py().get_type::<MlodError>())?;
    m.add_class::<Dataset>()?;
    m.add_function(wrap_pyfunction!(perturb, m)?)?;
    m.add_function(wrap_pyfunction!(propagate, m)?)?;
    m.add_function(wrap_pyfunction!(define_detector, m)?)?;
    m.add_function(wrap_pyfunction!(prior, m)?)?;
    Ok(())
}
