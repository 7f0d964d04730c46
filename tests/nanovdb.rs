//! NanoVDB loader against files written by `nanovdb_convert` 32.4.2 and 32.9.2: their
//! sidecars (`*.nvdb.json`: FileMetaData parsed with `struct`, probes, what OpenVDB read
//! back after a round trip), the dense numpy truth, and damaged copies (truncations,
//! seeded bit flips, absurd sizes, broken tree links) that must fail without panicking.
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DAffine3, DMat3, DVec3, IVec3};
use ppb::error::Error;
use ppb::media::grid::Grid;
use ppb::media::nanovdb::{list_grids, load_grid, Codec, GridMetaData, GridType};
use serde_json::Value;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/nvdb/");
const FILES: [&str; 7] = [
    "smoke_plume.nvdb",
    "smoke_plume_zip.nvdb",
    "smoke_plume_blosc.nvdb",
    "smoke_plume_v32_9.nvdb",
    "smoke_plume_v32_9_zip.nvdb",
    "multi_grid.nvdb",
    "multi_grid_v32_9.nvdb",
];
/// The README's seven active 8^3 tiles of the plume, all exactly 1.0.
const PLUME_TILES: [[i32; 3]; 7] = [
    [-8, 0, -8],
    [-8, 0, 0],
    [-8, 8, -8],
    [0, 0, -8],
    [0, 0, 0],
    [0, 8, -8],
    [0, 8, 0],
];
/// Where the single grid buffer starts in the one-grid files (16 + 176 + "density\0").
const GRID_AT: usize = 200;
const GRID_DATA: usize = 672;
const TREE_DATA: usize = 64;

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
}

fn bytes(name: &str) -> Vec<u8> {
    std::fs::read(data(name)).expect("test file readable")
}

fn sidecar(file: &str) -> Value {
    let text = std::fs::read_to_string(data(&format!("{file}.json"))).expect("sidecar");
    serde_json::from_str(&text).expect("sidecar is JSON")
}

/// The sidecar's per-grid FileMetaData, over all segments in file order.
fn sidecar_grids(sc: &Value) -> Vec<Value> {
    let segments = sc["layout"]["segments"].as_array().expect("segments");
    segments
        .iter()
        .flat_map(|s| s["grids"].as_array().expect("grids").clone())
        .collect()
}

fn ivec(v: &Value) -> IVec3 {
    let c = |i: usize| v[i].as_i64().expect("int") as i32;
    IVec3::new(c(0), c(1), c(2))
}

fn dvec(v: &Value) -> DVec3 {
    let c = |i: usize| v[i].as_f64().expect("number");
    DVec3::new(c(0), c(1), c(2))
}

/// A C-order float32 `.npy` array of three dimensions.
struct Dense {
    shape: [usize; 3],
    values: Vec<f32>,
}

impl Dense {
    fn read(name: &str) -> Dense {
        let raw = bytes(name);
        assert_eq!(&raw[..6], b"\x93NUMPY", "{name}: npy magic");
        let (len, start) = match raw[6] {
            1 => (u16::from_le_bytes([raw[8], raw[9]]) as usize, 10),
            _ => (
                u32::from_le_bytes(raw[8..12].try_into().unwrap()) as usize,
                12,
            ),
        };
        let header = std::str::from_utf8(&raw[start..start + len]).expect("npy header");
        assert!(header.contains("'descr': '<f4'") && header.contains("'fortran_order': False"));
        let dims = header.split("'shape': (").nth(1).expect("shape");
        let dims: Vec<usize> = dims[..dims.find(')').expect("shape end")]
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| s.trim().parse().expect("dim"))
            .collect();
        let values: Vec<f32> = raw[start + len..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let shape = [dims[0], dims[1], dims[2]];
        assert_eq!(
            values.len(),
            shape.iter().product::<usize>(),
            "{name}: size"
        );
        Dense { shape, values }
    }

    fn get(&self, i: usize, j: usize, k: usize) -> f32 {
        self.values[(i * self.shape[1] + j) * self.shape[2] + k]
    }
}

