//! Scenes, rigs and the accuracy oracle of the stereo tests. The truth is the renderer's exact
//! depth (the nearest surface along each pixel centre's exact water ray); which reference pixels
//! another camera sees comes from the true depth maps, the model's exact projection and an
//! occlusion test, never from the stereo code.
#![allow(dead_code)]

use std::path::Path;

use flatport::engine::{CpuEngine, Engine};
use flatport::io::rig_from_json_str;
use flatport::model::{Interface, Ports, Rig, RigCamera};
use flatport::render::{
    GreyImage, Relief, RenderOptions, Shape, Sphere, Surface, SurfaceFrame, Texture, TexturedScene,
    render_textured,
};
use flatport::stereo::DepthMap;
use nalgebra::{Point2, Point3, Vector3};

pub fn cpu() -> Engine {
    Engine::Cpu(CpuEngine::new(None))
}

pub fn rig(json: &str) -> Rig {
    rig_from_json_str(json, Path::new("test-rig.json")).expect("a valid test rig")
}

/// A stereo pair behind one shared, tilted port with a glass layer and lens distortion (the
/// example rig's port, a 0.2 m baseline converging by 4°), 320 × 256.
pub const SHARED_PORT_PAIR: &str = r#"{
  "cameras": [
    {"name": "left", "width": 320, "height": 256, "fx": 260, "fy": 260, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.08, 0.012, 0.0004, -0.0003, 0.0]},
    {"name": "right", "width": 320, "height": 256, "fx": 260, "fy": 260, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.08, 0.012, 0.0, 0.0, 0.0],
     "rotation": [[0.9975640502598242, 0.0, 0.0697564737441253], [0.0, 1.0, 0.0], [-0.0697564737441253, 0.0, 0.9975640502598242]],
     "translation": [-0.19951281005196484, 0.0, 0.013951294748825061]}
  ],
  "interface": {"normal": [0.1, 0.1, 1.0], "distance": 0.05,
                "layers": [{"thickness": 0.014, "index": 1.473}],
                "index_air": 1.003, "index_water": 1.333}
}"#;

/// Two housings with a port each (tilted 8° and 5°, acrylic), a 0.25 m baseline converging by
/// 2°, mild distortion, 320 × 256.
pub const PORT_PER_CAMERA: &str = r#"{
  "cameras": [
    {"name": "left", "width": 320, "height": 256, "fx": 250, "fy": 250, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.04, 0.006, 0.0, 0.0, 0.0],
     "interface": {"normal": [0.139173100960065, 0.0, 0.99026806874157], "distance": 0.012,
                   "layers": [{"thickness": 0.01, "index": 1.49}], "index_air": 1.0, "index_water": 1.333}},
    {"name": "right", "width": 320, "height": 256, "fx": 250, "fy": 250, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.04, 0.006, 0.0, 0.0, 0.0],
     "rotation": [[0.999390827019, 0.0, 0.034899496703], [0.0, 1.0, 0.0], [-0.034899496703, 0.0, 0.999390827019]],
     "translation": [-0.249847706755, 0.0, 0.008724874176],
     "interface": {"normal": [-0.04531629009889, 0.078490116861808, 0.99588439861597], "distance": 0.018,
                   "layers": [{"thickness": 0.01, "index": 1.49}], "index_air": 1.0, "index_water": 1.333}}
  ]
}"#;

/// Three cameras 0.4 m above a bare water surface (no layers), looking down (z down), mild
/// distortion, 320 × 256, in a triangle of 0.2 m sides.
pub const ABOVE_WATER_TRIO: &str = r#"{
  "cameras": [
    {"name": "a", "width": 320, "height": 256, "fx": 250, "fy": 250, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0]},
    {"name": "b", "width": 320, "height": 256, "fx": 250, "fy": 250, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0], "translation": [-0.2, 0.0, 0.0]},
    {"name": "c", "width": 320, "height": 256, "fx": 250, "fy": 250, "cx": 159.5, "cy": 127.5,
     "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0], "translation": [-0.1, -0.1732, 0.0]}
  ],
  "interface": {"normal": [0.0, 0.0, 1.0], "distance": 0.4, "layers": [],
                "index_air": 1.0003, "index_water": 1.333}
}"#;

