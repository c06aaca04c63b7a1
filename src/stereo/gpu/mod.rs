//! Stages 1–7 of the sweep on the GPU (`shaders/stereo/`, one WGSL twin per CPU stage): the
//! reference rays from the pixel grid, the hypothesis points projected into every voter through
//! its port, the warped samples, the windowed ZNCC combined into the cost volume, SGM along every
//! path and the winner-take-all with its refinement. The cost volume and the aggregated costs
//! stay on the device; the images go up once per depth map and only the winners (refined index,
//! quality, distinctness: 12 bytes a pixel) come back, into the same [`Winners`] the CPU's
//! [`winner_take_all`](super::select::winner_take_all) returns, so the rest (depths, points,
//! consistency, confidence) is the CPU path's own code.
//!
//! **Precision.** Everything on the device is f32: the rays, the hypothesis points and their
//! exact projections (f32 Newton, within ~1e-3 px of the f64 reference), the bilinear samples
//! and the ZNCC sums (separable running sums down strips of 16 rows, shifted by a pixel of the
//! strip against cancellation: `shaders/stereo/zncc.wgsl`). The
//! costs are then rounded to the same u16 units as on the CPU, and SGM and the selection are
//! integer arithmetic identical to the CPU's; the host turns the refined index into depth and
//! point in f64 as on the CPU.
//!
//! **Reuse.** The pipelines are compiled once per [`GpuContext`] (its cache); a
//! [`GpuStereo`] keeps its buffers between depth maps of one size, so the frames of a sequence
//! stream through without new pipelines or allocations.

pub mod kernels;

use std::sync::Mutex;

use bytemuck::{Pod, Zeroable};

use super::StereoError;
use super::select::Winners;
use crate::base::GreyImage;
use crate::gpu::compose::{Precision, Rows, WORKGROUP_SIZE};
use crate::gpu::layout::Params;
use crate::gpu::{GpuContext, GpuError};
use crate::model::RefractiveCamera;

/// Most voting cameras of one depth map (`MAX_VOTERS` in `shaders/stereo/sweep.wgsl`).
pub const MAX_VOTERS: usize = 8;
/// Most hypotheses: one SGM line's rows of L, 2·(D + 2) u32, fit the kernel's workgroup memory
/// up to it (`SGM_PREVIOUS`; a test checks every D).
pub const MAX_HYPOTHESES: usize = 1024;
/// Most hypotheses of one warp chunk: bounds the warped samples' buffer.
const MAX_CHUNK: usize = 32;
/// Rows one invocation of the ZNCC kernel walks down its column (`Sweep::strip`): its running
/// sums' rounding grows with the walk, the rows it reads twice (entering and leaving) shrink.
const ZNCC_STRIP: u32 = 16;
/// Workgroup memory (u32) for the rows of L of the SGM lines a workgroup walks together
/// (`PREVIOUS` in `shaders/stereo/sgm.wgsl`): 2·(D + 2) a line.
const SGM_PREVIOUS: usize = 3968;

/// SGM path lines one workgroup walks together (a power of two up to `most`, at most 8, as many
/// as its memory holds for D hypotheses): they share its barriers, which a software adapter pays
/// for every invocation. The kernel's workgroup memory is a fixed 16 KiB whatever D, which on a
/// hardware GPU bounds the workgroups resident at once (an NVIDIA SM holds about 14 of them): a
/// 1280 × 1024 image's 8 directions have about 14 000 lines, in about 1 800 workgroups of 8 lines
/// (one wave on a 132-SM H200) or 7 300 of 2 (four waves). So 8 there too, by reasoning until a
/// GPU has measured it: `flatport bench` prints the 1280 × 1024 figure for 8, 2 and 1 lines.
fn sgm_group_lines(hypotheses: usize, most: u32) -> u32 {
    let mut group = most.min(8);
    while group > 1 && group as usize * 2 * (hypotheses + 2) > SGM_PREVIOUS {
        group /= 2;
    }
    group
}

/// The stereo kernels' uniform; mirrors `struct Sweep` in `shaders/stereo/sweep.wgsl`, keep in
/// sync (80 bytes; a test checks with naga's layouter).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct Sweep {
    width: u32,
    height: u32,
    hypotheses: u32,
    first: u32,
    chunk: u32,
    voters: u32,
    radius: u32,
    voter: u32,
    voter_width: u32,
    voter_height: u32,
    p1: u32,
    p2: u32,
    q0: f32,
    dq: f32,
    min_texture: f32,
    gradient: f32,
    paths: u32,
    strip: u32,
    group_lines: u32,
    pad: u32,
}

