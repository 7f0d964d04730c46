#!/usr/bin/env python3
"""Writes production-size sparse OpenVDB density files with OpenVDB itself, plus JSON sidecars
holding what a loader must reproduce (counts, bounding box, min/max, sum, probe values).

Files (in --out, default target/large-vdb/ under the repository, git-ignored):

  plume_512.vdb    smoke plume in a 512^3 index box: rises along +y from a small source at
                   y = 0, widens, sways; domain-warped fBm turbulence; thins out with height.
  cloud_1024.vdb   cumulus-like cloud in a 1024^3 index box: a dozen overlapping spheres with
                   a flat base, noise-displaced (cauliflower) edges and a dense core; most of
                   the box is empty.
  cloud_<N>.vdb    with --sizes: the same cloud at N^3 (N a multiple of 8). Every size samples
                   the same world-space function at its voxel centres, so cloud_64 ...
                   cloud_1024 are one cloud at several resolutions; cloud_1024 of the series
                   is the cloud_1024.vdb above (one file).

Grid conventions (every file): one FloatGrid named "density", grid class fog volume,
background 0, values in [0, 1] written as 32-bit floats; a voxel is active exactly when its
value is >= --threshold (default 1e-3), every smaller value is written as inactive background.
The index box is [0, N)^3; voxel size 4 m / N; the linear transform puts voxel ijk's value at
world ((i + 0.5) v - 2, (j + 0.5) v, (k + 0.5) v - 2), so the N^3 cells exactly fill the box
[-2, 2] x [0, 4] x [-2, 2] m: bottom at y = 0, centred in x and z, +Y up, metres.
OpenVDB's own writer chooses the file's compression (the library default; the sidecar records
what the file's metadata says, e.g. "blosc + active values").

Each <name>.vdb gets <name>.json beside it: generation parameters, resolution, voxel size,
index_to_world (row-major 4x4, OpenVDB row-vector convention: translation in the last row),
active voxel count / active index bbox / min-max of active values / leaf and tile counts as
reported by OpenVDB, the float64 sum of all active values computed from the numpy chunks,
probes read back through grid.getConstAccessor(), a re-read of the written file, the
OpenVDB version used, generation wall time, file size and peak RSS.

Generation runs in slabs along x (--slab voxels thick); within a slab only 8^3 bricks that
can hold density (a conservative bound on each model's support) are evaluated, with numpy,
then the slab is copied into the grid with grid.copyFromArray(slab, ijk, tolerance=0). No
dense N^3 array is ever allocated: peak memory is the grid plus one slab (about 0.9 GiB
for cloud_1024). Noise is seeded value noise on a 64^3 random lattice with smoothstep-
trilinear interpolation, summed over rotated octaves (fBm) and used for domain warping.
Output depends only on the parameters (and the numpy build's float32 rounding), not on --slab.

A rerun skips a file whose .vdb and .json exist with matching parameters and file size
("up to date"); --force rewrites. Files are written under a temporary name and renamed.

OpenVDB: any of `import openvdb` (OpenVDB >= 11 and Blender's bpy wheel), `import pyopenvdb`
(OpenVDB <= 10, e.g. Debian's python3-openvdb) works. Blender's bpy wheel ships the module
inside bpy/<version>/python/lib/python3.X/site-packages; the script finds it there itself.

Examples:
  ~/.pyenv/versions/3.13.0/bin/python tools/make_large_vdbs.py           # plume_512, cloud_1024
  ~/.pyenv/versions/3.13.0/bin/python tools/make_large_vdbs.py --sizes 64 128 256 512 1024
  /usr/bin/python3 tools/make_large_vdbs.py --only cloud_256 --out /tmp/vdb   # Debian OpenVDB 10
"""
import argparse
import glob
import importlib
import importlib.util
import json
import math
import os
import platform
import resource
import sys
import time

import numpy as np

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
DEFAULT_OUT = os.path.join(ROOT, "target", "large-vdb")
EXTENT = 4.0  # metres across the box, every axis
BRICK = 8  # culling brick edge in voxels (= an OpenVDB leaf)
# Bump when a density function or the noise changes: a rerun then regenerates every file.
MODEL_VERSION = 1
MODELS = ("plume", "cloud")
DEFAULT_TARGETS = ("plume_512", "cloud_1024")


