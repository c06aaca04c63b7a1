// The stereo kernels' shared uniform and buffers (src/stereo/gpu/). `Sweep` is mirrored by the
// `#[repr(C)]` struct `Sweep` in src/stereo/gpu/mod.rs: keep them in sync (a test compares the
// sizes). Every stereo kernel runs in f32 (the photometric part and the sweep's geometry; the
// host's depths and points are f64, docs/stereo.md).

struct Sweep {
    width: u32,        // reference image
    height: u32,
    hypotheses: u32,   // D
    first: u32,        // the chunk's first hypothesis
    chunk: u32,        // hypotheses per chunk (the warped buffer's stride)
    voters: u32,       // cameras that vote
    radius: u32,       // ZNCC window radius r
    voter: u32,        // this dispatch's voter (warp)
    voter_width: u32,  // its image
    voter_height: u32,
    p1: u32,           // SGM penalties, cost units
    p2: u32,
    q0: f32,           // inverse depth of hypothesis 0, 1/m
    dq: f32,           // inverse-depth step
    min_texture: f32,  // least standard deviation of a matched window
    gradient: f32,     // grey change that halves P2
    paths: u32,        // SGM path directions, 4 or 8 (the first of `SGM_DIRECTIONS`)
    strip: u32,        // rows one invocation of the ZNCC kernel walks
    group_lines: u32,  // SGM path lines a workgroup walks together (1, 2, 4 or 8)
    pad: u32,
}

// The cost volume and the aggregated costs are packed, two u16 a u32 (every cost ≤ NO_VOTE, every
// L ≤ NO_VOTE + P2 < 4 096, so the sum of 8 paths < 32 768 never carries into the next half):
// hypothesis k of pixel p is the low half (k even) or the high half (k odd) of word
// p·⌈D/2⌉ + k/2. `GpuStereo::volume_bytes` on the host.
fn volume_word(p: u32, k: u32) -> u32 {
    return p * ((sweep.hypotheses + 1u) / 2u) + k / 2u;
}

// Hypothesis k's half of its word.
fn volume_half(word: u32, k: u32) -> u32 {
    return (word >> ((k & 1u) * 16u)) & 0xFFFFu;
}

// The cameras (reference 0, voter 1), read by the kernels that project; in the others unused,
// so absent from their pipelines' layouts.
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> sweep: Sweep;

// A cost of 1 (ZNCC ≤ 0) and the cost where no camera votes: `COST_SCALE` and `NO_VOTE` of
// src/stereo/cost.rs.
const COST_SCALE: u32 = 2047u;
const NO_VOTE: u32 = 2048u;
// A warped sample without an answer (the images are finite; NaN is not used on the device).
const NO_SAMPLE: f32 = -1e30;
// ZNCC without a vote.
const NO_ZNCC: f32 = 8.0;
// A warped window's spread ΣW² − (ΣW)²/n below this fraction of ΣW² is within the f32 sums'
// rounding (about (2·(strip + 2r) + 2r + 1)·u ≤ 4e-6 for r ≤ 15): flat, ZNCC 0.
const ZNCC_FLAT: f32 = 1e-5;
// The most voting cameras of one depth map.
const MAX_VOTERS: u32 = 8u;
