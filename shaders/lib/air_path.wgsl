// Forward projection: how light from a point in the water reaches the camera, the pixel it lands
// on, and the point's VOP. Twin of `RefractiveCamera::{air_path_to, project, vop}`
// (src/model/refractive_camera.rs): the same equation, reference-medium switching, bracket,
// bisection fallback and stopping rules, with the precision's tolerance.
//
// f(v) = Σₘ Lₘ T(v; kₘ) − r, T(v; k) = k v / √(1 + (1 − k²) v²), v = tan θ in the reference
// medium, kₘ = ρ_ref / ρₘ, over the media m = air (d_k), water (depth), layers (tᵢ).

// Medium i of a path as (length along the axis, ρ = μ/μ_air): 0 = air (d_k), 1 = water at
// `depth`, 2 = the first layer (from the View), 3.. = the later layers, read from the uniform (a
// local array of media, dynamically indexed, lives in memory on SIMD drivers).
fn medium(cam: View, depth: real, i: u32) -> vec2r {
    if (i == 0u) {
        return vec2r(cam.d_k, 1.0);
    }
    if (i == 1u) {
        return vec2r(depth, cam.rho_water);
    }
    if (i == 2u) {
        return cam.first_layer.xy;
    }
    return later_layer(cam, i - 2u).xy;
}

fn media_count(cam: View) -> u32 {
    return cam.layers + 2u;
}

// f, f′ in the variable of the reference medium of index rho_ref, and the medium whose term
// contributes most to f′ as (length, ρ).
struct Equation {
    f: real,
    df: real,
    dominant: vec2r,
}

fn incidence_equation(cam: View, depth: real, v: real, rho_ref: real, r: real) -> Equation {
    let v2 = v * v;
    var f = -r;
    var df: real = 0.0;
    var dominant = vec2r(0.0, 1.0);
    var dominant_slope: real = 0.0;
    for (var i = 0u; i < media_count(cam); i++) {
        let medium = medium(cam, depth, i);
        let k = rho_ref / medium.y;
        let inv_sqrt = 1.0 / sqrt(1.0 + (1.0 - k * k) * v2);
        let lk = medium.x * k * inv_sqrt;
        let slope = lk * inv_sqrt * inv_sqrt;
        f += lk * v;
        df += slope;
        if (slope > dominant_slope) {
            dominant = medium;
            dominant_slope = slope;
        }
    }
    return Equation(f, df, dominant);
}

// Upper end of the bracket in the variable of the reference medium: f(r / L_ref) ≥ 0, and light
// must enter every medium (v < 1/√(k² − 1) where k > 1).
fn bracket_top(cam: View, depth: real, r: real, reference: vec2r) -> real {
    var hi = r / reference.x;
    for (var i = 0u; i < media_count(cam); i++) {
        let k = reference.y / medium(cam, depth, i).y;
        if (k > 1.0) {
            hi = min(hi, 1.0 / sqrt(k * k - 1.0));
        }
    }
    return hi;
}

// T(x; k): the tangent in another medium; REAL_HUGE past its critical angle.
fn map_tangent(x: real, k: real) -> real {
    let q = 1.0 + (1.0 - k * k) * x * x;
    if (q > 0.0) {
        return k * x / sqrt(q);
    }
    return REAL_HUGE;
}

// The iteration state: v, bracket [lo, hi], f′ and the reference medium (length, ρ).
struct Newton {
    v: real,
    lo: real,
    hi: real,
    df: real,
    reference: vec2r,
}

// Whether the angle of medium `to` can carry the iterate: the map keeps it to SWITCH_MAX_Q·ε
// (coming back multiplies a rounding by q). Far to the side the water's term has the steepest
// slope while its angle sits at the critical cap within rounding; there the iteration stays in the
// air's variable. Twin of PathMedia::resolves.
fn resolves(s: Newton, to: vec2r) -> bool {
    let k = s.reference.y / to.y;
    let q = 1.0 + (1.0 - k * k) * s.v * s.v;
    return q > 0.0 && q <= SWITCH_MAX_Q;
}

