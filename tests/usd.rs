//! USD import against the glass-and-smoke stage and the values Pixar's library reports
//! for it (`glass_smoke.usd.json`), plus synthetic stages for transforms, units, up
//! axis, and bad input (malformed, truncated, missing VDB, unsupported prims).
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

use glam::Vec3;
use ppb::scene::usd::load_usd;
use ppb::scene::{Imported, Light, Material, Mesh};
use serde_json::Value;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/usd/stage/");

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
}

fn reference() -> Value {
    let text = std::fs::read_to_string(data("glass_smoke.usd.json")).expect("json readable");
    serde_json::from_str(&text).expect("json parses")
}

fn prim<'a>(j: &'a Value, path: &str) -> &'a Value {
    &j["stage"]["prims"][path]
}

fn v3(v: &Value) -> Vec3 {
    let a = v.as_array().expect("array of 3");
    Vec3::new(
        a[0].as_f64().unwrap() as f32,
        a[1].as_f64().unwrap() as f32,
        a[2].as_f64().unwrap() as f32,
    )
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

fn mesh<'a>(imp: &'a Imported, name: &str) -> &'a Mesh {
    imp.meshes
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("mesh {name} imported"))
}

fn bbox(m: &Mesh) -> (Vec3, Vec3) {
    let lo = m.positions.iter().fold(Vec3::MAX, |a, &p| a.min(p));
    let hi = m.positions.iter().fold(Vec3::MIN, |a, &p| a.max(p));
    (lo, hi)
}

/// A scratch folder for synthetic stages, unique per test.
fn scratch(test: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("usd-{test}"));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch dir");
    d
}

fn write_stage(dir: &Path, name: &str, body: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, body).expect("write stage");
    p
}

fn check_stage(file: &str) {
    let j = reference();
    let imp = load_usd(&data(file)).expect("stage imports");
    assert_eq!(imp.meshes.len(), 3, "Floor, GlassSphere, GlassTorus");
    for name in ["/World/Floor", "/World/GlassTorus"] {
        let m = mesh(&imp, name);
        let p = prim(&j, name);
        assert_eq!(m.positions.len() as u64, p["points"].as_u64().unwrap());
        // Every face of the stage is a quad: two fan triangles each.
        assert_eq!(m.triangles.len() as u64, 2 * p["faces"].as_u64().unwrap());
        assert_eq!(m.normals.len(), if name == "/World/Floor" { 4 } else { 0 });
    }
    // The torus and the sphere are centred on their translation; the floor is y = 0.
    let (lo, hi) = bbox(mesh(&imp, "/World/GlassTorus"));
    let t = v3(&prim(&j, "/World/GlassTorus")["world_translation"]);
    assert!(close((lo + hi) * 0.5, t, 1e-3), "{lo} {hi} vs {t}");
    let sphere = mesh(&imp, "/World/GlassSphere");
    let (lo, hi) = bbox(sphere);
    let t = v3(&prim(&j, "/World/GlassSphere")["world_translation"]);
    let r = prim(&j, "/World/GlassSphere")["radius"].as_f64().unwrap() as f32;
    assert!(close((lo + hi) * 0.5, t, 1e-3));
    assert!(close(hi - lo, Vec3::splat(2.0 * r), 1e-3));
    let (lo, hi) = bbox(mesh(&imp, "/World/Floor"));
    assert_eq!((lo.y, hi.y), (0.0, 0.0));

    check_materials(&imp);
    check_lights(&j, &imp);
    check_camera(&j, &imp);
    check_volume(&imp);
    assert!(imp
        .notes
        .contains(&"imported Mesh /World/Floor (2 triangles)".to_string()));
}

fn check_materials(imp: &Imported) {
    let mat = |name: &str| imp.materials[mesh(imp, name).material].material;
    assert_eq!(
        mat("/World/Floor"),
        Material::Lambert {
            reflectance: Vec3::splat(0.5)
        }
    );
    for glass in ["/World/GlassSphere", "/World/GlassTorus"] {
        assert_eq!(mat(glass), Material::Dielectric { ior: 1.5 });
    }
}

