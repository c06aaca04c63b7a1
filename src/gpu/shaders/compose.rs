//! The pure-string composition of the WGSL kernels: which files make each kernel, in which order,
//! in which precision. No crate item is used here: `build.rs` compiles this same file (through
//! `#[path]`) to parse and validate every composed kernel with naga at build time, so there is one
//! composition for the build check, the tests and the runtime.

/// Floating-point type of a kernel's arithmetic and buffers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Precision {
    /// 32-bit: every adapter, fastest.
    F32,
    /// 64-bit: adapters with SHADER_F64 (lavapipe has it); agrees with the CPU to ~1e-12.
    F64,
}

impl Precision {
    /// Bytes per value.
    pub fn size(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// A stand-in for infinity in the kernels (`REAL_HUGE`; WGSL has no infinity literal), also
    /// packed as the fold radius of a lens without a fold.
    pub fn huge(self) -> f64 {
        match self {
            Self::F32 => 1e30,
            Self::F64 => 1e300,
        }
    }

    /// `f32` or `f64`.
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F64 => "f64",
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Where a per-view kernel ([`Kernel::reads_view_rows`]) reads its corner rows: binding 1,
/// `input: array<vec4r…>`, composed in front of the kernel. Both bindings hold the same blocks:
/// a view table, (first vec4, corners, 0, 0) per view, followed by the views' rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Rows {
    /// A storage buffer holding every view: any size up to the storage-binding cap.
    Storage,
    /// A window of [`UNIFORM_WINDOW_BYTES`] of a uniform buffer holding some of the views; one
    /// dispatch per window. Mesa's llvmpipe (lavapipe) loads a uniform array element with a
    /// vector gather, where a storage load is a loop over the lanes with a branch and a bounds
    /// check per value; on discrete GPUs the lanes of a workgroup read the same rows (one view),
    /// which a constant cache serves as one broadcast.
    Uniform,
}

/// Bytes of a [`Rows::Uniform`] window: the size of the WGSL array that binds it, and the
/// uniform binding size every WebGPU adapter supports.
pub const UNIFORM_WINDOW_BYTES: usize = 1 << 16;

impl Rows {
    /// Both bindings.
    pub const ALL: [Rows; 2] = [Rows::Storage, Rows::Uniform];

    /// vec4 of `precision` in one uniform window.
    pub fn uniform_window_vec4(precision: Precision) -> usize {
        UNIFORM_WINDOW_BYTES / (4 * precision.size())
    }

    /// The declaration of binding 1, `input`.
    fn declaration(self, precision: Precision) -> String {
        match self {
            Self::Storage => {
                "@group(0) @binding(1) var<storage, read> input: array<vec4r>;".to_string()
            }
            Self::Uniform => format!(
                "@group(0) @binding(1) var<uniform> input: array<vec4r, {}>;",
                Self::uniform_window_vec4(precision)
            ),
        }
    }

    /// `storage` or `uniform`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Storage => "storage",
            Self::Uniform => "uniform",
        }
    }
}

/// The status of a row a fast kernel left to its safeguarded twin (`STATUS_RETRY` in
/// `shaders/common.wgsl`): not a `NoSolution` code, and never returned to a caller.
pub const STATUS_RETRY: u32 = 255;

/// One compute kernel (entry point `main`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// u,v → ray in the water.
    Backproject,
    /// Every pixel of an image → ray in the water, pixels generated in the shader.
    BackprojectGrid,
    /// x,y,z → u,v by the unbracketed Newton iteration; the rows it does not settle come back
    /// with status [`STATUS_RETRY`] for [`Kernel::ProjectSafeguarded`].
    Project,
    /// x,y,z → u,v with every safeguard of the forward projection.
    ProjectSafeguarded,
    /// x,y,z → depth, VOP distance, VOP, tan a.
    Vop,
    /// ul,vl,ur,vr → x,y,z, residual.
    Triangulate,
    /// ul,vl,ur,vr → both VOPs, axis offset, conditioning.
    BinocularVop,
    /// Candidate interfaces × corners (two air rays) → x, y, z, gap.
    CalibTriangulate,
    /// Candidate axes × corners (air rays and their pixel Jacobians) → projected binocular VOP
    /// q₁, q₂ in the plane ⟂ n and its Jacobian ∂q/∂(u_l, v_l, u_r, v_r).
    CalibProjectedVop,
    /// Candidate axes × views (fused corner rows) → weighted affine-grid χ² and degrees of freedom;
    /// always f64.
    CalibAffineGrid,
    /// Candidate axes × views (air rays) → the view's gap-line sums Σa², Σab, Σb².
    CalibSceneGap,
    /// Candidate interfaces × views (air rays, board points) → the rigid board fit's 3-D sum of
    /// squares.
    CalibSceneFit,
    /// Candidate interfaces × views (air rays, board points, pixels) → the rigid board fit's
    /// reprojection sum of squares, each corner projected from its observed air ray; the views
    /// with a corner that does not settle come back with status [`STATUS_RETRY`] for
    /// [`Kernel::CalibSceneReprojectionSafeguarded`].
    CalibSceneReprojection,
    /// The same sum with every corner by the safeguarded forward projection.
    CalibSceneReprojectionSafeguarded,
}