// Moves the iteration to the angle of medium `to`: v and the bracket map through T(·; ρ_ref/ρ_to),
// f′ is divided by T′, and the mapped top is capped by `to`'s own bound (is that bound where no
// evaluation has lowered the old top).
fn reparametrise(cam: View, depth: real, s: Newton, to: vec2r, r: real) -> Newton {
    let k = s.reference.y / to.y;
    let q = 1.0 + (1.0 - k * k) * s.v * s.v;
    let df = s.df / (k / (q * sqrt(q)));
    // A top no evaluation has lowered is the old medium's own bound, often its critical angle
    // rounded down, whose image falls short of a grazing root: take the new medium's bound.
    let top = bracket_top(cam, depth, r, to);
    var hi = top;
    if (s.hi < bracket_top(cam, depth, r, s.reference)) {
        hi = min(map_tangent(s.hi, k), top);
    }
    return Newton(map_tangent(s.v, k), map_tangent(s.lo, k), hi, df, to);
}

// tan a from the tangent v in the reference medium of index rho_ref.
fn tan_incidence_from(v: real, rho_ref: real) -> real {
    return rho_ref * v / sqrt(1.0 + (1.0 - rho_ref * rho_ref) * v * v);
}

// tan a of the path to a point at `depth` and lateral distance r > 0; `ok` false if the
// iteration bound is hit.
fn solve_tan_incidence(cam: View, depth: real, r: real) -> Maybe {
    // Start in the medium with the largest paraxial weight L/ρ, from the paraxial root.
    var reference = vec2r(cam.d_k, 1.0);
    var paraxial_slope: real = 0.0;
    var slowest = vec2r(0.0, REAL_HUGE);
    for (var i = 0u; i < media_count(cam); i++) {
        let medium = medium(cam, depth, i);
        paraxial_slope += medium.x / medium.y;
        if (medium.x / medium.y > reference.x / reference.y) {
            reference = medium;
        }
        if (medium.y < slowest.y) {
            slowest = medium;
        }
    }
    var s = Newton(r / (paraxial_slope * reference.y), 0.0, 0.0, 0.0, reference);
    s.hi = bracket_top(cam, depth, r, reference);
    if (!(s.v > s.lo && s.v < s.hi)) {
        s.v = 0.5 * (s.lo + s.hi);
    }
    for (var iteration = 1u; iteration <= PROJECT_MAX_ITERATIONS; iteration++) {
        let e = incidence_equation(cam, depth, s.v, s.reference.y, r);
        if (e.f < 0.0) {
            s.lo = s.v;
        } else if (e.f > 0.0) {
            s.hi = s.v;
        } else if (e.f == 0.0) {
            return Maybe(tan_incidence_from(s.v, s.reference.y), true);
        } else {
            // NaN at a critical-angle cap, or v² overflowed (r / d_k > √REAL_HUGE: out of
            // range): never a silent root.
            return Maybe(0.0, false);
        }
        s.df = e.df;
        if (e.dominant.y != s.reference.y && resolves(s, e.dominant)) {
            s = reparametrise(cam, depth, s, e.dominant, r);
        }
        var step = e.f / s.df;
        if (s.v - step >= s.hi && slowest.y != s.reference.y) {
            // The step leaves through the slowest medium's critical angle: continue in its angle.
            s = reparametrise(cam, depth, s, slowest, r);
            step = e.f / s.df;
        }
        if (s.v >= REAL_HUGE) {
            // The iterate sat at the new medium's critical angle within rounding: bisect, and test
            // convergence only where f was evaluated; f(0) = −r < 0 bottoms a collapsed bracket.
            if (!(s.lo < s.hi)) {
                s.lo = 0.0;
            }
            s.v = 0.5 * (s.lo + s.hi);
            continue;
        }
        if (abs(step) <= PROJECT_TOLERANCE * s.v) {
            return Maybe(tan_incidence_from(s.v - step, s.reference.y), true);
        }
        var next = s.v - step;
        if (!(next > s.lo && next < s.hi)) {
            next = 0.5 * (s.lo + s.hi);
        }
        if (s.hi - s.lo <= PROJECT_TOLERANCE * s.hi) {
            return Maybe(tan_incidence_from(next, s.reference.y), true);
        }
        s.v = next;
    }
    return Maybe(0.0, false);
}