pub fn noise(seed: u64, scale: f64) -> Texture {
    Texture::Noise {
        seed,
        scale,
        octaves: 4,
        contrast: 3.0,
    }
}

/// The plane z = `z` (master frame), facing the cameras.
pub fn plane_at(z: f64, tilt_x: f64, texture: Texture) -> Surface {
    Surface {
        shape: Shape::Plane {
            frame: SurfaceFrame::new(Point3::new(0.0, 0.0, z), Vector3::new(tilt_x, 0.0, -1.0))
                .unwrap(),
            extent: None,
        },
        texture,
    }
}

/// A seabed: a height field about z = `z` (relief ±5 cm over 0.7 m waves).
pub fn seabed(z: f64, seed: u64) -> Surface {
    Surface {
        shape: Shape::HeightField {
            frame: SurfaceFrame::new(Point3::new(0.0, 0.0, z), Vector3::new(0.0, 0.0, -1.0))
                .unwrap(),
            extent: None,
            relief: Relief::seeded(0.05, 0.7, 6, seed).unwrap(),
        },
        texture: noise(seed + 100, 0.15),
    }
}

pub fn sphere(centre: [f64; 3], radius: f64, seed: u64) -> Surface {
    Surface {
        shape: Shape::Sphere(Sphere {
            centre: Point3::from(centre),
            radius,
        }),
        texture: noise(seed, 0.06),
    }
}

pub fn scene(surfaces: Vec<Surface>) -> TexturedScene {
    TexturedScene {
        surfaces,
        background: 0.35,
        frames: vec![Vector3::zeros()],
    }
}

/// Every camera's image and exact depth map.
pub struct Rendered {
    pub images: Vec<GreyImage>,
    pub depths: Vec<Vec<f32>>,
}

/// Renders every camera of `rig` (3 × 3 supersampling, `noise` grey levels of 255).
pub fn render_all(rig: &Rig, scene: &TexturedScene, noise: f64) -> Rendered {
    let engine = cpu();
    let (mut images, mut depths) = (Vec::new(), Vec::new());
    for k in 0..rig.cameras().len() {
        let view = render_textured(
            &engine,
            &rig.refractive_camera(k),
            scene,
            0,
            &RenderOptions {
                supersample: 3,
                noise,
                seed: 7 + k as u64,
                ..RenderOptions::default()
            },
        )
        .unwrap();
        images.push(view.image);
        depths.push(view.depth);
    }
    Rendered { images, depths }
}

/// The true point of reference pixel i (its exact water ray at the rendered depth), master frame.
pub fn true_point(rig: &Rig, reference: usize, i: usize, depth: f32) -> Option<Point3<f64>> {
    if !depth.is_finite() {
        return None;
    }
    let camera = rig.refractive_camera(reference);
    let w = camera.intrinsics().width as usize;
    let ray = camera
        .backproject(&Point2::new((i % w) as f64, (i / w) as f64))
        .ok()?;
    let z_row = camera.cam_from_master().row(2).transpose();
    let (z0, dz) = (
        z_row.dot(&(ray.origin - camera.centre())),
        z_row.dot(&ray.dir),
    );
    Some(ray.point_at((f64::from(depth) - z0) / dz))
}

/// Whether some other camera sees the true point of each reference pixel: its exact projection
/// lies in that camera's image and that camera's true depth at the nearest pixel is the point's
/// own depth in its frame (within 1 %: not occluded).
pub fn seen_by_another(rig: &Rig, reference: usize, rendered: &Rendered) -> Vec<bool> {
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let depth = &rendered.depths[reference];
    (0..depth.len())
        .map(|i| {
            let Some(x) = true_point(rig, reference, i, depth[i]) else {
                return false;
            };
            cameras.iter().enumerate().any(|(k, c)| {
                if k == reference {
                    return false;
                }
                let Ok(q) = c.project(&x) else {
                    return false;
                };
                let (w, h) = (c.intrinsics().width as f64, c.intrinsics().height as f64);
                if !(q.x >= 0.0 && q.y >= 0.0 && q.x <= w - 1.0 && q.y <= h - 1.0) {
                    return false;
                }
                let j = q.y.round() as usize * w as usize + q.x.round() as usize;
                let z_there = f64::from(rendered.depths[k][j]);
                let z_own = c
                    .cam_from_master()
                    .row(2)
                    .transpose()
                    .dot(&(x - c.centre()));
                ((z_there - z_own) / z_own).abs() < 0.01
            })
        })
        .collect()
}