/// What one depth map asks of the device.
pub(crate) struct Job<'a> {
    pub cameras: &'a [RefractiveCamera],
    pub images: &'a [GreyImage],
    pub reference: usize,
    /// q₀ and Δq of the hypotheses (1/m).
    pub q0: f64,
    pub dq: f64,
    pub hypotheses: usize,
    pub radius: usize,
    pub min_texture: f64,
    /// SGM's P1 and P2 in cost units, the gradient that halves P2, 8 or 4 paths.
    pub p1: u16,
    pub p2: u16,
    pub gradient: f32,
    pub paths: usize,
}

/// Buffers of one image size, hypothesis count and voter count, reused across depth maps.
struct Buffers {
    key: (usize, usize, usize, usize),
    chunk: usize,
    rays: wgpu::Buffer,
    image: wgpu::Buffer,
    warped: wgpu::Buffer,
    zncc: wgpu::Buffer,
    cost: wgpu::Buffer,
    sum: wgpu::Buffer,
    winners: wgpu::Buffer,
    staging: wgpu::Buffer,
}

/// Dense stereo's GPU stages on one adapter: the context (with its pipeline cache) and the
/// buffers of the last depth map's size.
pub struct GpuStereo {
    context: GpuContext,
    buffers: Mutex<Option<Buffers>>,
    /// SGM path lines a workgroup walks together, where not the default.
    sgm_lines: Option<u32>,
}

fn gpu_error(error: GpuError) -> StereoError {
    StereoError::Gpu(error.to_string())
}

impl GpuStereo {
    /// Opens the adapter `name` names (as [`GpuContext::new`]).
    ///
    /// Errors: [`StereoError::Gpu`] when there is no such adapter.
    pub fn new(name: Option<&str>) -> Result<Self, StereoError> {
        Ok(Self::from_context(
            GpuContext::new(name).map_err(gpu_error)?,
        ))
    }

    /// On an open context.
    pub fn from_context(context: GpuContext) -> Self {
        Self {
            context,
            buffers: Mutex::new(None),
            sgm_lines: None,
        }
    }

    /// With SGM walking `lines` path lines per workgroup (1, 2, 4 or 8; fewer where D hypotheses
    /// do not fit its memory) instead of the default, 8. The depths do not depend on it (integer sums); tests use it to run every
    /// grouping on one adapter, and it is there to tune a GPU.
    ///
    /// Panics when `lines` is not 1, 2, 4 or 8.
    pub fn with_sgm_lines(mut self, lines: u32) -> Self {
        assert!(
            matches!(lines, 1 | 2 | 4 | 8),
            "SGM lines per workgroup: 1, 2, 4 or 8, got {lines}"
        );
        self.sgm_lines = Some(lines);
        self
    }

    /// The context.
    pub fn context(&self) -> &GpuContext {
        &self.context
    }

    /// Bytes of the cost volume (and of the aggregated costs) of `width` × `height` pixels and
    /// `hypotheses` hypotheses on the device: two u16 a u32 word, ⌈D/2⌉ words a pixel
    /// (`volume_word` in `shaders/stereo/sweep.wgsl`).
    pub fn volume_bytes(width: usize, height: usize, hypotheses: usize) -> u64 {
        (width * height * hypotheses.div_ceil(2) * 4) as u64
    }

    /// Why a depth map of `width` × `height` pixels, `hypotheses` hypotheses and `voters` voting
    /// cameras does not fit this adapter, if it does not: the cost volume and the aggregated
    /// costs are each one storage binding of W·H·D u16 ([`Self::volume_bytes`]).
    pub fn refuses(
        &self,
        width: usize,
        height: usize,
        hypotheses: usize,
        voters: usize,
    ) -> Option<String> {
        let volume = Self::volume_bytes(width, height, hypotheses);
        let cap = self.context.max_storage_binding();
        if voters > MAX_VOTERS {
            Some(format!(
                "{voters} voting cameras: the GPU stereo takes at most {MAX_VOTERS}"
            ))
        } else if hypotheses > MAX_HYPOTHESES {
            Some(format!(
                "{hypotheses} hypotheses: the GPU stereo takes at most {MAX_HYPOTHESES}"
            ))
        } else if volume > cap {
            Some(format!(
                "the cost volume of {width} × {height} pixels × {hypotheses} hypotheses is {} MiB, over the adapter's largest storage binding of {} MiB ({}); use fewer hypotheses, smaller images or --device cpu",
                volume >> 20,
                cap >> 20,
                self.context.adapter().name
            ))
        } else {
            None
        }
    }

