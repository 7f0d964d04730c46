//! The OpenVDB reader against real files (OpenVDB 10 and 13, vdb_tool, Blender Mantaflow)
//! and their JSON sidecars / dense `.npy` truth, plus corrupt and hand-built variants.
use glam::{DVec3, IVec3};
use ppb::error::Error;
use ppb::media::grid::Grid;
use ppb::media::openvdb::{list_grids, load_grid, GridDescriptor};
use serde_json::Value;
use std::io::Read;
use std::path::{Path, PathBuf};

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/vdb/");

/// The plume-family files whose sidecar has `header.grids_in_file_order` and `grids[]`.
const PLUME_FILES: [&str; 9] = [
    "smoke_plume",
    "smoke_plume_ovdb10",
    "smoke_plume_none",
    "smoke_plume_active",
    "smoke_plume_zip",
    "half_precision",
    "half_precision_zip",
    "multi_grid",
    "multi_grid_zip",
];
const MANTA_FILES: [&str; 3] = [
    "manta_smoke_0016.vdb",
    "manta_smoke_0032.vdb",
    "manta_smoke_0048.vdb",
];

fn data(rel: &str) -> PathBuf {
    PathBuf::from(DIR).join(rel)
}

fn json(rel: &str) -> Value {
    let text = std::fs::read_to_string(data(rel)).expect("sidecar");
    serde_json::from_str(&text).expect("sidecar JSON")
}

