//! The tabulated projection of the depth hypotheses (`flatport::stereo::table`) against the exact
//! projection of every pixel's point (`project_hypotheses`, Newton on the refraction equation),
//! over every pixel of whole images, for a shared tilted port with glass, two housings and three
//! cameras above a bare water surface (all with lens distortion), at depths from inside the ports
//! to far away: the interpolated pixels within the stated tolerance, the pixels without an answer
//! answered exactly as the exact projection answers them. Release mode: `cargo test --release
//! --test stereo_table`.

mod stereo_common;

use flatport::model::{RefractiveCamera, Rig};
use flatport::stereo::GreyImage;
use flatport::stereo::cost::{air_ray_starts, project_hypotheses, warp_bilinear};
use flatport::stereo::rays::{RayGrid, hypothesis_points, reference_rays};
use flatport::stereo::table::{
    ProjectionTable, TABLE_STEP, TABLE_TOLERANCE_PX, TableBand, project_tabulated, warp_tabulated,
};
use stereo_common::*;

/// Rows per band and halo, as the cost volume sweeps them.
const BAND_ROWS: usize = 32;
const HALO: usize = 3;

/// What a comparison over one image and depth found.
#[derive(Debug, Default)]
struct Found {
    pixels: usize,
    interpolated: usize,
    no_answer: usize,
    max_error: f64,
}

/// The exact projections of every pixel's point at depth `z` into `voter`.
fn exact(rays: &RayGrid, voter: &RefractiveCamera, z: f64) -> (Vec<[f64; 2]>, Vec<u32>) {
    let n = rays.width * rays.height;
    let mut points = vec![[0.0; 3]; n];
    let mut starts = vec![0.0; n];
    hypothesis_points(rays, 0, 1.0 / z, voter.centre().coords.into(), &mut points);
    air_ray_starts(rays, 0, voter, &mut starts);
    let (mut pixels, mut status) = (vec![[0.0; 2]; n], vec![0u32; n]);
    project_hypotheses(voter, &points, &starts, &mut pixels, &mut status);
    (pixels, status)
}

