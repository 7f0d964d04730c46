"""Mitsuba 3 reference for the cloud-sky conformance scene (see scene.md).

Conventions: ../../../../../shared/conformance/SPEC.md (= /work/shared/conformance/SPEC.md).
The density grid is read from /work/shared/conformance/cloud-hg/density.npy (the same grid as
cloud-hg; override with --density). sky.exr is made by make_sky.py in this folder.

Usage
  python3 render_reference.py validate [--spp-half 512]
      re-render cloud-hg (directional light) and compare with its shared reference.exr
  python3 render_reference.py render --budget-s 1800 [--work /tmp/cloudsky_acc]
      render 32-spp chunks with seed = chunk index until the time budget is spent (an even
      number of chunks); accumulators are checkpointed in --work
  python3 render_reference.py finalize [--work /tmp/cloudsky_acc]
      write reference.exr, reference.json, reference.png in this folder

Mitsuba 3.9.1, variant llvm_ad_rgb (DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1),
integrator volpath (max_depth 1024, rr_depth 5), independent sampler, box filter.
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SHARED_CLOUD_HG = "/work/shared/conformance/cloud-hg"
DENSITY = os.path.join(SHARED_CLOUD_HG, "density.npy")
LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
VARIANT = "llvm_ad_rgb"
SPP_PER_CHUNK = 32

CAMERA = {"origin": [0.0, 1.0, 5.0], "target": [0.0, 1.1, 0.0], "up": [0.0, 1.0, 0.0],
          "vfov_deg": 40.0, "width": 320, "height": 192}
FLOOR = {"y": 0.0, "xmin": -3.0, "xmax": 3.0, "zmin": -3.0, "zmax": 3.0, "rho": [0.5, 0.5, 0.5]}
MEDIUM = {"box_min": [-1.5, 0.6, -1.0], "box_max": [1.5, 1.8, 1.0], "scale": 20.0,
          "albedo": [0.98, 0.98, 0.98], "g": 0.7}
CLOUD_HG_LIGHT_DIR = list(np.array([0.5, -0.6, -0.4]) / np.linalg.norm([0.5, -0.6, -0.4]))


def setup_mitsuba():
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", LIBLLVM)
    import mitsuba as mi
    mi.set_variant(VARIANT)
    return mi


def _rgb(v):
    return {"type": "rgb", "value": [float(c) for c in v]}


def build_scene(mi, light="sky", density_path=DENSITY, sky_path=None):
    """light: 'sky' (cloud-sky: envmap sky.exr, scale 1, identity to_world) or
    'directional' (cloud-hg: E = 4 W/m^2 travelling along normalize(0.5, -0.6, -0.4))."""
    cam = CAMERA
    T = mi.ScalarTransform4f
    scene = {"type": "scene"}
    scene["integrator"] = {"type": "volpath", "max_depth": 1024, "rr_depth": 5}
    scene["sensor"] = {
        "type": "perspective", "fov": cam["vfov_deg"], "fov_axis": "y",
        "near_clip": 0.01, "far_clip": 1000.0,
        "to_world": T().look_at(origin=cam["origin"], target=cam["target"], up=cam["up"]),
        "sampler": {"type": "independent", "sample_count": SPP_PER_CHUNK, "seed": 0},
        "film": {"type": "hdrfilm", "width": cam["width"], "height": cam["height"],
                 "rfilter": {"type": "box"}, "pixel_format": "rgb",
                 "component_format": "float32", "sample_border": False},
    }
    # floor: Mitsuba 'rectangle' is [-1,1]^2 in local xy with normal +z -> y = 0, normal +Y
    f = FLOOR
    cx, cz = (f["xmin"] + f["xmax"]) / 2, (f["zmin"] + f["zmax"]) / 2
    hx, hz = (f["xmax"] - f["xmin"]) / 2, (f["zmax"] - f["zmin"]) / 2
    m = T([[hx, 0, 0, cx], [0, 0, 1, f["y"]], [0, -hz, 0, cz], [0, 0, 0, 1]])
    scene["floor"] = {"type": "rectangle", "to_world": m,
                      "bsdf": {"type": "twosided",
                               "bsdf": {"type": "diffuse", "reflectance": _rgb(f["rho"])}}}
    # medium: gridvolume puts sample i at (i + 0.5)/n of its unit cube (cell centres),
    # trilinear, clamped at the border; the unit cube is mapped onto [box_min, box_max]
    md = MEDIUM
    dens = np.load(density_path).astype(np.float32)
    assert dens.shape == (96, 96, 96)
    bmin, bmax = md["box_min"], md["box_max"]
    size = [b - a for a, b in zip(bmin, bmax)]
    centre = [(a + b) / 2 for a, b in zip(bmin, bmax)]
    half = [s / 2 for s in size]
    scene["medium_cloud"] = {
        "type": "heterogeneous",
        "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(dens[..., None]),
                    "filter_type": "trilinear", "use_grid_bbox": False,
                    "to_world": T().translate(bmin).scale(size)},
        "scale": md["scale"],
        "albedo": {"type": "constvolume", "value": _rgb(md["albedo"])},
        "phase": {"type": "hg", "g": md["g"]},  # Mitsuba hg: g > 0 = forward scattering
    }
    scene["mediumbox_cloud"] = {"type": "cube", "to_world": T().translate(centre).scale(half),
                                "bsdf": {"type": "null"},
                                "interior": {"type": "ref", "id": "medium_cloud"}}
    if light == "sky":
        scene["sky"] = {"type": "envmap",
                        "filename": sky_path or os.path.join(HERE, "sky.exr"),
                        "scale": 1.0}
    elif light == "directional":
        scene["sun"] = {"type": "directional", "direction": CLOUD_HG_LIGHT_DIR,
                        "irradiance": _rgb([4.0, 4.0, 4.0])}
    else:
        raise ValueError(light)
    return mi.load_dict(scene)


def render_chunk(mi, scene, seed):
    img = mi.render(scene, spp=SPP_PER_CHUNK, seed=seed)
    return np.array(img, dtype=np.float64)[..., :3]


def rel_l1(x, ref):
    return float(np.abs(x - ref).sum() / np.abs(ref).sum())


def block_means(img, b=4):
    h, w, c = img.shape
    return img[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, c).mean(axis=(1, 3))


def read_exr(mi, path):
    return np.array(mi.Bitmap(path), dtype=np.float64)[..., :3]


def write_exr(mi, img, path):
    mi.Bitmap(np.ascontiguousarray(img.astype(np.float32)),
              pixel_format=mi.Bitmap.PixelFormat.RGB).write(path)


def save_preview(mi, img, path):
    a = np.clip(np.asarray(img, dtype=np.float64), 0.0, 1.0) ** (1.0 / 2.2)
    a = (a * 255.0 + 0.5).astype(np.uint8)
    mi.Bitmap(np.ascontiguousarray(a), pixel_format=mi.Bitmap.PixelFormat.RGB).write(path)


def cmd_validate(args):
    mi = setup_mitsuba()
    scene = build_scene(mi, light="directional", density_path=args.density)
    n = args.spp_half // SPP_PER_CHUNK
    t0 = time.time()
    acc = [np.zeros((CAMERA["height"], CAMERA["width"], 3)) for _ in range(2)]
    for k in range(2 * n):
        acc[k % 2] += render_chunk(mi, scene, 1000 + k)  # seeds 1000.. (not the reference's)
    a, b = acc[0] / n, acc[1] / n
    full = (a + b) / 2
    ref = read_exr(mi, os.path.join(SHARED_CLOUD_HG, "reference.exr"))
    res = {"spp_total": 2 * n * SPP_PER_CHUNK, "seconds": round(time.time() - t0, 1),
           "rel_l1_vs_shared_reference": rel_l1(full, ref),
           "own_noise_rel_l1_halves_over_2": rel_l1(a, b) / 2,
           "rel_l1_vs_reference_4x4": rel_l1(block_means(full), block_means(ref)),
           "own_noise_4x4": rel_l1(block_means(a), block_means(b)) / 2,
           "mean_rgb": full.mean(axis=(0, 1)).tolist(),
           "reference_mean_rgb": ref.mean(axis=(0, 1)).tolist()}
    print(json.dumps(res, indent=2))


def _acc_paths(work):
    return os.path.join(work, "acc.npz"), os.path.join(work, "progress.json")


def cmd_render(args):
    mi = setup_mitsuba()
    os.makedirs(args.work, exist_ok=True)
    acc_path, prog_path = _acc_paths(args.work)
    scene = build_scene(mi, light="sky", density_path=args.density)
    shape = (CAMERA["height"], CAMERA["width"], 3)
    sum_a, sum_b, sumsq = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    n_a = n_b = 0
    t0 = time.time()
    chunk_times = []
    k = 0
    while True:
        elapsed = time.time() - t0
        if k % 2 == 0:
            # start a new pair only if it is expected to finish within the budget
            per_chunk = np.median(chunk_times[-20:]) if chunk_times else 0.0
            if (args.max_chunks and k >= args.max_chunks) or \
                    (k > 0 and elapsed + 2 * per_chunk > args.budget_s):
                break
        tc = time.time()
        img = render_chunk(mi, scene, k)
        chunk_times.append(time.time() - tc)
        if not np.all(np.isfinite(img)):
            print("chunk", k, "has non-finite values", file=sys.stderr)
        if k % 2 == 0:
            sum_a += img
            n_a += 1
        else:
            sum_b += img
            n_b += 1
        sumsq += img * img
        k += 1
        if k % 2 == 0 and (k % 20 == 0 or time.time() - t0 > args.budget_s - 60):
            _checkpoint(acc_path, prog_path, sum_a, sum_b, sumsq, n_a, n_b, t0, chunk_times)
    _checkpoint(acc_path, prog_path, sum_a, sum_b, sumsq, n_a, n_b, t0, chunk_times, done=True)
    print("done: %d chunks, %.1f s" % (k, time.time() - t0))


def _checkpoint(acc_path, prog_path, sum_a, sum_b, sumsq, n_a, n_b, t0, chunk_times, done=False):
    tmp = acc_path + ".tmp.npz"
    np.savez(tmp, sum_a=sum_a, sum_b=sum_b, sumsq=sumsq, n_a=n_a, n_b=n_b)
    os.replace(tmp, acc_path)
    prog = {"chunks": n_a + n_b, "wall_seconds": round(time.time() - t0, 1),
            "first_chunk_seconds_incl_jit": round(chunk_times[0], 2) if chunk_times else None,
            "median_chunk_seconds": float(np.median(chunk_times)) if chunk_times else None,
            "done": done}
    with open(prog_path, "w") as fh:
        json.dump(prog, fh)


def cmd_finalize(args):
    mi = setup_mitsuba()
    import drjit as dr
    acc_path, prog_path = _acc_paths(args.work)
    z = np.load(acc_path)
    prog = json.load(open(prog_path))
    n_a, n_b = int(z["n_a"]), int(z["n_b"])
    assert n_a == n_b and n_a > 0
    K = n_a + n_b
    a, b = z["sum_a"] / n_a, z["sum_b"] / n_b
    full = (z["sum_a"] + z["sum_b"]) / K
    assert np.all(np.isfinite(full))
    var = np.maximum(z["sumsq"] / K - full * full, 0.0) * K / (K - 1)  # chunk variance
    se = np.sqrt(var / K)  # standard error of the mean, per pixel and channel
    expected = float(np.sqrt(2 / np.pi) * se.sum() / np.abs(full).sum())
    pix_mean = full.mean(axis=2)
    pix_se = np.sqrt((se * se).mean(axis=2))
    mask = pix_mean > 1e-3 * full.mean()
    rel = pix_se[mask] / pix_mean[mask]
    # pixels that only see the environment map directly (sky or the map's ground band): their
    # chunk spread is tiny (sub-pixel gradient only); noise over the remaining pixels
    env_only = (pix_se / np.maximum(pix_mean, 1e-30)) < 1e-3
    keep = ~env_only
    noise_obj = float(np.abs(a - b)[keep].sum() / np.abs(full[keep]).sum() / 2)
    write_exr(mi, full, os.path.join(HERE, "reference.exr"))
    save_preview(mi, full, os.path.join(HERE, "reference.png"))
    cpu = subprocess.run("lscpu | grep 'Model name'", shell=True, capture_output=True,
                         text=True).stdout.split(":", 1)[-1].strip()
    info = {
        "scene": "cloud-sky",
        "renderer": "Mitsuba 3",
        "mitsuba_version": mi.__version__,
        "drjit_version": dr.__version__,
        "variant": VARIANT,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH"),
        "integrator": {"type": "volpath", "max_depth": 1024, "rr_depth": 5,
                       "note": "unidirectional volumetric path tracer with next-event estimation "
                               "(envmap importance sampling + MIS), delta tracking; Russian "
                               "roulette from depth 5"},
        "sampler": "independent",
        "rfilter": "box",
        "emitter": {"type": "envmap", "filename": "sky.exr", "scale": 1.0,
                    "to_world": "identity"},
        "density": DENSITY,
        "spp": K * SPP_PER_CHUNK,
        "chunks": K,
        "spp_per_chunk": SPP_PER_CHUNK,
        "seeds": "chunk k uses sampler seed 0+k; half A = even k, half B = odd k",
        "wall_seconds": prog["wall_seconds"],
        "first_chunk_seconds_incl_jit": prog["first_chunk_seconds_incl_jit"],
        "machine": "%s, %d CPU cores (nproc; LLVM JIT backend), shared with other work"
                   % (cpu, os.cpu_count()),
        "noise": {
            "rel_l1_halves_over_2": rel_l1(a, b) / 2,
            "rel_l1_halves_over_2_4x4_block_means":
                rel_l1(block_means(a), block_means(b)) / 2,
            "expected_rel_l1_from_chunk_variance": expected,
            "rel_l1_halves_over_2_excluding_direct_env": noise_obj,
            "excluding_direct_env_definition":
                "rel_l1(halfA, halfB)/2 over the %d of %d pixels whose relative standard error "
                "is >= 1e-3; the other %d see only the environment map directly (sky above the "
                "cloud, the map's ground band beyond the floor) and are nearly noise-free"
                % (int(keep.sum()), keep.size, int(env_only.sum())),
            "pixel_rel_std_error": {
                "definition": "per pixel: RMS over R,G,B of the standard error of the pixel's "
                              "mean, estimated from the spread of the %d independent chunks, "
                              "divided by the pixel's mean over R,G,B; over pixels with mean > "
                              "1e-3 * image mean (%d of %d pixels)"
                              % (K, int(mask.sum()), mask.size),
                "median": float(np.median(rel)), "mean": float(rel.mean()),
                "p90": float(np.percentile(rel, 90)), "p99": float(np.percentile(rel, 99)),
                "max": float(rel.max())},
        },
        "mean_rgb": full.mean(axis=(0, 1)).tolist(),
    }
    with open(os.path.join(HERE, "reference.json"), "w") as fh:
        json.dump(info, fh, indent=2)
        fh.write("\n")
    print(json.dumps(info, indent=2))


def main():
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("validate")
    v.add_argument("--spp-half", type=int, default=512)
    r = sub.add_parser("render")
    r.add_argument("--budget-s", type=float, default=1800.0)
    r.add_argument("--max-chunks", type=int, default=0)
    f = sub.add_parser("finalize")
    for p in (v, r, f):
        p.add_argument("--density", default=DENSITY)
        p.add_argument("--work", default="/tmp/cloudsky_acc")
    args = ap.parse_args()
    {"validate": cmd_validate, "render": cmd_render, "finalize": cmd_finalize}[args.cmd](args)


if __name__ == "__main__":
    main()