/// A gzipped little-endian f32 `.npy`: (shape, values in C order).
fn npy_gz(rel: &str) -> (Vec<usize>, Vec<f32>) {
    let gz = std::fs::read(data(rel)).expect("npy.gz");
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(&gz[..])
        .read_to_end(&mut raw)
        .expect("gunzip");
    assert_eq!(&raw[..6], b"\x93NUMPY", "{rel}: npy magic");
    let (hlen, start) = if raw[6] == 1 {
        (u16::from_le_bytes([raw[8], raw[9]]) as usize, 10)
    } else {
        (
            u32::from_le_bytes(raw[8..12].try_into().unwrap()) as usize,
            12,
        )
    };
    let header = std::str::from_utf8(&raw[start..start + hlen]).unwrap();
    assert!(
        header.contains("'<f4'"),
        "{rel}: not little-endian f32: {header}"
    );
    assert!(header.contains("'fortran_order': False"), "{rel}: {header}");
    let dims = &header[header.find("'shape': (").unwrap() + 10..];
    let shape: Vec<usize> = dims[..dims.find(')').unwrap()]
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let values: Vec<f32> = raw[start + hlen..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(values.len(), shape.iter().product::<usize>(), "{rel}: size");
    (shape, values)
}

fn ivec(v: &Value) -> IVec3 {
    let c = |i: usize| v[i].as_i64().unwrap() as i32;
    IVec3::new(c(0), c(1), c(2))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// Smallest and largest active value (leaves and active tiles).
fn active_min_max(g: &Grid) -> (f32, f32) {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    for (_, leaf) in g.leaves() {
        for n in 0..512 {
            if leaf.active[n / 64] >> (n % 64) & 1 == 1 {
                lo = lo.min(leaf.value(n));
                hi = hi.max(leaf.value(n));
            }
        }
    }
    for t in g.tiles().iter().filter(|t| t.active) {
        lo = lo.min(t.value);
        hi = hi.max(t.value);
    }
    (lo, hi)
}

fn active_tile_voxels(g: &Grid) -> u64 {
    g.tiles()
        .iter()
        .filter(|t| t.active)
        .map(|t| {
            let d = (t.max - t.min + 1).as_i64vec3();
            (d.x * d.y * d.z) as u64
        })
        .sum()
}

/// Compares every voxel of a dense array `a[i, j, k]` = voxel `origin + (i, j, k)`; zero
/// entries must be inactive and non-zero ones active when `check_active`. Returns the f64
/// sum of the grid's values over the array.
fn compare_dense(g: &Grid, origin: IVec3, shape: &[usize], a: &[f32], check_active: bool) -> f64 {
    let mut bad = Vec::new();
    let mut sum = 0.0;
    for i in 0..shape[0] {
        for j in 0..shape[1] {
            for k in 0..shape[2] {
                let want = a[(i * shape[1] + j) * shape[2] + k];
                let ijk = origin + IVec3::new(i as i32, j as i32, k as i32);
                let (got, active) = (g.value(ijk), g.is_active(ijk));
                sum += got as f64;
                if got != want || (check_active && active != (want != 0.0)) {
                    bad.push((ijk, got, active, want));
                }
            }
        }
    }
    assert!(
        bad.is_empty(),
        "{}: {} voxels differ from the dense truth, first: {:?}",
        g.name,
        bad.len(),
        &bad[..bad.len().min(5)]
    );
    sum
}

/// `world = [i j k 1] * M` with `M` in OpenVDB's row-major layout.
fn row_major_apply(m: &Value, p: IVec3) -> DVec3 {
    let v = [p.x as f64, p.y as f64, p.z as f64, 1.0];
    let col = |c: usize| (0..4).map(|r| v[r] * f(&m[r][c])).sum::<f64>();
    DVec3::new(col(0), col(1), col(2))
}

fn assert_near(a: DVec3, b: DVec3, what: &str) {
    assert!((a - b).abs().max_element() < 1e-12, "{what}: {a} != {b}");
}

fn expect_field_error(r: ppb::error::Result<Grid>, needle: &str) {
    match r {
        Err(Error::Field { field, msg, .. }) => {
            assert_eq!(field, "grid");
            assert!(msg.contains(needle), "message {msg:?} lacks {needle:?}");
        }
        other => panic!("expected a field error containing {needle:?}, got {other:?}"),
    }
}

#[test]
fn lists_grids_in_file_order() {
    for name in PLUME_FILES {
        let side = json(&format!("{name}.json"));
        let got = list_grids(&data(&format!("{name}.vdb"))).unwrap();
        let want = side["header"]["grids_in_file_order"].as_array().unwrap();
        assert_eq!(got.len(), want.len(), "{name}");
        for (index, (g, w)) in got.iter().zip(want).enumerate() {
            let written = w["type"].as_str().unwrap();
            let grid = side["grids"]
                .as_array()
                .unwrap()
                .iter()
                .find(|s| s["name"] == w["unique_name"])
                .unwrap();
            let expected = GridDescriptor {
                name: w["unique_name"].as_str().unwrap().into(),
                value_type: written.trim_end_matches("_HalfFloat").into(),
                class: grid["grid_class"].as_str().unwrap().into(),
                half: written.ends_with("_HalfFloat"),
                index,
            };
            assert_eq!(*g, expected, "{name}");
            assert_eq!(g.half, grid["save_float_as_half"].as_bool().unwrap());
        }
    }
    let manta = json("mantaflow/mantaflow.json");
    for file in MANTA_FILES {
        let got = list_grids(&data(&format!("mantaflow/{file}"))).unwrap();
        let want = manta["files"][file]["grids"].as_array().unwrap();
        let mut names: Vec<_> = got.iter().map(|g| g.name.as_str()).collect();
        names.sort();
        let wanted: Vec<_> = want.iter().map(|g| g["name"].as_str().unwrap()).collect();
        assert_eq!(names, wanted, "{file} (the sidecar lists grids by name)");
        for g in &got {
            let w = want.iter().find(|w| w["name"] == g.name.as_str()).unwrap();
            let ty = if w["value_type"] == "float" {
                "Tree_float_5_4_3"
            } else {
                "Tree_vec3s_5_4_3"
            };
            assert_eq!(g.value_type, ty, "{file} {}", g.name);
            assert_eq!(
                g.class,
                w["grid_class"].as_str().unwrap(),
                "{file} {}",
                g.name
            );
            assert!(!g.half);
        }
    }
    for scene in ["smoke-grid", "cloud-hg"] {
        let got = list_grids(&data(&format!("conformance/{scene}/density.vdb"))).unwrap();
        let want = GridDescriptor {
            name: "density".into(),
            value_type: "Tree_float_5_4_3".into(),
            class: "fog volume".into(),
            half: false,
            index: 0,
        };
        assert_eq!(got, vec![want], "{scene}");
    }
}

/// Every float grid of every plume-family file reproduces its sidecar and dense truth.
#[test]
fn plume_files_match_sidecars_and_dense_truth() {
    for name in PLUME_FILES {
        let side = json(&format!("{name}.json"));
        let path = data(&format!("{name}.vdb"));
        for s in side["grids"].as_array().unwrap() {
            let grid_name = s["name"].as_str().unwrap();
            if s["value_type"] != "float" {
                expect_field_error(load_grid(&path, grid_name), "Tree_vec3s_5_4_3");
                continue;
            }
            let g = load_grid(&path, grid_name).unwrap_or_else(|e| panic!("{name}: {e}"));
            check_plume_grid(name, &side, s, &g);
        }
    }
}

fn check_plume_grid(file: &str, side: &Value, s: &Value, g: &Grid) {
    let what = format!("{file}:{}", g.name);
    assert_eq!(g.background as f64, f(&s["background"]), "{what}");
    assert_eq!(
        g.active_voxels(),
        s["active_voxel_count"].as_u64().unwrap(),
        "{what}"
    );
    assert_eq!(
        g.leaf_count() as u64,
        s["leaf_count"].as_u64().unwrap(),
        "{what}"
    );
    let tile_voxels = s["active_tile_voxel_count"].as_u64().unwrap();
    assert_eq!(active_tile_voxels(g), tile_voxels, "{what}");
    let bbox = &s["active_index_bbox"];
    assert_eq!(
        g.active_bbox(),
        Some((ivec(&bbox["min"]), ivec(&bbox["max"]))),
        "{what}"
    );
    let (lo, hi) = active_min_max(g);
    assert_eq!(lo, f(&s["min_max_active"][0]) as f32, "{what} min");
    assert_eq!(hi, f(&s["min_max_active"][1]) as f32, "{what} max");
    let m = &s["transform"]["index_to_world_row_major_4x4"];
    for p in [IVec3::ZERO, IVec3::new(1, 2, 3), IVec3::new(-40, 17, 1000)] {
        let got = g.index_to_world.transform_point3(p.as_dvec3());
        assert_near(got, row_major_apply(m, p), &what);
    }
    for p in s["probes"].as_array().unwrap() {
        let ijk = ivec(&p["ijk"]);
        assert_eq!(g.value(ijk), f(&p["value"]) as f32, "{what} value at {ijk}");
        assert_eq!(
            g.is_active(ijk),
            p["active"].as_bool().unwrap(),
            "{what} state at {ijk}"
        );
        let world = g.index_to_world.transform_point3(ijk.as_dvec3());
        let want = DVec3::new(f(&p["world"][0]), f(&p["world"][1]), f(&p["world"][2]));
        assert_near(world, want, &what);
    }
    let dense = &side["dense"][&g.name];
    let (shape, a) = npy_gz(&format!("{}.gz", dense["npy"].as_str().unwrap()));
    let sum = compare_dense(g, ivec(&dense["origin_ijk"]), &shape, &a, true);
    if let Some(want) = side["dense_stats"][&g.name]["sum_float64"].as_f64() {
        assert!(
            (sum - want).abs() < 1e-9 * want.abs(),
            "{what}: sum {sum} != {want}"
        );
    }
}

#[test]
fn half_precision_rounds_the_plume() {
    let (_, full) = npy_gz("smoke_plume.density.npy.gz");
    for file in ["half_precision.vdb", "half_precision_zip.vdb"] {
        let g = load_grid(&data(file), "density").unwrap();
        let origin = IVec3::new(-32, 0, -32);
        let rounded: Vec<f32> = full
            .iter()
            .map(|&v| half::f16::from_f32(v).to_f32())
            .collect();
        let sum = compare_dense(&g, origin, &[64, 64, 64], &rounded, true);
        assert!((sum - 16473.182037353516).abs() < 1e-7, "{file}: sum {sum}");
        assert_eq!(g.value(IVec3::new(0, 20, 0)), 0.96484375);
    }
}

#[test]
fn mantaflow_frames_match_sidecar() {
    let manta = json("mantaflow/mantaflow.json");
    for file in MANTA_FILES {
        let path = data(&format!("mantaflow/{file}"));
        let side = &manta["files"][file];
        for s in side["grids"].as_array().unwrap() {
            let name = s["name"].as_str().unwrap();
            if s["value_type"] != "float" {
                expect_field_error(load_grid(&path, name), "Tree_vec3s_5_4_3");
                continue;
            }
            let g = load_grid(&path, name).unwrap_or_else(|e| panic!("{file}: {e}"));
            let what = format!("{file}:{name}");
            let count = s["active_voxel_count"].as_u64().unwrap();
            assert_eq!(g.active_voxels(), count, "{what}");
            assert_eq!(
                g.leaf_count() as u64,
                s["leaf_count"].as_u64().unwrap(),
                "{what}"
            );
            let voxel = f(&s["voxel_size"][0]);
            assert_eq!(s["map_type"], "UniformScaleMap");
            let p = DVec3::new(3.0, -4.0, 5.0);
            let origin = DVec3::new(0.0, 0.0, 0.0);
            assert_near(
                g.index_to_world.transform_point3(p),
                origin + p * voxel,
                &what,
            );
            if count == 0 {
                assert_eq!(g.active_bbox(), None, "{what}");
                continue;
            }
            let bbox = &s["active_index_bbox"];
            assert_eq!(
                g.active_bbox(),
                Some((ivec(&bbox["min"]), ivec(&bbox["max"]))),
                "{what}"
            );
            let (lo, hi) = active_min_max(&g);
            assert_eq!(
                (lo, hi),
                (f(&s["min_max"][0]) as f32, f(&s["min_max"][1]) as f32),
                "{what}"
            );
        }
        check_manta_density(file, &side["density_dense"]);
    }
}

fn check_manta_density(file: &str, dense: &Value) {
    let g = load_grid(&data(&format!("mantaflow/{file}")), "density").unwrap();
    let (shape, a) = npy_gz(&format!("mantaflow/{}.gz", dense["npy"].as_str().unwrap()));
    let sum = compare_dense(&g, ivec(&dense["origin_ijk"]), &shape, &a, true);
    let want = f(&dense["sum_float64"]);
    assert!(
        (sum - want).abs() < 1e-9 * want,
        "{file}: sum {sum} != {want}"
    );
    let nonzero = a.iter().filter(|&&v| v != 0.0).count() as u64;
    assert_eq!(nonzero, dense["nonzero_count"].as_u64().unwrap());
    for p in dense["probes"].as_array().unwrap() {
        let ijk = ivec(&p["ijk"]);
        assert_eq!(g.value(ijk), f(&p["value"]) as f32, "{file} at {ijk}");
        assert_eq!(
            g.is_active(ijk),
            p["active"].as_bool().unwrap(),
            "{file} at {ijk}"
        );
    }
}

/// The renderer's conformance grids: transform from scene.md, values = density.npy.
#[test]
fn conformance_grids_match_dense_truth() {
    let cases = [
        (
            "smoke-grid",
            [-0.984375, 0.215625, -0.984375],
            [0.03125; 3],
            64,
            21139.262,
        ),
        (
            "cloud-hg",
            [-1.484375, 0.60625, -0.9895833333],
            [0.03125, 0.0125, 0.02083333333],
            96,
            96596.586,
        ),
    ];
    for (scene, t, s, n, stated_sum) in cases {
        let g = load_grid(
            &data(&format!("conformance/{scene}/density.vdb")),
            "density",
        )
        .unwrap();
        for p in [
            DVec3::ZERO,
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::splat(n as f64 - 1.0),
        ] {
            let want = DVec3::from(t) + p * DVec3::from(s);
            let got = g.index_to_world.transform_point3(p);
            assert!(
                (got - want).abs().max_element() < 1e-9,
                "{scene}: {got} != {want}"
            );
        }
        let (shape, d) = npy_gz(&format!("conformance/{scene}/density.npy.gz"));
        assert_eq!(shape, vec![n; 3]);
        // d[k, j, i] is voxel (i, j, k): transpose to a[i, j, k].
        let mut a = vec![0.0f32; d.len()];
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    a[(i * n + j) * n + k] = d[(k * n + j) * n + i];
                }
            }
        }
        let sum = compare_dense(&g, IVec3::ZERO, &shape, &a, false);
        // scene.md rounds a float32 sum.
        assert!(
            (sum - stated_sum).abs() < 1e-6 * stated_sum,
            "{scene}: sum {sum}"
        );
        let (lo, hi) = g.active_bbox().unwrap();
        assert!(lo.cmpge(IVec3::ZERO).all() && hi.cmplt(IVec3::splat(n as i32)).all());
    }
}

