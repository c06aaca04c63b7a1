#!/usr/bin/env python3
"""Corner errors of a detected observations file against the exact corners `flatport render`
wrote beside its images: RMS and largest distance in pixels, and the boards and corners compared.

    python3 scripts/corner_errors.py shots/corners.json observations.json

Views pair by position, so both files must hold the same views (detect leaves out views it cannot
use, and says so); cameras pair by key (`left`/`right` in the stereo form, camera names in the
general form)."""
import json
import math
import sys


def cameras(view):
    return {k: v for k, v in view.items() if isinstance(v, list)}


def main(exact_path, found_path):
    exact, found = (json.load(open(p)) for p in (exact_path, found_path))
    if len(exact["views"]) != len(found["views"]):
        sys.exit(f"{found_path} holds {len(found['views'])} views, {exact_path} {len(exact['views'])}: they do not pair")
    squares, largest, count, boards = 0.0, 0.0, 0, 0
    for e, f in zip(exact["views"], found["views"]):
        for name, corners in cameras(f).items():
            boards += 1
            for p, q in zip(corners, cameras(e)[name]):
                if p is None or q is None:
                    continue
                d = math.hypot(p[0] - q[0], p[1] - q[1])
                squares += d * d
                largest = max(largest, d)
                count += 1
    print(f"{boards} boards, {count} corners: RMS {math.sqrt(squares / max(count, 1)):.4f} px, largest {largest:.4f} px")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
