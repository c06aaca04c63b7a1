#!/usr/bin/env bash
# Runs the commands of README.md and docs/*.md as a user would type them, so that the guides stay
# true. Usage: scripts/check-docs.sh [FILE.md ...]   (default: README.md docs/*.md)
#
# What runs:
#   ```sh        blocks run with bash, in order, in a fresh temporary folder per file that holds
#                links to the checkout's data/, docs/ and scripts/ (the guides read data/...), with
#                the built flatport first on PATH; a block's state (files, `cd`, variables) carries
#                to the next block of the same file.
#   ```python    blocks run after the file's sh blocks, in order, as one Python program, in the same
#                folder, when FLATPORT_PYTHON names a Python with the flatport package (scripts/test.sh
#                sets it); otherwise they are skipped, and the check says so.
#   anything else (```sh skip, ```python skip, ```text, ```json, ```rust, ...) is not run here.
#                ```rust blocks are compiled and run by `cargo test --doc` (src/lib.rs includes the
#                files); tests/docs.rs checks that every fence has a known info string.
# A failing command fails the check, naming the file and the line of the command, with its output.
#
# Environment: FLATPORT_BIN (default target/release/flatport), FLATPORT_PYTHON (optional),
# CHECK_DOCS_TIMEOUT_S (per file, default 300).
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD"

bin="${FLATPORT_BIN:-$root/target/release/flatport}"
if [ ! -x "$bin" ]; then
    echo "check-docs: no flatport binary at $bin: run cargo build --release first (or set FLATPORT_BIN)" >&2
    exit 1
fi
python="${FLATPORT_PYTHON:-}"
timeout_s="${CHECK_DOCS_TIMEOUT_S:-300}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

if [ $# -gt 0 ]; then files=("$@"); else files=(README.md docs/*.md); fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/bin"
ln -s "$(cd "$(dirname "$bin")" && pwd)/$(basename "$bin")" "$work/bin/flatport"

# Writes the blocks of $1 whose info string is exactly $2 to stdout, every other line blank, so that
# line N of the output is line N of the file (bash's $LINENO and Python's tracebacks then name the
# file's own lines). Line 1 becomes $3, the program's preamble. An unclosed fence is an error.
extract() {
    awk -v want="$2" -v preamble="$3" '
        NR == 1 { if ($0 ~ /^```/) { print "check-docs: " FILENAME ":1: a file may not open with a code block" > "/dev/stderr"; exit 2 } print preamble; next }
        inside == 0 && /^```/ { info = substr($0, 4); sub(/[ \t]+$/, "", info); inside = 1; run = (info == want); start = NR; print ""; next }
        inside == 1 && /^```[ \t]*$/ { inside = 0; run = 0; print ""; next }
        { print (inside && run) ? $0 : "" }
        END { if (inside) { print "check-docs: " FILENAME ":" start ": code block never closed" > "/dev/stderr"; exit 2 } }
    ' "$1"
}

# Seconds since $1 (from date +%s%N), to a tenth.
elapsed() {
    local tenths=$(( ($(date +%s%N) - $1) / 100000000 ))
    echo "$((tenths / 10)).$((tenths % 10))"
}

failed=0
total_start=$(date +%s%N)
for file in "${files[@]}"; do
    [ -f "$file" ] || { echo "check-docs: $file: no such file" >&2; failed=1; continue; }
    name=$(echo "$file" | tr '/' '_')
    dir="$work/$name.run"
    mkdir -p "$dir"
    ln -s "$root/data" "$dir/data"
    ln -s "$root/docs" "$dir/docs"
    ln -s "$root/scripts" "$dir/scripts"
    sh_blocks=$(grep -c '^```sh[[:space:]]*$' "$file" || true)
    py_blocks=$(grep -c '^```python[[:space:]]*$' "$file" || true)
    [ "$sh_blocks" -gt 0 ] || [ "$py_blocks" -gt 0 ] || continue

    start=$(date +%s%N)
    log="$work/$name.log"
    : > "$log"
    status=0
    if [ "$sh_blocks" -gt 0 ]; then
        preamble="set -eEuo pipefail; trap 'rc=\$?; echo \"check-docs: $file:\$LINENO: exit status \$rc: \$BASH_COMMAND\" >&2; exit \$rc' ERR"
        extract "$file" sh "$preamble" > "$work/$name.sh" || exit 2
        (cd "$dir" && PATH="$work/bin:$PATH" timeout "$timeout_s" bash "$work/$name.sh") >> "$log" 2>&1 || status=$?
        if [ "$status" = 124 ]; then echo "check-docs: $file: the shell blocks ran past ${timeout_s} s" >> "$log"; fi
    fi
    py_note=""
    if [ "$status" = 0 ] && [ "$py_blocks" -gt 0 ]; then
        if [ -n "$python" ]; then
            # The program is named after the file, so that tracebacks read "docs/python.md", line N.
            mkdir -p "$work/py/$(dirname "$file")"
            extract "$file" python "" > "$work/py/$file" || exit 2
            (cd "$dir" && PATH="$work/bin:$PATH" FLATPORT_BIN="$bin" timeout "$timeout_s" "$python" "$work/py/$file") >> "$log" 2>&1 || status=$?
            if [ "$status" != 0 ]; then echo "check-docs: $file: a python block failed (exit status $status; the traceback names the file's line)" >> "$log"; fi
        else
            py_note=" ($py_blocks python block(s) skipped: set FLATPORT_PYTHON)"
        fi
    fi
    seconds=$(elapsed "$start")
    if [ "$status" = 0 ]; then
        printf 'check-docs: %-22s ok, %s sh block(s)%s, %s s\n' "$file" "$sh_blocks" "$py_note" "$seconds"
    else
        echo "check-docs: $file FAILED; its output (last 60 lines):" >&2
        tail -n 60 "$log" | sed 's/^/    /' >&2
        failed=1
    fi
done
echo "check-docs: ${#files[@]} file(s) in $(elapsed "$total_start") s"
exit "$failed"