#[test]
fn picks_grids_by_name() {
    for file in ["multi_grid.vdb", "multi_grid_zip.vdb"] {
        let path = data(file);
        let t = load_grid(&path, "temperature").unwrap();
        assert_eq!(t.name, "temperature");
        assert_eq!(t.value(IVec3::new(0, 5, 0)), 806.25);
        assert_eq!(t.index_to_world.matrix3.x_axis.x, 1.0 / 16.0);
        let d = load_grid(&path, "density").unwrap();
        assert_eq!(d.value(IVec3::new(0, 20, 0)), 0.965_062_74);
        assert_eq!(d.index_to_world.matrix3.x_axis.x, 1.0 / 32.0);
        expect_field_error(load_grid(&path, "vel"), "has type Tree_vec3s_5_4_3");
    }
    expect_field_error(
        load_grid(&data("multi_grid.vdb"), "smoke"),
        "no grid \"smoke\" (grids in file: temperature, vel, density)",
    );
    expect_field_error(
        load_grid(&data("multi_grid_zip.vdb"), "smoke"),
        "no grid \"smoke\" (grids in file: vel, temperature, density)",
    );
    match load_grid(Path::new("/nonexistent/x.vdb"), "density") {
        Err(Error::Io { .. }) => {}
        other => panic!("expected an I/O error, got {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------
// Hand-built variants: an instanced grid (OpenVDB shares a tree between grids by writing
// the second one as metadata + transform + the parent's name) carrying each map type.

fn push_str(out: &mut Vec<u8>, s: &str) {
    out.extend((s.len() as u32).to_le_bytes());
    out.extend(s.as_bytes());
}

fn push_f64s(out: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        out.extend(x.to_le_bytes());
    }
}

/// Byte offset of smoke_plume.vdb's grid count (its single descriptor follows it).
fn plume_grid_count_at(side: &Value) -> usize {
    let grid_pos = side["header"]["grids_in_file_order"][0]["grid_pos"]
        .as_u64()
        .unwrap() as usize;
    grid_pos - (4 + 7) - (4 + 16) - 4 - 24 - 4
}

/// smoke_plume.vdb plus an instance "copy" of "density" whose transform is `map` + `fields`.
fn with_instance(map: &str, fields: &[f64]) -> Vec<u8> {
    let mut bytes = std::fs::read(data("smoke_plume.vdb")).unwrap();
    let count_at = plume_grid_count_at(&json("smoke_plume.json"));
    assert_eq!(bytes[count_at..count_at + 4], 1i32.to_le_bytes());
    bytes[count_at..count_at + 4].copy_from_slice(&2i32.to_le_bytes());
    let mut grid = 6u32.to_le_bytes().to_vec();
    grid.extend(1u32.to_le_bytes());
    push_str(&mut grid, "class");
    push_str(&mut grid, "string");
    push_str(&mut grid, "fog volume");
    push_str(&mut grid, map);
    push_f64s(&mut grid, fields);
    let mut desc = Vec::new();
    push_str(&mut desc, "copy");
    push_str(&mut desc, "Tree_float_5_4_3");
    push_str(&mut desc, "density");
    let grid_pos = (bytes.len() + desc.len() + 24) as i64;
    for p in [grid_pos, 0, grid_pos + grid.len() as i64] {
        desc.extend(p.to_le_bytes());
    }
    bytes.extend(desc);
    bytes.extend(grid);
    bytes
}

fn temp_file(name: &str, bytes: &[u8]) -> PathBuf {
    let path = std::env::temp_dir().join(format!("ppb-openvdb-{}-{name}", std::process::id()));
    std::fs::write(&path, bytes).unwrap();
    path
}

/// ScaleMap-style fields for scale `s`: scale, voxel size, 1/s, 1/s², 1/(2s).
fn scale_fields(s: [f64; 3]) -> Vec<f64> {
    let mut v = s.to_vec();
    v.extend(s.map(f64::abs));
    v.extend(s.map(|x| 1.0 / x));
    v.extend(s.map(|x| 1.0 / (x * x)));
    v.extend(s.map(|x| 0.5 / x));
    v
}

#[test]
fn instanced_grid_with_every_linear_map() {
    let t = [0.5, -2.0, 3.25];
    let s = [0.1, 0.2, -0.3];
    let (c, sn) = (0.6f64, 0.8f64);
    // Row-vector matrix: rotate about z, scale by 2, translate by t.
    let affine = [
        2.0 * c,
        2.0 * sn,
        0.0,
        0.0,
        -2.0 * sn,
        2.0 * c,
        0.0,
        0.0,
        0.0,
        0.0,
        2.0,
        0.0,
        t[0],
        t[1],
        t[2],
        1.0,
    ];
    let unitary = [
        c, sn, 0.0, 0.0, -sn, c, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let mut st = t.to_vec();
    st.extend(scale_fields(s));
    let mut ust = t.to_vec();
    ust.extend(scale_fields([0.25; 3]));
    let p = DVec3::new(3.0, -7.0, 11.0);
    let rot =
        |p: DVec3, k: f64| DVec3::new(k * (c * p.x - sn * p.y), k * (sn * p.x + c * p.y), k * p.z);
    let cases: [(&str, Vec<f64>, DVec3); 7] = [
        ("UniformScaleMap", scale_fields([0.25; 3]), p * 0.25),
        ("ScaleMap", scale_fields(s), p * DVec3::from(s)),
        ("ScaleTranslateMap", st, p * DVec3::from(s) + DVec3::from(t)),
        ("UniformScaleTranslateMap", ust, p * 0.25 + DVec3::from(t)),
        ("TranslationMap", t.to_vec(), p + DVec3::from(t)),
        ("AffineMap", affine.to_vec(), rot(p, 2.0) + DVec3::from(t)),
        ("UnitaryMap", unitary.to_vec(), rot(p, 1.0)),
    ];
    let original = load_grid(&data("smoke_plume.vdb"), "density").unwrap();
    for (map, fields, want) in cases {
        let path = temp_file(&format!("instance-{map}.vdb"), &with_instance(map, &fields));
        let names: Vec<String> = list_grids(&path)
            .unwrap()
            .into_iter()
            .map(|g| g.name)
            .collect();
        assert_eq!(names, ["density", "copy"]);
        let g = load_grid(&path, "copy").unwrap_or_else(|e| panic!("{map}: {e}"));
        assert_near(g.index_to_world.transform_point3(p), want, map);
        assert_eq!(g.name, "copy");
        assert_eq!(g.active_voxels(), original.active_voxels());
        for (origin, leaf) in original.leaves() {
            assert_eq!(
                g.value(origin + IVec3::new(1, 2, 3)),
                leaf.value((8 + 2) * 8 + 3)
            );
        }
        let d = load_grid(&path, "density").unwrap();
        assert_eq!(d.index_to_world, original.index_to_world);
        std::fs::remove_file(path).ok();
    }
    for (map, needle) in [
        ("NonlinearFrustumMap", "NonlinearFrustumMap is not linear"),
        ("FancyMap", "unknown transform map type \"FancyMap\""),
    ] {
        let path = temp_file(
            &format!("instance-{map}.vdb"),
            &with_instance(map, &[1.0; 30]),
        );
        match load_grid(&path, "copy") {
            Err(Error::Format { msg, .. }) => assert!(msg.contains(needle), "{msg}"),
            other => panic!("{map}: expected a format error, got {other:?}"),
        }
        std::fs::remove_file(path).ok();
    }
}

// ---------------------------------------------------------------------------------------
// Corrupt input: never a panic, and an error where the damage is certain.

/// Files, and the float grid to load from each, used for corruption.
const CORRUPT_CASES: [(&str, &str); 7] = [
    ("smoke_plume.vdb", "density"),
    ("smoke_plume_zip.vdb", "density"),
    ("smoke_plume_active.vdb", "density"),
    ("half_precision.vdb", "density"),
    ("multi_grid.vdb", "temperature"),
    ("mantaflow/manta_smoke_0016.vdb", "shadow"),
    ("conformance/cloud-hg/density.vdb", "density"),
];

fn is_format_error<T: std::fmt::Debug>(r: &ppb::error::Result<T>) -> bool {
    matches!(r, Err(Error::Format { .. }))
}

#[test]
fn truncated_files_are_errors() {
    for (file, grid) in CORRUPT_CASES {
        let bytes = std::fs::read(data(file)).unwrap();
        let n = bytes.len();
        let mut lengths: Vec<usize> = (0..200).collect();
        lengths.extend((0..300).map(|i| 200 + i * (n - 200) / 300));
        lengths.extend(n - 16..n);
        let path = temp_file(&format!("trunc-{}", file.replace('/', "-")), b"");
        for len in lengths {
            std::fs::write(&path, &bytes[..len]).unwrap();
            let listed = list_grids(&path);
            let loaded = load_grid(&path, grid);
            assert!(is_format_error(&listed), "{file} cut to {len}: {listed:?}");
            let loaded = loaded.map(|_| "loaded");
            assert!(is_format_error(&loaded), "{file} cut to {len}: {loaded:?}");
        }
        std::fs::remove_file(path).ok();
    }
}

/// xorshift64*: a fixed seed gives the same flips every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

#[test]
fn bit_flips_never_panic() {
    let mut rng = Rng(0x5eed_f0dd_b175_0001);
    let (mut ok, mut err) = (0, 0);
    for (file, grid) in CORRUPT_CASES {
        let bytes = std::fs::read(data(file)).unwrap();
        let n = bytes.len() as u64;
        let mut offsets: Vec<usize> = (0..400).collect();
        offsets.extend((0..250).map(|_| (rng.next() % n) as usize));
        let path = temp_file(&format!("flip-{}", file.replace('/', "-")), b"");
        for at in offsets {
            let mut b = bytes.clone();
            b[at] ^= 1 << (rng.next() % 8);
            std::fs::write(&path, &b).unwrap();
            let _ = list_grids(&path);
            match load_grid(&path, grid) {
                Ok(g) => {
                    let _ = (g.active_voxels(), g.active_bbox());
                    ok += 1;
                }
                Err(_) => err += 1,
            }
        }
        std::fs::remove_file(path).ok();
    }
    eprintln!("bit flips: {ok} loaded, {err} rejected");
    assert!(err > 0 && ok > 0);
}

fn patched(bytes: &[u8], at: usize, with: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[at..at + with.len()].copy_from_slice(with);
    b
}

/// Offset of the root node: after the transform's map name and its six Vec3d fields.
fn plume_topology_at(bytes: &[u8]) -> usize {
    let name = b"UniformScaleTranslateMap";
    let at = bytes.windows(name.len()).position(|w| w == name).unwrap();
    at + name.len() + 6 * 24
}

#[test]
fn absurd_sizes_are_errors() {
    let bytes = std::fs::read(data("smoke_plume.vdb")).unwrap();
    let side = json("smoke_plume.json");
    let count_at = plume_grid_count_at(&side);
    let desc = count_at + 4;
    let grid_pos = side["header"]["grids_in_file_order"][0]["grid_pos"]
        .as_u64()
        .unwrap() as usize;
    let block_pos = side["header"]["grids_in_file_order"][0]["block_pos"]
        .as_u64()
        .unwrap() as usize;
    let root = plume_topology_at(&bytes);
    assert_eq!(
        bytes[root..root + 4],
        1i32.to_le_bytes(),
        "tree buffer count"
    );
    // The first leaf buffer: value mask, metadata byte 0 (fog), then the i64 chunk size.
    assert_eq!(bytes[block_pos + 64], 0);
    let chunk = block_pos + 65;
    let max32 = u32::MAX.to_le_bytes();
    let cases: Vec<(&str, usize, Vec<u8>)> = vec![
        ("magic", 0, vec![0x21]),
        ("format version", 8, 200u32.to_le_bytes().to_vec()),
        ("file metadata count", 57, max32.to_vec()),
        ("file metadata name length", 61, max32.to_vec()),
        ("grid count", count_at, i32::MAX.to_le_bytes().to_vec()),
        (
            "negative grid count",
            count_at,
            (-1i32).to_le_bytes().to_vec(),
        ),
        ("grid name length", desc, max32.to_vec()),
        (
            "grid offset",
            grid_pos - 24,
            i64::MAX.to_le_bytes().to_vec(),
        ),
        (
            "negative grid offset",
            grid_pos - 24,
            (-8i64).to_le_bytes().to_vec(),
        ),
        (
            "end offset",
            grid_pos - 8,
            (1i64 << 40).to_le_bytes().to_vec(),
        ),
        (
            "compression flags",
            grid_pos,
            0xff00u32.to_le_bytes().to_vec(),
        ),
        ("grid metadata count", grid_pos + 4, max32.to_vec()),
        ("tree buffer count", root, 7i32.to_le_bytes().to_vec()),
        ("root tile count", root + 8, max32.to_vec()),
        ("root child count", root + 12, max32.to_vec()),
        ("chunk size", chunk, i64::MAX.to_le_bytes().to_vec()),
        (
            "negative chunk size",
            chunk,
            i64::MIN.to_le_bytes().to_vec(),
        ),
        (
            "huge chunk size",
            chunk,
            (1i64 << 40).to_le_bytes().to_vec(),
        ),
        ("blosc raw size", chunk + 8 + 4, max32.to_vec()),
        ("blosc block size", chunk + 8 + 8, max32.to_vec()),
        ("blosc frame size", chunk + 8 + 12, max32.to_vec()),
    ];
    for (what, at, with) in cases {
        let path = temp_file(
            &format!("absurd-{}", what.replace(' ', "-")),
            &patched(&bytes, at, &with),
        );
        let r = load_grid(&path, "density");
        assert!(is_format_error(&r), "{what}: {:?}", r.map(|_| "loaded"));
        std::fs::remove_file(path).ok();
    }
}

// ---------------------------------------------------------------------------------------
// A hand-built tree that the real files lack: root tiles, upper and lower internal-node
// tiles (active, and inactive with non-background values), a non-zero background, every
// per-node inactive-value encoding (metadata bytes 0 to 6), and each compression flag
// combination, in full and half precision.

const ZIP: u32 = 1;
const MASK: u32 = 2;
const BLOSC: u32 = 4;

struct Enc {
    compression: u32,
    half: bool,
}

/// A node's values as OpenVDB lays them out: metadata byte, inactive values, selection
/// mask, then the stored values as one raw, zlib or Blosc (stored-frame) chunk.
struct NodeValues<'a> {
    values: &'a [f32],
    active: &'a [bool],
    meta: u8,
    inactive: [f32; 2],
    selection: &'a [bool],
}

fn push_mask(out: &mut Vec<u8>, bits: &[bool]) {
    for word in bits.chunks(64) {
        let w = word
            .iter()
            .enumerate()
            .fold(0u64, |w, (i, &b)| w | (b as u64) << i);
        out.extend(w.to_le_bytes());
    }
}

fn push_node_values(out: &mut Vec<u8>, enc: &Enc, n: &NodeValues) {
    out.push(n.meta);
    if matches!(n.meta, 2 | 4 | 5) {
        out.extend(n.inactive[0].to_le_bytes());
    }
    if n.meta == 5 {
        out.extend(n.inactive[1].to_le_bytes());
    }
    if matches!(n.meta, 3..=5) {
        push_mask(out, n.selection);
    }
    let masked = enc.compression & MASK != 0 && n.meta != 6;
    let stored: Vec<f32> = (0..n.values.len())
        .filter(|&i| !masked || n.active[i])
        .map(|i| n.values[i])
        .collect();
    if enc.half && stored.is_empty() {
        return;
    }
    let raw: Vec<u8> = if enc.half {
        stored
            .iter()
            .flat_map(|&v| half::f16::from_f32(v).to_le_bytes())
            .collect()
    } else {
        stored.iter().flat_map(|v| v.to_le_bytes()).collect()
    };
    if enc.compression & BLOSC != 0 {
        let mut frame = vec![2, 1, 0x02 | 0x20, 4];
        for v in [raw.len(), raw.len().max(1), 16 + raw.len()] {
            frame.extend((v as u32).to_le_bytes());
        }
        frame.extend(&raw);
        out.extend((frame.len() as i64).to_le_bytes());
        out.extend(frame);
    } else if enc.compression & ZIP != 0 {
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut z, &raw).unwrap();
        let zipped = z.finish().unwrap();
        out.extend((zipped.len() as i64).to_le_bytes());
        out.extend(zipped);
    } else {
        out.extend(raw);
    }
}

const BG: f32 = 0.5;

/// Expected leaf contents for a metadata byte: active every third voxel (n / 10), the
/// inactive ones as that encoding allows. Returns (values, active, inactive, selection).
fn leaf_truth(meta: u8) -> (Vec<f32>, Vec<bool>, [f32; 2], Vec<bool>) {
    let active: Vec<bool> = (0..512).map(|n| n % 3 == 0).collect();
    let (a, b, inactive) = match meta {
        0 | 6 => (BG, BG, [BG, BG]),
        1 => (-BG, -BG, [-BG, BG]),
        2 => (9.0, 9.0, [9.0, BG]),
        3 => (BG, -BG, [-BG, BG]),
        4 => (BG, 9.0, [9.0, BG]),
        _ => (11.0, 9.0, [9.0, 11.0]),
    };
    let values = (0..512)
        .map(|n| match n % 3 {
            0 => n as f32 / 10.0,
            1 => a,
            _ => b,
        })
        .collect();
    // Selection bit on: the second inactive value (`a` on n % 3 == 1 where two differ).
    let selection = (0..512)
        .map(|n| n % 3 == 1 && matches!(meta, 3..=5))
        .collect();
    (values, active, inactive, selection)
}

/// Topology and buffers of the hand-built tree, and its leaf's expected values.
fn synthetic_tree(enc: &Enc, leaf_meta: u8) -> (Vec<u8>, Vec<u8>, Vec<f32>) {
    let mask = enc.compression & MASK != 0;
    let mut t = 1i32.to_le_bytes().to_vec();
    t.extend(BG.to_le_bytes());
    t.extend(3u32.to_le_bytes());
    t.extend(1u32.to_le_bytes());
    for (origin, value, active) in [
        ([4096, 0, 0], 2.0f32, 1u8),
        ([0, 4096, 0], BG, 0),
        ([0, 0, 4096], -3.0, 0),
    ] {
        origin.iter().for_each(|c: &i32| t.extend(c.to_le_bytes()));
        t.extend(value.to_le_bytes());
        t.push(active);
    }
    t.extend([0u8; 12]);
    // Upper node: child in slot 0, active tile 3.0 in slot 1, inactive tile 7.0 in slot 2.
    let n5 = 32768;
    let child5: Vec<bool> = (0..n5).map(|i| i == 0).collect();
    let active5: Vec<bool> = (0..n5).map(|i| i == 1).collect();
    let values5: Vec<f32> = (0..n5)
        .map(|i| [BG, 3.0, 7.0].get(i).copied().unwrap_or(BG))
        .collect();
    let sel5: Vec<bool> = (0..n5).map(|i| i != 2).collect();
    push_mask(&mut t, &child5);
    push_mask(&mut t, &active5);
    let (meta5, inactive5) = if mask {
        (4, [7.0, BG])
    } else {
        (6, [0.0, 0.0])
    };
    push_node_values(
        &mut t,
        enc,
        &NodeValues {
            values: &values5,
            active: &active5,
            meta: meta5,
            inactive: inactive5,
            selection: &sel5,
        },
    );
    // Lower node: leaf in slot 0, active tile 4.0 in slot 1, inactive -background in slot 3.
    let n4 = 4096;
    let child4: Vec<bool> = (0..n4).map(|i| i == 0).collect();
    let active4: Vec<bool> = (0..n4).map(|i| i == 1).collect();
    let values4: Vec<f32> = (0..n4)
        .map(|i| [BG, 4.0, BG, -BG].get(i).copied().unwrap_or(BG))
        .collect();
    let sel4: Vec<bool> = (0..n4).map(|i| i != 3).collect();
    push_mask(&mut t, &child4);
    push_mask(&mut t, &active4);
    let meta4 = if mask { 3 } else { 6 };
    push_node_values(
        &mut t,
        enc,
        &NodeValues {
            values: &values4,
            active: &active4,
            meta: meta4,
            inactive: [0.0; 2],
            selection: &sel4,
        },
    );
    let (values, active, inactive, selection) = leaf_truth(leaf_meta);
    push_mask(&mut t, &active);
    let mut b = Vec::new();
    push_mask(&mut b, &active);
    let meta = if mask { leaf_meta } else { 6 };
    push_node_values(
        &mut b,
        enc,
        &NodeValues {
            values: &values,
            active: &active,
            meta,
            inactive,
            selection: &selection,
        },
    );
    (t, b, values)
}

/// A one-grid file around a tree; the transform is a unit UniformScaleMap.
fn synthetic_file(tree_type: &str, compression: u32, topology: &[u8], buffers: &[u8]) -> Vec<u8> {
    let mut out = 0x5644_4220i64.to_le_bytes().to_vec();
    for v in [224u32, 10, 0] {
        out.extend(v.to_le_bytes());
    }
    out.push(1);
    out.extend([b'0'; 36]);
    out.extend(0u32.to_le_bytes());
    out.extend(1i32.to_le_bytes());
    let mut grid = compression.to_le_bytes().to_vec();
    grid.extend(0u32.to_le_bytes());
    push_str(&mut grid, "UniformScaleMap");
    push_f64s(&mut grid, &scale_fields([1.0; 3]));
    push_str(&mut out, "synth");
    push_str(&mut out, tree_type);
    push_str(&mut out, "");
    let grid_pos = out.len() + 24;
    let block_pos = grid_pos + grid.len() + topology.len();
    for p in [grid_pos, block_pos, block_pos + buffers.len()] {
        out.extend((p as i64).to_le_bytes());
    }
    out.extend(grid);
    out.extend(topology);
    out.extend(buffers);
    out
}

#[test]
fn hand_built_tree_in_every_encoding() {
    let compressions = [0, MASK, ZIP, ZIP | MASK, BLOSC, BLOSC | MASK];
    for compression in compressions {
        for half in [false, true] {
            for leaf_meta in 0..=6 {
                let enc = Enc { compression, half };
                let (topology, buffers, leaf) = synthetic_tree(&enc, leaf_meta);
                let tree_type = if half {
                    "Tree_float_5_4_3_HalfFloat"
                } else {
                    "Tree_float_5_4_3"
                };
                let bytes = synthetic_file(tree_type, compression, &topology, &buffers);
                let what =
                    format!("compression {compression}, half {half}, leaf metadata {leaf_meta}");
                let path = temp_file(
                    &format!("synth-{compression}-{half}-{leaf_meta}.vdb"),
                    &bytes,
                );
                let g = load_grid(&path, "synth").unwrap_or_else(|e| panic!("{what}: {e}"));
                std::fs::remove_file(path).ok();
                check_hand_built(&g, &leaf, &enc, &what);
            }
        }
    }
}

fn check_hand_built(g: &Grid, leaf: &[f32], enc: &Enc, what: &str) {
    let round = |v: f32| {
        if enc.half {
            half::f16::from_f32(v).to_f32()
        } else {
            v
        }
    };
    assert_eq!(g.background, BG, "{what}");
    let probes = [
        (IVec3::new(4096 + 5, 3, 4000), 2.0, true),
        (IVec3::new(1, 4096 + 1, 2), BG, false),
        (IVec3::new(0, 3, 4096 + 9), -3.0, false),
        (IVec3::new(10, 20, 130), 3.0, true),
        (IVec3::new(127, 0, 383), 7.0, false),
        (IVec3::new(200, 5, 5), BG, false),
        (IVec3::new(1, 2, 9), 4.0, true),
        (IVec3::new(7, 7, 31), -BG, false),
        (IVec3::new(0, 0, 40), BG, false),
        (IVec3::new(-1, 0, 0), BG, false),
    ];
    for (ijk, value, active) in probes {
        assert_eq!(
            (g.value(ijk), g.is_active(ijk)),
            (value, active),
            "{what} at {ijk}"
        );
    }
    for n in 0..512i32 {
        let ijk = IVec3::new(n / 64, (n / 8) % 8, n % 8);
        let active = n % 3 == 0;
        let want = if active {
            round(leaf[n as usize])
        } else {
            leaf[n as usize]
        };
        assert_eq!(
            (g.value(ijk), g.is_active(ijk)),
            (want, active),
            "{what} leaf voxel {n}"
        );
    }
    let leaf_active = (0..512).filter(|n| n % 3 == 0).count() as u64;
    assert_eq!(
        g.active_voxels(),
        4096u64.pow(3) + 128u64.pow(3) + 512 + leaf_active,
        "{what}"
    );
    assert_eq!(g.leaf_count(), 1);
}