fn check_lights(j: &Value, imp: &Imported) {
    assert_eq!(imp.lights.len(), 2);
    let pl = prim(j, "/World/PointLight");
    let r = pl["radius"].as_f64().unwrap() as f32;
    let l = pl["intensity"].as_f64().unwrap() as f32
        * 2f32.powf(pl["exposure"].as_f64().unwrap() as f32)
        * v3(&pl["color"]);
    match imp.lights[0] {
        Light::Point {
            position,
            intensity,
        } => {
            assert!(close(position, v3(&pl["world_translation"]), 1e-6));
            // Point-like sphere light: radiant intensity L * pi * r^2 (W/sr).
            assert!(close(intensity, l * PI * r * r, 1e-4), "{intensity}");
        }
        ref other => panic!("expected a point light, got {other:?}"),
    }
    let sun = prim(j, "/World/Sun");
    match imp.lights[1] {
        Light::Directional {
            direction,
            irradiance,
        } => {
            assert!(
                close(direction, v3(&sun["direction_world"]), 1e-5),
                "{direction}"
            );
            let e = sun["intensity"].as_f64().unwrap() as f32 * v3(&sun["color"]);
            assert!(close(irradiance, e, 1e-6));
        }
        ref other => panic!("expected a directional light, got {other:?}"),
    }
}

fn check_camera(j: &Value, imp: &Imported) {
    let c = imp.camera.expect("camera imported");
    let cj = prim(j, "/World/Camera");
    assert!(close(c.origin, v3(&cj["world_translation"]), 1e-6));
    let dir = (c.target - c.origin).normalize();
    assert!(close(dir, v3(&cj["view_direction_world"]), 1e-5), "{dir}");
    let vfov = cj["vertical_fov_deg"].as_f64().unwrap() as f32;
    assert!((c.vfov_deg - vfov).abs() < 1e-4, "{}", c.vfov_deg);
    // Row 1 of the authored xformOp:transform is the camera's +Y.
    assert!(
        close(c.up, Vec3::new(0.0, 0.966_235, -0.257_663), 1e-5),
        "{}",
        c.up
    );
}

fn check_volume(imp: &Imported) {
    assert_eq!(imp.grid_media.len(), 1);
    let g = &imp.grid_media[0];
    assert_eq!(g.density_scale, 1.0);
    assert_eq!(g.albedo, Vec3::splat(0.9));
    assert_eq!(g.phase.g, 0.0);
    // The stage's authored extent of the Volume (the VDB's own index-to-world map).
    let lo = Vec3::new(-0.539_062_5, -0.007_812_5, -1.304_687_5);
    let hi = Vec3::new(1.054_687_5, 1.804_687_5, 0.195_312_5);
    // The medium's bounds are whole 8^3 leaves (voxel 1/32 m): they hold the extent
    // and reach at most one leaf past it.
    let leaf = 8.0 / 32.0 + 1e-4;
    assert!(g.bounds[0].cmple(lo).all() && g.bounds[0].cmpge(lo - leaf).all());
    assert!(g.bounds[1].cmpge(hi).all() && g.bounds[1].cmple(hi + leaf).all());
    assert!(g.source.contains("smoke_plume.vdb"));
}

#[test]
fn usda_matches_pixar_readout() {
    check_stage("glass_smoke.usda");
}

#[test]
fn usdc_matches_pixar_readout() {
    check_stage("glass_smoke.usdc");
}

#[test]
fn usda_and_usdc_agree() {
    let a = load_usd(&data("glass_smoke.usda")).unwrap();
    let c = load_usd(&data("glass_smoke.usdc")).unwrap();
    assert_eq!(a.lights, c.lights);
    assert_eq!(a.camera, c.camera);
    assert_eq!(a.materials, c.materials);
    for (x, y) in a.meshes.iter().zip(&c.meshes) {
        assert_eq!(x.positions, y.positions);
        assert_eq!(x.triangles, y.triangles);
    }
}

#[test]
fn stage_renders_as_a_scene_file() {
    let f = ppb::scene::toml::load(&data("glass_smoke.usda")).expect("usda as scene");
    assert_eq!(f.scene.meshes.len(), 3);
    assert_eq!(f.scene.lights.len(), 2);
    assert_eq!(f.scene.grid_media.len(), 1);
    assert!((f.scene.camera.vfov_deg - 30.219_15).abs() < 1e-4);
    assert!(f.notes.iter().any(|n| n.contains("/World/Smoke")));
}

#[test]
fn toml_import_of_a_stage() {
    let dir = Path::new(DATA);
    let text = "[[import]]\npath = \"glass_smoke.usdc\"\n[render]\nwidth = 8\nheight = 8\n";
    let f = ppb::scene::toml::parse(&dir.join("scene.toml"), text).expect("scene parses");
    assert_eq!(f.scene.meshes.len(), 3);
    assert_eq!(f.scene.grid_media.len(), 1);
    assert_eq!(f.settings.width, 8);
    assert!(f.scene.materials.len() >= 2);
}

