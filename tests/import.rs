//! OBJ and glTF import against the Blender-exported glass scene and the values its sidecars
//! state (`glass_scene.check.json`: pygltflib/validator/MTL readout; `glass_scene.blender.json`:
//! what Blender itself reports), plus malformed and synthetic inputs.
use std::f64::consts::FRAC_1_SQRT_2;
use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};
use ppb::error::Error;
use ppb::scene::gltf::load_gltf;
use ppb::scene::obj::load_obj;
use ppb::scene::{Imported, Light, Material, Mesh};
use serde_json::{json, Value};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/scene/");
const MESH_NAMES: [&str; 4] = ["Floor", "GlassSphere", "GlassTorus", "GlassSuzanne"];
const LM_PER_W: f32 = 683.0;

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
}

fn sidecar(name: &str) -> Value {
    let text = std::fs::read_to_string(data(name)).expect("sidecar readable");
    serde_json::from_str(&text).expect("sidecar is JSON")
}

fn blender() -> Value {
    sidecar("glass_scene.blender.json")
}

/// The pygltflib readout of one file ("glass_scene.gltf" or "glass_scene.glb").
fn readout(file: &str) -> Value {
    let check = sidecar("glass_scene.check.json");
    let all = check["pygltflib"].as_array().expect("pygltflib list");
    all.iter()
        .find(|r| r["file"] == file)
        .expect("readout for file")
        .clone()
}

fn vec3(v: &Value) -> Vec3 {
    let c: Vec<f32> = v
        .as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number") as f32)
        .collect();
    Vec3::new(c[0], c[1], c[2])
}

fn f(v: &Value) -> f32 {
    v.as_f64().expect("number") as f32
}

fn assert_close(a: Vec3, b: Vec3, tol: f32, what: &str) {
    assert!((a - b).abs().max_element() <= tol, "{what}: {a} vs {b}");
}

/// A scratch directory unique to this process and test.
fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ppb-import-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn mesh<'a>(imported: &'a Imported, name: &str) -> &'a Mesh {
    let found: Vec<_> = imported.meshes.iter().filter(|m| m.name == name).collect();
    assert_eq!(found.len(), 1, "exactly one mesh named {name}");
    found[0]
}

fn aabb(mesh: &Mesh) -> (Vec3, Vec3) {
    let min = mesh.positions.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
    let max = mesh
        .positions
        .iter()
        .fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
    (min, max)
}

fn material_of<'a>(imported: &'a Imported, mesh: &Mesh) -> &'a ppb::scene::NamedMaterial {
    &imported.materials[mesh.material]
}

/// World transform of a glTF node as pygltflib read it (absent TRS parts are identity).
fn node_transform(name: &str) -> Mat4 {
    let nodes = readout("glass_scene.gltf")["nodes"].clone();
    let node = nodes
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == name)
        .unwrap()
        .clone();
    let or = |v: &Value, default: Vec3| if v.is_null() { default } else { vec3(v) };
    let q = &node["rotation_xyzw"];
    let rotation = if q.is_null() {
        Quat::IDENTITY
    } else {
        Quat::from_xyzw(f(&q[0]), f(&q[1]), f(&q[2]), f(&q[3]))
    };
    let scale = or(&node["scale"], Vec3::ONE);
    Mat4::from_scale_rotation_translation(scale, rotation, or(&node["translation"], Vec3::ZERO))
}

/// Blender's `world_aabb_gltf_yup` is the box around the 8 world-space corners of the
/// object's local box (looser than the vertices for the rotated Suzanne), so rebuild exactly
/// that: take the mesh back to object space, then push its local box corners out again.
fn check_bounds(m: &Mesh, blender_box: &Value) {
    let to_world = node_transform(&m.name);
    let to_local = to_world.inverse();
    let local = Mesh {
        positions: m
            .positions
            .iter()
            .map(|&p| to_local.transform_point3(p))
            .collect(),
        ..Default::default()
    };
    let (lo, hi) = aabb(&local);
    let corners = (0..8).map(|i| {
        let pick = |bit: usize, a: f32, b: f32| if i & bit == 0 { a } else { b };
        let c = Vec3::new(
            pick(1, lo.x, hi.x),
            pick(2, lo.y, hi.y),
            pick(4, lo.z, hi.z),
        );
        to_world.transform_point3(c)
    });
    let world = Mesh {
        positions: corners.collect(),
        ..Default::default()
    };
    let (min, max) = aabb(&world);
    assert_close(
        min,
        vec3(&blender_box["min"]),
        2e-5,
        &format!("{} min", m.name),
    );
    assert_close(
        max,
        vec3(&blender_box["max"]),
        2e-5,
        &format!("{} max", m.name),
    );
}

