//! `flatport stereo`: dense depth maps and point clouds from a rig's synchronised images.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::{Context, bail};
use clap::Args;
use serde_json::json;

use flatport::io::read_rig;
use flatport::io::stereo_files::{
    CloudPoint, read_colour_image, read_grey_f32, write_depth_png, write_npy_f32,
    write_point_cloud_ply,
};
use flatport::io::write_atomic;
use flatport::model::Rig;
use flatport::render::GreyImage;
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::range::{CountChoice, MAX_HYPOTHESES, RangeChoice, Sampling};
use flatport::stereo::{Backend, StereoOptions, choose_sampling, resolve_depth_range, stereo_on};

use super::Device;
use super::progress::Progress;

/// `flatport stereo`
#[derive(Debug, Args)]
pub struct StereoArgs {
    /// Rig file: the cameras and their port(s)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Folder with one sub-folder of images per rig camera, named as in the rig (the layout
    /// `flatport render` writes); frames are matched by sorted file name
    #[arg(long, value_name = "DIR")]
    images: PathBuf,
    /// Output folder: FRAME/{points,depth,confidence}.npy, FRAME/cloud.ply, FRAME/depth.png per
    /// frame, and summary.json
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
    /// The reference camera (name or index; default: the master, the rig's first camera)
    #[arg(long, value_name = "CAMERA")]
    reference: Option<String>,
    /// Range of depth z in the reference camera's frame, metres (default: found per frame by a
    /// coarse sweep of the images at most 320 px wide from the port out to 20 m: the range of
    /// its confident depths, padded; 0.3:3 with a warning where it finds none)
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range, allow_hyphen_values = true)]
    depth: Option<(f64, f64)>,
    /// Depth hypotheses per pixel, uniform in 1/z (default: the step rule, the fewest for which
    /// one step moves a hypothesis by at most 0.8 px in every voting camera over the whole range
    /// and image, 16 to 512)
    #[arg(long, value_name = "N")]
    hypotheses: Option<usize>,
    /// ZNCC window radius in pixels: (2R+1)² windows
    #[arg(long, value_name = "R", default_value_t = 3)]
    window: usize,
    /// Least confidence (0 to 1) of a returned point
    #[arg(long, value_name = "C", default_value_t = StereoOptions::default().min_confidence)]
    min_confidence: f64,
    /// Where the sweep runs (rays, costs, SGM, selection; the consistency check is on the CPU):
    /// gpu the WGSL kernels on a Vulkan adapter (f32; lavapipe when there is no GPU), cpu the
    /// f64 stages on every core, auto a hardware GPU when there is one and the cost volume fits
    /// it, else the CPU (lavapipe runs these kernels ~30× slower than the CPU path)
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    device: Device,
    /// GPU adapter: its index or part of its name as `flatport info` lists them (else
    /// $FLATPORT_ADAPTER, else the best: discrete, integrated, then lavapipe)
    #[arg(long, value_name = "INDEX|NAME")]
    adapter: Option<String>,
    /// No progress bar
    #[arg(long, short)]
    quiet: bool,
}

/// `MIN:MAX`, two finite numbers.
fn parse_range(text: &str) -> Result<(f64, f64), String> {
    let parts: Vec<&str> = text.split(':').collect();
    let [a, b] = parts[..] else {
        return Err(format!(
            "expected MIN:MAX in metres such as 0.5:3, got '{text}'"
        ));
    };
    let number = |t: &str| -> Result<f64, String> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("'{t}' is not a finite number (in '{text}')"))
    };
    Ok((number(a)?, number(b)?))
}

/// File name extensions read as images.
const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "tif", "tiff"];

