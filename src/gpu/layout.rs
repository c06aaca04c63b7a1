//! Host mirrors of the WGSL uniform `Params` of `shaders/common.wgsl` (`cams`: two `Camera`s, and
//! the dispatch description), in f32 and f64: `#[repr(C)]` [`Pod`] structs over glam vectors whose
//! bytes are the uniform's. WGSL lays a struct of vec4s out without holes; only the struct's
//! alignment (that of a vec4 of reals: 16 bytes in f32, 32 in f64) pads its end, which the mirrors
//! spell as an `end_padding` field (empty in f32). The field order lives in `mirrors!` only;
//! `tests/gpu.rs` compares sizes and field offsets with naga's layouter for both precisions.

use bytemuck::{Pod, Zeroable};
use glam::{DVec4, UVec4, Vec4};

use super::shaders::Precision;
use crate::model::RefractiveCamera;

/// Largest number of layers the kernels take (`MAX_LAYERS` in `shaders/common.wgsl`).
pub const MAX_LAYERS: usize = 8;

/// A vec4 of reals in a kernel precision, from f64 values (rounded to nearest in f32).
trait Real4 {
    fn from_f64s(values: [f64; 4]) -> Self;
}

impl Real4 for Vec4 {
    fn from_f64s([x, y, z, w]: [f64; 4]) -> Self {
        Vec4::new(x as f32, y as f32, z as f32, w as f32)
    }
}

impl Real4 for DVec4 {
    fn from_f64s(values: [f64; 4]) -> Self {
        DVec4::from_array(values)
    }
}

/// Defines the host mirrors of `Camera` and `Params` for one precision (`$real4` the vec4 of
/// reals, `$padding` what WGSL adds at the end of each struct) and the one function that fills each.
macro_rules! mirrors {
    ($precision:expr, $real:literal, $real4:ty, $padding:ty, $camera:ident, $params:ident) => {
        #[doc = concat!("Mirrors `struct Camera` in shaders/common.wgsl in ", $real, " — keep in sync.")]
        ///
        /// One camera behind the interface, master frame.
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
        pub struct $camera {
            /// fx, fy, cx, cy.
            pub intrinsics: $real4,
            /// k1, k2, p1, p2.
            pub distortion: $real4,
            /// k3, fold radius² (`REAL_HUGE` when none), ρ_w = μ_w/μ_air, d_k.
            pub extra: $real4,
            /// Row 0 of R_kᵀ (w = 0).
            pub master_from_cam0: $real4,
            /// Row 1 of R_kᵀ (w = 0).
            pub master_from_cam1: $real4,
            /// Row 2 of R_kᵀ (w = 0).
            pub master_from_cam2: $real4,
            /// C_k, w = Σ tᵢ.
            pub centre: $real4,
            /// n, w = 0.
            pub normal: $real4,
            /// (tᵢ, ρᵢ = μᵢ/μ_air, 0, 0) per layer, zeros past the layer count.
            pub layers: [$real4; MAX_LAYERS],
            /// Layer count, has distortion (0 or 1), 0, 0.
            pub counts: UVec4,
            /// WGSL's padding of the struct's end to the alignment of a vec4 of reals.
            pub end_padding: $padding,
        }

        impl $camera {
            /// `camera` as the kernels read it. The caller has checked the layer count.
            fn new(camera: &RefractiveCamera) -> Self {
                let i = camera.intrinsics();
                let m = camera.master_from_cam();
                let c = camera.centre();
                let n = camera.normal();
                let fold = camera.fold_radius2();
                let fold = if fold.is_finite() { fold } else { $precision.huge() };
                let thickness: f64 = camera.layers().iter().map(|l| l.thickness).sum();
                let row = |r: usize| <$real4>::from_f64s([m[(r, 0)], m[(r, 1)], m[(r, 2)], 0.0]);
                let mut layers = [<$real4>::ZERO; MAX_LAYERS];
                for (slot, layer) in layers.iter_mut().zip(camera.layers()) {
                    *slot = <$real4>::from_f64s([layer.thickness, layer.index / camera.index_air(), 0.0, 0.0]);
                }
                Self {
                    intrinsics: <$real4>::from_f64s([i.fx, i.fy, i.cx, i.cy]),
                    distortion: <$real4>::from_f64s([i.distortion[0], i.distortion[1], i.distortion[2], i.distortion[3]]),
                    extra: <$real4>::from_f64s([i.distortion[4], fold, camera.relative_index_water(), camera.air_distance()]),
                    master_from_cam0: row(0),
                    master_from_cam1: row(1),
                    master_from_cam2: row(2),
                    centre: <$real4>::from_f64s([c.x, c.y, c.z, thickness]),
                    normal: <$real4>::from_f64s([n.x, n.y, n.z, 0.0]),
                    layers,
                    counts: UVec4::new(camera.layers().len() as u32, i.has_distortion() as u32, 0, 0),
                    end_padding: Zeroable::zeroed(),
                }
            }
        }

        #[doc = concat!("Mirrors `struct Params` in shaders/common.wgsl in ", $real, " — keep in sync.")]
        ///
        /// The uniform of every kernel: one or two cameras and the dispatch description.
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
        pub struct $params {
            /// The cameras (the second = the first for one-camera kernels).
            pub cams: [$camera; 2],
            /// Items in this dispatch, then per kernel: grid width, first grid row, …
            pub info: UVec4,
            /// WGSL's padding of the struct's end to the alignment of a vec4 of reals.
            pub end_padding: $padding,
        }

        impl $params {
            /// The uniform for cameras `a` and `b` and `info`. The caller has checked the layer counts.
            fn new(a: &RefractiveCamera, b: &RefractiveCamera, info: [u32; 4]) -> Self {
                Self { cams: [<$camera>::new(a), <$camera>::new(b)], info: UVec4::from_array(info), end_padding: Zeroable::zeroed() }
            }
        }
    };
}

mirrors!(Precision::F32, "f32", Vec4, [u32; 0], CameraF32, ParamsF32);
mirrors!(Precision::F64, "f64", DVec4, UVec4, CameraF64, ParamsF64);

/// The uniform `Params` of a kernel in its precision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Params {
    /// f32 kernels.
    F32(ParamsF32),
    /// f64 kernels.
    F64(ParamsF64),
}

impl Params {
    /// The uniform for cameras `a` and `b` (`b` = `a` for one-camera kernels) and `info` = (items,
    /// then per kernel: grid width, first grid row, …).
    ///
    /// Panics if a camera has more than [`MAX_LAYERS`] layers (the engine checks first).
    pub fn new(precision: Precision, a: &RefractiveCamera, b: &RefractiveCamera, info: [u32; 4]) -> Self {
        assert!(a.layers().len() <= MAX_LAYERS && b.layers().len() <= MAX_LAYERS, "layer count checked by the engine");
        match precision {
            Precision::F32 => Self::F32(ParamsF32::new(a, b, info)),
            Precision::F64 => Self::F64(ParamsF64::new(a, b, info)),
        }
    }

    /// Replaces `info`.
    pub fn set_info(&mut self, info: [u32; 4]) {
        match self {
            Self::F32(params) => params.info = UVec4::from_array(info),
            Self::F64(params) => params.info = UVec4::from_array(info),
        }
    }

    /// The bytes of the uniform buffer.
    pub fn bytes(&self) -> &[u8] {
        match self {
            Self::F32(params) => bytemuck::bytes_of(params),
            Self::F64(params) => bytemuck::bytes_of(params),
        }
    }
}

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
