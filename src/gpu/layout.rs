//! Host mirrors of the WGSL uniform `Params` of `shaders/common.wgsl` (`cams`: two `Camera`s, and
//! the dispatch description), in f32 and f64: `#[repr(C)]` [`Pod`] structs over glam vectors whose
//! bytes are the uniform's. WGSL lays a struct of vec4s out without holes; only the struct's
//! alignment (that of a vec4 of reals: 16 bytes in f32, 32 in f64) pads its end, which the mirrors
//! spell as an `end_padding` field (empty in f32). The field order lives in `mirrors!` only;
//! `tests/gpu.rs` compares sizes and field offsets with naga's layouter for both precisions.

use bytemuck::{Pod, Zeroable};
use glam::{DVec4, UVec4, Vec4};

use super::compose::Precision;
use super::context::GpuError;
use crate::model::RefractiveCamera;

/// Largest number of layers the kernels take (`MAX_LAYERS` in `shaders/common.wgsl`).
pub const MAX_LAYERS: usize = 8;

/// Refuses a camera behind more than [`MAX_LAYERS`] layers, which no kernel takes.
pub(crate) fn check_layers(camera: &RefractiveCamera) -> Result<(), GpuError> {
    if camera.layers().len() > MAX_LAYERS {
        return Err(GpuError::Unsupported(format!(
            "the GPU kernels take at most {MAX_LAYERS} layers, this interface has {}",
            camera.layers().len()
        )));
    }
    Ok(())
}

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
            /// (tᵢ, ρᵢ = μᵢ/μ_air, 1/ρᵢ, 0) per layer, zeros past the layer count.
            pub layers: [$real4; MAX_LAYERS],
            /// Layer count, has distortion (0 or 1), no medium less dense than air (0 or 1), port
            /// held (1: a candidate interface does not move this camera's port; see
            /// [`Params::hold_port`]).
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
                // No medium less dense than the air around the camera (`project_near_pair`'s condition).
                let dense = camera.relative_index_water() >= 1.0
                    && camera.layers().iter().all(|l| l.index >= camera.index_air());
                let mut layers = [<$real4>::ZERO; MAX_LAYERS];
                for (slot, layer) in layers.iter_mut().zip(camera.layers()) {
                    let rho = layer.index / camera.index_air();
                    *slot = <$real4>::from_f64s([layer.thickness, rho, 1.0 / rho, 0.0]);
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
                    counts: UVec4::new(
                        camera.layers().len() as u32,
                        i.has_distortion() as u32,
                        dense as u32,
                        0,
                    ),
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
#[allow(
    clippy::large_enum_variant,
    reason = "one per call, on the stack: boxing the f64 uniform buys nothing"
)]
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
    pub fn new(
        precision: Precision,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        info: [u32; 4],
    ) -> Self {
        assert!(
            a.layers().len() <= MAX_LAYERS && b.layers().len() <= MAX_LAYERS,
            "layer count checked by the engine"
        );
        match precision {
            Precision::F32 => Self::F32(ParamsF32::new(a, b, info)),
            Precision::F64 => Self::F64(ParamsF64::new(a, b, info)),
        }
    }

    /// Holds camera `k`'s port (0 or 1) where a candidate interface moves the other's: the
    /// candidate kernels' `with_interface` then keeps this camera's own port (its normal and air
    /// layer as packed), as behind a port per camera.
    pub fn hold_port(&mut self, k: usize) {
        match self {
            Self::F32(params) => params.cams[k].counts.w = 1,
            Self::F64(params) => params.cams[k].counts.w = 1,
        }
    }

    /// The most layers of its two cameras: the value of the kernels' `override RIG_LAYERS`
    /// (`shaders/common.wgsl`) in the pipelines this uniform is bound to.
    pub fn layers(&self) -> u32 {
        match self {
            Self::F32(params) => params.cams[0].counts.x.max(params.cams[1].counts.x),
            Self::F64(params) => params.cams[0].counts.x.max(params.cams[1].counts.x),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The uniform's bytes are the mirror's: fx first, `info` where the struct puts it, and
    /// `set_info` writes `info` only. (tests/gpu.rs checks the layout against naga.)
    #[test]
    fn params_bytes_hold_the_fields_where_the_mirror_puts_them() {
        let rig = crate::io::read_rig("data/example_rig.json".as_ref()).expect("example rig");
        let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
        for precision in [Precision::F32, Precision::F64] {
            let mut params = Params::new(precision, &a, &b, [1, 2, 3, 4]);
            let before = params.bytes().to_vec();
            params.set_info([5, 6, 7, 8]);
            let (size, info) = match precision {
                Precision::F32 => (
                    size_of::<ParamsF32>(),
                    std::mem::offset_of!(ParamsF32, info),
                ),
                Precision::F64 => (
                    size_of::<ParamsF64>(),
                    std::mem::offset_of!(ParamsF64, info),
                ),
            };
            let bytes = params.bytes();
            assert_eq!(bytes.len(), size);
            let (fx, expected) = match precision {
                Precision::F32 => (
                    f32::from_le_bytes(bytes[..4].try_into().unwrap()) as f64,
                    a.intrinsics().fx as f32 as f64,
                ),
                Precision::F64 => (
                    f64::from_le_bytes(bytes[..8].try_into().unwrap()),
                    a.intrinsics().fx,
                ),
            };
            assert_eq!(fx, expected, "{precision}: fx first");
            let words: Vec<u32> = (0..4)
                .map(|k| {
                    u32::from_le_bytes(bytes[info + 4 * k..info + 4 * k + 4].try_into().unwrap())
                })
                .collect();
            assert_eq!(words, [5, 6, 7, 8], "{precision}");
            assert_eq!(
                bytes[..info],
                before[..info],
                "{precision}: set_info writes info only"
            );
            assert_eq!(bytes[info + 16..], before[info + 16..], "{precision}");
            assert!(
                bytes[info + 16..].iter().all(|&b| b == 0),
                "{precision}: end padding is zero"
            );
        }
    }
}
