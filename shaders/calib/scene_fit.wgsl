// The triangulating calibration costs reduced on the device, one invocation per (candidate, view):
// the view's corners are triangulated under the candidate interface, the rigid board model is
// fitted to them (Kabsch: the rotation as the polar factor of the cross-covariance) and the
// view's sum of squares is written, four numbers per (candidate, view), which calib_view_sum
// (shaders/calib/view_sum.wgsl) then adds over the views on the device. Twin of `calib::costs::scene::AxisRays` (gap lines, `cost`) and of
// `calib::problem::board::fit_rigid`.
//
// Modes (MODE, a constant composed in front of this file per kernel: calib_scene_gap,
// calib_scene_fit, calib_scene_reprojection, calib_scene_reprojection_safeguarded; a constant, not
// a uniform, so that the compiler drops the other modes' code, which SIMD drivers such as
// lavapipe would otherwise run masked):
// - MODE_GAP: candidate (n, unused): Σa², Σab, Σb² of the view's gap lines g(d) = a·d + b
//   (DESIGN.md §2: the signed distance between the two water rays, linear in d; the origin moves
//   by v/(n·v) per metre of air layer), for the host's least-squares air layer.
// - MODE_SCENE: candidate (n, d): Σ|R·P + t − X|² over the view (the 3-D scene error's sum).
// - MODE_REPROJECTION: candidate (n, d): Σ |observed − projected|² of R·P + t in both images,
//   each corner projected from its observed air ray (`project_near_pair`); STATUS_RETRY where that
//   leaves a corner unsettled.
// - MODE_REPROJECTION_SAFEGUARDED: the same sum, every corner by the full forward projection
//   (`project`), for the items MODE_REPROJECTION returned with STATUS_RETRY.
// output: 4 reals per item: (Σa², Σab, Σb², 0) for MODE_GAP, (sum, corners, 0, 0) for the
// others; zeros where the status is not STATUS_OK (STATUS_RETRY included).
//
// Items are view-major within a dispatch: item i = view · info.y + candidate, info.y the
// candidates per view: all of them when they fit one chunk, else a multiple of the workgroup
// size, so the invocations of a workgroup read the same corner rows. The item's view is entry
// i / info.y + info.w of the block's view table; its output goes to item info.z + i.
// input (binding 1, composed in front of this file: a storage buffer or a uniform window, see
// `Rows` in src/gpu/compose.rs): a block of (first vec4 of the view's rows, row count,
// 0, 0) per view, then 3 vec4 per corner: (v_l xyz, v_r x), (v_r yz, P x, P y),
// (u_l, v_l, u_r, v_r).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(2) var<storage, read_write> output: array<real>; // 4 reals per item
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> candidates: array<vec4r>; // n xyz (unit), d

const MODE_GAP: u32 = 0u;
const MODE_SCENE: u32 = 1u;
const MODE_REPROJECTION: u32 = 2u;
const MODE_REPROJECTION_SAFEGUARDED: u32 = 3u;
// calib::costs::air_layer::MIN_GAP_LINE_SIN.
const MIN_GAP_LINE_SIN: real = 1e-9;
// Triangulated corners kept for the second pass of a view of at most this many corners (a 9×6
// board has 54); larger views triangulate their corners again.
const CACHED_CORNERS: u32 = 64u;

struct CornerRow {
    v_l: vec3r,
    v_r: vec3r,
    board: vec3r,
    pixels: vec4r,
}

fn corner_row(row: u32) -> CornerRow {
    let q0 = input[row];
    let q1 = input[row + 1u];
    let q2 = input[row + 2u];
    return CornerRow(q0.xyz, vec3r(q0.w, q1.x, q1.y), vec3r(q1.z, q1.w, 0.0), q2);
}

struct Point {
    x: vec3r,
    status: u32,
}

fn triangulate_corner(a: View, b: View, c: CornerRow) -> Point {
    let ray_a = ray_in_water(a, c.v_l);
    if (ray_a.status != STATUS_OK) {
        return Point(vec3r(0.0), ray_a.status);
    }
    let ray_b = ray_in_water(b, c.v_r);
    if (ray_b.status != STATUS_OK) {
        return Point(vec3r(0.0), ray_b.status);
    }
    let t = triangulate_rays(ray_a, ray_b);
    return Point(t.point, t.status);
}

// The earlier failure code where there is one, else `next`.
fn first_failure(earlier: u32, next: u32) -> u32 {
    return select(next, earlier, earlier != STATUS_OK);
}

// The fitted board point R·(P − P₀) + t′ of a board offset P − P₀ (about the first corner's X₀).
fn fitted_about_first(rotation: Mat3, shift: vec3r, board_offset: vec2r) -> vec3r {
    return times(rotation, vec3r(board_offset, 0.0)) + shift;
}

// |observed − projected|² of a corner in both images.
fn pixel_squares(c: CornerRow, left: Pixel, right: Pixel) -> real {
    let e_l = c.pixels.xy - left.pixel;
    let e_r = c.pixels.zw - right.pixel;
    return dot(e_l, e_l) + dot(e_r, e_r);
}

