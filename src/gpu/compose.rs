//! The pure-string composition of WGSL kernels: a kernel module is a precision prelude (type
//! aliases and the CPU's stopping rules, [`prelude`]), `shaders/common.wgsl`, the relations of
//! `shaders/lib/`, the binding of view rows where the kernel reads them ([`Rows`]), then the
//! kernel's own parts as its [`KernelSource`] lists them. Which kernels exist is not said here:
//! each user of the GPU keeps a catalogue of `KernelSource`s beside its host code.
//!
//! No crate item is used here, and the catalogues are pure data too: `build.rs` compiles this
//! file and every catalogue (through `#[path]`) to parse and validate every composed kernel with
//! naga at build time, so there is one composition for the build check, the tests and the
//! runtime.

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

/// Where a kernel that reads view rows ([`KernelSource::reads_view_rows`]) reads them: binding 1,
/// `input: array<vec4r…>`, composed in front of the kernel's parts. Both bindings hold the same
/// blocks: a view table, (first vec4, rows, 0, 0) per view, followed by the views' rows.
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

/// Invocations per workgroup of every kernel: the value of WGSL's `override WORKGROUP_SIZE`
/// (`shaders/common.wgsl`, no default there), set at pipeline creation by
/// `GpuContext::pipeline`, and the width of every host dispatch computation.
pub const WORKGROUP_SIZE: u32 = 64;

/// One compute kernel (entry point `main`): its name and the WGSL parts composed after
/// `shaders/common.wgsl` and `shaders/lib/`, with what the host needs to know to dispatch it.
/// Catalogues build them in constants with [`new`](Self::new) and the `const` setters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KernelSource {
    /// Name: labels its pipeline and errors, and keys the pipeline cache, so unique across every
    /// catalogue (`build.rs` checks).
    pub name: &'static str,
    /// The WGSL composed in this order after the shared files: bindings, constants, the kernel.
    pub parts: &'static [&'static str],
    /// The precision the kernel is composed in whatever its caller's, if fixed.
    pub fixed_precision: Option<Precision>,
    /// True for kernels whose binding 1 holds view rows as [`Rows`] say (composed in front of
    /// the parts, not declared in them).
    pub reads_view_rows: bool,
    /// Rows of its batch one invocation handles: a dispatch launches the rows' count divided by
    /// this, rounded up.
    pub rows_per_invocation: usize,
}

impl KernelSource {
    /// A kernel of `parts` in the caller's precision, one row per invocation, its own bindings.
    pub const fn new(name: &'static str, parts: &'static [&'static str]) -> Self {
        Self {
            name,
            parts,
            fixed_precision: None,
            reads_view_rows: false,
            rows_per_invocation: 1,
        }
    }

    /// The same kernel, always composed in `precision`.
    pub const fn in_precision(mut self, precision: Precision) -> Self {
        self.fixed_precision = Some(precision);
        self
    }

    /// The same kernel, reading view rows from binding 1 ([`Rows`]).
    pub const fn reading_view_rows(mut self) -> Self {
        self.reads_view_rows = true;
        self
    }

    /// The same kernel, `rows` rows per invocation.
    pub const fn with_rows_per_invocation(mut self, rows: usize) -> Self {
        self.rows_per_invocation = rows;
        self
    }

    /// The precision it is composed in for a caller at `precision`.
    pub fn precision(&self, precision: Precision) -> Precision {
        self.fixed_precision.unwrap_or(precision)
    }

    /// The binding it reads view rows from when asked for `rows`: `rows` where it reads view
    /// rows, else [`Rows::Storage`] (which it ignores), so that a pipeline is compiled once.
    pub fn rows(&self, rows: Rows) -> Rows {
        if self.reads_view_rows {
            rows
        } else {
            Rows::Storage
        }
    }

    /// The label of its pipeline with view rows bound as `rows`: the name, and the binding where
    /// it reads view rows.
    pub fn label(&self, rows: Rows) -> String {
        if self.reads_view_rows {
            format!("{} ({} rows)", self.name, rows.name())
        } else {
            self.name.to_string()
        }
    }
}

const COMMON: &str = include_str!("../../shaders/common.wgsl");
/// The relation files, in dependency order.
const LIBRARY: [&str; 6] = [
    include_str!("../../shaders/lib/exact.wgsl"),
    include_str!("../../shaders/lib/lens.wgsl"),
    include_str!("../../shaders/lib/lambda.wgsl"),
    include_str!("../../shaders/lib/ray.wgsl"),
    include_str!("../../shaders/lib/air_path.wgsl"),
    include_str!("../../shaders/lib/stereo.wgsl"),
];

/// The CPU path's stopping rules and thresholds, which the prelude writes into every kernel so the
/// CPU and GPU stop at the same bounds (`gpu::CPU_BOUNDS` fills them from `crate::model`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CpuBounds {
    /// Most iterations of the lens undistortion.
    pub undistort_max_iterations: usize,
    /// Relative stopping tolerance of the forward projection's Newton iteration (f64 kernels).
    pub project_tolerance: f64,
    /// Most Newton iterations of the forward projection.
    pub project_max_iterations: u32,
    /// Largest q at which the forward projection's root finder changes medium
    /// (`SWITCH_MAX_Q` of the model).
    pub switch_max_q: f64,
    /// sin² of the smallest angle between two rays that are triangulated.
    pub min_ray_angle_sin2: f64,
    /// Smallest conditioning of the binocular-VOP system that is solved.
    pub min_binocular_conditioning: f64,
}

