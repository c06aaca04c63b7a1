//! `flatport._flatport`: the compiled half of the Python package. The Python half
//! (`python/flatport/__init__.py`) checks and converts arguments (shapes, dtypes, camera names)
//! and documents the API; this module takes C-contiguous float64 arrays, runs the engine with the
//! GIL released and hands the results to numpy without a copy (`PyArray::from_vec`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use numpy::prelude::*;
use numpy::{PyArray1, PyArray2, PyArray3, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use flatport::calib::sweep::{Linspace, SweepSpec, sweep as run_sweep};
use flatport::calib::{Backend, Board, CostBackend, CostKind, CpuBackend, Estimate, GpuBackend, Method, Options, SceneSpec, StereoData, Target, calibrate as run_calibrate, simulate as run_simulate};
use flatport::engine::raymap::backproject_rows;
use flatport::engine::{Device, Engine, EngineOptions};
use flatport::engine::GpuEngine;
use flatport::engine::gpu::{Pixels, Points, Rays, Triangulated};
use flatport::gpu::{DeviceRows, GpuError, Precision, RowKind};
use flatport::io::{ColmapDialect, Truth, aquacal_json, read_aquacal, colmap_cameras_txt_as, colmap_rig_config, colmap_rigs_txt, observations_from_json_str, opencv_yaml, read_rig, report_to_json_string, rig_from_json_str, rig_to_json_string, stereo_observations_to_json_string};
use flatport::io::calib_json::truth_to_json_string;
use flatport::calib::pipeline::boards::{PortKind, RefineIntrinsics, RigSetup};
use flatport::runs::board_footage::{DEFAULT_MAX_AIR_VIEWS, DEFAULT_MAX_WATER_FRAMES, FootageOptions, read_board_footage};
use flatport::runs::images::{
    FitSettings, Glass, LensSource, air_lens, boards_options, calibrate as run_calibration, cameras_from_rig, check_glass,
    glass_per_camera, refusal, water_lens_starts,
};
use flatport::io::calib_json::boards_report_to_json_string;
use flatport::io::{read_board, write_boards_report, write_rig};
use flatport::model::Rig;

fn value_error(error: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(error.to_string())
}

fn runtime_error(error: impl std::fmt::Display) -> PyErr {
    PyRuntimeError::new_err(error.to_string())
}

/// The engine options of `device` ("cpu" | "gpu" | "auto") and `precision` ("f64" | "f32").
fn engine_options(device: &str, precision: &str) -> PyResult<EngineOptions> {
    let device = match device {
        "cpu" => Device::Cpu,
        "gpu" => Device::Gpu,
        "auto" => Device::Auto,
        other => return Err(value_error(format!("device must be 'cpu', 'gpu' or 'auto', got {other:?}"))),
    };
    let precision = match precision {
        "f64" => Precision::F64,
        "f32" => Precision::F32,
        other => return Err(value_error(format!("precision must be 'f64' or 'f32', got {other:?}"))),
    };
    if device == Device::Cpu && precision == Precision::F32 {
        return Err(value_error("precision='f32' runs on the GPU kernels: the CPU path is f64 only (use device='gpu' or 'auto')"));
    }
    Ok(EngineOptions { device, precision: Some(precision), ..Default::default() })
}

/// A rig with its engines, one per (device, precision), built on first use and reused.
#[pyclass(name = "_Rig", module = "flatport._flatport", frozen)]
struct PyRig {
    rig: Arc<Rig>,
    engines: Mutex<HashMap<(String, String), Arc<Engine>>>,
    /// The f64 GPU engines the calibration's cost batches run on, by device.
    gpu_engines: Mutex<HashMap<String, Arc<flatport::engine::GpuEngine>>>,
}

impl PyRig {
    fn wrap(rig: Rig) -> Self {
        Self { rig: Arc::new(rig), engines: Mutex::new(HashMap::new()), gpu_engines: Mutex::new(HashMap::new()) }
    }

    fn engine(&self, py: Python<'_>, device: &str, precision: &str) -> PyResult<Arc<Engine>> {
        let key = (device.to_string(), precision.to_string());
        if let Some(engine) = self.engines.lock().expect("engine cache").get(&key) {
            return Ok(engine.clone());
        }
        let options = engine_options(device, precision)?;
        // Opening a GPU takes a while: other Python threads run meanwhile.
        let engine = Arc::new(py.detach(|| Engine::new(&options)).map_err(runtime_error)?);
        // Another thread may have built one meanwhile: every caller gets the one kept.
        Ok(self.engines.lock().expect("engine cache").entry(key).or_insert(engine).clone())
    }

    /// The f64 GPU engine of `device` for the calibration's cost batches; `None` where `device`
    /// (`auto`) finds no GPU.
    fn gpu_engine(&self, py: Python<'_>, device: &str) -> PyResult<Option<Arc<flatport::engine::GpuEngine>>> {
        if let Some(engine) = self.gpu_engines.lock().expect("engine cache").get(device) {
            return Ok(Some(engine.clone()));
        }
        let options = engine_options(device, "f64")?;
        let engine = py.detach(|| Engine::new(&options)).map_err(runtime_error)?;
        let Engine::Gpu(gpu) = engine else { return Ok(None) };
        let gpu = Arc::new(gpu);
        Ok(Some(self.gpu_engines.lock().expect("engine cache").entry(device.to_string()).or_insert(gpu).clone()))
    }

    fn camera(&self, index: usize) -> PyResult<flatport::model::RefractiveCamera> {
        if index >= self.rig.cameras().len() {
            return Err(value_error(format!("the rig has {} cameras, there is no camera {index}", self.rig.cameras().len())));
        }
        Ok(self.rig.refractive_camera(index))
    }
}

/// A batch's answer: (N, M) float64 rows and the (N,) uint32 status.
type Rows<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<u32>>);

/// A ray map: (H, W, 6) float64 rays and the (H, W) uint32 status.
type Image<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<u32>>);

