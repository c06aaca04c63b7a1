//! Subcommands of the `flatport` binary (clap). No math here: every command reads its inputs,
//! calls the library row by row, and writes the CSV contract of docs/DESIGN.md §1.

/// `println!` that ends the process quietly when standard output is a closed pipe
/// ([`signals::print_stdout`]); `println!` would panic there.
macro_rules! outln {
    () => { $crate::cli::signals::print_stdout(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::cli::signals::print_stdout(format_args!("{}\n", format_args!($($arg)*))) };
}
/// `print!` with the same care as [`outln!`].
macro_rules! out {
    ($($arg:tt)*) => { $crate::cli::signals::print_stdout(format_args!($($arg)*)) };
}

mod batch;
mod bench;
mod calib;
mod calib_images;
mod calib_targetless;
mod demo;
mod detect;
mod export;
mod geometry;
mod info;
mod progress;
mod render;
mod render_scene;
mod rig;
mod signals;
mod simulate;
mod stereo;
mod sweep;
mod values;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};

/// Refraction through flat ports: exact projection, back-projection, VOPs and triangulation for
/// cameras in air behind glass in water.
#[derive(Debug, Parser)]
#[command(name = "flatport", version, about, long_about = None, after_help = "\
Conventions: metres, OpenCV camera frames (x right, y down, z forward), the first camera of the rig
defines the world (master) frame. CSV files have a header row; rows without an answer are written
as NaN and counted on stderr. Inputs of any size are streamed in chunks.

Devices: --device cpu runs the f64 reference on all cores, --device gpu the WGSL kernels on a
Vulkan adapter, --device auto (default) a hardware GPU if there is one. The device used is printed
on stderr. GPU precision (--precision f32|f64): project, backproject, triangulate and vop run f32
unless told; calibrate and demo run f64 where the adapter has SHADER_F64 (their finite differences
are below f32's resolution); sweep's affine-grid cost always runs f64 (the adapter must have
SHADER_F64), its reprojection and scene costs in --precision (f32 unless told).

Start with:  flatport demo")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Project 3-D points (master frame) through the interface to pixels: x,y,z → u,v
    #[command(after_help = "\
Examples:
  flatport project --rig rig.json --points points.csv > pixels.csv
  flatport project --rig rig.json --points points.csv --camera right --output right.csv
  flatport project --rig rig.json --points points.csv --device gpu --precision f64 -o pixels.csv")]
    Project(geometry::PointsArgs),
    /// Back-project pixels to rays in the water: u,v → ox,oy,oz,dx,dy,dz
    #[command(after_help = "\
The ray origin lies on the outer interface, the direction is a unit vector in the water, both in
the master frame.

Examples:
  flatport backproject --rig rig.json --pixels pixels.csv > rays.csv
  flatport backproject --rig rig.json --pixels pixels.csv --camera 1 --output rays.csv
  flatport backproject --rig rig.json --pixels pixels.csv --device gpu -o rays.csv")]
    Backproject(geometry::BackprojectArgs),
    /// Triangulate stereo matches refractively: ul,vl,ur,vr → x,y,z,residual
    #[command(after_help = "\
Both pixels are back-projected into the water; the point is the midpoint of the rays' closest
approach and the residual is their distance (metres). Nearly parallel rays give a NaN row.

Examples:
  flatport triangulate --rig rig.json --matches matches.csv > points.csv
  flatport triangulate --rig rig.json --matches matches.csv --cameras left,right")]
    Triangulate(geometry::TriangulateArgs),
    /// Virtual Object Points of 3-D points: x,y,z → depth,vop_distance,vop_x,vop_y,vop_z,incidence
    #[command(after_help = "\
depth is the point's distance x from the outer interface along the axis (thesis eq 4.7),
vop_distance the signed distance x̌ from the outer interface to the VOP along the axis (negative
inside the glass, eq 4.8), vop_x..z the VOP in the master frame, incidence the angle in air (rad).

Example:
  flatport vop --rig rig.json --points points.csv --camera left")]
    Vop(geometry::PointsArgs),
    /// Simulate views of a chessboard or a 3-D target by any rig (with known truth)
    #[command(after_help = "\
Random target poses in the water in front of the master camera, corners projected exactly through
each camera's port (the truth: shared, or each camera's own), Gaussian pixel noise. Writes
DIR/observations.json (the calibration input), DIR/truth.json (the master's port, its tilt and
azimuth, the target poses, the whole true rig), DIR/rig.json (the rig with the true ports) and
DIR/start_rig.json (the same rig with a naive start: each port's axis on its camera's z axis,
10 mm of air, as the demo uses).

