// Shared structs of every flatport kernel. Composed in front of each kernel file at build time.
// Mirrors `GpuCamera` in src/gpu/layout.rs: keep in sync (a test checks the sizes).

// Per-element status codes: 0 = answer, otherwise `NoSolution::code()` of the CPU path.
const STATUS_OK: u32 = 0u;
const STATUS_OUTSIDE_LENS: u32 = 1u;
const STATUS_MISSES_INTERFACE: u32 = 2u;
const STATUS_TOTAL_INTERNAL_REFLECTION: u32 = 3u;

const MAX_LAYERS: u32 = 8u;
const UNDISTORT_MAX_ITERATIONS: u32 = 20u;

// One camera behind the interface, master frame, f32. vec4 slots avoid vec3 padding surprises.
struct Camera {
    intrinsics: vec4<f32>,      // fx, fy, cx, cy
    distortion: vec4<f32>,      // k1, k2, p1, p2
    extra: vec4<f32>,           // k3, fold radius² (1e30 when none), ρ_w = μ_w/μ_air, d_k
    master_from_cam0: vec4<f32>,// rows of R_kᵀ (w unused)
    master_from_cam1: vec4<f32>,
    master_from_cam2: vec4<f32>,
    centre: vec4<f32>,          // C_k (w unused)
    normal: vec4<f32>,          // n (w unused)
    layers: array<vec4<f32>, 8>,// (tᵢ, ρᵢ, 0, 0)
    counts: vec4<u32>,          // layer count, item count, has distortion, unused
}

// Linear item index of a 2-D dispatch of 64-wide workgroups.
fn item_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * 64u + gid.x;
}
