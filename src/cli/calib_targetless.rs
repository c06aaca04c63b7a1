//! `flatport calibrate --images DIR --rig RIG.json --targetless`: the port(s) of a rig calibrated
//! in air, from synchronized frames of any textured scene, no board (DESIGN.md §3c, issue 40).

use std::path::Path;

use anyhow::{Context, bail};

use flatport::calib::targetless::{TargetlessOptions, calibrate_targetless};
use flatport::io::frames::{FrameSelection, FrameSource, check_synchronized, open_cameras};
use flatport::io::{read_rig, write_rig};
use flatport::model::Rig;
use flatport::stereo::GreyImage;

use super::calib::{CalibrateArgs, rig_truth_errors};

/// Frames used when `--frames` is not given: at most this many, spread evenly over the footage.
const DEFAULT_FRAMES: usize = 8;

/// Each rig camera's frame source from `dir` (a folder per camera, named as in the rig).
fn sources(rig: &Rig, dir: &Path) -> anyhow::Result<Vec<(String, FrameSource)>> {
    let mut found = open_cameras(dir)?;
    let mut ordered = Vec::with_capacity(rig.cameras().len());
    for camera in rig.cameras() {
        let Some(i) = found.iter().position(|(name, _)| *name == camera.name) else {
            bail!(
                "{}: no folder for camera '{}' (--targetless needs one folder per rig camera, named as in the rig; found: {})",
                dir.display(),
                camera.name,
                found
                    .iter()
                    .map(|(n, _)| n.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        };
        ordered.push(found.swap_remove(i));
    }
    for (name, _) in &found {
        eprintln!("note: folder '{name}' is not a camera of the rig: not used");
    }
    Ok(ordered)
}

/// The run of `flatport calibrate --images DIR --rig RIG.json --targetless`.
pub fn run(args: &CalibrateArgs, dir: &Path) -> anyhow::Result<()> {
    let rig_path = args.rig.as_ref().context(
        "--targetless needs --rig RIG.json (the cameras calibrated in air, the port guessed)",
    )?;
    let rig = read_rig(rig_path)?;
    if args.estimate.intrinsics {
        bail!(
            "--targetless does not estimate intrinsics: calibrate the lenses in air first (calibrate --images with air/ views of a board)"
        );
    }
    let sources = sources(&rig, dir)?;
    let count = check_synchronized(dir, &sources)?;
    let selection = args.frames.unwrap_or(FrameSelection {
        start: 0,
        stop: None,
        step: count.div_ceil(DEFAULT_FRAMES).max(1),
    });
    let indices: Vec<usize> = selection
        .indices(count)
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .collect();
    let mut frames: Vec<Vec<GreyImage>> = vec![Vec::with_capacity(sources.len()); indices.len()];
    for (name, source) in &sources {
        for (slot, item) in frames.iter_mut().zip(source.frames(&selection)?) {
            let (_, image) = item.with_context(|| format!("camera '{name}'"))?;
            slot.push(GreyImage {
                width: image.width(),
                height: image.height(),
                pixels: image.pixels().map(|p| f32::from(p.0[0]) / 255.0).collect(),
            });
        }
    }
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    eprintln!(
        "targetless: cameras {} (master {}), {} of {count} frame(s) ({}), estimating {}",
        names.join(", "),
        names[0],
        indices.len(),
        match args.frames {
            Some(s) => format!("--frames {s}"),
            None => format!(
                "frame step {}: at most {DEFAULT_FRAMES} spread over the footage",
                selection.step
            ),
        },
        args.estimate.name()
    );
    let options = TargetlessOptions {
        estimate: args.estimate,
        max_axis_sigma_deg: args.max_sigma_axis_deg,
        max_distance_sigma_m: args.max_sigma_distance_mm * 1e-3,
        ..TargetlessOptions::default()
    };
    let quiet = args.quiet;
    let started = std::time::Instant::now();
    let result = calibrate_targetless(&rig, &frames, &options, &mut |line| {
        if !quiet {
            eprintln!("  {line}");
        }
    })?;
    println!(
        "fit: {} of {} tracks ({} observations), {:.4} px RMS, {} start(s), {} ({:.1} s)",
        result.inliers,
        result.candidates,
        result.observations,
        result.rms_px,
        result.starts,
        result.termination.describe(),
        started.elapsed().as_secs_f64()
    );
    for port in &result.ports {
        let n = port.port.normal();
        let axis = port
            .axis_sigma_deg
            .map_or(" (known)".to_string(), |s| format!(" σ {s:.4}°"));
        let distance = port
            .distance_sigma_m
            .map_or(" (known)".to_string(), |s| format!(" σ {:.3} mm", s * 1e3));
        println!(
            "port {}: axis [{:.6}, {:.6}, {:.6}] (tilt {:.3}°, azimuth {:.2}°){axis}; air distance {:.3} mm{distance}",
            port.name,
            n.x,
            n.y,
            n.z,
            port.port.tilt().to_degrees(),
            port.port.azimuth().to_degrees(),
            port.port.air_distance() * 1e3
        );
    }
    if let Some(truth) = &args.truth {
        let truth = read_rig(truth)?;
        println!("{}", rig_truth_errors(&result.rig, &truth));
    }
    let calibrated = result.confident_rig()?;
    write_rig(&args.output, calibrated)?;
    println!("wrote {}", args.output.display());
    Ok(())
}
