#!/usr/bin/env python3
"""Fills fuzz/corpus/<target>/ with seeds: the real files under ../shared/data, scenes/ and
tests/data, plus a few small hand-made files (small inputs mutate faster).
Run from the repository root: python3 fuzz/seed.py"""
import glob, hashlib, io, json, os, shutil, struct, sys, zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(ROOT), "shared", "data")
CORPUS = os.path.join(ROOT, "fuzz", "corpus")


def add(target, data, name=None):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    name = name or hashlib.sha1(data).hexdigest()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def files(*patterns):
    seen = set()
    for base in (SHARED, os.path.join(ROOT, "tests", "data"), os.path.join(ROOT, "scenes")):
        for p in patterns:
            for f in sorted(glob.glob(os.path.join(base, "**", p), recursive=True)):
                data = open(f, "rb").read()
                h = hashlib.sha1(data).hexdigest()
                if h not in seen:
                    seen.add(h)
                    yield f, data


def vdb_string(s):
    s = s.encode()
    return struct.pack("<I", len(s)) + s


def tiny_vdb():
    """One float grid: a root child (upper node) with one lower node and one leaf, no
    compression, plus one root tile: about 11 kB."""
    grid = bytearray()
    grid += struct.pack("<I", 0)  # compression flags
    grid += struct.pack("<I", 1) + vdb_string("class") + vdb_string("string") + vdb_string("fog volume")
    grid += vdb_string("UniformScaleTranslateMap")
    grid += struct.pack("<3d", 0.5, 0.25, 0.0) + struct.pack("<3d", 0.1, 0.1, 0.1) + bytes(4 * 24)
    grid += struct.pack("<i", 1) + struct.pack("<f", 0.0)  # buffer count, background
    grid += struct.pack("<II", 1, 1)  # root tiles, root children
    grid += struct.pack("<3i", 4096, 0, 0) + struct.pack("<f", 1.0) + b"\x01"
    grid += struct.pack("<3i", 0, 0, 0)
    child = bytearray(4096); child[0] = 1
    grid += child + bytes(4096)  # upper child mask, value mask
    grid += b"\x00" + bytes(32768 * 4)[:0]  # meta 0; no compression: all values follow
    grid += bytes(32768 * 4)
    lchild = bytearray(512); lchild[0] = 1
    grid += lchild + bytes(512) + b"\x00" + bytes(4096 * 4)
    leafmask = bytearray(64); leafmask[0] = 0xFF
    grid += leafmask
    topo_end = len(grid)
    grid += leafmask + b"\x00" + b"".join(struct.pack("<f", i / 512) for i in range(512))
    return grid, topo_end


def tiny_vdb_file():
    grid, topo_end = tiny_vdb()
    head = bytearray()
    head += struct.pack("<q", 0x56444220) + struct.pack("<III", 224, 10, 0) + b"\x01" + b"0" * 36
    head += struct.pack("<I", 0)  # file metadata
    head += struct.pack("<i", 1)
    desc = vdb_string("density") + vdb_string("Tree_float_5_4_3") + vdb_string("")
    start = len(head) + len(desc) + 24
    gpos = start
    # Block offset: where the leaf buffers start (after the topology).
    bpos = gpos + topo_end
    epos = gpos + len(grid)
    return bytes(head + desc + struct.pack("<qqq", gpos, bpos, epos) + grid)


def tiny_nvdb():
    """A NanoVDB raw grid buffer (NanoVDB1) of a float grid with one active root tile."""
    buf = bytearray(672 + 64 + 64 + 32)
    struct.pack_into("<Q", buf, 0, int.from_bytes(b"NanoVDB1", "little"))
    struct.pack_into("<Q", buf, 8, 0xFFFFFFFFFFFFFFFF)  # no checksum
    struct.pack_into("<I", buf, 16, 32 << 21 | 7 << 10)
    struct.pack_into("<Q", buf, 32, len(buf))
    buf[40:47] = b"density"
    m = [0.1, 0, 0, 0, 0.1, 0, 0, 0, 0.1]
    struct.pack_into("<9d", buf, 296 + 88, *m)
    struct.pack_into("<IIi", buf, 632, 2, 1, 0)
    tree = 672
    struct.pack_into("<QQQQ", buf, tree, 0, 0, 0, 64)  # leaf, lower, upper, root offsets
    struct.pack_into("<Q", buf, tree + 56, 4096 ** 3)  # active voxels
    root = tree + 64
    struct.pack_into("<3i3i", buf, root, 0, 0, 0, 4095, 4095, 4095)
    struct.pack_into("<I", buf, root + 24, 1)
    struct.pack_into("<QqIf", buf, root + 64, 0, 0, 1, 1.0)
    return bytes(buf)


def tiny_gltf():
    import base64
    pos = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    idx = struct.pack("<3H", 0, 1, 2) + b"\0\0"
    data = pos + idx
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "children": [2]}, {"camera": 0, "translation": [0, 0, 3]},
                  {"extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}],
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "spot", "intensity": 10, "spot": {}}]}},
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}}],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }
    text = json.dumps(doc).encode()
    # The same as a .glb with a BIN chunk.
    del doc["buffers"][0]["uri"]
    j = json.dumps(doc).encode()
    j += b" " * (-len(j) % 4)
    b = data + b"\0" * (-len(data) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(j) + 8 + len(b))
    glb += struct.pack("<I4s", len(j), b"JSON") + j + struct.pack("<I4s", len(b), b"BIN\0") + b
    return text, glb