/// Rows of an (N, width) C-contiguous float64 array as `[f64; N]` rows, no copy.
fn rows<'a, const W: usize>(array: &'a PyReadonlyArray2<'_, f64>, name: &str) -> PyResult<&'a [[f64; W]]> {
    let shape = array.shape();
    if shape[1] != W {
        return Err(value_error(format!("{name} must have shape (N, {W}), got {shape:?}")));
    }
    let flat = array.as_slice().map_err(|_| value_error(format!("{name} must be C-contiguous")))?;
    Ok(flat.as_chunks::<W>().0)
}

/// Runs `run` on `input` with the GIL released; rows without an answer are NaN. Returns the
/// (N, M) float64 result and the (N,) uint32 status, both handed to numpy without a copy.
fn batch<'py, const N: usize, const M: usize>(
    py: Python<'py>,
    input: &[[f64; N]],
    run: impl FnOnce(&[[f64; N]], &mut [[f64; M]], &mut [u32]) -> Result<(), flatport::engine::EngineError> + Send,
) -> PyResult<Rows<'py>> {
    let n = input.len();
    let (output, status) = py
        .detach(|| {
            let mut output = vec![[0.0; M]; n];
            let mut status = vec![0u32; n];
            run(input, &mut output, &mut status)?;
            for (row, &s) in output.iter_mut().zip(&status) {
                if s != 0 {
                    *row = [f64::NAN; M];
                }
            }
            Ok::<_, flatport::engine::EngineError>((output, status))
        })
        .map_err(runtime_error)?;
    let flat: Vec<f64> = output.into_flattened();
    Ok((PyArray1::from_vec(py, flat).reshape([n, M])?, PyArray1::from_vec(py, status)))
}

/// Rows on the GPU of one of the engine's kinds.
enum AnyRows {
    Pixels(DeviceRows<Pixels>),
    Points(DeviceRows<Points>),
    Rays(DeviceRows<Rays>),
    Triangulated(DeviceRows<Triangulated>),
}

impl AnyRows {
    fn kind(&self) -> &'static str {
        match self {
            Self::Pixels(_) => "pixels",
            Self::Points(_) => "points",
            Self::Rays(_) => "rays",
            Self::Triangulated(_) => "triangulated",
        }
    }
}

/// Rows that live on the GPU (`flatport.gpu.DeviceArray` wraps it): nothing is copied to the host
/// until `read` is called. Keeps the engine that made it, whose device holds the rows.
#[pyclass(name = "_DeviceArray", module = "flatport._flatport", frozen)]
struct PyDeviceArray {
    engine: Arc<Engine>,
    rows: AnyRows,
}

/// A GPU call's error: rows that do not fit the call are a ValueError, the rest a RuntimeError.
fn device_error(error: GpuError) -> PyErr {
    match error {
        GpuError::Rows(_) => value_error(error),
        other => runtime_error(other),
    }
}

/// The (N, width) float64 rows and (N,) uint32 status of `rows`, read back with the GIL released.
fn read_device<'py, K: RowKind>(py: Python<'py>, engine: &GpuEngine, rows: &DeviceRows<K>) -> PyResult<Rows<'py>> {
    let (flat, status) = py.detach(|| engine.read_reals(rows)).map_err(device_error)?;
    Ok((PyArray1::from_vec(py, flat).reshape([status.len(), K::WIDTH])?, PyArray1::from_vec(py, status)))
}

impl PyDeviceArray {
    fn gpu(&self) -> &GpuEngine {
        match &*self.engine {
            Engine::Gpu(gpu) => gpu,
            Engine::Cpu(_) => unreachable!("device arrays are made by GPU engines only"),
        }
    }

    fn wrap(&self, rows: AnyRows) -> Self {
        Self { engine: self.engine.clone(), rows }
    }
}

#[pymethods]
impl PyDeviceArray {
    /// "pixels", "points", "rays" or "triangulated".
    #[getter]
    fn kind(&self) -> &'static str {
        self.rows.kind()
    }

    /// Reals per row.
    #[getter]
    fn width(&self) -> usize {
        match &self.rows {
            AnyRows::Pixels(_) => Pixels::WIDTH,
            AnyRows::Points(_) => Points::WIDTH,
            AnyRows::Rays(_) => Rays::WIDTH,
            AnyRows::Triangulated(_) => Triangulated::WIDTH,
        }
    }

    /// "f32" or "f64": the reals on the device.
    #[getter]
    fn precision(&self) -> &'static str {
        self.gpu().precision().name()
    }

    fn __len__(&self) -> usize {
        match &self.rows {
            AnyRows::Pixels(r) => r.len(),
            AnyRows::Points(r) => r.len(),
            AnyRows::Rays(r) => r.len(),
            AnyRows::Triangulated(r) => r.len(),
        }
    }

    /// The rows copied to the host: (N, width) float64, NaN where the (N,) uint32 status is not 0.
    fn read<'py>(&self, py: Python<'py>) -> PyResult<Rows<'py>> {
        let gpu = self.gpu();
        match &self.rows {
            AnyRows::Pixels(r) => read_device(py, gpu, r),
            AnyRows::Points(r) => read_device(py, gpu, r),
            AnyRows::Rays(r) => read_device(py, gpu, r),
            AnyRows::Triangulated(r) => read_device(py, gpu, r),
        }
    }

    /// The engine that made the rows (`_Rig.engine_id` of the same engine).
    fn engine_id(&self) -> usize {
        Arc::as_ptr(&self.engine) as usize
    }
}

impl PyRig {
    /// The GPU engine of `precision` (device "gpu"), for device arrays.
    fn device_engine(&self, py: Python<'_>, precision: &str) -> PyResult<Arc<Engine>> {
        let engine = self.engine(py, "gpu", precision)?;
        match &*engine {
            Engine::Gpu(_) => Ok(engine),
            Engine::Cpu(_) => Err(runtime_error("device arrays need a GPU engine")),
        }
    }
}