A stereo rig behind one shared port looking at a board (or a pair named by --cameras) gets the
stereo observations ({\"left\", \"right\"} per view). Any other rig (one camera, three or more, a port
per camera) or a 3-D target (--target) gets the general form (DESIGN.md §3b): each view holds the
images of the cameras that saw the whole target, keyed by camera name; a camera that did not is
left out of the view. Every view is seen by the master camera and by --min-cameras in all.

Examples:
  flatport simulate --rig rig.json --board 9x6@0.04 --views 20 --noise 0.1 --seed 1 --output scene
  flatport calibrate --rig scene/start_rig.json --observations scene/observations.json \\
      -o calibrated.json --truth scene/truth.json
  flatport simulate --rig data/rigs/array_2x2.json --views 30 --min-cameras 2 --output array
  flatport simulate --rig data/rigs/housings.json --target data/rigs/target_v.json --output v
  flatport simulate --rig data/rigs/tank.json --board 7x5@0.03 --output tank")]
    Simulate(simulate::SimulateArgs),
    /// Find chessboard corners in every camera's images and write the observations file
    #[command(after_help = "\
Each --images CAMERA=GLOB gives one camera's images (PNG, JPEG or TIFF; 8 or 16 bit; grey or
colour); quote the glob so that the shell leaves it alone. Every camera's files are sorted by name
and the n-th files of all cameras form view n. The corners are written row-major as OpenCV's
findChessboardCorners orders them, with corner 0 the same physical corner in every camera of a
view: the inner corner at the board's black corner square when the board's colours tell its ends
apart (squares per side add up to an odd number, e.g. 9x6 = 10 x 7 squares); otherwise, with
--rig, the cameras follow the first one by their rays, and without it each image takes the order
whose rows run left to right. Views that cannot be resolved, and views no camera found, are left
out and listed on stderr. A camera that found no board is absent from that view; for two cameras
the file has the stereo form the calibration reads today, which holds only views both cameras saw,
so a view one camera saw is left out and listed too.

