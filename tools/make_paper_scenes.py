#!/usr/bin/env python3
"""Writes the geometry of the paper's scenes (scenes/paper/) as an artist's tool would
hand it over: glTF 2.0 (.gltf + .bin) with KHR_materials_transmission / KHR_materials_ior
glass and KHR_lights_punctual lights, a USD stage (.usda) with UsdPreviewSurface,
SphereLight, Camera and a Volume reading an OpenVDB file, and one OBJ where glTF adds
nothing (a large ground plane).

    python3 tools/make_paper_scenes.py          # rewrites the files in place

The scene.toml files beside them are written by hand; the media come from ppb's procedural
noise or from OpenVDB files written by OpenVDB and Blender (scenes/paper/assets/,
scenes/mantaflow/). Output is deterministic: rerunning leaves git clean.

Conventions: +Y up, metres, right-handed. glTF light intensities are photometric (candela
for point and spot lights); ppb divides them by 683 lm/W, so a spot of I W/sr is written as
683 I cd. Cameras look down their node's -Z.
"""
import json
import math
import os
import struct
import sys

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "paper")
LM_PER_W = 683.0


# ---------------------------------------------------------------- meshes
# Every mesh is closed (except planes) and wound counter-clockwise seen from outside, so its
# normals point out: ppb needs that of glass.

def uv_sphere(radius, segments=64, rings=32):
    """UV sphere about the origin: (positions, normals, triangle indices)."""
    pos, nrm = [], []
    for j in range(rings + 1):
        theta = math.pi * j / rings
        for i in range(segments + 1):
            phi = 2.0 * math.pi * i / segments
            n = (math.sin(theta) * math.cos(phi), math.cos(theta), -math.sin(theta) * math.sin(phi))
            nrm.append(n)
            pos.append(tuple(radius * c for c in n))
    tri = []
    w = segments + 1
    for j in range(rings):
        for i in range(segments):
            a, b = j * w + i, j * w + i + 1
            c, d = (j + 1) * w + i, (j + 1) * w + i + 1
            if j != 0:
                tri.append((a, c, b))
            if j != rings - 1:
                tri.append((b, c, d))
    return np.array(pos, np.float32), np.array(nrm, np.float32), np.array(tri, np.uint32)


def torus(major, minor, segments=64, sides=32):
    """Torus about the Y axis (lying in the XZ plane)."""
    pos, nrm = [], []
    for i in range(segments):
        u = 2.0 * math.pi * i / segments
        cu, su = math.cos(u), math.sin(u)
        for j in range(sides):
            v = 2.0 * math.pi * j / sides
            cv, sv = math.cos(v), math.sin(v)
            nrm.append((cv * cu, sv, -cv * su))
            pos.append(((major + minor * cv) * cu, minor * sv, -(major + minor * cv) * su))
    tri = []
    for i in range(segments):
        for j in range(sides):
            a = i * sides + j
            b = ((i + 1) % segments) * sides + j
            c = ((i + 1) % segments) * sides + (j + 1) % sides
            d = i * sides + (j + 1) % sides
            tri += [(a, b, c), (a, c, d)]
    return np.array(pos, np.float32), np.array(nrm, np.float32), np.array(tri, np.uint32)


def box(half):
    """Axis-aligned box with flat faces (4 vertices per face)."""
    hx, hy, hz = half
    pos, nrm, tri = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3
            base = len(pos)
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis] = sign
                p[u_axis] = du
                p[v_axis] = dv
                pos.append((p[0] * hx, p[1] * hy, p[2] * hz))
                nrm.append(tuple(n))
            # (u, v, n) is right-handed, so u x v = +n for this winding; flip for -n.
            if sign > 0:
                tri += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
            else:
                tri += [(base, base + 2, base + 1), (base, base + 3, base + 2)]
    return np.array(pos, np.float32), np.array(nrm, np.float32), np.array(tri, np.uint32)


def plane(half):
    """A square at y = 0 facing +Y."""
    h = half
    pos = np.array([(-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h)], np.float32)
    nrm = np.array([(0, 1, 0)] * 4, np.float32)
    tri = np.array([(0, 1, 2), (0, 2, 3)], np.uint32)
    return pos, nrm, tri


def check_closed_outward(pos, tri):
    """Signed volume > 0 for an outward-facing closed mesh (a sanity check on winding)."""
    p = pos.astype(np.float64)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert vol > 0, f"mesh winding is inward (volume {vol})"
    return vol


