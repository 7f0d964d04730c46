"""Adaptive against fixed bandwidth at equal time, against the references.

Fixed and adaptive images of one render come from the same passes (the bandwidth is chosen
when the image is written), so equal passes are equal time: for each scene, `ppb render
--time T` renders the fixed image and records its pass count, then `ppb render --passes N
--bandwidth adaptive` the adaptive one; both are compared with the scene's reference per
pixel and on 4x4 block means (`ppb compare`, no emitter mask). Run from the project root
after `cargo build --release`:
  python3 tools/bandwidth_ab.py [--time 60] [--scenes fog-box,smoke-grid,...]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from radius_split import ROOT, compare  # noqa: E402

SCENES = "fog-box,smoke-grid,cloud-hg,glass-caustic,cloud-sky,fog-near-light"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--time", type=float, default=60.0)
    ap.add_argument("--scenes", default=SCENES)
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target/release/ppb"))
    args = ap.parse_args()
    print("| scene | T (s) | passes | pixel: fixed | adaptive | 4x4: fixed | adaptive |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes.split(","):
            src = os.path.join(ROOT, "scenes/conformance", scene, "scene.toml")
            stats = os.path.join(tmp, "stats.json")
            fixed, adaptive = (os.path.join(tmp, f"{scene}-{b}.exr") for b in ("fixed", "adaptive"))
            subprocess.run([args.ppb, "render", src, "--time", str(args.time), "-o", fixed,
                            "--stats", stats, "--quiet"], check=True)
            passes = json.load(open(stats))["passes"]
            subprocess.run([args.ppb, "render", src, "--passes", str(passes), "--bandwidth",
                            "adaptive", "-o", adaptive, "--quiet"], check=True)
            f, a = compare(args.ppb, fixed, scene), compare(args.ppb, adaptive, scene)
            print(f"| {scene} | {args.time:g} | {passes} | {f[0]:.5f} | {a[0]:.5f} | {f[1]:.5f} | {a[1]:.5f} |",
                  flush=True)


if __name__ == "__main__":
    main()
