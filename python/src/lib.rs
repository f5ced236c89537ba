//! The `spreadlet` Python module: the renderer with numpy arrays in and out (float32, linear
//! premultiplied RGBA, shape (height, width, channels)). Every error the library reports is a
//! `ValueError` with its message; nothing panics across the boundary. Long calls release the
//! GIL and tell an optional `progress(message, fraction)` callback what they are doing.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use numpy::{
    PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyReadonlyArray4,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The lens and shutter (`camera.json`): millimetres for the lens and sensor, scene units for
/// the focus distance, frames for the shutter.
#[pyclass(name = "Camera", module = "spreadlet")]
#[derive(Clone)]
struct PyCamera {
    inner: renderer::Camera,
}

#[pymethods]
impl PyCamera {
    #[new]
    #[pyo3(signature = (width, height, focal_length_mm, sensor_width_mm, f_stop=None, focus_distance=None, aperture_blades=0, shutter_frames=0.0, scene_unit_mm=1000.0, aperture_rotation_deg=0.0, aperture_ratio=1.0, aperture_image=None, lens=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        width: u32,
        height: u32,
        focal_length_mm: f64,
        sensor_width_mm: f64,
        f_stop: Option<f64>,
        focus_distance: Option<f64>,
        aperture_blades: u32,
        shutter_frames: f64,
        scene_unit_mm: f64,
        aperture_rotation_deg: f64,
        aperture_ratio: f64,
        aperture_image: Option<PathBuf>,
        lens: Option<String>,
    ) -> PyResult<Self> {
        let inner = renderer::Camera {
            width,
            height,
            focal_length_mm,
            sensor_width_mm,
            f_stop,
            focus_distance,
            aperture_blades,
            aperture_rotation_deg,
            aperture_ratio,
            aperture_image,
            lens,
            shutter_frames,
            scene_unit_mm,
        };
        inner.validate().map_err(value_error)?;
        // Read the lens now, so a misspelt name fails here rather than at the first frame.
        inner.prescription().map_err(value_error)?;
        Ok(Self { inner })
    }

    /// Reads and validates a `camera.json`.
    #[staticmethod]
    fn from_json(path: PathBuf) -> PyResult<Self> {
        let inner = renderer::Camera::from_json_file(&path).map_err(value_error)?;
        Ok(Self { inner })
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }
    #[getter]
    fn focal_length_mm(&self) -> f64 {
        self.inner.focal_length_mm
    }
    #[getter]
    fn sensor_width_mm(&self) -> f64 {
        self.inner.sensor_width_mm
    }
    #[getter]
    fn f_stop(&self) -> Option<f64> {
        self.inner.f_stop
    }
    #[getter]
    fn focus_distance(&self) -> Option<f64> {
        self.inner.focus_distance
    }
    #[getter]
    fn aperture_blades(&self) -> u32 {
        self.inner.aperture_blades
    }
    #[getter]
    fn aperture_rotation_deg(&self) -> f64 {
        self.inner.aperture_rotation_deg
    }
    #[getter]
    fn aperture_ratio(&self) -> f64 {
        self.inner.aperture_ratio
    }
    #[getter]
    fn shutter_frames(&self) -> f64 {
        self.inner.shutter_frames
    }

    /// The signed circle-of-confusion radius in pixels at planar `depth` (scene units); 0 for
    /// a pinhole.
    fn signed_coc_px(&self, depth: f64) -> f64 {
        self.inner
            .thin_lens()
            .map_or(0.0, |l| l.signed_coc_px(depth))
    }

    fn __repr__(&self) -> String {
        format!("{:?}", self.inner)
    }
}

