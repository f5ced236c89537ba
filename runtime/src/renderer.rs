//! [`Renderer`]: the library's one entry point. It holds what is worth keeping between frames
//! (the device, the PSF databases an input needed, conditioned, and the GPU pipelines with the
//! database uploaded), so a sequence is just repeated calls, and it applies one policy for
//! which device runs and which databases serve which effect, whoever calls it: the `spreadlet`
//! command, the Python module or the Blender add-on.

use crate::synth::ms_since;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use psf_db::PsfModel;

use crate::baseline;
use crate::camera::Camera;
use crate::databases::{self, Conditioned, DbUsed, Source};
use crate::dbcache::{self, CacheEvent};
use crate::dbset::DbSet;
use crate::error::Error;
use crate::gbuffer::GBuffer;
use crate::pipeline::Effects;
use crate::prepare::{Input, Plan, PreparedFrame};
use crate::synth::{SynthOptions, SynthStats};
use formats::{RgbaImage, StochasticFrames};

/// Which device runs the stages after classification.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Backend {
    /// The GPU when an adapter exists, else the CPU
    #[default]
    Auto,
    /// The GPU (an error when there is none)
    Gpu,
    /// The CPU (rayon)
    Cpu,
}

/// Where the PSF databases come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DbSource {
    /// The cache folder; a database missing there is built on demand with `profile`.
    Cache {
        /// The folder ([`dbcache::cache_dir`] by default).
        dir: PathBuf,
        /// The profile of databases built on demand.
        profile: precompute::Profile,
    },
    /// One database file, used for every pixel; it must be of a model the input can use (a
    /// lens-motion database also serves defocus alone).
    File(PathBuf),
}

impl Default for DbSource {
    fn default() -> Self {
        DbSource::Cache {
            dir: dbcache::cache_dir(),
            profile: precompute::Profile::Quick,
        }
    }
}

/// The synthesis method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// Sparse Laplacian splatting (the paper's method).
    #[default]
    Spreadlet,
    /// Baseline: the same pipeline with every pre-filtered PSF drawn whole (no Laplacian).
    Dense,
    /// Baseline: every output pixel gathers the input with its own pre-filtered PSF
    /// ([`Renderer::filter`]); databases are built with every PSF dense, as for `Dense`.
    Filter,
}

impl Method {
    /// The methods' names, as the command line spells them.
    pub const NAMES: [&'static str; 3] = baseline::METHODS;
}

/// What the renderer tells its caller while it works (the library prints nothing).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// The database cache rebuilds or builds a database.
    Cache(CacheEvent),
    /// `Backend::Auto` runs on the CPU, and why (no adapter, or only a software one, which is
    /// slower than the CPU path).
    CpuFallback {
        /// Why, in words.
        reason: String,
    },
    /// The dense baseline was given a database whose PSFs are stored sparse: it draws their
    /// integrated spreadlets instead of the pre-filtered PSFs.
    DensifiedSparse {
        /// The database file.
        path: PathBuf,
        /// PSFs stored sparse.
        count: usize,
    },
}

impl std::fmt::Display for Event {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Event::Cache(e) => e.fmt(f),
            Event::CpuFallback { reason } => write!(f, "backend auto: {reason}; using the CPU"),
            Event::DensifiedSparse { path, count } => write!(
                f,
                "--method dense: {count} PSFs of {} are stored sparse; drawing their \
                 integrated spreadlets (not the pre-filtered PSFs)",
                path.display()
            ),
        }
    }
}

/// A callback for [`Event`]s.
pub type EventSink = Arc<dyn Fn(&Event) + Send + Sync>;

/// How a [`Renderer`] is set up; fixed for its life.
#[derive(Clone)]
pub struct RendererOptions {
    /// The device.
    pub backend: Backend,
    /// Where the databases come from.
    pub databases: DbSource,
    /// The method.
    pub method: Method,
    /// Condition the databases before use (monopole removal, energy normalisation); off only
    /// to study the stored spreadlets as they are.
    pub condition: bool,
    /// Show the database builder's progress bars on stderr (builds take minutes).
    pub progress: bool,
    /// Told of builds and fallbacks; `None` hears nothing.
    pub on_event: Option<EventSink>,
}