/// Geometry shared by both importers: names, triangle counts, world bounds, material names
/// and unit normals, all as Blender reports them.
fn check_geometry_against_blender(imported: &Imported) {
    let objects = &blender()["objects"];
    assert_eq!(imported.meshes.len(), MESH_NAMES.len());
    for name in MESH_NAMES {
        let m = mesh(imported, name);
        let o = &objects[name];
        assert_eq!(
            m.triangles.len() as u64,
            o["triangles"].as_u64().unwrap(),
            "{name}"
        );
        check_bounds(m, &o["world_aabb_gltf_yup"]);
        assert_eq!(
            material_of(imported, m).name,
            o["material"].as_str().unwrap()
        );
        assert_eq!(m.normals.len(), m.positions.len(), "{name} normals");
        assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5));
        let n = m.positions.len() as u32;
        assert!(
            m.triangles.iter().flatten().all(|&i| i < n),
            "{name} indices"
        );
    }
}

fn expected_gltf_material(name: &str) -> Material {
    let m = &blender()["materials"][name];
    if m["transmission"].as_f64().unwrap_or(0.0) > 0.0 {
        Material::Dielectric { ior: f(&m["ior"]) }
    } else {
        Material::Lambert {
            reflectance: vec3(&Value::from(
                m["baseColor"].as_array().unwrap()[..3].to_vec(),
            )),
        }
    }
}

fn assert_material_eq(got: Material, want: Material, name: &str) {
    match (got, want) {
        (Material::Dielectric { ior: a }, Material::Dielectric { ior: b }) => {
            assert!((a - b).abs() < 1e-6, "{name}: ior {a} vs {b}")
        }
        (Material::Lambert { reflectance: a }, Material::Lambert { reflectance: b }) => {
            assert_close(a, b, 1e-6, name)
        }
        _ => panic!("{name}: {got:?} vs {want:?}"),
    }
}

#[test]
fn gltf_geometry_and_materials_match_sidecars() {
    for file in ["glass_scene.gltf", "glass_scene.glb"] {
        let imported = load_gltf(&data(file)).expect(file);
        check_geometry_against_blender(&imported);
        let meshes = readout(file)["meshes"].as_array().unwrap().clone();
        for (name, expected) in MESH_NAMES
            .iter()
            .map(|n| (n, meshes.iter().find(|m| m["name"] == *n)))
        {
            let prim = &expected.expect("mesh in readout")["primitives"][0];
            let m = mesh(&imported, name);
            assert_eq!(
                m.positions.len() as u64,
                prim["attributes"]["POSITION"]["count"].as_u64().unwrap()
            );
            assert_eq!(
                m.triangles.len() as u64,
                prim["triangles"].as_u64().unwrap()
            );
        }
        let names: Vec<_> = imported.materials.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["Floor_Lambert", "Glass", "Glass_IOR1.45"], "{file}");
        for m in &imported.materials {
            assert_material_eq(m.material, expected_gltf_material(&m.name), &m.name);
        }
    }
}

#[test]
fn gltf_and_glb_import_identically() {
    let a = load_gltf(&data("glass_scene.gltf")).unwrap();
    let b = load_gltf(&data("glass_scene.glb")).unwrap();
    assert_eq!(a.materials, b.materials);
    assert_eq!(a.lights, b.lights);
    assert_eq!(a.camera, b.camera);
    assert_eq!(a.meshes.len(), b.meshes.len());
    for (x, y) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.positions, y.positions);
        assert_eq!(x.normals, y.normals);
        assert_eq!(x.triangles, y.triangles);
        assert_eq!(x.material, y.material);
    }
}

