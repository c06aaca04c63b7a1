//! The headless wgpu context: Vulkan only (never a silent fallback to OpenGL), an adapter chosen
//! explicitly, features and limits requested from what the adapter has, and the cache of compiled
//! pipelines every user of the context shares. Built once, reused for every call. All wgpu calls
//! that moved between releases are in this file.
//!
//! Mesa prints `XDG_RUNTIME_DIR` warnings on headless machines unless that variable is set; the
//! `flatport` binary sets it at start-up, and `scripts/test.sh` exports it.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use super::compose::{CpuBounds, KernelSource, Precision, Rows, WORKGROUP_SIZE, compose};
use crate::model::camera::UNDISTORT_MAX_ITERATIONS;
use crate::model::refractive_camera::{PROJECT_MAX_ITERATIONS, PROJECT_TOLERANCE, SWITCH_MAX_Q};
use crate::model::stereo::{MIN_BINOCULAR_CONDITIONING, MIN_RAY_ANGLE_SIN2};

/// The CPU path's stopping rules, as every kernel of the pipeline cache gets them (in its
/// prelude, [`compose`](super::compose::prelude)).
pub const CPU_BOUNDS: CpuBounds = CpuBounds {
    undistort_max_iterations: UNDISTORT_MAX_ITERATIONS,
    project_tolerance: PROJECT_TOLERANCE,
    project_max_iterations: PROJECT_MAX_ITERATIONS,
    switch_max_q: SWITCH_MAX_Q,
    min_ray_angle_sin2: MIN_RAY_ANGLE_SIN2,
    min_binocular_conditioning: MIN_BINOCULAR_CONDITIONING,
};

/// The composed WGSL module of `kernel` at `precision` with the CPU's stopping rules, its view
/// rows bound as `rows` (ignored by kernels without): the text [`GpuContext::kernel_pipeline`]
/// compiles, for `precision` = [`KernelSource::precision`].
pub fn source(kernel: &KernelSource, precision: Precision, rows: Rows) -> String {
    compose(kernel, precision, rows, &CPU_BOUNDS)
}

/// What a pipeline of the cache is compiled from: the kernel (by its name, unique across the
/// catalogues), its precision, its view-row binding and `RIG_LAYERS`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct PipelineKey {
    kernel: &'static str,
    precision: Precision,
    rows: Rows,
    rig_layers: u32,
}

/// Why no GPU context could be made.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No Vulkan adapter matched.
    #[error("no GPU adapter: {tried}. {hint}")]
    NoAdapter {
        /// What was looked for and what was found.
        tried: String,
        /// What to install or set.
        hint: String,
    },
    /// The adapter refused the device.
    #[error("adapter '{adapter}' refused a device: {reason}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// wgpu's message.
        reason: String,
    },
    /// Reading results back failed.
    #[error("reading results back from the GPU failed: {0}")]
    Readback(String),
    /// The input cannot run on the GPU kernels.
    #[error("{0}")]
    Unsupported(String),
    /// Device rows that do not fit the call: of another device or precision, of unequal
    /// lengths, or buffers too short for the rows they should hold.
    #[error("device rows: {0}")]
    Rows(String),
    /// A kernel did not compile into a pipeline (a WGSL or layout error the adapter refused).
    #[error("GPU kernel '{kernel}' was refused by the adapter: {reason}")]
    Kernel {
        /// Kernel name.
        kernel: String,
        /// wgpu's message.
        reason: String,
    },
    /// A buffer could not be allocated on the device.
    #[error("cannot allocate a GPU buffer '{label}' of {bytes} bytes: {reason}")]
    OutOfMemory {
        /// Buffer label.
        label: String,
        /// Requested size.
        bytes: u64,
        /// wgpu's message, or the limit exceeded.
        reason: String,
    },
    /// wgpu reported an error for a command (bind group, dispatch, copy).
    #[error("the GPU refused {what}: {reason}")]
    Validation {
        /// What was being done.
        what: String,
        /// wgpu's message.
        reason: String,
    },
    /// The device was lost (driver reset, GPU removed, fatal error): no result can be trusted.
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
    /// The device did not finish its work in time.
    #[error(
        "the GPU did not finish within {seconds} s (a hung or overloaded device; set {TIMEOUT_ENV} to wait longer)"
    )]
    Timeout {
        /// The wait's limit.
        seconds: u64,
    },
}