/// Accuracy of a depth map against the truth.
#[derive(Debug, Clone, Copy)]
pub struct Accuracy {
    /// Reference pixels another camera sees.
    pub seen: usize,
    /// Of those, with a point.
    pub valid_fraction: f64,
    /// Median relative depth error over the seen pixels with a point.
    pub median: f64,
    /// Fraction of the seen pixels with a point whose error is ≤ 2 %.
    pub within_2: f64,
    /// Median relative error over seen pixels with a point in the periphery.
    pub periphery_median: f64,
    /// Seen periphery pixels with a point.
    pub periphery_points: usize,
    /// Median relative error over seen pixels with a point outside the periphery.
    pub centre_median: f64,
    /// Points returned where no other camera sees.
    pub unseen_points: usize,
    /// Fraction of those with an error above 2 % (or no true surface).
    pub unseen_gross: f64,
}

/// The periphery: the outer ring of the image, max(|u − cx|/(w/2), |v − cy|/(h/2)) ≥ 0.7.
pub fn periphery(i: usize, w: usize, h: usize) -> bool {
    let (u, v) = ((i % w) as f64, (i / w) as f64);
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    ((u - cx).abs() / (w as f64 / 2.0)).max((v - cy).abs() / (h as f64 / 2.0)) >= 0.7
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn accuracy(map: &DepthMap, truth: &[f32], seen: &[bool]) -> Accuracy {
    let (w, h) = (map.width, map.height);
    let (mut errors, mut peripheral, mut central) = (Vec::new(), Vec::new(), Vec::new());
    let (mut seen_count, mut unseen_points, mut unseen_gross) = (0, 0, 0);
    for i in 0..w * h {
        let estimate = f64::from(map.depth[i]);
        let error = ((estimate - f64::from(truth[i])) / f64::from(truth[i])).abs();
        if seen[i] {
            seen_count += 1;
            if estimate.is_finite() {
                errors.push(error);
                if periphery(i, w, h) {
                    peripheral.push(error);
                } else {
                    central.push(error);
                }
            }
        } else if estimate.is_finite() {
            unseen_points += 1;
            if error.is_nan() || error > 0.02 {
                unseen_gross += 1;
            }
        }
    }
    let within = errors.iter().filter(|e| **e <= 0.02).count();
    Accuracy {
        seen: seen_count,
        valid_fraction: errors.len() as f64 / seen_count.max(1) as f64,
        within_2: within as f64 / errors.len().max(1) as f64,
        median: median(errors.clone()),
        periphery_points: peripheral.len(),
        periphery_median: median(peripheral),
        centre_median: median(central),
        unseen_points,
        unseen_gross: unseen_gross as f64 / unseen_points.max(1) as f64,
    }
}

/// The same cameras as pinholes with the in-water focal length f·μ_w/μ_air and no port (equal
/// indices: no refraction), for the comparison that motivates the exact model.
pub fn pinhole_rig(rig: &Rig) -> Rig {
    let (index_air, index_water) = {
        let port = rig.port_in_master(0);
        (port.index_air(), port.index_water())
    };
    let scale = index_water / index_air;
    let cameras: Vec<RigCamera> = rig
        .cameras()
        .iter()
        .map(|c| {
            let i = c.intrinsics;
            let intrinsics = flatport::model::PinholeCamera::new(
                &c.name,
                i.width,
                i.height,
                i.fx * scale,
                i.fy * scale,
                i.cx,
                i.cy,
                i.distortion,
            )
            .unwrap();
            RigCamera::new(
                &c.name,
                intrinsics,
                c.cam_from_master.rotation.to_rotation_matrix().into_inner(),
                c.cam_from_master.translation.vector,
            )
            .unwrap()
        })
        .collect();
    // A "port" of equal indices 1 mm in front of each camera: the rays go straight.
    let ports = cameras
        .iter()
        .map(|_| Interface::new(Vector3::z(), 0.001, vec![], 1.0, 1.0).unwrap())
        .collect();
    Rig::with_ports(cameras, Ports::PerCamera(ports)).unwrap()
}
