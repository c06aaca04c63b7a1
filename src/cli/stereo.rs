//! `flatport stereo`: dense depth maps, point clouds and fused clouds from a rig's synchronised images
//! or videos, over a sequence of frames (selected, resumed, sharded).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::{Context, bail};
use clap::Args;
use serde_json::json;

use flatport::calib::sweep::Shard;
use flatport::io::frames::FrameSelection;
use flatport::io::read_rig;
use flatport::io::stereo_files::{
    CloudPoint, OrientedCloudPoint, write_depth_png, write_npy_f32, write_point_cloud_ply,
};
use flatport::io::sweep_shard::sha256_file;
use flatport::io::write_atomic;
use flatport::model::Rig;
use flatport::render::GreyImage;
use flatport::report::stereo::{StereoFrame, StereoInput, write_stereo_report};
use flatport::runs::sequence::{Sequence, SequenceFrame};
use flatport::stereo::fuse::{FuseOptions, FuseView, fuse};
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::range::{CountChoice, MAX_HYPOTHESES, RangeChoice, Sampling};
use flatport::stereo::{
    Backend, DepthMap, StereoOptions, StereoProgress, choose_sampling, consistency_px_for,
    resolve_depth_range, stereo_on,
};

use super::Device;
use super::progress::Progress;

/// `flatport stereo`
#[derive(Debug, Args)]
pub struct StereoArgs {
    /// Rig file: the cameras and their port(s)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Folder with one sub-folder per rig camera, named as in the rig, holding its images (PNG,
    /// JPEG, TIFF; frames paired by sorted file name, the layout `flatport render` writes) or one
    /// video (MP4, MOV, AVI, MKV; frames paired by index, decoded by the ffmpeg tool)
    #[arg(long, value_name = "DIR")]
    images: PathBuf,
    /// Which frames: START:STOP:STEP as Python slices (0-based; each part optional: 0:300:10,
    /// ::5, 40:, or one frame N)
    #[arg(long, value_name = "START:STOP:STEP", default_value = ":", value_parser = parse_frames)]
    frames: FrameSelection,
    /// Skip the frames whose outputs are complete in the output folder (FRAME/frame.json written
    /// with the same rig file and settings, every file it lists there with its size); the
    /// others are computed, and summary.json covers them all
    #[arg(long)]
    resume: bool,
    /// Compute slice INDEX of COUNT (0-based: 0/4 … 3/4) of the selected frames: contiguous
    /// blocks, frames ⌊I·n/N⌋ up to ⌊(I+1)·n/N⌋ of the n selected, the summary in
    /// summary-shard-I-of-N.json; afterwards the same command with --resume and no --shard
    /// writes summary.json for all of them without computing any again
    #[arg(long, value_name = "INDEX/COUNT", value_parser = Shard::parse)]
    shard: Option<Shard>,
    /// Also fuse each frame's depth maps into FRAME/fused.ply: every camera is the reference in
    /// turn, a point is kept where another camera's map confirms it, points closer than a pixel's
    /// footprint are merged, with normals (toward the camera that saw them) and colours. Costs one
    /// stereo run per camera
    #[arg(long)]
    fuse: bool,
    /// Output folder: per frame FRAME/{points,depth,confidence}.npy, cloud.ply, depth.png,
    /// frame.json (and fused.ply with --fuse); summary.json (a shard's: summary-shard-I-of-N.json)
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
    /// The reference camera (name or index; default: the master, the rig's first camera)
    #[arg(long, value_name = "CAMERA")]
    reference: Option<String>,
    /// Range of depth z in the reference camera's frame, metres (default: found per frame by a
    /// coarse sweep of the images at most 160 px wide from where the cameras' views overlap out
    /// to 20 m: the range of its confident depths, padded; 0.3:3 with a warning where it finds
    /// none)
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range, allow_hyphen_values = true)]
    depth: Option<(f64, f64)>,
    /// Depth hypotheses per pixel, uniform in 1/z (default: the step rule, the fewest for which
    /// one step moves a hypothesis by at most 0.8 px in every voting camera over the whole range
    /// and image, 16 to 512)
    #[arg(long, value_name = "N")]
    hypotheses: Option<usize>,
    /// ZNCC window radius in pixels: (2R+1)² windows (3 at any resolution: at 1280 × 1024, 6 left
    /// 9.4 % gross points where no other camera sees; docs/stereo.md)
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
    /// Also write DIR/index.html, a page to read offline: the depth range and sampling each frame
    /// chose and why, completeness per frame, and depth and confidence pictures (at most 12
    /// frames spread over the run), with frames.csv
    #[arg(long, value_name = "DIR")]
    report_dir: Option<PathBuf>,
    /// No progress bar
    #[arg(long, short)]
    quiet: bool,
}