/// Environment variable: seconds to wait for the device to finish one submission (default
/// [`DEFAULT_TIMEOUT_S`]).
pub const TIMEOUT_ENV: &str = "FLATPORT_GPU_TIMEOUT_S";

/// Seconds a wait for one submission may take before it is an error: far above any chunk's time
/// (a 4 Mi-item chunk takes well under a second on lavapipe), so only a hung device reaches it.
pub const DEFAULT_TIMEOUT_S: u64 = 600;

/// Environment variable naming the adapter (a case-insensitive part of its name).
pub const ADAPTER_ENV: &str = "FLATPORT_ADAPTER";

const INSTALL_HINT: &str = "Install a Vulkan driver and loader. Debian/Ubuntu without a GPU: \
    `apt-get install mesa-vulkan-drivers libvulkan1` gives the lavapipe software adapter. NVIDIA \
    (H100, H200, A100, …): the driver's Vulkan ICD (`/usr/share/vulkan/icd.d/nvidia_icd.json`, from the \
    NVIDIA driver; Debian non-free: `nvidia-vulkan-icd`) and `libvulkan1`; in a container, the NVIDIA Container Toolkit \
    mounts them only when NVIDIA_DRIVER_CAPABILITIES includes `graphics` (or is `all`): the default \
    `compute,utility` has CUDA but no Vulkan. Check with `flatport info` or `vulkaninfo --summary`";

