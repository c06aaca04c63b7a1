//! Back-projection on the GPU (f32): twin of [`RefractiveCamera::backproject`].

use wgpu::util::DeviceExt;

use super::context::{GpuContext, GpuError};
use super::layout::{GpuCamera, MAX_LAYERS};
use super::shaders;
use crate::model::RefractiveCamera;

/// Items per dispatch: 4 Mi pixels (32 MiB in, 96 MiB of rays out) stays under lavapipe's
/// 128 MiB storage-binding cap.
pub const CHUNK_ITEMS: usize = 1 << 22;

/// The compiled back-projection kernel.
pub struct GpuBackproject {
    pipeline: wgpu::ComputePipeline,
}

impl GpuBackproject {
    /// Compiles the kernel on `context`.
    pub fn new(context: &GpuContext) -> Self {
        Self { pipeline: context.pipeline("backproject", shaders::BACKPROJECT) }
    }

    /// Back-projects `pixels` (raw, distorted) of `camera` into `rays` (origin xyz, unit direction
    /// xyz, master frame) and `status` (0, or the [`NoSolution`](crate::model::NoSolution) code
    /// of the CPU path). The three slices must have the same length. Rows with a non-zero status
    /// are left untouched in `rays`.
    pub fn run(
        &self,
        context: &GpuContext,
        camera: &RefractiveCamera,
        pixels: &[[f32; 2]],
        rays: &mut [[f32; 6]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        assert!(pixels.len() == rays.len() && pixels.len() == status.len(), "slices of equal length");
        if camera.layers().len() > MAX_LAYERS {
            return Err(GpuError::Unsupported(format!(
                "the GPU kernels take at most {MAX_LAYERS} layers, this interface has {}",
                camera.layers().len()
            )));
        }
        let device = &context.device;
        let chunk = CHUNK_ITEMS.min(pixels.len()).max(1);
        let storage = |label: &str, bytes: usize, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: bytes as u64, usage, mapped_at_creation: false })
        };
        use wgpu::BufferUsages as U;
        let pixel_buffer = storage("pixels", chunk * 8, U::STORAGE | U::COPY_DST);
        let ray_buffer = storage("rays", chunk * 24, U::STORAGE | U::COPY_SRC);
        let status_buffer = storage("status", chunk * 4, U::STORAGE | U::COPY_SRC);
        let ray_staging = storage("rays staging", chunk * 24, U::MAP_READ | U::COPY_DST);
        let status_staging = storage("status staging", chunk * 4, U::MAP_READ | U::COPY_DST);

        for start in (0..pixels.len()).step_by(chunk) {
            let end = (start + chunk).min(pixels.len());
            let items = (end - start) as u32;
            let gpu_camera = GpuCamera::new(camera, items).expect("layer count checked above");
            let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("camera"),
                contents: bytemuck::bytes_of(&gpu_camera),
                usage: U::UNIFORM,
            });
            context.queue.write_buffer(&pixel_buffer, 0, bytemuck::cast_slice(&pixels[start..end]));
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("backproject"),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: pixel_buffer.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: ray_buffer.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: status_buffer.as_entire_binding() },
                ],
            });
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("backproject") });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("backproject"), timestamp_writes: None });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                let (x, y) = context.dispatch_size(items);
                pass.dispatch_workgroups(x, y, 1);
            }
            let n = items as u64;
            let data = context.read_back(encoder, &[(&ray_buffer, &ray_staging, n * 24), (&status_buffer, &status_staging, n * 4)])?;
            status[start..end].copy_from_slice(bytemuck::cast_slice(&data[1]));
            let out: &[[f32; 6]] = bytemuck::cast_slice(&data[0]);
            for ((row, s), value) in rays[start..end].iter_mut().zip(&status[start..end]).zip(out) {
                if *s == 0 {
                    *row = *value;
                }
            }
        }
        Ok(())
    }
}
