"""Write sky.exr, the procedural lat-long environment map of the cloud-sky scene.

Every formula is also stated in scene.md. Run: python3 make_sky.py  (writes sky.exr next to
this script and prints the sun's irradiance and the map's mean radiance).

Lat-long convention (Mitsuba 3 `envmap`, identity to_world): image 512 x 256, texel (i, j) =
column i (0 = left), row j (0 = top); its centre has u = (i + 0.5)/W, v = (j + 0.5)/H and
direction d = (sin(pi v) sin(2 pi u), cos(pi v), -sin(pi v) cos(2 pi u)), i.e. u = 0 towards -Z,
u = 0.25 towards +X, v = 0 at +Y (zenith, top row).
"""
import os
import sys

import numpy as np

W, H = 512, 256

# sun: opposite of cloud-hg's light propagation direction normalize(0.5, -0.6, -0.4)
SUN_DIR = -np.array([0.5, -0.6, -0.4]) / np.linalg.norm([0.5, -0.6, -0.4])
SUN_FULL_DEG = 2.0      # full radiance inside this angle from SUN_DIR
SUN_EDGE_DEG = 3.0      # smoothstep down to 0 at this angle
# sun radiance SUN_RADIANCE (W/m^2/sr, white): a fixed constant defined below, after
# sun_irradiance_per_unit_radiance, chosen so that the sun's irradiance on a plane facing it,
# summed over the texels (nearest lookup), is 4.000 W/m^2

HORIZON_COLOR = np.array([1.0, 1.0, 1.05])
ZENITH_COLOR = np.array([0.30, 0.50, 1.0])
SKY_SCALE = 0.25
GLOW_COLOR = np.array([1.0, 0.9, 0.7])
GLOW_SCALE = 0.2
GLOW_WIDTH = 0.2        # glow = GLOW_SCALE * GLOW_COLOR * exp((dot(d, s) - 1) / GLOW_WIDTH)
GROUND_COLOR = np.array([0.05, 0.045, 0.04])
HORIZON_BLEND_DEG = 3.0  # sky/ground blend: smoothstep over elevation [-3, +3] degrees


def smoothstep(a, b, x):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def texel_directions(w=W, h=H):
    i = np.arange(w)
    j = np.arange(h)
    u = (i + 0.5) / w
    v = (j + 0.5) / h
    uu, vv = np.meshgrid(u, v)  # shape (h, w): row j, column i
    st = np.sin(np.pi * vv)
    d = np.stack([st * np.sin(2 * np.pi * uu), np.cos(np.pi * vv), -st * np.cos(2 * np.pi * uu)],
                 axis=-1)
    return d


def texel_solid_angles(w=W, h=H):
    """Exact solid angle of each texel: (2 pi / w) * (cos(pi j/h) - cos(pi (j+1)/h))."""
    j = np.arange(h)
    band = (2 * np.pi / w) * (np.cos(np.pi * j / h) - np.cos(np.pi * (j + 1) / h))
    return np.repeat(band[:, None], w, axis=1)


def sun_weight(d):
    cs = np.clip(d @ SUN_DIR, -1.0, 1.0)
    theta_deg = np.degrees(np.arccos(cs))
    return 1.0 - smoothstep(SUN_FULL_DEG, SUN_EDGE_DEG, theta_deg)


def background(d):
    """Sky + ground without the sun disk, RGB, float64."""
    y = d[..., 1]
    elev_deg = np.degrees(np.arcsin(np.clip(y, -1.0, 1.0)))
    wh = smoothstep(-HORIZON_BLEND_DEG, HORIZON_BLEND_DEG, elev_deg)[..., None]
    tz = np.sqrt(np.maximum(y, 0.0))[..., None]
    sky = SKY_SCALE * ((1.0 - tz) * HORIZON_COLOR + tz * ZENITH_COLOR)
    cs = (d @ SUN_DIR)[..., None]
    glow = GLOW_SCALE * GLOW_COLOR * np.exp((cs - 1.0) / GLOW_WIDTH)
    return wh * (sky + glow) + (1.0 - wh) * GROUND_COLOR


def sky_map(sun_radiance):
    d = texel_directions()
    return background(d) + sun_radiance * sun_weight(d)[..., None]


def sun_irradiance_per_unit_radiance():
    """sum over texels of sun_weight * texel solid angle * max(0, cos to the sun)."""
    d = texel_directions()
    dom = texel_solid_angles()
    cs = np.maximum(d @ SUN_DIR, 0.0)
    return float(np.sum(sun_weight(d) * dom * cs))


# fixed constant: 4 / sun_irradiance_per_unit_radiance() = 664.98457, rounded to 3 decimals
SUN_RADIANCE = 664.985


def main():
    k = sun_irradiance_per_unit_radiance()
    print("sun irradiance per unit radiance (texel sum, nearest): %.9f sr" % k)
    print("radiance for E = 4 exactly: %.6f ; used SUN_RADIANCE = %.3f" % (4.0 / k, SUN_RADIANCE))
    img = sky_map(SUN_RADIANCE).astype(np.float32)
    d = texel_directions()
    dom = texel_solid_angles()
    e_sun = SUN_RADIANCE * k
    # irradiance of the whole map (sun + sky) on a plane facing the sun
    cs = np.maximum(d @ SUN_DIR, 0.0)
    e_all = (img.astype(np.float64) * (dom * cs)[..., None]).sum(axis=(0, 1))
    e_up = (img.astype(np.float64) * (dom * np.maximum(d[..., 1], 0.0))[..., None]).sum(axis=(0, 1))
    bg = background(d)
    e_up_bg = (bg * (dom * np.maximum(d[..., 1], 0.0))[..., None]).sum(axis=(0, 1))
    mean_sa = (img.astype(np.float64) * dom[..., None]).sum(axis=(0, 1)) / (4 * np.pi)
    mean_sa_bg = (bg * dom[..., None]).sum(axis=(0, 1)) / (4 * np.pi)
    mean_px = img.astype(np.float64).mean(axis=(0, 1))
    print("sun irradiance on a plane facing it: %.6f W/m^2" % e_sun)
    print("whole map irradiance on a plane facing the sun (RGB):", e_all)
    print("whole map irradiance on an upward plane (RGB):", e_up, " without sun:", e_up_bg)
    print("map mean radiance, solid-angle weighted (RGB):", mean_sa, " without sun:", mean_sa_bg)
    print("map mean radiance, plain texel mean (RGB):", mean_px)
    print("max texel:", img.max(), " min texel:", img.min())
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "sky.exr")
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    bmp = mi.Bitmap(np.ascontiguousarray(img), pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.write(out)
    back = np.array(mi.Bitmap(out))
    assert back.shape == (H, W, 3) and back.dtype == np.float32 and np.array_equal(back, img), \
        (back.shape, back.dtype)
    print("wrote", out, back.shape, back.dtype)


if __name__ == "__main__":
    main()