impl Kernel {
    /// Every kernel.
    pub const ALL: [Kernel; 14] = [
        Self::Backproject,
        Self::BackprojectGrid,
        Self::Project,
        Self::ProjectSafeguarded,
        Self::Vop,
        Self::Triangulate,
        Self::BinocularVop,
        Self::CalibTriangulate,
        Self::CalibProjectedVop,
        Self::CalibAffineGrid,
        Self::CalibSceneGap,
        Self::CalibSceneFit,
        Self::CalibSceneReprojection,
        Self::CalibSceneReprojectionSafeguarded,
    ];

    /// Rows of its batch one invocation handles: the dispatch launches the rows' count divided by
    /// this, rounded up. [`Kernel::Project`] takes two, whose Newton iterations overlap on a CPU
    /// driver (`shaders/kernels/project.wgsl`).
    pub fn rows_per_invocation(self) -> usize {
        match self {
            Self::Project => 2,
            _ => 1,
        }
    }

    /// Name (the file name in `shaders/kernels/`, but for the modes of `calib_scene_fit.wgsl`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Backproject => "backproject",
            Self::BackprojectGrid => "backproject_grid",
            Self::Project => "project",
            Self::ProjectSafeguarded => "project_safeguarded",
            Self::Vop => "vop",
            Self::Triangulate => "triangulate",
            Self::BinocularVop => "binocular_vop",
            Self::CalibTriangulate => "calib_triangulate",
            Self::CalibProjectedVop => "calib_projected_vop",
            Self::CalibAffineGrid => "calib_affine_grid",
            Self::CalibSceneGap => "calib_scene_gap",
            Self::CalibSceneFit => "calib_scene_fit",
            Self::CalibSceneReprojection => "calib_scene_reprojection",
            Self::CalibSceneReprojectionSafeguarded => "calib_scene_reprojection_safeguarded",
        }
    }

    fn file(self) -> &'static str {
        match self {
            Self::Backproject => include_str!("../../../shaders/kernels/backproject.wgsl"),
            Self::BackprojectGrid => include_str!("../../../shaders/kernels/backproject_grid.wgsl"),
            Self::Project => include_str!("../../../shaders/kernels/project.wgsl"),
            Self::ProjectSafeguarded => {
                include_str!("../../../shaders/kernels/project_safeguarded.wgsl")
            }
            Self::Vop => include_str!("../../../shaders/kernels/vop.wgsl"),
            Self::Triangulate => include_str!("../../../shaders/kernels/triangulate.wgsl"),
            Self::BinocularVop => include_str!("../../../shaders/kernels/binocular_vop.wgsl"),
            Self::CalibTriangulate => {
                include_str!("../../../shaders/kernels/calib_triangulate.wgsl")
            }
            Self::CalibProjectedVop => {
                include_str!("../../../shaders/kernels/calib_projected_vop.wgsl")
            }
            Self::CalibAffineGrid => {
                include_str!("../../../shaders/kernels/calib_affine_grid.wgsl")
            }
            Self::CalibSceneGap
            | Self::CalibSceneFit
            | Self::CalibSceneReprojection
            | Self::CalibSceneReprojectionSafeguarded => {
                include_str!("../../../shaders/kernels/calib_scene_fit.wgsl")
            }
        }
    }

    /// Constants composed in front of the kernel's file: the mode of the four kernels of
    /// `calib_scene_fit.wgsl` (a constant, so that the compiler drops the other modes).
    fn constants(self) -> &'static str {
        match self {
            Self::CalibSceneGap => "const MODE: u32 = 0u;",
            Self::CalibSceneFit => "const MODE: u32 = 1u;",
            Self::CalibSceneReprojection => "const MODE: u32 = 2u;",
            Self::CalibSceneReprojectionSafeguarded => "const MODE: u32 = 3u;",
            _ => "",
        }
    }

    /// The shared bindings composed in front of the kernel: those of the row-mapping kernels
    /// (`shaders/kernels/map_bindings.wgsl`), of the candidate-batch kernels
    /// (`shaders/kernels/candidate_bindings.wgsl`), or none (the kernel declares its own).
    fn bindings(self) -> &'static str {
        match self {
            Self::BackprojectGrid
            | Self::CalibAffineGrid
            | Self::CalibSceneGap
            | Self::CalibSceneFit
            | Self::CalibSceneReprojection
            | Self::CalibSceneReprojectionSafeguarded => "",
            Self::CalibTriangulate | Self::CalibProjectedVop => {
                include_str!("../../../shaders/kernels/candidate_bindings.wgsl")
            }
            Self::Backproject
            | Self::Project
            | Self::ProjectSafeguarded
            | Self::Vop
            | Self::Triangulate
            | Self::BinocularVop => {
                include_str!("../../../shaders/kernels/map_bindings.wgsl")
            }
        }
    }

    /// The precision a kernel is composed in whatever the engine's, if fixed: the fused affine
    /// grid's one-pass χ² needs f64.
    pub fn fixed_precision(self) -> Option<Precision> {
        matches!(self, Self::CalibAffineGrid).then_some(Precision::F64)
    }

    /// True for the per-(candidate, view) kernels, whose corner rows binding 1 holds as
    /// [`Rows`] say (composed in front of the kernel, not declared in its file).
    pub fn reads_view_rows(self) -> bool {
        matches!(
            self,
            Self::CalibAffineGrid
                | Self::CalibSceneGap
                | Self::CalibSceneFit
                | Self::CalibSceneReprojection
                | Self::CalibSceneReprojectionSafeguarded
        )
    }
}