impl Default for RendererOptions {
    fn default() -> Self {
        Self {
            backend: Backend::Auto,
            databases: DbSource::default(),
            method: Method::Spreadlet,
            condition: true,
            progress: false,
            on_event: None,
        }
    }
}

impl std::fmt::Debug for RendererOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RendererOptions")
            .field("backend", &self.backend)
            .field("databases", &self.databases)
            .field("method", &self.method)
            .field("condition", &self.condition)
            .field("progress", &self.progress)
            .field("on_event", &self.on_event.as_ref().map(|_| "callback"))
            .finish()
    }
}

/// One rendered frame and what it took.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The image: linear premultiplied RGBA, the frame's size (overscan removed).
    pub image: RgbaImage,
    /// Effects, counts per path, layers and stage times.
    pub stats: SynthStats,
    /// The device that ran it: `cpu` or `gpu (<adapter>)`.
    pub device: String,
    /// The GPU's own breakdown of its stages (upload, readback, timestamps), on the GPU.
    #[cfg(feature = "gpu")]
    pub gpu_stages: Option<crate::gpu::GpuStageTimes>,
    /// The databases loaded by this call (empty when they were kept from an earlier call).
    pub databases: Vec<DbUsed>,
    /// What conditioning changed in the databases loaded by this call.
    pub conditioning: Vec<Conditioned>,
    /// Time spent finding, building, reading and conditioning databases, milliseconds.
    pub database_ms: f64,
}

/// The databases a renderer holds: what they were loaded for, and the set.
struct HeldDatabases {
    model: Option<PsfModel>,
    /// Loaded without the lens-motion database (moving pixels smear the thin-lens PSF).
    without_motion_database: bool,
    aperture: psf_db::Aperture,
    lens: Option<precompute::LensOptions>,
    set: Arc<DbSet>,
}

/// The device a renderer settled on at its first frame.
enum Device {
    Cpu,
    #[cfg(feature = "gpu")]
    Gpu(Box<GpuState>),
}

#[cfg(feature = "gpu")]
struct GpuState {
    ctx: crate::gpu::GpuContext,
    /// Pipelines with the current databases uploaded; rebuilt when they change.
    synthesizer: Option<crate::gpu::GpuSynthesizer>,
}

/// The renderer: synthesis from pinhole G-buffers and reconstruction from stochastic frames,
/// on the device [`RendererOptions::backend`] picks, with databases loaded once and kept.
///
/// The device is chosen at the first frame and kept; databases are kept as long as the frames
/// need the same model and aperture (a set loaded for motion blur also serves a still frame).
pub struct Renderer {
    options: RendererOptions,
    device: Option<Device>,
    databases: Option<HeldDatabases>,
    loads: usize,
}

impl Renderer {
    /// A renderer; nothing is loaded until the first frame needs it.
    ///
    /// ```
    /// use spreadlet::{Backend, DbSource, Profile, Renderer, RendererOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// let renderer = Renderer::new(RendererOptions {
    ///     backend: Backend::Cpu,
    ///     // Databases from this folder, built there with the quick profile when missing.
    ///     databases: DbSource::Cache { dir: spreadlet::cache_dir(), profile: Profile::Quick },
    ///     ..Default::default()
    /// })?;
    /// assert_eq!(renderer.database_loads(), 0);
    /// # Ok(()) }
    /// ```
    pub fn new(options: RendererOptions) -> Result<Self, Error> {
        #[cfg(not(feature = "gpu"))]
        if options.backend == Backend::Gpu {
            return Err(Error::NoGpuSupport);
        }
        Ok(Self {
            options,
            device: None,
            databases: None,
            loads: 0,
        })
    }

    /// The options it was made with.
    pub fn options(&self) -> &RendererOptions {
        &self.options
    }

    /// How many times databases were loaded (a sequence of frames with the same needs loads
    /// them once).
    pub fn database_loads(&self) -> usize {
        self.loads
    }

    /// The databases held now (after a frame), if any.
    pub fn databases(&self) -> Option<&DbSet> {
        self.databases.as_ref().map(|d| d.set.as_ref())
    }

    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    fn emit(&self, event: Event) {
        if let Some(sink) = &self.options.on_event {
            sink(&event);
        }
    }