/// A file in the temp directory, removed again when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(tag: &str, contents: &[u8]) -> Scratch {
        static COUNT: AtomicUsize = AtomicUsize::new(0);
        let n = COUNT.fetch_add(1, Ordering::Relaxed);
        let name = format!("ppb-nanovdb-{}-{n}-{tag}.nvdb", std::process::id());
        let path = std::env::temp_dir().join(name);
        std::fs::write(&path, contents).expect("scratch file writable");
        Scratch(path)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn format_message<T>(r: ppb::error::Result<T>, what: &str) -> String {
    match r {
        Err(Error::Format { msg, .. }) => msg,
        Err(e) => panic!("{what}: expected a format error, got {e}"),
        Ok(_) => panic!("{what}: expected a format error, got a result"),
    }
}

fn field_message<T>(r: ppb::error::Result<T>) -> (String, String) {
    match r {
        Err(Error::Field { field, msg, .. }) => (field, msg),
        Err(e) => panic!("expected a field error, got {e}"),
        Ok(_) => panic!("expected a field error, got a result"),
    }
}

fn codec_name(c: Codec) -> &'static str {
    match c {
        Codec::None => "NONE",
        Codec::Zip => "ZIP",
        Codec::Blosc => "BLOSC",
    }
}

fn check_info(file: &str, got: &GridMetaData, want: &Value) {
    let ctx = format!("{file} {}", got.name);
    let v = &want["version"];
    let version = [got.version.major, got.version.minor, got.version.patch];
    let nodes = &want["node_count_leaf_lower_upper_root"];
    let tiles = &want["active_tile_count_lower_upper_root"];
    assert_eq!(got.name, want["name"], "{ctx}");
    assert_eq!(got.grid_type.0 as u64, want["grid_type_enum"], "{ctx}");
    assert_eq!(got.grid_class.0 as u64, want["grid_class_enum"], "{ctx}");
    assert_eq!(
        version.map(|x| x as u64),
        [0, 1, 2].map(|i| v[i].as_u64().unwrap())
    );
    assert_eq!(codec_name(got.codec), want["codec"], "{ctx}");
    assert_eq!(got.grid_bytes, want["grid_size_bytes"], "{ctx}");
    assert_eq!(got.file_bytes, want["file_size_bytes"], "{ctx}");
    assert_eq!(got.active_voxels, want["active_voxel_count"], "{ctx}");
    let ib = &want["index_bbox"];
    assert_eq!(
        got.index_bbox,
        (ivec(&ib["min"]), ivec(&ib["max"])),
        "{ctx}"
    );
    let wb = &want["world_bbox"];
    assert_eq!(
        got.world_bbox,
        (dvec(&wb["min"]), dvec(&wb["max"])),
        "{ctx}"
    );
    assert_eq!(got.voxel_size, dvec(&want["voxel_size"]), "{ctx}");
    assert_eq!(
        got.node_counts.map(|n| n as u64),
        [0, 1, 2].map(|i| nodes[i].as_u64().unwrap())
    );
    assert_eq!(
        got.active_tiles.map(|n| n as u64),
        [0, 1, 2].map(|i| tiles[i].as_u64().unwrap())
    );
}

/// Every voxel of the dense array equals the grid, active exactly where non-zero, and no
/// voxel outside the array is active.
fn check_dense(ctx: &str, grid: &Grid, dense: &Dense, origin: IVec3) {
    let mut active = 0u64;
    for i in 0..dense.shape[0] {
        for j in 0..dense.shape[1] {
            for k in 0..dense.shape[2] {
                let ijk = origin + IVec3::new(i as i32, j as i32, k as i32);
                let want = dense.get(i, j, k);
                assert_eq!(
                    grid.value(ijk).to_bits(),
                    want.to_bits(),
                    "{ctx} value at {ijk}"
                );
                assert_eq!(grid.is_active(ijk), want != 0.0, "{ctx} active at {ijk}");
                active += (want != 0.0) as u64;
            }
        }
    }
    assert_eq!(
        grid.active_voxels(),
        active,
        "{ctx}: active voxels outside the array"
    );
}

