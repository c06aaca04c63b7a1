//! `flatport calibrate --images DIR --rig RIG.json --targetless`: the port(s) of a rig calibrated
//! in air, from synchronized frames of any textured scene, no board (DESIGN.md §3c, issue 40).

use std::path::Path;

use anyhow::{Context, bail};

use flatport::calib::targetless::{DEFAULT_FRAMES, TargetlessOptions, calibrate_targetless};
use flatport::io::frames::{FrameSelection, read_camera_frames};
use flatport::io::{read_rig, write_rig};
use flatport::model::Rig;
use flatport::stereo::GreyImage;

use super::calib::{CalibrateArgs, rig_truth_errors};

/// The frames of every rig camera from `dir` (a folder per camera, named as in the rig), as
/// `--frames` picks them or at most [`DEFAULT_FRAMES`] spread over the footage; notes the folders
/// that name no camera and says on stderr what is read.
pub fn read_frames(
    rig: &Rig,
    dir: &Path,
    frames: Option<FrameSelection>,
) -> anyhow::Result<Vec<Vec<GreyImage>>> {
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    let read = read_camera_frames(dir, &names, frames, DEFAULT_FRAMES)?;
    for name in &read.unused {
        eprintln!("note: folder '{name}' is not a camera of the rig: not used");
    }
    eprintln!(
        "targetless: cameras {} (master {}), {} of {} frame(s) ({})",
        names.join(", "),
        names[0],
        read.indices.len(),
        read.count,
        match frames {
            Some(s) => format!("--frames {s}"),
            None => format!(
                "frame step {}: at most {DEFAULT_FRAMES} spread over the footage",
                read.selection.step
            ),
        },
    );
    Ok(read.frames)
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
    let frames = read_frames(&rig, dir, args.frames)?;
    eprintln!("estimating {}", args.estimate.name());
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
    if let Some(report_dir) = &args.report_dir {
        let input =
            flatport::report::Input::from_targetless(&super::calib::command_line(), &result);
        super::calib::written_report(report_dir, &input)?;
    }
    let calibrated = result.confident_rig()?;
    write_rig(&args.output, calibrated)?;
    println!("wrote {}", args.output.display());
    Ok(())
}