    /// Adds depth of field and motion blur to a pinhole G-buffer as `camera` sees it.
    /// `options` apply to this call, on either device. A pinhole, still input comes back
    /// unchanged.
    ///
    /// ```
    /// use spreadlet::{Backend, Camera, GBuffer, Renderer, RendererOptions, SynthOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// // A 4 x 4 grey G-buffer, 2 scene units away, seen through a pinhole (no `f_stop`)
    /// // that does not move: nothing to simulate, and no database is loaded.
    /// let gbuffer = GBuffer::from_planes(4, 4, vec![[0.5, 0.5, 0.5, 1.0]; 16], Some(vec![2.0; 16]), None)?;
    /// let camera = Camera::from_json_str(
    ///     r#"{"width": 4, "height": 4, "focal_length_mm": 50, "sensor_width_mm": 36}"#,
    /// )?;
    /// let mut renderer = Renderer::new(RendererOptions { backend: Backend::Cpu, ..Default::default() })?;
    /// let frame = renderer.synthesize(&gbuffer, &camera, &SynthOptions::default())?;
    /// assert_eq!(frame.image.pixels, gbuffer.color);
    /// assert!(!frame.stats.defocus && !frame.stats.motion);
    /// # Ok(()) }
    /// ```
    pub fn synthesize(
        &mut self,
        gbuffer: &GBuffer,
        camera: &Camera,
        options: &SynthOptions,
    ) -> Result<Frame, Error> {
        self.render(Plan::new(Input::Flat(gbuffer), camera, options)?)
    }

    /// Depth of field and motion blur from several render layers of one frame (Blender view
    /// layers, or one file per layer): every layer's pixels are splatted with their own PSFs
    /// into the global depth layers, so what a blurred foreground hides is the background's
    /// real pixels. One layer (not declared still) gives exactly [`Renderer::synthesize`]'s
    /// result.
    ///
    /// ```no_run
    /// use spreadlet::{Camera, GBuffer, Renderer, SynthOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// // Every view layer of a Blender multilayer EXR with Combined and Depth passes.
    /// let layers = GBuffer::read_view_layers("layers.exr".as_ref(), None)?;
    /// let camera = Camera::from_json_file("camera.json".as_ref())?;
    /// let mut renderer = Renderer::new(Default::default())?;
    /// let frame = renderer.synthesize_layers(&layers, &camera, &SynthOptions::default())?;
    /// frame.image.write_exr("out.exr".as_ref())?;
    /// # Ok(()) }
    /// ```
    pub fn synthesize_layers(
        &mut self,
        layers: &[crate::gbuffer::ViewLayer],
        camera: &Camera,
        options: &SynthOptions,
    ) -> Result<Frame, Error> {
        self.render(Plan::new(Input::Layers(layers), camera, options)?)
    }

    /// Depth of field and motion blur from a deep image ([`formats::DeepImage`]): every deep
    /// sample is splatted with its own PSF, so anti-aliased edges and semi-transparent
    /// surfaces blur by their own depths.
    ///
    /// ```no_run
    /// use spreadlet::{Camera, DeepImage, Renderer, SynthOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// let deep = DeepImage::read("deep.exr".as_ref())?;
    /// let camera = Camera::from_json_file("camera.json".as_ref())?;
    /// let mut renderer = Renderer::new(Default::default())?;
    /// let frame = renderer.synthesize_deep(&deep, &camera, &SynthOptions::default())?;
    /// frame.image.write_exr("out.exr".as_ref())?;
    /// # Ok(()) }
    /// ```
    pub fn synthesize_deep(
        &mut self,
        deep: &formats::DeepImage,
        camera: &Camera,
        options: &SynthOptions,
    ) -> Result<Frame, Error> {
        self.render(Plan::new(Input::Deep(deep), camera, options)?)
    }

    /// Reconstructs depth of field and motion blur from stochastic frames (each sample
    /// labelled with its lens position and time; `docs/STOCHASTIC.md`).
    ///
    /// ```no_run
    /// use spreadlet::{Camera, Renderer, StochasticFrames, SynthOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// let frames = StochasticFrames::read_exr("stochastic_1spp.exr".as_ref())?;
    /// let camera = Camera::from_json_file("camera.json".as_ref())?;
    /// let mut renderer = Renderer::new(Default::default())?;
    /// let frame = renderer.reconstruct(&frames, &camera, &SynthOptions::default())?;
    /// frame.image.write_exr("out.exr".as_ref())?;
    /// # Ok(()) }
    /// ```
    pub fn reconstruct(
        &mut self,
        frames: &StochasticFrames,
        camera: &Camera,
        options: &SynthOptions,
    ) -> Result<Frame, Error> {
        self.render(Plan::new(Input::samples(frames), camera, options)?)
    }

