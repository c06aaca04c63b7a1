//! Host-side mirrors of the WGSL structs, `#[repr(C)]` and Pod for upload.

use bytemuck::{Pod, Zeroable};

use crate::model::RefractiveCamera;

/// Largest number of layers the kernels take (`MAX_LAYERS` in `shaders/common.wgsl`).
pub const MAX_LAYERS: usize = 8;

/// Mirrors `struct Camera` in `shaders/common.wgsl`: keep in sync (a test checks the size).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuCamera {
    /// fx, fy, cx, cy.
    pub intrinsics: [f32; 4],
    /// k1, k2, p1, p2.
    pub distortion: [f32; 4],
    /// k3, fold radius² (1e30 when none), ρ_w, d_k.
    pub extra: [f32; 4],
    /// Rows of R_kᵀ (w unused).
    pub master_from_cam: [[f32; 4]; 3],
    /// C_k (w unused).
    pub centre: [f32; 4],
    /// n (w unused).
    pub normal: [f32; 4],
    /// (tᵢ, ρᵢ, 0, 0) per layer.
    pub layers: [[f32; 4]; MAX_LAYERS],
    /// Layer count, item count, has distortion, unused.
    pub counts: [u32; 4],
}

impl GpuCamera {
    /// Packs a camera for the kernels; `None` when it has more than [`MAX_LAYERS`] layers.
    pub fn new(camera: &RefractiveCamera, items: u32) -> Option<Self> {
        if camera.layers().len() > MAX_LAYERS {
            return None;
        }
        let i = camera.intrinsics();
        let m = camera.master_from_cam();
        let c = camera.centre();
        let n = camera.normal();
        let mut layers = [[0.0f32; 4]; MAX_LAYERS];
        for (slot, layer) in layers.iter_mut().zip(camera.layers()) {
            *slot = [layer.thickness as f32, (layer.index / camera.index_air()) as f32, 0.0, 0.0];
        }
        let fold = camera.fold_radius2();
        Some(Self {
            intrinsics: [i.fx as f32, i.fy as f32, i.cx as f32, i.cy as f32],
            distortion: [i.distortion[0] as f32, i.distortion[1] as f32, i.distortion[2] as f32, i.distortion[3] as f32],
            extra: [
                i.distortion[4] as f32,
                if fold.is_finite() { fold as f32 } else { 1e30 },
                camera.relative_index_water() as f32,
                camera.air_distance() as f32,
            ],
            master_from_cam: [0, 1, 2].map(|r| [m[(r, 0)] as f32, m[(r, 1)] as f32, m[(r, 2)] as f32, 0.0]),
            centre: [c.x as f32, c.y as f32, c.z as f32, 0.0],
            normal: [n.x as f32, n.y as f32, n.z as f32, 0.0],
            layers,
            counts: [camera.layers().len() as u32, items, i.has_distortion() as u32, 0],
        })
    }
}
