//! `flatport render --scene`: images and exact depth maps of a textured scene by every camera.

use std::path::{Path, PathBuf};

use anyhow::Context;

use flatport::io::scene_json::{read_scene, read_scene_without_rig};
use flatport::io::stereo_files::{read_grey_f32, write_npy_f32};
use flatport::io::{read_rig, write_grey_png, write_grey16_png, write_rig};
use flatport::render::imaging::h264_round_trip;
use flatport::render::{RenderOptions, render_textured};

use super::progress::Progress;

/// What `flatport render --scene` was asked.
pub struct SceneRun<'a> {
    /// The scene file.
    pub scene: &'a Path,
    /// --rig, which replaces the scene file's rig.
    pub rig: Option<&'a Path>,
    /// Supersampling (every pixel), blur, noise, seed, imaging effects (H.264 on each camera's
    /// frames once all are written).
    pub options: RenderOptions,
    /// 8 or 16 bits per pixel.
    pub bits: u8,
    /// The output folder.
    pub output: &'a Path,
    /// No progress bar.
    pub quiet: bool,
    /// The device.
    pub engine: &'a super::EngineArgs,
}

/// Renders DIR/CAMERA/frame_NNN.png and DIR/CAMERA/depth_NNN.npy for every frame and camera, and
/// DIR/rig.json. Nothing is written when the scene, the rig or an option is refused.
pub fn run(run: SceneRun) -> anyhow::Result<()> {
    let (scene, rig) = match run.rig {
        Some(path) => (read_scene_without_rig(run.scene)?, read_rig(path)?),
        None => {
            let contents = read_scene(run.scene)?;
            let Some(rig) = contents.rig else {
                anyhow::bail!(
                    "{}: the scene names no rig (a \"rig\" key); give --rig RIG.json",
                    run.scene.display()
                );
            };
            (contents.scene, rig)
        }
    };
    let engine = run.engine.engine()?;
    let scene = &scene;
    let names: Vec<String> = rig.cameras().iter().map(|c| c.name.clone()).collect();
    let cameras: Vec<_> = (0..names.len()).map(|k| rig.refractive_camera(k)).collect();
    let total = scene.frames.len() * names.len();
    let mut progress = Progress::new("render", "images", run.quiet);
    let started = std::time::Instant::now();
    let mut done = 0;
    let mut pngs = vec![Vec::new(); names.len()];
    for frame in 0..scene.frames.len() {
        for (k, camera) in cameras.iter().enumerate() {
            let seed = run
                .options
                .seed
                .wrapping_mul(1_000_003)
                .wrapping_add((frame * names.len() + k) as u64);
            let view = render_textured(
                &engine,
                camera,
                scene,
                frame,
                &RenderOptions {
                    seed,
                    ..run.options.clone()
                },
            )?;
            if done == 0 {
                // The first image rendered: the options are good, the folders can be made.
                for name in &names {
                    let folder = run.output.join(name);
                    std::fs::create_dir_all(&folder)
                        .with_context(|| format!("cannot create {}", folder.display()))?;
                }
                write_rig(&run.output.join("rig.json"), &rig)?;
            }
            let folder = run.output.join(&names[k]);
            let image = &view.image;
            let png = folder.join(format!("frame_{frame:03}.png"));
            if run.bits == 16 {
                write_grey16_png(&png, &image.to_u16(), image.width, image.height)?;
            } else {
                write_grey_png(&png, &image.to_u8(), image.width, image.height)?;
            }
            write_npy_f32(
                &folder.join(format!("depth_{frame:03}.npy")),
                &[image.height as usize, image.width as usize],
                &view.depth,
            )?;
            pngs[k].push(png);
            done += 1;
            progress.update(done, total);
        }
    }
    if let Some(crf) = run.options.imaging.h264_crf {
        for camera in &pngs {
            h264_sequence(camera, crf, run.bits)?;
        }
    }
    outln!(
        "rendered {} images ({} frames × {} cameras) in {:.2} s into {}/: CAMERA/frame_NNN.png, CAMERA/depth_NNN.npy (z in that camera's frame, float32, NaN where nothing is hit), rig.json",
        done,
        scene.frames.len(),
        names.len(),
        started.elapsed().as_secs_f64(),
        run.output.display()
    );
    Ok(())
}

/// Replaces the PNG files of one camera's sequence, in order, by their H.264 round trip at
/// `crf` ([`flatport::render::imaging::h264_round_trip`]), written back with `bits` per pixel.
pub fn h264_sequence(paths: &[PathBuf], crf: u8, bits: u8) -> anyhow::Result<()> {
    let frames = paths
        .iter()
        .map(|path| read_grey_f32(path).map_err(anyhow::Error::from))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let folder = paths
        .first()
        .and_then(|p| p.parent())
        .map_or_else(String::new, |p| p.display().to_string());
    let decoded = h264_round_trip(&frames, crf)
        .with_context(|| format!("{folder}: H.264 of the camera's {} frames", frames.len()))?;
    for (path, image) in paths.iter().zip(&decoded) {
        if bits == 16 {
            write_grey16_png(path, &image.to_u16(), image.width, image.height)?;
        } else {
            write_grey_png(path, &image.to_u8(), image.width, image.height)?;
        }
    }
    Ok(())
}