def log(msg):
    print(msg, file=sys.stderr, flush=True)


# ------------------------------------------------------------------ OpenVDB import

def import_openvdb():
    """Returns (module, import name, where it was found)."""
    for name in ("openvdb", "pyopenvdb"):
        try:
            mod = importlib.import_module(name)
            return mod, name, mod.__file__
        except ImportError:
            pass
    # Blender's bpy wheel: site-packages/bpy/<ver>/python/lib/python3.X/site-packages/openvdb*.so
    spec = importlib.util.find_spec("bpy")
    if spec is not None and spec.submodule_search_locations:
        for base in spec.submodule_search_locations:
            pat = os.path.join(base, "*", "python", "lib", "python3*", "site-packages", "openvdb*")
            for hit in sorted(glob.glob(pat)):
                sys.path.append(os.path.dirname(hit))
                try:
                    mod = importlib.import_module("openvdb")
                    return mod, "openvdb", mod.__file__
                except ImportError:
                    sys.path.pop()
    sys.exit("error: no OpenVDB python module: install python3-openvdb (Debian: import pyopenvdb) "
             "or the bpy wheel (pip install bpy), or put openvdb on PYTHONPATH")


# ------------------------------------------------------------------ noise

class ValueNoise:
    """Seeded value noise: uniform [0, 1) values on a periodic 64^3 lattice, interpolated
    trilinearly with smoothstep weights. float32 in, float32 out, fully vectorised."""

    P = 64

    def __init__(self, seed):
        self.table = np.random.default_rng(seed).random(self.P ** 3, dtype=np.float32)
        # An orthonormal matrix that turns each octave's lattice against the previous one
        # (hides the axis-aligned lattice); fixed, independent of the seed.
        a, b = 0.61, 0.93
        rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
        ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
        self.rot = (ry @ rx).astype(np.float32)

    def __call__(self, x, y, z):
        P, m, t = self.P, self.P - 1, self.table
        fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
        tx, ty, tz = x - fx, y - fy, z - fz
        ix, iy, iz = fx.astype(np.int32), fy.astype(np.int32), fz.astype(np.int32)
        x0 = (ix & m) * (P * P)
        x1 = ((ix + 1) & m) * (P * P)
        y0 = (iy & m) * P
        y1 = ((iy + 1) & m) * P
        z0 = iz & m
        z1 = (iz + 1) & m
        sx = tx * tx * (3.0 - 2.0 * tx)
        sy = ty * ty * (3.0 - 2.0 * ty)
        sz = tz * tz * (3.0 - 2.0 * tz)
        out = None
        for xa, wx in ((x0, None), (x1, sx)):
            row = None
            for ya, wy in ((y0, None), (y1, sy)):
                a = xa + ya
                c0 = t.take(a + z0)
                c1 = t.take(a + z1)
                c0 += sz * (c1 - c0)
                row = c0 if row is None else row + wy * (c0 - row)
            out = row if out is None else out + wx * (row - out)
        return out

    def fbm(self, x, y, z, octaves, freq, offset=0.0, gain=0.5, lacunarity=2.0):
        """Sum of `octaves` rotated octaves, normalised to [0, 1] (mean about 0.5)."""
        r = self.rot
        px, py, pz = x * freq + offset, y * freq + offset * 0.7, z * freq - offset * 1.3
        total, amp, norm = None, 1.0, 0.0
        for o in range(octaves):
            n = self(px, py, pz)
            total = n if total is None else total + np.float32(amp) * n
            norm += amp
            amp *= gain
            if o + 1 < octaves:
                px, py, pz = (lacunarity * (r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz) + 5.17,
                              lacunarity * (r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz) + 11.3,
                              lacunarity * (r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz) + 23.9)
        return total * np.float32(1.0 / norm)


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ------------------------------------------------------------------ models
# A model maps world points (float32 arrays, metres) to density in [0, 1] (before the
# threshold), and bounds its support: may_hold(cx, cy, cz, h) is False only where no point
# within distance h of (cx, cy, cz) can have density > 0.

