"""Radius schedules at equal time, with the error split into noise and bias.

For each scene and each value of one schedule key, `ppb render --time T` renders a copy of
the scene (beside the original, so its relative paths hold) with every radius set
explicitly to the auto value and the swept key changed:
- beam_radius, photon_radius, smooth_photon_radius: a multiple of the auto R1 (the beams'
  2 pixels at the medium, the sharp photons' 1.5 pixels at the floor, the smooth ones 10
  times that);
- alpha (the beams'), photon_alpha: the value itself.
The image is compared with the reference per pixel and on 4x4 block means (`ppb compare`,
without the emitter mask's pixels where the scene has one, as the estimate leaves them
out). The render's own error estimate (`--stats`, noise and kernel bias) is printed beside
the measured error; what the measured error holds beyond the estimated noise and the
reference's own, sqrt(err^2 - noise^2 - ref^2), is the bias. Run on an idle machine from
the project root after `cargo build --release`:
  python3 tools/radius_split.py [--time 60] [--key beam_radius] [--values 0.75,1,1.5]
      [--scenes fog-box,...]
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
RADII = ["beam_radius", "photon_radius", "smooth_photon_radius"]
KEYS = RADII + ["alpha", "photon_alpha"]

def reference_noise(scene):
    """The reference's own rel_l1 (per pixel, 4x4), outside its emitter mask if it says."""
    p = os.path.join(ROOT, "tests/data/conformance", scene, "reference.json")
    if not os.path.exists(p):
        p = os.path.join(os.path.dirname(ROOT), "shared/conformance", scene, "reference.json")
    info = json.load(open(p))
    n = info.get("emitter_mask", {}).get("noise_excluding_mask") or info["noise"]
    return n["rel_l1_halves_over_2"], n["rel_l1_halves_over_2_4x4_block_means"]


def compare(ppb, img, scene, mask=True):
    """rel_l1 per pixel and of 4x4 block means against the reference, without the emitter
    mask's pixels where there is one (and `mask`)."""
    data = os.path.join(ROOT, "tests/data/conformance", scene)
    cmd = [ppb, "compare", img, os.path.join(data, "reference.exr"), "--block", "4"]
    m = os.path.join(data, "emitter_mask.png")
    if mask and os.path.exists(m):
        cmd += ["--mask", m]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return (float(re.search(r"^rel_l1\s+([\d.e-]+)", out, re.M).group(1)),
            float(re.search(r"block means\s+([\d.e-]+)", out).group(1)))


def render(ppb, scene_file, out, stats, extra):
    subprocess.run([ppb, "render", scene_file, "-o", out, "--stats", stats, "--quiet"] + extra,
                   check=True)
    return json.load(open(stats))


def with_settings(text, values):
    """The scene text with these [render] keys set (earlier lines for them removed)."""
    for key in values:
        text = re.sub(rf"^{key}\s*=.*$", "", text, flags=re.M)
    lines = "".join(f"\n{k} = {v}" for k, v in values.items())
    return text.replace("[render]", "[render]" + lines, 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--time", type=float, default=60.0)
    ap.add_argument("--key", default="beam_radius", choices=KEYS)
    ap.add_argument("--values", "--scales", dest="values", default="0.75,1,1.5")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target/release/ppb"))
    a = ap.parse_args()
    print(f"{'scene':<14} {a.key:>20} {'passes':>6} | {'pixel: err':>10} {'noise':>7} {'bias':>7} "
          f"{'est bias':>8} | {'4x4: err':>9} {'noise':>7} {'bias':>7} {'est bias':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes.split(","):
            src = os.path.join(ROOT, "scenes/conformance", scene, "scene.toml")
            text = open(src).read()
            probe = render(a.ppb, src, os.path.join(tmp, "probe.exr"), os.path.join(tmp, "probe.json"),
                           ["--passes", "1"])
            auto = {"beam_radius": probe["beam_r1"], "photon_radius": probe["photon_r1"],
                    "smooth_photon_radius": probe["smooth_photon_r1"]}
            ref = reference_noise(scene)
            for v in [float(x) for x in a.values.split(",")]:
                values = dict(auto)
                values[a.key] = auto[a.key] * v if a.key in RADII else v
                copy = os.path.join(os.path.dirname(src), f".radius-split-{os.getpid()}.toml")
                open(copy, "w").write(with_settings(text, values))
                try:
                    out, stats = os.path.join(tmp, "r.exr"), os.path.join(tmp, "r.json")
                    s = render(a.ppb, copy, out, stats, ["--time", str(a.time)])
                finally:
                    os.remove(copy)
                err = compare(a.ppb, out, scene)
                none = {"pixel": 0.0, "block": 0.0}
                est = s.get("estimated_rel_l1") or {"noise": none}
                bias_est = est.get("bias") or none
                cols = []
                for e, n, r, b in [(err[0], est["noise"]["pixel"], ref[0], bias_est["pixel"]),
                                   (err[1], est["noise"]["block"], ref[1], bias_est["block"])]:
                    bias = math.sqrt(max(e * e - n * n - r * r, 0.0))
                    cols.append(f"{e:>10.5f} {n:>7.4f} {bias:>7.4f} {b:>8.4f}")
                print(f"{scene:<14} {v:>20.3g} {s['passes']:>6} | {cols[0]} | {cols[1]}", flush=True)


if __name__ == "__main__":
    main()