/// Each camera's image files (rig order), sorted by file name, with the frames checked to match:
/// the same count everywhere, and a file name that two cameras share at the same place in both.
pub fn list_frames(rig: &Rig, dir: &Path) -> anyhow::Result<Vec<Vec<PathBuf>>> {
    if !dir.is_dir() {
        bail!(
            "{}: not a folder (--images takes a folder with one sub-folder per rig camera)",
            dir.display()
        );
    }
    let mut cameras = Vec::new();
    for camera in rig.cameras() {
        let folder = dir.join(&camera.name);
        if !folder.is_dir() {
            bail!(
                "{}: missing: the folder of camera '{}' (--images needs one sub-folder per rig camera, named as in the rig)",
                folder.display(),
                camera.name
            );
        }
        let mut files: Vec<PathBuf> = std::fs::read_dir(&folder)
            .with_context(|| format!("{}: cannot list the folder", folder.display()))?
            .filter_map(|entry| entry.ok().map(|e| e.path()))
            .filter(|p| {
                p.is_file()
                    && p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                        IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str())
                    })
            })
            .collect();
        files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
        if files.is_empty() {
            bail!(
                "{}: no image (PNG, JPEG or TIFF) of camera '{}'",
                folder.display(),
                camera.name
            );
        }
        cameras.push(files);
    }
    let first = &rig.cameras()[0].name;
    for (k, files) in cameras.iter().enumerate().skip(1) {
        let name = &rig.cameras()[k].name;
        if files.len() != cameras[0].len() {
            bail!(
                "frames do not match: camera '{first}' has {} images and camera '{name}' has {} (frames are paired by sorted file name, so every camera needs one image per frame)",
                cameras[0].len(),
                files.len()
            );
        }
        let positions: HashMap<_, usize> = cameras[0]
            .iter()
            .enumerate()
            .map(|(i, p)| (p.file_stem().map(|s| s.to_os_string()), i))
            .collect();
        for (i, file) in files.iter().enumerate() {
            if let Some(&j) = positions.get(&file.file_stem().map(|s| s.to_os_string()))
                && j != i
            {
                bail!(
                    "frames do not match: {} is frame {} of camera '{name}' but {} is frame {} of camera '{first}' (an image missing in one camera?)",
                    file.display(),
                    i,
                    cameras[0][j].display(),
                    j
                );
            }
        }
    }
    Ok(cameras)
}

/// The GPU stereo (opened once: every frame reuses its pipelines and buffers) or `None` for the
/// CPU, and the device's description; says on stderr which runs and, for auto, why.
fn choose_device(
    args: &StereoArgs,
    rig: &Rig,
    options: &StereoOptions,
) -> anyhow::Result<(Option<GpuStereo>, String)> {
    let cpu = format!(
        "cpu (vector {}, {} threads)",
        flatport::engine::cpu::lanes::instruction_set(),
        rayon::current_num_threads()
    );
    let intrinsics = &rig.cameras()[options.reference].intrinsics;
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    // Every camera is a reference once (the consistency check): the largest image decides.
    let (w, h) = rig
        .cameras()
        .iter()
        .map(|c| (c.intrinsics.width as usize, c.intrinsics.height as usize))
        .fold((w, h), |a, b| if b.0 * b.1 > a.0 * a.1 { b } else { a });
    let voters = rig.cameras().len() - 1;
    // Without --hypotheses the step rule's count is known per frame: its maximum decides.
    let hypotheses = options.hypotheses.unwrap_or(MAX_HYPOTHESES);
    match args.device {
        Device::Cpu => {
            eprintln!("device: {cpu}");
            Ok((None, cpu))
        }
        Device::Gpu => {
            let gpu = GpuStereo::new(args.adapter.as_deref()).context("--device gpu")?;
            if let Some(reason) = gpu.refuses(w, h, hypotheses, voters) {
                bail!("--device gpu: {reason}");
            }
            let name = format!("gpu: {}", gpu.context().adapter().name);
            eprintln!("device: {name}");
            Ok((Some(gpu), name))
        }
        Device::Auto => match GpuStereo::new(args.adapter.as_deref()) {
            Ok(gpu) if gpu.context().is_software() => {
                eprintln!(
                    "device: {cpu} (auto: no hardware GPU; {} runs the stereo kernels ~30× slower than the CPU, --device gpu to use it)",
                    gpu.context().adapter().name
                );
                Ok((None, cpu))
            }
            Ok(gpu) => match gpu.refuses(w, h, hypotheses, voters) {
                None => {
                    let name = format!("gpu: {}", gpu.context().adapter().name);
                    eprintln!("device: {name} (auto: a Vulkan adapter)");
                    Ok((Some(gpu), name))
                }
                Some(reason) => {
                    eprintln!("device: {cpu} (auto: {reason})");
                    Ok((None, cpu))
                }
            },
            Err(error) => {
                eprintln!("device: {cpu} (auto: {error})");
                Ok((None, cpu))
            }
        },
    }
}