class Cloud:
    """Cumulus: union of spheres (signed distance), flat base, domain-warped and
    fBm-displaced surface, density 1 - exp(-depth / 0.14 m) times a gentle internal noise."""

    BLOBS = [  # centre x, y, z, radius (m)
        (0.00, 1.55, 0.00, 0.68),
        (-0.72, 1.30, 0.22, 0.49),
        (0.78, 1.32, -0.18, 0.51),
        (0.22, 1.28, 0.72, 0.42),
        (-0.30, 1.22, -0.66, 0.42),
        (0.18, 2.25, 0.06, 0.49),
        (-0.38, 2.70, -0.12, 0.36),
        (0.55, 2.02, 0.38, 0.37),
        (-0.62, 2.02, -0.30, 0.34),
        (-1.30, 1.02, -0.32, 0.31),
        (1.36, 1.06, 0.42, 0.29),
        (0.02, 3.10, 0.10, 0.24),
    ]
    BASE_Y = 0.80  # flat bottom
    WARP = 0.06  # per-axis warp amplitude (m)
    DISP = 0.20  # surface displacement amplitude (m)
    DEPTH = 0.14  # e-folding depth of the density inside the surface (m)

    def __init__(self, seed):
        self.noise = ValueNoise(seed)
        b = np.array(self.BLOBS, dtype=np.float32)
        self.c, self.r = b[:, :3], b[:, 3]

    def sdf(self, x, y, z):
        d = None
        for (cx, cy, cz), r in zip(self.c, self.r):
            di = np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) - r
            d = di if d is None else np.minimum(d, di)
        return d

    def may_hold(self, cx, cy, cz, h):
        margin = self.WARP * math.sqrt(3.0) + self.DISP
        return self.sdf(cx, cy, cz) - h < margin

    def density(self, x, y, z):
        n = self.noise
        w = np.float32(2.0 * self.WARP)
        qx = x + w * (n.fbm(x, y, z, 2, 1.3, offset=17.0) - 0.5)
        qy = y + w * (n.fbm(x, y, z, 2, 1.3, offset=41.0) - 0.5)
        qz = z + w * (n.fbm(x, y, z, 2, 1.3, offset=73.0) - 0.5)
        f = n.fbm(qx, qy, qz, 5, 2.2)
        # billowy: sharpen the noise's crests so the surface grows rounded cauliflower lumps
        bil = 1.0 - np.abs(2.0 * f - 1.0)
        depth = -self.sdf(qx, qy, qz) + np.float32(self.DISP) * (2.0 * bil - 1.0)
        depth = np.minimum(depth, (y - np.float32(self.BASE_Y)) * 0.8)
        core = 1.0 - np.exp(np.maximum(depth, 0.0) * np.float32(-1.0 / self.DEPTH))
        dens = core * (0.75 + 0.5 * (f - 0.5))
        return np.where(depth > 0.0, np.clip(dens, 0.0, 1.0), 0.0).astype(np.float32)