/// Lights are glTF cd * colour / 683 (W/sr). Blender's exporter wrote P / (4 pi) * 683 cd,
/// so 4 pi times our intensity must give back Blender's watts.
#[test]
fn gltf_lights_are_converted_to_radiometric_units() {
    let imported = load_gltf(&data("glass_scene.gltf")).unwrap();
    let check = readout("glass_scene.gltf");
    let objects = &blender()["objects"];
    assert_eq!(imported.lights.len(), 2);
    let gltf_lights = check["lights"].as_array().unwrap();

    let Light::Point {
        position,
        intensity,
    } = imported.lights[0]
    else {
        panic!("first light is a point light: {:?}", imported.lights[0]);
    };
    let point = &gltf_lights[0];
    let want = vec3(&point["color"]) * f(&point["intensity"]) / LM_PER_W;
    assert_close(intensity, want, 1e-4, "point intensity");
    let watts =
        f(&objects["PointLight"]["blender_power_W"]) * vec3(&objects["PointLight"]["color"]);
    assert_close(
        intensity * 4.0 * std::f32::consts::PI,
        watts,
        1e-2,
        "point watts",
    );
    assert_close(
        position,
        vec3(&objects["PointLight"]["gltf_location"]),
        1e-6,
        "point position",
    );

    let Light::Spot {
        position,
        direction,
        intensity,
        inner_deg,
        outer_deg,
    } = imported.lights[1]
    else {
        panic!("second light is a spot light: {:?}", imported.lights[1]);
    };
    let spot = &gltf_lights[1];
    let want = vec3(&spot["color"]) * f(&spot["intensity"]) / LM_PER_W;
    assert_close(intensity, want, 1e-4, "spot intensity");
    let watts = f(&objects["SpotLight"]["blender_power_W"]) * vec3(&objects["SpotLight"]["color"]);
    assert_close(
        intensity * 4.0 * std::f32::consts::PI,
        watts,
        1e-2,
        "spot watts",
    );
    assert_close(
        position,
        vec3(&objects["SpotLight"]["gltf_location"]),
        1e-6,
        "spot position",
    );
    let dir = vec3(&objects["SpotLight"]["gltf_direction_world"]);
    assert_close(direction, dir, 2e-6, "spot direction");
    assert!((inner_deg - f(&spot["spot"]["innerConeAngle"]).to_degrees()).abs() < 1e-4);
    assert!(
        (outer_deg - f(&objects["SpotLight"]["gltf_outerConeAngle_expected"]).to_degrees()).abs()
            < 1e-4
    );
    assert!(
        (outer_deg - 22.5).abs() < 1e-4,
        "Blender spot_size 45 deg is a 22.5 deg half-angle"
    );
}

