//! The batch engine: one API, [`Engine`], over two backends: [`CpuEngine`] ([`cpu`]: the f64
//! reference of [`crate::model`], parallel over all cores, on a vector path in [`cpu::lanes`])
//! and [`GpuEngine`] ([`gpu`]: the relations as WGSL kernels through the wgpu toolkit of
//! [`crate::gpu`], f32 or f64). [`raymap`] back-projects whole images on either; [`workload`]
//! makes the benchmarks' batches.
//!
//! Every call takes input rows as f64 slices and writes into caller-provided output slices of
//! the same length, so a pipeline embeds it without copies. `status[i]` is 0 where row i has an
//! answer, otherwise the [`NoSolution`](crate::model::NoSolution) code, and the output row is NaN.
//!
//! ```no_run
//! use flatport::engine::{Device, Engine, EngineOptions};
//! # let rig: flatport::model::Rig = unimplemented!();
//! let engine = Engine::new(&EngineOptions { device: Device::Auto, ..Default::default() })?;
//! eprintln!("device: {}", engine.describe());
//! let camera = rig.refractive_camera(0);
//! let pixels = vec![[640.0, 512.0], [10.0, 20.0]];
//! let mut rays = vec![[0.0; 6]; pixels.len()];
//! let mut status = vec![0; pixels.len()];
//! engine.backproject(&camera, &pixels, &mut rays, &mut status)?;
//! # Ok::<(), flatport::engine::EngineError>(())
//! ```

pub mod cpu;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod raymap;
pub mod workload;

pub use cpu::{CpuEngine, CpuPath};
#[cfg(feature = "gpu")]
pub use gpu::GpuEngine;

use crate::gpu::Precision;
#[cfg(feature = "gpu")]
use crate::gpu::{GpuContext, GpuError};
use crate::model::RefractiveCamera;

/// Where a batch runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Device {
    /// The f64 reference on the CPU.
    Cpu,
    /// A Vulkan adapter (a GPU, or lavapipe when that is all there is).
    Gpu,
    /// A hardware GPU adapter if there is one, otherwise the CPU.
    #[default]
    Auto,
}

/// How to build an [`Engine`].
#[derive(Debug, Clone, Default)]
pub struct EngineOptions {
    /// Backend choice.
    pub device: Device,
    /// Kernel precision on the GPU (default f32). The CPU is always f64.
    pub precision: Option<Precision>,
    /// Part of the adapter's name (else `FLATPORT_ADAPTER`, else the first hardware GPU, else lavapipe).
    pub adapter: Option<String>,
    /// CPU threads (default: all cores).
    pub threads: Option<usize>,
}

/// Why an engine could not be built or a batch could not run.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// A GPU failure (no adapter, device lost, unsupported input).
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Options that contradict each other.
    #[error("{0}")]
    Options(String),
}

/// The backend that runs batches.
#[allow(clippy::large_enum_variant)] // one per program: boxing would buy nothing
pub enum Engine {
    /// The f64 reference.
    Cpu(CpuEngine),
    /// The WGSL kernels.
    #[cfg(feature = "gpu")]
    Gpu(GpuEngine),
}

impl Engine {
    /// Builds the backend `options` ask for. `Device::Auto` takes a hardware GPU adapter when the
    /// machine has one (never lavapipe, which runs on the same cores as the CPU path) and falls
    /// back to the CPU otherwise; [`choose`](Self::choose) also says why.
    pub fn new(options: &EngineOptions) -> Result<Self, EngineError> {
        Ok(Self::choose(options)?.0)
    }

    /// As [`new`](Self::new), with a sentence saying why this device runs (for `--device auto`:
    /// which adapter was taken, or why the CPU runs instead).
    pub fn choose(options: &EngineOptions) -> Result<(Self, String), EngineError> {
        match options.device {
            Device::Cpu => {
                if options.precision == Some(Precision::F32) {
                    return Err(EngineError::Options(
                        "the CPU path is f64 only: drop --precision f32 or use --device gpu".into(),
                    ));
                }
                Ok((
                    Self::Cpu(CpuEngine::new(options.threads)),
                    "asked for (--device cpu)".into(),
                ))
            }
            #[cfg(feature = "gpu")]
            Device::Gpu | Device::Auto => {
                gpu_or_cpu(options, options.precision.unwrap_or(Precision::F32))
            }
            #[cfg(not(feature = "gpu"))]
            Device::Gpu => Err(EngineError::Options(
                "this build of flatport has no GPU support (the crate's `gpu` feature is off): use --device cpu".into(),
            )),
            #[cfg(not(feature = "gpu"))]
            Device::Auto => Ok((
                Self::Cpu(CpuEngine::new(options.threads)),
                "auto: this build has no GPU support (the crate's `gpu` feature is off)".into(),
            )),
        }
    }