/// `array` as the rows of `kind` on the device of `engine`.
fn upload_any(engine: &GpuEngine, array: &PyReadonlyArray2<'_, f64>, kind: &str) -> PyResult<AnyRows> {
    let rows = match kind {
        "pixels" => AnyRows::Pixels(engine.upload::<Pixels>(rows::<2>(array, "pixels")?).map_err(device_error)?),
        "points" => AnyRows::Points(engine.upload::<Points>(rows::<3>(array, "points")?).map_err(device_error)?),
        "rays" => AnyRows::Rays(engine.upload::<Rays>(rows::<6>(array, "rays")?).map_err(device_error)?),
        other => return Err(value_error(format!("kind must be 'pixels', 'points' or 'rays', got {other:?}"))),
    };
    Ok(rows)
}

#[pymethods]
impl PyRig {
    /// Uploads (N, width) float64 rows of `kind` to the GPU engine of `precision`.
    fn upload_rows(&self, py: Python<'_>, array: PyReadonlyArray2<'_, f64>, kind: &str, precision: &str) -> PyResult<PyDeviceArray> {
        let engine = self.device_engine(py, precision)?;
        let Engine::Gpu(gpu) = &*engine else { unreachable!("checked by device_engine") };
        let rows = upload_any(gpu, &array, kind)?;
        Ok(PyDeviceArray { engine, rows })
    }

    /// Pixels of a grid made on the GPU (row-major, every `step` pixels).
    fn pixel_grid_rows(&self, py: Python<'_>, width: u32, height: u32, step: u32, precision: &str) -> PyResult<PyDeviceArray> {
        let engine = self.device_engine(py, precision)?;
        let Engine::Gpu(gpu) = &*engine else { unreachable!("checked by device_engine") };
        let rows = py.detach(|| gpu.pixel_grid(width, height, step)).map_err(device_error)?;
        Ok(PyDeviceArray { engine, rows: AnyRows::Pixels(rows) })
    }

    /// Rays in the water of device pixels of `camera`, on the device.
    fn backproject_rows(&self, py: Python<'_>, pixels: &PyDeviceArray, camera: usize) -> PyResult<PyDeviceArray> {
        let view = self.camera(camera)?;
        let AnyRows::Pixels(on_device) = &pixels.rows else {
            return Err(value_error(format!("backproject takes pixels, got {}", pixels.rows.kind())));
        };
        let rays = py.detach(|| pixels.gpu().backproject_rows(&view, on_device)).map_err(device_error)?;
        Ok(pixels.wrap(AnyRows::Rays(rays)))
    }

    /// Pixels of device points in each of `cameras`, on the device.
    fn project_rows(&self, py: Python<'_>, points: &PyDeviceArray, cameras: Vec<usize>) -> PyResult<Vec<PyDeviceArray>> {
        let views = cameras.iter().map(|&k| self.camera(k)).collect::<PyResult<Vec<_>>>()?;
        let AnyRows::Points(on_device) = &points.rows else {
            return Err(value_error(format!("project takes points, got {}", points.rows.kind())));
        };
        let all = py.detach(|| points.gpu().project_many(on_device, &views)).map_err(device_error)?;
        Ok(all.into_iter().map(|p| points.wrap(AnyRows::Pixels(p))).collect())
    }

    /// Triangulated points (x, y, z, residual) of device rays `a` and `b`, row by row, on the device.
    fn triangulate_rows(&self, py: Python<'_>, a: &PyDeviceArray, b: &PyDeviceArray) -> PyResult<PyDeviceArray> {
        let (AnyRows::Rays(rays_a), AnyRows::Rays(rays_b)) = (&a.rows, &b.rows) else {
            return Err(value_error(format!("triangulate takes two arrays of rays, got {} and {}", a.rows.kind(), b.rows.kind())));
        };
        let points = py.detach(|| a.gpu().triangulate_rows(rays_a, rays_b)).map_err(device_error)?;
        Ok(a.wrap(AnyRows::Triangulated(points)))
    }

    /// Triangulated points (x, y, z, residual) of matched device pixels `a` (camera `camera_a`)
    /// and `b` (camera `camera_b`), row by row, in one fused kernel on the device (no rays between).
    fn triangulate_pixels_rows(&self, py: Python<'_>, a: &PyDeviceArray, b: &PyDeviceArray, camera_a: usize, camera_b: usize) -> PyResult<PyDeviceArray> {
        let (view_a, view_b) = (self.camera(camera_a)?, self.camera(camera_b)?);
        let (AnyRows::Pixels(pixels_a), AnyRows::Pixels(pixels_b)) = (&a.rows, &b.rows) else {
            return Err(value_error(format!("triangulate_pixels takes two arrays of pixels, got {} and {}", a.rows.kind(), b.rows.kind())));
        };
        let points = py.detach(|| a.gpu().triangulate_pixels(&view_a, &view_b, pixels_a, pixels_b)).map_err(device_error)?;
        Ok(a.wrap(AnyRows::Triangulated(points)))
    }

    #[staticmethod]
    fn load(path: &str) -> PyResult<Self> {
        Ok(Self::wrap(read_rig(Path::new(path)).map_err(value_error)?))
    }

    #[staticmethod]
    fn from_json(text: &str, source: &str) -> PyResult<Self> {
        Ok(Self::wrap(rig_from_json_str(text, Path::new(source)).map_err(value_error)?))
    }

    fn to_json(&self) -> String {
        rig_to_json_string(&self.rig)
    }

    /// A rig from AquaCal's calibration.json (`flatport rig from-aquacal`); `master` names the
    /// camera that becomes the master (default: the first in the file).
    #[staticmethod]
    #[pyo3(signature = (path, master=None))]
    fn from_aquacal(path: &str, master: Option<&str>) -> PyResult<Self> {
        Ok(Self::wrap(read_aquacal(Path::new(path), master).map_err(value_error)?))
    }

    /// The rig as AquaCal's calibration.json text (`flatport export aquacal`, no board).
    fn to_aquacal(&self) -> PyResult<String> {
        aquacal_json(&self.rig, None).map_err(value_error)
    }

    fn camera_names(&self) -> Vec<String> {
        self.rig.cameras().iter().map(|c| c.name.clone()).collect()
    }

    /// The shared port as camera `index` sees it, in its own frame: (normal, air distance d_k, centre in master).
    fn port_in_camera(&self, index: usize) -> PyResult<([f64; 3], f64, [f64; 3])> {
        let view = self.camera(index)?;
        let n = view.master_from_cam().transpose() * view.normal().into_inner();
        let c = view.centre();
        Ok(([n.x, n.y, n.z], view.air_distance(), [c.x, c.y, c.z]))
    }