/// Uniform scale plus translation, as every map in the test data is.
fn check_transform(ctx: &str, m: &DAffine3, voxel: DVec3, origin: DVec3) {
    assert_eq!(
        m.matrix3,
        DMat3::from_diagonal(voxel),
        "{ctx}: index-to-world matrix"
    );
    assert_eq!(m.translation, origin, "{ctx}: index-to-world translation");
}

#[test]
fn list_grids_reproduces_sidecar_metadata() {
    for file in FILES {
        let want = sidecar_grids(&sidecar(file));
        let got = list_grids(&data(file)).expect(file);
        assert_eq!(got.len(), want.len(), "{file}: grid count");
        for (g, w) in got.iter().zip(&want) {
            check_info(file, g, w);
        }
    }
}

#[test]
fn float_grids_equal_dense_truth_and_round_trip() {
    for file in FILES {
        let sc = sidecar(file);
        let infos = list_grids(&data(file)).expect(file);
        for (name, dense) in sc["dense"].as_object().expect("dense") {
            let info = infos.iter().find(|i| &i.name == name).expect("grid listed");
            if info.grid_type != GridType::FLOAT {
                continue;
            }
            let ctx = format!("{file} {name}");
            let grid = load_grid(&data(file), name).expect(&ctx);
            let npy = Dense::read(dense["npy"].as_str().expect("npy name"));
            assert_eq!(grid.name, *name);
            assert_eq!(grid.background, 0.0, "{ctx}");
            check_dense(&ctx, &grid, &npy, ivec(&dense["origin_ijk"]));
            let rt = &sc["round_trip_via_nanovdb_convert_and_openvdb"][name];
            assert_eq!(grid.active_voxels(), rt["active_voxel_count"], "{ctx}");
            let bbox = &rt["active_index_bbox"];
            assert_eq!(
                grid.active_bbox(),
                Some((ivec(&bbox["min"]), ivec(&bbox["max"])))
            );
            let (voxel, origin) = (dvec(&rt["voxel_size"]), dvec(&rt["index_to_world_origin"]));
            check_transform(&ctx, &grid.index_to_world, voxel, origin);
        }
    }
}

#[test]
fn density_probes_tiles_and_world_positions() {
    for file in FILES {
        let sc = sidecar(file);
        let grid = load_grid(&data(file), "density").expect(file);
        for p in sc["density_probes"].as_array().expect("probes") {
            let ijk = ivec(&p["ijk"]);
            let value = p["value"].as_f64().expect("value") as f32;
            assert_eq!(grid.value(ijk), value, "{file} probe {ijk}");
            assert_eq!(
                grid.is_active(ijk),
                p["active"] == true,
                "{file} probe {ijk}"
            );
        }
        assert_eq!(grid.leaf_count(), 217, "{file}");
        let mut tiles: Vec<[i32; 3]> = grid.tiles().iter().map(|t| t.min.to_array()).collect();
        tiles.sort();
        assert_eq!(tiles, PLUME_TILES, "{file}: tiles");
        for t in grid.tiles() {
            assert!(t.active && t.value == 1.0 && t.max - t.min == IVec3::splat(7));
        }
        let centre = grid
            .index_to_world
            .transform_point3(DVec3::new(0.0, 20.0, 0.0));
        assert_eq!(
            centre,
            DVec3::new(0.2578125, 0.0078125 + 20.0 / 32.0, -0.4453125)
        );
        let value = grid.value(IVec3::new(0, 20, 0));
        assert_eq!(grid.sample_world(centre.as_vec3()), value, "{file}");
    }
}

