//! Chessboard corners hidden by a speck or a blotch (issue 45): a whole-extent grid's missing
//! inner corners are filled in (`flatport::detect::fill`), and a grid that is not the whole
//! board still is not. Rendered images of the example rig with the exact corners (the board's
//! corners projected through the port), specks painted on afterwards.

use std::path::Path;

use flatport::calib::{Board, SceneSpec, Target, simulate};
use flatport::detect::{Detection, Found, Miss, Unrefined, detect_board, resolve_view};
use flatport::engine::{Device, Engine, EngineOptions};
use flatport::model::Rig;
use flatport::render::{RenderOptions, render_board};
use image::GrayImage;
use nalgebra::{Isometry3, Point2};

fn example_rig() -> Rig {
    flatport::io::read_rig(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/example_rig.json"))
        .expect("example rig")
}

fn cpu() -> Engine {
    Engine::new(&EngineOptions {
        device: Device::Cpu,
        precision: None,
        adapter: None,
        threads: None,
    })
    .unwrap()
}

const BOARD: Board = Board {
    rows: 6,
    cols: 9,
    square: 0.04,
};

/// Poses that both cameras of the example rig see whole, corners 40 px inside the images.
fn poses(board: &Board, views: usize, seed: u64) -> Vec<Isometry3<f64>> {
    let mut spec = SceneSpec::pair(Target::Board(*board), views, 0.0, seed, 0, 1);
    spec.margin_px = 40.0;
    simulate(&example_rig(), &spec).unwrap().master_from_target
}

/// Rig camera `camera`'s image of `board` at `pose` (a little blur and noise, as a camera gives)
/// and its exact corners, row-major.
fn render(
    rig: &Rig,
    camera: usize,
    board: &Board,
    pose: &Isometry3<f64>,
) -> (GrayImage, Vec<Point2<f64>>) {
    let options = RenderOptions {
        noise: 1.0,
        blur_px: 0.8,
        ..RenderOptions::default()
    };
    let camera = rig.refractive_camera(camera);
    let image = render_board(&cpu(), &camera, board, pose, &options).unwrap();
    let image = GrayImage::from_raw(image.width, image.height, image.to_u8()).unwrap();
    let exact = (0..board.corners())
        .map(|c| camera.project(&(pose * board.point_in_board(c))).unwrap())
        .collect();
    (image, exact)
}

/// Adds a Gaussian speck (as backscatter gives: peak `peak` grey levels, σ `sigma` px) at
/// `centre`, clamped at 255.
fn add_speck(image: &mut GrayImage, centre: Point2<f64>, sigma: f64, peak: f64) {
    for (x, y, pixel) in image.enumerate_pixels_mut() {
        let r2 = (f64::from(x) - centre.x).powi(2) + (f64::from(y) - centre.y).powi(2);
        let added = peak * (-r2 / (2.0 * sigma * sigma)).exp();
        pixel.0[0] = (f64::from(pixel.0[0]) + added).round().min(255.0) as u8;
    }
}

/// Paints grey `grey` over every pixel for which `inside` holds.
fn paint(image: &mut GrayImage, grey: u8, inside: impl Fn(Point2<f64>) -> bool) {
    for (x, y, pixel) in image.enumerate_pixels_mut() {
        if inside(Point2::new(f64::from(x), f64::from(y))) {
            pixel.0[0] = grey;
        }
    }
}

/// Mean distance (px) between neighbouring corners along the rows: the square side.
fn side(board: &Board, exact: &[Point2<f64>]) -> f64 {
    let steps: Vec<f64> = (0..board.corners())
        .filter(|n| n % board.cols != board.cols - 1)
        .map(|n| (exact[n + 1] - exact[n]).norm())
        .collect();
    steps.iter().sum::<f64>() / steps.len() as f64
}

/// The ordering corner 0's rules choose for one image alone ([`resolve_view`]).
fn chosen(image: &GrayImage, board: &Board, detection: Detection) -> Vec<Point2<f64>> {
    let found = Found::new(image, board, detection);
    let choice = resolve_view(board, &["cam".to_string()], None, &[Some(found.clone())]).unwrap()
        [0]
    .unwrap()
    .0;
    found.detection.orderings[choice].clone()
}

fn errors(found: &[Point2<f64>], exact: &[Point2<f64>]) -> Vec<f64> {
    found
        .iter()
        .zip(exact)
        .map(|(a, b)| (a - b).norm())
        .collect()
}

#[test]
fn specks_on_inner_corners_are_filled_in_at_the_exact_corners() {
    // Measured (these 6 images, 8 specks): every specked corner was missed by the grid and
    // filled in, refined, within 0.012 px of the exact corner; all corners 0.015 px RMS, largest
    // 0.036 px. The bounds: 0.25 px for every corner (tests/detect.rs's), 0.1 px RMS (the
    // issue's goal).
    let rig = example_rig();
    // (corners specked, offset of the speck from the corner in px, σ px, peak grey levels)
    type Specks<'a> = (&'a [usize], (f64, f64), f64, f64);
    let specks: [Specks; 3] = [
        (&[13], (0.0, 0.0), 2.0, 180.0),
        (&[20, 32], (0.7, -0.5), 1.5, 220.0),
        (&[39], (-1.0, 0.8), 2.5, 150.0),
    ];
    let (mut filled, mut sum, mut count, mut largest_filled, mut largest) =
        (0, 0.0, 0, 0.0f64, 0.0f64);
    for (view, pose) in poses(&BOARD, specks.len(), 21).iter().enumerate() {
        let (corners, offset, sigma, peak) = specks[view];
        for camera in 0..2 {
            let (mut image, exact) = render(&rig, camera, &BOARD, pose);
            for &c in corners {
                let at = exact[c] + nalgebra::Vector2::new(offset.0, offset.1);
                add_speck(&mut image, at, sigma, peak);
            }
            let detection = detect_board(&image, &BOARD)
                .unwrap_or_else(|m| panic!("view {view} camera {camera}: {m}"));
            for corner in &detection.filled {
                assert_eq!(
                    corner.unrefined, None,
                    "view {view} camera {camera}: a filled corner was not refined: {corner:?}"
                );
                let nearest = exact
                    .iter()
                    .map(|e| (corner.pixel - e).norm())
                    .fold(f64::INFINITY, f64::min);
                largest_filled = largest_filled.max(nearest);
                assert!(
                    nearest <= 0.25,
                    "view {view} camera {camera}: filled corner {corner:?} is {nearest} px from the nearest exact corner"
                );
            }
            filled += detection.filled.len();
            let found = chosen(&image, &BOARD, detection);
            let e = errors(&found, &exact);
            let worst = e.iter().copied().fold(0.0, f64::max);
            assert!(
                worst <= 0.25,
                "view {view} camera {camera}: largest corner error {worst} px (corner 0 at the wrong end?)"
            );
            largest = largest.max(worst);
            sum += e.iter().map(|e| e * e).sum::<f64>();
            count += e.len();
        }
    }
    // Every speck hid its corner from the ChESS front end: the fill did the work.
    let specked: usize = specks.iter().map(|s| s.0.len()).sum();
    assert_eq!(filled, 2 * specked, "corners filled in");
    let rms = (sum / count as f64).sqrt();
    println!(
        "{filled} corners filled in, largest error {largest_filled:.3} px; all corners RMS {rms:.3} px, largest {largest:.3} px"
    );
    assert!(rms <= 0.1, "corner RMS {rms} px");
}