    /// One line saying what runs: `cpu (f64 reference, vector avx512, 16 threads)` or
    /// `gpu: NVIDIA H100 (Vulkan, NVIDIA 550.54), f32`.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu(cpu) => format!(
                "cpu (f64 reference, {}, {} threads)",
                cpu.path(),
                cpu.threads()
            ),
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => {
                let a = gpu.context().adapter();
                format!(
                    "gpu: {} ({}, {}), {}",
                    a.name,
                    a.backend,
                    a.driver,
                    gpu.precision()
                )
            }
        }
    }

    /// Back-projects raw pixels (u, v) of `camera` to rays in the water: origin xyz on the outer
    /// interface and unit direction xyz, master frame.
    ///
    /// Panics if the slices differ in length.
    pub fn backproject(
        &self,
        camera: &RefractiveCamera,
        pixels: &[[f64; 2]],
        rays: &mut [[f64; 6]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        match self {
            Self::Cpu(cpu) => {
                cpu.backproject(camera, pixels, rays, status);
                Ok(())
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => Ok(gpu.backproject(camera, pixels, rays, status)?),
        }
    }

    /// Projects points (x, y, z, master frame) through the interface to raw pixels (u, v).
    pub fn project(
        &self,
        camera: &RefractiveCamera,
        points: &[[f64; 3]],
        pixels: &mut [[f64; 2]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        match self {
            Self::Cpu(cpu) => {
                cpu.project(camera, points, pixels, status);
                Ok(())
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => Ok(gpu.project(camera, points, pixels, status)?),
        }
    }

    /// VOPs of points: depth, vop_distance, vop_x, vop_y, vop_z, incidence (radians), as
    /// [`RefractiveCamera::vop`].
    pub fn vop(
        &self,
        camera: &RefractiveCamera,
        points: &[[f64; 3]],
        vops: &mut [[f64; 6]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        match self {
            Self::Cpu(cpu) => {
                cpu.vop(camera, points, vops, status);
                Ok(())
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => Ok(gpu.vop(camera, points, vops, status)?),
        }
    }

    /// Triangulates matches (ul, vl, ur, vr: raw pixels in `a` and `b`): x, y, z, residual.
    pub fn triangulate(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[f64; 4]],
        points: &mut [[f64; 4]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        match self {
            Self::Cpu(cpu) => {
                cpu.triangulate(a, b, matches, points, status);
                Ok(())
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => Ok(gpu.triangulate(a, b, matches, points, status)?),
        }
    }

    /// Binocular VOPs of matches (ul, vl, ur, vr) from `a`'s system axis: left VOP xyz, right
    /// VOP xyz, axis offset m, conditioning, as [`binocular_vop`](crate::model::binocular_vop).
    pub fn binocular_vop(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[f64; 4]],
        vops: &mut [[f64; 8]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        match self {
            Self::Cpu(cpu) => {
                cpu.binocular_vop(a, b, matches, vops, status);
                Ok(())
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => Ok(gpu.binocular_vop(a, b, matches, vops, status)?),
        }
    }

    /// [`project`](Self::project) for f32 rows (a pipeline's own buffers): the rows are widened
    /// to f64 in blocks of [`F32_BLOCK_ROWS`], computed as f64 and narrowed back, so memory stays
    /// bounded and the answers are the f64 answers rounded to f32.
    pub fn project_f32(
        &self,
        camera: &RefractiveCamera,
        points: &[[f32; 3]],
        pixels: &mut [[f32; 2]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        widened(points, pixels, status, |i, o, s| {
            self.project(camera, i, o, s)
        })
    }

    /// [`backproject`](Self::backproject) for f32 rows, as [`project_f32`](Self::project_f32).
    pub fn backproject_f32(
        &self,
        camera: &RefractiveCamera,
        pixels: &[[f32; 2]],
        rays: &mut [[f32; 6]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        widened(pixels, rays, status, |i, o, s| {
            self.backproject(camera, i, o, s)
        })
    }

    /// [`vop`](Self::vop) for f32 rows, as [`project_f32`](Self::project_f32).
    pub fn vop_f32(
        &self,
        camera: &RefractiveCamera,
        points: &[[f32; 3]],
        vops: &mut [[f32; 6]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        widened(points, vops, status, |i, o, s| self.vop(camera, i, o, s))
    }

    /// [`triangulate`](Self::triangulate) for f32 rows, as [`project_f32`](Self::project_f32).
    pub fn triangulate_f32(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[f32; 4]],
        points: &mut [[f32; 4]],
        status: &mut [u32],
    ) -> Result<(), EngineError> {
        widened(matches, points, status, |i, o, s| {
            self.triangulate(a, b, i, o, s)
        })
    }
}

/// `Device::Gpu` and `Device::Auto` of [`Engine::choose`].
#[cfg(feature = "gpu")]
fn gpu_or_cpu(
    options: &EngineOptions,
    precision: Precision,
) -> Result<(Engine, String), EngineError> {
    match options.device {
        Device::Cpu => unreachable!("Engine::choose builds the CPU engine itself"),
        Device::Gpu => {
            let gpu = GpuEngine::new(GpuContext::new(options.adapter.as_deref())?, precision)?;
            Ok((Engine::Gpu(gpu), "asked for (--device gpu)".into()))
        }
        Device::Auto => {
            let cpu = || Engine::Cpu(CpuEngine::new(options.threads));
            let found = crate::gpu::adapters();
            let hardware: Vec<&str> = found
                .iter()
                .filter(|a| a.device_type != "Cpu")
                .map(|a| a.name.as_str())
                .collect();
            if hardware.is_empty() && options.adapter.is_none() {
                let why = match found.first() {
                    Some(software) => format!(
                        "auto: no hardware GPU (only the software adapter '{}', which runs on these same cores; --device gpu takes it)",
                        software.name
                    ),
                    None => {
                        "auto: no Vulkan adapter (flatport info says what to install)".to_string()
                    }
                };
                return Ok((cpu(), why));
            }
            match GpuContext::new(options.adapter.as_deref())
                .and_then(|context| GpuEngine::new(context, precision))
            {
                Ok(gpu) => {
                    let a = gpu.context().adapter();
                    let why = format!(
                        "auto: the {} GPU '{}', the best of {} adapter(s)",
                        a.device_type.to_lowercase(),
                        a.name,
                        found.len()
                    );
                    Ok((Engine::Gpu(gpu), why))
                }
                Err(error) => Ok((cpu(), format!("auto: the GPU could not be used ({error})"))),
            }
        }
    }
}

/// Rows per block of the `_f32` entry points: 64 Ki rows keep the f64 copies under 4 MiB per
/// block of 8-real rows while a GPU chunk stays large enough to pay for its dispatch.
pub const F32_BLOCK_ROWS: usize = 1 << 16;

/// Runs an f64 batch `run` over f32 rows block by block: widens `input`, narrows the output.
/// Panics if the slices differ in length, as the f64 entry points do.
fn widened<const N: usize, const M: usize>(
    input: &[[f32; N]],
    output: &mut [[f32; M]],
    status: &mut [u32],
    mut run: impl FnMut(&[[f64; N]], &mut [[f64; M]], &mut [u32]) -> Result<(), EngineError>,
) -> Result<(), EngineError> {
    assert!(
        input.len() == output.len() && input.len() == status.len(),
        "input, output and status of equal length"
    );
    let block = F32_BLOCK_ROWS.min(input.len().max(1));
    let (mut wide_in, mut wide_out) = (Vec::with_capacity(block), vec![[0.0; M]; block]);
    for ((rows_in, rows_out), rows_status) in input
        .chunks(block)
        .zip(output.chunks_mut(block))
        .zip(status.chunks_mut(block))
    {
        wide_in.clear();
        wide_in.extend(rows_in.iter().map(|row| row.map(f64::from)));
        let wide_out = &mut wide_out[..rows_in.len()];
        run(&wide_in, wide_out, rows_status)?;
        for (narrow, wide) in rows_out.iter_mut().zip(wide_out.iter()) {
            *narrow = wide.map(|v| v as f32);
        }
    }
    Ok(())
}
