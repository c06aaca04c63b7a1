//! `flatport export colmap|opencv|aquacal|raymap`: a rig in the files other tools read, and per-pixel ray
//! maps. The formats are in `flatport::io::export`, the rays in `flatport::engine::raymap`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};

use flatport::engine::raymap::{backproject_rows, rows_per_band};
use flatport::io::npy::{NpyDtype, NpyWriter};
use flatport::io::{
    AquaCalBoard, ColmapDialect, aquacal_json, colmap_cameras_txt_as, colmap_rig_config,
    colmap_rigs_txt, opencv_yaml, read_board, read_rig, write_atomic,
};
use flatport::model::NoSolution;

use super::geometry::camera_index;
use super::{Device, EngineArgs, PrecisionArg};

/// `flatport export …`
#[derive(Debug, Subcommand)]
pub enum ExportCommand {
    /// colmap_underwater's cameras.txt (lens + FLATPORT port per camera) and a rig configuration
    #[command(after_help = "\
Writes DIR/cameras.txt: one line per camera, CAMERA_ID k+1 for camera k,
  CAMERA_ID OPENCV|FULL_OPENCV WIDTH HEIGHT fx fy cx cy k1 k2 p1 p2 [k3 0 0 0] \\
      FLATPORT Nx Ny Nz int_dist int_thick n_air n_glass n_water
with the port in that camera's own frame (N = R_k n, int_dist = d_k = d - n.C_k) and COLMAP's pixel
convention (the centre of the top-left pixel is (0.5, 0.5), so cx, cy are flatport's + 0.5);
DIR/rig_config.json, COLMAP's rig configuration (rig_bundle_adjuster --rig_config_path) with every
camera's pose relative to the master (ref_camera_id 1) and the image prefix NAME/; and DIR/rigs.txt,
the same rig as COLMAP 3.12 reads rigs (sensor_from_rig of CAMERA k+1). --refrac-token writes
`... REFRAC FLATPORT ...`, the line of colmap_underwater's COLMAP 3.12 based port.
FLATPORT holds one glass layer: a port of two or more layers is refused; a port without layers is
written as a glass of thickness 0.

Example:
  flatport export colmap --rig calibrated.json --output colmap/")]
    Colmap(ColmapArgs),
    /// The in-air calibration as OpenCV FileStorage YAML (M1 D1 M2 D2 R T), as stereoCalibrate saves it
    #[command(after_help = "\
The file cv::FileStorage reads and `flatport rig from-opencv` imports: M1 D1 (and M2 D2 R T for a
pair, X_b = R X_a + T) as !!opencv-matrix, image_width and image_height. The interface is not part
of it.

Examples:
  flatport export opencv --rig rig.json --output stereo.yml
  flatport export opencv --rig rig.json --cameras right,left --output reversed.yml
  flatport export opencv --rig rig.json --camera left --output left.yml")]
    Opencv(OpencvArgs),
    /// The rig as AquaCal's calibration.json (one bare water surface; what AquaMVS reads)
    #[command(after_help = "\
Writes the file AquaCal's load_calibration reads (version \"1.0\"): every camera, master first,
with K, dist_coeffs, image_size, R and t (world -> camera) and water_z; interface.normal
[0, 0, -1], n_air and n_water. AquaCal's world frame has Z down into the water: it is the master's
frame turned so that Z is the rig's normal (the master's own frame for an untilted rig), with the
origin at the master's centre, so water_z is the rig's distance. --board fills AquaCal's board
object from a ChArUco board file; without it the board's values are null. A rig AquaCal cannot
hold is refused, saying why: glass layers (AquaCal models a bare surface), or ports per camera
that are not parallel surfaces in the same media.

Examples:
  flatport export aquacal --rig rig.json --output calibration.json
  flatport export aquacal --rig rig.json --board board.json -o calibration.json")]
    Aquacal(AquacalArgs),
    /// The water ray of every pixel of a camera as .npy (H x W x 6: origin on the outer interface, unit direction)
    #[command(after_help = "\
rays[v, u] is the ray of pixel (u, v) (flatport's convention: (0, 0) is the centre of the top-left
pixel), ox oy oz dx dy dz in the master frame, exactly what `flatport backproject` gives for that
pixel; a pixel without a ray is NaN (counted on stderr). --precision sets the file's dtype (f32 or
f64) and the GPU kernels' precision; the CPU computes f64. On the GPU the pixel grid is generated
in the shader. The image is done in bands, so memory stays bounded.

