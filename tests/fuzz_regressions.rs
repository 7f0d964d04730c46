//! Inputs that once crashed, hung or over-allocated a loader (found by the fuzz targets in
//! `fuzz/`, or made by hand for the absurd-size checks): each file in `tests/data/fuzz/`
//! is `<target>-<what>.<ext>` and is loaded through the same entry point as its target,
//! which must answer with a clean error naming the file, promptly, and never panic.
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use ppb::scene::files::Files;

/// A regression input must be refused well within this (the hangs took minutes).
const PROMPT: Duration = Duration::from_secs(20);

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz")
}

/// A scratch folder of its own for inputs that must sit next to other files.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ppb-fuzz-reg-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Every call the target makes, as (what, Ok or the error's text).
type Outcomes = Vec<(String, Result<(), String>)>;

fn push<T, E: std::fmt::Display>(out: &mut Outcomes, what: &str, r: Result<T, E>) {
    out.push((what.to_string(), r.map(|_| ()).map_err(|e| e.to_string())));
}

/// openvdb and nanovdb targets: list the grids, load each (and "density").
fn grids(path: &Path, bytes: &[u8], nano: bool) -> Outcomes {
    let mut out = Outcomes::new();
    let (list, load): (Vec<String>, _) = if nano {
        let l = ppb::media::nanovdb::list_grids_from(path, bytes);
        let names: Vec<String> = l
            .as_ref()
            .map(|g| g.iter().map(|d| d.name.clone()).collect())
            .unwrap_or_default();
        push(&mut out, "list", l);
        (
            names,
            ppb::media::nanovdb::load_grid_from as fn(&Path, &[u8], &str) -> _,
        )
    } else {
        let l = ppb::media::openvdb::list_grids_from(path, bytes);
        let names: Vec<String> = l
            .as_ref()
            .map(|g| g.iter().map(|d| d.name.clone()).collect())
            .unwrap_or_default();
        push(&mut out, "list", l);
        (
            names,
            ppb::media::openvdb::load_grid_from as fn(&Path, &[u8], &str) -> _,
        )
    };
    for name in list.iter().map(String::as_str).chain(["density"]) {
        push(&mut out, &format!("load {name}"), load(path, bytes, name));
    }
    out
}

/// obj target: the OBJ text, then after the first NUL byte the `fuzz.mtl` it names.
fn obj(name: &str, bytes: &[u8]) -> (Outcomes, Vec<PathBuf>) {
    let dir = scratch(name);
    let (text, mtl) = match bytes.iter().position(|&b| b == 0) {
        Some(i) => (&bytes[..i], Some(&bytes[i + 1..])),
        None => (bytes, None),
    };
    let (path, mtl_path) = (dir.join("fuzz.obj"), dir.join("fuzz.mtl"));
    std::fs::write(&path, text).unwrap();
    if let Some(m) = mtl {
        std::fs::write(&mtl_path, m).unwrap();
    }
    let mut out = Outcomes::new();
    push(
        &mut out,
        "read_obj",
        ppb::scene::obj::read_obj(&path, &Files::new()),
    );
    (out, vec![path, mtl_path])
}

/// Runs one regression input through its target's entry point; returns the outcomes and
/// the paths an error may name.
fn run(file: &Path) -> (Outcomes, Vec<PathBuf>) {
    let name = file.file_name().unwrap().to_string_lossy().into_owned();
    let target = name.split('-').next().unwrap();
    let bytes = std::fs::read(file).unwrap();
    let named = vec![file.to_path_buf()];
    let out = match target {
        "obj" => return obj(&name, &bytes),
        "openvdb" => grids(file, &bytes, false),
        "nanovdb" => grids(file, &bytes, true),
        "exr" => {
            let mut out = Outcomes::new();
            push(&mut out, "read_exr", ppb::output::read_exr(file));
            out
        }
        "gltf" => {
            let mut out = Outcomes::new();
            push(
                &mut out,
                "read_gltf",
                ppb::scene::gltf::read_gltf(file, &Files::new()),
            );
            out
        }
        "part" => {
            let mut out = Outcomes::new();
            push(&mut out, "Part::read", ppb::farm::Part::read(file));
            out
        }
        // The USD crate can abort the process on these, so they go through the binary,
        // which parses a stage in a child process first (tests/reliability.rs too).
        "usd" => {
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_ppb"))
                .arg("info")
                .arg(file)
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr).into_owned();
            assert_eq!(o.status.code(), Some(2), "{name}: {err}");
            assert!(!err.contains("panicked"), "{name}: {err}");
            let mut out = Outcomes::new();
            push(&mut out, "ppb info", Err::<(), _>(err));
            out
        }
        other => panic!("{name}: no target {other}"),
    };
    (out, named)
}