/// The precision prelude: type aliases and the stopping rules of the CPU path. f32 kernels stop
/// at tolerances a few ulps above f32 rounding instead of the CPU's f64 ones.
pub fn prelude(precision: Precision, bounds: &CpuBounds) -> String {
    // UNDISTORT_FLOOR: the residual the lens model's evaluation can round to, per unit of the
    // sum of its terms' magnitudes (γ₁₆ = 16 units of roundoff: the ~12 operations of the
    // distortion and the residual's subtraction, whatever a driver fuses or reorders). f32
    // accepts a residual at that floor after its last step; f64 keeps the CPU's rule (its
    // tolerance is ~90× above the floor there) so that it stops where the CPU does, pixel for
    // pixel.
    let (undistort_tolerance, undistort_floor, project_tolerance) = match precision {
        Precision::F32 => (4e-7, 16.0 * f64::from(f32::EPSILON) / 2.0, 2.5e-7),
        Precision::F64 => (1e-14, 0.0, bounds.project_tolerance),
    };
    let huge = precision.huge();
    let real = precision.name();
    let CpuBounds {
        undistort_max_iterations,
        project_max_iterations,
        switch_max_q,
        min_ray_angle_sin2,
        min_binocular_conditioning,
        ..
    } = bounds;
    format!(
        "alias real = {real};\nalias vec2r = vec2<{real}>;\nalias vec3r = vec3<{real}>;\nalias vec4r = vec4<{real}>;\n\
         const REAL_HUGE: real = {huge:e};\n\
         const UNDISTORT_TOLERANCE: real = {undistort_tolerance:e};\n\
         const UNDISTORT_FLOOR: real = {undistort_floor:e};\n\
         const UNDISTORT_MAX_ITERATIONS: u32 = {undistort_max_iterations}u;\n\
         const PROJECT_TOLERANCE: real = {project_tolerance:e};\n\
         const PROJECT_MAX_ITERATIONS: u32 = {project_max_iterations}u;\n\
         const SWITCH_MAX_Q: real = {switch_max_q:e};\n\
         const MIN_RAY_ANGLE_SIN2: real = {min_ray_angle_sin2:e};\n\
         const MIN_BINOCULAR_CONDITIONING: real = {min_binocular_conditioning:e};\n"
    )
}

/// The composed WGSL module of `kernel` at `precision` (as given: the caller applies
/// [`KernelSource::precision`]) with the stopping rules `bounds`: the prelude, the shared files,
/// the view-row binding `rows` where the kernel reads view rows, then the kernel's parts, each
/// followed by a newline.
pub fn compose(
    kernel: &KernelSource,
    precision: Precision,
    rows: Rows,
    bounds: &CpuBounds,
) -> String {
    let mut text = prelude(precision, bounds);
    let rows = if kernel.reads_view_rows {
        rows.declaration(precision)
    } else {
        String::new()
    };
    let view_rows = (!rows.is_empty()).then_some(rows.as_str());
    for part in [COMMON]
        .into_iter()
        .chain(LIBRARY)
        .chain(view_rows)
        .chain(kernel.parts.iter().copied())
    {
        text.push_str(part);
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOUNDS: CpuBounds = CpuBounds {
        undistort_max_iterations: 30,
        project_tolerance: 1e-13,
        project_max_iterations: 100,
        switch_max_q: 100.0,
        min_ray_angle_sin2: 1e-12,
        min_binocular_conditioning: 1e-9,
    };

    const PLAIN: KernelSource = KernelSource::new("plain", &["// first part", "// second part"]);
    const VIEWS: KernelSource = KernelSource::new("views", &["// the kernel"])
        .reading_view_rows()
        .in_precision(Precision::F64)
        .with_rows_per_invocation(3);

    /// The module is the prelude, the shared files, the view-row binding only for a kernel that
    /// reads view rows, then the parts in order; the same text every time.
    #[test]
    fn composition_puts_the_parts_after_the_shared_files_in_order() {
        for precision in [Precision::F32, Precision::F64] {
            for rows in Rows::ALL {
                let text = compose(&PLAIN, precision, rows, &BOUNDS);
                assert_eq!(text, compose(&PLAIN, precision, rows, &BOUNDS));
                assert!(text.starts_with(&prelude(precision, &BOUNDS)));
                let at = |needle: &str| text.find(needle).unwrap_or_else(|| panic!("{needle}"));
                assert!(at("override WORKGROUP_SIZE") < at("// first part"));
                assert!(at("// first part") < at("// second part"));
                assert!(!text.contains("@binding(1)"), "no view rows: {rows:?}");
                assert!(text.ends_with("// second part\n"));
                let views = compose(&VIEWS, precision, rows, &BOUNDS);
                let binding = rows.declaration(precision);
                assert_eq!(views.matches(&binding).count(), 1, "{rows:?}");
                assert!(views.find(&binding) < views.find("// the kernel"));
            }
        }
    }

    /// The builder's settings, and what they decide: the precision, the binding and the label.
    #[test]
    fn a_kernel_source_says_its_precision_binding_and_label() {
        assert_eq!(PLAIN.precision(Precision::F32), Precision::F32);
        assert_eq!(VIEWS.precision(Precision::F32), Precision::F64);
        assert_eq!(PLAIN.rows(Rows::Uniform), Rows::Storage);
        assert_eq!(VIEWS.rows(Rows::Uniform), Rows::Uniform);
        assert_eq!(
            (PLAIN.rows_per_invocation, VIEWS.rows_per_invocation),
            (1, 3)
        );
        assert_eq!(PLAIN.label(Rows::Uniform), "plain");
        assert_eq!(VIEWS.label(Rows::Uniform), "views (uniform rows)");
    }
}