A ChArUco board is given as a file, --board BOARD.json ({\"type\": \"charuco\", \"squares_x\": 7,
\"squares_y\": 5, \"square_size\": 0.04, \"marker_size\": 0.03, \"dictionary\": \"DICT_4X4_50\"}:
squares, metres, OpenCV's dictionary names). Its corners carry OpenCV's ids (row-major over the
inner corners, row 0 at the board's top edge), so partial views are kept, a corner not seen
written as null; an image needs 4 corners spanning two rows and two columns.

Examples:
  flatport detect --board 9x6@0.04 --images left='shots/left/*.png' --images right='shots/right/*.png' \\
      --rig rig.json --output observations.json --overlay overlays
  flatport detect --board data/boards/charuco_7x5.json --images left='shots/left/*.png' \\
      --images right='shots/right/*.png' --output observations.json
  flatport calibrate --rig rig.json --observations observations.json -o calibrated.json")]
    Detect(detect::DetectArgs),
    /// Render images of a chessboard or a ChArUco board seen through the port by every camera (with exact corners)
    #[command(after_help = "\
Every pixel is back-projected through the port (on the GPU the pixel grid is made in the shader),
its water ray meets the board, and the board's shade there is the pixel's value; pixels on an
edge of the pattern are supersampled (anti-aliasing). Lens distortion comes from the rig, noise
and blur are optional. The poses come from a truth file (`flatport simulate`) or are drawn as
simulate draws them. Writes DIR/CAMERA/view_NNN.png, DIR/rig.json (the rig with the true port),
DIR/truth.json and DIR/corners.json (the exact corners, the observations file's format: every
board corner projected through the port by the model; for a ChArUco board, --board BOARD.json,
every corner inside the image and null for the others). A rig whose port has index_water equal to
index_air and no layers renders in-air images.

--imaging SEVERITY adds what real cameras add (src/render/imaging.rs): defocus (a disc blur that
varies from image to image and grows to the corners), motion blur, vignetting, a light gradient,
lost contrast, backscatter (specks and a veil), shot and read noise, JPEG; 0 is none, 1 as real
underwater cameras give it, 2 harsher. --defocus, --motion-blur, --vignetting, --gradient,
--contrast, --backscatter, --veil, --shot-noise, --read-noise, --jpeg replace the preset's values;
--h264 CRF encodes each camera's sequence with libx264 (the ffmpeg tool) and writes the decoded
frames back as PNG. Everything is seeded by --seed and the image; the corners and truth files
stay the exact geometry.

With --scene SCENE.json it renders a textured scene instead (planes, height fields, spheres with
procedural noise or image textures; see data/scenes/ and docs/stereo.md): every sub-sample of every
pixel is back-projected exactly and meets the nearest surface; writes DIR/CAMERA/frame_NNN.png,
DIR/CAMERA/depth_NNN.npy (float32 [H,W]: z of the hit point in that camera's frame, NaN where
nothing is hit) and DIR/rig.json. Unknown keys in the scene file are errors naming their path.

Examples:
  flatport render --scene data/scenes/seabed.json --noise 2 --output seabed
  flatport render --rig data/example_rig.json --board 9x6@0.04 --views 15 --seed 1 --noise 2 --output shots
  flatport render --rig rig.json --truth scene/truth.json --board 9x6@0.04 --blur 0.8 --output shots
  flatport render --rig data/example_rig.json --board data/boards/charuco_7x5.json --views 15 --output shots
  flatport render --rig data/example_rig.json --calibration-set --imaging 1 --output set
  flatport render --rig data/example_rig.json --calibration-set --imaging 2 --jpeg 0 --h264 28 --output harsh
  flatport detect --board 9x6@0.04 --images left='shots/left/*.png' --images right='shots/right/*.png' -o obs.json")]
    Render(render::RenderArgs),
    /// Dense refraction-exact multi-view stereo: depth maps, points and point clouds from a rig's images
    #[command(after_help = "\
DIR holds one folder per rig camera, named as in the rig (the layout `flatport render` writes),
with its images (PNG, JPEG or TIFF, 8 or 16 bit, grey or colour; frames paired by sorted file
name) or one video (MP4, MOV, AVI, MKV, decoded by the ffmpeg tool; frames paired by index).
Every input is checked before anything is written.

Each reference pixel's water ray (exact back-projection through its port) carries N hypotheses
uniform in 1/z between MIN and MAX (z in the reference camera's frame). Without --depth the range
is found per frame by a coarse sweep (images at most 160 px wide, from where the cameras' views
overlap out to 20 m): its confident depths' 0.5-99.5 % quantiles, padded. Without --hypotheses N
is the step rule's: the fewest for which one step moves a hypothesis by at most 0.8 px in every
voting camera over the whole range and image (16 to 512). Both are printed. Each
hypothesis point is projected exactly into every other camera through that camera's own port
(not rectified: refraction bends the epipolar lines into curves), the other images are sampled
there and compared with the reference by windowed ZNCC, which a change of gain and offset between
viewpoints (attenuation, backscatter) does not affect. The cameras that see a hypothesis vote;
semi-global matching (8 paths) aggregates, the best hypothesis is refined by a parabola in 1/z,
and every other camera's own depth map must agree within max(1, 0.002·f) reference pixels
(left-right consistency; f the reference's focal length: 1 px up to f = 500, 2 px at f = 1000, the
same angle at any resolution). Untextured, occluded, inconsistent or unconfident pixels are NaN,
never guesses. Measured on a rendered 1280 x 1024 housings scene (f = 1000 px, no options): a
1 px tolerance left a point for 85.1 % of the pixels another camera sees, 2 px 91.6 % (median
error 0.029 % -> 0.031 % of the distance, all within 2 %, no gross point where no other camera
sees); 13 x 13 windows with 1 px gave 91.5 % but 9.4 % gross where unseen, so windows stay
7 x 7 (cargo test --release --test stereo_auto -- --ignored --nocapture rejections_at_full_size,
docs/stereo.md).

Per frame, OUT/FRAME/ (FRAME = the reference image's file name without extension, or
frame_NNNNNN, the index, for a video):
  points.npy      float32 [H,W,3]: each reference pixel's surface point, rig master frame, NaN where none
  depth.npy       float32 [H,W]: z in the reference camera's frame, metres, NaN where none
  confidence.npy  float32 [H,W]: 0 to 1 (0 where none)
  cloud.ply       binary little-endian PLY: float x y z, uchar red green blue (the points only)
  depth.png       the depth, colour-mapped, with a colour bar
  fused.ply       with --fuse: every camera's depth map fused (float x y z nx ny nz, uchar red
                  green blue): points confirmed by another camera, merged, with normals
  frame.json      the frame's summary entry, settings and file sizes (written last: --resume
                  skips a frame whose files are all there and whole)
and OUT/summary.json (hypotheses, depth_range_m and how they were chosen; per frame: valid
fraction, seconds per stage, device, hypotheses, depth range), or a shard's
OUT/summary-shard-I-of-N.json; after the shards, the same command with --resume and no --shard
computes nothing again and writes summary.json. --report-dir DIR also writes DIR/index.html, a
page to read offline: each frame's chosen range and sampling, completeness, depth and confidence.

Examples:
  flatport render --scene data/scenes/seabed.json --noise 2 -o seabed
  flatport stereo --rig seabed/rig.json --images seabed --output seabed-stereo
  flatport stereo --rig seabed/rig.json --images seabed --output seabed-stereo --report-dir report
  flatport stereo --rig seabed/rig.json --images seabed --output seabed-stereo --depth 0.8:2.5
  flatport stereo --rig rig.json --images shots --output out --reference right --hypotheses 96
  flatport stereo --rig rig.json --images videos --output out --frames 0:3000:10 --resume
  flatport stereo --rig rig.json --images videos --output out --shard 3/8 --resume --fuse
Timing a full-size pair (1280 x 1024, 128 hypotheses):
  flatport render --scene data/scenes/seabed.json --noise 2 -o big
  time flatport stereo --rig big/rig.json --images big --output big-out --depth 0.8:2.5 --hypotheses 128")]
    Stereo(stereo::StereoArgs),
    /// Calibrate a rig: its ports (axis, air layer; layers and extrinsics when asked) from views of a target, or everything (lenses, extrinsics, ports) from images or videos of a board, or its ports from footage of any textured scene (--targetless)
    #[command(after_help = "\
From images alone (--images DIR --board BOARD.json --port surface|shared|housings): DIR holds
air/<camera>/ (each camera's own views of the board in air) and water/<camera>/ (synchronized
frames under water: the n-th frame of every camera is the same instant), each folder images
(PNG/JPEG/TIFF, sorted by name) or exactly one video (MP4/MOV/AVI/MKV, decoded by the ffmpeg
tool). The camera names are the folder names; the master is the first by name (--master). Each
camera's lens is calibrated in air (OpenCV's model, the distortion terms the held-out views ask
for), the extrinsics are started from the frames two cameras share (chains of frames are fine),
then the extrinsics, the ports and every board pose by maximum likelihood under a Huber loss;
frames far above the others are dropped, a fifth of the frames held out; the lenses refined under
water where the held-out frames say it helps (--refine-intrinsics). --rig takes the cameras'
in-air calibration from a rig file instead of air/; with neither air/ nor --rig, every lens comes
from the underwater frames with the ports. The result carries a verdict from the held-out frames
(good, usable or poor, and why); a poor one (RMS over 2 px, held-out frames or squares far off
the fit's) writes no rig and exits 1.
  flatport calibrate --images footage --board board.json --port housings --glass 0.008:1.49 \\
      --output rig.json --report report.json --report-dir report

--report-dir DIR (every route) also writes DIR/index.html, a page to read offline with pictures
(the rig from the top and the side; per camera the residual quiver, an error map and where the
corners fell; RMS per frame; the error histogram; held-out frames by depth), every parameter's
sigma and what it trades off with, the verdict, and which view to add: the board's distance, tilt
and place in which camera's image that shrinks the worst-determined parameter's sigma most.

With observations: the rig's cameras are calibrated in air (intrinsics, distortion, extrinsics); its ports (the shared
interface, or each camera's own) are the start guess, and what --estimate does not name is known.
The observations hold, per view, the target's corners in every camera that saw it, keyed by rig
camera name, in target order (for a board row-major as cv::findChessboardCorners returns them),
raw (distorted) pixels, null where a corner was not found; a camera absent from a view did not see
it. The target is a board or any 3-D layout of points (metres):
  {\"board\": {\"rows\": 6, \"cols\": 9, \"square\": 0.04},
   \"views\": [{\"left\": [[u, v], ...], \"right\": [[u, v], ...]}, ...]}
  {\"target\": {\"points\": [[x, y, z], ...]}, \"views\": [{\"cam0\": [[u, v], ...]}, ...]}
The stereo form (left/right with \"cameras\": [A, B]) is read too.

Two cameras behind one shared port with a board, estimating axis,distance, run the thesis' methods:
consecutive (the axis from the pattern invariants by a global search over tilts up to
--max-tilt-deg and local refinement, then the air layer by linear least squares); simultaneous
(maximum likelihood: Levenberg-Marquardt over axis, air layer and board poses on the reprojection
error, started from the consecutive result, with standard deviations); auto (default: consecutive,
then maximum likelihood from several starts, keeping the lowest cost). Every other rig (one camera,
N cameras, a port per camera, a 3-D target, layers or extrinsics estimated): a pose per view, the
consecutive method over every camera pair behind a shared port (auto, consecutive) or a global
search over each port's axis (auto without such pairs, simultaneous), then maximum likelihood over
everything estimated, with a standard deviation for each. A fit above --max-rms-px (or far above
the corner noise seen in the images) says which usual input mistake it looks like: a wrong square,
half-resolution pixels, corners undistorted twice, a baseline in millimetres.

Examples:
  flatport calibrate --rig rig.json --observations obs.json --output calibrated.json
  flatport calibrate --rig rig.json --observations obs.json -o calibrated.json --report report.json \\
      --method simultaneous --huber 1.0
  flatport calibrate --rig one/start_rig.json --observations one/observations.json -o one.json
  flatport calibrate --rig rig.json --observations obs.json --estimate axis,distance,extrinsics -o out.json
  flatport calibrate --rig tank.json --observations obs.json --estimate axis,layer:1 -o out.json")]
    Calibrate(calib::CalibrateArgs),
    /// Sweep a calibration cost over a grid of axes (and air layers): .npy, CSV, heat maps, summary
    #[command(after_help = "\
Tilt is the angle between the axis and the master camera's z axis, azimuth atan2(n_y, n_x), both in
degrees; grids are START:STOP:COUNT with both ends included (numpy's linspace). --distance is a
grid of air layers d in metres (the rig file's interface.distance); without it, every axis takes
its least-squares air layer (a profile; affine-grid needs none). The grid is
evaluated in batches on the device, so memory stays bounded whatever its size.

Writes DIR/cost.npy (float64, shape [tilt, azimuth] or [tilt, azimuth, distance]), DIR/cost.csv
(tilt_deg,azimuth_deg,distance,cost per cell; inf where the candidate leaves some corner without
an answer, counted on stderr and drawn grey in the pictures),
DIR/distance.npy (the profile's air layers, for reprojection and scene without --distance),
DIR/heatmap.png and DIR/polar.png (minimum marked, truth marked with --truth), DIR/summary.json
(argmin, grid, timing). Files appear only when the sweep completed; Ctrl-C (or SIGTERM) stops it
at once and leaves nothing behind.

Examples:
  flatport sweep --rig rig.json --observations obs.json --cost affine-grid \\
      --tilt-deg 0:20:64 --azimuth-deg -180:180:64 --output sweep
  flatport sweep --rig rig.json --observations obs.json --cost reprojection \\
      --tilt-deg 6:10:21 --azimuth-deg 40:50:21 --distance 0.015:0.025:11 --output sweep3d --device gpu

No board (--targetless, docs/targetless.md): the cost of matches of a textured scene filmed by the
rig (DIR as calibrate --targetless reads it), each match's point fitted alone under the cell's
port, as an RMS reprojection error in px; the master's port is moved; --distance is required:
  flatport sweep --images seabed --rig naive.json --targetless \
      --tilt-deg 6:10:17 --azimuth-deg 35:55:21 --distance 0.01:0.03:21 --output well

Over many machines (a SLURM array, a Kubernetes Indexed Job; see docs/sweeps.md): --shard I/N writes
slice I of N into its own folder, `flatport sweep merge` joins the folders into the files above:
  flatport sweep ... --shard 0/4 --output shard-0      (and 1/4, 2/4, 3/4)
  flatport sweep merge shard-0 shard-1 shard-2 shard-3 --output sweep")]
    Sweep(sweep::SweepCommand),
    /// Rig files: import OpenCV stereoCalibrate output or an AquaCal calibration.json, show a rig
    #[command(subcommand)]
    Rig(rig::RigCommand),
    /// Export a rig for other tools (colmap_underwater, OpenCV, AquaCal) or a camera's per-pixel ray map (.npy)
    #[command(subcommand)]
    Export(export::ExportCommand),
    /// Run the built-in example end to end: a whole rig calibrated from rendered ChArUco footage alone (lenses, extrinsics, port), then a rig's views of a chessboard rendered, its corners detected, the port calibrated, the cost swept, the geometry toured, and dense stereo of a rendered seabed (point cloud, depth picture)
    #[command(after_help = "\
Example:
  flatport demo --output flatport-demo")]
    Demo(demo::DemoArgs),
    /// Measure items/s of every path (CPU scalar/vector, 1 thread/all threads, GPU f32/f64), each against its measured roof
    #[command(after_help = "\
Prints items per second for back-projection (with the rig's lens distortion and without),
forward projection and triangulation on the CPU (f64; the scalar path, the model row by row, and
the vector path, run by run in turn; one thread, with cycles per item at the OS's clock, and all
threads), where the vector path's time goes against the floor of its square roots and divisions
(each costed at this machine's measured throughput), and the GPU (f32 and f64; `kernel` = dispatch
only with the data on the device, timed by GPU timestamps where the adapter has TIMESTAMP_QUERY,
`end_to_end` = upload, dispatch and results in host memory, host clocks, in the chunks the engine
chooses for the adapter; forward projection also `end_to_end_streamed` (chunks of 2^19 rows through
the ring of buffer sets, the choice on a hardware GPU), `end_to_end_one_chunk` (no overlap, the
choice on lavapipe) and `end_to_end_f32_host` (f32 host data)). The device-resident chain, matched
pixels of two cameras -> 3-D points with the rows never on the host between: `chain_triangulate`
(one fused kernel) and `chain_triangulate_unfused` (back-projection in each camera, then
triangulation of the rays: three kernels), `kernel` (pixels already on the device) and
`end_to_end` (pixels up, points down).

Roofs, measured in the same run: the CPU's memory bandwidth (a STREAM triad); the GPU's host link
(256 MiB up and down through wgpu) and its device memory (a copy kernel). Each GPU relation figure
says what share of its roof it uses: a kernel of the device memory (its rows read and written), an
end-to-end call of the host link (its inputs up and its outputs down). Every figure names its
device and precision.

Costs: the weighted affine-grid sweep (axis cells x correspondences per second over 185 simulated
views, 9 990 correspondences; its GPU kernel is f64 on every adapter), the reprojection and scene
sweeps over a quarter of the cells (GPU, f64 engine), and the calibration backend's stencil calls
(7 candidates, rows resident or uploaded each call). Then the ratios between the paths of this run
(the speed goals and their reference are in docs/performance.md, \"Speed goals\").

JSON: {\"memory_stream_bytes_per_s\", \"cpu_model\", \"cpu_threads\", \"cpu_instruction_set\",
\"cpu_clock_hz\", \"floors\": {\"sqrt_cycles_per_lane\", \"div_cycles_per_lane\", \"kernels\": [...]},
\"gpu_adapter\", \"host_link_upload_bytes_per_s\", \"host_link_download_bytes_per_s\",
\"device_memory_bytes_per_s\", \"results\": [{\"kernel\", \"path\", \"cpu_path\" (scalar|vector,
CPU only), \"precision\", \"threads\" (0 on the GPU), \"stage\", \"device\", \"timer\"
(gpu_timestamp|host), \"items\", \"items_per_s\", \"cycles_per_item\" (one CPU thread), \"roof\"
(device_memory|host_link, GPU relations), \"roof_fraction\"}, ...]}.

Examples:
  flatport bench
  flatport bench --items 4000000 --json bench.json
  flatport bench --no-gpu
  scripts/gpu-check.sh      (the GPU tests and this bench on a GPU machine, one report)")]
    Bench(bench::BenchArgs),
    /// Version, build and the compute devices found
    Info,
}

/// Where the computation runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Device {
    /// The f64 reference on all CPU cores
    Cpu,
    /// The WGSL kernels on a Vulkan adapter (a GPU, or lavapipe when there is none)
    Gpu,
    /// A hardware GPU when the machine has one, otherwise the CPU
    Auto,
}

/// Arithmetic of the GPU kernels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PrecisionArg {
    /// 32-bit floats: fastest; pixels within 1e-3 px, directions within 2e-6 of the f64 reference
    F32,
    /// 64-bit floats (adapters with SHADER_F64): agrees with the CPU reference to 1e-9 relative
    F64,
}

/// Where and how batches run (`--device`, `--precision`, `--adapter`).
#[derive(Debug, Args)]
pub struct EngineArgs {
    /// Compute device
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    pub device: Device,
    /// Precision of the GPU kernels. Default: f32 for project, backproject, triangulate, vop and
    /// sweep's reprojection and scene costs; f64 (where the adapter has it) for calibrate and demo;
    /// sweep's affine-grid cost is always f64. The CPU is always f64.
    #[arg(long, value_enum, value_name = "f32|f64")]
    pub precision: Option<PrecisionArg>,
    /// GPU adapter: its index or part of its name as `flatport info` lists them (else
    /// $FLATPORT_ADAPTER, else the best: discrete, integrated, then lavapipe)
    #[arg(long, value_name = "INDEX|NAME")]
    pub adapter: Option<String>,
}

impl EngineArgs {
    /// Builds the engine and says on stderr which device runs.
    pub fn engine(&self) -> anyhow::Result<flatport::engine::Engine> {
        let (engine, why) = flatport::engine::Engine::choose(&self.options())?;
        if self.device == Device::Auto
            && self.precision == Some(PrecisionArg::F32)
            && matches!(engine, flatport::engine::Engine::Cpu(_))
        {
            eprintln!(
                "note: no hardware GPU, so the f64 CPU reference runs (--precision f32 applies to GPUs)"
            );
        }
        if self.device == Device::Auto {
            eprintln!("device: {} ({why})", engine.describe());
        } else {
            eprintln!("device: {}", engine.describe());
        }
        Ok(engine)
    }

    /// Builds the engine without a word on stderr.
    pub fn engine_quiet(&self) -> anyhow::Result<flatport::engine::Engine> {
        Ok(flatport::engine::Engine::new(&self.options())?)
    }

    fn options(&self) -> flatport::engine::EngineOptions {
        use flatport::engine::{Device as D, EngineOptions};
        use flatport::gpu::Precision;
        EngineOptions {
            device: match self.device {
                Device::Cpu => D::Cpu,
                Device::Gpu => D::Gpu,
                Device::Auto => D::Auto,
            },
            precision: self.precision.map(|p| match p {
                PrecisionArg::F32 => Precision::F32,
                PrecisionArg::F64 => Precision::F64,
            }),
            adapter: self.adapter.clone(),
            threads: None,
        }
    }
}

/// Arguments every geometry command shares.
#[derive(Debug, Args)]
pub struct CommonArgs {
    /// Rig file (JSON: cameras and interface, see docs/rigs.md)
    #[arg(long, value_name = "RIG.json")]
    pub rig: PathBuf,
    /// Output CSV file (default: standard output); written only when every input row parsed
    #[arg(long, short, value_name = "FILE")]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub engine: EngineArgs,
}

/// Parses `A,B` (two names).
pub fn parse_pair(text: &str) -> Result<(String, String), String> {
    match text.split(',').map(str::trim).collect::<Vec<_>>()[..] {
        [a, b] if !a.is_empty() && !b.is_empty() => Ok((a.to_string(), b.to_string())),
        _ => Err(format!("expected two names A,B, got '{text}'")),
    }
}

/// `error: cause: cause …` as `{error:#}` writes it, leaving out a cause whose text the message
/// already holds (an I/O error that shows its OS error also returns it as its source, which
/// printed "No such file or directory (os error 2)" twice).
fn chain_once(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&cause);
        }
    }
    text
}

/// Entry point: runs the command, prints errors as `error: …` with their causes, exit code 1.
pub fn main() -> ExitCode {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        // SAFETY: first statement of main, before any thread exists. Keeps Mesa's Vulkan driver
        // from warning about a missing runtime directory on headless machines.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
    signals::install();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Project(args) => geometry::project(args),
        Command::Backproject(args) => geometry::backproject(args),
        Command::Triangulate(args) => geometry::triangulate(args),
        Command::Vop(args) => geometry::vop(args),
        Command::Rig(command) => rig::run(command),
        Command::Export(command) => export::run(command),
        Command::Simulate(args) => simulate::run_simulate(args),
        Command::Calibrate(args) => match args.images.clone() {
            Some(dir) if args.targetless => calib_targetless::run(&args, &dir),
            Some(dir) => calib_images::run(&args, &dir),
            None => calib::run_calibrate(args),
        },
        Command::Sweep(args) => sweep::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Detect(args) => detect::run(args),
        Command::Render(args) => render::run(args),
        Command::Stereo(args) => stereo::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Info => info::run(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) if signals::is_broken_pipe(&error) => signals::exit_on_broken_pipe(),
        Err(error) => {
            eprintln!("error: {}", chain_once(&error));
            ExitCode::FAILURE
        }
    }
}