#[test]
fn gltf_camera_follows_its_node() {
    let imported = load_gltf(&data("glass_scene.glb")).unwrap();
    let cam = imported.camera.expect("camera");
    let object = &blender()["objects"]["Camera"];
    let node = readout("glass_scene.glb")["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["camera"] == 0)
        .unwrap()
        .clone();
    assert_close(cam.origin, vec3(&object["gltf_location"]), 1e-6, "origin");
    let forward = (cam.target - cam.origin).normalize();
    assert_close(
        forward,
        vec3(&object["gltf_direction_world"]),
        2e-6,
        "forward",
    );
    let q = &node["rotation_xyzw"];
    let rot = Quat::from_xyzw(f(&q[0]), f(&q[1]), f(&q[2]), f(&q[3]));
    assert_close(cam.up, rot * Vec3::Y, 1e-6, "up");
    assert!(cam.up.dot(forward).abs() < 1e-6);
    assert!((cam.vfov_deg - f(&object["yfov_rad"]).to_degrees()).abs() < 1e-4);
    assert!((cam.vfov_deg - 40.0).abs() < 1e-4);
}

#[test]
fn obj_geometry_and_materials_match_sidecars() {
    let imported = load_obj(&data("glass_scene.obj")).unwrap();
    check_geometry_against_blender(&imported);
    let obj = &sidecar("glass_scene.check.json")["obj"];
    let names: Vec<_> = imported.meshes.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(Value::from(names), obj["objects"]);
    let faces: usize = imported.meshes.iter().map(|m| m.triangles.len()).sum();
    assert_eq!(faces, 4714, "validator's totalTriangleCount");
    assert!(imported.lights.is_empty() && imported.camera.is_none());
    for m in &imported.materials {
        let mtl = &obj["mtl"][m.name.as_str()];
        let want = if m.name.to_lowercase().contains("glass") {
            Material::Dielectric { ior: f(&mtl["Ni"]) }
        } else {
            Material::Lambert {
                reflectance: vec3(&mtl["Kd"]),
            }
        };
        assert_material_eq(m.material, want, &m.name);
    }
    let glass = imported
        .materials
        .iter()
        .filter(|m| matches!(m.material, Material::Dielectric { .. }));
    assert_eq!(glass.count(), 2, "Blender's illum-2 glass is still glass");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write temp file");
    path
}

#[test]
fn obj_material_rules_and_default() {
    let dir = scratch("obj-rules");
    write(
        &dir,
        "rules.mtl",
        "newmtl Plastic\nKd 0.2 0.3 0.4\nillum 2\n\
         newmtl Clear\nKd 1 1 1\nd 0.5\nNi 1.33\n\
         newmtl Refract\nKd 1 1 1\nillum 7\n\
         newmtl WindowGLASS\nKd 1 1 1\nillum 2\nNi 1.6\n",
    );
    let obj = "mtllib rules.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
               o Bare\nf 1 2 3\n\
               o Quad\nusemtl Plastic\nf 1 2 3 4\n\
               o Clear\nusemtl Clear\nf 1 2 3\n\
               o Refract\nusemtl Refract\nf 1 2 3\n\
               o Window\nusemtl WindowGLASS\nf 1 2 3\n\
               o Lines\nl 1 2\n";
    let imported = load_obj(&write(&dir, "rules.obj", obj)).unwrap();
    let material = |name: &str| material_of(&imported, mesh(&imported, name)).material;
    let lambert = |r: Vec3| Material::Lambert { reflectance: r };
    assert_material_eq(
        material("Quad"),
        lambert(Vec3::new(0.2, 0.3, 0.4)),
        "Plastic",
    );
    assert_material_eq(
        material("Clear"),
        Material::Dielectric { ior: 1.33 },
        "Clear",
    );
    assert_material_eq(
        material("Refract"),
        Material::Dielectric { ior: 1.5 },
        "Refract",
    );
    assert_material_eq(
        material("Window"),
        Material::Dielectric { ior: 1.6 },
        "WindowGLASS",
    );
    assert_eq!(
        material_of(&imported, mesh(&imported, "Bare")).name,
        "default"
    );
    assert_material_eq(material("Bare"), lambert(Vec3::splat(0.8)), "default");
    assert_eq!(
        mesh(&imported, "Quad").triangles.len(),
        2,
        "quad triangulated"
    );
    assert!(
        mesh(&imported, "Quad").normals.is_empty(),
        "no vn, flat shading"
    );
    assert!(
        imported.meshes.iter().all(|m| m.name != "Lines"),
        "no triangles, skipped"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn obj_with_missing_mtl_uses_default_material() {
    let dir = scratch("obj-no-mtl");
    let path = write(
        &dir,
        "a.obj",
        "mtllib nowhere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl X\nf 1 2 3\n",
    );
    let imported = load_obj(&path).unwrap();
    assert_eq!(imported.meshes.len(), 1);
    assert_eq!(material_of(&imported, &imported.meshes[0]).name, "default");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn obj_without_triangles_is_an_error() {
    let dir = scratch("obj-empty");
    let path = write(&dir, "empty.obj", "v 0 0 0\nv 1 0 0\nl 1 2\n");
    assert!(matches!(load_obj(&path), Err(Error::Format { .. })));
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn missing_files_are_io_errors() {
    let missing = data("no_such_file");
    assert!(matches!(
        load_obj(&missing.with_extension("obj")),
        Err(Error::Io { .. })
    ));
    assert!(matches!(
        load_gltf(&missing.with_extension("gltf")),
        Err(Error::Io { .. })
    ));
    assert!(matches!(
        load_gltf(&missing.with_extension("glb")),
        Err(Error::Io { .. })
    ));
}

#[test]
fn truncated_files_are_errors_not_panics() {
    let dir = scratch("truncated");
    let glb = std::fs::read(data("glass_scene.glb")).unwrap();
    for cut in [0, 4, 12, 100, glb.len() / 2, glb.len() - 1] {
        let path = dir.join(format!("cut{cut}.glb"));
        std::fs::write(&path, &glb[..cut]).unwrap();
        assert!(load_gltf(&path).is_err(), "glb cut at {cut}");
    }
    let bin = std::fs::read(data("glass_scene.bin")).unwrap();
    std::fs::write(dir.join("glass_scene.bin"), &bin[..bin.len() / 2]).unwrap();
    std::fs::copy(data("glass_scene.gltf"), dir.join("short_bin.gltf")).unwrap();
    assert!(
        load_gltf(&dir.join("short_bin.gltf")).is_err(),
        "short .bin"
    );
    let gltf = std::fs::read(data("glass_scene.gltf")).unwrap();
    std::fs::write(dir.join("cut.gltf"), &gltf[..gltf.len() / 2]).unwrap();
    assert!(matches!(
        load_gltf(&dir.join("cut.gltf")),
        Err(Error::Format { .. })
    ));
    let _ = std::fs::remove_dir_all(dir);
}

/// Writes an edited copy of glass_scene.gltf (with its .bin) into a scratch directory.
fn edited_gltf(test: &str, edit: impl FnOnce(&mut Value)) -> PathBuf {
    let dir = scratch(test);
    std::fs::copy(data("glass_scene.bin"), dir.join("glass_scene.bin")).unwrap();
    let mut doc: Value =
        serde_json::from_slice(&std::fs::read(data("glass_scene.gltf")).unwrap()).unwrap();
    edit(&mut doc);
    write(&dir, "edited.gltf", &doc.to_string())
}

fn field_of(result: ppb::error::Result<Imported>) -> String {
    match result {
        Err(Error::Field { field, .. }) => field,
        other => panic!("expected a field error, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn gltf_refuses_unsupported_required_extensions() {
    let path = edited_gltf("ext-draco", |doc| {
        doc["extensionsRequired"] = json!(["KHR_lights_punctual", "KHR_draco_mesh_compression"]);
    });
    let err = load_gltf(&path);
    assert!(format!("{:?}", err.as_ref().map(|_| ())).contains("KHR_draco_mesh_compression"));
    assert_eq!(field_of(err), "extensionsRequired");

    let path = edited_gltf("ext-ok", |doc| {
        doc["extensionsRequired"] = json!([
            "KHR_lights_punctual",
            "KHR_mesh_quantization",
            "KHR_materials_emissive_strength"
        ]);
    });
    assert!(load_gltf(&path).is_ok(), "listed extensions are accepted");
}

#[test]
fn gltf_refuses_non_triangle_primitives() {
    let path = edited_gltf("mode-lines", |doc| {
        doc["meshes"][2]["primitives"][0]["mode"] = json!(1)
    });
    assert_eq!(field_of(load_gltf(&path)), "meshes[2].primitives[0].mode");
}

#[test]
fn gltf_refuses_out_of_range_indices() {
    // Point GlassSuzanne's indices at the Floor's 4-vertex positions instead.
    let path = edited_gltf("bad-index", |doc| {
        doc["meshes"][2]["primitives"][0]["attributes"]["POSITION"] = json!(0)
    });
    assert_eq!(
        field_of(load_gltf(&path)),
        "meshes[2].primitives[0].attributes.NORMAL"
    );
    let path = edited_gltf("bad-index2", |doc| {
        let attrs = &mut doc["meshes"][2]["primitives"][0]["attributes"];
        attrs["POSITION"] = json!(0);
        attrs.as_object_mut().unwrap().remove("NORMAL");
    });
    assert_eq!(
        field_of(load_gltf(&path)),
        "meshes[2].primitives[0].indices"
    );
}

#[test]
fn gltf_refuses_cyclic_node_hierarchy() {
    let path = edited_gltf("cycle", |doc| {
        doc["nodes"][1]["children"] = json!([2]);
        doc["nodes"][2]["children"] = json!([1]);
    });
    assert_eq!(field_of(load_gltf(&path)), "nodes[1]");
}

/// Hand-made file: composed parent/child transforms, quantized (normalized i16) positions,
/// no indices, no material, a directional light and a spot light with default cone angles.
#[test]
fn gltf_synthetic_hierarchy_quantization_and_lights() {
    let dir = scratch("synthetic");
    let mut bin = Vec::new();
    for p in [[32767i16, 0, 0], [0, 32767, 0], [0, 0, -32767]] {
        p.iter()
            .chain(&[0])
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    std::fs::write(dir.join("q.bin"), &bin).unwrap();
    let doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_mesh_quantization", "KHR_lights_punctual"],
        "extensionsRequired": ["KHR_mesh_quantization", "KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "intensity": 683.0, "color": [1.0, 0.5, 0.25]},
            {"type": "spot", "intensity": 1366.0, "spot": {}}
        ]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 3]}],
        "nodes": [
            {"name": "Parent", "translation": [0, 1, 0], "scale": [2, 2, 2], "children": [1, 2]},
            {"name": "Tri", "mesh": 0, "translation": [1, 0, 0]},
            {"name": "Spot", "translation": [0, 0, 1], "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"name": "Sun", "rotation": [-FRAC_1_SQRT_2, 0, 0, FRAC_1_SQRT_2],
             "extensions": {"KHR_lights_punctual": {"light": 0}}}
        ],
        "meshes": [{"name": "TriMesh", "primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5122, "normalized": true, "count": 3,
                       "type": "VEC3", "min": [0, 0, -32767], "max": [32767, 32767, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": 24, "byteStride": 8}],
        "buffers": [{"uri": "q.bin", "byteLength": 24}]
    });
    let imported = load_gltf(&write(&dir, "synthetic.gltf", &doc.to_string())).unwrap();

    let tri = mesh(&imported, "Tri");
    let want = [
        Vec3::new(4.0, 1.0, 0.0),
        Vec3::new(2.0, 3.0, 0.0),
        Vec3::new(2.0, 1.0, -2.0),
    ];
    for (got, want) in tri.positions.iter().zip(want) {
        assert_close(*got, want, 1e-6, "world position");
    }
    assert_eq!(tri.triangles, [[0, 1, 2]]);
    assert!(tri.normals.is_empty());
    assert_eq!(material_of(&imported, tri).name, "default");
    assert_material_eq(
        material_of(&imported, tri).material,
        Material::Lambert {
            reflectance: Vec3::splat(0.8),
        },
        "default",
    );

    let spot = imported
        .lights
        .iter()
        .find(|l| matches!(l, Light::Spot { .. }))
        .unwrap();
    let Light::Spot {
        position,
        direction,
        intensity,
        inner_deg,
        outer_deg,
    } = *spot
    else {
        unreachable!()
    };
    assert_close(position, Vec3::new(0.0, 1.0, 2.0), 1e-6, "spot position");
    assert_close(direction, Vec3::NEG_Z, 1e-6, "spot direction");
    assert_close(intensity, Vec3::splat(2.0), 1e-6, "spot W/sr");
    assert_eq!((inner_deg, outer_deg), (0.0, 45.0));

    let sun = imported
        .lights
        .iter()
        .find(|l| matches!(l, Light::Directional { .. }))
        .unwrap();
    let Light::Directional {
        direction,
        irradiance,
    } = *sun
    else {
        unreachable!()
    };
    assert_close(direction, Vec3::NEG_Y, 1e-6, "sun direction");
    assert_close(irradiance, Vec3::new(1.0, 0.5, 0.25), 1e-6, "sun W/m^2");
    assert!(imported.camera.is_none());
    let _ = std::fs::remove_dir_all(dir);
}

/// Every file in `dir` appears exactly once in `read` (and nothing else does).
fn assert_each_read_once(dir: &Path, read: &[PathBuf]) {
    let mut got: Vec<PathBuf> = read.to_vec();
    got.sort();
    let mut want: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path().canonicalize().unwrap())
        .collect();
    want.sort();
    assert_eq!(got, want, "files read, in order: {read:?}");
}

/// A scene with a glTF (and its .bin), an OBJ (and its .mtl) and two grid media on one
/// VDB: each file is read from disk once, and the grid's octree cache key is still
/// blake3(VDB bytes, grid name, scale, transform) as before.
#[test]
fn scene_import_reads_each_file_once() {
    use ppb::scene::assets::AssetCache;
    let dir = scratch("read-once");
    for f in [
        "glass_scene.gltf",
        "glass_scene.bin",
        "glass_scene.obj",
        "glass_scene.mtl",
    ] {
        std::fs::copy(data(f), dir.join(f)).unwrap();
    }
    let vdb =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/smoke-grid/density.vdb");
    std::fs::copy(&vdb, dir.join("density.vdb")).unwrap();
    let text = "[camera]\norigin = [0, 1, 5]\ntarget = [0, 0, 0]\nvfov = 40\n\
                [[import]]\npath = \"glass_scene.gltf\"\n[[mesh]]\npath = \"glass_scene.obj\"\n\
                [[light]]\ntype = \"point\"\nposition = [0, 2, 0]\nintensity = [1, 1, 1]\n\
                [[medium]]\ntype = \"grid\"\npath = \"density.vdb\"\ndensity_scale = 8.0\nalbedo = [0.9, 0.9, 0.9]\n\
                [[medium]]\ntype = \"grid\"\npath = \"density.vdb\"\ngrid = \"density\"\ndensity_scale = 4.0\nalbedo = [0.5, 0.5, 0.5]\n\
                transform = { translate = [1, 0, 0] }\n";
    let path = write(&dir, "scene.toml", text);
    let mut cache = AssetCache::new();
    let file = ppb::scene::toml::load_cached(&path, &mut cache).expect("scene loads");
    assert_each_read_once(&dir, &cache.files_read());
    assert_eq!(file.scene.grid_media.len(), 2);

    let bytes = std::fs::read(dir.join("density.vdb")).unwrap();
    let key = |suffix: String| {
        let mut h = blake3::Hasher::new();
        h.update(&bytes);
        h.update(suffix.as_bytes());
        *h.finalize().as_bytes()
    };
    let g = &file.scene.grid_media;
    let id = glam::DAffine3::IDENTITY;
    let moved = glam::DAffine3::from_translation(glam::DVec3::X);
    assert_eq!(g[0].source_hash, key(format!("density 8 {id:?}")));
    assert_eq!(g[1].source_hash, key(format!("density 4 {moved:?}")));
    let _ = std::fs::remove_dir_all(dir);
}

/// One extension dispatch: an unknown import or grid extension is an error naming the
/// scene, the field, the file and the extensions expected.
#[test]
fn unknown_extensions_name_file_and_expected_ones() {
    let dir = scratch("extensions");
    let scene = |extra: &str| {
        format!(
            "[camera]\norigin = [0, 1, 5]\ntarget = [0, 0, 0]\nvfov = 40\n\
             [[light]]\ntype = \"point\"\nposition = [0, 2, 0]\nintensity = [1, 1, 1]\n{extra}"
        )
    };
    let err = |extra: &str| {
        let p = write(&dir, "scene.toml", &scene(extra));
        ppb::scene::toml::load(&p).err().expect("fails").to_string()
    };
    let e = err("[[mesh]]\npath = \"floor.ply\"\n");
    assert!(e.contains("scene.toml: mesh[0].path: "), "{e}");
    assert!(
        e.contains("floor.ply: expected a .obj, .gltf, .glb, .usd, .usda, .usdc or .usdz file"),
        "{e}"
    );
    let e = err("[[medium]]\ntype = \"grid\"\npath = \"smoke.bgeo\"\ndensity_scale = 1.0\nalbedo = [0.9, 0.9, 0.9]\n");
    assert!(e.contains("scene.toml: medium[0].path: "), "{e}");
    assert!(
        e.contains("smoke.bgeo: expected a .vdb or .nvdb file"),
        "{e}"
    );
    let e = ppb::scene::toml::load(&data("glass_scene.obj"))
        .err()
        .expect("an OBJ is not a scene")
        .to_string();
    assert!(e.contains("glass_scene.obj: not a scene file"), "{e}");
    let _ = std::fs::remove_dir_all(dir);
}