class Plume:
    """Rising smoke: a widening column about a swaying axis, radius 0.15 + 0.37 y m,
    domain warp growing with height, fBm-displaced edge, fBm-modulated interior, density
    fading with height and to 0 near the top of the box."""

    R0, R1 = 0.15, 0.37  # radius(y) = R0 + R1 y
    DISP = 0.16  # edge displacement amplitude (m)
    SWAY_SLOPE = 0.16  # >= |d axis / dy|
    TOP = 3.95  # density is 0 above this height

    def __init__(self, seed):
        self.noise = ValueNoise(seed)

    @staticmethod
    def warp_amp(y):
        return 0.04 + 0.08 * y  # per-axis (m)

    @staticmethod
    def axis(y):
        return 0.12 * np.sin(1.1 * y + 0.3), 0.10 * np.sin(0.8 * y + 2.0)

    def g(self, x, y, z):
        """Distance-like: radial distance to the axis minus the radius (m)."""
        ax, az = self.axis(y)
        return np.sqrt((x - ax) ** 2 + (z - az) ** 2) - (self.R0 + self.R1 * y)

    def may_hold(self, cx, cy, cz, h):
        lip = math.sqrt(1.0 + (self.SWAY_SLOPE + self.R1) ** 2)  # Lipschitz bound of g
        wy = np.minimum(cy + h, EXTENT)
        reach = h + self.warp_amp(wy) * math.sqrt(3.0)
        return (self.g(cx, cy, cz) - lip * reach < self.DISP) & (cy - h < self.TOP)

    def density(self, x, y, z):
        n = self.noise
        w = (2.0 * self.warp_amp(y)).astype(np.float32)
        qx = x + w * (n.fbm(x, y, z, 3, 1.1, offset=7.0) - 0.5)
        qy = y + w * (n.fbm(x, y, z, 3, 1.1, offset=29.0) - 0.5)
        qz = z + w * (n.fbm(x, y, z, 3, 1.1, offset=53.0) - 0.5)
        # the flow rises: stretch the fine noise along y so wisps look drawn upwards
        f = n.fbm(qx, qy * 0.6 - 0.2 * y, qz, 5, 2.6, offset=3.0)
        inside = -self.g(qx, qy, qz) + np.float32(self.DISP) * (2.0 * f - 1.0)
        rad = self.R0 + self.R1 * y
        s = np.clip(inside / rad, 0.0, 1.0)
        prof = s * (2.0 - s)  # 0 at the edge, 1 on the axis
        mod = np.clip(0.2 + 2.4 * (f - 0.4), 0.12, 1.0)
        fade = np.exp(-0.32 * y) * (1.0 - smoothstep(3.3, self.TOP, y))
        dens = 0.98 * prof * mod * fade
        return np.where(inside > 0.0, np.clip(dens, 0.0, 1.0), 0.0).astype(np.float32)


def make_model(name, seed):
    return {"plume": Plume, "cloud": Cloud}[name](seed)


# ------------------------------------------------------------------ generation

def parse_target(name):
    try:
        model, n = name.rsplit("_", 1)
        n = int(n)
    except ValueError:
        raise SystemExit(f"error: bad name {name!r}: expected MODEL_N, e.g. cloud_256")
    if model not in MODELS:
        raise SystemExit(f"error: bad name {name!r}: model must be one of {', '.join(MODELS)}")
    if n < BRICK or n % BRICK:
        raise SystemExit(f"error: bad name {name!r}: N must be a positive multiple of {BRICK}")
    return model, n


def index_to_world(n):
    v = EXTENT / n
    t = (-EXTENT / 2 + v / 2, v / 2, -EXTENT / 2 + v / 2)
    return [[v, 0.0, 0.0, 0.0], [0.0, v, 0.0, 0.0], [0.0, 0.0, v, 0.0], [t[0], t[1], t[2], 1.0]]


def world_coords(idx, n):
    """World coordinate (float32) of voxel centres along one axis, same for every axis but the
    y offset: x = (i + 0.5) * 4/N - 2; y = (j + 0.5) * 4/N."""
    return (idx.astype(np.float64) + 0.5) * (EXTENT / n)


