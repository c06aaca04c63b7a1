//! `project`, `backproject`, `triangulate`, `vop`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use nalgebra::{Point2, Point3};

use flatport::io::{read_rig, read_table};
use flatport::model::{Rig, triangulate_rays};

use super::{CommonArgs, Device};
use super::batch::Batch;

/// `flatport project` and `flatport vop`: points in, one camera.
#[derive(Debug, Args)]
pub struct PointsArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Points CSV with header x,y,z (master frame, metres)
    #[arg(long, value_name = "POINTS.csv")]
    points: PathBuf,
    /// Camera by name or index (default: the master camera)
    #[arg(long, value_name = "NAME|INDEX")]
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
    #[arg(long, value_name = "NAME|INDEX")]
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
    #[arg(long, value_name = "A,B", value_parser = super::parse_pair)]
    cameras: Option<(String, String)>,
}

/// Index of `--camera` in the rig, the master when absent.
pub fn camera_index(rig: &Rig, camera: Option<&str>) -> anyhow::Result<usize> {
    let Some(name) = camera else { return Ok(0) };
    rig.camera_index(name).with_context(|| {
        let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
        format!(
            "no camera '{name}' in the rig (cameras: {}; or an index 0..{})",
            names.join(", "),
            names.len() - 1
        )
    })
}

/// Says on stderr which device computes, so a user knows which path produced the numbers.
fn announce(common: &CommonArgs) {
    match common.device {
        Device::Cpu => eprintln!("device: cpu (f64 reference)"),
    }
}

pub fn project(args: PointsArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref())?);
    let points = read_table(&args.points, ["x", "y", "z"])?;
    announce(&args.common);
    let batch = Batch::map(&points, |&[x, y, z]| {
        camera.project(&Point3::new(x, y, z)).map(|p| [p.x, p.y])
    });
    batch.write(args.common.output.as_deref(), ["u", "v"])
}

pub fn backproject(args: BackprojectArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref())?);
    let pixels = read_table(&args.pixels, ["u", "v"])?;
    announce(&args.common);
    let batch = Batch::map(&pixels, |&[u, v]| {
        camera.backproject(&Point2::new(u, v)).map(|ray| {
            let (o, d) = (ray.origin, ray.dir);
            [o.x, o.y, o.z, d.x, d.y, d.z]
        })
    });
    batch.write(args.common.output.as_deref(), ["ox", "oy", "oz", "dx", "dy", "dz"])
}

pub fn triangulate(args: TriangulateArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let (a, b) = match &args.cameras {
        Some((a, b)) => (camera_index(&rig, Some(a))?, camera_index(&rig, Some(b))?),
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
        bail!("--cameras names the same camera twice ('{}')", rig.cameras()[a].name);
    }
    let (first, second) = (rig.refractive_camera(a), rig.refractive_camera(b));
    let matches = read_table(&args.matches, ["ul", "vl", "ur", "vr"])?;
    announce(&args.common);
    let batch = Batch::map(&matches, |&[ul, vl, ur, vr]| {
        let ray_a = first.backproject(&Point2::new(ul, vl))?;
        let ray_b = second.backproject(&Point2::new(ur, vr))?;
        let t = triangulate_rays(&ray_a, &ray_b)?;
        Ok([t.point.x, t.point.y, t.point.z, t.residual])
    });
    batch.write(args.common.output.as_deref(), ["x", "y", "z", "residual"])
}

pub fn vop(args: PointsArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.common.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref())?);
    let points = read_table(&args.points, ["x", "y", "z"])?;
    announce(&args.common);
    let batch = Batch::map(&points, |&[x, y, z]| {
        camera.vop(&Point3::new(x, y, z)).map(|v| {
            [v.depth, v.vop_distance, v.vop.x, v.vop.y, v.vop.z, v.incidence]
        })
    });
    batch.write(
        args.common.output.as_deref(),
        ["depth", "vop_distance", "vop_x", "vop_y", "vop_z", "incidence"],
    )
}