/// A G-buffer read from an EXR: `color` (h, w, 4), `depth` (h, w) or None, `motion` (h, w, 2)
/// at the frame time, pixels per frame, x right, y down, or None, and `acceleration` (h, w, 2),
/// pixels per frame squared, where the file has both of Blender's vectors, else None.
#[pyclass(name = "GBuffer", module = "spreadlet")]
struct PyGBuffer {
    #[pyo3(get)]
    color: Py<PyArray3<f32>>,
    #[pyo3(get)]
    depth: Option<Py<PyArray2<f32>>>,
    #[pyo3(get)]
    motion: Option<Py<PyArray3<f32>>>,
    #[pyo3(get)]
    acceleration: Option<Py<PyArray3<f32>>>,
}

fn rgba_array<'py>(py: Python<'py>, image: &formats::RgbaImage) -> Bound<'py, PyArray3<f32>> {
    let flat: Vec<f32> = image.pixels.iter().flatten().copied().collect();
    numpy::PyArray1::from_vec(py, flat)
        .reshape([image.height, image.width, 4])
        .expect("the pixels fill the shape")
}

/// Reads a pinhole G-buffer (Blender multilayer or plain channels) or any RGBA EXR.
#[pyfunction]
fn read_gbuffer(py: Python<'_>, path: PathBuf) -> PyResult<PyGBuffer> {
    let g = py
        .allow_threads(|| renderer::GBuffer::read_exr(&path, &Default::default()))
        .map_err(value_error)?;
    let g = if g.overscan.is_none() {
        g
    } else {
        g.frame_only()
    };
    let (w, h) = (g.width, g.height);
    let color = rgba_array(
        py,
        &formats::RgbaImage {
            width: w,
            height: h,
            pixels: g.color.clone(),
        },
    );
    let depth = g.depth.as_ref().map(|d| {
        numpy::PyArray1::from_vec(py, d.clone())
            .reshape([h, w])
            .expect("shape")
            .unbind()
    });
    let pairs = |m: &Vec<[f32; 2]>| {
        let flat: Vec<f32> = m.iter().flatten().copied().collect();
        numpy::PyArray1::from_vec(py, flat)
            .reshape([h, w, 2])
            .expect("shape")
            .unbind()
    };
    Ok(PyGBuffer {
        color: color.unbind(),
        depth,
        motion: g.motion.as_ref().map(pairs),
        acceleration: g.acceleration.as_ref().map(pairs),
    })
}