#[test]
fn a_blotch_over_the_refinement_window_leaves_the_corner_out_of_the_observations() {
    // A flat grey disc of 0.45 of a side over corner 22 leaves no edge in the refinement's
    // window: the fit finds no saddle (Weak, σ infinite); the prediction (its neighbours'
    // homography and quadratic) completes the grid, flagged, and is no observation. Measured
    // 0.017 px from the exact corner here (an inner corner, neighbours all round), but on a
    // slanted, distorted board 2.5 px (zoo seed 43): a guess is not a measurement.
    let rig = example_rig();
    let pose = poses(&BOARD, 1, 5)[0];
    let (mut image, exact) = render(&rig, 0, &BOARD, &pose);
    let radius = 0.45 * side(&BOARD, &exact);
    let corner = exact[22];
    paint(&mut image, 128, |p| (p - corner).norm() <= radius);
    let detection = detect_board(&image, &BOARD).expect("the board with one corner predicted");
    assert_eq!(detection.filled.len(), 1, "{:?}", detection.filled);
    let filled = &detection.filled[0];
    assert!(
        matches!(filled.unrefined, Some(Unrefined::Weak { .. })),
        "{filled:?}"
    );
    assert_eq!(filled.pixel, filled.predicted);
    let gap = (filled.pixel - corner).norm();
    println!("blotch: {filled:?}, {gap:.3} px from the exact corner");
    assert!(gap <= 0.5, "predicted corner {gap} px from the exact one");
    // In every ordering the observations leave that corner out, and only that one.
    for o in 0..detection.orderings.len() {
        let observed = detection.observed(o);
        for (i, (pixel, seen)) in detection.orderings[o].iter().zip(&observed).enumerate() {
            let guessed = *pixel == filled.pixel;
            assert_eq!(seen.is_none(), guessed, "ordering {o}, corner {i}");
        }
        assert_eq!(observed.iter().filter(|c| c.is_none()).count(), 1);
    }
    let found = chosen(&image, &BOARD, detection);
    assert!(
        (found[22] - corner).norm() <= 0.5,
        "corner 22 is where it was filled in"
    );
}

