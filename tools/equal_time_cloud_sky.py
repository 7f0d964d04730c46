"""Equal time on cloud-sky (tests/data/conformance/cloud-sky): Mitsuba 3 and ppb.

The shared ../shared/tools/equal_time.py knows only the shared scenes; this is the same
measurement for the scene this repository added. For each budget T seconds, Mitsuba 3
(volpath, the reference's own scene, render_reference.py) renders 32-spp chunks with fresh
seeds until T is spent (JIT warm-up not counted), then ppb renders
scenes/conformance/cloud-sky/scene.toml with `--time T`. Both are compared with the
reference: rel_l1 per pixel and over 4x4 block means, raw and net of the reference's own
noise (reference.json; net = sqrt(err^2 - noise^2)), and the ratio Mitsuba / ppb (above 1:
ppb is ahead). Run on an otherwise idle machine, from the project root, after
`cargo build --release`:
  python3 tools/equal_time_cloud_sky.py [--budgets 60,300] [--ppb target/release/ppb]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "tests/data/conformance/cloud-sky")
sys.path.insert(0, DATA)
import render_reference as R  # noqa: E402


def errors(img, ref, noise):
    out = {}
    for name, a, b, n in [("pixel", img, ref, noise[0]),
                          ("4x4", R.block_means(img), R.block_means(ref), noise[1])]:
        e = R.rel_l1(a, b)
        out[name] = (e, float(np.sqrt(max(e * e - n * n, 0.0))))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--budgets", default="60")
    ap.add_argument("--ppb", default="target/release/ppb")
    ap.add_argument("--json")
    a = ap.parse_args()
    mi = R.setup_mitsuba()
    ref = R.read_exr(mi, os.path.join(DATA, "reference.exr"))
    info = json.load(open(os.path.join(DATA, "reference.json")))["noise"]
    noise = (info["rel_l1_halves_over_2"], info["rel_l1_halves_over_2_4x4_block_means"])
    scene = R.build_scene(mi, "sky")
    R.render_chunk(mi, scene, 987654)  # JIT warm-up, not timed
    rows = []
    for budget in [float(b) for b in a.budgets.split(",")]:
        acc, n, seed, t0 = np.zeros_like(ref), 0, 7_000_000, time.time()
        while time.time() - t0 < budget:
            acc += R.render_chunk(mi, scene, seed)
            seed, n = seed + 1, n + 1
        mts = acc / max(n, 1)
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "ppb.exr")
            subprocess.run([a.ppb, "render", "scenes/conformance/cloud-sky/scene.toml",
                            "--time", f"{budget:g}", "-o", out, "--quiet"],
                           cwd=ROOT, check=True)
            ppb = R.read_exr(mi, out)
        em, ep = errors(mts, ref, noise), errors(ppb, ref, noise)
        row = {"budget_s": budget, "mitsuba_spp": n * R.SPP_PER_CHUNK,
               "mitsuba": em, "ppb": ep,
               "ratio_net": {k: em[k][1] / max(ep[k][1], 1e-12) for k in em},
               "ratio_raw": {k: em[k][0] / ep[k][0] for k in em}}
        rows.append(row)
        print(f"cloud-sky {budget:g} s: Mitsuba {n * R.SPP_PER_CHUNK} spp")
        for k in ("pixel", "4x4"):
            print(f"  {k:5s} rel_l1 Mitsuba {em[k][0]:.4f} (net {em[k][1]:.4f})"
                  f"  ppb {ep[k][0]:.4f} (net {ep[k][1]:.4f})"
                  f"  Mitsuba/ppb raw {row['ratio_raw'][k]:.2f}, net {row['ratio_net'][k]:.2f}")
    if a.json:
        json.dump(rows, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    main()
