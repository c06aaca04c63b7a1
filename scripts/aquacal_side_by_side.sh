#!/usr/bin/env bash
# flatport and AquaCal 2.1 side by side on the same rendered images (issue 38 item 11; the figures
# are in docs/performance.md, "Calibration from images: flatport and AquaCal"). Not run in CI: it
# installs AquaCal from PyPI and AquaCal's calibration takes minutes.
#
#   scripts/aquacal_side_by_side.sh [OUT_DIR]        (default OUT_DIR: target/aquacal-bench)
#
# 1. renders a calibration set of data/rigs/surface_4.json (four cameras 0.15 m apart above one
#    bare water surface 0.2 m below) with the 7x5 ChArUco board: 30 synchronized underwater views,
#    12 in-air views a camera, image noise 1 grey level;
# 2. times `flatport calibrate --images` end to end (corner detection, each lens in air, the
#    extrinsics and the surface);
# 3. times `aquacal calibrate CONFIG.yaml` end to end on the same folders (its in-air and
#    underwater pipeline, its CLI as a new user runs it);
# 4. converts AquaCal's calibration.json with `flatport rig from-aquacal` and compares both rigs
#    against the true rig with scripts/aquacal_compare.py (extrinsics, surface, in-air lens, 3-D).
#
# Settings: FLATPORT (the binary; default target/release/flatport, built when missing), VENV (a
# Python venv holding aquacal; default target/aquacal-venv, made and filled when missing),
# AQUACAL_VERSION (2.1.0). AquaCal 2.1.0 pins opencv-python==4.13.*, so it runs with OpenCV 4.13.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
out="${1:-target/aquacal-bench}"
flatport="${FLATPORT:-$root/target/release/flatport}"
venv="${VENV:-$root/target/aquacal-venv}"
version="${AQUACAL_VERSION:-2.1.0}"
board="$root/data/boards/charuco_7x5.json"
rig="$root/data/rigs/surface_4.json"

if [ ! -x "$flatport" ]; then
    cargo build --release --bin flatport
fi
if [ ! -x "$venv/bin/aquacal" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q "aquacal==$version"
fi
flatport="$(cd "$(dirname "$flatport")" && pwd)/$(basename "$flatport")"
venv="$(cd "$venv" && pwd)"
mkdir -p "$out"
cd "$out"

echo "== machine"
lscpu | grep -E '^(Model name|CPU\(s\)):' || true
uptime
"$venv/bin/python" -c 'import aquacal, cv2, importlib.metadata as m; print("aquacal", m.version("aquacal"), "OpenCV", cv2.__version__)'

echo "== render"
rm -rf set
"$flatport" render --rig "$rig" --board "$board" --calibration-set --views 30 --air-views 12 \
    --noise 1 --quiet -o set

# Wall, user and system seconds of one command, as bash's `time` prints them.
TIMEFORMAT='%R s wall, %U s user, %S s system'

echo "== flatport"
rm -f flatport_rig.json flatport_report.json
{ time "$flatport" calibrate --images set --board "$board" --port surface \
    -o flatport_rig.json --report flatport_report.json --truth set/water/truth.json \
    >flatport.log 2>&1; } 2>flatport.time
tail -n 25 flatport.log
cat flatport.time

echo "== aquacal"
cameras="$("$venv/bin/python" -c 'import json,sys; print(",".join(c["name"] for c in json.load(open(sys.argv[1]))["cameras"]))' "$rig")"
{
    echo "# AquaCal $version on the flatport calibration set (written by scripts/aquacal_side_by_side.sh)"
    "$venv/bin/python" -c 'import json,sys; b=json.load(open(sys.argv[1])); print("board:"); [print(f"  {k}: {json.dumps(b[k])}") for k in ("squares_x","squares_y","square_size","marker_size","dictionary","legacy_pattern")]' "$board"
    echo "cameras: [$cameras]"
    echo "paths:"
    echo "  intrinsic_videos: {$(echo "$cameras" | sed -E 's#([^,]+)#\1: "set/air/\1"#g; s#,#, #g')}"
    echo "  extrinsic_videos: {$(echo "$cameras" | sed -E 's#([^,]+)#\1: "set/water/\1"#g; s#,#, #g')}"
    echo '  output_dir: "aquacal_out"'
    echo "interface: {n_air: 1.0, n_water: 1.333, normal_fixed: false}"
    echo 'optimization: {robust_loss: "huber", loss_scale: 1.0, reject_outlier_frames: true}'
    echo "detection: {min_corners: 8, min_cameras: 2, frame_step: 1}"
} >aquacal.yaml
rm -rf aquacal_out
{ time "$venv/bin/aquacal" calibrate aquacal.yaml >aquacal.log 2>&1; } 2>aquacal.time
grep -E 'Stage|RMS|Water surface|tilt|3D' aquacal.log || true
cat aquacal.time
"$flatport" rig from-aquacal aquacal_out/calibration.json -o aquacal_rig.json

echo "== against the truth (set/water/rig.json)"
"$venv/bin/python" "$root/scripts/aquacal_compare.py" "$flatport" set/water/rig.json \
    flatport=flatport_rig.json aquacal=aquacal_rig.json --json compare.json

fp="$(cut -d' ' -f1 flatport.time)"
aq="$(cut -d' ' -f1 aquacal.time)"
fp_cpu="$(awk '{print $4 + $7}' flatport.time)"
aq_cpu="$(awk '{print $4 + $7}' aquacal.time)"
echo "== time: flatport ${fp} s, AquaCal ${aq} s wall: AquaCal/flatport $(awk -v a="$aq" -v b="$fp" 'BEGIN{printf "%.1f", a/b}')x;" \
    "CPU (user + system) ${fp_cpu} s and ${aq_cpu} s: $(awk -v a="$aq_cpu" -v b="$fp_cpu" 'BEGIN{printf "%.1f", a/b}')x"
