"""Equal time, Mitsuba 3 beside ppb at both kernel bandwidths, in one sitting.

For each public scene and budget T: Mitsuba renders for T seconds (as
../shared/tools/equal_time.py does, whose functions this uses), then ppb renders once with
`--time T --bandwidth adaptive --error-layer`. Fixed and adaptive images come from the
same passes (lambda is chosen when the image is written), so the fixed one is recovered
from that one render's layers: fixed = adaptive - narrowing. Both are then at
exactly equal time. Printed per scene and budget: passes, and the rel_l1 of Mitsuba, ppb
fixed and ppb adaptive, per pixel and over 4x4 block means, raw and net of the
reference's own noise, with Mitsuba / ppb. Pixels of emitter_mask.png are left out where
it exists. Set-up as for equal_time.py; run from the project root after
`cargo build --release`:
  python3 tools/equal_time_bandwidth.py [--budgets 60,300] [--scenes fog-box,...] [--json F]
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
sys.path.insert(0, os.path.join(ROOT, "..", "shared", "tools"))
import equal_time as E  # noqa: E402
import mitsuba_scenes as S  # noqa: E402

def both_images(mi, path):
    """The adaptive image of an `--error-layer` EXR and the fixed one of the same passes."""
    bitmap = mi.Bitmap(path)
    names = [f.name for f in bitmap.struct_()]
    data = np.array(bitmap, dtype=np.float64)
    pick = lambda *chans: np.stack([data[..., names.index(c)] for c in chans], axis=-1)
    adaptive = pick("R", "G", "B")
    if "narrowing.R" not in names:
        return adaptive, adaptive
    return adaptive - pick("narrowing.R", "narrowing.G", "narrowing.B"), adaptive


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--budgets", default="60,300")
    ap.add_argument("--scenes", default=",".join(S.ORDER))
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target/release/ppb"))
    ap.add_argument("--chunk", type=int, default=16)
    ap.add_argument("--json")
    a = ap.parse_args()
    mi = S.setup_mitsuba()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.scenes.split(","):
            d = S.scene_dir(name)
            ref = E.load_exr(mi, os.path.join(d, "reference.exr"))
            mp = os.path.join(d, "emitter_mask.png")
            mask = (np.array(mi.Bitmap(mp))[..., 0] > 127) if os.path.exists(mp) else None
            n_px, n_blk = E.reference_noise(d, mask is not None)
            for budget in [float(b) for b in a.budgets.split(",")]:
                mit, spp, _ = E.mitsuba_for(mi, name, budget, a.chunk, ref.shape)
                out, stats = os.path.join(tmp, "ppb.exr"), os.path.join(tmp, "ppb.json")
                scene = os.path.join(ROOT, "scenes", "conformance", name, "scene.toml")
                t0 = time.time()
                subprocess.run([a.ppb, "render", scene, "-o", out, "--time", str(budget), "--quiet",
                                "--bandwidth", "adaptive", "--error-layer", "--stats", stats], check=True)
                secs = time.time() - t0
                fixed, adaptive = both_images(mi, out)
                row = {"scene": name, "budget_s": budget, "mitsuba_spp": spp, "ppb_s": round(secs, 1),
                       "ppb_passes": json.load(open(stats))["passes"],
                       "reference_noise": [round(n_px, 4), round(n_blk, 4)]}
                for key, img in [("mitsuba", mit), ("fixed", fixed), ("adaptive", adaptive)]:
                    e, b = E.rel_l1(img, ref, mask), E.rel_l1(img, ref, mask, 4)
                    row[key] = [round(e, 5), round(b, 5)]
                    row[key + "_net"] = [round(E.net(e, n_px), 5), round(E.net(b, n_blk), 5)]
                for k in ("fixed", "adaptive"):
                    row["mitsuba_over_" + k + "_net"] = [
                        round(m / p, 2) if p > 0 else None
                        for m, p in zip(row["mitsuba_net"], row[k + "_net"])]
                rows.append(row)
                print(json.dumps(row), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