/// `result` is a partial grid; with `spanning`, one whose labels span the board's shape, so
/// that the fill's own rules (not the extent) turned it down.
fn assert_partial(result: Result<Detection, Miss>, spanning: bool, what: &str) {
    match result {
        Err(Miss::Partial { found, extent }) => {
            println!("{what}: {found} corners, extent {extent:?}");
            if spanning {
                assert!(
                    extent.0 * extent.1 == BOARD.corners() && found < BOARD.corners(),
                    "{what}: expected a grid spanning the board with corners missing, got {found} corners over {extent:?}"
                );
            }
        }
        Err(other) => panic!("{what}: expected a partial grid, got {other}"),
        Ok(d) => panic!(
            "{what}: accepted as the whole board ({} corners filled in: {:?})",
            d.filled.len(),
            d.filled
        ),
    }
}

#[test]
fn a_board_missing_a_border_row_or_a_half_is_not_the_whole_board() {
    let rig = example_rig();
    let pose = poses(&BOARD, 1, 5)[0];
    let (image, exact) = render(&rig, 0, &BOARD, &pose);
    let s = side(&BOARD, &exact);
    let (rows, cols) = (BOARD.rows, BOARD.cols);
    // The first two hold: without them the cases below would not test the rule.
    let whole = detect_board(&image, &BOARD).expect("the whole board");
    assert!(whole.filled.is_empty());

    // The last row of corners painted over in white (the squares either side of it merged):
    // the grid is a row short.
    let last_row: Vec<Point2<f64>> = exact[(rows - 1) * cols..].to_vec();
    let mut row_gone = image.clone();
    paint(&mut row_gone, 230, |p| {
        last_row
            .windows(2)
            .any(|w| distance_to_segment(p, w[0], w[1]) <= 0.45 * s)
    });
    assert_partial(
        detect_board(&row_gone, &BOARD),
        false,
        "last row painted over",
    );

    // Specks on 5 of the last row's 9 corners: no more than a tenth of the board is missing, but
    // the border row keeps fewer than half its corners, so its extent rests on too few.
    let mut row_specked = image.clone();
    for c in [0, 2, 4, 6, 8] {
        add_speck(&mut row_specked, last_row[c], 2.5, 255.0);
    }
    assert_partial(
        detect_board(&row_specked, &BOARD),
        true,
        "5 of the last row's corners specked",
    );

    // The right half of the board behind a grey occluder.
    let middle = exact[cols / 2];
    let across = exact[cols - 1] - exact[0];
    let mut half = image.clone();
    paint(&mut half, 128, |p| (p - middle).dot(&across) > 0.0);
    assert_partial(detect_board(&half, &BOARD), false, "right half occluded");

    // A grey occluder over corner 22 and the middles of its four squares: the gap is no
    // chessboard corner on the image, and the grid is not filled in with a guess.
    let corner = exact[22];
    let mut occluded = image.clone();
    paint(&mut occluded, 128, |p| (p - corner).norm() <= 0.85 * s);
    assert_partial(
        detect_board(&occluded, &BOARD),
        true,
        "corner 22 and its squares occluded",
    );
}

