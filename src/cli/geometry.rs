//! `project`, `backproject`, `triangulate`, `vop`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;

use flatport::io::read_rig;
use flatport::model::Rig;

use super::CommonArgs;
use super::batch::stream;

/// `flatport project` and `flatport vop`: points in, one camera.
#[derive(Debug, Args)]
pub struct PointsArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Points CSV with header x,y,z (master frame, metres)
    #[arg(long, value_name = "POINTS.csv")]
    points: PathBuf,
    /// Camera by name or index (default: the master camera)
    #[arg(long, value_name = "NAME|INDEX", allow_hyphen_values = true)]
    camera: Option<String>,
}

/// `flatport backproject`
#[derive(Debug, Args)]
pub struct BackprojectArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Pixels CSV with header u,v (raw, distorted pixels)
    #[arg(long, value_name = "PIXELS.csv")]
    pixels: PathBuf,
    /// Camera by name or index (default: the master camera)
    #[arg(long, value_name = "NAME|INDEX", allow_hyphen_values = true)]
    camera: Option<String>,
}

/// `flatport triangulate`
#[derive(Debug, Args)]
pub struct TriangulateArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Matches CSV with header ul,vl,ur,vr (raw pixels in the first and second camera)
    #[arg(long, value_name = "MATCHES.csv")]
    matches: PathBuf,
    /// The two cameras, by name or index (default: the first two of the rig)
    #[arg(long, value_name = "A,B", value_parser = super::parse_pair, allow_hyphen_values = true)]
    cameras: Option<(String, String)>,
}

/// Index of `--camera` (or the option named `option`) in the rig, the master when absent.
pub fn camera_index(rig: &Rig, camera: Option<&str>, option: &str) -> anyhow::Result<usize> {
    let Some(name) = camera else { return Ok(0) };
    rig.camera_index(name).with_context(|| {
        let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
        format!(
            "{option}: no camera '{name}' in the rig (cameras: {}; or an index 0..{})",
            names.join(", "),
            names.len() - 1
        )
    })
}

pub fn project(args: PointsArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref(), "--camera")?);
    let engine = args.common.engine.engine()?;
    stream(
        &engine,
        &args.points,
        ["x", "y", "z"],
        args.common.output.as_deref(),
        ["u", "v"],
        |e, points, pixels, status| e.project(&camera, points, pixels, status),
    )
}

pub fn backproject(args: BackprojectArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref(), "--camera")?);
    let engine = args.common.engine.engine()?;
    let header = ["ox", "oy", "oz", "dx", "dy", "dz"];
    stream(
        &engine,
        &args.pixels,
        ["u", "v"],
        args.common.output.as_deref(),
        header,
        |e, pixels, rays, status| e.backproject(&camera, pixels, rays, status),
    )
}

pub fn triangulate(args: TriangulateArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let (a, b) = match &args.cameras {
        Some((a, b)) => (
            camera_index(&rig, Some(a), "--cameras")?,
            camera_index(&rig, Some(b), "--cameras")?,
        ),
        None => {
            if rig.cameras().len() < 2 {
                bail!(
                    "triangulate needs two cameras, but {} has only '{}'",
                    args.common.rig.display(),
                    rig.cameras()[0].name
                );
            }
            (0, 1)
        }
    };
    if a == b {
        bail!(
            "--cameras names the same camera twice ('{}')",
            rig.cameras()[a].name
        );
    }
    let (first, second) = (rig.refractive_camera(a), rig.refractive_camera(b));
    let engine = args.common.engine.engine()?;
    let output = args.common.output.as_deref();
    stream(
        &engine,
        &args.matches,
        ["ul", "vl", "ur", "vr"],
        output,
        ["x", "y", "z", "residual"],
        |e, matches, points, status| e.triangulate(&first, &second, matches, points, status),
    )
}

pub fn vop(args: PointsArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref(), "--camera")?);
    let engine = args.common.engine.engine()?;
    let header = [
        "depth",
        "vop_distance",
        "vop_x",
        "vop_y",
        "vop_z",
        "incidence",
    ];
    stream(
        &engine,
        &args.points,
        ["x", "y", "z"],
        args.common.output.as_deref(),
        header,
        |e, points, vops, status| e.vop(&camera, points, vops, status),
    )
}
