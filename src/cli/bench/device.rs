//! `flatport bench`'s figures of rows that live on the device: matched pixels → 3-D points, rows
//! never on the host between. `chain_triangulate` is the fused kernel
//! (`GpuEngine::triangulate_pixels`: both back-projections and the triangulation in one pass);
//! `chain_triangulate_unfused` the same chain in three kernels and their status merges
//! (`GpuEngine::backproject_rows` in each camera, then `triangulate_rows`, the rays written to
//! device memory and read again). Kernel: the device's time for the chain, the pixels already
//! uploaded (GPU timestamps where the adapter has them); end to end: upload, chain and read-back
//! of the points.

use flatport::engine::GpuEngine;
use flatport::engine::gpu::{Pixels, Triangulated};
use flatport::gpu::{DeviceRows, GpuError};
use flatport::model::RefractiveCamera;

/// The fused chain's label in the report.
pub(super) const LABEL: &str = "chain_triangulate";

/// The three-kernel chain's label in the report.
pub(super) const LABEL_UNFUSED: &str = "chain_triangulate_unfused";

/// Seconds of one chain over `matches` (ul, vl, ur, vr), the fastest of `repeats` runs each.
pub(super) struct ChainSeconds {
    /// The device's time for the kernels, rows on the device.
    pub(super) kernel: f64,
    /// `gpu_timestamp` or `host`: the clock of `kernel`.
    pub(super) timer: &'static str,
    /// Upload of both cameras' pixels, the chain, read-back of the points.
    pub(super) end_to_end: f64,
}

/// The fused chain (`fused`) and the three-kernel chain (`unfused`), measured in turn.
pub(super) struct Chains {
    pub(super) fused: ChainSeconds,
    pub(super) unfused: ChainSeconds,
}

/// Runs both chains on `gpu` with cameras `a` and `b`.
pub(super) fn chains(
    gpu: &GpuEngine,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    repeats: usize,
) -> anyhow::Result<Chains> {
    let fused = |on_a: &DeviceRows<Pixels>, on_b: &DeviceRows<Pixels>| {
        gpu.triangulate_pixels(a, b, on_a, on_b)
    };
    let unfused = |on_a: &DeviceRows<Pixels>, on_b: &DeviceRows<Pixels>| {
        let rays_a = gpu.backproject_rows(a, on_a)?;
        let rays_b = gpu.backproject_rows(b, on_b)?;
        gpu.triangulate_rows(&rays_a, &rays_b)
    };
    Ok(Chains {
        fused: chain(gpu, matches, repeats, fused)?,
        unfused: chain(gpu, matches, repeats, unfused)?,
    })
}

/// Times `run` (pixels of both cameras on the device → points) kernel-side and end to end.
fn chain(
    gpu: &GpuEngine,
    matches: &[[f64; 4]],
    repeats: usize,
    run: impl Fn(&DeviceRows<Pixels>, &DeviceRows<Pixels>) -> Result<DeviceRows<Triangulated>, GpuError>,
) -> anyhow::Result<ChainSeconds> {
    let pixels_a: Vec<[f64; 2]> = matches.iter().map(|m| [m[0], m[1]]).collect();
    let pixels_b: Vec<[f64; 2]> = matches.iter().map(|m| [m[2], m[3]]).collect();
    let on_a = gpu.upload::<Pixels>(&pixels_a)?;
    let on_b = gpu.upload::<Pixels>(&pixels_b)?;
    let (kernel, timer) = gpu.seconds_on_device(repeats, || run(&on_a, &on_b).map(drop))?;
    let end_to_end = super::fastest(repeats, || {
        let on_a = gpu.upload::<Pixels>(&pixels_a)?;
        let on_b = gpu.upload::<Pixels>(&pixels_b)?;
        gpu.read(&run(&on_a, &on_b)?)?;
        Ok(())
    })?;
    Ok(ChainSeconds {
        kernel,
        timer: timer.name(),
        end_to_end,
    })
}