/// The (h, w, 2) array `array` named `what` as one pair a pixel; an error naming its shape
/// where it is another.
fn pairs_of_array(
    what: &str,
    array: &PyReadonlyArray3<'_, f32>,
    h: usize,
    w: usize,
) -> PyResult<Vec<[f32; 2]>> {
    if array.shape() != [h, w, 2] {
        return Err(value_error(format!(
            "{what} must have shape ({h}, {w}, 2), got {:?}",
            array.shape()
        )));
    }
    let flat: Vec<f32> = array.as_array().iter().copied().collect();
    Ok(flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
}

/// The renderer: keeps its databases and GPU pipelines between calls.
#[pyclass(name = "Renderer", module = "spreadlet", unsendable)]
struct PyRenderer {
    inner: renderer::Renderer,
    progress: Arc<ProgressSlot>,
}

/// The progress callback of the call in flight, and the first exception it raised. Locked only
/// while the GIL is held (the GIL first, then the lock), so the builder's threads and the
/// caller cannot deadlock.
#[derive(Default)]
struct ProgressSlot {
    callback: Mutex<Option<Py<PyAny>>>,
    raised: Mutex<Option<PyErr>>,
}

impl ProgressSlot {
    /// Tells the callback of `event`: `(message, fraction)`, the fraction in [0, 1] for a
    /// database build's progress and None for other news.
    fn tell(&self, event: &renderer::Event) {
        Python::with_gil(|py| {
            let callback = match self.callback.lock() {
                Ok(slot) => slot.as_ref().map(|c| c.clone_ref(py)),
                Err(_) => None,
            };
            let Some(callback) = callback else { return };
            let fraction = match event {
                renderer::Event::Cache(c) => c.fraction(),
                _ => None,
            };
            if let Err(err) = callback.call1(py, (event.to_string(), fraction)) {
                if let Ok(mut raised) = self.raised.lock() {
                    raised.get_or_insert(err);
                }
            }
        });
    }

    /// Runs `work` with the GIL released and `callback` told of its events; an exception the
    /// callback raised is raised after `work` ends.
    fn around<T: Send>(
        &self,
        py: Python<'_>,
        callback: Option<Py<PyAny>>,
        work: impl FnOnce() -> Result<T, renderer::Error> + Send,
    ) -> PyResult<T> {
        if let Some(c) = &callback {
            if !c.bind(py).is_callable() {
                return Err(value_error("progress must be callable"));
            }
        }
        set(&self.callback, callback);
        set(&self.raised, None);
        let result = py.allow_threads(work);
        set(&self.callback, None);
        if let Some(err) = self.raised.lock().ok().and_then(|mut r| r.take()) {
            return Err(err);
        }
        result.map_err(value_error)
    }
}

fn set<T>(slot: &Mutex<Option<T>>, value: Option<T>) {
    match slot.lock() {
        Ok(mut guard) => *guard = value,
        Err(poisoned) => *poisoned.into_inner() = value,
    }
}

fn backend_of(name: &str) -> PyResult<renderer::Backend> {
    match name {
        "auto" => Ok(renderer::Backend::Auto),
        "gpu" => Ok(renderer::Backend::Gpu),
        "cpu" => Ok(renderer::Backend::Cpu),
        other => Err(value_error(format!(
            "backend must be auto, gpu or cpu, not {other:?}"
        ))),
    }
}

#[pymethods]
impl PyRenderer {
    /// `backend`: auto, gpu or cpu. Databases come from `db` (a file) or from the cache folder
    /// `cache_dir` (default `$SPREADLET_CACHE`, else `~/.cache/spreadlet`), built with
    /// `db_profile` when missing.
    #[new]
    #[pyo3(signature = (backend="auto", db=None, db_profile="quick", cache_dir=None))]
    fn new(
        backend: &str,
        db: Option<PathBuf>,
        db_profile: &str,
        cache_dir: Option<PathBuf>,
    ) -> PyResult<Self> {
        let databases = match db {
            Some(path) => renderer::DbSource::File(path),
            None => renderer::DbSource::Cache {
                dir: cache_dir.unwrap_or_else(renderer::cache_dir),
                profile: db_profile
                    .parse::<precompute::Profile>()
                    .map_err(value_error)?,
            },
        };
        let progress = Arc::new(ProgressSlot::default());
        let sink = progress.clone();
        let inner = renderer::Renderer::new(renderer::RendererOptions {
            backend: backend_of(backend)?,
            databases,
            on_event: Some(Arc::new(move |e: &renderer::Event| sink.tell(e))),
            ..Default::default()
        })
        .map_err(value_error)?;
        Ok(Self { inner, progress })
    }

    /// How many times databases were loaded (a second frame with the same needs loads none).
    #[getter]
    fn database_loads(&self) -> usize {
        self.inner.database_loads()
    }

    /// Depth of field and motion blur from a pinhole G-buffer: `color` (h, w, 4) float32,
    /// `depth` (h, w) planar, scene units, `motion` (h, w, 2) at the frame time, pixels per
    /// frame, x right, y down (or None for a still frame), and optionally `acceleration`
    /// (h, w, 2), pixels per frame squared (what `read_gbuffer` gives: each path's bend over
    /// the shutter; without it the bend is taken from the motion field). Returns the image
    /// (h, w, 4), and with `stats=True` also a dict of what was done.
    /// `progress(message, fraction)` hears of database builds (fraction in [0, 1]) and
    /// fallbacks (fraction None).
    #[pyo3(signature = (color, depth, motion, camera, stats=false, progress=None, acceleration=None))]
    #[allow(clippy::too_many_arguments)]
    fn synthesize<'py>(
        &mut self,
        py: Python<'py>,
        color: PyReadonlyArray3<'py, f32>,
        depth: Option<PyReadonlyArray2<'py, f32>>,
        motion: Option<PyReadonlyArray3<'py, f32>>,
        camera: &PyCamera,
        stats: bool,
        progress: Option<Py<PyAny>>,
        acceleration: Option<PyReadonlyArray3<'py, f32>>,
    ) -> PyResult<PyObject> {
        let shape = color.shape();
        let (h, w) = (shape[0], shape[1]);
        if shape[2] != 4 {
            return Err(value_error(format!(
                "color must have shape (height, width, 4), got {shape:?}"
            )));
        }
        let pixels: Vec<[f32; 4]> = color
            .as_array()
            .as_standard_layout()
            .as_slice()
            .ok_or_else(|| value_error("color is not contiguous"))?
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect();
        let depth = match depth {
            Some(d) => {
                if d.shape() != [h, w] {
                    return Err(value_error(format!(
                        "depth must have shape ({h}, {w}), got {:?}",
                        d.shape()
                    )));
                }
                Some(d.as_array().iter().copied().collect::<Vec<f32>>())
            }
            None => None,
        };
        let motion = motion
            .map(|m| pairs_of_array("motion", &m, h, w))
            .transpose()?;
        let gbuffer =
            renderer::GBuffer::from_planes(w, h, pixels, depth, motion).map_err(value_error)?;
        let gbuffer = match acceleration {
            Some(a) => gbuffer
                .with_acceleration(pairs_of_array("acceleration", &a, h, w)?)
                .map_err(value_error)?,
            None => gbuffer,
        };
        let camera = camera.inner.clone();
        let renderer = &mut self.inner;
        let frame = self.progress.around(py, progress, || {
            renderer.synthesize(&gbuffer, &camera, &renderer::SynthOptions::default())
        })?;
        frame_result(py, &frame, stats)
    }

    /// Depth of field and motion blur reconstructed from stochastic frames
    /// (`docs/STOCHASTIC.md`): `frames` is an array (h, w, spp, 12) float32 whose last axis
    /// holds a sample's channels in `spreadlet.SAMPLE_CHANNELS` order (what `read_frames`
    /// returns), or the path of a stochastic-frames EXR. `guides`, optional, is the denoiser's
    /// albedo and normal of every sample, an array (h, w, spp, 6) float32 in
    /// `spreadlet.GUIDE_CHANNELS` order (what `read_frames(path, guides=True)` returns); it
    /// replaces the guides a file holds. Returns as `synthesize` does.
    #[pyo3(signature = (frames, camera, stats=false, progress=None, guides=None))]
    fn reconstruct<'py>(
        &mut self,
        py: Python<'py>,
        frames: &Bound<'py, PyAny>,
        camera: &PyCamera,
        stats: bool,
        progress: Option<Py<PyAny>>,
        guides: Option<PyReadonlyArray4<'py, f32>>,
    ) -> PyResult<PyObject> {
        let frames = if let Ok(array) = frames.extract::<PyReadonlyArray4<'py, f32>>() {
            frames_of_array(&array)?
        } else if let Ok(path) = frames.extract::<PathBuf>() {
            py.allow_threads(|| renderer::StochasticFrames::read_exr(&path))
                .map_err(value_error)?
        } else {
            return Err(value_error(
                "frames must be a float32 array (height, width, spp, 12) or a path",
            ));
        };
        let frames = match guides {
            Some(array) => with_guides_of_array(frames, &array)?,
            None => frames,
        };
        if (frames.width, frames.height)
            != (camera.inner.width as usize, camera.inner.height as usize)
        {
            return Err(value_error(format!(
                "the frames are {}x{} pixels but the camera is {}x{}",
                frames.width, frames.height, camera.inner.width, camera.inner.height
            )));
        }
        let camera = camera.inner.clone();
        let renderer = &mut self.inner;
        let frame = self.progress.around(py, progress, || {
            renderer.reconstruct(&frames, &camera, &renderer::SynthOptions::default())
        })?;
        frame_result(py, &frame, stats)
    }

    /// Depth of field and motion blur from a deep OpenEXR file (deep scanline: R, G, B, A, Z,
    /// optionally ZBack and motion.x/motion.y in pixels per frame): every deep sample is
    /// blurred with its own depth and motion. Returns the image (height, width, 4) float32,
    /// or (image, stats) with `stats=True`; `progress` as for `synthesize`.
    #[pyo3(signature = (path, camera, stats=false, progress=None))]
    fn synthesize_deep(
        &mut self,
        py: Python<'_>,
        path: PathBuf,
        camera: &PyCamera,
        stats: bool,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<PyObject> {
        let deep = py
            .allow_threads(|| formats::DeepImage::read(&path))
            .map_err(value_error)?;
        let camera = camera.inner.clone();
        let renderer = &mut self.inner;
        let frame = self.progress.around(py, progress, || {
            renderer.synthesize_deep(&deep, &camera, &renderer::SynthOptions::default())
        })?;
        frame_result(py, &frame, stats)
    }
}

