#!/usr/bin/env python3
"""Save-to-preview latency of `ppb watch`.

Copies a conformance scene into a temp folder, starts `ppb watch` on it at 256x256, lets it
refine, then saves edits the way editors do (write a temp file, rename it over the original)
and times from the rename to the moment ppb reports the rewritten preview (its "preview ...
rewritten: reload N" line is printed right after the EXR and PNG were renamed into place).

Edits: the light (intensity or irradiance scaled), and for grid scenes the VDB (swapped for
another density grid: the first swap builds an octree, swapping back finds it in the cache).

Each edit waits a random 2-4 s of refining first, so it lands at a random point of the pass
in flight (the worker applies reloads between passes).

Usage: tools/watch_latency.py [--ppb target/release/ppb] [--scene fog-box] [--repeats 5]
                              [--light-paths N] [--threads N] [--settle MIN MAX]
"""
import argparse
import os
import random
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Watch:
    """The ppb process and its stderr lines with arrival times."""

    def __init__(self, cmd):
        self.proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        self.lines = []
        self.lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stderr:
            with self.lock:
                self.lines.append((time.monotonic(), line.rstrip("\n")))

    def wait_for(self, pattern, after=0.0, timeout=120.0):
        """Time of the first line matching `pattern` that arrived after `after`."""
        rx = re.compile(pattern)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                for t, line in self.lines:
                    if t >= after and rx.search(line):
                        return t, line
            if self.proc.poll() is not None:
                sys.exit("ppb watch exited:\n" + "\n".join(l for _, l in self.lines))
            time.sleep(0.005)
        sys.exit(f"timed out waiting for /{pattern}/:\n" + "\n".join(l for _, l in self.lines))

    def stop(self):
        self.proc.kill()
        self.proc.wait()


def save_by_rename(path, data):
    tmp = os.path.join(os.path.dirname(path), "." + os.path.basename(path) + ".swp")
    with open(tmp, "wb") as f:
        f.write(data)
    os.rename(tmp, path)
    return time.monotonic()


def scale_light(text, factor):
    """Scales the first [[light]]'s intensity/irradiance/radiance triple."""
    rx = re.compile(r"^((?:intensity|irradiance|radiance)\s*=\s*)\[([^\]]*)\]", re.M)
    m = rx.search(text)
    if not m:
        sys.exit("the scene has no light intensity to edit")
    vals = [float(v) * factor for v in m.group(2).split(",")]
    new = m.group(1) + "[" + ", ".join(f"{v:.6g}" for v in vals) + "]"
    return text[: m.start()] + new + text[m.end():]


def measure(watch, edits, settle):
    """Runs (name, action) edits; returns {name: [seconds]}."""
    out = {}
    reload = 1
    rng = random.Random(1)
    for name, action in edits:
        # Refine a random while, so edits land at random points of the pass in flight.
        time.sleep(rng.uniform(*settle))
        t0 = action()
        reload += 1
        t1, line = watch.wait_for(rf"preview .* reload {reload},", after=t0)
        out.setdefault(name, []).append(t1 - t0)
        print(f"  {name}: {1000 * (t1 - t0):.0f} ms  ({line.strip()})", flush=True)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ppb", default=os.path.join(ROOT, "target", "release", "ppb"))
    ap.add_argument("--scene", default="fog-box", help="conformance scene name")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--light-paths", type=int, help="light paths per pass (default: the scene's)")
    ap.add_argument("--threads", type=int)
    ap.add_argument("--settle", type=float, nargs=2, default=[2.0, 4.0], metavar=("MIN", "MAX"),
                    help="seconds of refining before each edit, drawn uniformly")
    a = ap.parse_args()

    tmp = tempfile.mkdtemp(prefix="ppb-latency-")
    try:
        shutil.copytree(os.path.join(ROOT, "scenes", "common"), os.path.join(tmp, "common"))
        src = os.path.join(ROOT, "scenes", "conformance", a.scene)
        sdir = os.path.join(tmp, "conformance", a.scene)
        shutil.copytree(src, sdir)
        scene = os.path.join(sdir, "scene.toml")
        out = os.path.join(tmp, "out", a.scene + ".exr")
        cmd = [a.ppb, "watch", scene, "-o", out, "--size", "256x256", "--passes", "0",
               "--cache-dir", os.path.join(tmp, "cache")]
        if a.light_paths:
            cmd += ["--light-paths", str(a.light_paths)]
        if a.threads:
            cmd += ["--threads", str(a.threads)]
        print(" ".join(cmd), flush=True)
        w = Watch(cmd)
        w.wait_for(r"preview .* reload 1,")
        text = open(scene).read()
        edits = []
        for i in range(a.repeats):
            factor = 2.0 if i % 2 == 0 else 1.0
            edits.append(("light edit", lambda f=factor: save_by_rename(scene, scale_light(text, f).encode())))
        vdb = os.path.join(sdir, "density.vdb")
        if os.path.exists(vdb):
            original = open(vdb, "rb").read()
            other_name = "cloud-hg" if a.scene != "cloud-hg" else "smoke-grid"
            other = open(os.path.join(ROOT, "scenes", "conformance", other_name, "density.vdb"), "rb").read()
            edits.append(("VDB edit, octree built", lambda: save_by_rename(vdb, other)))
            for i in range(a.repeats - 1):
                data = original if i % 2 == 0 else other
                edits.append(("VDB edit, octree from cache", lambda d=data: save_by_rename(vdb, d)))
        results = measure(w, edits, a.settle)
        passes = [l for _, l in w.lines if "octree built" in l]
        w.stop()
        print(f"\n{a.scene} at 256x256, {os.cpu_count()} cores; save -> rewritten preview:")
        for name, xs in results.items():
            print(f"  {name:<28} median {1000 * statistics.median(xs):6.0f} ms  "
                  f"max {1000 * max(xs):6.0f} ms  (n = {len(xs)})")
        print(f"  octree builds: {len(passes)} (first load + VDB edits whose grid was not cached)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
