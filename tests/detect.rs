//! Board detection on rendered images against the exact corners (the board's corners projected
//! through the port by the model), corner 0 in both orientations of the board, and the ways an
//! image can fail.

use flatport::calib::{Board, SceneSpec, simulate};
use flatport::detect::{colour_rule, detect_board};
use flatport::engine::{Device, Engine, EngineOptions};
use flatport::model::Rig;
use flatport::render::{RenderOptions, render_board};
use nalgebra::Point2;

fn example_rig() -> Rig {
    flatport::io::read_rig(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json"))).expect("example rig")
}

fn cpu() -> Engine {
    Engine::new(&EngineOptions { device: Device::Cpu, precision: None, adapter: None, threads: None }).unwrap()
}

fn grey(image: &flatport::render::GreyImage) -> image::GrayImage {
    image::GrayImage::from_raw(image.width, image.height, image.to_u8()).unwrap()
}

#[test]
fn measure() {
    let rig = example_rig();
    let board = Board { rows: 6, cols: 9, square: 0.04 };
    let mut spec = SceneSpec::new(board, 15, 0.0, 7);
    spec.margin_px = 40.0;
    let scene = simulate(&rig, 0, 1, &spec).unwrap();
    let engine = cpu();
    let options = RenderOptions { noise: std::env::var("N").map(|v| v.parse().unwrap()).unwrap_or(2.0), blur_px: std::env::var("B").map(|v| v.parse().unwrap()).unwrap_or(0.7), ..RenderOptions::default() };
    let (mut sum, mut count, mut max) = (0.0, 0usize, 0.0f64);
    let t = std::time::Instant::now();
    for (v, pose) in scene.master_from_board.iter().enumerate() {
        for k in 0..2 {
            let tr = std::time::Instant::now();
            let image = render_board(&engine, &rig.refractive_camera(k), &board, pose, &RenderOptions { seed: (v * 2 + k) as u64, ..options.clone() }).unwrap();
            println!("render {:.3}s", tr.elapsed().as_secs_f64());
            let t0 = std::time::Instant::now();
            let image = grey(&image);
            let truth: Vec<Point2<f64>> = if k == 0 { &scene.observations.views[v].left } else { &scene.observations.views[v].right }.iter().map(|p| p.unwrap()).collect();
            let t1 = std::time::Instant::now();
            let d = detect_board(&image, &board);
            println!("detect {:.3}s", t1.elapsed().as_secs_f64()); let _ = t0;
            let Ok(d) = d else { println!("view {v} cam {k}: {:?}", d.unwrap_err()); continue };
            let choice = colour_rule(&image, &board, &d.orderings);
            println!("view {v} cam {k}: {} orderings, colour {:?}", d.orderings.len(), choice);
            let best = d.orderings.iter().map(|o| o.iter().zip(&truth).map(|(a, b)| (a - b).norm_squared()).sum::<f64>()).enumerate().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            for (a, b) in d.orderings[best.0].iter().zip(&truth) {
                let e = (a - b).norm();
                sum += e * e; count += 1; max = max.max(e);
            }
            println!("   truth ordering {} rms {:.4}", best.0, (best.1 / truth.len() as f64).sqrt());
        }
    }
    println!("corners {count}, rms {:.4} px, max {:.4} px, {:.2} s", (sum / count as f64).sqrt(), max, t.elapsed().as_secs_f64());
}