/// Stochastic frames from an array (h, w, spp, 12) of samples' channels.
fn frames_of_array(array: &PyReadonlyArray4<'_, f32>) -> PyResult<renderer::StochasticFrames> {
    let shape = array.shape();
    let (height, width, spp) = (shape[0], shape[1], shape[2]);
    if shape[3] != formats::stochastic::CHANNELS.len() || height == 0 || width == 0 || spp == 0 {
        return Err(value_error(format!(
            "frames must have shape (height, width, spp, {}), got {shape:?}",
            formats::stochastic::CHANNELS.len()
        )));
    }
    let view = array.as_array();
    let standard = view.as_standard_layout();
    let flat = standard
        .as_slice()
        .ok_or_else(|| value_error("frames is not contiguous"))?;
    let samples = flat
        .chunks_exact(formats::stochastic::CHANNELS.len())
        .map(|c| renderer::Sample::from_channels(std::array::from_fn(|i| c[i])))
        .collect();
    Ok(renderer::StochasticFrames::new(width, height, spp, samples))
}

/// The image of `frame`, with its statistics as a dict when `stats`.
fn frame_result(py: Python<'_>, frame: &renderer::Frame, stats: bool) -> PyResult<PyObject> {
    let image = rgba_array(py, &frame.image);
    if !stats {
        return Ok(image.into_any().unbind());
    }
    let d = PyDict::new(py);
    d.set_item("device", &frame.device)?;
    d.set_item("defocus", frame.stats.defocus)?;
    d.set_item("motion", frame.stats.motion)?;
    d.set_item("layers_used", frame.stats.layers_used)?;
    d.set_item("sparse", frame.stats.counts.sparse)?;
    d.set_item("dense", frame.stats.counts.dense)?;
    d.set_item("copied", frame.stats.counts.copied)?;
    d.set_item("total_ms", frame.stats.times.total_ms)?;
    d.set_item("databases_loaded", frame.databases.len())?;
    d.set_item(
        "databases_built",
        frame.databases.iter().filter(|u| u.built_now).count(),
    )?;
    Ok((image, d).into_pyobject(py)?.into_any().unbind())
}

