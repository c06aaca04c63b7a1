// The weighted affine-grid invariant fused per (candidate axis, view): one invocation sums the
// weighted normal equations of one view's corners under one axis and solves them, writing
// (χ², degrees of freedom), which calib_view_sum (shaders/calib/view_sum.wgsl) then adds over the
// views on the device. Twin of `calib::affine_grid` (same names, same loop; the formulation,
// the shift and the taper are documented there). Composed in f64 on every adapter. The positions
// are shifted by the affine map through the view's first three corners (the reference corners)
// before they are summed, so that the one-pass χ² subtracts numbers of the size of χ², not of
// the board's positions (unshifted it cancelled up to ~1e6-fold, and adapters that round
// differently disagreed by 4e-8). Divisions and square roots go through div_exact /
// recip_exact / sqrt_exact (shaders/lib/exact.wgsl): Vulkan lets a driver approximate them in
// f64.
//
// Items are view-major within a dispatch: item i = view · info.y + candidate, info.y the
// candidates per view: all of them when they fit one chunk, else a multiple of the workgroup
// size, so the invocations of a workgroup read the same corner rows. The item's view is entry
// i / info.y + info.w of the block's view table; its output goes to item info.z + i.
// input (binding 1, composed in front of this file: a storage buffer or a uniform window, see
// `Rows` in src/gpu/compose.rs): a block of (first vec4 of the view's rows, row count,
// 0, 0) per view, then ROW / 4 vec4 per corner.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(2) var<storage, read_write> output: array<real>;  // χ², dof per item
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> candidates: array<vec4r>;  // unit axis n (w unused)

const ROW: u32 = 36u;
const TAPER: real = 2.0;
const MIN_DENOMINATOR: real = 1e-12;
const MIN_CORNERS: u32 = 4u;
const CANCELLATION: real = 1e-5;
const MIN_REFERENCE_TAPER: real = 0.5;

// Π(w): w projected along t onto the plane z = 0.
fn along_axis(w: vec3r, t: vec3r) -> vec2r {
    return vec2r(w.x - w.z * t.x, w.y - w.z * t.y);
}

fn minor2(a: vec2r, b: vec2r) -> real {
    return a.x * b.y - a.y * b.x;
}

// One corner's terms under the axis t = n/n_z (CornerTerms of calib::affine_grid): q = q′/d,
// W = d²·d4_inverse·adj, the taper; ok false in the degenerate plane.
struct CornerTerms {
    ok: bool,
    q_prime: vec2r,
    d: real,
    adj: vec3r,
    d4_inverse: real,
    taper: real,
    g: vec2r,
}