def generate(vdb, model_name, n, seed, threshold, slab):
    """Builds the grid slab by slab; returns (grid, stats from the numpy values)."""
    model = make_model(model_name, seed)
    grid = vdb.FloatGrid(0.0)
    grid.name = "density"
    grid.gridClass = getattr(getattr(vdb, "GridClass", None), "FOG_VOLUME", "fog volume")
    grid.transform = vdb.createLinearTransform(index_to_world(n))
    v = EXTENT / n
    half = EXTENT / 2
    slab = max(BRICK, min(n, slab - slab % BRICK))
    nb = n // BRICK
    # local voxel offsets inside a brick, (512,) each
    lo = np.indices((BRICK, BRICK, BRICK)).reshape(3, -1).astype(np.int32)
    # brick centres along y and z for a slab (same for every slab)
    bj, bk = np.meshgrid(np.arange(nb), np.arange(nb), indexing="ij")
    bj, bk = bj.ravel().astype(np.int32), bk.ravel().astype(np.int32)
    cyz_y = ((bj * BRICK + (BRICK - 1) / 2.0 + 0.5) * v).astype(np.float32)
    cyz_z = ((bk * BRICK + (BRICK - 1) / 2.0 + 0.5) * v - half).astype(np.float32)
    hdiag = np.float32(math.sqrt(3.0) * (BRICK - 1) / 2.0 * v * 1.0001 + 1e-6)
    batch_bricks = max(1, (1 << 20) // BRICK ** 3)  # about 1M points per evaluation batch
    rng = np.random.default_rng(seed + 12345)

    st = {"count": 0, "sum": 0.0, "min": math.inf, "max": -math.inf, "argmin": None,
          "argmax": None, "bbox_min": [n, n, n], "bbox_max": [-1, -1, -1],
          "samples": [], "zero_samples": [], "bricks_evaluated": 0, "bricks_total": nb ** 3}
    buf = np.zeros((slab, n, n), dtype=np.float32)
    t0 = time.time()
    nslabs = (n + slab - 1) // slab
    for s in range(nslabs):
        x0 = s * slab
        sw = min(slab, n - x0)
        sbi = np.arange(x0 // BRICK, (x0 + sw) // BRICK, dtype=np.int32)
        cx_list = ((sbi * BRICK + (BRICK - 1) / 2.0 + 0.5) * v - half).astype(np.float32)
        cand = []
        for bi, cx in zip(sbi, cx_list):
            keep = model.may_hold(np.full_like(cyz_y, cx), cyz_y, cyz_z, hdiag)
            idx = np.nonzero(keep)[0]
            cand.append(np.stack([np.full(idx.size, bi, np.int32), bj[idx], bk[idx]], axis=1))
        cand = np.concatenate(cand) if cand else np.zeros((0, 3), np.int32)
        st["bricks_evaluated"] += len(cand)
        smin, smax = [n, n, n], [-1, -1, -1]
        for b0 in range(0, len(cand), batch_bricks):
            cb = cand[b0:b0 + batch_bricks]
            ii = (cb[:, 0:1] * BRICK + lo[0][None, :]).ravel()
            jj = (cb[:, 1:2] * BRICK + lo[1][None, :]).ravel()
            kk = (cb[:, 2:3] * BRICK + lo[2][None, :]).ravel()
            x = (world_coords(ii, n) - half).astype(np.float32)
            y = world_coords(jj, n).astype(np.float32)
            z = (world_coords(kk, n) - half).astype(np.float32)
            d = model.density(x, y, z)
            d[d < threshold] = 0.0
            nz = np.nonzero(d)[0]
            if nz.size:
                vals = d[nz]
                gi, gj, gk = ii[nz], jj[nz], kk[nz]
                buf[gi - x0, gj, gk] = vals
                st["count"] += int(nz.size)
                st["sum"] += float(np.sum(vals, dtype=np.float64))
                a_min, a_max = int(np.argmin(vals)), int(np.argmax(vals))
                if vals[a_min] < st["min"]:
                    st["min"] = float(vals[a_min])
                    st["argmin"] = [int(gi[a_min]), int(gj[a_min]), int(gk[a_min])]
                if vals[a_max] > st["max"]:
                    st["max"] = float(vals[a_max])
                    st["argmax"] = [int(gi[a_max]), int(gj[a_max]), int(gk[a_max])]
                for ax, arr in enumerate((gi, gj, gk)):
                    smin[ax] = min(smin[ax], int(arr.min()))
                    smax[ax] = max(smax[ax], int(arr.max()))
                r = int(rng.integers(nz.size))
                st["samples"].append(([int(gi[r]), int(gj[r]), int(gk[r])], float(vals[r])))
            zr = np.nonzero(d == 0.0)[0]
            if zr.size:
                r = int(zr[rng.integers(zr.size)])
                st["zero_samples"].append([int(ii[r]), int(jj[r]), int(kk[r])])
        if smax[0] >= 0:
            sub = np.ascontiguousarray(buf[smin[0] - x0:smax[0] - x0 + 1, smin[1]:smax[1] + 1,
                                           smin[2]:smax[2] + 1])
            grid.copyFromArray(sub, ijk=(smin[0], smin[1], smin[2]), tolerance=0.0)
            del sub
            buf[smin[0] - x0:smax[0] - x0 + 1, smin[1]:smax[1] + 1, smin[2]:smax[2] + 1] = 0.0
            for ax in range(3):
                st["bbox_min"][ax] = min(st["bbox_min"][ax], smin[ax])
                st["bbox_max"][ax] = max(st["bbox_max"][ax], smax[ax])
        el = time.time() - t0
        log(f"  slab {s + 1}/{nslabs} x {x0}..{x0 + sw - 1}: {len(cand)} of {sw // BRICK * nb * nb} "
            f"bricks evaluated, {st['count']:,} active so far, {el:.1f} s"
            f"{'' if s + 1 == nslabs else f', ~{el / (s + 1) * (nslabs - s - 1):.0f} s left'}")
    del buf
    if hasattr(grid, "prune"):
        grid.prune(0.0)
    return grid, st


def pick_probes(grid, st, n, seed):
    """About ten probe voxels: max, min, random active ones, inactive ones inside the active
    bbox, the index-box corners and one outside the box; read back through the accessor."""
    rng = np.random.default_rng(seed + 999)
    want = []
    if st["argmax"]:
        want.append(("max", st["argmax"], st["max"]))
        want.append(("min", st["argmin"], st["min"]))
    samples = st["samples"]
    for i in rng.choice(len(samples), size=min(5, len(samples)), replace=False) if samples else []:
        want.append(("random active", samples[int(i)][0], samples[int(i)][1]))
    zs = [z for z in st["zero_samples"]
          if all(st["bbox_min"][a] <= z[a] <= st["bbox_max"][a] for a in range(3))]
    if zs:
        want.append(("inactive inside the active bbox", zs[int(rng.integers(len(zs)))], 0.0))
    want.append(("index box corner", [0, 0, 0], None))
    want.append(("index box corner", [n - 1, n - 1, n - 1], None))
    want.append(("outside the index box", [n + 100, n // 2, -7], 0.0))
    acc = grid.getConstAccessor()
    probes = []
    for what, ijk, expect in want:
        val = float(acc.getValue(tuple(ijk)))
        on = bool(acc.isValueOn(tuple(ijk)))
        if expect is not None and (val != expect or on != (expect != 0.0)):
            raise SystemExit(f"error: probe {ijk} ({what}): OpenVDB has {val} (active {on}), "
                             f"numpy had {expect}")
        if expect is None and on != (val != 0.0):
            raise SystemExit(f"error: probe {ijk}: OpenVDB value {val} but active {on}")
        w = grid.transform.indexToWorld(tuple(ijk))
        probes.append({"ijk": list(ijk), "value": val, "active": on,
                       "world": [float(c) for c in w], "what": what})
    return probes


def params_for(model, n, seed, threshold):
    return {"model": model, "resolution": n, "seed": seed, "threshold": threshold,
            "extent_m": EXTENT, "model_version": MODEL_VERSION}


def up_to_date(vdb_path, json_path, params):
    try:
        with open(json_path) as f:
            side = json.load(f)
        return side.get("params") == params and os.path.getsize(vdb_path) == side.get("file_size")
    except (OSError, ValueError):
        return False


def to_json(obj, ind=""):
    """JSON with one key per line, but lists of numbers (and small flat objects such as a
    probe) on one line, like the sidecars in tests/data/vdb/."""
    flat = json.dumps(obj)
    if not isinstance(obj, (dict, list)) or (len(flat) <= 160 and flat.count("{") <= 1) \
            or (isinstance(obj, list) and all(not isinstance(v, dict) for v in obj) and len(flat) <= 140):
        return flat
    sub = ind + " "
    if isinstance(obj, dict):
        items = [f"{sub}{json.dumps(k)}: {to_json(v, sub)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + ind + "}"
    return "[\n" + ",\n".join(sub + to_json(v, sub) for v in obj) + "\n" + ind + "]"


def write_json_atomic(path, obj):
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        f.write(to_json(obj) + "\n")
    json.loads(open(tmp).read())  # it parses
    os.replace(tmp, path)


def verify_file(vdb, path, probes, avc):
    """Re-reads the written file with OpenVDB; compares the count and the probes."""
    t0 = time.time()
    g2 = vdb.read(path, "density")
    readback = {"active_voxel_count": int(g2.activeVoxelCount()),
                "active_index_bbox": [list(c) for c in g2.evalActiveVoxelBoundingBox()],
                "min_max_active": [float(c) for c in g2.evalMinMax()],
                "metadata": {k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in sorted(dict(g2.metadata).items())}}
    acc2 = g2.getConstAccessor()
    bad = [p for p in probes if float(acc2.getValue(tuple(p["ijk"]))) != p["value"]
           or bool(acc2.isValueOn(tuple(p["ijk"]))) != p["active"]]
    readback["probes_equal"] = not bad
    readback["seconds"] = round(time.time() - t0, 3)
    if bad or readback["active_voxel_count"] != avc:
        raise SystemExit(f"error: the re-read file {path} differs: {readback}")
    return readback


def build(vdb, vdb_name, vdb_where, name, args):
    model, n = parse_target(name)
    vdb_path = os.path.join(args.out, name + ".vdb")
    json_path = os.path.join(args.out, name + ".json")
    params = params_for(model, n, args.seed, args.threshold)
    if not args.force and up_to_date(vdb_path, json_path, params):
        log(f"{name}: up to date ({vdb_path})")
        return None
    log(f"{name}: {model}, {n}^3 voxels of {EXTENT / n * 1000:.3f} mm, slabs of {args.slab}")
    t0 = time.time()
    grid, st = generate(vdb, model, n, args.seed, args.threshold, args.slab)
    t_gen = time.time() - t0

    avc = int(grid.activeVoxelCount())
    alvc = int(grid.activeLeafVoxelCount())
    bbox = grid.evalActiveVoxelBoundingBox()
    mm = grid.evalMinMax()
    errs = []
    if avc != st["count"]:
        errs.append(f"active voxels: OpenVDB {avc}, numpy {st['count']}")
    if st["count"]:
        if [list(bbox[0]), list(bbox[1])] != [st["bbox_min"], st["bbox_max"]]:
            errs.append(f"active bbox: OpenVDB {bbox}, numpy {st['bbox_min']}..{st['bbox_max']}")
        if (float(mm[0]), float(mm[1])) != (st["min"], st["max"]):
            errs.append(f"min/max: OpenVDB {mm}, numpy {st['min']}, {st['max']}")
    if errs:
        raise SystemExit(f"error: {name}: OpenVDB disagrees with the numpy values: " + "; ".join(errs))
    probes = pick_probes(grid, st, n, args.seed)
    leaf_count = int(grid.leafCount()) if hasattr(grid, "leafCount") else None
    non_leaf = int(grid.nonLeafCount()) if hasattr(grid, "nonLeafCount") else None
    mem = int(grid.memUsage()) if hasattr(grid, "memUsage") else None
    vs = grid.transform.voxelSize()

    os.makedirs(args.out, exist_ok=True)
    tmp = os.path.join(args.out, f".{name}.{os.getpid()}.vdb.tmp")
    t1 = time.time()
    try:
        vdb.write(tmp, [grid], metadata={"creator": "ppb tools/make_large_vdbs.py",
                                          "description": f"procedural {model} ({name})"})
        t_write = time.time() - t1
        del grid
        readback = verify_file(vdb, tmp, probes, avc) if not args.no_verify else None
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise

    size = os.path.getsize(tmp)
    if os.path.exists(json_path):
        os.remove(json_path)  # no stale sidecar beside a new file, even if we die right here
    os.replace(tmp, vdb_path)
    total = time.time() - t0
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    side = {
        "file": name + ".vdb",
        "params": params,
        "generator": "tools/make_large_vdbs.py",
        "written_by": f"OpenVDB {'.'.join(map(str, vdb.LIBRARY_VERSION))} python module "
                      f"'{vdb_name}' (file format {getattr(vdb, 'FILE_FORMAT_VERSION', '?')})",
        "openvdb_library_version": list(vdb.LIBRARY_VERSION),
        "openvdb_file_format_version": getattr(vdb, "FILE_FORMAT_VERSION", None),
        "openvdb_module_path": vdb_where,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "grid": {"name": "density", "value_type": "float", "grid_class": "fog volume",
                 "background": 0.0, "save_float_as_half": False},
        "resolution": n,
        "index_box": {"min": [0, 0, 0], "max": [n - 1] * 3, "inclusive": True},
        "world_box_m": {"min": [-EXTENT / 2, 0.0, -EXTENT / 2], "max": [EXTENT / 2, EXTENT, EXTENT / 2],
                        "note": "cell faces of the index box; voxel ijk's value sits at world(ijk), its cell centre"},
        "voxel_size": [float(c) for c in vs],
        "index_to_world_row_major_4x4": index_to_world(n),
        "index_to_world_note": "OpenVDB row-vector convention: world = [i j k 1] * M (translation in the last row)",
        "active_voxel_count": avc,
        "active_leaf_voxel_count": alvc,
        "active_tile_voxel_count": avc - alvc,
        "leaf_count": leaf_count,
        "non_leaf_count": non_leaf,
        "active_index_bbox": {"min": list(bbox[0]), "max": list(bbox[1]), "inclusive": True},
        "min_max_active": [float(mm[0]), float(mm[1])],
        "sum_active_float64": st["sum"],
        "mean_active": st["sum"] / avc if avc else None,
        "active_fraction_of_index_box": avc / n ** 3,
        "threshold_note": f"values < {args.threshold} are inactive background 0; every active value is >= {args.threshold}",
        "probes": probes,
        "grid_mem_usage_bytes": mem,
        "readback": readback,
        "file_size": size,
        "generation_seconds": round(t_gen, 3),
        "write_seconds": round(t_write, 3),
        "total_seconds": round(total, 3),
        "bricks_evaluated": st["bricks_evaluated"],
        "bricks_total": st["bricks_total"],
        "peak_rss_mib_of_process_so_far": round(peak_kib / 1024.0, 1),
    }
    write_json_atomic(json_path, side)
    log(f"{name}: {avc:,} active voxels, {leaf_count} leaves, bbox {list(bbox[0])}..{list(bbox[1])}, "
        f"min/max {mm[0]:.6g}/{mm[1]:.6g}, {size / 2 ** 20:.1f} MiB, generation {t_gen:.1f} s, "
        f"write {t_write:.1f} s, total {total:.1f} s, peak RSS {peak_kib / 1024:.0f} MiB -> {vdb_path}")
    return side


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=DEFAULT_OUT,
                    help="output folder (default: %(default)s)")
    ap.add_argument("--sizes", nargs="+", metavar="N", default=None,
                    help="write the cloud at these resolutions (cloud_N.vdb, N a multiple of 8; "
                         "commas or spaces), e.g. --sizes 64 128 256 512 1024; plume_512 is "
                         "written too unless --only is given (default: 1024 only)")
    ap.add_argument("--only", action="append", metavar="NAME", default=None,
                    help="write only this file, MODEL_N (e.g. plume_512, cloud_256; any N that is a "
                         "multiple of 8); repeatable")
    ap.add_argument("--slab", type=int, default=32,
                    help="slab thickness along x in voxels, a multiple of 8 (default: %(default)s); "
                         "does not change the output")
    ap.add_argument("--seed", type=int, default=1, help="noise seed (default: %(default)s)")
    ap.add_argument("--threshold", type=float, default=1e-3,
                    help="values below this are inactive background (default: %(default)s)")
    ap.add_argument("--force", action="store_true", help="rewrite files even if up to date")
    ap.add_argument("--no-verify", action="store_true",
                    help="skip re-reading each written file with OpenVDB")
    args = ap.parse_args()

    if args.only:
        targets = list(args.only)
    else:
        sizes = [1024]
        if args.sizes:
            sizes = [int(t) for s in args.sizes for t in s.split(",") if t.strip()]
        targets = ["plume_512"] + [f"cloud_{s}" for s in sizes]
    for t in targets:
        parse_target(t)  # validate every name before spending minutes on the first
    vdb, vdb_name, where = import_openvdb()
    log(f"OpenVDB {'.'.join(map(str, vdb.LIBRARY_VERSION))} via 'import {vdb_name}' ({where}); "
        f"numpy {np.__version__}; writing {', '.join(targets)} to {args.out}")
    for t in dict.fromkeys(targets):
        build(vdb, vdb_name, where, t, args)
    sys.stdout.flush()
    sys.stderr.flush()
    # OpenVDB 12+'s nanobind bindings print "leaked instance" warnings at interpreter exit;
    # every file is closed and renamed by now, so leave without the interpreter's teardown.
    os._exit(0)


if __name__ == "__main__":
    main()