    fn describe_engine(&self, py: Python<'_>, device: &str, precision: &str) -> PyResult<String> {
        Ok(self.engine(py, device, precision)?.describe())
    }

    /// The address of the engine of (device, precision), for tests that it is built once.
    fn engine_id(&self, py: Python<'_>, device: &str, precision: &str) -> PyResult<usize> {
        Ok(Arc::as_ptr(&self.engine(py, device, precision)?) as usize)
    }

    fn project<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f64>,
        camera: usize,
        device: &str,
        precision: &str,
    ) -> PyResult<Rows<'py>> {
        let (engine, view) = (self.engine(py, device, precision)?, self.camera(camera)?);
        batch(py, rows::<3>(&points, "points")?, |i, o, s| engine.project(&view, i, o, s))
    }

    fn backproject<'py>(
        &self,
        py: Python<'py>,
        pixels: PyReadonlyArray2<'py, f64>,
        camera: usize,
        device: &str,
        precision: &str,
    ) -> PyResult<Rows<'py>> {
        let (engine, view) = (self.engine(py, device, precision)?, self.camera(camera)?);
        batch(py, rows::<2>(&pixels, "pixels")?, |i, o, s| engine.backproject(&view, i, o, s))
    }

    fn vop<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f64>,
        camera: usize,
        device: &str,
        precision: &str,
    ) -> PyResult<Rows<'py>> {
        let (engine, view) = (self.engine(py, device, precision)?, self.camera(camera)?);
        batch(py, rows::<3>(&points, "points")?, |i, o, s| engine.vop(&view, i, o, s))
    }

    #[allow(clippy::too_many_arguments)] // the Python signature
    fn triangulate<'py>(
        &self,
        py: Python<'py>,
        matches: PyReadonlyArray2<'py, f64>,
        a: usize,
        b: usize,
        device: &str,
        precision: &str,
    ) -> PyResult<Rows<'py>> {
        let engine = self.engine(py, device, precision)?;
        let (view_a, view_b) = (self.camera(a)?, self.camera(b)?);
        batch(py, rows::<4>(&matches, "matches")?, |i, o, s| engine.triangulate(&view_a, &view_b, i, o, s))
    }

    /// Rays of every pixel: (H, W, 6) float64 and (H, W) uint32 status.
    fn raymap<'py>(
        &self,
        py: Python<'py>,
        camera: usize,
        device: &str,
        precision: &str,
    ) -> PyResult<Image<'py>> {
        let (engine, view) = (self.engine(py, device, precision)?, self.camera(camera)?);
        let (width, height) = (view.intrinsics().width, view.intrinsics().height);
        let pixels = width as usize * height as usize;
        let (rays, status) = py
            .detach(|| {
                let mut rays = vec![[0.0; 6]; pixels];
                let mut status = vec![0u32; pixels];
                backproject_rows(&engine, &view, 0, height, &mut rays, &mut status)?;
                for (ray, &s) in rays.iter_mut().zip(&status) {
                    if s != 0 {
                        *ray = [f64::NAN; 6];
                    }
                }
                Ok::<_, flatport::engine::EngineError>((rays, status))
            })
            .map_err(runtime_error)?;
        let (h, w) = (height as usize, width as usize);
        Ok((PyArray1::from_vec(py, rays.into_flattened()).reshape([h, w, 6])?, PyArray1::from_vec(py, status).reshape([h, w])?))
    }

    /// colmap_underwater's cameras.txt, COLMAP's rig configuration JSON and rigs.txt.
    #[pyo3(signature = (refrac_token=false))]
    fn export_colmap(&self, refrac_token: bool) -> PyResult<(String, String, String)> {
        let dialect = if refrac_token { ColmapDialect::RefracToken } else { ColmapDialect::Legacy };
        Ok((colmap_cameras_txt_as(&self.rig, dialect).map_err(value_error)?, colmap_rig_config(&self.rig), colmap_rigs_txt(&self.rig)))
    }

    /// OpenCV FileStorage YAML of camera `a` (and `b`).
    #[pyo3(signature = (a, b=None))]
    fn export_opencv(&self, a: usize, b: Option<usize>) -> PyResult<String> {
        opencv_yaml(&self.rig, a, b).map_err(value_error)
    }
}

/// Observations (JSON text) of a board, checked against the rig, one camera pair's corners prepared
/// for the pair costs: the two cameras of every view when each view holds the same two (the
/// stereo form), else the rig's first two (as `flatport sweep` takes them).
fn stereo_data(rig: &Rig, observations_json: &str) -> PyResult<(StereoData, Vec<String>)> {
    let observations = observations_from_json_str(observations_json, Path::new("observations")).map_err(value_error)?;
    if rig.cameras().len() < 2 {
        return Err(value_error(format!("the rig has {} camera(s): the pair costs need two", rig.cameras().len())));
    }
    let board = *observations.target.board().ok_or_else(|| value_error("the pair costs need a board, not a 3-D target"))?;
    let seen = observations.resolve(rig).map_err(value_error)?;
    let warnings = observations.check(&seen).map_err(value_error)?;
    let pair = match seen.first().map(|v| v.cameras.as_slice()) {
        Some([(a, _), (b, _)]) if seen.iter().all(|v| v.cameras.iter().map(|c| c.0).eq([*a, *b])) => {
            let first = &observations.views[0].images[0];
            let first_is_a = match &first.camera {
                flatport::calib::CameraKey::Position(k) => *k == *a,
                flatport::calib::CameraKey::Name(n) => rig.camera_index(n) == Some(*a),
            };
            if first_is_a { [*a, *b] } else { [*b, *a] }
        }
        _ => [0, 1],
    };
    let data = StereoData::new(rig, pair, &board, &seen).map_err(value_error)?;
    Ok((data, warnings))
}