#[test]
fn multi_grid_picks_grids_by_name() {
    for file in ["multi_grid.nvdb", "multi_grid_v32_9.nvdb"] {
        let names: Vec<String> = list_grids(&data(file))
            .unwrap()
            .into_iter()
            .map(|i| i.name)
            .collect();
        assert_eq!(names, ["density", "temperature", "vel"], "{file}");
        let temperature = load_grid(&data(file), "temperature").expect(file);
        let density = load_grid(&data(file), "density").expect(file);
        assert_eq!(temperature.value(IVec3::new(0, 5, 0)), 806.25, "{file}");
        assert_eq!(temperature.active_voxels(), 8514);
        assert_eq!(temperature.leaf_count(), 45);
        assert!(temperature.tiles().is_empty());
        let origin = DVec3::new(35.0, 3.0, -55.0) / 128.0;
        check_transform(
            file,
            &temperature.index_to_world,
            DVec3::splat(1.0 / 16.0),
            origin,
        );
        assert_eq!(density.active_voxels(), 62266);
        assert_eq!(density.index_to_world.matrix3.x_axis.x, 1.0 / 32.0);
    }
}

#[test]
fn unknown_grid_name_lists_the_grids_in_the_file() {
    let (field, msg) = field_message(load_grid(&data("multi_grid_v32_9.nvdb"), "smoke"));
    assert_eq!(field, "grid");
    assert_eq!(
        msg,
        "no grid \"smoke\" (grids in file: density, temperature, vel)"
    );
    let (_, msg) = field_message(load_grid(&data("smoke_plume_blosc.nvdb"), "Density"));
    assert_eq!(msg, "no grid \"Density\" (grids in file: density)");
}

#[test]
fn non_float_grid_is_refused_naming_its_type() {
    for file in ["multi_grid.nvdb", "multi_grid_v32_9.nvdb"] {
        let (field, msg) = field_message(load_grid(&data(file), "vel"));
        assert_eq!(field, "grid");
        assert!(
            msg.contains("\"vel\"") && msg.contains("Vec3f"),
            "{file}: {msg}"
        );
    }
}

/// The temperature grid buffer of `multi_grid_v32_9.nvdb`, inflated (its ZIP payload is a
/// u64 byte count and a zlib stream).
fn temperature_buffer() -> Vec<u8> {
    use std::io::Read;
    let sc = sidecar("multi_grid_v32_9.nvdb");
    let meta = &sidecar_grids(&sc)[1];
    let at = meta["data_offset"].as_u64().unwrap() as usize;
    let raw = bytes("multi_grid_v32_9.nvdb");
    let count = u64::from_le_bytes(raw[at..at + 8].try_into().unwrap()) as usize;
    let mut out = Vec::new();
    flate2::read::ZlibDecoder::new(&raw[at + 8..at + 8 + count])
        .read_to_end(&mut out)
        .unwrap();
    assert_eq!(out.len() as u64, meta["grid_size_bytes"].as_u64().unwrap());
    out
}

#[test]
fn raw_grid_buffer_files_load() {
    let mut raw = bytes("smoke_plume_v32_9.nvdb")[GRID_AT..].to_vec();
    raw.extend_from_slice(&temperature_buffer());
    let file = Scratch::new("raw", &raw);
    let infos = list_grids(file.path()).unwrap();
    let want = sidecar_grids(&sidecar("multi_grid_v32_9.nvdb"));
    for (got, want) in infos.iter().zip(&want) {
        assert_eq!(got.codec, Codec::None);
        assert_eq!(got.file_bytes, got.grid_bytes);
        let mut want = want.clone();
        want["codec"] = "NONE".into();
        want["file_size_bytes"] = got.grid_bytes.into();
        check_info("raw buffer", got, &want);
    }
    assert_eq!(infos.len(), 2);
    let density = load_grid(file.path(), "density").unwrap();
    check_dense(
        "raw density",
        &density,
        &Dense::read("smoke_plume.density.npy"),
        IVec3::new(-32, 0, -32),
    );
    let temperature = load_grid(file.path(), "temperature").unwrap();
    let dense = Dense::read("multi_grid.temperature.npy");
    check_dense(
        "raw temperature",
        &temperature,
        &dense,
        IVec3::new(-16, 0, -16),
    );
}

