//! The headless wgpu context: Vulkan only (never a silent fallback to OpenGL), an adapter chosen
//! explicitly, features and limits requested from what the adapter has. Built once, reused for
//! every call. All wgpu calls that moved between releases are in this file.
//!
//! Mesa prints `XDG_RUNTIME_DIR` warnings on headless machines unless that variable is set; the
//! `flatport` binary sets it at start-up, and `scripts/test.sh` exports it.

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
}

/// Environment variable naming the adapter (a case-insensitive part of its name).
pub const ADAPTER_ENV: &str = "FLATPORT_ADAPTER";

const INSTALL_HINT: &str = "Install a Vulkan driver: on Debian/Ubuntu `apt-get install mesa-vulkan-drivers` \
    gives the lavapipe software adapter; on a GPU machine install its vendor's Vulkan driver";

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
    /// Largest workgroup count per dispatch dimension.
    pub max_workgroups_per_dimension: u32,
}

fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    wgpu::Instance::new(desc)
}

fn summary(adapter: &wgpu::Adapter) -> AdapterSummary {
    let info = adapter.get_info();
    let features = adapter.features();
    let limits = adapter.limits();
    AdapterSummary {
        name: info.name,
        backend: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
        driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        f64: features.contains(wgpu::Features::SHADER_F64),
        subgroup: features.contains(wgpu::Features::SUBGROUP),
        timestamp: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        max_storage_binding: limits.max_storage_buffer_binding_size,
        max_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
    }
}

/// Every Vulkan adapter on this machine.
pub fn adapters() -> Vec<AdapterSummary> {
    pollster::block_on(instance().enumerate_adapters(wgpu::Backends::VULKAN)).iter().map(summary).collect()
}

/// A device and queue on one adapter, reused for every kernel call.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    summary: AdapterSummary,
    /// Storage buffers can be mapped by the host (MAPPABLE_PRIMARY_BUFFERS on shared memory).
    mapped_storage: bool,
}

impl GpuContext {
    /// Opens the adapter whose name contains `name` (case-insensitive), else the one named by
    /// `FLATPORT_ADAPTER`, else the first hardware GPU, else the first adapter (lavapipe).
    pub fn new(name: Option<&str>) -> Result<Self, GpuError> {
        Self::open(name, true)
    }

    /// As [`new`](Self::new), and `map_storage` says whether kernels' buffers may be mapped by
    /// the host directly where the adapter shares its memory (`false`: always staging copies,
    /// the path of discrete GPUs; for tests and comparisons).
    pub fn open(name: Option<&str>, map_storage: bool) -> Result<Self, GpuError> {
        let wanted = name.map(str::to_string).or_else(|| std::env::var(ADAPTER_ENV).ok());
        let all = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::VULKAN));
        let names: Vec<String> = all.iter().map(|a| a.get_info().name).collect();
        let chosen = match &wanted {
            Some(w) => all.iter().find(|a| a.get_info().name.to_lowercase().contains(&w.to_lowercase())),
            None => all
                .iter()
                .find(|a| a.get_info().device_type != wgpu::DeviceType::Cpu)
                .or_else(|| all.first()),
        };
        let Some(adapter) = chosen else {
            let tried = match &wanted {
                Some(w) => format!("no Vulkan adapter named like '{w}' (found: {})", list(&names)),
                None => "no Vulkan adapter found".to_string(),
            };
            return Err(GpuError::NoAdapter { tried, hint: INSTALL_HINT.to_string() });
        };
        let summary = summary(adapter);
        let mut wanted_features = wgpu::Features::SHADER_F64 | wgpu::Features::SUBGROUP | wgpu::Features::TIMESTAMP_QUERY;
        // Where the device shares the host's memory (lavapipe, integrated GPUs), storage buffers
        // that the host maps directly save the staging copies both ways.
        let shares_memory = matches!(adapter.get_info().device_type, wgpu::DeviceType::Cpu | wgpu::DeviceType::IntegratedGpu);
        if shares_memory && map_storage {
            wanted_features |= wgpu::Features::MAPPABLE_PRIMARY_BUFFERS;
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("flatport"),
            required_features: adapter.features() & wanted_features,
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device { adapter: summary.name.clone(), reason: e.to_string() })?;
        let mapped_storage = device.features().contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
        Ok(Self { device, queue, summary, mapped_storage })
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
        receiver.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
        buffer.get_mapped_range_mut(..len).map_err(|e| GpuError::Readback(e.to_string()))?.copy_from_slice(bytes);
        buffer.unmap();
        Ok(())
    }

    /// Largest storage binding, bytes.
    pub fn max_storage_binding(&self) -> u64 {
        self.summary.max_storage_binding
    }

    /// Compiles a composed WGSL kernel with entry point `main` into a pipeline.
    pub(crate) fn pipeline(&self, label: &str, source: &str) -> wgpu::ComputePipeline {
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        })
    }

    /// Workgroup counts (x, y) for `items` items in 64-wide workgroups: 2-D past the per-dimension limit.
    pub(crate) fn dispatch_size(&self, items: u32) -> (u32, u32) {
        let groups = items.div_ceil(64).max(1);
        let max = self.summary.max_workgroups_per_dimension.max(1);
        if groups <= max { (groups, 1) } else { (max, groups.div_ceil(max)) }
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
            receiver.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
        }
        let views = copies
            .iter()
            .map(|&(_, staging, bytes)| staging.get_mapped_range(..bytes).map_err(|e| GpuError::Readback(e.to_string())))
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

    /// Blocks until every submitted command has finished.
    pub(crate) fn wait(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map(drop).map_err(|e| GpuError::Readback(e.to_string()))
    }
}

fn list(names: &[String]) -> String {
    if names.is_empty() { "none".to_string() } else { names.join(", ") }
}