#[test]
fn fuzz_inputs_are_clean_errors() {
    let mut files: Vec<PathBuf> = std::fs::read_dir(fuzz_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty());
    for file in files {
        let start = Instant::now();
        let (out, named) = run(&file);
        let took = start.elapsed();
        let shown = file.display().to_string();
        assert!(took < PROMPT, "{shown}: took {took:?}");
        assert!(
            out.iter().any(|(_, r)| r.is_err()),
            "{shown}: loaded without an error: {out:?}"
        );
        for (what, r) in &out {
            if let Err(e) = r {
                let names_one = named.iter().any(|p| e.contains(&p.display().to_string()));
                assert!(
                    names_one,
                    "{shown}: {what}: error does not name the file: {e}"
                );
            }
        }
        eprintln!("{shown}: {:?}", out.iter().find(|(_, r)| r.is_err()));
    }
}

/// A chain of nodes as deep as the file is long (each node the only child of the one
/// before) once overflowed the stack in the recursive scene walk (SIGSEGV at 60,000
/// nodes). Now it loads, and a chain that loops back is a clean cycle error.
#[test]
fn gltf_deep_node_chain_does_not_overflow_the_stack() {
    let dir = scratch("deep");
    let n = 200_000;
    let chain = |last: &str| {
        let mut nodes: Vec<String> = (1..n).map(|i| format!("{{\"children\":[{i}]}}")).collect();
        nodes.push(last.to_string());
        format!(
            "{{\"asset\":{{\"version\":\"2.0\"}},\"scene\":0,\"scenes\":[{{\"nodes\":[0]}}],\
             \"nodes\":[{}],\"meshes\":[{{\"primitives\":[{{\"attributes\":{{\"POSITION\":0}}}}]}}],\
             \"buffers\":[{{\"byteLength\":36,\"uri\":\"tri.bin\"}}],\
             \"bufferViews\":[{{\"buffer\":0,\"byteLength\":36}}],\
             \"accessors\":[{{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\",\
             \"min\":[0,0,0],\"max\":[1,1,0]}}]}}",
            nodes.join(",")
        )
    };
    let tri: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(dir.join("tri.bin"), tri).unwrap();
    let deep = dir.join("deep.gltf");
    std::fs::write(&deep, chain("{\"mesh\":0}")).unwrap();
    // Run on a thread with a small stack, as a test or a worker thread has.
    let r = std::thread::Builder::new()
        .stack_size(1 << 20)
        .spawn(move || ppb::scene::gltf::read_gltf(&deep, &Files::new()).map(|i| i.meshes.len()))
        .unwrap()
        .join()
        .expect("no panic");
    assert_eq!(r.unwrap(), 1);
    let looped = dir.join("loop.gltf");
    std::fs::write(&looped, chain("{\"mesh\":0,\"children\":[1]}")).unwrap();
    let e = ppb::scene::gltf::read_gltf(&looped, &Files::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("nodes[1]") && e.contains("cycle"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The NanoVDB plume with its last upper node's subtree moved 2^23 voxels along x (as in
/// `tests/nanovdb.rs`' spread test, which moves it 2^30): a 1.7 MB grid whose leaf table
/// would take 2^20 x 8 x 7 slots (235 MB). Under the fixed 2^27-slot cap it was built;
/// now the table may not outgrow the buffer by more than 4 slots per byte.
#[test]
fn nanovdb_sparse_leaves_cannot_claim_a_table_out_of_proportion() {
    const FAR: i32 = 1 << 23;
    const GRID_AT: usize = 16 + 176 + 8;
    const GRID_DATA: usize = 672;
    const TREE_DATA: usize = 64;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/nvdb/smoke_plume_v32_9.nvdb");
    let mut buf = std::fs::read(&path).unwrap();
    let put = |buf: &mut Vec<u8>, at: usize, v: &[u8]| buf[at..at + v.len()].copy_from_slice(v);
    let u64_at =
        |buf: &[u8], at: usize| u64::from_le_bytes(buf[at..at + 8].try_into().unwrap()) as usize;
    put(&mut buf, GRID_AT + 8, &u64::MAX.to_le_bytes());
    let tree = GRID_AT + GRID_DATA;
    let root = tree + TREE_DATA;
    put(
        &mut buf,
        root + 64 + 3 * 32,
        &(((FAR as u64) >> 12) << 42).to_le_bytes(),
    );
    let upper = tree + u64_at(&buf, tree + 16) + 3 * 270_400;
    let lower = tree + u64_at(&buf, tree + 8) + 3 * 33_856;
    for node in [upper, lower] {
        put(
            &mut buf,
            node,
            &[1i32, 1, 1, 0, 0, 0].map(i32::to_le_bytes).concat(),
        );
    }
    let children: u32 = (0..64)
        .map(|w| u64_at(&buf, lower + 32 + 512 + 8 * w).count_ones())
        .sum();
    let leaves = tree + u64_at(&buf, tree);
    for i in 217 - children as usize..217 {
        let at = leaves + i * 2144;
        let x = i32::from_le_bytes(buf[at..at + 4].try_into().unwrap());
        put(&mut buf, at, &(x + FAR).to_le_bytes());
    }
    let p = Path::new("spread.nvdb");
    let e = ppb::media::nanovdb::load_grid_from(p, &buf, "density")
        .unwrap_err()
        .to_string();
    assert!(e.contains("spread.nvdb") && e.contains("too sparse"), "{e}");
}