/// Tabulated (nodes every `step` pixels, bands of [`BAND_ROWS`] rows with a halo) against exact,
/// over every pixel.
fn compare(rig: &Rig, reference: usize, voter: usize, step: usize, depths: &[f64]) -> Found {
    let (ref_camera, voter) = (
        rig.refractive_camera(reference),
        rig.refractive_camera(voter),
    );
    let rays = reference_rays(&ref_camera);
    let (w, h) = (rays.width, rays.height);
    let table = ProjectionTable::with_step(&ref_camera, w, h, step);
    // A textured image of the voter's size to sample.
    let (vw, vh) = (
        voter.intrinsics().width as usize,
        voter.intrinsics().height as usize,
    );
    let image = GreyImage {
        width: vw as u32,
        height: vh as u32,
        pixels: (0..vw * vh)
            .map(|i| {
                let (x, y) = ((i % vw) as f32, (i / vw) as f32);
                0.5 + 0.25 * (0.37 * x).sin() * (0.23 * y + 0.1 * x).cos()
            })
            .collect(),
    };
    let mut found = Found::default();
    for &z in depths {
        let before = (found.pixels, found.interpolated);
        let (want, want_status) = exact(&rays, &voter, z);
        for first in (0..h).step_by(BAND_ROWS) {
            let (ext_first, ext_end) = (
                first.saturating_sub(HALO),
                (first + BAND_ROWS + HALO).min(h),
            );
            let n = (ext_end - ext_first) * w;
            let mut band = TableBand::new(&table, &rays, ext_first, ext_end - ext_first, &voter);
            let mut starts = vec![0.0; n];
            air_ray_starts(&rays, ext_first, &voter, &mut starts);
            let (mut pixels, mut status) = (vec![[0.0; 2]; n], vec![0u32; n]);
            let counts = project_tabulated(
                &table,
                &mut band,
                &rays,
                &voter,
                &starts,
                1.0 / z,
                &mut pixels,
                &mut status,
            );
            assert_eq!(counts.interpolated + counts.exact, n);
            // Sampled as it projects: the same samples as the stored projections warped.
            let mut fused = vec![0f32; n];
            let mut fresh = TableBand::new(&table, &rays, ext_first, ext_end - ext_first, &voter);
            let fused_counts = warp_tabulated(
                &table,
                &mut fresh,
                &rays,
                &voter,
                &starts,
                1.0 / z,
                &image,
                &mut fused,
            );
            assert_eq!(fused_counts, counts);
            let mut warped = vec![0f32; n];
            warp_bilinear(&image, &pixels, &status, &mut warped);
            for j in 0..n {
                assert!(
                    fused[j].to_bits() == warped[j].to_bits(),
                    "z {z} m, band pixel {j}: sampled as projected {} against stored {}",
                    fused[j],
                    warped[j]
                );
            }
            let exact_pixels = band.exact_pixels();
            for j in 0..n {
                let i = ext_first * w + j;
                let (x, y) = (i % w, i / w);
                if want_status[i] != 0 {
                    // No answer: the pixel was projected exactly and answered as exact does.
                    assert_eq!(
                        status[j], want_status[i],
                        "z {z} m, pixel ({x}, {y}): status {} against exact {}",
                        status[j], want_status[i]
                    );
                    assert!(
                        exact_pixels.binary_search(&j).is_ok(),
                        "({x}, {y}) not flagged"
                    );
                    found.no_answer += 1;
                    continue;
                }
                assert_eq!(
                    status[j], 0,
                    "z {z} m, ({x}, {y}): exact answers, tabulated not"
                );
                let error = ((pixels[j][0] - want[i][0]).powi(2)
                    + (pixels[j][1] - want[i][1]).powi(2))
                .sqrt();
                assert!(
                    error <= TABLE_TOLERANCE_PX,
                    "z {z} m, step {step}, pixel ({x}, {y}): {:?} against exact {:?}: {error} px",
                    pixels[j],
                    want[i]
                );
                if exact_pixels.binary_search(&j).is_ok() {
                    assert_eq!(pixels[j], want[i], "a pixel projected exactly is exact");
                } else {
                    found.interpolated += 1;
                    found.max_error = found.max_error.max(error);
                }
            }
            found.pixels += n;
        }
        eprintln!(
            "  z {z} m: {:.2} % interpolated",
            100.0 * (found.interpolated - before.1) as f64 / (found.pixels - before.0) as f64
        );
    }
    eprintln!(
        "step {step}: {} pixel-depths, {:.2} % interpolated, {} without an answer, max error {:.2e} px",
        found.pixels,
        100.0 * found.interpolated as f64 / found.pixels as f64,
        found.no_answer,
        found.max_error
    );
    found
}

#[test]
fn shared_tilted_port_with_glass_and_distortion() {
    let rig = rig(SHARED_PORT_PAIR);
    // 0.07 m: inside the port for part of the image (its outer surface is 0.05–0.08 m away).
    let depths = [0.07, 0.12, 0.3, 0.8, 1.6, 3.0, 10.0];
    let found = compare(&rig, 0, 1, TABLE_STEP, &depths);
    assert!(
        found.no_answer > 0,
        "the nearest depth must reach into the port"
    );
    // At 320 × 256 (f = 260 px) a node step of 8 px is 1.8°: near the port the projection bends
    // too much within a cell and only the far depths interpolate.
    assert!(
        found.interpolated as f64 > 0.4 * found.pixels as f64,
        "{found:?}"
    );
    // The other way round (the right camera as the reference).
    let found = compare(&rig, 1, 0, TABLE_STEP, &depths);
    assert!(
        found.interpolated as f64 > 0.4 * found.pixels as f64,
        "{found:?}"
    );
}

#[test]
fn two_housings() {
    let rig = rig(PORT_PER_CAMERA);
    let depths = [0.03, 0.05, 0.2, 1.0, 2.6];
    let found = compare(&rig, 0, 1, TABLE_STEP, &depths);
    assert!(
        found.interpolated as f64 > 0.2 * found.pixels as f64,
        "{found:?}"
    );
}