Examples:
  flatport export raymap --rig rig.json --camera left --output rays.npy
  flatport export raymap --rig rig.json --camera 1 --precision f32 --device gpu --output rays32.npy")]
    Raymap(RaymapArgs),
}

/// `flatport export colmap`
#[derive(Debug, Args)]
pub struct ColmapArgs {
    /// Rig file (JSON)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Output folder (created if missing): cameras.txt, rig_config.json, rigs.txt
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
    /// Put the token REFRAC before FLATPORT (the COLMAP 3.12 based port of colmap_underwater)
    #[arg(long)]
    refrac_token: bool,
}

/// `flatport export opencv`
#[derive(Debug, Args)]
pub struct OpencvArgs {
    /// Rig file (JSON)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// The pair to write, first = camera 1 (default: the rig's first two cameras)
    #[arg(long, value_name = "A,B", value_parser = super::parse_pair, conflicts_with = "camera")]
    cameras: Option<(String, String)>,
    /// Write this camera alone (M1 D1), by name or index
    #[arg(long, value_name = "NAME|INDEX")]
    camera: Option<String>,
    /// Output YAML file (default: standard output)
    #[arg(long, short, value_name = "FILE.yml")]
    output: Option<PathBuf>,
}

/// `flatport export aquacal`
#[derive(Debug, Args)]
pub struct AquacalArgs {
    /// Rig file (JSON)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// ChArUco BOARD.json (docs/images.md: squares_x, squares_y, square_size, marker_size, dictionary) for AquaCal's board object
    #[arg(long, value_name = "BOARD.json")]
    board: Option<PathBuf>,
    /// Output calibration.json (default: standard output)
    #[arg(long, short, value_name = "calibration.json")]
    output: Option<PathBuf>,
}

/// `flatport export raymap`
#[derive(Debug, Args)]
pub struct RaymapArgs {
    /// Rig file (JSON)
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Camera by name or index (default: the master)
    #[arg(long, value_name = "NAME|INDEX")]
    camera: Option<String>,
    /// Output .npy file, shape (height, width, 6)
    #[arg(long, short, value_name = "FILE.npy")]
    output: PathBuf,
    /// dtype of the file, and precision of the GPU kernels
    #[arg(long, value_enum, value_name = "f32|f64", default_value = "f64")]
    precision: PrecisionArg,
    /// Compute device
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    device: Device,
    /// GPU adapter: its index or part of its name as `flatport info` lists them
    #[arg(long, value_name = "INDEX|NAME")]
    adapter: Option<String>,
}

pub fn run(command: ExportCommand) -> anyhow::Result<()> {
    match command {
        ExportCommand::Colmap(args) => colmap(args),
        ExportCommand::Opencv(args) => opencv(args),
        ExportCommand::Aquacal(args) => aquacal(args),
        ExportCommand::Raymap(args) => raymap(args),
    }
}