/// `START:STOP:STEP` ([`FrameSelection`]).
fn parse_frames(text: &str) -> Result<FrameSelection, String> {
    text.parse()
        .map_err(|e: flatport::io::frames::FrameSelectionError| e.to_string())
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

/// The files of every frame, in the order they are written; [`FRAME_RECORD`] comes last.
const FRAME_FILES: [&str; 5] = [
    "points.npy",
    "depth.npy",
    "confidence.npy",
    "cloud.ply",
    "depth.png",
];
/// The fused cloud of `--fuse`.
const FUSED_FILE: &str = "fused.ply";
/// A frame's record, written after its other files: its summary entry, the settings it was made
/// with and the size of every file; a frame is complete when it is there and they all are.
const FRAME_RECORD: &str = "frame.json";

pub fn run(args: StereoArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    let reference = match &args.reference {
        None => 0,
        Some(name) => rig.camera_index(name).with_context(|| {
            format!(
                "--reference {name}: the rig {} has cameras {}",
                args.rig.display(),
                names.join(", ")
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
    let range = resolve_depth_range(&rig, &options).context("--depth")?;
    // With --fuse every camera is the reference once, each with its range (its own default, or
    // --depth as z in its own frame): all checked before anything is read or written.
    let mut references = Vec::new();
    for (k, name) in names.iter().enumerate() {
        if k != reference && !args.fuse {
            continue;
        }
        let o = StereoOptions {
            reference: k,
            ..options.clone()
        };
        resolve_depth_range(&rig, &o)
            .with_context(|| format!("--depth with camera '{name}' as the reference"))?;
        references.push(o);
    }
    let sequence = Sequence::open(&rig, &args.images)?;
    let selected = sequence.select(&args.frames)?;
    let frames: &[usize] = match args.shard {
        Some(shard) => &selected[shard.cells(selected.len())],
        None => &selected,
    };
    let frame_names: Vec<String> = frames
        .iter()
        .map(|&i| sequence.frame_name(reference, i))
        .collect();
    let mut seen = HashMap::new();
    for (&index, name) in frames.iter().zip(&frame_names) {
        if let Some(other) = seen.insert(name.as_str(), index) {
            bail!(
                "frames {other} and {index} of camera '{}' are both named '{name}' (images of one name in two formats?): each frame needs its own output folder",
                names[reference]
            );
        }
    }
    // The settings as given (a range or count chosen per frame is null here): a frame's choice
    // depends on its own images only, so shards and resumed runs make the same outputs.
    let settings = json!({
        "rig_sha256": sha256_file(&args.rig)?,
        "reference": names[reference],
        "depth_range_m": range.map(|(a, b)| [a, b]),
        "hypotheses": options.hypotheses,
        "window": 2 * options.window_radius + 1,
        "min_confidence": options.min_confidence,
        // The consistency tolerance each reference uses (given, or the focal-length rule), so
        // that outputs made under another tolerance are not taken as complete.
        "consistency_px": references
            .iter()
            .map(|o| {
                let c = &rig.cameras()[o.reference].intrinsics;
                o.consistency_px
                    .unwrap_or_else(|| consistency_px_for(0.5 * (c.fx + c.fy)))
            })
            .collect::<Vec<f64>>(),
        "fuse": args.fuse,
    });
    let mut records: HashMap<usize, serde_json::Value> = HashMap::new();
    let mut todo = Vec::new();
    for (&index, name) in frames.iter().zip(&frame_names) {
        if args.resume {
            match complete_frame(&args.output.join(name), &settings, args.fuse) {
                Ok(record) => {
                    records.insert(index, record);
                    continue;
                }
                Err(Incomplete::Absent) => {}
                Err(Incomplete::Because(why)) => eprintln!("{name}: computed again: {why}"),
            }
        }
        todo.push(index);
    }
    // Every image of the frames to compute decodes (videos are checked as they are read).
    sequence.check_images(&todo)?;
    let (gpu, device) = if todo.is_empty() {
        (None, "none (every frame complete)".to_string())
    } else {
        choose_device(&args, &rig, &options)?
    };
    let backend = match &gpu {
        Some(gpu) => Backend::Gpu(gpu),
        None => Backend::Cpu,
    };
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))?;
    let shard_text = args
        .shard
        .map(|s| format!(", shard {s}"))
        .unwrap_or_default();
    outln!(
        "{} frame(s) of {} selected{shard_text}: {} to compute, {} complete (--resume)",
        frames.len(),
        sequence.len(),
        todo.len(),
        frames.len() - todo.len()
    );
    let bar = Mutex::new(Progress::new(
        &format!(
            "stereo {} frame(s), {} reference camera(s)",
            todo.len(),
            references.len()
        ),
        "hypotheses",
        args.quiet,
    ));
    let name_of: HashMap<usize, &String> = frames.iter().copied().zip(&frame_names).collect();
    for (done, frame) in sequence.reader(&todo).enumerate() {
        let frame = frame?;
        let name = name_of[&frame.index];
        let record = compute_frame(
            &rig,
            &frame,
            name,
            &references,
            reference,
            backend,
            &device,
            &settings,
            &args.output.join(name),
            &|run, p| {
                // One unit per hypothesis and band of rows of every depth map of every frame.
                let per_map = p.runs * p.total;
                let per_frame = per_map * references.len();
                if let Ok(mut bar) = bar.lock() {
                    bar.update(
                        done * per_frame + run * per_map + p.run * p.total + p.done,
                        todo.len() * per_frame,
                    );
                }
            },
        )?;
        records.insert(frame.index, record);
    }
    // Over the frames: the union of their ranges and the most hypotheses (each frame's own in
    // "frames").
    let mut span = (f64::INFINITY, 0f64);
    let mut most = 0;
    for record in records.values() {
        if let Some([a, b]) = record["depth_range_m"]
            .as_array()
            .and_then(|r| Some([r.first()?.as_f64()?, r.get(1)?.as_f64()?]))
        {
            span = (span.0.min(a), span.1.max(b));
        }
        most = most.max(record["hypotheses"].as_u64().unwrap_or(0));
    }
    let entries: Vec<serde_json::Value> = frames
        .iter()
        .filter_map(|i| records.remove(i))
        .map(|mut record| {
            if let Some(object) = record.as_object_mut() {
                object.remove("settings");
                object.remove("files");
            }
            record
        })
        .collect();
    let mut document = json!({
        "rig": args.rig.display().to_string(),
        "images": args.images.display().to_string(),
        "frames_selected": args.frames.to_string(),
        "frames_in_sequence": sequence.len(),
        "reference": names[reference],
        "depth_range_m": [span.0, span.1],
        "hypotheses": most,
        "depth_range_chosen": if options.depth_range.is_some() { "given" } else { "found from the images (coarse sweep)" },
        "hypotheses_chosen": if options.hypotheses.is_some() { "given" } else { "step rule" },
        "window": 2 * options.window_radius + 1,
        "min_confidence": options.min_confidence,
        "fuse": args.fuse,
        "device": device,
        "computed": todo.len(),
        "skipped_complete": frames.len() - todo.len(),
        "frames": entries,
    });
    let summary = match args.shard {
        Some(shard) if shard.count > 1 => {
            document["shard"] = json!({"index": shard.index, "count": shard.count});
            format!("summary-shard-{}-of-{}.json", shard.index, shard.count)
        }
        _ => "summary.json".to_string(),
    };
    let mut text = serde_json::to_string_pretty(&document).expect("plain data");
    text.push('\n');
    write_atomic(&args.output.join(&summary), text.as_bytes())?;
    outln!(
        "wrote {} frame(s) into {}/: FRAME/points.npy, depth.npy, confidence.npy, cloud.ply, depth.png{}, frame.json; {summary}",
        todo.len(),
        args.output.display(),
        if args.fuse { ", fused.ply" } else { "" }
    );
    if let Some(dir) = &args.report_dir {
        let input = StereoInput {
            command: super::calib::command_line(),
            reference: names[reference].to_string(),
            device: device.clone(),
            window: 2 * options.window_radius + 1,
            min_confidence: options.min_confidence,
            frames: document["frames"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|record| report_frame(record, &args.output))
                .collect(),
        };
        let written = write_stereo_report(dir, &input)?;
        outln!(
            "report: {} ({} files)",
            written.index.display(),
            written.files.len()
        );
    }
    Ok(())
}

/// Why a frame's outputs are not taken as complete.
enum Incomplete {
    /// It has no record: never computed (or its computation was stopped).
    Absent,
    /// A record that does not hold: a file missing or not whole, other settings.
    Because(String),
}

/// The record of a complete frame in `dir`: `frame.json` reads, was made with `settings`, lists
/// every output, and each output it lists is there with the size it records (outputs are
/// written whole or not at all, the record after them).
fn complete_frame(
    dir: &Path,
    settings: &serde_json::Value,
    fuse: bool,
) -> Result<serde_json::Value, Incomplete> {
    let path = dir.join(FRAME_RECORD);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Err(Incomplete::Absent);
    };
    let because = |why: String| Incomplete::Because(why);
    let record: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| because(format!("{}: {e}", path.display())))?;
    let made_with = record
        .get("settings")
        .and_then(serde_json::Value::as_object);
    let now = settings.as_object().into_iter().flatten();
    let changed: Vec<String> = now
        .filter(|(key, value)| made_with.and_then(|m| m.get(*key)) != Some(*value))
        .map(|(key, value)| {
            let then = made_with.and_then(|m| m.get(key));
            format!(
                "{key} {} then, {value} now",
                then.unwrap_or(&serde_json::Value::Null)
            )
        })
        .collect();
    if !changed.is_empty() {
        return Err(because(format!(
            "it was made with other settings ({})",
            changed.join("; ")
        )));
    }
    let files = record
        .get("files")
        .and_then(serde_json::Value::as_object)
        .ok_or_else(|| because(format!("{}: no \"files\"", path.display())))?;
    let wanted = FRAME_FILES.iter().chain(fuse.then_some(&FUSED_FILE));
    for name in wanted {
        let size = files.get(*name).and_then(serde_json::Value::as_u64);
        let actual = std::fs::metadata(dir.join(name)).ok().map(|m| m.len());
        match (size, actual) {
            (Some(size), Some(actual)) if size == actual => {}
            (None, _) => return Err(because(format!("{} does not list {name}", path.display()))),
            (Some(_), None) => return Err(because(format!("{name} is missing"))),
            (Some(size), Some(actual)) => {
                return Err(because(format!(
                    "{name} has {actual} bytes, {size} were written"
                )));
            }
        }
    }
    Ok(record)
}

/// The depth maps of one frame (each reference of `references`; the first outputs are those of
/// `reference`), its files written into `dir`, its record last; returns the record.
#[allow(clippy::too_many_arguments)]
fn compute_frame(
    rig: &Rig,
    frame: &SequenceFrame,
    name: &str,
    references: &[StereoOptions],
    reference: usize,
    backend: Backend,
    device: &str,
    settings: &serde_json::Value,
    dir: &Path,
    progress: &(dyn Fn(usize, &StereoProgress) + Sync),
) -> anyhow::Result<serde_json::Value> {
    let started = std::time::Instant::now();
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    let images: Vec<GreyImage> = frame.images.iter().map(|c| c.grey.clone()).collect();
    let mut maps = Vec::with_capacity(references.len());
    let mut samplings = Vec::with_capacity(references.len());
    for (run, options) in references.iter().enumerate() {
        // The range and count chosen first (and said), so that a long run shows them at its
        // start; the check cameras' own counts follow the same rule inside the run.
        let sampling = choose_sampling(rig, &images, options, backend)?;
        if options.depth_range.is_none() || options.hypotheses.is_none() {
            eprintln!("{name}, camera {}: {sampling}", names[options.reference]);
        }
        let frame_options = StereoOptions {
            depth_range: Some(sampling.depth_range),
            ..options.clone()
        };
        let map = stereo_on(rig, &images, &frame_options, backend, &|p| progress(run, p))?;
        maps.push(map);
        samplings.push(sampling);
    }
    let main = maps
        .iter()
        .position(|m| m.reference == reference)
        .expect("the reference is among the references");
    let map = &maps[main];
    let sampling = &samplings[main];
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let (w, h) = (map.width, map.height);
    let fraction = map.valid as f64 / (w * h) as f64;
    // The five files at once: they are independent, and one after another they were a tenth of
    // a 1280 × 1024 frame's time.
    let write_arrays = || -> anyhow::Result<()> {
        let flat: Vec<f32> = map.points.iter().flatten().copied().collect();
        write_npy_f32(&dir.join("points.npy"), &[h, w, 3], &flat)?;
        write_npy_f32(&dir.join("depth.npy"), &[h, w], &map.depth)?;
        write_npy_f32(&dir.join("confidence.npy"), &[h, w], &map.confidence)?;
        Ok(())
    };
    let write_cloud = || -> anyhow::Result<()> {
        let cloud: Vec<CloudPoint> = map
            .points
            .iter()
            .zip(&frame.images[reference].rgb)
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
                    "flatport stereo, frame {name}, reference camera {}",
                    names[reference]
                ),
                "points in the rig's master frame, metres".into(),
            ],
        )?;
        Ok(())
    };
    let write_png = || -> anyhow::Result<()> {
        write_depth_png(
            &dir.join("depth.png"),
            w as u32,
            h as u32,
            &map.depth,
            &format!(
                "{name}: depth z in camera '{}', {:.1} % of pixels",
                names[reference],
                100.0 * fraction
            ),
        )?;
        Ok(())
    };
    let (arrays, (cloud, png)) = rayon::join(write_arrays, || rayon::join(write_cloud, write_png));
    arrays?;
    cloud?;
    png?;
    let mut fused_points = None;
    if references.len() > 1 {
        let fused = fuse_frame(rig, &maps, frame, name, dir)?;
        fused_points = Some(fused);
    }
    let seconds = started.elapsed().as_secs_f64();
    outln!(
        "{name}: {:.1} % of pixels with a point ({} points){}, {:.1} s",
        100.0 * fraction,
        map.valid,
        fused_points.map_or(String::new(), |n| format!(", {n} fused points")),
        seconds
    );
    let mut stages: Vec<(&str, f64)> = Vec::new();
    for m in &maps {
        for (stage, s) in &m.stage_seconds {
            match stages.iter_mut().find(|(n, _)| n == stage) {
                Some((_, total)) => *total += s,
                None => stages.push((stage, *s)),
            }
        }
    }
    let stages: serde_json::Map<String, serde_json::Value> = stages
        .into_iter()
        .map(|(stage, s)| (stage.to_string(), json!(s)))
        .collect();
    let mut files = serde_json::Map::new();
    for file in FRAME_FILES
        .iter()
        .chain(fused_points.is_some().then_some(&FUSED_FILE))
    {
        let path = dir.join(file);
        let size = std::fs::metadata(&path)
            .with_context(|| format!("{}: just written, cannot be read", path.display()))?
            .len();
        files.insert(file.to_string(), json!(size));
    }
    let mut record = json!({
        "frame": name,
        "index": frame.index,
        "valid_fraction": fraction,
        "valid_points": map.valid,
        "pixels": w * h,
        "seconds": seconds,
        "stage_seconds": stages,
        "device": device,
        "hypotheses": map.hypotheses,
        "depth_range_m": [sampling.depth_range.0, sampling.depth_range.1],
        "sampling": sampling_json(sampling),
        "depth_maps": maps.iter().map(|m| m.runs).sum::<usize>(),
        "consistency_px": map.consistency_px,
        "settings": settings,
        "files": files,
    });
    if let Some(n) = fused_points {
        record["fused_points"] = json!(n);
    }
    let mut text = serde_json::to_string_pretty(&record).expect("plain data");
    text.push('\n');
    write_atomic(&dir.join(FRAME_RECORD), text.as_bytes())?;
    Ok(record)
}

