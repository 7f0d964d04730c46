"""--target-error against the references: does a render stop near the error it was asked for?

For each public scene and target, `ppb render --target-error E` (per pixel, or on 4x4 block
means where the scene's reference is judged there) renders until its own estimate falls
below E; the image is then compared with the reference (`ppb compare`). Printed per run:
passes, seconds, the estimate when it stopped, the measured rel_l1 raw and net of the
reference's own noise (reference.json; net = sqrt(err^2 - noise^2)), and net / target.
Where the scene has an emitter mask (the pixels that see a light directly), the estimate
leaves those pixels out (and the 4x4 blocks they touch), so the measurement does too, as
`equal_time.py` does. Run from the project root after `cargo build --release`:
  python3 tools/target_error_check.py [--targets 0.02,0.01] [--scenes fog-box,...]
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from radius_split import compare, reference_noise  # noqa: E402
# Scene, metric the target applies to (glass-caustic's reference is judged on blocks).
SCENES = [
    ("fog-box", "pixel"),
    ("smoke-grid", "pixel"),
    ("cloud-hg", "pixel"),
    ("fog-near-light", "pixel"),
    ("fog-near-light", "blocks"),
    ("glass-caustic", "blocks"),
    ("cloud-sky", "pixel"),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", default="0.02,0.01")
    ap.add_argument("--scenes", default=",".join(dict.fromkeys(s for s, _ in SCENES)))
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target/release/ppb"))
    a = ap.parse_args()
    wanted = a.scenes.split(",")
    print(f"{'scene':<15} {'on':<6} {'target':>7} {'passes':>6} {'s':>6} {'estimate':>9} "
          f"{'measured':>9} {'ref noise':>9} {'net':>7} {'net/target':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for scene, on in SCENES:
            if scene not in wanted:
                continue
            noise = reference_noise(scene)
            for t in [float(x) for x in a.targets.split(",")]:
                out = os.path.join(tmp, f"{scene}.exr")
                stats = os.path.join(tmp, f"{scene}.json")
                subprocess.run([a.ppb, "render", os.path.join(ROOT, "scenes/conformance", scene, "scene.toml"),
                                "-o", out, "--target-error", str(t), "--target-on", on,
                                "--stats", stats, "--quiet"], check=True)
                s = json.load(open(stats))
                est = s["estimated_rel_l1"]["pixel" if on == "pixel" else "block"]
                k = 0 if on == "pixel" else 1
                measured = compare(a.ppb, out, scene)[k]
                net = math.sqrt(max(measured ** 2 - noise[k] ** 2, 0.0))
                print(f"{scene:<15} {on:<6} {t:>7.3f} {s['passes']:>6} {s['seconds']['total']:>6.1f} "
                      f"{est:>9.4f} {measured:>9.4f} {noise[k]:>9.4f} {net:>7.4f} {net / t:>10.2f}",
                      flush=True)


if __name__ == "__main__":
    main()