#[test]
fn sidecar_overrides_settings() {
    let dir = scratch("sidecar");
    // A copy of the stage whose Volume names the shipped VDB by absolute path, plus a
    // sidecar with render settings.
    let text = std::fs::read_to_string(data("glass_smoke.usda")).unwrap();
    let vdb = Path::new(DATA).join("../smoke_plume.vdb");
    let text = text.replace("../smoke_plume.vdb", &vdb.display().to_string());
    std::fs::write(dir.join("glass_smoke.usda"), text).unwrap();
    std::fs::write(
        dir.join("glass_smoke.ppb.toml"),
        "[render]\nwidth = 16\nheight = 12\n",
    )
    .unwrap();
    let f = ppb::scene::toml::load(&dir.join("glass_smoke.usda")).expect("loads");
    assert_eq!((f.settings.width, f.settings.height), (16, 12));
    assert_eq!(f.scene.grid_media.len(), 1);
}

const HEADER: &str = "#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = \"Y\"\n)\n";

#[test]
fn xform_ops_compose_in_order_and_through_parents() {
    let dir = scratch("xform");
    let body = format!(
        r#"{HEADER}
def Xform "Root"
{{
    double3 xformOp:translate = (10, 0, 0)
    float xformOp:rotateY = 90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]

    def Mesh "Tri"
    {{
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
        double3 xformOp:scale = (2, 2, 2)
        double3 xformOp:translate = (0, 0, 1)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }}
    def Mesh "Oriented"
    {{
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
        quatf xformOp:orient = (0.70710677, 0, 0, 0.70710677)
        uniform token[] xformOpOrder = ["!resetXformStack!", "xformOp:orient"]
    }}
}}
def SphereLight "L"
{{
    float inputs:radius = 0
    float inputs:intensity = 2
    float inputs:exposure = 1
}}
"#
    );
    let p = write_stage(&dir, "x.usda", &body);
    let imp = load_usd(&p).expect("imports");
    // Local: scale 2 then translate z+1; parent: rotateY 90 then translate x+10.
    // (1,0,0) -> (2,0,1) -> rotY90 (x,z)->(z,-x): (1,0,-2) -> (11,0,-2).
    let m = mesh(&imp, "/Root/Tri");
    assert!(
        close(m.positions[0], Vec3::new(11.0, 0.0, -2.0), 1e-5),
        "{:?}",
        m.positions
    );
    assert!(close(m.positions[1], Vec3::new(11.0, 2.0, 0.0), 1e-5));
    // resetXformStack drops the parent; orient is 90 degrees about Z.
    let o = mesh(&imp, "/Root/Oriented");
    assert!(
        close(o.positions[0], Vec3::new(0.0, 1.0, 0.0), 1e-5),
        "{:?}",
        o.positions
    );
    // radius 0: intensity read as W/sr, times 2^exposure, colour fallback white.
    assert_eq!(
        imp.lights,
        vec![Light::Point {
            position: Vec3::ZERO,
            intensity: Vec3::splat(4.0)
        }]
    );
    // Unbound meshes take UsdPreviewSurface's grey.
    assert_eq!(
        imp.materials[m.material].material,
        Material::Lambert {
            reflectance: Vec3::splat(0.18)
        }
    );
}