pub fn run(args: StereoArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let reference = match &args.reference {
        None => 0,
        Some(name) => rig.camera_index(name).with_context(|| {
            format!(
                "--reference {name}: the rig {} has cameras {}",
                args.rig.display(),
                rig.cameras()
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?,
    };
    let options = StereoOptions {
        reference,
        depth_range: args.depth,
        hypotheses: args.hypotheses,
        window_radius: args.window,
        min_confidence: args.min_confidence,
        ..StereoOptions::default()
    };
    resolve_depth_range(&rig, &options).context("--depth")?;
    let (gpu, device) = choose_device(&args, &rig, &options)?;
    let backend = match &gpu {
        Some(gpu) => Backend::Gpu(gpu),
        None => Backend::Cpu,
    };
    let frames = list_frames(&rig, &args.images)?;
    // Every image is read and checked before anything is written.
    for (k, files) in frames.iter().enumerate() {
        let camera = &rig.cameras()[k];
        for file in files {
            let image = read_grey_f32(file)?;
            let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
            if (image.width, image.height) != (w, h) {
                bail!(
                    "{}: the image is {} × {} pixels, camera '{}' of the rig is {w} × {h}",
                    file.display(),
                    image.width,
                    image.height,
                    camera.name
                );
            }
        }
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))?;
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    let count = frames[0].len();
    let mut summary = Vec::with_capacity(count);
    let mut samplings: Vec<Sampling> = Vec::with_capacity(count);
    for f in 0..count {
        let started = std::time::Instant::now();
        let reference_file = &frames[reference][f];
        let stem = reference_file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("frame_{f:03}"));
        let colour = read_colour_image(reference_file)?;
        let mut images: Vec<GreyImage> = Vec::with_capacity(names.len());
        for (k, files) in frames.iter().enumerate() {
            images.push(if k == reference {
                colour.grey.clone()
            } else {
                read_grey_f32(&files[f])?
            });
        }
        let bar = Mutex::new(Progress::new(
            &format!("stereo {stem} ({})", names[reference]),
            "hypotheses",
            args.quiet,
        ));
        let sampling = choose_sampling(&rig, &images, &options, backend)?;
        if options.depth_range.is_none() || options.hypotheses.is_none() {
            eprintln!("{stem}: {sampling}");
        }
        let frame_options = StereoOptions {
            depth_range: Some(sampling.depth_range),
            ..options.clone()
        };
        let map = stereo_on(&rig, &images, &frame_options, backend, &|p| {
            if let Ok(mut bar) = bar.lock() {
                bar.update(p.run * p.total + p.done, p.runs * p.total);
            }
        })?;
        let dir = args.output.join(&stem);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let (w, h) = (map.width, map.height);
        let flat: Vec<f32> = map.points.iter().flatten().copied().collect();
        write_npy_f32(&dir.join("points.npy"), &[h, w, 3], &flat)?;
        write_npy_f32(&dir.join("depth.npy"), &[h, w], &map.depth)?;
        write_npy_f32(&dir.join("confidence.npy"), &[h, w], &map.confidence)?;
        let cloud: Vec<CloudPoint> = map
            .points
            .iter()
            .zip(&colour.rgb)
            .filter(|(p, _)| p[0].is_finite())
            .map(|(p, c)| CloudPoint {
                position: *p,
                colour: *c,
            })
            .collect();
        write_point_cloud_ply(
            &dir.join("cloud.ply"),
            &cloud,
            &[
                format!(
                    "flatport stereo, frame {stem}, reference camera {}",
                    names[reference]
                ),
                "points in the rig's master frame, metres".into(),
            ],
        )?;
        let fraction = map.valid as f64 / (w * h) as f64;
        write_depth_png(
            &dir.join("depth.png"),
            w as u32,
            h as u32,
            &map.depth,
            &format!(
                "{stem}: depth z in camera '{}', {:.1} % of pixels",
                names[reference],
                100.0 * fraction
            ),
        )?;
        let seconds = started.elapsed().as_secs_f64();
        outln!(
            "{stem}: {:.1} % of pixels with a point ({} points), {:.1} s",
            100.0 * fraction,
            map.valid,
            seconds
        );
        let stages: serde_json::Map<String, serde_json::Value> = map
            .stage_seconds
            .iter()
            .map(|(stage, s)| (stage.to_string(), json!(s)))
            .collect();
        summary.push(json!({
            "frame": stem,
            "valid_fraction": fraction,
            "valid_points": map.valid,
            "pixels": w * h,
            "seconds": seconds,
            "stage_seconds": stages,
            "device": device,
            "hypotheses": map.hypotheses,
            "depth_range_m": [sampling.depth_range.0, sampling.depth_range.1],
            "sampling": sampling_json(&sampling),
            "depth_maps": map.runs,
        }));
        samplings.push(sampling);
    }
    // Over the frames: the union of their ranges and the most hypotheses (each frame's own in
    // "frames").
    let range = samplings.iter().fold((f64::INFINITY, 0f64), |(a, b), s| {
        (a.min(s.depth_range.0), b.max(s.depth_range.1))
    });
    let hypotheses = samplings.iter().map(|s| s.hypotheses).max().unwrap_or(0);
    let document = json!({
        "rig": args.rig.display().to_string(),
        "images": args.images.display().to_string(),
        "reference": names[reference],
        "depth_range_m": [range.0, range.1],
        "hypotheses": hypotheses,
        "depth_range_chosen": if options.depth_range.is_some() { "given" } else { "found from the images (coarse sweep)" },
        "hypotheses_chosen": if options.hypotheses.is_some() { "given" } else { "step rule" },
        "window": 2 * options.window_radius + 1,
        "min_confidence": options.min_confidence,
        "device": device,
        "frames": summary,
    });
    let mut text = serde_json::to_string_pretty(&document).expect("plain data");
    text.push('\n');
    write_atomic(&args.output.join("summary.json"), text.as_bytes())?;
    outln!(
        "wrote {} frame(s) into {}/: FRAME/points.npy, depth.npy, confidence.npy, cloud.ply, depth.png; summary.json",
        count,
        args.output.display()
    );
    Ok(())
}

/// How a frame's depth range and hypotheses were chosen, for summary.json.
fn sampling_json(sampling: &Sampling) -> serde_json::Value {
    let rule = |r: &flatport::stereo::range::StepRule| {
        json!({
            "target_step_px": r.target_px,
            "largest_step_px": r.step_px,
            "motion_px_per_inverse_m": r.motion_px_m,
            "needed": r.needed,
            "clamped": r.clamped(),
        })
    };
    let coarse = |c: &flatport::stereo::range::CoarseSweep| {
        json!({
            "size": [c.width, c.height],
            "factor": c.factor,
            "searched_m": [c.searched_m.0, c.searched_m.1],
            "hypotheses": c.rule.count,
            "confident_pixels": c.confident,
            "quantiles_m": [c.quantiles_m.0, c.quantiles_m.1],
            "seconds": c.seconds,
        })
    };
    let range = match &sampling.range {
        RangeChoice::Given => json!({"how": "given"}),
        RangeChoice::Found(c) => json!({"how": "found", "coarse_sweep": coarse(c)}),
        RangeChoice::Fallback(c) => {
            json!({"how": "fallback (default range: too few confident depths)", "coarse_sweep": coarse(c)})
        }
    };
    let count = match &sampling.count {
        CountChoice::Given => json!({"how": "given"}),
        CountChoice::Rule(r) => json!({"how": "step rule", "rule": rule(r)}),
    };
    json!({"depth_range": range, "hypotheses": count})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse() {
        assert_eq!(parse_range("0.5:3").unwrap(), (0.5, 3.0));
        assert_eq!(parse_range("-1:2").unwrap(), (-1.0, 2.0));
        assert!(parse_range("0.5").is_err());
        assert!(parse_range("a:2").is_err());
        assert!(parse_range("1:inf").is_err());
    }
}