/// Preference among adapter kinds: a discrete GPU before an integrated one, before a virtual one,
/// before anything else, before a software adapter (lavapipe runs on the CPU's own cores).
fn rank(kind: wgpu::DeviceType) -> u8 {
    match kind {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// The adapter to open among `adapters` (in enumeration order, the order `flatport info` numbers
/// them): `wanted` as an index (`0`, `3`) or a case-insensitive part of a name (`h200`, `llvmpipe`;
/// the first match); without it the best by [`rank`], the first of equals.
///
/// Errors: what was looked for and what was found, for [`GpuError::NoAdapter`].
pub(crate) fn choose_adapter(
    adapters: &[wgpu::AdapterInfo],
    wanted: Option<&str>,
) -> Result<usize, String> {
    let found = || {
        let names: Vec<String> = adapters
            .iter()
            .enumerate()
            .map(|(i, a)| format!("{i}: {}", a.name))
            .collect();
        list(&names)
    };
    match wanted.map(str::trim) {
        Some(w) if !w.is_empty() && w.bytes().all(|b| b.is_ascii_digit()) => {
            match w.parse::<usize>() {
                Ok(i) if i < adapters.len() => Ok(i),
                _ => Err(format!(
                    "no Vulkan adapter with index {w} (found: {})",
                    found()
                )),
            }
        }
        Some(w) => adapters
            .iter()
            .position(|a| a.name.to_lowercase().contains(&w.to_lowercase()))
            .ok_or_else(|| format!("no Vulkan adapter named like '{w}' (found: {})", found())),
        None => (0..adapters.len())
            .min_by_key(|&i| rank(adapters[i].device_type))
            .ok_or_else(|| "no Vulkan adapter found".to_string()),
    }
}

/// One adapter as `flatport info` lists it.
#[derive(Debug, Clone)]
pub struct AdapterSummary {
    /// Adapter name (`llvmpipe (LLVM 15.0.6, 256 bits)`, …).
    pub name: String,
    /// Backend (always Vulkan here).
    pub backend: String,
    /// Discrete, integrated, CPU (software), …
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
    /// SHADER_F64 available.
    pub f64: bool,
    /// SUBGROUP available.
    pub subgroup: bool,
    /// TIMESTAMP_QUERY available.
    pub timestamp: bool,
    /// Largest storage binding, bytes.
    pub max_storage_binding: u64,
    /// Largest uniform binding, bytes.
    pub max_uniform_binding: u64,
    /// Largest workgroup count per dispatch dimension.
    pub max_workgroups_per_dimension: u32,
}

fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    wgpu::Instance::new(desc)
}

fn summary(adapter: &wgpu::Adapter) -> AdapterSummary {
    summary_of(adapter.get_info(), adapter.features(), &adapter.limits())
}

/// The summary of an adapter with these features and limits (the adapter's own, or those a
/// device was given).
fn summary_of(
    info: wgpu::AdapterInfo,
    features: wgpu::Features,
    limits: &wgpu::Limits,
) -> AdapterSummary {
    AdapterSummary {
        name: info.name,
        backend: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
        driver: format!("{} {}", info.driver, info.driver_info)
            .trim()
            .to_string(),
        f64: features.contains(wgpu::Features::SHADER_F64),
        subgroup: features.contains(wgpu::Features::SUBGROUP),
        timestamp: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        max_storage_binding: limits.max_storage_buffer_binding_size,
        max_uniform_binding: limits.max_uniform_buffer_binding_size,
        max_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
    }
}

/// The limit of one wait: [`TIMEOUT_ENV`] seconds, else [`DEFAULT_TIMEOUT_S`].
fn wait_limit() -> std::time::Duration {
    let seconds = std::env::var(TIMEOUT_ENV)
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .filter(|&s| s > 0)
        .unwrap_or(DEFAULT_TIMEOUT_S);
    std::time::Duration::from_secs(seconds)
}

/// Every Vulkan adapter on this machine.
pub fn adapters() -> Vec<AdapterSummary> {
    pollster::block_on(instance().enumerate_adapters(wgpu::Backends::VULKAN))
        .iter()
        .map(summary)
        .collect()
}

/// A device and queue on one adapter, reused for every kernel call.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    summary: AdapterSummary,
    /// Storage buffers can be mapped by the host (MAPPABLE_PRIMARY_BUFFERS on shared memory).
    mapped_storage: bool,
    /// A software adapter (lavapipe): the kernels run on the host's own cores.
    software: bool,
    /// Errors wgpu reported outside an error scope (instead of its default handler, which
    /// panics), and the reason the device was lost: both checked after every wait.
    faults: Arc<Faults>,
    /// Limit of one wait.
    timeout: std::time::Duration,
    /// Compiled pipelines, shared by every user of the context.
    pipelines: Mutex<HashMap<PipelineKey, Arc<wgpu::ComputePipeline>>>,
    /// This context's own number ([`id`](GpuContext::id)).
    id: u64,
}

/// The number of the next context.
static NEXT_CONTEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// What wgpu's callbacks report, for [`GpuContext::check`].
#[derive(Debug, Default)]
struct Faults {
    uncaptured: Mutex<Option<String>>,
    lost: Mutex<Option<String>>,
}

fn take(slot: &Mutex<Option<String>>) -> Option<String> {
    slot.lock().unwrap_or_else(|p| p.into_inner()).take()
}

fn keep_first(slot: &Mutex<Option<String>>, message: String) {
    slot.lock()
        .unwrap_or_else(|p| p.into_inner())
        .get_or_insert(message);
}

impl GpuContext {
    /// Opens the adapter `name` names (its index as `flatport info` lists it, or a case-insensitive
    /// part of its name), else the one `FLATPORT_ADAPTER` names, else the best one: a discrete GPU
    /// before an integrated one, before lavapipe (`choose_adapter`).
    pub fn new(name: Option<&str>) -> Result<Self, GpuError> {
        Self::open(name, true)
    }

