//! Textured scenes in `flatport render` against oracles of their own: the rendered depth of every
//! pixel puts its point on the surface the pixel sees (plane and sphere by their equations, the
//! height field by a brute-force march written here), the nearest surface wins, image textures
//! land where metres per pixel put them, the example scene files read, and the CLI writes its
//! files (and nothing for a bad scene).

mod stereo_common;

use std::path::Path;
use std::process::Command;

use flatport::io::scene_json::read_scene;
use flatport::render::{
    ImageTexture, RenderOptions, Shape, Surface, SurfaceFrame, Texture, render_textured,
};
use nalgebra::{Point2, Point3, Vector3};
use stereo_common::*;

fn still(options_noise: f64) -> RenderOptions {
    RenderOptions {
        supersample: 3,
        noise: options_noise,
        ..RenderOptions::default()
    }
}

#[test]
fn a_plane_and_a_sphere_render_with_their_exact_depths_and_the_nearest_wins() {
    let rig = rig(SHARED_PORT_PAIR);
    let centre = Point3::new(0.1, 0.0, 1.2);
    let radius = 0.15;
    let the_scene = scene(vec![
        plane_at(1.5, 0.0, noise(1, 0.1)),
        sphere([centre.x, centre.y, centre.z], radius, 2),
    ]);
    let engine = cpu();
    for k in 0..2 {
        let camera = rig.refractive_camera(k);
        let view = render_textured(&engine, &camera, &the_scene, 0, &still(0.0)).unwrap();
        let w = camera.intrinsics().width as usize;
        let (mut on_plane, mut on_sphere) = (0, 0);
        for (i, &depth) in view.depth.iter().enumerate() {
            let ray = camera
                .backproject(&Point2::new((i % w) as f64, (i / w) as f64))
                .unwrap();
            // The sphere along this ray, by the quadratic written out here.
            let oc = ray.origin - centre;
            let b = ray.dir.dot(&oc);
            let disc = b * b - (oc.norm_squared() - radius * radius);
            let meets_sphere = disc >= 0.0 && -b - disc.sqrt() > 0.0;
            let Some(x) = true_point(&rig, k, i, depth) else {
                // Nothing hit: neither surface lies along the ray (the plane is infinite, so this
                // happens only for a ray that has no answer).
                panic!("pixel {i} of camera {k} hits nothing");
            };
            if meets_sphere {
                on_sphere += 1;
                // The near side: the smaller root.
                let near = ray.point_at(-b - disc.sqrt());
                assert!((x - near).norm() < 2e-6, "pixel {i}: {x} against {near}");
            } else {
                on_plane += 1;
                assert!((x.z - 1.5).abs() < 2e-6, "pixel {i}: {x}");
            }
        }
        assert!(
            on_sphere > 3000 && on_plane > 30_000,
            "{on_sphere} {on_plane}"
        );
        // The image: textured, no value outside 0 … 1 without noise.
        assert!(view.image.pixels.iter().all(|p| (0.0..=1.0).contains(p)));
    }
    // The master's depth is z: on the fronto-parallel plane every plane pixel reads 1.5.
    let camera = rig.refractive_camera(0);
    let view = render_textured(&engine, &camera, &the_scene, 0, &still(0.0)).unwrap();
    let plane_pixels = view
        .depth
        .iter()
        .filter(|d| (**d - 1.5).abs() < 1e-6)
        .count();
    assert!(plane_pixels > 30_000, "{plane_pixels}");
}

#[test]
fn a_height_field_is_hit_where_a_brute_force_march_finds_it() {
    let rig = rig(ABOVE_WATER_TRIO);
    let surface = seabed(1.5, 5);
    let Shape::HeightField { frame, relief, .. } = &surface.shape else {
        unreachable!()
    };
    // h(s, t) from the waves, written out here.
    let waves = relief.waves().to_vec();
    let height = |s: f64, t: f64| -> f64 {
        waves
            .iter()
            .map(|w| w.amplitude * (w.k[0] * s + w.k[1] * t + w.phase).sin())
            .sum()
    };
    let frame: SurfaceFrame = frame.clone();
    let local = |p: &Point3<f64>| {
        let d = p - frame.origin;
        (frame.e1.dot(&d), frame.e2.dot(&d), frame.normal.dot(&d))
    };
    let the_scene = scene(vec![surface.clone()]);
    let camera = rig.refractive_camera(0);
    let view = render_textured(&cpu(), &camera, &the_scene, 0, &still(0.0)).unwrap();
    let w = camera.intrinsics().width as usize;
    let mut checked = 0;
    for i in (0..view.depth.len()).step_by(397) {
        let ray = camera
            .backproject(&Point2::new((i % w) as f64, (i / w) as f64))
            .unwrap();
        let g = |l: f64| {
            let (s, t, up) = local(&ray.point_at(l));
            up - height(s, t)
        };
        // March in 0.2 mm steps from the port to the first sign change, then bisect.
        let (mut a, mut b) = (0.0, 0.0);
        let start = g(0.0);
        let mut l = 0.0;
        while l < 3.0 {
            let next = l + 2e-4;
            if (g(next) > 0.0) != (start > 0.0) {
                (a, b) = (l, next);
                break;
            }
            l = next;
        }
        assert!(b > 0.0, "pixel {i}: no crossing within 3 m");
        for _ in 0..60 {
            let m = 0.5 * (a + b);
            if (g(m) > 0.0) == (start > 0.0) {
                a = m;
            } else {
                b = m;
            }
        }
        let x = ray.point_at(0.5 * (a + b));
        let z = camera
            .cam_from_master()
            .row(2)
            .transpose()
            .dot(&(x - camera.centre()));
        let rendered = f64::from(view.depth[i]);
        assert!(
            (rendered - z).abs() < 2e-6 * z,
            "pixel {i}: rendered {rendered}, marched {z}"
        );
        checked += 1;
    }
    assert!(checked > 150);
}

