"""Beam radius R1 at equal time, with the error split into noise and bias.

For each scene and each beam R1 (a multiple of the auto radius, which is 2 pixels at the
medium), `ppb render --time T` renders a copy of the scene with `beam_radius` set, beside
the original so its relative paths hold; the image is compared with the reference per
pixel and on 4x4 block means (`ppb compare`; no emitter mask: the estimate covers the whole
image). The render's own error estimate (`--stats`) is its noise; what the measured error
holds beyond that noise and the reference's own, sqrt(err^2 - noise^2 - ref^2), is the
bias (mostly the kernel's blur). Run on an idle machine from the project root after
`cargo build --release`:
  python3 tools/radius_split.py [--time 60] [--scales 0.75,1,1.5] [--scenes fog-box,...]
"""
import argparse
import json
import math
import os
import re
import subprocess
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["fog-box", "smoke-grid", "cloud-hg", "glass-caustic", "cloud-sky"]


def reference_noise(scene):
    p = os.path.join(ROOT, "tests/data/conformance", scene, "reference.json")
    if not os.path.exists(p):
        p = os.path.join(os.path.dirname(ROOT), "shared/conformance", scene, "reference.json")
    n = json.load(open(p))["noise"]
    return n["rel_l1_halves_over_2"], n["rel_l1_halves_over_2_4x4_block_means"]


def compare(ppb, img, scene):
    ref = os.path.join(ROOT, "tests/data/conformance", scene, "reference.exr")
    out = subprocess.run([ppb, "compare", img, ref, "--block", "4"],
                         capture_output=True, text=True, check=True).stdout
    return (float(re.search(r"^rel_l1\s+([\d.e-]+)", out, re.M).group(1)),
            float(re.search(r"block means\s+([\d.e-]+)", out).group(1)))


def render(ppb, scene_file, out, stats, extra):
    subprocess.run([ppb, "render", scene_file, "-o", out, "--stats", stats, "--quiet"] + extra,
                   check=True)
    return json.load(open(stats))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--time", type=float, default=60.0)
    ap.add_argument("--scales", default="0.75,1,1.5")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target/release/ppb"))
    a = ap.parse_args()
    print(f"{'scene':<14} {'R1 px':>5} {'passes':>6} | {'pixel: err':>10} {'noise':>7} {'bias':>7} | "
          f"{'4x4: err':>9} {'noise':>7} {'bias':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes.split(","):
            src = os.path.join(ROOT, "scenes/conformance", scene, "scene.toml")
            text = open(src).read()
            auto = render(a.ppb, src, os.path.join(tmp, "probe.exr"), os.path.join(tmp, "probe.json"),
                          ["--passes", "1"])["beam_r1"]
            ref = reference_noise(scene)
            for k in [float(x) for x in a.scales.split(",")]:
                body = re.sub(r'^beam_radius\s*=.*$', '', text, flags=re.M)
                body = body.replace("[render]", f"[render]\nbeam_radius = {auto * k}", 1)
                copy = os.path.join(os.path.dirname(src), f".radius-split-{os.getpid()}.toml")
                open(copy, "w").write(body)
                try:
                    out, stats = os.path.join(tmp, "r.exr"), os.path.join(tmp, "r.json")
                    s = render(a.ppb, copy, out, stats, ["--time", str(a.time)])
                finally:
                    os.remove(copy)
                err = compare(a.ppb, out, scene)
                est = s["estimated_rel_l1"]
                cols = []
                for e, n, r in [(err[0], est["pixel"], ref[0]), (err[1], est["block"], ref[1])]:
                    bias = math.sqrt(max(e * e - n * n - r * r, 0.0))
                    cols.append(f"{e:>10.4f} {n:>7.4f} {bias:>7.4f}")
                print(f"{scene:<14} {2 * k:>5.2f} {s['passes']:>6} | {cols[0]} | {cols[1]}", flush=True)


if __name__ == "__main__":
    main()