/// Calibrates what `estimate` names on any rig, as `flatport calibrate` does: (calibrated rig or
/// None when the fit is refused, report JSON).
#[pyfunction]
#[pyo3(signature = (rig, observations_json, estimate, method, device, max_tilt_deg, grid_step_deg, huber, max_iterations, max_rms_px, report_dir=None))]
#[allow(clippy::too_many_arguments)] // the Python signature
fn calibrate(
    py: Python<'_>,
    rig: &PyRig,
    observations_json: &str,
    estimate: &str,
    method: &str,
    device: &str,
    max_tilt_deg: f64,
    grid_step_deg: f64,
    huber: Option<f64>,
    max_iterations: usize,
    max_rms_px: Option<f64>,
    report_dir: Option<PathBuf>,
) -> PyResult<(Option<PyRig>, String)> {
    let method = Method::from_name(method)
        .ok_or_else(|| value_error(format!("method must be 'consecutive', 'simultaneous' or 'auto', got {method:?}")))?;
    let estimate = Estimate::parse(estimate).map_err(value_error)?;
    let observations = observations_from_json_str(observations_json, Path::new("observations")).map_err(value_error)?;
    // The finite differences of the refinement are below f32's resolution: f64 kernels.
    let backend = match device {
        "cpu" => Backend::Cpu,
        _ => rig.gpu_engine(py, device)?.map_or(Backend::Cpu, Backend::Gpu),
    };
    let options = Options {
        method,
        estimate,
        max_tilt: max_tilt_deg.to_radians(),
        grid_spacing: Some(grid_step_deg.to_radians()),
        huber,
        max_iterations,
        max_rms_px,
        backend,
        lens_prior: None,
    };
    let calibration = py.detach(|| run_calibrate(&rig.rig, &observations, &options)).map_err(value_error)?;
    let report = report_to_json_string(&calibration.report);
    if let Some(dir) = &report_dir {
        let input = flatport::report::Input::from_observations("flatport.calibrate (Python)", &calibration.rig, &calibration.report, &observations, huber);
        py.detach(|| flatport::report::write_report(dir, &input)).map_err(value_error)?;
    }
    let calibrated = calibration.report.fits.then(|| PyRig::wrap(calibration.rig));
    Ok((calibrated, report))
}

/// The glass of each camera's port, as `calibrate --images --glass` takes it: `(camera, thickness,
/// index)` rows, `camera` None for every port (a camera's own row wins over it).
fn glass_rows(glass: Vec<(Option<String>, f64, f64)>) -> Vec<Glass> {
    glass.into_iter().map(|(camera, thickness, index)| Glass { camera, thickness, index }).collect()
}

/// A whole rig from images or videos of a board, as `flatport calibrate --images DIR --board
/// BOARD.json --port …` (the same steps, `flatport::runs::images`, as the command line): every
/// camera's lens in air (or `rig`'s), then the extrinsics and the ports under water. Returns (the
/// calibrated rig, or None when it does not fit; the report JSON, `--report`'s; why it does not
/// fit). `report` is written in either case, `output` only with a rig that fits.
#[pyfunction]
#[pyo3(signature = (images, board, port, glass, index_water, index_air, master, rig, rig_label, frame_step, max_frames, holdout, output, report, device, max_tilt_deg, huber, max_iterations, max_rms_px, refine_intrinsics, report_dir=None))]
#[allow(clippy::too_many_arguments)] // the Python signature
fn calibrate_images(
    py: Python<'_>,
    images: PathBuf,
    board: PathBuf,
    port: &str,
    glass: Vec<(Option<String>, f64, f64)>,
    index_water: f64,
    index_air: f64,
    master: Option<String>,
    rig: Option<&PyRig>,
    rig_label: &str,
    frame_step: Option<usize>,
    max_frames: Option<usize>,
    holdout: f64,
    output: Option<PathBuf>,
    report: Option<PathBuf>,
    device: &str,
    max_tilt_deg: f64,
    huber: Option<f64>,
    max_iterations: usize,
    max_rms_px: Option<f64>,
    refine_intrinsics: &str,
    report_dir: Option<PathBuf>,
) -> PyResult<(Option<PyRig>, String, Option<String>)> {
    let port = PortKind::from_name(port)
        .ok_or_else(|| value_error(format!("port must be 'surface', 'shared' or 'housings', got {port:?}")))?;
    let glass = glass_rows(glass);
    check_glass(&glass, port).map_err(value_error)?;
    let refine_intrinsics = RefineIntrinsics::from_name(refine_intrinsics).ok_or_else(|| {
        value_error(format!("refine_intrinsics must be 'auto', 'never' or 'always', got {refine_intrinsics:?}"))
    })?;
    let spec = read_board(&board).map_err(value_error)?;
    let grid = spec.corner_grid();
    let source = LensSource::choose(&images, rig.is_some());
    let footage_options = FootageOptions {
        master,
        frame_step,
        max_air_views: max_frames.unwrap_or(DEFAULT_MAX_AIR_VIEWS),
        max_water_frames: max_frames.unwrap_or(DEFAULT_MAX_WATER_FRAMES),
        air: source == LensSource::Air,
    };
    let footage = py.detach(|| read_board_footage(&images, &spec, &footage_options, &mut |_, _, _| {})).map_err(value_error)?;
    let names = footage.names();
    let glass = glass_per_camera(&glass, &names, port).map_err(value_error)?;
    let mut fits = Vec::new();
    let cameras = match rig {
        Some(rig) => cameras_from_rig(&rig.rig, rig_label, &footage).map_err(value_error)?,
        None if source == LensSource::Water => water_lens_starts(&footage, &grid, index_air, index_water).map_err(value_error)?,
        None => {
            let mut cameras = Vec::new();
            for (k, camera) in footage.cameras.iter().enumerate() {
                let fit = py.detach(|| air_lens(&footage, k, &grid)).map_err(value_error)?;
                cameras.push(fit.camera.clone());
                fits.push((camera.name.clone(), fit));
            }
            cameras
        }
    };
    let setup = RigSetup { cameras, port, glass, index_air, index_water };
    // The finite differences of the refinement are below f32's resolution: f64 kernels.
    let backend = match device {
        "cpu" => Backend::Cpu,
        "gpu" | "auto" => {
            let engine_options = engine_options(device, "f64")?;
            let engine = py.detach(|| Engine::new(&engine_options)).map_err(runtime_error)?;
            match engine {
                Engine::Gpu(gpu) => Backend::Gpu(Arc::new(gpu)),
                Engine::Cpu(_) => Backend::Cpu,
            }
        }
        other => return Err(value_error(format!("device must be 'cpu', 'gpu' or 'auto', got {other:?}"))),
    };
    let settings = FitSettings { huber, max_iterations, max_rms_px, max_tilt_deg, holdout, refine_intrinsics };
    let options = boards_options(&settings, backend, &fits);
    let (result, _) = py
        .detach(|| run_calibration(source, &names, &setup, &grid, &footage, &options, &mut |_| {}))
        .map_err(value_error)?;
    let report_text = boards_report_to_json_string(&result, &names, &fits);
    if let Some(path) = &report {
        write_boards_report(path, &result, &names, &fits).map_err(value_error)?;
    }
    if let Some(dir) = &report_dir {
        let mut input = flatport::report::Input::from_boards(
            "flatport.calibrate_images (Python)",
            &result,
            &names,
            &grid,
            &footage.water,
            options.calibration.huber,
        );
        input.air = footage.air_corners();
        py.detach(|| flatport::report::write_report(dir, &input)).map_err(value_error)?;
    }
    let fit = &result.calibration.report;
    if !fit.fits {
        let why = format!(
            "{} {}{}",
            refusal(&result),
            output.as_ref().map_or("No rig returned".to_string(), |p| format!("{} not written", p.display())),
            report.as_ref().map_or(String::new(), |p| format!("; the report is in {}", p.display()))
        );
        return Ok((None, report_text, Some(why)));
    }
    if let Some(path) = &output {
        write_rig(path, &result.calibration.rig).map_err(value_error)?;
    }
    Ok((Some(PyRig::wrap(result.calibration.rig)), report_text, None))
}