// The corner whose row starts at vec4 k.
fn corner_terms(k: u32, t: vec3r) -> CornerTerms {
    // The row as 9 vec4: v_l, p, m, ∂v_l/∂u, ∂v_l/∂v, a_u, a_v, c_u, c_v, e_u, e_v, g.
    let q0 = input[k];
    let q1 = input[k + 1u];
    let q2 = input[k + 2u];
    let q3 = input[k + 3u];
    let q4 = input[k + 4u];
    let q5 = input[k + 5u];
    let q6 = input[k + 6u];
    let q7 = input[k + 7u];
    let q8 = input[k + 8u];
    var terms: CornerTerms;
    let d = dot(t, vec3r(q1.z, q1.w, q2.x));
    terms.ok = abs(d) > MIN_DENOMINATOR;
    if (!terms.ok) {
        return terms;
    }
    let numerator = dot(t, vec3r(q0.w, q1.x, q1.y)); // s = numerator / d
    let pv = along_axis(q0.xyz, t);
    let ta_u = dot(t, vec3r(q3.w, q4.x, q4.y));
    let ta_v = dot(t, vec3r(q4.z, q4.w, q5.x));
    let tc_u = dot(t, q5.yzw);
    let tc_v = dot(t, q6.xyz);
    let te_u = dot(t, vec3r(q6.w, q7.x, q7.y));
    let te_v = dot(t, vec3r(q7.z, q7.w, q8.x));
    // Columns of d²·J, J = ∂q/∂(u_l, v_l, u_r, v_r): no division until the weight. The two right
    // columns are cₖ·Π(v_l): only ρ = c₁² + c₂² enters Σ and its determinant.
    let j0 = numerator * (d * along_axis(q2.yzw, t) - ta_u * pv);
    let j1 = numerator * (d * along_axis(q3.xyz, t) - ta_v * pv);
    let c1 = tc_u * d - numerator * te_u;
    let c2 = tc_v * d - numerator * te_v;
    let rho = c1 * c1 + c2 * c2;
    let sxx = j0.x * j0.x + j1.x * j1.x + rho * pv.x * pv.x;
    let sxy = j0.x * j0.y + j1.x * j1.y + rho * pv.x * pv.y;
    let syy = j0.y * j0.y + j1.y * j1.y + rho * pv.y * pv.y;
    // det(d⁴Σ) by Cauchy–Binet (never negative).
    let m01 = minor2(j0, j1);
    let m0v = minor2(j0, pv);
    let m1v = minor2(j1, pv);
    let det = m01 * m01 + rho * (m0v * m0v + m1v * m1v);
    let trace = sxx + syy;
    let d2 = d * d;
    let ridge = 1e-12 * trace + 1e-30 * d2 * d2;
    let det_ridged = det + ridge * trace + ridge * ridge;
    let sigma_d2 = ta_u * ta_u + ta_v * ta_v + te_u * te_u + te_v * te_v;
    let inverse = recip_exact((d2 + TAPER * TAPER * sigma_d2) * det_ridged);
    terms.q_prime = numerator * pv;
    terms.d = d;
    terms.adj = vec3r(syy + ridge, -sxy, sxx + ridge);
    terms.d4_inverse = d2 * d2 * inverse;
    terms.taper = d2 * det_ridged * inverse;
    terms.g = q8.yz;
    return terms;
}

// The affine map q_ref(g) = origin + M·g through the reference corners (Reference of
// calib::affine_grid); zero where they cannot give one.
struct Reference {
    origin: vec2r,
    map: vec4r, // M by rows: (m₀₀, m₀₁, m₁₀, m₁₁)
}

// The map through the corners at vec4 start, start + ROW/4, start + 2·ROW/4 of a view of `count`
// corners: M = Q·G⁻¹, origin = q₀ − M·g₀.
fn reference_map(start: u32, count: u32, t: vec3r) -> Reference {
    var none: Reference;
    none.origin = vec2r(0.0);
    none.map = vec4r(0.0);
    if (count < 3u) {
        return none;
    }
    let c0 = corner_terms(start, t);
    let c1 = corner_terms(start + ROW / 4u, t);
    let c2 = corner_terms(start + 2u * (ROW / 4u), t);
    if (!(c0.ok && c1.ok && c2.ok) || !(c0.taper >= MIN_REFERENCE_TAPER && c1.taper >= MIN_REFERENCE_TAPER && c2.taper >= MIN_REFERENCE_TAPER)) {
        return none;
    }
    let q0 = vec2r(div_exact(c0.q_prime.x, c0.d), div_exact(c0.q_prime.y, c0.d));
    let q1 = vec2r(div_exact(c1.q_prime.x, c1.d), div_exact(c1.q_prime.y, c1.d)) - q0;
    let q2 = vec2r(div_exact(c2.q_prime.x, c2.d), div_exact(c2.q_prime.y, c2.d)) - q0;
    let g1 = c1.g - c0.g;
    let g2 = c2.g - c0.g;
    let det = g1.x * g2.y - g2.x * g1.y;
    if (!(det != 0.0) || !(abs(det) <= REAL_HUGE)) {
        return none;
    }
    let inv_det = recip_exact(det);
    // G⁻¹ by rows.
    let gi0 = vec2r(g2.y * inv_det, -g2.x * inv_det);
    let gi1 = vec2r(-g1.y * inv_det, g1.x * inv_det);
    let m = vec4r(q1.x * gi0.x + q2.x * gi1.x, q1.x * gi0.y + q2.x * gi1.y,
                  q1.y * gi0.x + q2.y * gi1.x, q1.y * gi0.y + q2.y * gi1.y);
    var r: Reference;
    r.map = m;
    r.origin = vec2r(q0.x - (m.x * c0.g.x + m.y * c0.g.y), q0.y - (m.z * c0.g.x + m.w * c0.g.y));
    return r;
}