#[test]
fn cameras_above_a_water_surface() {
    let rig = rig(ABOVE_WATER_TRIO);
    let depths = [0.41, 0.5, 0.9, 2.2];
    for voter in [1, 2] {
        let found = compare(&rig, 0, voter, TABLE_STEP, &depths);
        assert!(
            found.interpolated as f64 > 0.8 * found.pixels as f64,
            "{found:?}"
        );
    }
}

/// The bound holds whatever the spacing: coarser nodes interpolate fewer cells, never worse ones.
#[test]
fn the_bound_holds_for_coarse_nodes() {
    let rig = rig(SHARED_PORT_PAIR);
    for step in [2, 4, 16] {
        let found = compare(&rig, 0, 1, step, &[0.07, 0.15, 0.8, 3.0]);
        assert!(found.interpolated > 0, "{found:?}");
    }
}

/// A full-size image (1280 × 1024, the example rig's lens times 4): the table's nodes are as far
/// apart in angle as at 320 × 256 with a step of 2, the cells as smooth.
#[test]
fn full_size_image() {
    let json = SHARED_PORT_PAIR.replace(
        "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
        "\"width\": 1280, \"height\": 1024, \"fx\": 1040, \"fy\": 1040, \"cx\": 639.5, \"cy\": 511.5",
    );
    let found = compare(&rig(&json), 0, 1, TABLE_STEP, &[0.1, 1.1, 2.2]);
    assert!(
        found.interpolated as f64 > 0.6 * found.pixels as f64,
        "{found:?}"
    );
    let found = compare(&rig(&json), 0, 1, 16, &[1.1]);
    assert!(found.interpolated > 0, "{found:?}");
}

/// The cost volume written into a reused buffer full of garbage equals one written into fresh
/// memory (every value is written: the volume is never filled first), and a band of rows with
/// no texture at all holds no vote anywhere.
#[test]
fn a_reused_cost_volume_is_written_whole_and_an_untextured_band_has_no_vote() {
    use flatport::stereo::cost::{
        NO_VOTE, Voter, cost_volume, cost_volume_into, reference_windows,
    };
    let rig = rig(SHARED_PORT_PAIR);
    let (reference, voter) = (rig.refractive_camera(0), rig.refractive_camera(1));
    let rays = reference_rays(&reference);
    let (w, h) = (rays.width, rays.height);
    // Texture above row 160, flat grey below: the rows from 192 on (a whole band of 32 or 64
    // rows) have no window with texture.
    let (flat_from, untextured_from) = (160, 192);
    let texture = |x: f32, y: f32| 0.5 + 0.25 * (0.37 * x).sin() * (0.23 * y + 0.1 * x).cos();
    let image = |flat: bool| GreyImage {
        width: w as u32,
        height: h as u32,
        pixels: (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if flat && y >= flat_from {
                    0.5
                } else {
                    texture(x as f32, y as f32)
                }
            })
            .collect(),
    };
    let (left, right) = (image(true), image(false));
    let windows = reference_windows(&left, HALO, 0.01);
    let voters = [Voter {
        camera: voter,
        image: &right,
    }];
    let d = 24;
    let q: Vec<f64> = (0..d)
        .map(|k| 1.0 / 2.2 + k as f64 * (1.0 - 1.0 / 2.2) / (d - 1) as f64)
        .collect();
    let table = ProjectionTable::new(&reference, w, h);
    let fresh = cost_volume(
        &rays,
        &left,
        &windows,
        0.01,
        &voters,
        &q,
        Some(&table),
        &|| {},
    );
    let mut reused = vec![12345u16; w * h * d + 77];
    cost_volume_into(
        &rays,
        &left,
        &windows,
        0.01,
        &voters,
        &q,
        Some(&table),
        &|| {},
        &mut reused,
    );
    assert!(
        reused == fresh,
        "the reused volume differs from a fresh one"
    );
    assert!(
        fresh[untextured_from * w * d..]
            .iter()
            .all(|&c| c == NO_VOTE)
    );
    let voted = fresh[..flat_from * w * d]
        .iter()
        .filter(|&&c| c < NO_VOTE)
        .count();
    assert!(
        voted > flat_from * w * d / 2,
        "{voted} votes above the flat rows"
    );
}