/// Names of every grid in `file` (undamaged).
fn grid_names(file: &str) -> Vec<String> {
    list_grids(&data(file))
        .unwrap()
        .into_iter()
        .map(|i| i.name)
        .collect()
}

#[test]
fn truncated_files_are_format_errors() {
    for file in FILES {
        let full = bytes(file);
        let sc = sidecar(file);
        let segment_ends: Vec<u64> = sc["layout"]["segments"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["offset"].as_u64().unwrap())
            .collect();
        let step = (full.len() / 120).max(1);
        let mut lengths: Vec<usize> = (0..=300).chain((301..full.len()).step_by(step)).collect();
        lengths.extend([full.len() - 8, full.len() - 1]);
        lengths.retain(|&n| n == 0 || !segment_ends.contains(&(n as u64)));
        for len in lengths {
            let cut = Scratch::new("cut", &full[..len]);
            let what = format!("{file} cut to {len} bytes");
            format_message(list_grids(cut.path()), &what);
            format_message(load_grid(cut.path(), "density"), &what);
        }
    }
}

/// xorshift64: a fixed seed makes every run damage the same bits.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

fn flip(buf: &mut [u8], at: usize, bit: usize) {
    buf[at] ^= 1 << (bit % 8);
}

#[test]
fn seeded_bit_flips_never_panic() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for file in FILES {
        let full = bytes(file);
        let names = grid_names(file);
        for trial in 0..40 {
            let mut bad = full.clone();
            for _ in 0..1 + rng.below(4) {
                let span = if rng.below(2) == 0 {
                    full.len().min(4096)
                } else {
                    full.len()
                };
                let (at, bit) = (rng.below(span), rng.below(8));
                flip(&mut bad, at, bit);
            }
            let f = Scratch::new("flip", &bad);
            let listed = list_grids(f.path());
            assert!(
                !matches!(listed, Err(Error::Io { .. })),
                "{file} trial {trial}"
            );
            for name in &names {
                match load_grid(f.path(), name) {
                    Ok(_) | Err(Error::Format { .. } | Error::Field { .. }) => {}
                    Err(e) => panic!("{file} trial {trial}: unexpected error {e}"),
                }
            }
        }
    }
}

/// The grid header, tree header and root (bytes 16.. of the grid buffer) are covered by
/// NanoVDB's head checksum, so any single flipped bit there is caught. The checksum's
/// upper word (the tail CRC, unset by `nanovdb_convert`) is not checked.
#[test]
fn damage_to_the_grid_head_is_detected() {
    let mut rng = Rng(42);
    for file in ["smoke_plume.nvdb", "smoke_plume_v32_9.nvdb"] {
        let full = bytes(file);
        for _ in 0..150 {
            let at = GRID_AT + rng.below(GRID_DATA + TREE_DATA);
            if (GRID_AT + 12..GRID_AT + 16).contains(&at) {
                continue;
            }
            let mut bad = full.clone();
            flip(&mut bad, at, rng.below(8));
            let f = Scratch::new("head", &bad);
            format_message(
                load_grid(f.path(), "density"),
                &format!("{file} flip at {at}"),
            );
        }
    }
}

fn put(buf: &mut [u8], at: usize, value: &[u8]) {
    buf[at..at + value.len()].copy_from_slice(value);
}

fn expect_error(tag: &str, buf: &[u8], needle: &str) {
    let f = Scratch::new(tag, buf);
    let list = list_grids(f.path());
    let msg = match list {
        Err(_) => format_message(list, tag),
        Ok(_) => format_message(load_grid(f.path(), "density"), tag),
    };
    assert!(msg.contains(needle), "{tag}: \"{msg}\" lacks \"{needle}\"");
}