struct AirPath {
    dir: vec3r,   // unit air ray from the camera centre, master frame
    tan_a: real,  // tan a
    depth: real,  // x
    r: real,      // distance from the line C_k + s·n
    status: u32,
}

fn air_path_to(cam: View, point: vec3r) -> AirPath {
    let n = cam.n;
    let offset = point - cam.centre;
    let z = dot(n, offset);
    let depth = z - cam.d_k - cam.thickness;
    if (!(depth > 0.0)) {
        return AirPath(vec3r(0.0), 0.0, depth, 0.0, STATUS_NOT_IN_WATER);
    }
    let lateral = offset - n * z;
    let r = length_scaled(lateral);
    if (r == 0.0) {
        return AirPath(n, 0.0, depth, 0.0, STATUS_OK);
    }
    let tau = solve_tan_incidence(cam, depth, r);
    if (!tau.ok) {
        var status = STATUS_NO_CONVERGENCE;
        if (above_root_huge(r / cam.d_k)) { // tan a > √REAL_HUGE: its square overflows
            status = STATUS_OUT_OF_RANGE;
        }
        return AirPath(vec3r(0.0), 0.0, depth, r, status);
    }
    if (above_root_huge(r / cam.d_k)) {
        // tan a may be beyond √REAL_HUGE, where the iteration's squares overflow: accept the root
        // only if the lateral offsets, summed without squares of tan a, give r.
        var residual = cam.d_k * tau.value - r;
        for (var i = 1u; i < media_count(cam); i++) {
            let m = medium(cam, depth, i);
            let k = 1.0 / m.y;
            residual += m.x * k / sqrt((1.0 / tau.value) * (1.0 / tau.value) + 1.0 - k * k);
        }
        if (!(abs(residual) <= 1e-6 * r)) {
            return AirPath(vec3r(0.0), 0.0, depth, r, STATUS_OUT_OF_RANGE);
        }
    }
    var dir: vec3r;
    if (above_root_huge(tau.value)) {
        // Near grazing, where τ² would overflow: the same direction divided by τ.
        let inv_tau = 1.0 / tau.value;
        dir = (n * inv_tau + lateral * (1.0 / r)) / sqrt(1.0 + inv_tau * inv_tau);
    } else {
        dir = (n + lateral * (tau.value / r)) / sqrt(1.0 + tau.value * tau.value);
    }
    return AirPath(dir, tau.value, depth, r, STATUS_OK);
}

// x > √REAL_HUGE, without a square that could overflow (naga evaluates no sqrt of an f64 constant).
fn above_root_huge(x: real) -> bool {
    return x > 1.0 && x > REAL_HUGE / x;
}

// |v| without overflow of the squares: scaled by the largest component above √REAL_HUGE (twin of
// `length` in src/model/refractive_camera.rs, whose threshold 1e150 is √REAL_HUGE in f64).
fn length_scaled(v: vec3r) -> real {
    let largest = max(abs(v.x), max(abs(v.y), abs(v.z)));
    if (above_root_huge(largest)) {
        return largest * length(v * (1.0 / largest));
    }
    return length(v);
}

struct Pixel {
    pixel: vec2r,
    status: u32,
}

// Forward projection: the raw pixel at which a point in the water appears.
fn project(cam: View, point: vec3r) -> Pixel {
    let path = air_path_to(cam, point);
    if (path.status != STATUS_OK) {
        return Pixel(vec2r(0.0), path.status);
    }
    return pixel_along(cam, path.dir);
}

// The raw pixel of the air ray along `dir` (master frame; any positive multiple of the direction
// gives the same pixel), with `project`'s checks.
fn pixel_along(cam: View, dir: vec3r) -> Pixel {
    let d = cam_from_master(cam, dir);
    if (!(d.z > 0.0)) {
        return Pixel(vec2r(0.0), STATUS_BEHIND_CAMERA);
    }
    let normalized = d.xy / d.z;
    if (!(dot(normalized, normalized) < cam.fold2)) {
        return Pixel(vec2r(0.0), STATUS_OUTSIDE_LENS);
    }
    return Pixel(img_from_normalized(cam, normalized), STATUS_OK);
}