    /// Any input, through the one seam: the databases its plan needs, then the frame prepared
    /// once and drawn on this renderer's device.
    ///
    /// ```
    /// use spreadlet::{Backend, Camera, GBuffer, Input, Plan, Renderer, RendererOptions, SynthOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// let gbuffer = GBuffer::from_planes(2, 2, vec![[1.0, 0.0, 0.0, 1.0]; 4], Some(vec![3.0; 4]), None)?;
    /// let camera = Camera::from_json_str(
    ///     r#"{"width": 2, "height": 2, "focal_length_mm": 35, "sensor_width_mm": 36}"#,
    /// )?;
    /// let plan = Plan::new(Input::Flat(&gbuffer), &camera, &SynthOptions::default())?;
    /// assert_eq!(plan.model(), None); // a pinhole that does not move needs no database
    /// let mut renderer = Renderer::new(RendererOptions { backend: Backend::Cpu, ..Default::default() })?;
    /// let frame = renderer.render(plan)?;
    /// assert_eq!(frame.image.pixels, gbuffer.color);
    /// # Ok(()) }
    /// ```
    pub fn render(&mut self, plan: Plan) -> Result<Frame, Error> {
        let smear_motion = plan.options().classify.smear_motion;
        let selected = self.databases_for(plan.effects(), plan.camera(), smear_motion)?;
        // The device is picked once per renderer (probing for a GPU takes tens of ms), before
        // the frame's clock starts: the frame's times are its own.
        let plan = match self.device()? {
            Device::Cpu => plan.with_images_packed(),
            #[cfg(feature = "gpu")]
            Device::Gpu(_) => plan.with_sparse_records_kept(),
        };
        let prepared = plan.prepare(&selected.set)?;
        self.run(prepared, selected)
    }

    /// The databases `effects` need: the held set when it serves them, else loaded now. With
    /// `smear_motion` moving pixels smear the thin-lens PSF, and no lens-motion database is
    /// loaded for them.
    fn databases_for(
        &mut self,
        effects: Effects,
        camera: &Camera,
        smear_motion: bool,
    ) -> Result<Selected, Error> {
        let started = Instant::now();
        let needed = effects.cheapest_model();
        // A user-drawn aperture shapes the thin-lens and lens-motion PSFs; read it only when
        // there is a lens to shape.
        let mask = if effects.defocus {
            camera.aperture_mask()?
        } else {
            None
        };
        let aperture = databases::with_mask(databases::aperture_of(camera), mask.as_ref());
        let lens = if effects.defocus {
            databases::lens_of(camera)?
        } else {
            None
        };
        if let Some(held) = &self.databases {
            let needs_motion_database =
                needed == Some(PsfModel::LensMotion) && !smear_motion && lens.is_none();
            if held.aperture == aperture
                && held.lens == lens
                && databases::serves(held.model, needed)
                && !(needs_motion_database && held.without_motion_database)
            {
                return Ok(Selected {
                    set: held.set.clone(),
                    used: Vec::new(),
                    conditioning: Vec::new(),
                    ms: 0.0,
                });
            }
        }
        let sink = self.options.on_event.clone();
        let on_cache = |e: CacheEvent| {
            if let Some(sink) = &sink {
                sink(&Event::Cache(e));
            }
        };
        let method = self.options.method;
        let densify = |db: psf_db::PsfDatabase| -> Result<psf_db::PsfDatabase, Error> {
            // A given database that stores PSFs sparse has no pre-filtered images of them:
            // the dense baseline integrates their spreadlets instead.
            if baseline::sparse_psf_count(&db) == 0 {
                return Ok(db);
            }
            let (dense, count) = baseline::densify(&db)?;
            if let (Some(sink), DbSource::File(path)) = (&sink, &self.options.databases) {
                sink(&Event::DensifiedSparse {
                    path: path.clone(),
                    count,
                });
            }
            Ok(dense)
        };
        let adjust = |cfg: precompute::BuildConfig| baseline::dense_build_config(&cfg);
        let source = match &self.options.databases {
            DbSource::Cache { dir, profile } => Source::Cache {
                dir,
                profile: *profile,
            },
            DbSource::File(path) => Source::File(path),
        };
        let is_file = matches!(source, Source::File(_));
        let request = databases::Request {
            source,
            needed,
            aperture,
            mask: mask.as_ref(),
            lens: lens.as_ref(),
            condition: self.options.condition,
            // The baselines draw the pre-filtered PSFs the spreadlets were fitted to.
            adjust: (method != Method::Spreadlet && !is_file).then_some(&adjust as &dyn Fn(_) -> _),
            transform: (method == Method::Dense && is_file).then_some(&densify as &dyn Fn(_) -> _),
            progress: self.options.progress,
            smear_motion,
        };
        let loaded = databases::load(&request, &on_cache)?;
        let set = Arc::new(loaded.set);
        self.databases = Some(HeldDatabases {
            model: needed,
            without_motion_database: smear_motion,
            aperture,
            lens,
            set: set.clone(),
        });
        self.loads += 1;
        #[cfg(feature = "gpu")]
        if let Some(Device::Gpu(gpu)) = &mut self.device {
            gpu.synthesizer = None; // new databases: upload them again
        }
        Ok(Selected {
            set,
            used: loaded.used,
            conditioning: loaded.conditioning,
            ms: ms_since(started),
        })
    }