/// `frames` with the guides of an array (h, w, spp, 6), which must match the frames' shape.
fn with_guides_of_array(
    frames: renderer::StochasticFrames,
    array: &PyReadonlyArray4<'_, f32>,
) -> PyResult<renderer::StochasticFrames> {
    let shape = array.shape();
    let want = [
        frames.height,
        frames.width,
        frames.spp,
        formats::stochastic::GUIDE_CHANNELS.len(),
    ];
    if shape != want {
        return Err(value_error(format!(
            "guides must have shape {want:?} (the frames' height, width and spp, then {}), \
             got {shape:?}",
            formats::stochastic::GUIDE_CHANNELS.join(", ")
        )));
    }
    let view = array.as_array();
    let standard = view.as_standard_layout();
    let flat = standard
        .as_slice()
        .ok_or_else(|| value_error("guides is not contiguous"))?;
    let guides = flat
        .chunks_exact(formats::stochastic::GUIDE_CHANNELS.len())
        .map(|c| formats::SampleGuides::from_channels(std::array::from_fn(|i| c[i])))
        .collect();
    frames.with_guides(guides).map_err(value_error)
}

/// Reads a stochastic-frames EXR (`docs/STOCHASTIC.md`) as an array (h, w, spp, 12) float32,
/// the last axis a sample's channels in `SAMPLE_CHANNELS` order. With `guides=True`, returns
/// `(frames, guides)`: `guides` is an array (h, w, spp, 6) float32 of the denoiser's albedo
/// and normal in `GUIDE_CHANNELS` order, or None when the file has no guide channels.
#[pyfunction]
#[pyo3(signature = (path, guides=false))]
fn read_frames(py: Python<'_>, path: PathBuf, guides: bool) -> PyResult<PyObject> {
    let frames = py
        .allow_threads(|| renderer::StochasticFrames::read_exr(&path))
        .map_err(value_error)?;
    let (h, w, spp) = (frames.height, frames.width, frames.spp);
    let flat: Vec<f32> = frames
        .samples
        .iter()
        .flat_map(|s| s.to_channels())
        .collect();
    let samples = numpy::PyArray1::from_vec(py, flat)
        .reshape([h, w, spp, formats::stochastic::CHANNELS.len()])
        .map_err(|e| value_error(e.to_string()))?;
    if !guides {
        return Ok(samples.into_any().unbind());
    }
    let guide_array = match &frames.guides {
        Some(g) => {
            let flat: Vec<f32> = g.iter().flat_map(|g| g.to_channels()).collect();
            Some(
                numpy::PyArray1::from_vec(py, flat)
                    .reshape([h, w, spp, formats::stochastic::GUIDE_CHANNELS.len()])
                    .map_err(|e| value_error(e.to_string()))?,
            )
        }
        None => None,
    };
    Ok((samples, guide_array)
        .into_pyobject(py)?
        .into_any()
        .unbind())
}

