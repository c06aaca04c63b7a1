// The bundle's reprojection residuals over a stencil batch: evaluation e (a camera set, a pose set,
// the only camera it projects) × observed corner j (target point, observed pixel, view, camera) →
// projected − observed, pixels. Each corner goes to the master frame by its view's pose in the
// evaluation's pose set, X = R·P + t, then through its camera's port by the exact forward
// projection (`project`, shaders/lib/air_path.wgsl, with every safeguard). Twin of
// `CpuResiduals` (src/calib/backends/residuals.rs); the host code is
// src/calib/backends/gpu/bundle.rs. Always f64: the bundle's central differences of 1e-6 need
// residuals exact to ~1e-10 px.
//
// Items are evaluation-major: item i = (e − first evaluation of the chunk) · corners + j.
// A corner of a camera the evaluation does not project gets 0 (status 0).

struct BundleInfo {
    // Items in this chunk, observed corners, cameras per camera set, views per pose set.
    sizes: vec4<u32>,
    // First evaluation of this chunk, 0, 0, 0.
    chunk: vec4<u32>,
}

@group(0) @binding(0) var<uniform> bundle: BundleInfo;
// Per corner: target point x, y, z, observed u, v, view, camera, 0.
@group(0) @binding(1) var<storage, read> corners: array<real>;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> cameras: array<Camera>;
// Per pose: the rows of [R | t], three vec4 (pose set s, view v at 3 · (s · views + v)).
@group(0) @binding(5) var<storage, read> poses: array<vec4r>;
// Per evaluation: camera set, pose set, only camera (ALL_CAMERAS: every camera), 0.
@group(0) @binding(6) var<storage, read> evaluations: array<vec4<u32>>;

// The relations in shaders/lib/ read the camera from `params` (`view`, `later_layer`): here a
// private copy that each invocation fills with its own camera from the camera sets.
var<private> params: Params;

const ALL_CAMERAS: u32 = 0xffffffffu;
const CORNER_ROW: u32 = 8u;

// The corner in the master frame under pose `at` of the pose table.
fn corner_in_master(at: u32, p: vec3r) -> vec3r {
    let r0 = poses[at];
    let r1 = poses[at + 1u];
    let r2 = poses[at + 2u];
    return vec3r(dot(r0.xyz, p) + r0.w, dot(r1.xyz, p) + r1.w, dot(r2.xyz, p) + r2.w);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= bundle.sizes.x) {
        return;
    }
    let count = bundle.sizes.y;
    let local = i / count;
    let j = i - local * count;
    let evaluation = evaluations[bundle.chunk.x + local];
    let row = CORNER_ROW * j;
    let view_index = u32(corners[row + 5u]);
    let camera = u32(corners[row + 6u]);
    if (evaluation.z != ALL_CAMERAS && evaluation.z != camera) {
        status[i] = STATUS_OK;
        output[2u * i] = 0.0;
        output[2u * i + 1u] = 0.0;
        return;
    }
    params.cams[0] = cameras[evaluation.x * bundle.sizes.z + camera];
    let cam = view(0u);
    let point = corner_in_master(
        3u * (evaluation.y * bundle.sizes.w + view_index),
        vec3r(corners[row], corners[row + 1u], corners[row + 2u]),
    );
    let pixel = project(cam, point);
    status[i] = pixel.status;
    if (pixel.status == STATUS_OK) {
        output[2u * i] = pixel.pixel.x - corners[row + 3u];
        output[2u * i + 1u] = pixel.pixel.y - corners[row + 4u];
    }
}