    /// The device for this renderer, chosen at its first frame.
    fn device(&mut self) -> Result<&mut Device, Error> {
        if self.device.is_none() {
            let device = self.pick_device()?;
            self.device = Some(device);
        }
        Ok(self.device.as_mut().expect("set above"))
    }

    #[cfg(feature = "gpu")]
    fn pick_device(&self) -> Result<Device, Error> {
        let backend = self.options.backend;
        if backend == Backend::Cpu {
            return Ok(Device::Cpu);
        }
        // A software adapter (lavapipe) is slower than the CPU path: `auto` sets it aside
        // without opening a device on it.
        use crate::gpu::{adapter_label, GpuContext, Opened, SoftwareAdapter};
        let software = match backend {
            Backend::Gpu => SoftwareAdapter::Open,
            Backend::Auto | Backend::Cpu => SoftwareAdapter::SetAside,
        };
        match GpuContext::open(backend == Backend::Gpu, software)? {
            Opened::Context(ctx) => Ok(Device::Gpu(Box::new(GpuState {
                ctx: *ctx,
                synthesizer: None,
            }))),
            Opened::Software(info) => {
                self.emit(Event::CpuFallback {
                    reason: format!("{} is a software adapter", adapter_label(&info)),
                });
                Ok(Device::Cpu)
            }
            Opened::NoAdapter => {
                self.emit(Event::CpuFallback {
                    reason: "no GPU adapter".into(),
                });
                Ok(Device::Cpu)
            }
        }
    }

    #[cfg(not(feature = "gpu"))]
    fn pick_device(&self) -> Result<Device, Error> {
        Ok(Device::Cpu)
    }

    fn run(&mut self, prepared: PreparedFrame, selected: Selected) -> Result<Frame, Error> {
        let dbs = selected.set.as_ref();
        let frame = |image, stats, device, _stages: Option<GpuStages>| Frame {
            image,
            stats,
            device,
            #[cfg(feature = "gpu")]
            gpu_stages: _stages,
            databases: selected.used.clone(),
            conditioning: selected.conditioning.clone(),
            database_ms: selected.ms,
        };
        match self.device()? {
            #[cfg(feature = "gpu")]
            Device::Gpu(gpu) => {
                use crate::gpu::{GpuSynthOptions, GpuSynthesizer};
                if gpu.synthesizer.is_none() {
                    gpu.synthesizer = Some(GpuSynthesizer::for_database(
                        &gpu.ctx,
                        dbs.combined.as_ref(),
                        GpuSynthOptions::from_synth(prepared.options()),
                    )?);
                }
                let name = format!("gpu ({})", gpu.ctx.adapter_name());
                // A frame with PSFs of its own (smeared along the motion through a real lens)
                // uploads its database for this frame alone.
                let mut own = None;
                if prepared.database_or(None).is_some() {
                    own = Some(GpuSynthesizer::for_database(
                        &gpu.ctx,
                        prepared.database_or(None),
                        GpuSynthOptions::from_synth(prepared.options()),
                    )?);
                }
                let synthesizer = match own.as_mut() {
                    Some(s) => s,
                    None => gpu.synthesizer.as_mut().expect("set above"),
                };
                let (image, stats, stages) = crate::gpu::render_gpu(synthesizer, prepared, dbs)?;
                Ok(frame(image, stats, name, Some(stages)))
            }
            Device::Cpu => {
                let (image, stats) = crate::synth::render_cpu(prepared, dbs);
                Ok(frame(image, stats, "cpu".to_string(), None))
            }
        }
    }