#[test]
fn a_different_board_with_a_speck_is_not_taken_for_the_board() {
    // 10 × 6 and 8 × 6 inner corners, each with a speck on an inner corner, detected as 9 × 6.
    let rig = example_rig();
    for other in [
        Board {
            rows: 6,
            cols: 10,
            square: 0.035,
        },
        Board {
            rows: 6,
            cols: 8,
            square: 0.04,
        },
    ] {
        let pose = poses(&other, 1, 5)[0];
        let (mut image, exact) = render(&rig, 0, &other, &pose);
        add_speck(&mut image, exact[other.cols + 3], 2.0, 200.0);
        assert_partial(
            detect_board(&image, &BOARD),
            false,
            &format!("a {} × {} board", other.cols, other.rows),
        );
    }
}

fn distance_to_segment(p: Point2<f64>, a: Point2<f64>, b: Point2<f64>) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (p - (a + ab * t)).norm()
}

/// What detect_board fills in on the images named in `FLATPORT_FILL_IMAGES` (paths separated by
/// `:`), as a 9 × 6 board (`FLATPORT_FILL_BOARD=COLSxROWS` for another): a look at real or
/// rendered footage, run by hand:
/// `FLATPORT_FILL_IMAGES=a.png:b.png cargo test --release --test detect_specks -- --ignored --nocapture`.
#[test]
#[ignore = "a look at given images, run by hand"]
fn show_filled_corners() {
    let board = std::env::var("FLATPORT_FILL_BOARD")
        .ok()
        .and_then(|b| {
            let (c, r) = b.split_once('x')?;
            Some(Board {
                cols: c.parse().ok()?,
                rows: r.parse().ok()?,
                square: 1.0,
            })
        })
        .unwrap_or(BOARD);
    for path in std::env::var("FLATPORT_FILL_IMAGES")
        .unwrap_or_default()
        .split(':')
        .filter(|p| !p.is_empty())
    {
        let image = flatport::io::read_grey_image(Path::new(path)).unwrap();
        match detect_board(&image, &board) {
            Ok(d) => {
                for f in &d.filled {
                    let moved = (f.pixel - f.predicted).norm();
                    match f.unrefined {
                        None => println!(
                            "{path}: filled at ({:.2}, {:.2}), refined {moved:.3} px from the prediction",
                            f.pixel.x, f.pixel.y
                        ),
                        Some(why) => println!(
                            "{path}: filled at ({:.2}, {:.2}), the prediction: {why}",
                            f.pixel.x, f.pixel.y
                        ),
                    }
                }
                if d.filled.is_empty() {
                    println!("{path}: whole grid");
                }
            }
            Err(m) => println!("{path}: {m}"),
        }
    }
}

