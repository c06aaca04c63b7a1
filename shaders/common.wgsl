// Shared structs, status codes and indexing of every flatport kernel. Every kernel declares the
// uniform `params: Params` at binding 0, which the relations in shaders/lib/ read.
//
// A kernel module is composed (src/gpu/compose.rs) from: a precision prelude that defines
// `real` (f32 or f64), `vec2r`..`vec4r` and the tolerances; this file; the relations in
// shaders/lib/; one kernel's parts as its catalogue lists them (src/engine/gpu/kernels.rs for
// shaders/kernels/, src/calib/backends/gpu/kernels.rs for shaders/calib/). `Camera` and
// `Params` are mirrored by the `#[repr(C)]` structs `CameraF32`/`CameraF64` and
// `ParamsF32`/`ParamsF64` in src/gpu/layout.rs: keep them in sync (tests/gpu.rs compares their
// sizes and field offsets with naga's layouter for both precisions). build.rs parses and
// validates every composed kernel of every catalogue with naga.

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
// (`STATUS_RETRY` in src/gpu/compose.rs).
const STATUS_RETRY: u32 = 255u;

const MAX_LAYERS: u32 = 8u;
// Invocations per workgroup of every kernel. No default: the host sets it at pipeline creation
// from `WORKGROUP_SIZE` in src/gpu/compose.rs, which its dispatch arithmetic reads too.
override WORKGROUP_SIZE: u32;
// The most layers of a camera the pipeline serves (0 to MAX_LAYERS), set by the host at pipeline
// creation (`Params::layers`, one pipeline per value). The layer loops run to it, not to a
// camera's own count: with a constant trip count the compiler removes or unrolls them, where
// Mesa's llvmpipe (lavapipe) runs a loop body at least once even when no lane enters it (its loops
// test their mask at the end, and a branch is masked, never skipped), which cost the cost kernels'
// corner loops a pass over an absent second layer per ray and per Newton step.
override RIG_LAYERS: u32;

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

// Camera k of `params` as the relations read it: the interface it sees (the axis n and its own
// air layer d_k, which a cost kernel moves per candidate) and every value of its lens, pose and
// media but the second and later layers. A kernel takes it once, at its top, before any branch or
// loop: Mesa's llvmpipe (lavapipe) loads a uniform as one scalar only outside control flow, and
// inside a loop or after an early return every read of `params` is an 8-lane gather (an extract
// and an insert per lane), which the corner loops of the cost kernels paid per corner and value.
// No array member: a struct with one, copied by value, lives in memory on SIMD drivers.
struct View {
    k: u32,
    n: vec3r,
    d_k: real,
    centre: vec3r,       // C_k
    thickness: real,     // Σ tᵢ
    master_from_cam0: vec3r, // rows of R_kᵀ
    master_from_cam1: vec3r,
    master_from_cam2: vec3r,
    intrinsics: vec4r,   // fx, fy, cx, cy
    distortion: vec4r,   // k1, k2, p1, p2
    k3: real,
    fold2: real,         // fold radius² (REAL_HUGE when none)
    rho_water: real,     // ρ_w = μ_w/μ_air
    first_layer: vec3r,  // (t₁, ρ₁, 1/ρ₁) of the first layer; (0, 1, 1), a layer of air, when none
    layers: u32,         // layer count (at most MAX_LAYERS)
    distorted: bool,     // the lens has distortion
    dense: bool,         // no medium less dense than air (ρ ≥ 1)
    held: bool,          // the port is held: a candidate interface does not move it
}

fn view(k: u32) -> View {
    let layers = min(params.cams[k].counts.x, MAX_LAYERS);
    let first = select(vec3r(0.0, 1.0, 1.0), params.cams[k].layers[0].xyz, layers > 0u);
    return View(
        k,
        params.cams[k].normal.xyz,
        params.cams[k].extra.w,
        params.cams[k].centre.xyz,
        params.cams[k].centre.w,
        params.cams[k].master_from_cam0.xyz,
        params.cams[k].master_from_cam1.xyz,
        params.cams[k].master_from_cam2.xyz,
        params.cams[k].intrinsics,
        params.cams[k].distortion,
        params.cams[k].extra.x,
        params.cams[k].extra.y,
        params.cams[k].extra.z,
        first,
        layers,
        params.cams[k].counts.y != 0u,
        params.cams[k].counts.z != 0u,
        params.cams[k].counts.w != 0u,
    );
}

// Layer l ≥ 1 of a camera as (t, ρ, 1/ρ), read from the uniform (rigs of more than one layer).
fn later_layer(cam: View, l: u32) -> vec3r {
    return params.cams[cam.k].layers[l].xyz;
}

// The camera `cam` behind a candidate interface (n, d) (n unit, master frame): d_k = d − n·C_k.
// A camera whose port is held (behind a port each, the second camera of a pair) keeps its own.
// Selects, not a branch: SIMD drivers run a branch on a uniform value as divergent code (a
// branch here cost lavapipe 8 % of a reprojection sweep).
fn with_interface(cam: View, candidate: vec4r) -> View {
    var moved = cam;
    moved.n = select(candidate.xyz, cam.n, cam.held);
    moved.d_k = select(candidate.w - dot(candidate.xyz, cam.centre), cam.d_k, cam.held);
    return moved;
}

// 1 where a candidate's air layer moves the camera's port, 0 where the port is held.
fn port_moves(cam: View) -> real {
    return select(real(1.0), real(0.0), cam.held);
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
    return cam.master_from_cam0 * v.x + cam.master_from_cam1 * v.y + cam.master_from_cam2 * v.z;
}

// R_kᵀ · v: master frame from camera frame.
fn master_from_cam(cam: View, v: vec3r) -> vec3r {
    return vec3r(dot(cam.master_from_cam0, v), dot(cam.master_from_cam1, v), dot(cam.master_from_cam2, v));
}
