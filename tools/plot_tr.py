#!/usr/bin/env python3
"""Plots `ppb bench-tr --csv` output: rel_l1 vs passes and vs seconds (log-log), one row
per scene and metric (whole image, media region), one colour per configuration. Needs Pillow (pip install pillow).
Usage: tools/plot_tr.py bench.csv out.png"""
import csv
import math
import sys
from collections import defaultdict

from PIL import Image, ImageDraw

COLOURS = [(220, 50, 47), (181, 137, 0), (38, 139, 210), (133, 153, 0), (108, 113, 196), (42, 161, 152)]
W, H, M = 460, 300, 60


def panel(draw, ox, oy, curves, xkey, title):
    xs = [p[xkey] for c in curves.values() for p in c]
    ys = [p[2] for c in curves.values() for p in c]
    x0, x1 = math.log10(min(xs)), math.log10(max(xs))
    y0, y1 = math.log10(min(ys)) - 0.05, math.log10(max(ys)) + 0.05
    sx = lambda v: ox + M + (math.log10(v) - x0) / max(x1 - x0, 1e-9) * (W - 2 * M)
    sy = lambda v: oy + H - M + (math.log10(v) - y0) / max(y1 - y0, 1e-9) * -(H - 2 * M)
    draw.rectangle([ox + M, oy + M, ox + W - M, oy + H - M], outline=(0, 0, 0))
    draw.text((ox + M, oy + 20), title, fill=(0, 0, 0))
    for v in (min(xs), max(xs)):
        draw.text((sx(v) - 10, oy + H - M + 5), f"{v:g}", fill=(0, 0, 0))
    for v in (min(ys), max(ys)):
        draw.text((ox + 5, sy(v) - 5), f"{v:.3f}", fill=(0, 0, 0))
    draw.text((ox + W // 2 - 20, oy + H - 25), "passes" if xkey == 0 else "seconds", fill=(0, 0, 0))
    for i, (name, pts) in enumerate(curves.items()):
        line = [(sx(p[xkey]), sy(p[2])) for p in pts]
        draw.line(line, fill=COLOURS[i % len(COLOURS)], width=2)
        for x, y in line:
            draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=COLOURS[i % len(COLOURS)])


def main():
    rows = list(csv.DictReader(open(sys.argv[1])))
    metrics = [m for m in ("rel_l1", "rel_l1_media") if m in rows[0]]
    scenes = defaultdict(lambda: defaultdict(list))
    for r in rows:
        for m in metrics:
            scenes[(r["scene"], m)][r["config"]].append((int(r["passes"]), float(r["seconds"]), float(r[m])))
    img = Image.new("RGB", (2 * W, H * len(scenes) + 30 * 5), "white")
    d = ImageDraw.Draw(img)
    for k, ((scene, m), curves) in enumerate(scenes.items()):
        what = "rel_l1" if m == "rel_l1" else "rel_l1 in media"
        panel(d, 0, k * H, curves, 0, f"{scene}: {what} vs passes")
        panel(d, W, k * H, curves, 1, f"{scene}: {what} vs wall time")
    names = list(next(iter(scenes.values())).keys())
    for i, n in enumerate(names):
        y = H * len(scenes) + 8 + 28 * i
        d.rectangle([M, y, M + 20, y + 12], fill=COLOURS[i % len(COLOURS)])
        d.text((M + 30, y), n, fill=(0, 0, 0))
    img.save(sys.argv[2])


if __name__ == "__main__":
    main()
