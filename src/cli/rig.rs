//! `flatport rig from-opencv`, `flatport rig from-aquacal`, `flatport rig show`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use nalgebra::Vector3;

use flatport::io::{
    MAX_BASELINE_M, read_aquacal, read_opencv_stereo, read_rig, rig_to_json_string, write_atomic,
};
use flatport::model::{Interface, Layer, Ports, Rig, interface};

/// `flatport rig …`
#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Build a rig from OpenCV stereoCalibrate output (FileStorage YAML) and an interface
    #[command(after_help = "\
The YAML must hold M1 D1 M2 D2 R T (or K1 … K2 …) as written by cv::FileStorage, with %YAML:1.0.
The first camera becomes the master; R, T map master coordinates into the second camera. T is in
the unit the board's square was given to OpenCV in: flatport works in metres, and a T longer than
2 m is refused as probably millimetres; --unit mm converts it (--distance and --layer stay metres).

Examples:
  flatport rig from-opencv stereo.yml --distance 0.02 --layer 0.014:1.473 --output rig.json
  flatport rig from-opencv stereo_mm.yml --unit mm --distance 0.02 --layer 0.014:1.473 -o rig.json
  flatport rig from-opencv stereo.yml --normal 0.1,0.1,1 --distance 0.02 --layer 0.014:1.473 \\
      --index-air 1.003 --index-water 1.333 --names left,right --size 1280x1024")]
    FromOpencv(FromOpencvArgs),
    /// Build a rig from AquaCal's calibration.json (cameras in the air above one water surface)
    #[command(after_help = "\