def octree_cache():
    """Header (the harness fixes magic, key and checksum when asked) and 9 nodes."""
    node = lambda lo, hi, first, depth: struct.pack("<3ff3fffII2I", *lo, 1.0, *hi, 0.5, first, depth, 0, 0) if False else \
        struct.pack("<3f f 3f f I I 2I", *lo, 1.0, *hi, 0.5, first, depth, 0, 0)
    nodes = node((0, 0, 0), (1, 1, 1), 1, 0)
    for i in range(8):
        o = ((i >> 2) & 1, (i >> 1) & 1, i & 1)
        nodes += node(tuple(x * 0.5 for x in o), tuple(x * 0.5 + 0.5 for x in o), 0, 1)
    head = b"PPBOCTR\0" + struct.pack("<IIQ", 2, 48, 9) + bytes(32) + hashlib.sha256(nodes).digest() + bytes(8)
    return head + nodes


def part_body():
    header = {
        "version": "0.1.0", "scene": "scene.toml", "scene_hash": "00" * 32, "settings": "s",
        "width": 2, "height": 1, "seed": 1, "frame": None, "passes": 4,
        "range": {"start": 0, "end": 2}, "done": 2, "seconds": 1.5, "exposure": 0.0,
        "exr": {"owner": None, "comments": None, "frames_per_second": None,
                "world_to_camera": None, "world_to_ndc": None, "text": [["a", "b"]]},
    }
    j = json.dumps(header).encode()
    sums = b"".join((v).to_bytes(16, "little", signed=True) for v in (1, -2, 3, 4, 5, 1 << 100))
    return b"PPBPART1" + struct.pack("<I", len(j)) + j + sums


def main():
    if os.path.isdir(CORPUS) and "--fresh" in sys.argv:
        shutil.rmtree(CORPUS)
    for _, d in files("*.vdb"):
        add("openvdb", d)
    add("openvdb", tiny_vdb_file(), "tiny.vdb")
    for _, d in files("*.nvdb"):
        add("nanovdb", d)
    add("nanovdb", tiny_nvdb(), "tiny.nvdb")
    for f, d in files("*.gltf"):
        add("gltf", d.replace(b"glass_scene.bin", b"fuzz.bin"))
    for _, d in files("*.glb"):
        add("gltf", d)
    t, g = tiny_gltf()
    add("gltf", t, "tiny.gltf")
    add("gltf", g, "tiny.glb")
    mtl = b"".join(d for _, d in files("*.mtl"))
    for f, d in files("*.obj"):
        if len(d) > 400_000:
            continue
        body = b"\n".join(l if not l.startswith(b"mtllib") else b"mtllib fuzz.mtl" for l in d.split(b"\n"))
        add("obj", body + b"\0" + mtl)
        add("obj", body)
    add("obj", b"mtllib fuzz.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nusemtl glass\nf 1//1 2//1 3//1\n"
        b"\0newmtl glass\nNi 1.33\nd 0.5\nillum 7\nnewmtl red\nKd 1 0 0\n", "tiny")
    for _, d in files("*.usda", "*.usdc"):
        add("usd", d)
        z = io.BytesIO()
        with zipfile.ZipFile(z, "w", zipfile.ZIP_STORED) as zf:
            zf.writestr("root.usdc" if not d.startswith(b"#usda") else "root.usda", d)
        add("usd", z.getvalue())
    for _, d in files("*.toml"):
        add("scene_toml", d)
        if b'preset = ' in d:
            add("scene_toml", d.replace(b'preset = ', b'resolution = 8\npreset = ', 1))
    add("octree_cache", b"\x07" + octree_cache(), "tiny")
    for f in glob.glob("/tmp/ppb-cli-cache-*/.ppb-cache/octree-*.bin")[:1]:
        add("octree_cache", b"\x02" + open(f, "rb").read())
    for f, d in files("*.exr"):
        add("exr", d)
    add("part", part_body(), "tiny")


main()


def tiny_exr(compression):
    """A 4x3 RGB float scanline EXR, uncompressed (0) or ZIPS (2)."""
    import zlib
    w, h = 4, 3

    def attr(name, ty, data):
        return name.encode() + b"\0" + ty.encode() + b"\0" + struct.pack("<i", len(data)) + data

    chans = b"".join(c + b"\0" + struct.pack("<iBBBBii", 2, 0, 0, 0, 0, 1, 1) for c in (b"B", b"G", b"R")) + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    head = struct.pack("<ii", 20000630, 2)
    head += attr("channels", "chlist", chans)
    head += attr("compression", "compression", bytes([compression]))
    head += attr("dataWindow", "box2i", box)
    head += attr("displayWindow", "box2i", box)
    head += attr("lineOrder", "lineOrder", b"\0")
    head += attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    head += attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
    head += attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
    head += b"\0"
    lines = []
    for y in range(h):
        raw = b"".join(struct.pack("<f", (x + y * w) * 0.1 + c) for c in range(3) for x in range(w))
        if compression == 2:
            t = raw[0::2] + raw[1::2]
            p = bytearray(t)
            for i in range(len(t) - 1, 0, -1):
                p[i] = (t[i] - t[i - 1] + 128 + 256) & 0xFF
            z = zlib.compress(bytes(p))
            raw = z if len(z) < len(raw) else raw
        lines.append(struct.pack("<ii", y, len(raw)) + raw)
    table_at = len(head)
    offsets, at = [], table_at + 8 * h
    for l in lines:
        offsets.append(at)
        at += len(l)
    return head + b"".join(struct.pack("<Q", o) for o in offsets) + b"".join(lines)


add("exr", tiny_exr(0), "tiny-none.exr")
add("exr", tiny_exr(2), "tiny-zips.exr")