// tan a of the unit air ray v under the view's axis (0 where it misses the interface).
fn tan_in_air(cam: View, v: vec3r) -> real {
    let c = dot(cam.n, v);
    return select(0.0, sqrt(max(1.0 - c * c, 0.0)) / c, c > 0.0);
}

// Item i's output (i within the dispatch).
fn write(i: u32, values: vec4r, code: u32) {
    let o = params.info.z + i;
    output[4u * o] = values.x;
    output[4u * o + 1u] = values.y;
    output[4u * o + 2u] = values.z;
    output[4u * o + 3u] = values.w;
    status[o] = code;
}

// A 3×3 matrix by columns (WGSL has no f64 matrices).
struct Mat3 {
    c0: vec3r,
    c1: vec3r,
    c2: vec3r,
}

fn frobenius2(m: Mat3) -> real {
    return dot(m.c0, m.c0) + dot(m.c1, m.c1) + dot(m.c2, m.c2);
}

fn times(m: Mat3, v: vec3r) -> vec3r {
    return m.c0 * v.x + m.c1 * v.y + m.c2 * v.z;
}

// The rotation closest to M (det M > 0): its polar factor, by Newton's iteration
// X ← (γX + X⁻ᵀ/γ)/2 with Higham's scaling γ = (‖X⁻¹‖/‖X‖)^½ (Frobenius), which converges
// quadratically from any nonsingular start; it stops when a step changes X by less than the
// forward projection's relative tolerance (|R|² = 3), or after 30 steps.
fn polar_rotation(m: Mat3) -> Mat3 {
    var x = m;
    for (var k = 0u; k < 30u; k++) {
        // X⁻ᵀ = cof(X)/det X, the cofactors as cross products of the columns.
        let det = dot(x.c0, cross3(x.c1, x.c2));
        let s = 1.0 / det;
        let inv_t = Mat3(cross3(x.c1, x.c2) * s, cross3(x.c2, x.c0) * s, cross3(x.c0, x.c1) * s);
        let gamma = sqrt(sqrt(frobenius2(inv_t) / frobenius2(x)));
        let g = 0.5 * gamma;
        let h = 0.5 / gamma;
        let next = Mat3(x.c0 * g + inv_t.c0 * h, x.c1 * g + inv_t.c1 * h, x.c2 * g + inv_t.c2 * h);
        let change = frobenius2(Mat3(next.c0 - x.c0, next.c1 - x.c1, next.c2 - x.c2));
        x = next;
        if (!(change > 3.0 * PROJECT_TOLERANCE * PROJECT_TOLERANCE)) {
            break;
        }
    }
    return x;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`): the corner loops read them per
    // corner.
    let left = view(0u);
    let right = view(1u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let per_view = params.info.y;
    let view = i / per_view + params.info.w;
    let candidate = candidates[i % per_view];
    let table = input[view];
    let first = u32(table.x);
    let count = u32(table.y);
    let end = first + 3u * count;
    let n = candidate.xyz;

    if (MODE == MODE_GAP) {
        // The rays at d = 0 (d_k may be negative: only the line is wanted).
        let a = with_interface(left, vec4r(n, 0.0));
        let b = with_interface(right, vec4r(n, 0.0));
        var sums = vec3r(0.0);
        var code = STATUS_OK;
        for (var row = first; row < end; row += 3u) {
            let c = corner_row(row);
            let l = ray_in_water(a, c.v_l);
            let r = ray_in_water(b, c.v_r);
            let w = cross3(l.dir, r.dir);
            let sin_angle = length(w);
            var corner_code = STATUS_OK;
            if (!(sin_angle > MIN_GAP_LINE_SIN)) {
                corner_code = STATUS_DEGENERATE;
            }
            code = first_failure(code, first_failure(l.status, first_failure(r.status, corner_code)));
            let m = w / sin_angle;
            let line_b = dot(m, l.origin - r.origin);
            let line_a = dot(m, c.v_l * (port_moves(a) / dot(a.n, c.v_l)) - c.v_r * (port_moves(b) / dot(b.n, c.v_r)));
            sums += vec3r(line_a * line_a, line_a * line_b, line_b * line_b);
        }
        if (code != STATUS_OK) {
            write(i, vec4r(0.0), code);
            return;
        }
        write(i, vec4r(sums, 0.0), STATUS_OK);
        return;
    }

    let a = with_interface(left, candidate);
    let b = with_interface(right, candidate);
    if (!(a.d_k > 0.0 && b.d_k > 0.0)) {
        write(i, vec4r(0.0), STATUS_MISSES_INTERFACE); // a camera outside the air
        return;
    }
    if (count < 3u) {
        write(i, vec4r(0.0), STATUS_DEGENERATE);
        return;
    }
    // Pass 1: the means and the cross-covariance H = Σ (X − X̄)(P − P̄)ᵀ, summed about the first
    // corner (X₀, P₀) so that the sums do not cancel.
    let c0 = corner_row(first);
    let x0 = triangulate_corner(a, b, c0);
    var code = x0.status;
    var sum_x = vec3r(0.0);
    var sum_p = vec2r(0.0);
    var h1 = vec3r(0.0); // Σ (X − X₀)(P − P₀)_x
    var h2 = vec3r(0.0); // Σ (X − X₀)(P − P₀)_y
    var cached: array<vec3r, CACHED_CORNERS>;
    for (var row = first; row < end; row += 3u) {
        let c = corner_row(row);
        let x = triangulate_corner(a, b, c);
        code = first_failure(code, x.status);
        let dx = x.x - x0.x;
        let j = (row - first) / 3u;
        if (MODE == MODE_SCENE && j < CACHED_CORNERS) {
            cached[j] = dx;
        }
        let dp = c.board.xy - c0.board.xy;
        sum_x += dx;
        sum_p += dp;
        h1 += dx * dp.x;
        h2 += dx * dp.y;
    }
    if (code != STATUS_OK) {
        write(i, vec4r(0.0), code);
        return;
    }
    let inv = 1.0 / real(count);
    let mean_x = sum_x * inv;
    let mean_p = sum_p * inv;
    h1 -= sum_x * mean_p.x;
    h2 -= sum_x * mean_p.y;
    // The board is planar (P_z = 0): H = [h₁ h₂ 0]. The best rotation maximises h₁·r₁ + h₂·r₂; with
    // h₃ = h₁ × h₂ as third column, M = [h₁ h₂ h₃] has det |h₃|² > 0 and its polar factor is that
    // rotation (r₃ = r₁ × r₂ ∥ h₃ at the optimum). Collinear corners leave it undetermined, as
    // fit_rigid says: σ₂ ≤ 1e-12 σ₁, with σ₁²σ₂² = |h₃|² and σ₁² ≤ |h₁|² + |h₂|².
    let h3 = cross3(h1, h2);
    let trace = dot(h1, h1) + dot(h2, h2);
    if (!(dot(h3, h3) > 1e-24 * trace * trace)) {
        write(i, vec4r(0.0), STATUS_DEGENERATE);
        return;
    }
    let rotation = polar_rotation(Mat3(h1, h2, h3));
    // X = R·(P − P₀) + t′ with t′ = X̄ − R·(P̄ − P₀), about X₀.
    let shift = mean_x - times(rotation, vec3r(mean_p, 0.0));
    var sum: real = 0.0;
    if (MODE == MODE_SCENE) {
        // The cached corners, then (a view of more than CACHED_CORNERS) the others triangulated
        // again: two loops, not a branch per corner, which SIMD drivers run both sides of.
        let cached_end = first + 3u * min(count, CACHED_CORNERS);
        for (var row = first; row < cached_end; row += 3u) {
            let c = corner_row(row);
            let fitted = fitted_about_first(rotation, shift, c.board.xy - c0.board.xy);
            let e = fitted - cached[(row - first) / 3u];
            sum += dot(e, e);
        }
        for (var row = cached_end; row < end; row += 3u) {
            let c = corner_row(row);
            let fitted = fitted_about_first(rotation, shift, c.board.xy - c0.board.xy);
            let e = fitted - (triangulate_corner(a, b, c).x - x0.x);
            sum += dot(e, e);
        }
    } else if (MODE == MODE_REPROJECTION) {
        // Each corner projected from its observed air rays (`project_near_pair`). A view with a
        // corner it does not settle comes back as STATUS_RETRY, for the safeguarded kernel: the
        // full projection's code is not here at all (present, even unrun, it cost lavapipe 7 %).
        var unsettled = false;
        for (var row = first; row < end; row += 3u) {
            let c = corner_row(row);
            let point = fitted_about_first(rotation, shift, c.board.xy - c0.board.xy) + x0.x;
            let near = project_near_pair(a, point, b, point, vec2r(tan_in_air(a, c.v_l), tan_in_air(b, c.v_r)));
            let left = near.a;
            let right = near.b;
            if (left.converged && right.converged) {
                code = first_failure(code, first_failure(left.pixel.status, right.pixel.status));
                sum += pixel_squares(c, left.pixel, right.pixel);
            } else {
                unsettled = true;
            }
        }
        if (unsettled) {
            write(i, vec4r(0.0), STATUS_RETRY);
            return;
        }
    } else {
        // MODE_REPROJECTION_SAFEGUARDED: every corner by the full forward projection.
        for (var row = first; row < end; row += 3u) {
            let c = corner_row(row);
            let point = fitted_about_first(rotation, shift, c.board.xy - c0.board.xy) + x0.x;
            let left = project(a, point);
            let right = project(b, point);
            code = first_failure(code, first_failure(left.status, right.status));
            sum += pixel_squares(c, left, right);
        }
    }
    if (code != STATUS_OK) {
        write(i, vec4r(0.0), code);
        return;
    }
    write(i, vec4r(sum, real(count), 0.0, 0.0), STATUS_OK);
}