// Most Newton steps of `project_near_pair` before it leaves the point to `project`.
const NEAR_MAX_ITERATIONS: u32 = 16u;

struct NearPixel {
    pixel: Pixel,
    converged: bool,
}

// A layer (t, k = 1/ρ)'s terms (f, f′, f″) of `project_near_pair`'s equation at x = tan a:
// t·T(x; k) and its derivatives, with T(x; k) = k x / √q, q = 1 + (1 − k²) x² (see there).
fn near_layer_terms(layer: vec2r, x: real) -> vec3r {
    let k = layer.y;
    let s = inverseSqrt(1.0 + (1.0 - k * k) * x * x);
    let slope = k * s * s * s;
    return vec3r(layer.x * k * s * x, layer.x * slope, layer.x * (k * k - 1.0) * 3.0 * x * slope * s * s);
}

// A point's place about a camera's axis line C_k + s·n, for `project_near_pair`.
struct NearPath {
    lateral: vec3r, // the point − C_k − z·n
    r: real,        // |lateral|
    depth: real,    // beyond the outer interface
}

fn near_path(cam: View, point: vec3r) -> NearPath {
    let offset = point - cam.centre;
    let z = dot(cam.n, offset);
    let lateral = offset - cam.n * z;
    return NearPath(lateral, length(lateral), z - cam.d_k - cam.thickness);
}

// `project_near_pair`'s equation (f, f′, f″) at x = tan a.
fn near_equation(cam: View, path: NearPath, x: real) -> vec3r {
    // T(x; k) = k x / √q, T′ = k / √q³, T″ = −3 (1 − k²) x T′ / q, q = 1 + (1 − k²) x²:
    // with s = 1/√q, T = k s x, T′ = k s³, T″ = 3 (k² − 1) x T′ s² (no division).
    let k_water = 1.0 / cam.rho_water;
    let s = inverseSqrt(1.0 + (1.0 - k_water * k_water) * x * x);
    let slope = k_water * s * s * s;
    // The air and the water, the first layer (a layer of air, which adds nothing, when there is
    // none), then the later layers to RIG_LAYERS (common.wgsl); one the camera lacks is packed as
    // zeros (t = 0, 1/ρ = 0) and adds nothing.
    var terms = vec3r(
        cam.d_k * x + path.depth * k_water * s * x - path.r,
        cam.d_k + path.depth * slope,
        path.depth * (k_water * k_water - 1.0) * 3.0 * x * slope * s * s,
    ) + near_layer_terms(cam.first_layer.xz, x);
    for (var l = 1u; l < RIG_LAYERS; l++) {
        terms += near_layer_terms(later_layer(cam, l).xz, x);
    }
    return terms;
}

// Whether the Newton step from x settles `project_near_pair`'s iteration: the step is within
// the tolerance, or the step's own error, by the quadratic model |f″| step² / 2f′, is within half
// of it. The model holds where f″ barely changes over the step (|f″| grows with x from 0): only for
// steps under 1 % of x.
fn near_settles(terms: vec3r, step: real, x: real) -> bool {
    let modelled = abs(step) <= 0.01 * x && abs(terms.z) * step * step <= PROJECT_TOLERANCE * x * terms.y;
    return abs(step) <= PROJECT_TOLERANCE * x || modelled;
}

// The pixel of the root tau, and whether `project_near_pair` answers for `project` there. A point
// not in the water is `project`'s first check, whatever the iteration did: it is answered here.
fn near_pixel(cam: View, path: NearPath, tau: real, settled: bool) -> NearPixel {
    let in_water = path.depth > 0.0;
    // Beyond √REAL_HUGE the squares of tan a overflow: `project` scales them.
    let converged = !in_water || (settled && cam.dense && !above_root_huge(path.r / cam.d_k));
    // n·r + lateral·tan a: the air direction times r√(1 + tan² a); n itself on the axis.
    var pixel = pixel_along(cam, select(cam.n * path.r + path.lateral * tau, cam.n, path.r == 0.0));
    if (!in_water) {
        pixel = Pixel(vec2r(0.0), STATUS_NOT_IN_WATER);
    }
    return NearPixel(pixel, converged);
}

