#!/usr/bin/env bash
# Checks a flatport build on the GPU of this machine, in minutes: runs the GPU test binaries and
# `flatport bench` on the hardware adapter and writes one report, text and JSON.
#
#   scripts/gpu-check.sh [OUT_DIR]          (default OUT_DIR: gpu-check)
#
# From a checkout with Rust, it builds what it runs (release). On a machine without Rust, point it
# at binaries built elsewhere (docs/testing.md, "A GPU machine"):
#   FLATPORT_BIN=path/to/flatport FLATPORT_GPU_TESTS=dir/of/test/executables scripts/gpu-check.sh
# The test executables read data/ at the absolute path of the checkout they were built in.
#
# Other settings: FLATPORT_ADAPTER (which adapter, as `flatport info` lists them; default the best),
# FLATPORT_ALLOW_SOFTWARE=1 (accept lavapipe: to try the script without a GPU), and the bench's
# sizes BENCH_ITEMS (16000000), BENCH_REPEATS (5), BENCH_SWEEP_CELLS (65536 = 256² axes).
#
# Outputs: OUT_DIR/report.txt and OUT_DIR/report.json (adapter, each test binary's counts, the
# bench's figures), OUT_DIR/info.txt, OUT_DIR/tests/*.txt, OUT_DIR/bench.txt, OUT_DIR/bench.json.
# Exit status: 0 when every test passed and the bench ran; 1 otherwise.
set -uo pipefail
cd "$(dirname "$0")/.."

out="${1:-gpu-check}"
mkdir -p "$out/tests"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
# The GPU test binaries: the relations, the calibration kernels, failure handling, and every other
# test file whose name says it runs on the GPU.
gpu_tests="gpu calib_gpu gpu_failures device_rows stereo_gpu calibrate_gpu"

die() { echo "gpu-check: $*" >&2; exit 1; }

# The flatport binary and the test executables: given, or built here.
bin="${FLATPORT_BIN:-}"
tests_dir="${FLATPORT_GPU_TESTS:-}"
if [ -z "$bin" ] || [ -z "$tests_dir" ]; then
    command -v cargo >/dev/null 2>&1 || die "no cargo here: set FLATPORT_BIN and FLATPORT_GPU_TESTS to binaries built elsewhere"
    echo "building flatport and the GPU test binaries (release)..." >&2
    cargo build --release --bin flatport >&2 || die "cargo build failed"
    bin="${bin:-target/release/flatport}"
    if [ -z "$tests_dir" ]; then
        tests_dir="$out/test-bin"
        mkdir -p "$tests_dir"
        args=()
        for t in $gpu_tests; do [ -f "tests/$t.rs" ] && args+=(--test "$t"); done
        # cargo prints one JSON message per artifact; the test executables are the non-null
        # "executable" fields of the test targets.
        cargo test --release --no-run --message-format=json "${args[@]}" 2>/dev/null \
            | grep -o '"executable":"[^"]*/deps/[^"]*"' | sed 's/"executable":"//; s/"$//' \
            | while read -r exe; do ln -sf "$(realpath "$exe")" "$tests_dir/$(basename "$exe" | sed 's/-[0-9a-f]*$//')"; done
    fi
fi
[ -x "$bin" ] || die "no flatport binary at $bin"
[ -d "$tests_dir" ] || die "no test directory at $tests_dir"

# The adapter: a hardware one unless told otherwise.
"$bin" info >"$out/info.txt" 2>&1 || die "flatport info failed: $(tail -3 "$out/info.txt")"
if ! grep -qiE 'DiscreteGpu|IntegratedGpu|VirtualGpu' "$out/info.txt" && [ "${FLATPORT_ALLOW_SOFTWARE:-0}" != 1 ]; then
    cat "$out/info.txt" >&2
    die "no hardware Vulkan adapter (set FLATPORT_ALLOW_SOFTWARE=1 to check on lavapipe)"
fi

# The tests, one binary at a time; each binary's counts from its "test result:" line.
status=0
tests_json=""
for exe in "$tests_dir"/*; do
    [ -x "$exe" ] || continue
    name="$(basename "$exe")"
    echo "running $name..." >&2
    CI=true "$exe" >"$out/tests/$name.txt" 2>&1
    rc=$?
    line="$(grep -E '^test result:' "$out/tests/$name.txt" | tail -1)"
    passed="$(echo "$line" | sed -n 's/.* \([0-9]*\) passed.*/\1/p')"
    failed="$(echo "$line" | sed -n 's/.* \([0-9]*\) failed.*/\1/p')"
    [ "$rc" = 0 ] || status=1
    failures="$(grep -E '^test .* FAILED$' "$out/tests/$name.txt" | sed 's/^test //; s/ \.\.\. FAILED$//' | tr '\n' ' ')"
    tests_json="$tests_json${tests_json:+,}{\"binary\":\"$name\",\"exit\":$rc,\"passed\":${passed:-0},\"failed\":${failed:-0},\"failures\":\"${failures% }\"}"
done
[ -n "$tests_json" ] || die "no test executables in $tests_dir"

echo "running flatport bench..." >&2
"$bin" bench --items "${BENCH_ITEMS:-16000000}" --repeats "${BENCH_REPEATS:-5}" \
    --sweep-cells "${BENCH_SWEEP_CELLS:-65536}" --json "$out/bench.json" >"$out/bench.txt" 2>&1 \
    || { status=1; echo '{}' >"$out/bench.json"; }

adapter="$( (grep -m1 -E '^  gpu [0-9]+: .*(DiscreteGpu|IntegratedGpu|VirtualGpu)' "$out/info.txt" \
    || grep -m1 -E '^  gpu [0-9]+: ' "$out/info.txt") | sed 's/^  //; s/"/\\"/g')"
{
    echo "flatport gpu-check, $(date -u +%Y-%m-%dT%H:%M:%SZ), $(uname -n)"
    echo "adapter: $adapter"
    echo
    echo "tests:"
    for f in "$out"/tests/*.txt; do
        printf '  %-28s %s\n' "$(basename "$f" .txt)" "$(grep -E '^test result:' "$f" | tail -1)"
        grep -E '^test .* FAILED$' "$f" | sed 's/^/    /'
    done
    echo
    echo "roofs and figures (flatport bench; all of it in bench.txt):"
    grep -E '^(host link|device memory|memory streaming)' "$out/bench.txt" | sed 's/^/  /'
    grep -E ' gpu .* (kernel|end_to_end) ' "$out/bench.txt" | sed 's/^/  /'
    grep -E '^(sweep|stencil|chain|stereo)[a-z_]* +(cpu|gpu) ' "$out/bench.txt" | sed 's/^/  /'
    echo
    grep -A100 '^ratios from this run' "$out/bench.txt"
} >"$out/report.txt"
{
    printf '{"adapter":"%s","tests":[%s],"bench":' "$adapter" "$tests_json"
    cat "$out/bench.json"
    printf '}\n'
} >"$out/report.json"
cat "$out/report.txt"
echo "wrote $out/report.txt and $out/report.json" >&2
exit $status