/// SSIM, PSNR (dB, None when identical), FLIP mean and 99th percentile of `a` against
/// `reference`, both (h, w, 4) or (h, w, 3) float32 linear, as the project reports them.
#[pyfunction]
fn compare<'py>(
    py: Python<'py>,
    a: PyReadonlyArray3<'py, f32>,
    reference: PyReadonlyArray3<'py, f32>,
) -> PyResult<Bound<'py, PyDict>> {
    if a.shape() != reference.shape() {
        return Err(value_error(format!(
            "the images differ in shape: {:?} and {:?}",
            a.shape(),
            reference.shape()
        )));
    }
    let (h, w, c) = (a.shape()[0], a.shape()[1], a.shape()[2]);
    if c != 4 {
        return Err(value_error(format!(
            "images must have shape (height, width, 4), got {:?}",
            a.shape()
        )));
    }
    let fa: Vec<f32> = a.as_array().iter().copied().collect();
    let fb: Vec<f32> = reference.as_array().iter().copied().collect();
    let (scores, _) = py
        .allow_threads(|| metrics::score_rgb(&fa, &fb, w, h))
        .map_err(value_error)?;
    let d = PyDict::new(py);
    d.set_item("ssim", scores.ssim)?;
    d.set_item("psnr_db", scores.psnr_db)?;
    d.set_item("flip_mean", scores.flip_mean)?;
    d.set_item("flip_p99", scores.flip_p99)?;
    Ok(d)
}

#[pymodule]
fn spreadlet(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCamera>()?;
    m.add_class::<PyGBuffer>()?;
    m.add_class::<PyRenderer>()?;
    m.add_function(wrap_pyfunction!(read_gbuffer, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(read_frames, m)?)?;
    m.add("SAMPLE_CHANNELS", formats::stochastic::CHANNELS.to_vec())?;
    m.add(
        "GUIDE_CHANNELS",
        formats::stochastic::GUIDE_CHANNELS.to_vec(),
    )?;
    Ok(())
}