/// Fuses a frame's depth maps (one per camera) into `dir`/fused.ply; the number of points.
fn fuse_frame(
    rig: &Rig,
    maps: &[DepthMap],
    frame: &SequenceFrame,
    name: &str,
    dir: &Path,
) -> anyhow::Result<usize> {
    let views: Vec<FuseView> = maps
        .iter()
        .map(|map| FuseView {
            map,
            colours: &frame.images[map.reference].rgb,
        })
        .collect();
    let options = FuseOptions::default();
    let cloud = fuse(rig, &views, &options)?;
    let points: Vec<OrientedCloudPoint> = cloud
        .iter()
        .map(|p| OrientedCloudPoint {
            position: p.position.map(|v| v as f32),
            normal: p.normal.map(|v| v as f32),
            colour: p.colour,
        })
        .collect();
    write_point_cloud_ply(
        &dir.join(FUSED_FILE),
        &points,
        &[
            format!(
                "flatport stereo --fuse, frame {name}: the depth maps of cameras {} fused",
                rig.cameras()
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            format!(
                "points confirmed by another camera within {} % of depth, merged within {} pixel footprint(s), normals from {} neighbours toward the camera",
                100.0 * options.depth_tolerance,
                options.merge_pixels,
                options.normal_neighbours
            ),
            "points and normals in the rig's master frame, metres".into(),
        ],
    )?;
    Ok(points.len())
}

/// A frame's summary entry as its report shows it; its maps are in `output`/FRAME.
fn report_frame(record: &serde_json::Value, output: &Path) -> StereoFrame {
    let name = record["frame"].as_str().unwrap_or("?").to_string();
    let pair = |v: &serde_json::Value| Some((v.get(0)?.as_f64()?, v.get(1)?.as_f64()?));
    let sampling = &record["sampling"];
    StereoFrame {
        folder: output.join(&name),
        name,
        valid_fraction: record["valid_fraction"].as_f64().unwrap_or(f64::NAN),
        points: record["valid_points"].as_u64().unwrap_or(0) as usize,
        seconds: record["seconds"].as_f64().unwrap_or(f64::NAN),
        hypotheses: record["hypotheses"].as_u64().unwrap_or(0) as usize,
        depth_range_m: pair(&record["depth_range_m"]).unwrap_or((f64::NAN, f64::NAN)),
        range_how: sampling["depth_range"]["how"]
            .as_str()
            .unwrap_or("?")
            .to_string(),
        quantiles_m: pair(&sampling["depth_range"]["coarse_sweep"]["quantiles_m"]),
        count_how: sampling["hypotheses"]["how"]
            .as_str()
            .unwrap_or("?")
            .to_string(),
        largest_step_px: sampling["hypotheses"]["rule"]["largest_step_px"].as_f64(),
    }
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