/// Frames for a targetless calibration: read from `images` (a folder per rig camera, as `flatport
/// calibrate --targetless` reads it) with `frames` (START:STOP:STEP, default at most 8 spread
/// over the footage), or given as `arrays` (one grey float32 image (H, W) per rig camera for
/// each frame).
fn targetless_frames(rig: &Rig, images: Option<PathBuf>, arrays: Option<Vec<Vec<PyReadonlyArray2<'_, f32>>>>, frames: Option<&str>) -> PyResult<Vec<Vec<flatport::stereo::GreyImage>>> {
    use flatport::io::frames::{FrameSelection, read_camera_frames};
    match (images, arrays) {
        (Some(dir), None) => {
            let selection = frames.map(|f| f.parse::<FrameSelection>()).transpose().map_err(value_error)?;
            let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
            Ok(read_camera_frames(&dir, &names, selection, flatport::calib::targetless::DEFAULT_FRAMES).map_err(value_error)?.frames)
        }
        (None, Some(arrays)) => arrays
            .iter()
            .map(|frame| {
                frame
                    .iter()
                    .map(|a| {
                        let shape = a.shape();
                        Ok(flatport::stereo::GreyImage { width: shape[1] as u32, height: shape[0] as u32, pixels: a.as_slice().map_err(value_error)?.to_vec() })
                    })
                    .collect::<PyResult<Vec<_>>>()
            })
            .collect(),
        _ => Err(value_error("give images as a folder or as arrays, not both")),
    }
}

/// The port(s) of `rig` (cameras and extrinsics known, its ports the start) from frames of any
/// textured scene, as `flatport calibrate --images DIR --rig RIG.json --targetless`: (the
/// calibrated rig, the report JSON, why it is refused or None). `output` is written only when
/// every estimated parameter is pinned down.
#[pyfunction]
#[pyo3(signature = (rig, images, arrays, frames, estimate, huber, max_rms_px, max_sigma_axis_deg, max_sigma_distance_mm, output))]
#[allow(clippy::too_many_arguments)] // the Python signature
fn calibrate_targetless(
    py: Python<'_>,
    rig: &PyRig,
    images: Option<PathBuf>,
    arrays: Option<Vec<Vec<PyReadonlyArray2<'_, f32>>>>,
    frames: Option<&str>,
    estimate: &str,
    huber: f64,
    max_rms_px: f64,
    max_sigma_axis_deg: f64,
    max_sigma_distance_mm: f64,
    output: Option<PathBuf>,
) -> PyResult<(PyRig, String, Option<String>)> {
    use flatport::calib::targetless::{TargetlessOptions, calibrate_targetless as run_targetless};
    let estimate = Estimate::parse(estimate).map_err(value_error)?;
    if estimate.intrinsics {
        return Err(value_error("a targetless calibration does not estimate intrinsics: calibrate the lenses in air first (calibrate_images)"));
    }
    for (name, value) in [("huber", huber), ("max_rms_px", max_rms_px), ("max_sigma_axis_deg", max_sigma_axis_deg), ("max_sigma_distance_mm", max_sigma_distance_mm)] {
        if !(value > 0.0 && value.is_finite()) {
            return Err(value_error(format!("{name} must be a positive number, got {value}")));
        }
    }
    let frames = targetless_frames(&rig.rig, images, arrays, frames)?;
    let options = TargetlessOptions {
        estimate,
        huber_px: huber,
        max_rms_px,
        max_axis_sigma_deg: max_sigma_axis_deg,
        max_distance_sigma_m: max_sigma_distance_mm * 1e-3,
        ..TargetlessOptions::default()
    };
    let result = py.detach(|| run_targetless(&rig.rig, &frames, &options, &mut |_| {})).map_err(value_error)?;
    let report = flatport::io::targetless_report_to_json_string(&result);
    let refused = match result.confident_rig() {
        Ok(calibrated) => {
            if let Some(path) = &output {
                write_rig(path, calibrated).map_err(value_error)?;
            }
            None
        }
        Err(why) => Some(format!("{why}{}", output.as_ref().map_or(String::new(), |p| format!(" ({} not written)", p.display())))),
    };
    Ok((PyRig::wrap(result.rig), report, refused))
}