#[test]
fn z_up_centimetre_stage_becomes_y_up_metres() {
    let dir = scratch("zup");
    let body = r#"#usda 1.0
(
    metersPerUnit = 0.01
    upAxis = "Z"
)
def Mesh "Tri"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(100, 0, 0), (0, 100, 0), (0, 0, 100)]
}
def SphereLight "Big"
{
    float inputs:radius = 50
    double3 xformOp:translate = (0, 0, 300)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Camera "Cam"
{
}
"#;
    let p = write_stage(&dir, "z.usda", body);
    let imp = load_usd(&p).expect("imports");
    let m = mesh(&imp, "/Tri");
    let want = [
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    for (a, b) in m.positions.iter().zip(want) {
        assert!(close(*a, b, 1e-6), "{:?}", m.positions);
    }
    match imp.lights[0] {
        Light::Sphere {
            center,
            radius,
            radiance,
        } => {
            assert!(close(center, Vec3::new(0.0, 3.0, 0.0), 1e-6));
            assert!((radius - 0.5).abs() < 1e-6);
            assert_eq!(radiance, Vec3::ONE);
        }
        ref other => panic!("expected a sphere light, got {other:?}"),
    }
    // Camera fallbacks: focalLength 50, verticalAperture 15.2908. Its own -Z is "down"
    // in a Z-up stage, so world -Y; its +Y maps to world -Z.
    let c = imp.camera.expect("camera");
    let vfov = 2.0 * (15.2908f32 / 100.0).atan().to_degrees();
    assert!((c.vfov_deg - vfov).abs() < 1e-4);
    assert!(close(c.target - c.origin, Vec3::new(0.0, -1.0, 0.0), 1e-6));
    assert!(close(c.up, Vec3::new(0.0, 0.0, -1.0), 1e-6));
}

#[test]
fn polygons_fan_triangulate_and_face_varying_normals() {
    let dir = scratch("fan");
    let body = format!(
        r#"{HEADER}
def Mesh "Penta"
{{
    int[] faceVertexCounts = [5, 3]
    int[] faceVertexIndices = [0, 1, 2, 3, 4, 0, 4, 5]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (2, 1, 0), (1, 2, 0), (0, 1, 0), (-1, 1, 0)]
    normal3f[] normals = [(0,0,1),(0,0,1),(0,0,1),(0,0,1),(0,0,1),(0,0,1),(0,0,1),(0,0,1)] (
        interpolation = "faceVarying"
    )
}}
def Mesh "Split"
{{
    int[] faceVertexCounts = [3, 3]
    int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 1)]
    normal3f[] normals = [(0,0,1),(0,0,1),(0,0,1),(1,0,0),(1,0,0),(1,0,0)] (
        interpolation = "faceVarying"
    )
}}
"#
    );
    let p = write_stage(&dir, "fan.usda", &body);
    let imp = load_usd(&p).expect("imports");
    let m = mesh(&imp, "/Penta");
    assert_eq!(
        m.triangles,
        vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]
    );
    assert_eq!(m.normals, vec![Vec3::Z; 6]);
    // Corners of vertex 0 disagree: no per-vertex normals can be kept.
    assert!(mesh(&imp, "/Split").normals.is_empty());
}

#[test]
fn unsupported_prims_are_listed() {
    let dir = scratch("unsupported");
    let body = format!(
        r#"{HEADER}
def Xform "World"
{{
    def Cube "Foo"
    {{
    }}
    def RectLight "Panel"
    {{
    }}
    def Mesh "Tri"
    {{
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    }}
}}
"#
    );
    let p = write_stage(&dir, "u.usda", &body);
    let imp = load_usd(&p).expect("imports");
    assert!(imp
        .notes
        .contains(&"ignored Cube /World/Foo: unsupported prim type".to_string()));
    assert!(imp
        .notes
        .contains(&"ignored RectLight /World/Panel: unsupported prim type".to_string()));
    assert!(imp
        .notes
        .contains(&"imported Mesh /World/Tri (1 triangles)".to_string()));
}

