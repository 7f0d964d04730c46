"""The fog-near-light light's own pixels: Mitsuba 3 with and without the fog box, and ppb.

The sphere light is cut by the image's top edge: four pixels of row 0 (x = 208..211) see
it. Physically the fog between the camera and the light (about 0.2 m at sigma_t = 0.1)
dims them by 2 %. This renders them with Mitsuba's volpath at max_depth 1 (emission only)
three ways: without the fog box, with a box of sigma_t = 1e-6, and as the reference has
it; then ppb (`--passes 256`), whose sphere light is seen by 4x4 jittered rays a pixel.
Prints each row's four pixels and their sum.

Set-up as for ../shared/tools/equal_time.py; run from the project root after
`cargo build --release`:  python3 tools/emitter_pixels.py [--spp 4096]
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED_TOOLS = os.path.join(ROOT, "..", "shared", "tools")
sys.path.insert(0, SHARED_TOOLS)
import mitsuba_scenes as S  # noqa: E402

SCENE = "fog-near-light"
COLUMNS = slice(208, 212)


def mitsuba_row(mi, spp, fog):
    d = S.build_mitsuba_scene(mi, SCENE, spp=spp, max_depth=1)
    if fog is None:
        d = {k: v for k, v in d.items() if "fog" not in k}
    elif fog != "scene":
        d["medium_fog"]["sigma_t"] = fog
    img = np.array(mi.render(mi.load_dict(d)), dtype=np.float64)
    return img[0, COLUMNS, 0]


def ppb_row(mi, passes):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "ppb.exr")
        scene = os.path.join(ROOT, "scenes/conformance", SCENE, "scene.toml")
        cmd = [os.path.join(ROOT, "target/release/ppb"), "render", scene, "--passes",
               str(passes), "--light-paths", "200", "-o", out]
        subprocess.run(cmd, check=True, capture_output=True)
        return np.array(mi.Bitmap(out), dtype=np.float64)[0, COLUMNS, 0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--passes", type=int, default=256)
    args = ap.parse_args()
    mi = S.setup_mitsuba()
    rows = [
        ("mitsuba, no fog box", mitsuba_row(mi, args.spp, None)),
        ("mitsuba, sigma_t 1e-6", mitsuba_row(mi, args.spp, 1e-6)),
        ("mitsuba, the scene's fog", mitsuba_row(mi, args.spp, "scene")),
        (f"ppb, {args.passes} passes", ppb_row(mi, args.passes)),
    ]
    ref = np.array(mi.Bitmap(os.path.join(ROOT, "tests/data/conformance", SCENE,
                                          "reference.exr")), dtype=np.float64)
    rows.append(("reference (all depths)", ref[0, COLUMNS, 0]))
    for name, row in rows:
        print(f"{name:28s} " + " ".join(f"{v:8.1f}" for v in row) + f"   sum {row.sum():8.1f}")


if __name__ == "__main__":
    main()