/// Simulates stereo views of a chessboard: (observations JSON, truth JSON).
#[pyfunction]
#[allow(clippy::too_many_arguments)] // the Python signature
fn simulate(
    rig: &PyRig,
    cols: usize,
    rows: usize,
    square: f64,
    views: usize,
    noise_px: f64,
    seed: u64,
    a: usize,
    b: usize,
    max_board_tilt_deg: f64,
) -> PyResult<(String, String)> {
    let mut spec = SceneSpec::pair(Target::Board(Board { rows, cols, square }), views, noise_px, seed, a, b);
    spec.max_target_tilt = max_board_tilt_deg.to_radians();
    let scene = run_simulate(&rig.rig, &spec).map_err(value_error)?;
    let truth = Truth { interface: rig.rig.port_in_master(0), master_from_board: scene.master_from_target, noise_px, seed, rig: Some(rig.rig.as_ref().clone()) };
    let observations = stereo_observations_to_json_string(&scene.observations, true).ok_or_else(|| runtime_error("a pair's scene is two images per view"))?;
    Ok((observations, truth_to_json_string(&truth)))
}

/// Sweeps a cost over an axis grid (and air layers): (cost array, air layer array, summary JSON).
#[pyfunction]
#[allow(clippy::too_many_arguments)] // the Python signature
fn sweep<'py>(
    py: Python<'py>,
    rig: &PyRig,
    observations_json: &str,
    cost: &str,
    tilt_deg: (f64, f64, usize),
    azimuth_deg: (f64, f64, usize),
    distance: Option<(f64, f64, usize)>,
    device: &str,
    precision: &str,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, String)> {
    let kind = CostKind::from_name(cost).ok_or_else(|| value_error(format!("unknown cost {cost:?} (affine-grid, reprojection, scene, …)")))?;
    let linspace = |(start, stop, count): (f64, f64, usize)| Linspace { start, stop, count };
    let spec = SweepSpec { kind, tilt_deg: linspace(tilt_deg), azimuth_deg: linspace(azimuth_deg), distance: distance.map(linspace) };
    spec.validate().map_err(value_error)?;
    let (data, _) = stereo_data(&rig.rig, observations_json)?;
    // The affine-grid kernel is f64 on every adapter.
    let precision = if kind == CostKind::AffineGrid { "f64" } else { precision };
    let engine = if device == "cpu" { None } else { Some(rig.engine(py, device, precision)?) };
    let cells = spec.cells();
    let (costs, distances, summary) = py
        .detach(|| {
            let backend: Box<dyn CostBackend + '_> = match engine.as_deref() {
                Some(Engine::Gpu(gpu)) => Box::new(GpuBackend::new(&data, gpu)),
                _ => Box::new(CpuBackend::new(&data)),
            };
            let (mut costs, mut distances) = (Vec::with_capacity(cells), Vec::with_capacity(cells));
            let summary = run_sweep(
                backend.as_ref(),
                &spec,
                4096,
                &mut |chunk| {
                    costs.extend_from_slice(chunk.costs);
                    distances.extend_from_slice(chunk.distances);
                    Ok(())
                },
                &mut |_, _| {},
            )?;
            Ok::<_, flatport::calib::CalibError>((costs, distances, summary))
        })
        .map_err(value_error)?;
    let minimum = summary.minimum.map(|m| {
        serde_json::json!({"cell": m.cell, "tilt_deg": m.tilt_deg, "azimuth_deg": m.azimuth_deg, "distance": m.distance, "cost": m.cost})
    });
    let summary = serde_json::json!({
        "cost": kind.name(),
        "unit": kind.unit(),
        "shape": spec.shape(),
        "cells": summary.cells,
        "finite": summary.finite,
        "seconds": summary.seconds,
        "minimum": minimum,
        "correspondences": data.corners.len(),
    });
    let shape = spec.shape();
    let costs = PyArray1::from_vec(py, costs).reshape(shape.clone())?.into_any();
    let distances = PyArray1::from_vec(py, distances).reshape(shape)?.into_any();
    Ok((costs, distances, summary.to_string()))
}

/// The GPU stereo, opened on first use and kept: every later call (the frames of a sequence)
/// reuses its pipelines and buffers. `Err` holds why there is none.
static GPU_STEREO: std::sync::OnceLock<Result<flatport::stereo::gpu::GpuStereo, String>> = std::sync::OnceLock::new();

/// Dense stereo as `flatport stereo` on one grey float32 image (H, W) per rig camera, 0 … 1:
/// (depth (H, W), points (H, W, 3), confidence (H, W), device). `device` "cpu", "gpu" or "auto"
/// (a hardware GPU whose storage binding holds the cost volume, else the CPU).
#[pyfunction]
#[pyo3(signature = (rig, images, reference, depth, hypotheses, window, min_confidence, device))]
#[allow(clippy::too_many_arguments)] // the Python signature
fn stereo<'py>(
    py: Python<'py>,
    rig: &PyRig,
    images: Vec<PyReadonlyArray2<'py, f32>>,
    reference: usize,
    depth: Option<(f64, f64)>,
    hypotheses: Option<usize>,
    window: usize,
    min_confidence: f64,
    device: &str,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>, String)> {
    use flatport::stereo::{Backend as StereoBackend, StereoOptions, stereo_on};
    let grey: Vec<flatport::stereo::GreyImage> = images
        .iter()
        .map(|a| {
            let shape = a.shape();
            Ok(flatport::stereo::GreyImage {
                width: shape[1] as u32,
                height: shape[0] as u32,
                pixels: a.as_slice().map_err(value_error)?.to_vec(),
            })
        })
        .collect::<PyResult<_>>()?;
    let options = StereoOptions {
        reference,
        depth_range: depth,
        hypotheses,
        window_radius: window,
        min_confidence,
        ..StereoOptions::default()
    };
    let gpu = stereo_gpu(&rig.rig, reference, hypotheses, device)?;
    let backend = gpu.map_or(StereoBackend::Cpu, StereoBackend::Gpu);
    let described = backend.describe();
    let map = py.detach(|| stereo_on(&rig.rig, &grey, &options, backend, &|_| {})).map_err(value_error)?;
    let (h, w) = (map.height, map.width);
    let depth = PyArray1::from_vec(py, map.depth).reshape([h, w])?.into_any();
    let points = PyArray1::from_vec(py, map.points.into_flattened()).reshape([h, w, 3])?.into_any();
    let confidence = PyArray1::from_vec(py, map.confidence).reshape([h, w])?.into_any();
    Ok((depth, points, confidence, described))
}

