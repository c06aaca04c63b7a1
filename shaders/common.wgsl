// Shared structs, status codes and indexing of every flatport kernel. Every kernel declares the
// uniform `params: Params` at binding 0, which the relations in shaders/lib/ read.
//
// A kernel module is composed (src/gpu/shaders.rs) from: a precision prelude that defines
// `real` (f32 or f64), `vec2r`..`vec4r` and the tolerances; this file; the relations in
// shaders/lib/; one kernel from shaders/kernels/. `Camera` and `Params` are mirrored by the
// `#[repr(C)]` structs `CameraF32`/`CameraF64` and `ParamsF32`/`ParamsF64` in src/gpu/layout.rs:
// keep them in sync (tests/gpu.rs compares their sizes and field offsets with naga's layouter for
// both precisions). build.rs parses and validates every composed kernel with naga.

// Per-element status: 0 = answer, otherwise `NoSolution::code()` of the CPU path.
const STATUS_OK: u32 = 0u;
const STATUS_OUTSIDE_LENS: u32 = 1u;
const STATUS_MISSES_INTERFACE: u32 = 2u;
const STATUS_TOTAL_INTERNAL_REFLECTION: u32 = 3u;
const STATUS_NOT_IN_WATER: u32 = 4u;
const STATUS_BEHIND_CAMERA: u32 = 5u;
const STATUS_DEGENERATE: u32 = 6u;
const STATUS_NO_CONVERGENCE: u32 = 7u;
const STATUS_OUT_OF_RANGE: u32 = 8u; // also set by the host for inputs beyond ±REAL_HUGE and non-finite results
// Not a `NoSolution`: a fast kernel left the row to its safeguarded twin, which the host runs on it
// (`STATUS_RETRY` in src/gpu/engine.rs).
const STATUS_RETRY: u32 = 255u;

const MAX_LAYERS: u32 = 8u;
// Invocations per workgroup of every kernel, a power of two (the workgroup tree reduction halves
// it). No default: the host sets it at pipeline creation from `WORKGROUP_SIZE` in
// src/gpu/shaders.rs, which its dispatch arithmetic reads too.
override WORKGROUP_SIZE: u32;

// One camera behind the interface, master frame. vec4 slots keep the layout identical in f32 and
// f64 apart from the element size.
struct Camera {
    intrinsics: vec4r,       // fx, fy, cx, cy
    distortion: vec4r,       // k1, k2, p1, p2
    extra: vec4r,            // k3, fold radius² (REAL_HUGE when none), ρ_w = μ_w/μ_air, d_k
    master_from_cam0: vec4r, // rows of R_kᵀ (w unused)
    master_from_cam1: vec4r,
    master_from_cam2: vec4r,
    centre: vec4r,           // C_k, w = Σ tᵢ
    normal: vec4r,           // n, w unused
    layers: array<vec4r, 8>, // (tᵢ, ρᵢ = μᵢ/μ_air, 1/ρᵢ, 0)
    counts: vec4<u32>,       // layer count, has distortion, no medium less dense than air (ρ ≥ 1), port held (1: a candidate interface does not move it)
}

// Uniform of every kernel: one or two cameras and the dispatch description.
struct Params {
    cams: array<Camera, 2>,
    info: vec4<u32>, // items in this dispatch, grid width, first grid row, 0
}

// Camera k of `params` and the interface it sees: the axis n and its own air layer d_k (a cost
// kernel moves them per candidate). Everything else is read from the uniform where it is used:
// a by-value copy of `Camera` lives in memory on SIMD drivers, which made lavapipe 1.4× slower.
struct View {
    k: u32,
    n: vec3r,
    d_k: real,
}

fn view(k: u32) -> View {
    return View(k, params.cams[k].normal.xyz, params.cams[k].extra.w);
}

// Camera k behind a candidate interface (n, d) (n unit, master frame): d_k = d − n·C_k.
// A camera whose port is held (behind a port each, the second camera of a pair) keeps its own.
// Selects, not a branch: SIMD drivers run a branch on a uniform value as divergent code (a
// branch here cost lavapipe 8 % of a reprojection sweep).
fn with_interface(k: u32, candidate: vec4r) -> View {
    let held = params.cams[k].counts.w != 0u;
    let d_k = candidate.w - dot(candidate.xyz, params.cams[k].centre.xyz);
    return View(k, select(candidate.xyz, params.cams[k].normal.xyz, held), select(d_k, params.cams[k].extra.w, held));
}

// 1 where a candidate's air layer moves camera k's port, 0 where the port is held.
fn port_moves(k: u32) -> real {
    return select(real(1.0), real(0.0), params.cams[k].counts.w != 0u);
}

// A value that may not exist (total internal reflection, …).
struct Maybe {
    value: real,
    ok: bool,
}

// Linear item index of a 2-D dispatch of WORKGROUP_SIZE-wide workgroups.
fn item_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * WORKGROUP_SIZE + gid.x;
}

fn cross3(a: vec3r, b: vec3r) -> vec3r {
    return vec3r(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

// R_k · v from the rows of R_kᵀ: camera frame from master frame.
fn cam_from_master(cam: View, v: vec3r) -> vec3r {
    return params.cams[cam.k].master_from_cam0.xyz * v.x + params.cams[cam.k].master_from_cam1.xyz * v.y + params.cams[cam.k].master_from_cam2.xyz * v.z;
}

// R_kᵀ · v: master frame from camera frame.
fn master_from_cam(cam: View, v: vec3r) -> vec3r {
    return vec3r(dot(params.cams[cam.k].master_from_cam0.xyz, v), dot(params.cams[cam.k].master_from_cam1.xyz, v), dot(params.cams[cam.k].master_from_cam2.xyz, v));
}