#[test]
fn an_image_texture_lands_where_metres_per_pixel_put_it() {
    // A 64 × 64 texture, 1 cm per texture pixel on the plane z = 1.5 (normal −z: s = x, t = −y),
    // repeated beyond its edges: four quadrants, each a ramp along the columns, so that a texture
    // pixel's place shows in its value (half a texture pixel off is 0.005 off).
    let values = [0.1f64, 0.5, 0.3, 0.2];
    let quadrant = |col: usize, row: usize| (row / 32) * 2 + col / 32;
    let grey = |col: f64, row: f64| {
        values[quadrant(col as usize, row as usize)] + 0.3 * (col % 32.0) / 31.0
    };
    let pixels: Vec<f32> = (0..64 * 64)
        .map(|i| grey((i % 64) as f64, (i / 64) as f64) as f32)
        .collect();
    let texture = Texture::Image(ImageTexture {
        width: 64,
        height: 64,
        pixels,
        metres_per_pixel: 0.01,
    });
    let plane = Surface {
        shape: Shape::Plane {
            frame: SurfaceFrame::new(Point3::new(0.0, 0.0, 1.5), Vector3::new(0.0, 0.0, -1.0))
                .unwrap(),
            extent: None,
        },
        texture,
    };
    let rig = rig(SHARED_PORT_PAIR);
    let camera = rig.refractive_camera(0);
    let view = render_textured(&cpu(), &camera, &scene(vec![plane]), 0, &still(0.0)).unwrap();
    let w = camera.intrinsics().width as usize;
    let mut checked = 0;
    for (i, &depth) in view.depth.iter().enumerate() {
        let x = true_point(&rig, 0, i, depth).unwrap();
        let (col, row) = (x.x / 0.01 + 31.5, -x.y / 0.01 + 31.5);
        let (c, r) = (col.rem_euclid(64.0), row.rem_euclid(64.0));
        // Well inside a quadrant: two texture pixels from its edges (a camera pixel spans about
        // half a texture pixel here).
        let inside = |v: f64| (v % 32.0) > 2.5 && (v % 32.0) < 29.5;
        if inside(c) && inside(r) {
            // Bilinear on a ramp: the ramp itself.
            let expected = grey(c, r) as f32;
            assert!(
                (view.image.pixels[i] - expected).abs() < 1e-3,
                "pixel ({}, {}): {} against {expected}",
                i % w,
                i / w,
                view.image.pixels[i]
            );
            checked += 1;
        }
    }
    assert!(checked > 20_000, "{checked}");
}

#[test]
fn the_example_scene_files_read() {
    for name in ["seabed", "step", "water_surface"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("data/scenes/{name}.json"));
        let read = read_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(read.rig.is_some(), "{name} names its rig");
        assert!(!read.scene.surfaces.is_empty());
    }
}

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("flatport runs")
}

#[test]
fn cli_render_takes_rig_over_the_scene_and_writes_16_bit_images() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.json");
    std::fs::write(
        &scene,
        r#"{"rig": "no-such-rig.json",
            "surfaces": [{"plane": {"point": [0, 0, 1.5], "normal": [0, 0, -1],
                          "texture": {"noise": {"scale": 0.2, "seed": 3}}}}]}"#,
    )
    .unwrap();
    let rig = dir.path().join("rig.json");
    let small = SHARED_PORT_PAIR
        .replace(
            "\"width\": 320, \"height\": 256",
            "\"width\": 64, \"height\": 48",
        )
        .replace("\"cx\": 159.5, \"cy\": 127.5", "\"cx\": 31.5, \"cy\": 23.5");
    std::fs::write(&rig, small).unwrap();
    let out = dir.path().join("out");
    // The scene's own rig does not exist: --rig replaces it.
    let run = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--rig",
        rig.to_str().unwrap(),
        "--bits",
        "16",
        "--device",
        "cpu",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let image = image::open(out.join("right/frame_000.png")).unwrap();
    assert_eq!(image.color(), image::ColorType::L16);
    assert_eq!((image.width(), image.height()), (64, 48));
    assert!(out.join("left/depth_000.npy").is_file() && out.join("rig.json").is_file());
    // Without --rig, the missing rig file is named.
    let out2 = dir.path().join("out2");
    let run = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "-o",
        out2.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && stderr.contains("no-such-rig.json"),
        "{stderr}"
    );
    assert!(!out2.exists());
}
