// Bindings of the candidate-batch kernels (calib_triangulate, calib_projected_vop): one item per candidate × corner, items
// candidate-major (item i = candidate c · corners + corner j, corners = params.info.y). `input`
// holds rows per corner (shared by every candidate); `output` M reals per item; one status per
// item. The first part of each of those kernels in src/calib/backends/gpu/kernels.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> input: array<real>;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> candidates: array<vec4r>; // n xyz (unit), d

struct Item {
    candidate: u32,
    corner: u32,
}

fn candidate_item(i: u32) -> Item {
    let c = i / params.info.y;
    return Item(c, i - c * params.info.y);
}

// The two cameras behind item i's candidate interface (n, d); `in_air` is false when the
// candidate puts one of them outside the air.
struct CandidateCameras {
    item: Item,
    a: View,
    b: View,
    in_air: bool,
}

fn candidate_cameras(i: u32) -> CandidateCameras {
    let item = candidate_item(i);
    let candidate = candidates[item.candidate];
    let a = with_interface(view(0u), candidate);
    let b = with_interface(view(1u), candidate);
    return CandidateCameras(item, a, b, a.d_k > 0.0 && b.d_k > 0.0);
}