fn colmap(args: ColmapArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let dialect = if args.refrac_token {
        ColmapDialect::RefracToken
    } else {
        ColmapDialect::Legacy
    };
    let cameras = colmap_cameras_txt_as(&rig, dialect).with_context(|| {
        format!(
            "{}: cannot be written for colmap_underwater",
            args.rig.display()
        )
    })?;
    if args.output.exists() && !args.output.is_dir() {
        bail!(
            "{}: --output of export colmap is a folder, and this is not one",
            args.output.display()
        );
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("{}: cannot create the folder", args.output.display()))?;
    for (name, text) in [
        ("cameras.txt", cameras),
        ("rig_config.json", colmap_rig_config(&rig)),
        ("rigs.txt", colmap_rigs_txt(&rig)),
    ] {
        let path = args.output.join(name);
        write_atomic(&path, text.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn opencv(args: OpencvArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let (a, b) = match (&args.camera, &args.cameras) {
        (Some(one), _) => (camera_index(&rig, Some(one), "--camera")?, None),
        (None, Some((a, b))) => (
            camera_index(&rig, Some(a), "--cameras")?,
            Some(camera_index(&rig, Some(b), "--cameras")?),
        ),
        (None, None) => (0, (rig.cameras().len() > 1).then_some(1)),
    };
    if Some(a) == b {
        bail!("--cameras names camera {a} twice");
    }
    let yaml = opencv_yaml(&rig, a, b)
        .with_context(|| format!("{}: cannot be written as OpenCV YAML", args.rig.display()))?;
    match &args.output {
        Some(path) => {
            write_atomic(path, yaml.as_bytes())?;
            eprintln!("wrote {}", path.display());
        }
        None => out!("{yaml}"),
    }
    Ok(())
}

fn aquacal(args: AquacalArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let board = args
        .board
        .as_deref()
        .map(|path| read_board(path).and_then(|board| AquaCalBoard::from_board(&board, path)))
        .transpose()?;
    let json = aquacal_json(&rig, board.as_ref())
        .with_context(|| format!("{}: cannot be written for AquaCal", args.rig.display()))?;
    match &args.output {
        Some(path) => {
            write_atomic(path, json.as_bytes())?;
            eprintln!("wrote {}", path.display());
        }
        None => out!("{json}"),
    }
    Ok(())
}

/// Pixels per band: 1 Mi pixels is 48 MiB of f64 rays.
const BAND_PIXELS: usize = 1 << 20;

fn raymap(args: RaymapArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let camera = rig.refractive_camera(camera_index(&rig, args.camera.as_deref(), "--camera")?);
    let engine_args = EngineArgs {
        device: args.device,
        // The CPU computes f64 whatever the file's dtype.
        precision: (args.device != Device::Cpu).then_some(args.precision),
        adapter: args.adapter.clone(),
    };
    let engine = engine_args.engine()?;
    let (width, height) = (camera.intrinsics().width, camera.intrinsics().height);
    let dtype = match args.precision {
        PrecisionArg::F32 => NpyDtype::F32,
        PrecisionArg::F64 => NpyDtype::F64,
    };
    let mut writer =
        NpyWriter::create_of(&args.output, &[height as usize, width as usize, 6], dtype)?;
    let band = rows_per_band(width, BAND_PIXELS);
    let (mut rays, mut status) = (Vec::new(), Vec::new());
    let mut rejections: BTreeMap<u32, (NoSolution, usize)> = BTreeMap::new();
    for first in (0..height).step_by(band as usize) {
        let rows = band.min(height - first);
        let pixels = (rows * width) as usize;
        rays.resize(pixels, [0.0; 6]);
        status.resize(pixels, 0);
        backproject_rows(&engine, &camera, first, rows, &mut rays, &mut status)?;
        for (ray, &code) in rays.iter_mut().zip(&status) {
            if code != 0 {
                *ray = [f64::NAN; 6];
                let reason = NoSolution::from_code(code).expect("engines return NoSolution codes");
                rejections.entry(code).or_insert((reason, 0)).1 += 1;
            }
        }
        writer.write(rays.as_flattened())?;
    }
    writer.finish()?;
    super::batch::report_rejections((width * height) as usize, &rejections);
    eprintln!(
        "wrote {} ({height} x {width} x 6, {})",
        args.output.display(),
        dtype_name(dtype)
    );
    Ok(())
}

fn dtype_name(dtype: NpyDtype) -> &'static str {
    match dtype {
        NpyDtype::F32 => "float32",
        NpyDtype::F64 => "float64",
    }
}