#[test]
fn absurd_sizes_in_headers_are_rejected() {
    let zip = bytes("smoke_plume_zip.nvdb");
    let cases: [(&str, usize, &[u8], &str); 9] = [
        (
            "grid count",
            12,
            &u16::MAX.to_le_bytes(),
            "metadata of grid",
        ),
        ("codec", 14, &7u16.to_le_bytes(), "unknown codec 7"),
        (
            "version",
            8,
            &(31u32 << 21).to_le_bytes(),
            "version 31.0.0 is not supported",
        ),
        (
            "grid size max",
            16,
            &u64::MAX.to_le_bytes(),
            "cannot come from",
        ),
        (
            "grid size 1 TiB",
            16,
            &(1u64 << 40).to_le_bytes(),
            "cannot come from",
        ),
        ("file size", 24, &u64::MAX.to_le_bytes(), "run past the end"),
        (
            "name size",
            16 + 136,
            &u32::MAX.to_le_bytes(),
            "run past the end",
        ),
        ("zip count", GRID_AT, &u64::MAX.to_le_bytes(), "zip stream"),
        (
            "zip count short",
            GRID_AT,
            &1000u64.to_le_bytes(),
            "zip stream",
        ),
    ];
    for (tag, at, value, needle) in cases {
        let mut bad = zip.clone();
        put(&mut bad, at, value);
        expect_error(tag, &bad, needle);
    }
}

#[test]
fn damaged_blosc_frames_are_rejected() {
    let blosc = bytes("smoke_plume_blosc.nvdb");
    let frame = GRID_AT + 8;
    let cases: [(&str, usize, &[u8], &str); 8] = [
        (
            "chunk size",
            GRID_AT,
            &u64::MAX.to_le_bytes(),
            "blosc chunk",
        ),
        ("typesize", frame + 3, &[0], "typesize"),
        (
            "nbytes",
            frame + 4,
            &u32::MAX.to_le_bytes(),
            "expected 1683200",
        ),
        ("blocksize", frame + 8, &0u32.to_le_bytes(), "block size 0"),
        (
            "cbytes",
            frame + 12,
            &u32::MAX.to_le_bytes(),
            "run past the end",
        ),
        ("codec", frame + 2, &[(4 << 5) | 1], "zstd"),
        (
            "block start",
            frame + 16,
            &(-5i32).to_le_bytes(),
            "negative block start",
        ),
        (
            "stream",
            frame + 24,
            &[0xff, 0xff, 0xff, 0x7f],
            "run past the end",
        ),
    ];
    for (tag, at, value, needle) in cases {
        let mut bad = blosc.clone();
        put(&mut bad, at, value);
        expect_error(tag, &bad, needle);
    }
}

/// `smoke_plume_v32_9.nvdb` with its checksum switched off (all ones, as NanoVDB writes
/// when checksums are disabled), so that the tree checks themselves are exercised.
fn unchecked_grid() -> Vec<u8> {
    let mut buf = bytes("smoke_plume_v32_9.nvdb");
    put(&mut buf, GRID_AT + 8, &u64::MAX.to_le_bytes());
    buf
}

