#!/usr/bin/env bash
# Checks a flatport build on the GPU of this machine, in minutes: runs the GPU test binaries and
# `flatport bench` on the hardware adapter and writes one report, text and JSON.
#
#   scripts/gpu-check.sh [OUT_DIR]              check here (default OUT_DIR: gpu-check)
#   scripts/gpu-check.sh --pack BUNDLE.tar.xz   build, and pack what a machine without Rust needs
#
# From a checkout with Rust, it builds what it runs (release). For a GPU machine without Rust,
# pack a bundle here, copy it there, and run the script inside it (docs/testing.md, "A GPU machine"):
#   tar -xJf BUNDLE.tar.xz && gpu-check-bundle/gpu-check.sh OUT_DIR
# The test executables read data/ (and run the flatport binary) at the absolute path of the
# checkout they were built in: inside a bundle, the script links that path to the bundle when it
# does not exist (as root, or where the parent folder is writable).
#
# Other settings: FLATPORT_BIN and FLATPORT_GPU_TESTS (a flatport binary and a folder of test
# executables to use instead), FLATPORT_ADAPTER (which adapter, as `flatport info` lists them;
# default the best), FLATPORT_ALLOW_SOFTWARE=1 (accept lavapipe: to try the script without a GPU),
# and the bench's sizes BENCH_ITEMS (4194304), BENCH_REPEATS (3), BENCH_SWEEP_CELLS (65536 = 256²).
#
# Outputs: OUT_DIR/report.txt and OUT_DIR/report.json (adapter, each test binary's counts, the
# bench's figures), OUT_DIR/info.txt, OUT_DIR/tests/*.txt, OUT_DIR/bench.txt, OUT_DIR/bench.json.
# Exit status: 0 when every test passed and the bench ran; 1 otherwise.
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
die() { echo "gpu-check: $*" >&2; exit 1; }

# The GPU test binaries: every tests/*gpu*.rs (the relations, the calibration kernels and
# backends, failure handling, device-resident rows, stereo).
gpu_test_names() {
    for f in tests/*gpu*.rs; do [ -f "$f" ] && basename "$f" .rs; done
}

# Builds flatport and the GPU test executables; links (or with --copy, copies and strips) them
# into $1 as NAME, the test's file name.
build_tests() {
    local dir="$1" mode="${2:-link}" args=()
    for t in $(gpu_test_names); do args+=(--test "$t"); done
    echo "building flatport and the GPU test binaries (release)..." >&2
    cargo build --release --bin flatport >&2 || die "cargo build failed"
    mkdir -p "$dir"
    # cargo prints one JSON message per artifact; the test executables are the "executable"
    # fields under target/release/deps/.
    cargo test --release --no-run --message-format=json "${args[@]}" 2>/dev/null \
        | grep -o '"executable":"[^"]*/deps/[^"]*"' | sed 's/"executable":"//; s/"$//' \
        | while read -r exe; do
            name="$(basename "$exe" | sed 's/-[0-9a-f]*$//')"
            if [ "$mode" = copy ]; then
                cp "$exe" "$dir/$name" && strip "$dir/$name"
            else
                ln -sf "$(realpath "$exe")" "$dir/$name"
            fi
        done
}

if [ "${1:-}" = "--pack" ]; then
    bundle="${2:?usage: scripts/gpu-check.sh --pack BUNDLE.tar.xz}"
    cd "$here/.."
    stage="$(mktemp -d)/gpu-check-bundle"
    mkdir -p "$stage/target/release" "$stage/scripts"
    build_tests "$stage/tests" copy
    cp target/release/flatport "$stage/target/release/" && strip "$stage/target/release/flatport"
    cp -r data "$stage/"
    cp scripts/gpu-check.sh "$stage/gpu-check.sh"
    pwd >"$stage/build-root"
    tar -C "$(dirname "$stage")" -cf - gpu-check-bundle | xz -T0 -6 >"$bundle"
    echo "wrote $bundle ($(du -h "$bundle" | cut -f1)); on the GPU machine: tar -xJf $(basename "$bundle") && gpu-check-bundle/gpu-check.sh OUT_DIR" >&2
    exit 0
fi

out="$(realpath -m "${1:-gpu-check}")"
mkdir -p "$out/tests"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

bin="${FLATPORT_BIN:-}"
tests_dir="${FLATPORT_GPU_TESTS:-}"
if [ -f "$here/build-root" ]; then
    # Inside a bundle: its binaries, and the checkout's path where the tests look.
    root="$(cat "$here/build-root")"
    bin="${bin:-$here/target/release/flatport}"
    tests_dir="${tests_dir:-$here/tests}"
    if [ ! -e "$root" ]; then
        mkdir -p "$(dirname "$root")" && ln -s "$here" "$root" \
            || die "the tests read $root/data: link it to $here (ln -s $here $root), or run as root"
    fi
    [ -d "$root/data" ] || die "$root exists but has no data/: the tests read $root/data"
elif [ -z "$bin" ] || [ -z "$tests_dir" ]; then
    cd "$here/.."
    command -v cargo >/dev/null 2>&1 || die "no cargo here: pack a bundle on a machine with Rust (--pack)"
    bin="${bin:-$PWD/target/release/flatport}"
    if [ -z "$tests_dir" ]; then
        tests_dir="$out/test-bin"
        build_tests "$tests_dir"
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
"$bin" bench --items "${BENCH_ITEMS:-4194304}" --repeats "${BENCH_REPEATS:-3}" \
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
    grep -E '^((sweep|stencil|chain)[a-z_]* +(cpu|gpu) |stereo )' "$out/bench.txt" | sed 's/^/  /'
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