/// A DomeLight is an environment of intensity x 2^exposure x color, turned by its world
/// transform's rotation: constant without a texture, else its lat-long map (read, and
/// listed among the files the stage read). Other texture formats are left out with a
/// note; a missing map is an error naming the prim and the file.
#[test]
fn dome_lights_become_environments_with_their_transform() {
    let dir = scratch("dome");
    exr::prelude::write_rgb_file(dir.join("sky.exr"), 8, 4, |i, j| {
        if (i, j) == (2, 1) {
            (9.0, 8.0, 7.0)
        } else {
            (0.1, 0.2, 0.3)
        }
    })
    .expect("writes the map");
    let body = format!(
        r#"{HEADER}
def Xform "World"
{{
    def DomeLight "Sky"
    {{
        float inputs:intensity = 2
        float inputs:exposure = 1
        color3f inputs:color = (0.5, 1, 0.25)
        double3 xformOp:rotateXYZ = (0, 90, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
    def DomeLight "Map"
    {{
        float inputs:intensity = 3
        asset inputs:texture:file = @sky.exr@
        token inputs:texture:format = "latlong"
        double3 xformOp:rotateXYZ = (0, -90, 0)
        double3 xformOp:scale = (2, 2, 2)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ", "xformOp:scale"]
    }}
    def DomeLight "Ball"
    {{
        asset inputs:texture:file = @sky.exr@
        token inputs:texture:format = "mirroredBall"
    }}
}}
"#
    );
    let p = write_stage(&dir, "dome.usda", &body);
    let imp = load_usd(&p).expect("imports");
    assert_eq!(imp.lights.len(), 2, "{:?}", imp.notes);
    let Light::Environment(sky) = &imp.lights[0] else {
        panic!("expected an environment, got {:?}", imp.lights[0])
    };
    assert_eq!(sky.radiance, Vec3::new(2.0, 4.0, 1.0));
    assert!(sky.map.is_none());
    let turned = |deg: f32| glam::Mat3::from_rotation_y(deg.to_radians());
    assert!(
        sky.to_world.abs_diff_eq(turned(90.0), 1e-6),
        "{}",
        sky.to_world
    );
    let Light::Environment(map) = &imp.lights[1] else {
        panic!("expected an environment, got {:?}", imp.lights[1])
    };
    assert_eq!(map.radiance, Vec3::splat(3.0));
    assert_eq!(map.map.as_ref().expect("the map is read").size(), (8, 4));
    assert!(
        map.to_world.abs_diff_eq(turned(-90.0), 1e-6),
        "{}",
        map.to_world
    );
    // Texel (2, 1)'s centre, u = 2.5 / 8 and v = 1.5 / 4, seen in the world turned by -90.
    let m = ppb::scene::environment::uv_to_dir(glam::Vec2::new(2.5 / 8.0, 1.5 / 4.0));
    let seen = map.eval(turned(-90.0) * m);
    assert!(
        (seen - Vec3::new(27.0, 24.0, 21.0)).length() < 1e-3,
        "{seen}"
    );
    assert!(
        imp.files.iter().any(|f| f.ends_with("sky.exr")),
        "{:?}",
        imp.files
    );
    assert!(imp.notes.iter().any(|n| n
        == "ignored DomeLight /World/Ball: texture format \"mirroredBall\" (only latlong maps are read)"));

    let missing = body.replace("@sky.exr@", "@nowhere.exr@");
    let p = write_stage(&dir, "missing.usda", &missing);
    let e = load_usd(&p).expect_err("the map is missing").to_string();
    assert!(e.contains("/World/Map") && e.contains("nowhere.exr"), "{e}");
}

fn err_text(p: &Path) -> String {
    match load_usd(p) {
        Ok(_) => panic!("{} should not import", p.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn missing_vdb_is_an_error_naming_the_prim() {
    let dir = scratch("missing-vdb");
    let body = format!(
        r#"{HEADER}
def Volume "Smoke"
{{
    custom rel field:density = </Smoke/density>
    def OpenVDBAsset "density"
    {{
        token fieldName = "density"
        asset filePath = @nowhere.vdb@
    }}
}}
"#
    );
    let p = write_stage(&dir, "v.usda", &body);
    let e = err_text(&p);
    assert!(e.contains("v.usda"), "{e}");
    assert!(e.contains("/Smoke/density"), "{e}");
    assert!(e.contains("nowhere.vdb"), "{e}");
}

#[test]
fn malformed_and_truncated_stages_are_errors() {
    let dir = scratch("malformed");
    let p = write_stage(
        &dir,
        "bad.usda",
        "#usda 1.0\ndef Mesh \"X\" {\n  int[] = [1,\n",
    );
    let e = err_text(&p);
    assert!(e.contains("bad.usda"), "{e}");

    let bytes = std::fs::read(data("glass_smoke.usdc")).unwrap();
    for cut in [16, 100, bytes.len() / 2, bytes.len() - 64] {
        let p = dir.join(format!("cut{cut}.usdc"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let e = err_text(&p);
        assert!(e.contains(&format!("cut{cut}.usdc")), "{e}");
    }
    let e = err_text(&dir.join("absent.usda"));
    assert!(e.contains("absent.usda"), "{e}");
}

#[test]
fn bad_mesh_indices_are_errors_naming_the_prim() {
    let dir = scratch("bad-mesh");
    let body = format!(
        r#"{HEADER}
def Mesh "Broken"
{{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 7]
    point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
}}
"#
    );
    let p = write_stage(&dir, "m.usda", &body);
    let e = err_text(&p);
    assert!(e.contains("/Broken"), "{e}");
}

#[test]
fn missing_sublayer_is_reported() {
    let dir = scratch("sublayer");
    let body = "#usda 1.0\n(\n    subLayers = [@gone.usda@]\n)\ndef Xform \"W\"\n{\n}\n";
    let p = write_stage(&dir, "s.usda", body);
    let e = err_text(&p);
    assert!(e.contains("s.usda"), "{e}");
}

/// Rows of a USD `matrix4d` (row vectors: X, Y, Z axes, then the translation) for a
/// frame whose -Z looks along `fwd` with `up` as its +Y hint.
fn look_matrix(origin: Vec3, fwd: Vec3, up: Vec3) -> String {
    let z = -fwd.normalize();
    let x = up.cross(z).normalize();
    let y = z.cross(x);
    let row = |v: Vec3, w: f32| format!("({}, {}, {}, {w})", v.x, v.y, v.z);
    format!(
        "( {}, {}, {}, {} )",
        row(x, 0.0),
        row(y, 0.0),
        row(z, 0.0),
        row(origin, 1.0)
    )
}

/// The smoke-grid conformance scene (floor, sun, OpenVDB smoke) as a USD stage.
fn smoke_grid_stage(vdb: &Path) -> String {
    let sun = Vec3::new(-0.357_770_9, -0.894_427_2, -0.268_328_2);
    let eye = Vec3::new(0.0, 1.5, 5.0);
    let cam = look_matrix(eye, Vec3::new(0.0, 0.8, 0.0) - eye, Vec3::Y);
    let sun_m = look_matrix(Vec3::ZERO, sun, Vec3::Y);
    let aperture = 100.0 * 20f32.to_radians().tan();
    format!(
        r#"{HEADER}
def Material "Floor"
{{
    token outputs:surface.connect = </Floor/S.outputs:surface>
    def Shader "S"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = (0.5, 0.5, 0.5)
        token outputs:surface
    }}
}}
def Mesh "Ground" (prepend apiSchemas = ["MaterialBindingAPI"])
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 3, 2, 1]
    point3f[] points = [(-3, 0, -3), (3, 0, -3), (3, 0, 3), (-3, 0, 3)]
    normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (interpolation = "vertex")
    rel material:binding = </Floor>
}}
def DistantLight "Sun"
{{
    float inputs:intensity = 3
    matrix4d xformOp:transform = {sun_m}
    uniform token[] xformOpOrder = ["xformOp:transform"]
}}
def Camera "Cam"
{{
    float focalLength = 50
    float verticalAperture = {aperture}
    matrix4d xformOp:transform = {cam}
    uniform token[] xformOpOrder = ["xformOp:transform"]
}}
def Volume "Smoke"
{{
    custom float ppb:densityScale = 8
    custom color3f ppb:albedo = (0.9, 0.9, 0.9)
    rel field:density = </Smoke/density>
    def OpenVDBAsset "density"
    {{
        token fieldName = "density"
        asset filePath = @{}@
    }}
}}
"#,
        vdb.display()
    )
}

fn render_mean(scene: &ppb::scene::Scene) -> (Vec<[f32; 3]>, f64) {
    use ppb::settings::RenderSettings;
    let s = RenderSettings {
        width: 24,
        height: 24,
        passes: 4,
        light_paths: 20_000,
        seed: 7,
        ..Default::default()
    };
    let r = ppb::pass::Tracer::new(scene, s).expect("renderer");
    let img = ppb::session::Session::cpu(r)
        .render(4)
        .expect("render")
        .pixels;
    let mean = img.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>() / img.len() as f64;
    (img, mean)
}

/// The USD stage and the hand-written TOML scene it mirrors render alike.
#[test]
fn stage_renders_like_the_equivalent_toml_scene() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let conf = root.join("scenes/conformance/smoke-grid");
    let dir = scratch("render");
    let stage = write_stage(
        &dir,
        "smoke.usda",
        &smoke_grid_stage(&conf.join("density.vdb")),
    );
    let usd = ppb::scene::toml::load(&stage).expect("stage loads");
    let toml_text = std::fs::read_to_string(conf.join("scene.toml")).unwrap();
    let toml = ppb::scene::toml::parse(&conf.join("scene.toml"), &toml_text).expect("toml");
    let c = usd.scene.camera;
    assert!(close(c.origin, toml.scene.camera.origin, 1e-5));
    assert!((c.vfov_deg - 40.0).abs() < 1e-3);
    let (a, ma) = render_mean(&usd.scene);
    let (b, mb) = render_mean(&toml.scene);
    eprintln!("mean pixel sum: USD {ma}, TOML {mb}");
    assert!(ma > 0.0 && mb > 0.0);
    assert!((ma - mb).abs() < 0.03 * mb, "mean {ma} vs {mb}");
    // 6x6 blocks of 4x4 pixels agree within noise.
    for by in 0..6 {
        for bx in 0..6 {
            let sum = |img: &[[f32; 3]]| {
                let mut s = 0.0f64;
                for y in 0..4 {
                    for x in 0..4 {
                        let p = img[(by * 4 + y) * 24 + bx * 4 + x];
                        s += (p[0] + p[1] + p[2]) as f64;
                    }
                }
                s
            };
            let (sa, sb) = (sum(&a), sum(&b));
            assert!(
                (sa - sb).abs() <= 0.1 * sb.max(sa) + 1e-3,
                "block {bx},{by}: {sa} vs {sb}"
            );
        }
    }
}

#[test]
fn usdz_package_imports() {
    let top = scratch("usdz");
    let dir = top.join("pkg");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("pkg.usdz");
    let mut w = openusd::usdz::ArchiveWriter::create(&p).expect("create usdz");
    let bytes = std::fs::read(data("glass_smoke.usdc")).unwrap();
    w.add_layer("glass_smoke.usdc", &bytes).expect("add layer");
    w.finish().expect("finish usdz");
    // The packaged stage's ../smoke_plume.vdb resolves next to the package: absent here.
    let e = err_text(&p);
    assert!(e.contains("/World/Smoke/density"), "{e}");
    std::fs::copy(data("../smoke_plume.vdb"), top.join("smoke_plume.vdb")).unwrap();
    let imp = load_usd(&p).expect("usdz imports");
    assert_eq!(imp.meshes.len(), 3);
    assert_eq!(imp.lights.len(), 2);
    assert!(imp.camera.is_some());
}

#[test]
fn invisible_and_guide_prims_are_skipped() {
    let dir = scratch("hidden");
    let body = format!(
        r#"{HEADER}
def Xform "Hidden"
{{
    token visibility = "invisible"
    def Mesh "A"
    {{
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    }}
}}
def Mesh "Guide"
{{
    uniform token purpose = "guide"
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
}}
def Mesh "Shown"
{{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
}}
"#
    );
    let imp = load_usd(&write_stage(&dir, "h.usda", &body)).expect("imports");
    assert_eq!(imp.meshes.len(), 1);
    assert_eq!(imp.meshes[0].name, "/Shown");
    assert!(imp
        .notes
        .iter()
        .any(|n| n.starts_with("ignored Mesh /Hidden/A")));
    assert!(imp
        .notes
        .iter()
        .any(|n| n.starts_with("ignored Mesh /Guide")));
}

#[test]
fn missing_referenced_layer_is_reported() {
    let dir = scratch("reference");
    let body =
        format!("{HEADER}\ndef Xform \"W\" (\n    references = @gone.usda@</X>\n)\n{{\n}}\n");
    let e = err_text(&write_stage(&dir, "r.usda", &body));
    assert!(e.contains("r.usda"), "{e}");
    assert!(e.contains("gone.usda"), "{e}");
}

#[test]
fn info_lists_imported_and_ignored_prims() {
    let dir = scratch("info");
    let body = format!(
        r#"{HEADER}
def Cube "Box"
{{
}}
def DistantLight "Sun"
{{
}}
def Camera "Cam"
{{
}}
"#
    );
    let p = write_stage(&dir, "i.usda", &body);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_ppb"))
        .arg("info")
        .arg(&p)
        .output()
        .expect("ppb runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("ignored Cube /Box: unsupported prim type"),
        "{text}"
    );
    assert!(text.contains("imported DistantLight /Sun"), "{text}");
    assert!(text.contains("imported Camera /Cam"), "{text}");
}

#[test]
fn instanced_prims_are_imported_through_proxies() {
    let dir = scratch("instances");
    let body = format!(
        r#"{HEADER}
def Xform "Proto"
{{
    def Mesh "Tri"
    {{
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    }}
}}
def Xform "A" (
    instanceable = true
    references = </Proto>
)
{{
    double3 xformOp:translate = (5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def Xform "B" (
    instanceable = true
    references = </Proto>
)
{{
    double3 xformOp:translate = (0, 5, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"#
    );
    let imp = load_usd(&write_stage(&dir, "inst.usda", &body)).expect("imports");
    let names: Vec<&str> = imp.meshes.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["/Proto/Tri", "/A/Tri", "/B/Tri"], "{:?}", imp.notes);
    assert!(close(
        mesh(&imp, "/A/Tri").positions[0],
        Vec3::new(6.0, 0.0, 0.0),
        1e-6
    ));
    assert!(close(
        mesh(&imp, "/B/Tri").positions[0],
        Vec3::new(1.0, 5.0, 0.0),
        1e-6
    ));
}

/// A USD scene (root `.usd` that the reader peeks then reads, a sublayer, a Volume on
/// a VDB) and a .usdz package: each file is read from disk once per load, through the
/// asset cache's reader, and the Volume's octree key is blake3(VDB bytes, grid name,
/// scale, transform) as before.
#[test]
fn usd_scene_reads_each_file_once() {
    use ppb::scene::assets::AssetCache;
    let dir = scratch("read-once");
    let vdb = data("../smoke_plume.vdb");
    std::fs::copy(&vdb, dir.join("smoke.vdb")).unwrap();
    let layer = format!(
        r#"{HEADER}
def DistantLight "Sun"
{{
    float inputs:intensity = 3
}}
def Camera "Cam"
{{
}}
"#
    );
    write_stage(&dir, "lights.usda", &layer);
    let root = r#"#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
    subLayers = [@lights.usda@]
)
def Volume "Smoke"
{
    custom float ppb:densityScale = 8
    rel field:density = </Smoke/density>
    def OpenVDBAsset "density"
    {
        token fieldName = "density"
        asset filePath = @smoke.vdb@
    }
}
"#;
    let stage = write_stage(&dir, "stage.usd", root);
    let mut cache = AssetCache::new();
    let file = ppb::scene::toml::load_cached(&stage, &mut cache).expect("stage loads");
    let mut read = cache.files_read();
    read.sort();
    let mut want: Vec<PathBuf> = ["lights.usda", "smoke.vdb", "stage.usd"]
        .iter()
        .map(|f| dir.join(f).canonicalize().unwrap())
        .collect();
    want.sort();
    assert_eq!(read, want, "{:?}", cache.files_read());
    let g = &file.scene.grid_media;
    assert_eq!(g.len(), 1);
    assert_eq!(g[0].density_scale, 8.0);
    let mut h = blake3::Hasher::new();
    h.update(&std::fs::read(&vdb).unwrap());
    h.update(format!("density 8 {:?}", glam::DAffine3::IDENTITY).as_bytes());
    assert_eq!(g[0].source_hash, *h.finalize().as_bytes());

    // A .usdz: the package is read once for the hash, the root layer and its lookups.
    let pkg = dir.join("pkg");
    std::fs::create_dir_all(&pkg).unwrap();
    let p = pkg.join("pkg.usdz");
    let mut w = openusd::usdz::ArchiveWriter::create(&p).expect("create usdz");
    let bytes = std::fs::read(data("glass_smoke.usdc")).unwrap();
    w.add_layer("glass_smoke.usdc", &bytes).expect("add layer");
    w.finish().expect("finish usdz");
    std::fs::copy(&vdb, dir.join("smoke_plume.vdb")).unwrap();
    let mut cache = AssetCache::new();
    ppb::scene::toml::load_cached(&p, &mut cache).expect("usdz loads");
    let mut read = cache.files_read();
    read.sort();
    let mut want = vec![
        p.canonicalize().unwrap(),
        dir.join("smoke_plume.vdb").canonicalize().unwrap(),
    ];
    want.sort();
    assert_eq!(read, want, "{:?}", cache.files_read());
}

/// The Volume's `ppb:*` parameters go through the same checks as a TOML medium's:
/// errors name the stage, the attribute (as a property path) and what was expected.
#[test]
fn volume_parameters_are_checked_like_toml_media() {
    let dir = scratch("volume-params");
    std::fs::copy(data("../smoke_plume.vdb"), dir.join("smoke.vdb")).unwrap();
    let stage = |attrs: &str| {
        format!(
            r#"{HEADER}
def Volume "Smoke"
{{
    {attrs}
    rel field:density = </Smoke/density>
    def OpenVDBAsset "density"
    {{
        token fieldName = "density"
        asset filePath = @smoke.vdb@
    }}
}}
"#
        )
    };
    let e = err_text(&write_stage(
        &dir,
        "a.usda",
        &stage("custom color3f ppb:albedo = (0.5, 1.5, 0.5)"),
    ));
    assert!(
        e.contains("a.usda: /Smoke.ppb:albedo: expected values in [0, 1]"),
        "{e}"
    );
    let e = err_text(&write_stage(
        &dir,
        "s.usda",
        &stage("custom float ppb:densityScale = -2"),
    ));
    assert!(
        e.contains("s.usda: /Smoke.ppb:densityScale: expected a finite number >= 0, got -2"),
        "{e}"
    );
    let e = err_text(&write_stage(
        &dir,
        "g.usda",
        &stage("custom float ppb:g = 1"),
    ));
    assert!(
        e.contains("g.usda: /Smoke.ppb:g: expected g in (-1, 1)"),
        "{e}"
    );
    let imp = load_usd(&write_stage(
        &dir,
        "ok.usda",
        &stage("custom float ppb:g = 0.5"),
    ))
    .expect("imports");
    assert_eq!(imp.grid_media[0].phase.g, 0.5);
    assert_eq!(imp.grid_media[0].albedo, Vec3::splat(0.9));
}
