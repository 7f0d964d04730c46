#!/usr/bin/env python3
"""Median time per pass of several ppb binaries (or instruction sets), interleaved.

    python3 tools/pass_time.py BIN[:SIMD],BIN[:SIMD]... [PASSES] [REPEATS]

Renders the four public conformance scenes and scenes/bench/dense-smoke with each binary in
turn, REPEATS times (default 3), PASSES passes each (default 12), and prints the median of
(sum of the stage times in --stats) / passes, which leaves out the scene load, with each
binary's ratio to the first. `BIN:scalar` sets PPB_SIMD=scalar for that binary. Run it from
the repository root on an idle machine: single runs move by 5 to 10 %.
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile

SCENES = ["conformance/fog-box", "conformance/smoke-grid", "conformance/cloud-hg",
          "conformance/glass-caustic", "bench/dense-smoke"]


def ms_per_pass(exe, simd, scene, passes, out):
    env = dict(os.environ)
    if simd:
        env["PPB_SIMD"] = simd
    stats, exr = os.path.join(out, "stats.json"), os.path.join(out, "image.exr")
    subprocess.run([exe, "render", f"scenes/{scene}/scene.toml", "--passes", str(passes), "-q",
                    "--stats", stats, "-o", exr], check=True, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(stats) as f:
        d = json.load(f)
    return 1e3 * sum(d["seconds"]["stages"].values()) / d["passes"]


def main():
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if len(sys.argv) > 1 else 2)
    runs = [b.partition(":")[::2] for b in sys.argv[1].split(",")]
    passes = int(sys.argv[2]) if len(sys.argv) > 2 else 12
    repeats = int(sys.argv[3]) if len(sys.argv) > 3 else 3
    with tempfile.TemporaryDirectory() as out:
        for scene in SCENES:
            times = {r: [] for r in runs}
            for _ in range(repeats):
                for exe, simd in runs:
                    times[(exe, simd)].append(ms_per_pass(exe, simd, scene, passes, out))
            med = {r: statistics.median(v) for r, v in times.items()}
            first = med[runs[0]]
            cells = [f"{os.path.basename(e)}{':' + s if s else ''} {med[(e, s)]:7.1f} ms "
                     f"({first / med[(e, s)]:.2f}x)" for e, s in runs]
            print(f"{scene.split('/')[-1]:<14} " + "  ".join(cells), flush=True)


if __name__ == "__main__":
    main()