    /// The filter baseline (every output pixel gathers the input with its own pre-filtered
    /// PSF; the paper's comparison), on the renderer's device, with the renderer's databases
    /// made dense. Returns the image, the device's name and the baseline's statistics.
    ///
    /// ```no_run
    /// use spreadlet::{Camera, FilterOptions, GBuffer, Method, Renderer, RendererOptions};
    /// # fn main() -> Result<(), spreadlet::Error> {
    /// let gbuffer = GBuffer::read_exr("input.exr".as_ref(), &Default::default())?;
    /// let camera = Camera::from_json_file("camera.json".as_ref())?;
    /// let mut renderer =
    ///     Renderer::new(RendererOptions { method: Method::Filter, ..Default::default() })?;
    /// let frame = renderer.filter(&gbuffer, &camera, &FilterOptions::default())?;
    /// frame.image.write_exr("filter.exr".as_ref())?;
    /// # Ok(()) }
    /// ```
    pub fn filter(
        &mut self,
        gbuffer: &GBuffer,
        camera: &Camera,
        options: &baseline::FilterOptions,
    ) -> Result<FilterFrame, Error> {
        // The filter knows no overscan: it sees the frame alone.
        let frame_only = gbuffer.frame_only();
        let effects = Effects::of(camera, &frame_only);
        // The filter gathers from the set's lens-motion PSFs.
        let selected = self.databases_for(effects, camera, false)?;
        let (dbs, databases) = (selected.set, selected.used);
        let kernels = match &dbs.combined {
            Some(db) => baseline::DenseKernels::from_db(db),
            None => baseline::DenseKernels::default(),
        };
        match self.device()? {
            #[cfg(feature = "gpu")]
            Device::Gpu(gpu) => {
                let filter = crate::gpu::GpuFilter::new(&gpu.ctx, &kernels)?;
                let (image, stats) =
                    crate::gpu::filter_gpu(&filter, &frame_only, camera, &dbs, options)?;
                Ok(FilterFrame {
                    image,
                    stats,
                    device: format!("gpu ({})", gpu.ctx.adapter_name()),
                    kernels_integrated: kernels.integrated,
                    databases,
                })
            }
            Device::Cpu => {
                let (image, stats) =
                    baseline::filter(&frame_only, camera, &dbs, &kernels, options)?;
                Ok(FilterFrame {
                    image,
                    stats,
                    device: "cpu".into(),
                    kernels_integrated: kernels.integrated,
                    databases,
                })
            }
        }
    }
}

/// A frame of the filter baseline.
#[derive(Clone, Debug)]
pub struct FilterFrame {
    /// The image.
    pub image: RgbaImage,
    /// The baseline's statistics.
    pub stats: baseline::FilterStats,
    /// The device that ran it.
    pub device: String,
    /// Kernels integrated from spreadlets (PSFs stored sparse).
    pub kernels_integrated: usize,
    /// The databases loaded by this call.
    pub databases: Vec<DbUsed>,
}

#[cfg(feature = "gpu")]
type GpuStages = crate::gpu::GpuStageTimes;
#[cfg(not(feature = "gpu"))]
type GpuStages = ();

/// The databases for one frame: the set and, when this call loaded it, what was loaded.
struct Selected {
    set: Arc<DbSet>,
    used: Vec<DbUsed>,
    conditioning: Vec<Conditioned>,
    /// Time spent loading, milliseconds.
    ms: f64,
}