    fn storage(&self, label: &str, bytes: u64, read: bool) -> Result<wgpu::Buffer, StereoError> {
        let mut usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        if read {
            usage |= wgpu::BufferUsages::COPY_SRC;
        }
        self.context
            .buffer(label, bytes.max(4), usage)
            .map_err(gpu_error)
    }

    fn uniform(&self, sweep: &Sweep) -> Result<wgpu::Buffer, StereoError> {
        let buffer = self
            .context
            .buffer(
                "stereo sweep",
                std::mem::size_of::<Sweep>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            )
            .map_err(gpu_error)?;
        self.context
            .queue()
            .write_buffer(&buffer, 0, bytemuck::bytes_of(sweep));
        Ok(buffer)
    }

    fn params(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
    ) -> Result<(wgpu::Buffer, u32), StereoError> {
        let params = Params::new(Precision::F32, a, b, [0; 4]);
        let buffer = self
            .context
            .buffer(
                "stereo params",
                params.bytes().len() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            )
            .map_err(gpu_error)?;
        self.context
            .queue()
            .write_buffer(&buffer, 0, params.bytes());
        Ok((buffer, params.layers()))
    }

    /// Stages 1–7 for `job`: the winners of every reference pixel, and the seconds of stages 1–5
    /// (the cost volume) and 6–7 (aggregation and selection, with the read-back).
    /// `report(done, total)` after each chunk of hypotheses.
    pub(crate) fn winners(
        &self,
        job: &Job,
        report: &dyn Fn(usize, usize),
    ) -> Result<(Winners, [f64; 2]), StereoError> {
        let started = std::time::Instant::now();
        let reference = &job.cameras[job.reference];
        let (w, h) = (
            reference.intrinsics().width as usize,
            reference.intrinsics().height as usize,
        );
        let d = job.hypotheses;
        let voters: Vec<usize> = (0..job.cameras.len())
            .filter(|&k| k != job.reference)
            .collect();
        if let Some(reason) = self.refuses(w, h, d, voters.len()) {
            return Err(StereoError::Gpu(reason));
        }
        let cap = self.context.max_storage_binding() as usize;
        let plane = w * h * 4;
        let chunk = (cap / (plane * voters.len())).clamp(1, MAX_CHUNK).min(d);
        let key = (w, h, d, voters.len());
        let mut slot = self.buffers.lock().unwrap_or_else(|p| p.into_inner());
        if slot.as_ref().map(|b| b.key) != Some(key) {
            *slot = None;
            let volume = Self::volume_bytes(w, h, d);
            let staging = self
                .context
                .buffer(
                    "stereo winners staging",
                    (w * h * 12) as u64,
                    wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                )
                .map_err(gpu_error)?;
            *slot = Some(Buffers {
                key,
                chunk,
                rays: self.storage("stereo rays", (w * h * 32) as u64, false)?,
                image: self.storage("stereo reference image", plane as u64, false)?,
                warped: self.storage(
                    "stereo warped samples",
                    (plane * chunk * voters.len()) as u64,
                    false,
                )?,
                zncc: self.storage(
                    "stereo ZNCC per voter",
                    (plane * chunk * voters.len()) as u64,
                    false,
                )?,
                cost: self.storage("stereo cost volume", volume, false)?,
                sum: self.storage("stereo aggregated costs", volume, false)?,
                winners: self.storage("stereo winners", (w * h * 12) as u64, true)?,
                staging,
            });
        }
        let buffers = slot.as_ref().expect("allocated above");
        let chunk = buffers.chunk;
        let queue = self.context.queue();
        queue.write_buffer(
            &buffers.image,
            0,
            bytemuck::cast_slice(&job.images[job.reference].pixels),
        );
        let mut voter_images = Vec::with_capacity(voters.len());
        for &k in &voters {
            let image = &job.images[k];
            let buffer =
                self.storage("stereo voter image", (image.pixels.len() * 4) as u64, false)?;
            queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&image.pixels));
            voter_images.push(buffer);
        }
        let base = Sweep {
            width: w as u32,
            height: h as u32,
            hypotheses: d as u32,
            first: 0,
            chunk: chunk as u32,
            voters: voters.len() as u32,
            radius: job.radius as u32,
            p1: u32::from(job.p1),
            p2: u32::from(job.p2),
            q0: job.q0 as f32,
            dq: job.dq as f32,
            min_texture: job.min_texture as f32,
            gradient: job.gradient,
            strip: ZNCC_STRIP,
            ..Sweep::default()
        };
        let layers = job
            .cameras
            .iter()
            .map(|c| c.layers().len() as u32)
            .max()
            .unwrap_or(0);
        let pipeline = |kernel| {
            self.context
                .kernel_pipeline(kernel, Precision::F32, Rows::Storage, layers)
                .map_err(gpu_error)
        };
        let (rays_p, warp_p, zncc_p, cost_p, sgm_p, select_p) = (
            pipeline(&kernels::RAYS)?,
            pipeline(&kernels::WARP)?,
            pipeline(&kernels::ZNCC)?,
            pipeline(&kernels::COST)?,
            pipeline(&kernels::SGM)?,
            pipeline(&kernels::SELECT)?,
        );
        let bind = |pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
            let entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .map(|&(binding, buffer)| wgpu::BindGroupEntry {
                    binding,
                    resource: buffer.as_entire_binding(),
                })
                .collect();
            self.context
                .device()
                .create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("stereo"),
                    layout: &pipeline.get_bind_group_layout(0),
                    entries: &entries,
                })
        };
        let groups_x = (w as u32).div_ceil(WORKGROUP_SIZE);
        let encoder = |label: &str| {
            self.context
                .device()
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
        };
        // Dispatches in order in one compute pass (wgpu orders those that write and read one
        // buffer).
        let dispatch =
            |encoder: &mut wgpu::CommandEncoder,
             label: &str,
             passes: &[(&wgpu::ComputePipeline, &wgpu::BindGroup, [u32; 3])]| {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some(label),
                    timestamp_writes: None,
                });
                for &(pipeline, group, [x, y, z]) in passes {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, group, &[]);
                    pass.dispatch_workgroups(x, y, z);
                }
            };

        // Stage 1: the rays.
        let (reference_params, _) = self.params(reference, reference)?;
        let general = self.uniform(&base)?;
        let group = bind(
            &rays_p,
            &[(0, &reference_params), (1, &general), (2, &buffers.rays)],
        );
        // The cost volume cleared (the cost kernel ORs each hypothesis into its half of a word),
        // then the rays.
        let mut first = encoder("stereo rays");
        first.clear_buffer(&buffers.cost, 0, None);
        dispatch(
            &mut first,
            "stereo rays",
            &[(&rays_p, &group, [groups_x, h as u32, 1])],
        );
        queue.submit([first.finish()]);

        // Stages 2–5, a chunk of hypotheses at a time: warp per voter, then the costs.
        let mut warp_groups = Vec::with_capacity(voters.len());
        let mut warp_uniforms = Vec::with_capacity(voters.len());
        for (v, &k) in voters.iter().enumerate() {
            let camera = &job.cameras[k];
            let (params, _) = self.params(reference, camera)?;
            let sweep = Sweep {
                voter: v as u32,
                voter_width: camera.intrinsics().width,
                voter_height: camera.intrinsics().height,
                ..base
            };
            let uniform = self.uniform(&sweep)?;
            warp_groups.push(bind(
                &warp_p,
                &[
                    (0, &params),
                    (1, &uniform),
                    (2, &buffers.rays),
                    (4, &voter_images[v]),
                    (5, &buffers.warped),
                ],
            ));
            warp_uniforms.push((uniform, sweep));
        }
        let zncc_group = bind(
            &zncc_p,
            &[
                (1, &general),
                (3, &buffers.image),
                (5, &buffers.warped),
                (9, &buffers.zncc),
            ],
        );
        let cost_group = bind(
            &cost_p,
            &[(1, &general), (6, &buffers.cost), (9, &buffers.zncc)],
        );
        let strips = (h as u32).div_ceil(ZNCC_STRIP);
        let chunks = d.div_ceil(chunk);
        for c in 0..chunks {
            let first = (c * chunk) as u32;
            for (uniform, sweep) in &warp_uniforms {
                queue.write_buffer(uniform, 0, bytemuck::bytes_of(&Sweep { first, ..*sweep }));
            }
            queue.write_buffer(&general, 0, bytemuck::bytes_of(&Sweep { first, ..base }));
            let pairs = (chunk as u32).div_ceil(2);
            let mut passes: Vec<(&wgpu::ComputePipeline, &wgpu::BindGroup, [u32; 3])> = warp_groups
                .iter()
                .map(|g| (&*warp_p, g, [groups_x, h as u32, pairs]))
                .collect();
            let votes = (voters.len() * chunk) as u32;
            passes.push((&*zncc_p, &zncc_group, [groups_x, strips, votes]));
            passes.push((&*cost_p, &cost_group, [groups_x, h as u32, chunk as u32]));
            let mut encoder = encoder("stereo sweep");
            dispatch(&mut encoder, "stereo sweep", &passes);
            let index = queue.submit([encoder.finish()]);
            self.context.wait_for(Some(index)).map_err(gpu_error)?;
            self.context
                .check("the stereo cost volume")
                .map_err(gpu_error)?;
            report(c + 1, chunks);
        }

        let cost_seconds = started.elapsed().as_secs_f64();
        let started = std::time::Instant::now();
        // Stage 6: SGM, every path direction in one dispatch (a row of workgroups per
        // direction, their L added to the sum atomically), then stage 7.
        let paths: u32 = if job.paths >= 8 { 8 } else { 4 };
        let group_lines = sgm_group_lines(
            d,
            self.sgm_lines
                .unwrap_or(if self.context.is_software() { 8 } else { 2 }),
        );
        let sgm_uniform = self.uniform(&Sweep {
            paths,
            group_lines,
            ..base
        })?;
        let lines = (if paths == 8 { w + h - 1 } else { w.max(h) } as u32).div_ceil(group_lines);
        let sgm_group = bind(
            &sgm_p,
            &[
                (1, &sgm_uniform),
                (3, &buffers.image),
                (6, &buffers.cost),
                (7, &buffers.sum),
            ],
        );
        let select_group = bind(
            &select_p,
            &[
                (1, &general),
                (6, &buffers.cost),
                (7, &buffers.sum),
                (8, &buffers.winners),
            ],
        );
        let mut encoder = encoder("stereo aggregation");
        encoder.clear_buffer(&buffers.sum, 0, None);
        dispatch(
            &mut encoder,
            "stereo aggregation",
            &[
                (&sgm_p, &sgm_group, [lines, paths, 1]),
                (&select_p, &select_group, [groups_x, h as u32, 1]),
            ],
        );
        let bytes = (w * h * 12) as u64;
        let values: Vec<f32> = self
            .context
            .read_back(
                encoder,
                &[(&buffers.winners, &buffers.staging, bytes)],
                |slices| bytemuck::cast_slice::<u8, f32>(slices[0]).to_vec(),
            )
            .map_err(gpu_error)?;
        self.context
            .check("the stereo aggregation")
            .map_err(gpu_error)?;
        let mut winners = Winners {
            index: Vec::with_capacity(w * h),
            quality: Vec::with_capacity(w * h),
            distinctness: Vec::with_capacity(w * h),
        };
        for v in values.chunks_exact(3) {
            winners
                .index
                .push(if v[0] >= 0.0 { v[0] } else { f32::NAN });
            winners.quality.push(v[1]);
            winners.distinctness.push(v[2]);
        }
        Ok((winners, [cost_seconds, started.elapsed().as_secs_f64()]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every hypothesis count and grouping the host can choose fits the lines' rows of L in the
    /// kernel's workgroup memory, with every line at least one invocation.
    #[test]
    fn every_sgm_grouping_fits_the_kernel() {
        for d in 3..=MAX_HYPOTHESES {
            for most in [1, 2, 4, 8] {
                let lines = sgm_group_lines(d, most) as usize;
                assert!(
                    lines.is_power_of_two() && lines <= most as usize,
                    "{d} {most}: {lines}"
                );
                assert!(lines * 2 * (d + 2) <= SGM_PREVIOUS, "{d} {most}: {lines}");
                assert!(lines <= WORKGROUP_SIZE as usize, "{d} {most}: {lines}");
            }
        }
        // The default fills the memory: 8 lines up to 246 hypotheses, one at 1024.
        assert_eq!(sgm_group_lines(246, 8), 8);
        assert_eq!(sgm_group_lines(247, 8), 4);
        assert_eq!(sgm_group_lines(1024, 8), 1);
    }
}