const COMMON: &str = include_str!("../../../shaders/common.wgsl");
/// The relation files, in dependency order.
const LIBRARY: [&str; 5] = [
    include_str!("../../../shaders/lib/lens.wgsl"),
    include_str!("../../../shaders/lib/lambda.wgsl"),
    include_str!("../../../shaders/lib/ray.wgsl"),
    include_str!("../../../shaders/lib/air_path.wgsl"),
    include_str!("../../../shaders/lib/stereo.wgsl"),
];

/// The CPU path's stopping rules and thresholds, which the prelude writes into every kernel so the
/// CPU and GPU stop at the same bounds (`src/gpu/shaders.rs` fills them from `crate::model`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CpuBounds {
    /// Most iterations of the lens undistortion.
    pub undistort_max_iterations: usize,
    /// Relative stopping tolerance of the forward projection's Newton iteration (f64 kernels).
    pub project_tolerance: f64,
    /// Most Newton iterations of the forward projection.
    pub project_max_iterations: u32,
    /// sin² of the smallest angle between two rays that are triangulated.
    pub min_ray_angle_sin2: f64,
    /// Smallest conditioning of the binocular-VOP system that is solved.
    pub min_binocular_conditioning: f64,
}

/// The precision prelude: type aliases and the stopping rules of the CPU path. f32 kernels stop
/// at tolerances a few ulps above f32 rounding instead of the CPU's f64 ones.
pub fn prelude(precision: Precision, bounds: &CpuBounds) -> String {
    let (undistort_tolerance, project_tolerance) = match precision {
        Precision::F32 => (4e-7, 2.5e-7),
        Precision::F64 => (1e-14, bounds.project_tolerance),
    };
    let huge = precision.huge();
    let real = precision.name();
    let CpuBounds {
        undistort_max_iterations,
        project_max_iterations,
        min_ray_angle_sin2,
        min_binocular_conditioning,
        ..
    } = bounds;
    format!(
        "alias real = {real};\nalias vec2r = vec2<{real}>;\nalias vec3r = vec3<{real}>;\nalias vec4r = vec4<{real}>;\n\
         const REAL_HUGE: real = {huge:e};\n\
         const UNDISTORT_TOLERANCE: real = {undistort_tolerance:e};\n\
         const UNDISTORT_MAX_ITERATIONS: u32 = {undistort_max_iterations}u;\n\
         const PROJECT_TOLERANCE: real = {project_tolerance:e};\n\
         const PROJECT_MAX_ITERATIONS: u32 = {project_max_iterations}u;\n\
         const MIN_RAY_ANGLE_SIN2: real = {min_ray_angle_sin2:e};\n\
         const MIN_BINOCULAR_CONDITIONING: real = {min_binocular_conditioning:e};\n"
    )
}

/// The composed WGSL module of `kernel` at `precision` with the stopping rules `bounds`; `rows`
/// is the corner-row binding of per-view kernels (ignored by the other kernels).
pub fn source(kernel: Kernel, precision: Precision, rows: Rows, bounds: &CpuBounds) -> String {
    let mut text = prelude(precision, bounds);
    let rows = if kernel.reads_view_rows() {
        rows.declaration(precision)
    } else {
        String::new()
    };
    for part in [COMMON].into_iter().chain(LIBRARY).chain([
        kernel.bindings(),
        &rows,
        kernel.constants(),
        kernel.file(),
    ]) {
        text.push_str(part);
        text.push('\n');
    }
    text
}