// Forward projection of two points seen near known air rays, each in its camera (one corner in
// both cameras of a stereo pair, or two rows of the forward projection), without `project`'s
// safeguards: Newton's iteration on f(x) = d_k x + Σₘ Lₘ T(x; 1/ρₘ) − r in x = tan a (water and
// layers m), from `tan_start` (the tan a of a ray each point is seen near). Where no medium is
// less dense than air (ρ ≥ 1), every term is increasing and concave in x, so the iterates, clamped
// at 0, approach the root from below after their first step, with no bracket to keep. Each stops
// at `project`'s tolerance on the step (`near_settles`). `converged` false (a medium less dense
// than air, a step that does not shrink to the tolerance within NEAR_MAX_ITERATIONS, a non-finite
// value, tan a beyond √REAL_HUGE): the caller takes `project`, which decides. Converged, the pixel
// and status are `project`'s (STATUS_NOT_IN_WATER for a point not in the water, `project`'s first
// test).
//
// The two iterations run in one loop, until both have settled: each is a chain of dependent square
// roots and divisions, and a CPU driver (lavapipe) overlaps two independent chains where it would
// run one loop after the other. On a SIMD driver every branch of a loop body runs for every lane,
// masked: this loop body is a fraction of `project`'s.
struct NearPair {
    a: NearPixel,
    b: NearPixel,
}

fn project_near_pair(a: View, point_a: vec3r, b: View, point_b: vec3r, tan_start: vec2r) -> NearPair {
    let path_a = near_path(a, point_a);
    let path_b = near_path(b, point_b);
    var x = max(tan_start, vec2r(0.0));
    var tau = vec2r(0.0);
    var settled = vec2<bool>(false);
    for (var iteration = 0u; iteration < NEAR_MAX_ITERATIONS; iteration++) {
        let terms_a = near_equation(a, path_a, x.x);
        let terms_b = near_equation(b, path_b, x.y);
        let step = vec2r(terms_a.x / terms_a.y, terms_b.x / terms_b.y);
        let now = !settled & vec2<bool>(near_settles(terms_a, step.x, x.x), near_settles(terms_b, step.y, x.y));
        tau = select(tau, x - step, now);
        settled = settled | now;
        if (all(settled)) {
            break;
        }
        x = max(x - step, vec2r(0.0));
    }
    return NearPair(near_pixel(a, path_a, tau.x, settled.x), near_pixel(b, path_b, tau.y, settled.y));
}

struct VirtualPoint {
    depth: real,
    vop_distance: real,
    vop: vec3r,
    tan_a: real,
    status: u32,
}

// The VOP: x̌ = r / tan a − d_k − Σ tᵢ (eq 4.8 on the camera's axis line, r = 0), Ǒ = O + (x̌ − x)·n.
fn vop(cam: View, point: vec3r) -> VirtualPoint {
    let path = air_path_to(cam, point);
    if (path.status != STATUS_OK) {
        return VirtualPoint(path.depth, 0.0, vec3r(0.0), 0.0, path.status);
    }
    var vop_distance: real = 0.0;
    if (path.tan_a > 0.0) {
        vop_distance = path.r / path.tan_a - cam.d_k - cam.thickness;
    } else {
        let axial = virtual_from_real(cam, path.depth, 0.0, 1.0);
        if (!axial.ok) {
            return VirtualPoint(path.depth, 0.0, vec3r(0.0), 0.0, STATUS_TOTAL_INTERNAL_REFLECTION);
        }
        vop_distance = axial.value;
    }
    let v = point + cam.n * (vop_distance - path.depth);
    return VirtualPoint(path.depth, vop_distance, v, path.tan_a, STATUS_OK);
}