AquaCal (PyPI aquacal, the file its calibration writes and AquaMVS reads): per camera K,
dist_coeffs, image_size, R and t (world -> camera, world Z down into the water, origin at the
reference camera) and water_z (the surface's world Z); interface.normal (water -> air), n_air,
n_water. The master is the first camera in the file unless --master names one; the others keep
the file's order. The surface becomes the rig's shared interface (normal into the water, distance
from the master's centre, no layers, index_air = n_air, index_water = n_water); a file whose
cameras see different surfaces (AquaCal's per-camera water_z) gets a port per camera. Fisheye
cameras, skewed K and non-zero distortion terms beyond k3 are refused.

Examples:
  flatport rig from-aquacal calibration.json --output rig.json
  flatport rig from-aquacal calibration.json --master cam2 -o rig.json")]
    FromAquacal {
        /// AquaCal's calibration.json
        #[arg(value_name = "CALIBRATION.json")]
        calibration: PathBuf,
        /// The camera that becomes the rig's master (default: the first in the file)
        #[arg(long, value_name = "NAME")]
        master: Option<String>,
        /// Output rig file (default: standard output)
        #[arg(long, short, value_name = "RIG.json")]
        output: Option<PathBuf>,
    },
    /// Print a rig: cameras, centres, air layers, axis tilt and azimuth
    #[command(after_help = "Example:\n  flatport rig show rig.json")]
    Show {
        /// Rig file (JSON)
        rig: PathBuf,
    },
}

/// `flatport rig from-opencv`
#[derive(Debug, Args)]
pub struct FromOpencvArgs {
    /// OpenCV FileStorage YAML from stereoCalibrate
    yaml: PathBuf,
    /// System axis in the master frame (normalised on load), pointing into the water
    #[arg(long, value_name = "X,Y,Z", default_value = "0,0,1", value_parser = parse_vector, allow_hyphen_values = true)]
    normal: Vector3<f64>,
    /// Air layer: distance from the master camera centre to the first interface along the normal (m)
    #[arg(long, value_name = "METRES", value_parser = super::values::positive, allow_negative_numbers = true)]
    distance: f64,
    /// A layer between air and water as THICKNESS:INDEX, in order from the camera (repeatable)
    #[arg(long = "layer", value_name = "THICKNESS:INDEX", value_parser = parse_layer, allow_hyphen_values = true)]
    layers: Vec<Layer>,
    /// Refractive index of the medium around the cameras
    #[arg(long, default_value_t = interface::DEFAULT_INDEX_AIR, value_parser = super::values::index, allow_negative_numbers = true)]
    index_air: f64,
    /// Refractive index of the last medium
    #[arg(long, default_value_t = interface::DEFAULT_INDEX_WATER, value_parser = super::values::index, allow_negative_numbers = true)]
    index_water: f64,
    /// Camera names, master first
    #[arg(long, value_name = "A,B", default_value = "left,right", value_parser = super::parse_pair, allow_hyphen_values = true)]
    names: (String, String),
    /// Image size WIDTHxHEIGHT when the YAML has no image_width/image_height
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Unit of the lengths in the YAML (T): metres, or millimetres converted to metres
    #[arg(long, value_enum, default_value_t = LengthUnit::M)]
    unit: LengthUnit,
    /// Output rig file (default: standard output)
    #[arg(long, short, value_name = "RIG.json")]
    output: Option<PathBuf>,
}

/// Unit of the lengths in an OpenCV YAML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LengthUnit {
    /// Metres (as flatport)
    M,
    /// Millimetres
    Mm,
}

fn parse_layer(text: &str) -> Result<Layer, String> {
    let (t, n) = text
        .split_once(':')
        .ok_or_else(|| format!("expected THICKNESS:INDEX, got '{text}'"))?;
    let thickness = super::values::positive(t).map_err(|e| format!("thickness {e}"))?;
    let index = super::values::index(n).map_err(|e| format!("index: {e}"))?;
    Ok(Layer { thickness, index })
}

fn parse_vector(text: &str) -> Result<Vector3<f64>, String> {
    let values: Vec<&str> = text.split(',').collect();
    if values.len() != 3 {
        return Err(format!("expected X,Y,Z, got '{text}'"));
    }
    let parse = |s: &str| {
        s.trim()
            .parse::<f64>()
            .map_err(|_| format!("'{s}' is not a number"))
    };
    Ok(Vector3::new(
        parse(values[0])?,
        parse(values[1])?,
        parse(values[2])?,
    ))
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got '{text}'"))?;
    let parse = |s: &str| {
        s.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{s}' is not a pixel count"))
    };
    Ok((parse(w)?, parse(h)?))
}

pub fn run(command: RigCommand) -> anyhow::Result<()> {
    match command {
        RigCommand::FromOpencv(args) => from_opencv(args),
        RigCommand::FromAquacal {
            calibration,
            master,
            output,
        } => {
            let rig = read_aquacal(&calibration, master.as_deref())?;
            write_rig_json(&rig, output.as_ref())
        }
        RigCommand::Show { rig } => {
            out!("{}", describe(&read_rig(&rig)?));
            Ok(())
        }
    }
}

fn from_opencv(args: FromOpencvArgs) -> anyhow::Result<()> {
    let mut stereo = read_opencv_stereo(&args.yaml)?;
    match args.unit {
        LengthUnit::Mm => stereo = stereo.scaled_from_millimetres(),
        LengthUnit::M => {
            let t = stereo.translation;
            if t.norm() > MAX_BASELINE_M {
                bail!(
                    "{}: T = [{}, {}, {}] puts the cameras {} apart; read as metres that is over {MAX_BASELINE_M} m, so it is probably millimetres (OpenCV keeps the unit of the board's square size): give --unit mm to convert it to metres",
                    args.yaml.display(),
                    t.x,
                    t.y,
                    t.z,
                    t.norm()
                );
            }
        }
    }
    let interface = Interface::new(
        args.normal,
        args.distance,
        args.layers,
        args.index_air,
        args.index_water,
    )
    .context("invalid interface flags")?;
    let (first, second) = &args.names;
    if first == second {
        bail!("--names gives the same name twice ('{first}')");
    }
    let rig = stereo.to_rig([first, second], args.size, interface, &args.yaml)?;
    write_rig_json(&rig, args.output.as_ref())
}

/// Writes a rig file to `output`, or to standard output.
fn write_rig_json(rig: &Rig, output: Option<&PathBuf>) -> anyhow::Result<()> {
    let json = rig_to_json_string(rig);
    match output {
        Some(path) => {
            write_atomic(path, json.as_bytes())?;
            eprintln!("wrote {}", path.display());
        }
        None => outln!("{json}"),
    }
    Ok(())
}

/// Human summary of one port: its axis (in the frame it is given in), air layer and media.
fn describe_port(title: &str, interface: &Interface) -> String {
    let n = interface.normal();
    let mut text = format!(
        "{title}: normal [{:.6}, {:.6}, {:.6}] (tilt {:.4}°, azimuth {:.4}°), air layer {} m\n",
        n.x,
        n.y,
        n.z,
        interface.tilt().to_degrees(),
        interface.azimuth().to_degrees(),
        interface.air_distance()
    );
    text += &format!("  index_air {}\n", interface.index_air());
    for (i, layer) in interface.layers().iter().enumerate() {
        text += &format!(
            "  layer {i}: {} m, index {}\n",
            layer.thickness, layer.index
        );
    }
    text += &format!("  index_water {}\n", interface.index_water());
    text
}

/// Human summary of a rig.
pub fn describe(rig: &Rig) -> String {
    let mut text = match rig.ports() {
        Ports::Shared(interface) => describe_port("interface", interface),
        Ports::PerCamera(ports) => rig
            .cameras()
            .iter()
            .zip(ports)
            .map(|(camera, port)| {
                describe_port(&format!("port of '{}' (its own frame)", camera.name), port)
            })
            .collect(),
    };
    for (k, camera) in rig.cameras().iter().enumerate() {
        let view = rig.refractive_camera(k);
        let c = view.centre();
        let i = &camera.intrinsics;
        text += &format!(
            "camera {k} '{}'{}: {}x{} px, fx {} fy {} cx {} cy {}, centre [{:.6}, {:.6}, {:.6}] m, own air layer {:.6} m\n",
            camera.name,
            if k == 0 { " (master)" } else { "" },
            i.width,
            i.height,
            i.fx,
            i.fy,
            i.cx,
            i.cy,
            c.x,
            c.y,
            c.z,
            view.air_distance()
        );
    }
    text
}