/// The GPU stereo for `device` ("cpu": none; "gpu": the GPU or an error; "auto": a hardware GPU
/// whose storage binding holds the cost volume of `hypotheses`, else none).
fn stereo_gpu(rig: &Rig, reference: usize, hypotheses: Option<usize>, device: &str) -> PyResult<Option<&'static flatport::stereo::gpu::GpuStereo>> {
    Ok(match device {
        "cpu" => None,
        "gpu" | "auto" => match GPU_STEREO.get_or_init(|| flatport::stereo::gpu::GpuStereo::new(None).map_err(|e| e.to_string())) {
            Ok(gpu) => {
                let i = &rig.cameras()[reference.min(rig.cameras().len() - 1)].intrinsics;
                let fits = gpu.refuses(i.width as usize, i.height as usize, hypotheses.unwrap_or(flatport::stereo::range::MAX_HYPOTHESES), rig.cameras().len().saturating_sub(1));
                match (device, fits) {
                    ("gpu", Some(reason)) => return Err(runtime_error(reason)),
                    ("auto", Some(_)) => None,
                    ("auto", None) if gpu.context().is_software() => None,
                    _ => Some(gpu),
                }
            }
            Err(reason) if device == "gpu" => return Err(runtime_error(reason)),
            Err(_) => None,
        },
        other => return Err(value_error(format!("device must be 'cpu', 'gpu' or 'auto', got {other:?}"))),
    })
}

/// One frame's depths from [`StereoFrames`]: (frame name, index, depth map, device) or why not.
type FrameResult = Result<(String, usize, flatport::stereo::DepthMap, String), String>;

/// The frames of a sequence, computed one ahead by a worker thread while Python uses the last
/// one: iterating yields (name, index, depth (H, W), points (H, W, 3), confidence (H, W),
/// device). Dropping the iterator stops the worker after the frame it is on.
#[pyclass]
struct StereoFrames {
    frames: Mutex<std::sync::mpsc::Receiver<FrameResult>>,
}

#[pymethods]
impl StereoFrames {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[allow(clippy::type_complexity)] // the Python tuple
    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<(String, usize, Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>, String)>> {
        // None: the worker is done (every frame sent, or an error sent and it stopped).
        let next = py.detach(|| self.frames.lock().ok().and_then(|frames| frames.recv().ok()));
        let Some(result) = next else {
            return Ok(None);
        };
        let (name, index, map, device) = result.map_err(value_error)?;
        let (h, w) = (map.height, map.width);
        let depth = PyArray1::from_vec(py, map.depth).reshape([h, w])?.into_any();
        let points = PyArray1::from_vec(py, map.points.into_flattened()).reshape([h, w, 3])?.into_any();
        let confidence = PyArray1::from_vec(py, map.confidence).reshape([h, w])?.into_any();
        Ok(Some((name, index, depth, points, confidence, device)))
    }
}

/// Dense stereo as `flatport stereo --images DIR --frames FRAMES` over a sequence (a folder per
/// rig camera of images or one video): an iterator of the frames' depths. The sequence, the
/// selection and the options are checked here, before any frame is computed.
#[pyfunction]
#[pyo3(signature = (rig, images, frames, reference, depth, hypotheses, window, min_confidence, device))]
#[allow(clippy::too_many_arguments)] // the Python signature
fn stereo_frames(
    rig: &PyRig,
    images: PathBuf,
    frames: &str,
    reference: usize,
    depth: Option<(f64, f64)>,
    hypotheses: Option<usize>,
    window: usize,
    min_confidence: f64,
    device: &str,
) -> PyResult<StereoFrames> {
    use flatport::runs::sequence::Sequence;
    use flatport::stereo::{Backend as StereoBackend, StereoOptions, resolve_depth_range, stereo_on};
    let options = StereoOptions {
        reference,
        depth_range: depth,
        hypotheses,
        window_radius: window,
        min_confidence,
        ..StereoOptions::default()
    };
    // Checked here; a range not given is found per frame, from that frame's images.
    resolve_depth_range(&rig.rig, &options).map_err(value_error)?;
    let selection: flatport::io::frames::FrameSelection = frames.parse().map_err(value_error)?;
    let sequence = Sequence::open(&rig.rig, &images).map_err(value_error)?;
    let wanted = sequence.select(&selection).map_err(value_error)?;
    let gpu = stereo_gpu(&rig.rig, reference, hypotheses, device)?;
    let rig = Arc::clone(&rig.rig);
    // One frame ahead: the worker computes the next frame while Python holds this one.
    let (sender, receiver) = std::sync::mpsc::sync_channel::<FrameResult>(1);
    std::thread::spawn(move || {
        let backend = gpu.map_or(StereoBackend::Cpu, StereoBackend::Gpu);
        let described = backend.describe();
        for frame in sequence.reader(&wanted) {
            let result = frame.map_err(|e| e.to_string()).and_then(|frame| {
                let images: Vec<_> = frame.images.into_iter().map(|c| c.grey).collect();
                let map = stereo_on(&rig, &images, &options, backend, &|_| {}).map_err(|e| e.to_string())?;
                Ok((sequence.frame_name(reference, frame.index), frame.index, map, described.clone()))
            });
            let failed = result.is_err();
            if sender.send(result).is_err() || failed {
                break;
            }
        }
    });
    Ok(StereoFrames { frames: Mutex::new(receiver) })
}

#[pymodule]
fn _flatport(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(stereo, m)?)?;
    m.add_function(wrap_pyfunction!(stereo_frames, m)?)?;
    m.add_class::<StereoFrames>()?;
    m.add_class::<PyRig>()?;
    m.add_class::<PyDeviceArray>()?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_images, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_targetless, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