// d·(q − q_ref(g)) of a corner, from q′ = d·q: no division.
fn shifted(reference: Reference, c: CornerTerms) -> vec2r {
    let at = vec2r(reference.origin.x + (reference.map.x * c.g.x + reference.map.y * c.g.y),
                   reference.origin.y + (reference.map.z * c.g.x + reference.map.w * c.g.y));
    return vec2r(c.q_prime.x - c.d * at.x, c.q_prime.y - c.d * at.y);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let per_view = params.info.y;
    let view = i / per_view + params.info.w;
    let candidate = i % per_view;
    let n = candidates[candidate].xyz;
    let t = vec3r(div_exact(n.x, n.z), div_exact(n.y, n.z), 1.0);
    let table = input[view];
    let start = u32(table.x);
    let end = start + (ROW / 4u) * u32(table.y);
    let reference = reference_map(start, u32(table.y), t);

    // W₁₁, W₁₂, W₂₂ times (g_x², g_x g_y, g_x) in *_a and (g_y², g_y, 1) in *_b.
    var s11_a = vec3r(0.0);
    var s11_b = vec3r(0.0);
    var s12_a = vec3r(0.0);
    var s12_b = vec3r(0.0);
    var s22_a = vec3r(0.0);
    var s22_b = vec3r(0.0);
    var r1 = vec3r(0.0);
    var r2 = vec3r(0.0);
    var qwq: real = 0.0;
    var weight: real = 0.0;
    var used = 0u;
    for (var k = start; k < end; k += ROW / 4u) {
        let c = corner_terms(k, t);
        if (!c.ok) {
            continue;
        }
        let scale = c.d * c.d * c.d4_inverse;
        let w11 = c.adj.x * scale;
        let w12 = c.adj.y * scale;
        let w22 = c.adj.z * scale;
        let gx = c.g.x;
        let gy = c.g.y;
        let ga = vec3r(gx * gx, gx * gy, gx);
        let gb = vec3r(gy * gy, gy, 1.0);
        s11_a += w11 * ga;
        s11_b += w11 * gb;
        s12_a += w12 * ga;
        s12_b += w12 * gb;
        s22_a += w22 * ga;
        s22_b += w22 * gb;
        // With q̃′ = d·q̃: Wq̃ = d·d4_inverse·adj·q̃′, q̃ᵀWq̃ = d4_inverse·q̃′ᵀ adj q̃′.
        let q = shifted(reference, c);
        let adj_q = vec2r(c.adj.x * q.x + c.adj.y * q.y, c.adj.y * q.x + c.adj.z * q.y);
        let wq = (c.d * c.d4_inverse) * adj_q;
        let g3 = vec3r(gx, gy, 1.0);
        r1 += wq.x * g3;
        r2 += wq.y * g3;
        qwq += c.d4_inverse * dot(q, adj_q);
        weight += c.taper;
        used += 1u;
    }
    if (used < MIN_CORNERS) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    // Cholesky of the normal matrix over (a₁₁, a₁₂, b₁, a₂₁, a₂₂, b₂), written out (a local
    // array indexed in loops lives in memory on SIMD drivers), then y = L⁻¹ rhs and
    // χ² = Σ qᵀWq − |y|². Entry (r, c) is block (r/3, c/3) of the sums at (r%3, c%3).
    let d0 = s11_a.x;
    if (!(d0 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l00 = sqrt_exact(d0);
    let inv0 = recip_exact(l00);
    let l10 = (s11_a.y) * inv0;
    let l20 = (s11_a.z) * inv0;
    let l30 = (s12_a.x) * inv0;
    let l40 = (s12_a.y) * inv0;
    let l50 = (s12_a.z) * inv0;
    let d1 = s11_b.x - l10 * l10;
    if (!(d1 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l11 = sqrt_exact(d1);
    let inv1 = recip_exact(l11);
    let l21 = (s11_b.y - l20 * l10) * inv1;
    let l31 = (s12_a.y - l30 * l10) * inv1;
    let l41 = (s12_b.x - l40 * l10) * inv1;
    let l51 = (s12_b.y - l50 * l10) * inv1;
    let d2 = s11_b.z - l20 * l20 - l21 * l21;
    if (!(d2 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l22 = sqrt_exact(d2);
    let inv2 = recip_exact(l22);
    let l32 = (s12_a.z - l30 * l20 - l31 * l21) * inv2;
    let l42 = (s12_b.y - l40 * l20 - l41 * l21) * inv2;
    let l52 = (s12_b.z - l50 * l20 - l51 * l21) * inv2;
    let d3 = s22_a.x - l30 * l30 - l31 * l31 - l32 * l32;
    if (!(d3 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l33 = sqrt_exact(d3);
    let inv3 = recip_exact(l33);
    let l43 = (s22_a.y - l40 * l30 - l41 * l31 - l42 * l32) * inv3;
    let l53 = (s22_a.z - l50 * l30 - l51 * l31 - l52 * l32) * inv3;
    let d4 = s22_b.x - l40 * l40 - l41 * l41 - l42 * l42 - l43 * l43;
    if (!(d4 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l44 = sqrt_exact(d4);
    let inv4 = recip_exact(l44);
    let l54 = (s22_b.y - l50 * l40 - l51 * l41 - l52 * l42 - l53 * l43) * inv4;
    let d5 = s22_b.z - l50 * l50 - l51 * l51 - l52 * l52 - l53 * l53 - l54 * l54;
    if (!(d5 > 0.0)) {
        status[params.info.z + i] = STATUS_DEGENERATE;
        return;
    }
    let l55 = sqrt_exact(d5);
    let inv5 = recip_exact(l55);
    let y0 = (r1.x) * inv0;
    let y1 = (r1.y - l10 * y0) * inv1;
    let y2 = (r1.z - l20 * y0 - l21 * y1) * inv2;
    let y3 = (r2.x - l30 * y0 - l31 * y1 - l32 * y2) * inv3;
    let y4 = (r2.y - l40 * y0 - l41 * y1 - l42 * y2 - l43 * y3) * inv4;
    let y5 = (r2.z - l50 * y0 - l51 * y1 - l52 * y2 - l53 * y3 - l54 * y4) * inv5;
    let explained = y0 * y0 + y1 * y1 + y2 * y2 + y3 * y3 + y4 * y4 + y5 * y5;
    var chi2 = max(qwq - explained, 0.0);
    // The fit's conditioning: max Aₖₖ / Lₖₖ² over the pivots (Fit::conditioning of the twin).
    let conditioning = max(max(max(1.0, s11_b.x / d1), max(s11_b.z / d2, s22_a.x / d3)),
                           max(s22_b.x / d4, s22_b.z / d5));
    if (chi2 < CANCELLATION * conditioning * qwq) {
        // The one pass may have lost more than 5e-10 (cancellation κ̃ times the factor's
        // conditioning): sum Σ rᵀWr again with θ = L⁻ᵀ y.
        let th5 = (y5) * inv5;
        let th4 = (y4 - l54 * th5) * inv4;
        let th3 = (y3 - l43 * th4 - l53 * th5) * inv3;
        let th2 = (y2 - l32 * th3 - l42 * th4 - l52 * th5) * inv2;
        let th1 = (y1 - l21 * th2 - l31 * th3 - l41 * th4 - l51 * th5) * inv1;
        let th0 = (y0 - l10 * th1 - l20 * th2 - l30 * th3 - l40 * th4 - l50 * th5) * inv0;
        chi2 = 0.0;
        for (var k = start; k < end; k += ROW / 4u) {
            let c = corner_terms(k, t);
            if (!c.ok) {
                continue;
            }
            let inv_d = recip_exact(c.d);
            let q = shifted(reference, c);
            let r = vec2r(q.x * inv_d - (th0 * c.g.x + th1 * c.g.y + th2), q.y * inv_d - (th3 * c.g.x + th4 * c.g.y + th5));
            chi2 += c.d * c.d * c.d4_inverse * (c.adj.x * r.x * r.x + 2.0 * c.adj.y * r.x * r.y + c.adj.z * r.y * r.y);
        }
    }
    let o = params.info.z + i;
    output[2u * o] = chi2;
    output[2u * o + 1u] = 2.0 * weight - 6.0;
    status[o] = STATUS_OK;
}
