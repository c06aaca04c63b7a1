//! Ray maps: the water ray of every pixel of an image, the fast path for pipelines that
//! back-project whole images every frame. On the GPU the pixels are generated in the shader
//! (`shaders/kernels/backproject_grid.wgsl`: no pixel buffer goes up); on the CPU they are the
//! same grid handed to the f64 reference.

use super::{Engine, EngineError};
use crate::model::RefractiveCamera;

/// Rays of the image rows `first_row .. first_row + rows` of `camera` (pixel (u, v) = (column,
/// row), flatport's convention: (0, 0) is the centre of the top-left pixel), row-major:
/// `rays[i]` belongs to pixel (i mod width, first_row + i div width), with the image's width.
/// Rows and status as [`Engine::backproject`]: origin on the outer interface and unit direction
/// in the water, master frame; a pixel without a ray is NaN with its status code.
///
/// Panics if `rays` or `status` is not `width · rows` long.
pub fn backproject_rows(
    engine: &Engine,
    camera: &RefractiveCamera,
    first_row: u32,
    rows: u32,
    rays: &mut [[f64; 6]],
    status: &mut [u32],
) -> Result<(), EngineError> {
    let width = camera.intrinsics().width;
    match engine {
        #[cfg(feature = "gpu")]
        Engine::Gpu(gpu) => {
            Ok(gpu.backproject_grid_rows(camera, width, first_row, rows, rays, status)?)
        }
        Engine::Cpu(_) => {
            let pixels: Vec<[f64; 2]> = (first_row..first_row + rows)
                .flat_map(|v| (0..width).map(move |u| [f64::from(u), f64::from(v)]))
                .collect();
            engine.backproject(camera, &pixels, rays, status)
        }
    }
}

/// Image rows per band of [`backproject_rows`] that keep a band near `pixels` pixels (at least
/// one row).
pub fn rows_per_band(width: u32, pixels: usize) -> u32 {
    (pixels / (width.max(1) as usize)).clamp(1, u32::MAX as usize) as u32
}
