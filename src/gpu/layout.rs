//! Host-side packing of the WGSL uniform `Params` (`cams`: two `Camera`s, and the dispatch description) of
//! `shaders/common.wgsl`, in f32 or f64. WGSL lays a struct of vec4s out without holes; only the
//! struct's alignment (that of a vec4: 16 bytes in f32, 32 in f64) pads its end. A test compares
//! these sizes and offsets with naga's layouter.

use super::shaders::Precision;
use crate::model::RefractiveCamera;

/// Largest number of layers the kernels take (`MAX_LAYERS` in `shaders/common.wgsl`).
pub const MAX_LAYERS: usize = 8;

/// Number of vec4 slots of reals in `Camera` before `counts`.
const CAMERA_REAL4: usize = 8 + MAX_LAYERS;

/// Alignment of `Camera` and `Params`: that of a vec4 of reals.
fn align(precision: Precision) -> usize {
    4 * precision.size()
}

/// Size of WGSL `Camera` in bytes.
pub fn camera_size(precision: Precision) -> usize {
    (CAMERA_REAL4 * 4 * precision.size() + 16).next_multiple_of(align(precision))
}

/// Size of WGSL `Params` in bytes, the offset of its second camera (`cams[1]`) and of `info`.
pub fn params_layout(precision: Precision) -> (usize, usize, usize) {
    let camera = camera_size(precision);
    ((2 * camera + 16).next_multiple_of(align(precision)), camera, 2 * camera)
}

/// Appends reals in the kernel's precision.
fn push_reals(bytes: &mut Vec<u8>, precision: Precision, values: &[f64]) {
    for &v in values {
        match precision {
            Precision::F32 => bytes.extend_from_slice(&(v as f32).to_le_bytes()),
            Precision::F64 => bytes.extend_from_slice(&v.to_le_bytes()),
        }
    }
}

/// Appends `camera` as a WGSL `Camera`. The caller has checked the layer count.
fn push_camera(bytes: &mut Vec<u8>, precision: Precision, camera: &RefractiveCamera) {
    let start = bytes.len();
    let i = camera.intrinsics();
    let m = camera.master_from_cam();
    let c = camera.centre();
    let n = camera.normal();
    let fold = camera.fold_radius2();
    let thickness: f64 = camera.layers().iter().map(|l| l.thickness).sum();
    let mut reals = vec![
        i.fx,
        i.fy,
        i.cx,
        i.cy,
        i.distortion[0],
        i.distortion[1],
        i.distortion[2],
        i.distortion[3],
        i.distortion[4],
        if fold.is_finite() { fold } else { precision.huge() },
        camera.relative_index_water(),
        camera.air_distance(),
    ];
    for r in 0..3 {
        reals.extend([m[(r, 0)], m[(r, 1)], m[(r, 2)], 0.0]);
    }
    reals.extend([c.x, c.y, c.z, thickness, n.x, n.y, n.z, 0.0]);
    for k in 0..MAX_LAYERS {
        match camera.layers().get(k) {
            Some(layer) => reals.extend([layer.thickness, layer.index / camera.index_air(), 0.0, 0.0]),
            None => reals.extend([0.0; 4]),
        }
    }
    push_reals(bytes, precision, &reals);
    for count in [camera.layers().len() as u32, i.has_distortion() as u32, 0, 0] {
        bytes.extend_from_slice(&count.to_le_bytes());
    }
    bytes.resize(start + camera_size(precision), 0);
}

/// The bytes of WGSL `Params` for cameras `a` and `b` (`b` = `a` for one-camera kernels) and
/// `info` = (items, grid width, first grid row, 0).
///
/// Panics if a camera has more than [`MAX_LAYERS`] layers (the engine checks first).
pub fn pack_params(precision: Precision, a: &RefractiveCamera, b: &RefractiveCamera, info: [u32; 4]) -> Vec<u8> {
    assert!(a.layers().len() <= MAX_LAYERS && b.layers().len() <= MAX_LAYERS, "layer count checked by the engine");
    let (size, _, _) = params_layout(precision);
    let mut bytes = Vec::with_capacity(size);
    push_camera(&mut bytes, precision, a);
    push_camera(&mut bytes, precision, b);
    for v in info {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes.resize(size, 0);
    bytes
}

/// Overwrites `info` in packed params.
pub fn set_info(params: &mut [u8], precision: Precision, info: [u32; 4]) {
    let (_, _, offset) = params_layout(precision);
    for (k, v) in info.iter().enumerate() {
        params[offset + 4 * k..offset + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
    }
}