#[test]
fn broken_tree_links_and_counts_are_rejected() {
    let good = unchecked_grid();
    let f = Scratch::new("unchecked", &good);
    assert_eq!(
        load_grid(f.path(), "density").unwrap().active_voxels(),
        62266
    );
    let tree = GRID_AT + GRID_DATA;
    let root = tree + TREE_DATA;
    let tile = |i: usize| root + 64 + 32 * i;
    let child0 = good[tile(0) + 8..tile(0) + 16].to_vec();
    let child0_plus_8 = (i64::from_le_bytes(child0.clone().try_into().unwrap()) + 8).to_le_bytes();
    let first_leaf = tree + read_u64(&good, tree);
    let cases: Vec<(&str, usize, Vec<u8>, &str)> = vec![
        (
            "grid size",
            GRID_AT + 32,
            u64::MAX.to_le_bytes().into(),
            "grid header says",
        ),
        (
            "grid type",
            GRID_AT + 636,
            6u32.to_le_bytes().into(),
            "Vec3f",
        ),
        (
            "root tiles",
            root + 24,
            u32::MAX.to_le_bytes().into(),
            "root table",
        ),
        (
            "leaf count",
            tree + 32,
            u32::MAX.to_le_bytes().into(),
            "leaf nodes",
        ),
        (
            "leaf count + 1",
            tree + 32,
            218u32.to_le_bytes().into(),
            "leaf nodes",
        ),
        (
            "upper count",
            tree + 40,
            3u32.to_le_bytes().into(),
            "not a new upper node",
        ),
        (
            "voxel count",
            tree + 56,
            62267u64.to_le_bytes().into(),
            "active voxels",
        ),
        ("aliased child", tile(1) + 8, child0, "not a new upper node"),
        (
            "misaligned child",
            tile(0) + 8,
            child0_plus_8.into(),
            "not a new upper node",
        ),
        (
            "child far away",
            tile(0) + 8,
            (i64::MIN).to_le_bytes().into(),
            "out of range",
        ),
        (
            "leaf origin",
            first_leaf,
            4096i32.to_le_bytes().into(),
            "origin",
        ),
        (
            "repeated key",
            tile(1),
            good[tile(0)..tile(0) + 8].to_vec(),
            "repeats key",
        ),
        (
            "root key",
            tile(3),
            (1u64 << 60).to_le_bytes().into(),
            "has origin",
        ),
        ("map", GRID_AT + 296 + 88, [0; 72].into(), "not invertible"),
    ];
    for (tag, at, value, needle) in cases {
        let mut bad = good.clone();
        put(&mut bad, at, &value);
        expect_error(tag, &bad, needle);
    }
}

#[test]
fn checksum_mismatch_and_foreign_files_are_reported() {
    let mut bad = bytes("smoke_plume_v32_9.nvdb");
    flip(&mut bad, GRID_AT + 40, 0);
    expect_error("checksum", &bad, "checksum mismatch");
    let mut vdb = vec![0u8; 64];
    put(&mut vdb, 0, &0x5644_4220u32.to_le_bytes());
    expect_error("openvdb", &vdb, "OpenVDB file");
    expect_error("empty", &[], "too short");
    expect_error(
        "text",
        b"hello, this is not a volume at all",
        "not a NanoVDB file",
    );
    let missing = load_grid(&data("no_such_file.nvdb"), "density");
    assert!(matches!(missing, Err(Error::Io { .. })));
}

fn read_u64(buf: &[u8], at: usize) -> usize {
    u64::from_le_bytes(buf[at..at + 8].try_into().unwrap()) as usize
}

/// Moves the last upper node's subtree (root key (0,0,0)) to x = 2^30 consistently: the
/// key, empty bboxes on its two internal nodes, and the origins of its leaves (the last
/// ones, as nodes are stored breadth-first). The result is a valid but absurdly sparse
/// tree whose leaf table would need 2^27 x 8 x 7 slots.
#[test]
fn absurdly_spread_tree_is_refused() {
    const FAR: i32 = 1 << 30;
    let mut buf = unchecked_grid();
    let tree = GRID_AT + GRID_DATA;
    let root = tree + TREE_DATA;
    put(
        &mut buf,
        root + 64 + 3 * 32,
        &(((FAR as u64) >> 12) << 42).to_le_bytes(),
    );
    let upper = tree + read_u64(&buf, tree + 16) + 3 * 270_400;
    let lower = tree + read_u64(&buf, tree + 8) + 3 * 33_856;
    for node in [upper, lower] {
        put(
            &mut buf,
            node,
            &[1i32, 1, 1, 0, 0, 0].map(i32::to_le_bytes).concat(),
        );
    }
    let children: u32 = (0..64)
        .map(|w| read_u64(&buf, lower + 32 + 512 + 8 * w).count_ones())
        .sum();
    let leaves = tree + read_u64(&buf, tree);
    for i in 217 - children as usize..217 {
        let at = leaves + i * 2144;
        let x = i32::from_le_bytes(buf[at..at + 4].try_into().unwrap());
        put(&mut buf, at, &(x + FAR).to_le_bytes());
    }
    expect_error("spread", &buf, "too sparse");
}