    /// As [`new`](Self::new), and `map_storage` says whether kernels' buffers may be mapped by
    /// the host directly where the adapter shares its memory (`false`: always staging copies,
    /// the path of discrete GPUs; for tests and comparisons).
    pub fn open(name: Option<&str>, map_storage: bool) -> Result<Self, GpuError> {
        let wanted = name
            .map(str::to_string)
            .or_else(|| std::env::var(ADAPTER_ENV).ok());
        let all = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::VULKAN));
        let infos: Vec<wgpu::AdapterInfo> = all.iter().map(|a| a.get_info()).collect();
        let index = choose_adapter(&infos, wanted.as_deref()).map_err(|tried| {
            // With adapters present the choice was wrong, not the installation.
            let hint = if infos.is_empty() {
                INSTALL_HINT
            } else {
                "`flatport info` lists the adapters with their indices"
            };
            GpuError::NoAdapter {
                tried,
                hint: hint.to_string(),
            }
        })?;
        let adapter = &all[index];
        let summary = summary(adapter);
        let mut wanted_features =
            wgpu::Features::SHADER_F64 | wgpu::Features::SUBGROUP | wgpu::Features::TIMESTAMP_QUERY;
        // Where the device shares the host's memory (lavapipe, integrated GPUs), storage buffers
        // that the host maps directly save the staging copies both ways.
        let shares_memory = matches!(
            adapter.get_info().device_type,
            wgpu::DeviceType::Cpu | wgpu::DeviceType::IntegratedGpu
        );
        if shares_memory && map_storage {
            wanted_features |= wgpu::Features::MAPPABLE_PRIMARY_BUFFERS;
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("flatport"),
            required_features: adapter.features() & wanted_features,
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: summary.name.clone(),
            reason: e.to_string(),
        })?;
        let mapped_storage = device
            .features()
            .contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
        let faults = Arc::new(Faults::default());
        let sink = faults.clone();
        device.on_uncaptured_error(Arc::new(move |error: wgpu::Error| {
            keep_first(&sink.uncaptured, error.to_string())
        }));
        let sink = faults.clone();
        device.set_device_lost_callback(move |reason, message| {
            if reason != wgpu::DeviceLostReason::Destroyed {
                keep_first(&sink.lost, format!("{reason:?}: {message}"));
            }
        });
        Ok(Self {
            device,
            queue,
            summary,
            mapped_storage,
            software: adapter.get_info().device_type == wgpu::DeviceType::Cpu,
            faults,
            timeout: wait_limit(),
            pipelines: Mutex::default(),
            id: NEXT_CONTEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    /// A context on a device and queue the caller already has (a pipeline that renders or runs
    /// its own kernels on the same GPU shares them with flatport instead of opening a second
    /// device). `adapter` is the one the device was requested from; flatport's kernels use what
    /// the device was given: f64 kernels need `SHADER_F64`, the subgroup reduction `SUBGROUP`, and
    /// buffers stay under the device's `max_storage_buffer_binding_size`.
    ///
    /// The device's uncaptured-error handler and device-lost callback stay the caller's: flatport
    /// installs none on a borrowed device, so a fault outside flatport's error scopes reaches the
    /// caller's handler (wgpu's default panics), and a lost device shows as failed waits.
    ///
    /// ```no_run
    /// # async fn run() -> Result<(), Box<dyn std::error::Error>> {
    /// let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    /// let adapter = instance.request_adapter(&wgpu::RequestAdapterOptions::default()).await?;
    /// let (device, queue) = adapter.request_device(&wgpu::DeviceDescriptor {
    ///     required_features: adapter.features() & wgpu::Features::SHADER_F64,
    ///     ..Default::default()
    /// }).await?;
    /// // … the pipeline's own work on `device` …
    /// let context = flatport::gpu::GpuContext::from_device(&adapter, device.clone(), queue.clone());
    /// let engine = flatport::engine::GpuEngine::new(context, flatport::gpu::Precision::F32)?;
    /// # Ok(()) }
    /// ```
    pub fn from_device(adapter: &wgpu::Adapter, device: wgpu::Device, queue: wgpu::Queue) -> Self {
        let features = device.features();
        let summary = summary_of(adapter.get_info(), features, &device.limits());
        let mapped_storage = features.contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
        Self {
            device,
            queue,
            summary,
            mapped_storage,
            software: adapter.get_info().device_type == wgpu::DeviceType::Cpu,
            faults: Arc::new(Faults::default()),
            timeout: wait_limit(),
            pipelines: Mutex::default(),
            id: NEXT_CONTEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// A number no other context of this process has: what data kept on a device compare to
    /// know whose they are. Not `wgpu::Device`'s equality, which compares wgpu-core's ids, and
    /// those repeat across instances (two contexts opened on one adapter have equal devices).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// The queue kernels are submitted to (shared with the caller after
    /// [`from_device`](Self::from_device)).
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The wgpu device, for a pipeline that runs its own work beside flatport's. Errors it raises
    /// outside an error scope are reported by [`check`](Self::check), not by a panic.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The adapter in use.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.summary
    }

    /// True when kernels' storage buffers are mapped by the host directly, without staging
    /// copies (adapters that share the host's memory and have MAPPABLE_PRIMARY_BUFFERS).
    pub fn maps_storage(&self) -> bool {
        self.mapped_storage
    }

    /// True on a software adapter (lavapipe, device type CPU), whose kernels run on the host's
    /// own cores.
    pub fn is_software(&self) -> bool {
        self.software
    }

    /// Writes `bytes` at the start of a MAP_WRITE buffer through a mapping.
    pub(crate) fn write_mapped(&self, buffer: &wgpu::Buffer, bytes: &[u8]) -> Result<(), GpuError> {
        if bytes.is_empty() {
            return Ok(());
        }
        let len = bytes.len() as u64;
        let (sender, receiver) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Write, ..len, move |r| {
            let _ = sender.send(r);
        });
        self.wait()?;
        receiver
            .recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        buffer
            .get_mapped_range_mut(..len)
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .copy_from_slice(bytes);
        buffer.unmap();
        Ok(())
    }

    /// Largest storage binding, bytes.
    pub fn max_storage_binding(&self) -> u64 {
        self.summary.max_storage_binding
    }

    /// Compiles a composed WGSL kernel with entry point `main` into a pipeline, with the overrides
    /// every composed kernel declares (in `shaders/common.wgsl`): `WORKGROUP_SIZE` set to
    /// [`WORKGROUP_SIZE`] and `RIG_LAYERS` to `rig_layers`, the most layers of a camera the
    /// pipeline will see (its layer loops run to that constant).
    ///
    /// Errors: [`GpuError::Kernel`] naming the kernel when the adapter refuses the shader or the
    /// pipeline, a source without those overrides included (caught in an error scope: wgpu's
    /// default would panic).
    pub fn pipeline(
        &self,
        label: &str,
        source: &str,
        rig_layers: u32,
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &[
                        ("WORKGROUP_SIZE", f64::from(WORKGROUP_SIZE)),
                        ("RIG_LAYERS", f64::from(rig_layers)),
                    ],
                    ..Default::default()
                },
                cache: None,
            });
        match pollster::block_on(scope.pop()) {
            Some(error) => Err(GpuError::Kernel {
                kernel: label.to_string(),
                reason: error.to_string(),
            }),
            None => Ok(pipeline),
        }
    }

    /// The compiled pipeline of `kernel` for a caller at `precision` (the kernel's own where it
    /// is fixed), its view rows bound as `rows` (ignored by kernels without), its layer loops
    /// running to `rig_layers` (`RIG_LAYERS`: the most layers of the cameras it will see; one
    /// pipeline per layer count, whose loops have a constant trip count). Compiled from
    /// [`source`] on first use and kept: every later call with the same kernel, precision,
    /// binding and layer count, by any user of this context, gets the same pipeline.
    ///
    /// Errors: [`GpuError::Kernel`] as [`pipeline`](Self::pipeline).
    pub fn kernel_pipeline(
        &self,
        kernel: &KernelSource,
        precision: Precision,
        rows: Rows,
        rig_layers: u32,
    ) -> Result<Arc<wgpu::ComputePipeline>, GpuError> {
        let key = PipelineKey {
            kernel: kernel.name,
            precision: kernel.precision(precision),
            rows: kernel.rows(rows),
            rig_layers,
        };
        let mut cache = self.pipelines.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(pipeline) = cache.get(&key) {
            return Ok(pipeline.clone());
        }
        let text = source(kernel, key.precision, key.rows);
        let pipeline = Arc::new(self.pipeline(&kernel.label(key.rows), &text, rig_layers)?);
        cache.insert(key, pipeline.clone());
        Ok(pipeline)
    }

    /// Allocates a buffer of `bytes`.
    ///
    /// Errors: [`GpuError::OutOfMemory`] naming the buffer when `bytes` exceeds the adapter's
    /// largest buffer or the device has no memory left; [`GpuError::Validation`] when the adapter
    /// refuses the descriptor (a usage it does not allow). Both are caught in error scopes.
    pub fn buffer(
        &self,
        label: &str,
        bytes: u64,
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer, GpuError> {
        let limit = self.device.limits().max_buffer_size;
        let refuse = |reason: String| GpuError::OutOfMemory {
            label: label.to_string(),
            bytes,
            reason,
        };
        if bytes > limit {
            return Err(refuse(format!(
                "the adapter's largest buffer is {limit} bytes"
            )));
        }
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes,
            usage,
            mapped_at_creation: false,
        });
        let invalid = pollster::block_on(validation.pop());
        let exhausted = pollster::block_on(memory.pop());
        if let Some(error) = exhausted {
            return Err(refuse(error.to_string()));
        }
        match invalid {
            Some(error) => Err(GpuError::Validation {
                what: format!("buffer '{label}' of {bytes} bytes"),
                reason: error.to_string(),
            }),
            None => Ok(buffer),
        }
    }

    /// Errors that wgpu reported since the last check outside an error scope, or the loss of the
    /// device: [`GpuError::DeviceLost`], or [`GpuError::Validation`] saying what was being done.
    pub fn check(&self, what: &str) -> Result<(), GpuError> {
        if let Some(reason) = take(&self.faults.lost) {
            // Kept: every later call on a lost device fails too.
            keep_first(&self.faults.lost, reason.clone());
            return Err(GpuError::DeviceLost(reason));
        }
        match take(&self.faults.uncaptured) {
            Some(reason) => Err(GpuError::Validation {
                what: what.to_string(),
                reason,
            }),
            None => Ok(()),
        }
    }

    /// Submits `encoder` after copying each `(source, staging, bytes)` into its staging buffer
    /// (nothing to copy where `staging` is `source`, a host-mappable storage buffer),
    /// waits, and hands the mapped bytes of every staging buffer, in order, to `read`.
    pub(crate) fn read_back<T>(
        &self,
        mut encoder: wgpu::CommandEncoder,
        copies: &[(&wgpu::Buffer, &wgpu::Buffer, u64)],
        read: impl FnOnce(&[&[u8]]) -> T,
    ) -> Result<T, GpuError> {
        for &(source, staging, bytes) in copies {
            // A source that is its own staging buffer is mapped directly.
            if source != staging {
                encoder.copy_buffer_to_buffer(source, 0, staging, 0, bytes);
            }
        }
        self.queue.submit([encoder.finish()]);
        let (sender, receiver) = std::sync::mpsc::channel();
        for &(_, staging, bytes) in copies {
            let sender = sender.clone();
            staging.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
                let _ = sender.send(r);
            });
        }
        self.wait()?;
        for _ in copies {
            receiver
                .recv()
                .map_err(|e| GpuError::Readback(e.to_string()))?
                .map_err(|e| GpuError::Readback(e.to_string()))?;
        }
        let views = copies
            .iter()
            .map(|&(_, staging, bytes)| {
                staging
                    .get_mapped_range(..bytes)
                    .map_err(|e| GpuError::Readback(e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let slices: Vec<&[u8]> = views.iter().map(|v| &v[..]).collect();
        let result = read(&slices);
        drop(slices);
        drop(views);
        for &(_, staging, _) in copies {
            staging.unmap();
        }
        Ok(result)
    }

    /// Starts mapping the first `bytes` of `buffer` for `mode`: the receiver gets the outcome
    /// once the device is done with every submission that uses the buffer, during a poll
    /// ([`await_map`](Self::await_map)).
    pub(crate) fn map(
        &self,
        buffer: &wgpu::Buffer,
        mode: wgpu::MapMode,
        bytes: u64,
    ) -> std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>> {
        let (sender, receiver) = std::sync::mpsc::channel();
        buffer.map_async(mode, ..bytes.max(1), move |r| {
            let _ = sender.send(r);
        });
        receiver
    }

    /// Waits for `count` mappings started by [`map`](Self::map) on `receiver`: polls the device
    /// without blocking first, then blocks until submission `after` has finished (the last one
    /// that used the buffers; `None`: every submission), at most the context's timeout.
    ///
    /// Errors: a failed mapping ([`GpuError::Readback`]), a timeout, or a fault the device
    /// reported ([`check`](Self::check)).
    pub(crate) fn await_map(
        &self,
        receiver: &std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
        count: usize,
        after: Option<&wgpu::SubmissionIndex>,
    ) -> Result<(), GpuError> {
        use std::sync::mpsc::TryRecvError;
        let mut left = count;
        // Set once the submission has finished: the callbacks are due by then.
        let mut deadline: Option<std::time::Instant> = None;
        while left > 0 {
            match receiver.try_recv() {
                Ok(mapped) => {
                    mapped.map_err(|e| GpuError::Readback(e.to_string()))?;
                    left -= 1;
                }
                Err(TryRecvError::Disconnected) => {
                    return Err(GpuError::Readback(
                        "a mapping was dropped before it completed".into(),
                    ));
                }
                Err(TryRecvError::Empty) if let Some(deadline) = deadline => {
                    // The submission has finished, but another thread's submit or poll may have
                    // taken the callback and not yet run it (the streaming engine submits from
                    // a second thread): poll and wait for it, up to the timeout.
                    if std::time::Instant::now() > deadline {
                        return Err(GpuError::Readback(
                            "a mapping did not complete after its submission finished".into(),
                        ));
                    }
                    let _ = self.device.poll(wgpu::PollType::Poll);
                    if let Ok(mapped) = receiver.recv_timeout(std::time::Duration::from_millis(1)) {
                        mapped.map_err(|e| GpuError::Readback(e.to_string()))?;
                        left -= 1;
                    }
                }
                Err(TryRecvError::Empty) => {
                    // A buffer no submission uses maps at the next poll; one in use once its
                    // submission has finished.
                    let _ = self.device.poll(wgpu::PollType::Poll);
                    if let Ok(mapped) = receiver.try_recv() {
                        mapped.map_err(|e| GpuError::Readback(e.to_string()))?;
                        left -= 1;
                        continue;
                    }
                    self.wait_for(after.cloned())?;
                    deadline = Some(std::time::Instant::now() + self.timeout);
                }
            }
        }
        self.check("mapping a buffer")
    }

    /// Submits `command` and returns its index, for [`await_map`](Self::await_map).
    pub(crate) fn submit(&self, command: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
        self.queue.submit([command])
    }

    /// Blocks until every submitted command has finished, at most the context's timeout
    /// ([`TIMEOUT_ENV`]), then [`check`](Self::check)s for errors and the loss of the device.
    pub(crate) fn wait(&self) -> Result<(), GpuError> {
        self.wait_for(None)
    }

    /// [`wait`](Self::wait) for submission `index` only (`None`: every submission).
    pub(crate) fn wait_for(&self, index: Option<wgpu::SubmissionIndex>) -> Result<(), GpuError> {
        let polled = self.device.poll(wgpu::PollType::Wait {
            submission_index: index,
            timeout: Some(self.timeout),
        });
        match polled {
            Ok(_) => self.check("a submitted kernel"),
            Err(wgpu::PollError::Timeout) => Err(GpuError::Timeout {
                seconds: self.timeout.as_secs(),
            }),
            Err(error) => {
                self.check("a submitted kernel")?;
                Err(GpuError::Readback(error.to_string()))
            }
        }
    }
}

fn list(names: &[String]) -> String {
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::{KernelSource, Precision, Rows};

    fn info(name: &str, device_type: wgpu::DeviceType) -> wgpu::AdapterInfo {
        wgpu::AdapterInfo {
            name: name.into(),
            device_type,
            ..wgpu::AdapterInfo::new(wgpu::DeviceType::Other, wgpu::Backend::Vulkan)
        }
    }

    #[test]
    fn adapters_are_chosen_discrete_first_then_by_index_or_name() {
        use super::choose_adapter;
        use wgpu::DeviceType as T;
        let machine = [
            info("llvmpipe (LLVM 15)", T::Cpu),
            info("Intel UHD 770", T::IntegratedGpu),
            info("NVIDIA H200", T::DiscreteGpu),
            info("NVIDIA H200", T::DiscreteGpu),
        ];
        assert_eq!(choose_adapter(&machine, None), Ok(2));
        assert_eq!(choose_adapter(&machine[..2], None), Ok(1));
        assert_eq!(choose_adapter(&machine[..1], None), Ok(0));
        assert_eq!(
            choose_adapter(&machine, Some("3")),
            Ok(3),
            "the second of two identical GPUs"
        );
        assert_eq!(choose_adapter(&machine, Some("h200")), Ok(2));
        assert_eq!(choose_adapter(&machine, Some("LLVMPIPE")), Ok(0));
        let error = choose_adapter(&machine, Some("4")).unwrap_err();
        assert!(
            error.contains("index 4") && error.contains("3: NVIDIA H200"),
            "{error}"
        );
        assert!(
            choose_adapter(&machine, Some("radeon"))
                .unwrap_err()
                .contains("'radeon'")
        );
        assert!(choose_adapter(&[], None).is_err());
    }

    /// A kernel of the context's prelude that writes one number: `RIG_LAYERS` plus the first
    /// `info` word.
    const PROBE: KernelSource = KernelSource::new(
        "probe",
        &["@group(0) @binding(0) var<uniform> params: Params;\n\
           @group(0) @binding(1) var<storage, read_write> out: array<u32>;\n\
           @compute @workgroup_size(WORKGROUP_SIZE) fn main() { out[0] = RIG_LAYERS + params.info.x; }"],
    );

    /// One compiled pipeline per (kernel, precision, binding, layer count): the same one for the
    /// same key, whoever asks, another for another layer count or precision, and the view-row
    /// binding ignored by a kernel that reads none.
    #[test]
    fn the_pipeline_cache_compiles_each_key_once() {
        let context = match super::GpuContext::new(None) {
            Ok(context) => context,
            Err(e) if std::env::var_os("CI").is_none() => {
                eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
                return;
            }
            Err(e) => panic!("CI needs a Vulkan adapter: {e}"),
        };
        let get = |precision, rows, layers| {
            context
                .kernel_pipeline(&PROBE, precision, rows, layers)
                .unwrap()
        };
        let one = get(Precision::F32, Rows::Storage, 1);
        assert!(Arc::ptr_eq(&one, &get(Precision::F32, Rows::Storage, 1)));
        assert!(
            Arc::ptr_eq(&one, &get(Precision::F32, Rows::Uniform, 1)),
            "the binding of view rows the probe does not read"
        );
        assert!(!Arc::ptr_eq(&one, &get(Precision::F32, Rows::Storage, 2)));
        if context.adapter().f64 {
            let f64_one = get(Precision::F64, Rows::Storage, 1);
            assert!(!Arc::ptr_eq(&one, &f64_one));
            let fixed = PROBE.in_precision(Precision::F64);
            let fixed = context
                .kernel_pipeline(&fixed, Precision::F32, Rows::Storage, 1)
                .unwrap();
            assert!(
                Arc::ptr_eq(&f64_one, &fixed),
                "a fixed precision is the key's"
            );
        }
        assert_eq!(
            context.pipelines.lock().unwrap().len(),
            2 + usize::from(context.adapter().f64)
        );
    }
}
