//! `flatport bench`'s figure of rows that live on the device: matched pixels → back-projection
//! in both cameras → triangulation, the rays never on the host (`GpuEngine::backproject_rows`,
//! `triangulate_rows`). Kernel: the device's time for the chain, the pixels already uploaded
//! (GPU timestamps where the adapter has them); end to end: upload, chain and read-back of the
//! points.

use flatport::engine::GpuEngine;
use flatport::engine::gpu::Pixels;
use flatport::model::RefractiveCamera;

/// The figure's label in the report.
pub(super) const LABEL: &str = "chain_triangulate";

/// Seconds of the chain over `matches` (ul, vl, ur, vr), the fastest of `repeats` runs each.
pub(super) struct ChainSeconds {
    /// The device's time for the kernels, rows on the device.
    pub(super) kernel: f64,
    /// `gpu_timestamp` or `host`: the clock of `kernel`.
    pub(super) timer: &'static str,
    /// Upload of both cameras' pixels, the chain, read-back of the points.
    pub(super) end_to_end: f64,
}

/// Runs the chain on `gpu` with cameras `a` and `b`.
pub(super) fn chain(
    gpu: &GpuEngine,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    repeats: usize,
) -> anyhow::Result<ChainSeconds> {
    let pixels_a: Vec<[f64; 2]> = matches.iter().map(|m| [m[0], m[1]]).collect();
    let pixels_b: Vec<[f64; 2]> = matches.iter().map(|m| [m[2], m[3]]).collect();
    let on_a = gpu.upload::<Pixels>(&pixels_a)?;
    let on_b = gpu.upload::<Pixels>(&pixels_b)?;
    let (kernel, timer) = gpu.seconds_on_device(repeats, || {
        let rays_a = gpu.backproject_rows(a, &on_a)?;
        let rays_b = gpu.backproject_rows(b, &on_b)?;
        gpu.triangulate_rows(&rays_a, &rays_b).map(drop)
    })?;
    let end_to_end = super::fastest(repeats, || {
        let on_a = gpu.upload::<Pixels>(&pixels_a)?;
        let on_b = gpu.upload::<Pixels>(&pixels_b)?;
        let rays_a = gpu.backproject_rows(a, &on_a)?;
        let rays_b = gpu.backproject_rows(b, &on_b)?;
        gpu.read(&gpu.triangulate_rows(&rays_a, &rays_b)?)?;
        Ok(())
    })?;
    Ok(ChainSeconds {
        kernel,
        timer: timer.name(),
        end_to_end,
    })
}