/// Every corner of each whole board in the rendered images named in `FLATPORT_FILL_IMAGES`
/// (`DIR/<camera>/view_NNN.png` with `DIR/corners.json`, as `flatport render` writes them; a 9 × 6
/// board unless `FLATPORT_FILL_BOARD`), left out in turn and filled in: the errors against the
/// exact corners of the ChESS corner, the prediction and the filled corner, and why any was not
/// refined. Run by hand:
/// `FLATPORT_FILL_IMAGES=a.png:b.png cargo test --release --test detect_specks leave_one_out -- --ignored --nocapture`.
#[test]
#[ignore = "a measurement on given images, run by hand"]
fn leave_one_out() {
    let board = std::env::var("FLATPORT_FILL_BOARD")
        .ok()
        .and_then(|b| {
            let (c, r) = b.split_once('x')?;
            Some(Board {
                cols: c.parse().ok()?,
                rows: r.parse().ok()?,
                square: 1.0,
            })
        })
        .unwrap_or(BOARD);
    let (mut chess, mut predicted, mut filled) = (Vec::new(), Vec::new(), Vec::new());
    let mut unrefined = std::collections::BTreeMap::<String, usize>::new();
    for path in std::env::var("FLATPORT_FILL_IMAGES")
        .unwrap_or_default()
        .split(':')
        .filter(|p| !p.is_empty())
    {
        let path = Path::new(path);
        let camera = path.parent().unwrap();
        let view: usize = path.file_stem().unwrap().to_str().unwrap()[5..]
            .parse()
            .unwrap();
        let truth: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(camera.parent().unwrap().join("corners.json")).unwrap(),
        )
        .unwrap();
        let exact: Vec<Point2<f64>> = truth["views"][view]
            [camera.file_name().unwrap().to_str().unwrap()]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| Point2::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
        .collect();
        let nearest = |q: Point2<f64>| {
            exact
                .iter()
                .map(|e| (q - e).norm())
                .fold(f64::INFINITY, f64::min)
        };
        let image = flatport::io::read_grey_image(path).unwrap();
        let Ok(detection) = detect_board(&image, &board) else {
            continue;
        };
        if !detection.filled.is_empty() {
            continue;
        }
        let grid: Vec<Option<Point2<f64>>> =
            detection.orderings[0].iter().copied().map(Some).collect();
        for k in 0..grid.len() {
            let mut holed = grid.clone();
            holed[k] = None;
            match flatport::detect::fill::fill_grid(&mut holed, board.cols, board.rows, &image) {
                Some(f) => {
                    chess.push(nearest(grid[k].unwrap()));
                    predicted.push(nearest(f[0].predicted));
                    filled.push(nearest(f[0].pixel));
                    if let Some(why) = f[0].unrefined {
                        *unrefined
                            .entry(format!("{why:?}").split(' ').next().unwrap().to_string())
                            .or_default() += 1;
                    }
                }
                None => *unrefined.entry("not filled".to_string()).or_default() += 1,
            }
        }
    }
    let stats = |e: &[f64]| {
        let rms = (e.iter().map(|e| e * e).sum::<f64>() / e.len() as f64).sqrt();
        format!(
            "RMS {rms:.3} px, largest {:.3} px",
            e.iter().copied().fold(0.0, f64::max)
        )
    };
    println!("{} corners left out in turn", chess.len());
    println!("ChESS corner: {}", stats(&chess));
    println!("prediction:   {}", stats(&predicted));
    println!("filled in:    {}", stats(&filled));
    println!("not refined:  {unrefined:?}");
}

/// `flatport detect` says which images had corners filled in (issue 45): a speck on corner 13 of
/// one view in both cameras gives a `filled:` line per image, and the corners are written.
#[test]
fn the_command_names_the_images_with_filled_corners() {
    let rig = example_rig();
    let dir = tempfile::tempdir().unwrap();
    let pose = poses(&BOARD, 1, 21)[0];
    for (camera, name) in ["left", "right"].iter().enumerate() {
        let (mut image, exact) = render(&rig, camera, &BOARD, &pose);
        add_speck(&mut image, exact[13], 2.0, 180.0);
        std::fs::create_dir_all(dir.path().join(name)).unwrap();
        image
            .save(dir.path().join(name).join("view_000.png"))
            .unwrap();
    }
    let output = dir.path().join("obs.json");
    let glob = |name: &str| format!("{name}={}/{name}/*.png", dir.path().display());
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(["detect", "--board", "9x6@0.04", "--images"])
        .arg(glob("left"))
        .arg("--images")
        .arg(glob("right"))
        .arg("-o")
        .arg(&output)
        .arg("-q")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for name in ["left", "right"] {
        assert!(
            stderr.contains(&format!(
                "({name}): 1 corner(s) the grid missed, filled in from their neighbours and placed on the image"
            )),
            "{stderr}"
        );
    }
    assert!(output.is_file());
}