# ---------------------------------------------------------------- transforms

def look_rotation(origin, target, up=(0.0, 1.0, 0.0)):
    """3x3 rotation whose -Z column points from origin to target (columns: x, y, z)."""
    o, t, u = (np.asarray(v, np.float64) for v in (origin, target, up))
    f = t - o
    f /= np.linalg.norm(f)
    x = np.cross(f, u)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return np.stack([x, y, -f], axis=1)


def quat_from_matrix(m):
    """Unit quaternion (x, y, z, w) of a rotation matrix."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x = 0.25 * s, (m[2, 1] - m[1, 2]) / s
        y, z = (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x = (m[2, 1] - m[1, 2]) / s, 0.25 * s
        y, z = (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s
        y, z = 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s
        y, z = (m[1, 2] + m[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    return [round(float(c), 9) for c in q / np.linalg.norm(q)]


def quat_axis_angle(axis, deg):
    a = np.asarray(axis, np.float64)
    a /= np.linalg.norm(a)
    h = math.radians(deg) / 2
    return [round(float(c), 9) for c in (*(a * math.sin(h)), math.cos(h))]


# ---------------------------------------------------------------- glTF

class Gltf:
    """A minimal glTF 2.0 writer: one .bin buffer, one node per mesh, light or camera."""

    def __init__(self, generator):
        self.doc = {
            "asset": {"version": "2.0", "generator": generator},
            "scene": 0,
            "scenes": [{"nodes": []}],
            "nodes": [],
            "meshes": [],
            "materials": [],
            "accessors": [],
            "bufferViews": [],
            "buffers": [],
        }
        self.bin = bytearray()
        self.lights = []
        self.extensions = set()

    def _view(self, data, target):
        while len(self.bin) % 4:
            self.bin.append(0)
        offset = len(self.bin)
        self.bin += data
        self.doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": offset, "byteLength": len(data), "target": target}
        )
        return len(self.doc["bufferViews"]) - 1

    def _accessor(self, array, kind):
        if kind == "index":
            flat = np.ascontiguousarray(array.reshape(-1), np.uint32)
            view = self._view(flat.tobytes(), 34963)
            acc = {"bufferView": view, "componentType": 5125, "count": int(flat.size), "type": "SCALAR"}
        else:
            a = np.ascontiguousarray(array, np.float32)
            view = self._view(a.tobytes(), 34962)
            acc = {"bufferView": view, "componentType": 5126, "count": int(a.shape[0]), "type": "VEC3"}
            if kind == "position":
                acc["min"] = [round(float(v), 6) for v in a.min(axis=0)]
                acc["max"] = [round(float(v), 6) for v in a.max(axis=0)]
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def material(self, name, base_color=(0.5, 0.5, 0.5), transmission=0.0, ior=None):
        m = {
            "name": name,
            "pbrMetallicRoughness": {
                "baseColorFactor": [*base_color, 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 0.0 if transmission > 0 else 1.0,
            },
        }
        ext = {}
        if transmission > 0:
            ext["KHR_materials_transmission"] = {"transmissionFactor": transmission}
        if ior is not None:
            ext["KHR_materials_ior"] = {"ior": ior}
        if ext:
            m["extensions"] = ext
            self.extensions.update(ext)
        self.doc["materials"].append(m)
        return len(self.doc["materials"]) - 1

    def _node(self, node):
        self.doc["nodes"].append(node)
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)

    def mesh(self, name, geometry, material, translation=(0, 0, 0), rotation=None):
        pos, nrm, tri = geometry
        prim = {
            "attributes": {
                "POSITION": self._accessor(pos, "position"),
                "NORMAL": self._accessor(nrm, "normal"),
            },
            "indices": self._accessor(tri, "index"),
            "material": material,
        }
        self.doc["meshes"].append({"name": name, "primitives": [prim]})
        node = {"name": name, "mesh": len(self.doc["meshes"]) - 1, "translation": list(translation)}
        if rotation is not None:
            node["rotation"] = rotation
        self._node(node)

    def spot_light(self, name, position, target, color, watts_per_sr, inner_deg, outer_deg):
        self.extensions.add("KHR_lights_punctual")
        self.lights.append({
            "name": name,
            "type": "spot",
            "color": list(color),
            "intensity": round(watts_per_sr * LM_PER_W, 3),
            "spot": {
                "innerConeAngle": round(math.radians(inner_deg), 6),
                "outerConeAngle": round(math.radians(outer_deg), 6),
            },
        })
        self._node({
            "name": name,
            "translation": list(position),
            "rotation": quat_from_matrix(look_rotation(position, target)),
            "extensions": {"KHR_lights_punctual": {"light": len(self.lights) - 1}},
        })

    def camera(self, name, origin, target, vfov_deg, aspect):
        self.doc.setdefault("cameras", []).append({
            "name": name,
            "type": "perspective",
            "perspective": {"yfov": round(math.radians(vfov_deg), 6), "aspectRatio": aspect,
                            "znear": 0.05, "zfar": 100.0},
        })
        self._node({
            "name": name,
            "camera": len(self.doc["cameras"]) - 1,
            "translation": list(origin),
            "rotation": quat_from_matrix(look_rotation(origin, target)),
        })

    def write(self, path):
        stem = os.path.splitext(os.path.basename(path))[0]
        self.doc["buffers"] = [{"uri": stem + ".bin", "byteLength": len(self.bin)}]
        if self.lights:
            self.doc["extensions"] = {"KHR_lights_punctual": {"lights": self.lights}}
        self.doc["extensionsUsed"] = sorted(self.extensions)
        with open(path, "w") as f:
            json.dump(self.doc, f, indent=1)
            f.write("\n")
        with open(os.path.join(os.path.dirname(path), stem + ".bin"), "wb") as f:
            f.write(self.bin)


# ---------------------------------------------------------------- USD (usda text)

def usd_floats(values):
    return ", ".join(f"{v:.9g}" for v in values)


def usd_tuples(rows):
    return "[" + ", ".join("(" + usd_floats(r) + ")" for r in rows) + "]"


def usd_matrix(rot, origin):
    """matrix4d rows (USD's row-vector layout): the axes, then the translation."""
    rows = [list(rot[:, 0]) + [0], list(rot[:, 1]) + [0], list(rot[:, 2]) + [0], list(origin) + [1]]
    return "( " + ", ".join("(" + usd_floats(r) + ")" for r in rows) + " )"


def usd_preview_material(name, diffuse, opacity=1.0, ior=1.5):
    return f'''        def Material "{name}"
        {{
            token outputs:surface.connect = </World/Looks/{name}/PreviewSurface.outputs:surface>

            def Shader "PreviewSurface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = ({usd_floats(diffuse)})
                float inputs:ior = {ior}
                float inputs:metallic = 0
                float inputs:opacity = {opacity}
                float inputs:roughness = {0 if opacity < 1 else 1}
                token outputs:surface
            }}
        }}
'''


# ---------------------------------------------------------------- scenes

def fig14_stage():
    """Fig. 14: smoke with a glass sphere. A USD stage: grey floor, glass sphere, the smoke
    plume as a Volume reading ../assets/smoke_plume.vdb, a small sphere light, a camera.
    The plume's lowest 0.5 m is a solid block (constant tiles of density 1, its source):
    the Volume is sunk by that much so the column rises out of the floor.
    The homogeneous fog that fills the room is added by scene.toml (USD has no such prim
    that ppb reads)."""
    d = os.path.join(ROOT, "fig14-smoke-glass-sphere")
    os.makedirs(d, exist_ok=True)
    floor = 4.0
    cam_origin, cam_target, vfov = (0.0, 1.25, 4.6), (0.1, 0.8, -0.3), 38.0
    rot = look_rotation(cam_origin, cam_target)
    focal = 50.0
    vap = 2 * focal * math.tan(math.radians(vfov) / 2)
    # A 5 cm sphere light of 12 W/sr: L = I / (pi r^2).
    r_light, intensity = 0.05, 12.0
    radiance = intensity / (math.pi * r_light * r_light)
    text = f'''#usda 1.0
(
    "Fig. 14 of Suzuki et al.: smoke around a glass sphere (tools/make_paper_scenes.py)"
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{{
    def Scope "Looks"
    {{
{usd_preview_material("Floor", (0.5, 0.5, 0.5))}
{usd_preview_material("Glass", (1, 1, 1), opacity=0, ior=1.5)}    }}

    def Mesh "Floor" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {{
        float3[] extent = [(-{floor}, 0, -{floor}), ({floor}, 0, {floor})]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        rel material:binding = </World/Looks/Floor>
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (
            interpolation = "vertex"
        )
        point3f[] points = [(-{floor}, 0, {floor}), ({floor}, 0, {floor}), ({floor}, 0, -{floor}), (-{floor}, 0, -{floor})]
        uniform token subdivisionScheme = "none"
    }}

    def Sphere "GlassSphere" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {{
        float3[] extent = [(-0.36, -0.36, -0.36), (0.36, 0.36, 0.36)]
        rel material:binding = </World/Looks/Glass>
        double radius = 0.36
        double3 xformOp:translate = (-0.6, 0.95, 0.35)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}

    def SphereLight "Lamp"
    {{
        color3f inputs:color = (1, 0.93, 0.82)
        float inputs:exposure = 0
        float inputs:intensity = {radiance:.6g}
        bool inputs:normalize = 0
        float inputs:radius = {r_light}
        double3 xformOp:translate = (-0.72, 2.75, 0.1)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}

    def Camera "Camera"
    {{
        float2 clippingRange = (0.1, 100)
        float focalLength = {focal}
        float horizontalAperture = {vap:.6g}
        token projection = "perspective"
        float verticalAperture = {vap:.6g}
        matrix4d xformOp:transform = {usd_matrix(rot, cam_origin)}
        uniform token[] xformOpOrder = ["xformOp:transform"]
    }}

    def Volume "Smoke"
    {{
        float3[] extent = [(-0.5390625, -0.0078125, -1.3046875), (1.0546875, 1.8046875, 0.1953125)]
        custom float ppb:densityScale = 10
        custom color3f ppb:albedo = (0.9, 0.9, 0.9)
        custom float ppb:g = 0
        custom rel field:density = </World/Smoke/density>
        double3 xformOp:translate = (0, -0.5, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]

        def OpenVDBAsset "density"
        {{
            token fieldDataType = "float"
            token fieldName = "density"
            asset filePath = @../assets/smoke_plume.vdb@
        }}
    }}
}}
'''
    with open(os.path.join(d, "smoke_glass.usda"), "w") as f:
        f.write(text)


def fig17_gltf():
    """Fig. 17: glass objects above a Lambert floor under red, green and blue spot lights."""
    d = os.path.join(ROOT, "fig17-glass-rgb-caustics")
    os.makedirs(d, exist_ok=True)
    g = Gltf("tools/make_paper_scenes.py (ppb)")
    floor = g.material("floor", (0.6, 0.6, 0.6))
    glass = g.material("glass", (1.0, 1.0, 1.0), transmission=1.0, ior=1.5)
    g.mesh("Floor", plane(3.0), floor)
    sphere = uv_sphere(0.34)
    check_closed_outward(sphere[0], sphere[2])
    g.mesh("GlassSphere", sphere, glass, translation=(-0.8, 0.34, 0.15))
    ring = torus(0.3, 0.11)
    check_closed_outward(ring[0], ring[2])
    # Standing on its rim, turned 30 degrees towards the camera.
    q = quat_axis_angle((0.5, 0.0, 0.866), 90.0)
    g.mesh("GlassTorus", ring, glass, translation=(0.75, 0.41, 0.1), rotation=q)
    cube = box((0.22, 0.22, 0.22))
    check_closed_outward(cube[0], cube[2])
    g.mesh("GlassCube", cube, glass, translation=(0.0, 0.22, -0.75),
           rotation=quat_axis_angle((0, 1, 0), 35.0))
    target = (0.0, 0.3, -0.1)
    for name, pos, color in (
        ("RedSpot", (-1.7, 2.6, 0.5), (1.0, 0.08, 0.05)),
        ("GreenSpot", (0.0, 2.8, -1.3), (0.08, 1.0, 0.1)),
        ("BlueSpot", (1.7, 2.6, 0.5), (0.1, 0.25, 1.0)),
    ):
        g.spot_light(name, pos, target, color, 40.0, 14.0, 24.0)
    g.camera("Camera", (0.0, 1.7, 4.4), (0.0, 0.45, 0.0), 36.0, 1.0)
    g.write(os.path.join(d, "glass_objects.gltf"))


def ground_obj():
    """A 24 m ground for the outdoor scenes (Fig. 18): OBJ, since glTF adds nothing."""
    d = os.path.join(ROOT, "assets")
    os.makedirs(d, exist_ok=True)
    h = 12
    with open(os.path.join(d, "ground.obj"), "w") as f:
        f.write("# 24 m square ground at y = 0, normal +Y (tools/make_paper_scenes.py)\n")
        for x, z in ((-h, -h), (h, -h), (h, h), (-h, h)):
            f.write(f"v {x} 0 {z}\n")
        f.write("vn 0 1 0\nf 1//1 4//1 3//1\nf 1//1 3//1 2//1\n")


def noise_medium(preset, lo, hi, seed, octaves, frequency, resolution, density_scale, albedo, g):
    lo = ", ".join(f"{v:g}" for v in lo)
    hi = ", ".join(f"{v:g}" for v in hi)
    alb = ", ".join(f"{v:g}" for v in albedo)
    return f"""[[medium]]
type = "noise"
preset = "{preset}"
bounds = [[{lo}], [{hi}]]
seed = {seed}
octaves = {octaves}
frequency = {frequency:g}
resolution = {resolution}
density_scale = {density_scale:g}
albedo = [{alb}]
phase = {{ type = "hg", g = {g:g} }}
"""


def cloud_cells(rng, nx, nz, pitch, size, y, jitter, grow=0.0, z0=0.0):
    """Cloud-cell boxes on a jittered grid (rows along x, receding along -z): (lo, hi)."""
    cells = []
    for j in range(nz):
        for i in range(nx):
            cx = (i - (nx - 1) / 2) * pitch[0] + rng.uniform(-jitter, jitter) + (0.5 * pitch[0] if j % 2 else 0)
            cz = z0 - j * pitch[1] + rng.uniform(-jitter, jitter)
            sx, sy, sz = (s * rng.uniform(0.85, 1.15) * (1 + grow * j) for s in size)
            cy = y + rng.uniform(-0.05, 0.05) * size[1]
            cells.append(((cx - sx / 2, cy, cz - sz / 2), (cx + sx / 2, cy + sy, cz + sz / 2)))
    return cells


def write_cell_scene(path, header, cells, first_seed, medium_args):
    out = [header.rstrip() + "\n"]
    for k, (lo, hi) in enumerate(cells):
        lo = tuple(round(v, 3) for v in lo)
        hi = tuple(round(v, 3) for v in hi)
        out.append("\n" + noise_medium("cloud", lo, hi, first_seed + k, **medium_args))
    with open(path, "w") as f:
        f.write("".join(out))


FIG16_HEADER = """# Fig. 16 of the paper: a cirrocumulus, 512x256: a thin, high layer of small cloud cells in
# rows (a "mackerel sky") seen from below, lit by a high sun behind the viewer, against a
# blue-scattering haze that stands in for the sky (as in fig15). Each cell is one procedural
# fBm cloud (noise medium, cloud preset) of its own seed; the cell list below is written by
# tools/make_paper_scenes.py (a jittered grid, rows offset by half a cell). Every cell box
# is at least 1.1 m wide.
[render]
width = 512
height = 256
passes = 128           # the paper's Figs. 15 and 16: 128 passes of 100,000 beams
light_paths = 100000
seed = 1

[camera]
origin = [0, 0.5, 6]
target = [0, 5.0, -3]
up = [0, 1, 0]
vfov = 30

[[light]]
type = "directional"
direction = [0.2, -0.75, -0.6]
irradiance = [6.0, 5.8, 5.4]

# The sky behind the cells: a slab of haze above the layer, sigma_t 0.08 1/m, scattering
# blue more than red.
[[medium]]
type = "homogeneous"
bounds = [[-10, 3.9, -12], [10, 7.5, 6]]
sigma_t = 0.08
albedo = [0.25, 0.45, 0.95]
phase = { type = "isotropic" }
"""


def fig16_cirrocumulus():
    d = os.path.join(ROOT, "fig16-cirrocumulus")
    os.makedirs(d, exist_ok=True)
    rng = np.random.default_rng(16)
    cells = cloud_cells(rng, nx=8, nz=6, pitch=(1.9, 1.9), size=(1.45, 0.38, 1.2), y=3.4,
                        jitter=0.22, grow=0.04, z0=3.0)
    write_cell_scene(os.path.join(d, "scene.toml"), FIG16_HEADER, cells, 1600,
                     dict(octaves=5, frequency=2.0, resolution=32, density_scale=25.0,
                          albedo=(0.99, 0.99, 0.99), g=0.6))


def main():
    fig14_stage()
    fig16_cirrocumulus()
    fig17_gltf()
    ground_obj()
    print("wrote", os.path.normpath(ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
