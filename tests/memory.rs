//! Peak memory of each loader against the size of the file it reads, counted by a global
//! allocator wrapper (one test, so nothing else allocates meanwhile).
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use ppb::scene::files::Files;

struct Counting;

static NOW: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = System.alloc(l);
        if !p.is_null() {
            let now = NOW.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l);
        NOW.fetch_sub(l.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static A: Counting = Counting;

/// What `f` allocated: at its peak, and still held by its result.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize, usize) {
    let base = NOW.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let r = f();
    let held = NOW.load(Ordering::Relaxed).saturating_sub(base);
    (r, PEAK.load(Ordering::Relaxed) - base, held)
}

/// A loader's peak is at most the bytes of the files it read (a compressed grid counted
/// at its uncompressed size, that of the same grid written uncompressed) plus twice what
/// it returns
/// (one working copy of the result, e.g. a vector grown by doubling), plus 2 MiB of fixed
/// overhead (parsers' tables, the USD crate's schema registry): nothing in a file can make
/// a loader hold many copies of it.
#[test]
fn loaders_peak_memory_against_file_size() {
    const FIXED: usize = 2 << 20;
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let mut rows = Vec::new();
    let mut check = |kind: &str,
                     name: &str,
                     raw: Option<&str>,
                     f: &dyn Fn(&Path, &Files) -> Box<dyn std::any::Any>| {
        let p = data.join(name);
        let files = Files::new();
        let (result, peak, held) = peak_of(|| f(&p, &files));
        let read: u64 = files
            .files_read()
            .iter()
            .map(|f| std::fs::metadata(f).unwrap().len())
            .sum();
        let read = match raw {
            Some(r) => std::fs::metadata(data.join(r)).unwrap().len().max(read),
            None => read,
        } as usize;
        drop(result);
        rows.push(format!(
            "{kind:8} {name:36} read {read:>9} B, result {held:>9} B, peak {peak:>9} B"
        ));
        let limit = read + 2 * held + FIXED;
        assert!(
            peak <= limit,
            "{name}: peak {peak} B over {limit} B (read {read} B, result {held} B)"
        );
    };
    let vdb = |p: &Path, f: &Files| -> Box<dyn std::any::Any> {
        let b = f.read(p).unwrap();
        Box::new(ppb::media::openvdb::load_grid_from(p, &b, "density").unwrap())
    };
    let nvdb = |p: &Path, f: &Files| -> Box<dyn std::any::Any> {
        let b = f.read(p).unwrap();
        Box::new(ppb::media::nanovdb::load_grid_from(p, &b, "density").unwrap())
    };
    let gltf = |p: &Path, f: &Files| -> Box<dyn std::any::Any> {
        Box::new(ppb::scene::gltf::read_gltf(p, f).unwrap())
    };
    let obj = |p: &Path, f: &Files| -> Box<dyn std::any::Any> {
        Box::new(ppb::scene::obj::read_obj(p, f).unwrap())
    };
    let usd = |p: &Path, f: &Files| -> Box<dyn std::any::Any> {
        Box::new(ppb::scene::usd::read_usd(p, f).unwrap())
    };
    let none = Some("vdb/smoke_plume_none.vdb");
    for (f, raw) in [
        ("vdb/smoke_plume_none.vdb", None),
        ("vdb/smoke_plume.vdb", none),
        ("vdb/smoke_plume_zip.vdb", none),
        ("vdb/half_precision.vdb", None),
        ("vdb/mantaflow/manta_smoke_0048.vdb", None),
    ] {
        check("openvdb", f, raw, &vdb);
    }
    let raw = Some("nvdb/smoke_plume.nvdb");
    for (f, raw) in [
        ("nvdb/smoke_plume.nvdb", None),
        ("nvdb/smoke_plume_zip.nvdb", raw),
        ("nvdb/smoke_plume_blosc.nvdb", raw),
    ] {
        check("nanovdb", f, raw, &nvdb);
    }
    check("gltf", "scene/glass_scene.gltf", None, &gltf);
    check("glb", "scene/glass_scene.glb", None, &gltf);
    check("obj", "scene/glass_scene.obj", None, &obj);
    check("usda", "usd/stage/glass_smoke.usda", None, &usd);
    check("usdc", "usd/stage/glass_smoke.usdc", None, &usd);
    eprintln!("{}", rows.join("\n"));
}
