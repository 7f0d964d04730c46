//! Production-size OpenVDB files written by OpenVDB itself (`tools/make_large_vdbs.py`, not
//! in git): the reader reproduces their sidecars, and the majorant octree keeps its
//! invariants on them. Without the files the tests say so and pass, unless
//! PPB_REQUIRE_LARGE=1 (CI, which generates them) makes that a failure.
use glam::{DAffine3, DMat3, DVec3, IVec3, Vec3};
use ppb::core::Ray;
use ppb::majorant::octree::{depth_for, leaf_for_point, root_span, Octree};
use ppb::majorant::DEFAULT_MAX_DEPTH;
use ppb::media::grid::Grid;
use ppb::media::openvdb::load_grid;
use ppb::media::{GridMedium, Phase};
use ppb::sampling::Rng;
use serde_json::Value;
use std::path::PathBuf;
use std::sync::Arc;

/// The folder of the generated files: PPB_LARGE_VDB_DIR, else the script's default.
fn dir() -> PathBuf {
    std::env::var_os("PPB_LARGE_VDB_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/large-vdb"))
}

/// The grid and its sidecar, or None (with a note) when the file was not generated.
fn load(name: &str) -> Option<(Grid, Value)> {
    let (vdb, json) = (
        dir().join(format!("{name}.vdb")),
        dir().join(format!("{name}.json")),
    );
    if !vdb.exists() || !json.exists() {
        let why = format!(
            "{} missing: run `python3 tools/make_large_vdbs.py` (see docs/media.md)",
            vdb.display()
        );
        if std::env::var("PPB_REQUIRE_LARGE").as_deref() == Ok("1") {
            panic!("PPB_REQUIRE_LARGE=1 but {why}");
        }
        eprintln!("skipped: {why}");
        return None;
    }
    let sidecar = serde_json::from_str(&std::fs::read_to_string(&json).expect("sidecar"))
        .expect("sidecar JSON");
    Some((load_grid(&vdb, "density").expect("loads"), sidecar))
}

fn ivec(v: &Value) -> IVec3 {
    let c = |i: usize| v[i].as_i64().expect("integer") as i32;
    IVec3::new(c(0), c(1), c(2))
}

/// Active voxel count, bounding box, value range, sum, leaves, transform and probes as
/// OpenVDB reported them when it wrote the file.
fn matches_sidecar(name: &str) {
    let Some((g, s)) = load(name) else { return };
    assert_eq!(
        g.active_voxels(),
        s["active_voxel_count"].as_u64().unwrap(),
        "{name}: active voxels"
    );
    assert_eq!(
        g.leaf_count() as u64,
        s["leaf_count"].as_u64().unwrap(),
        "{name}: leaves"
    );
    let (lo, hi) = g.active_bbox().expect("active voxels");
    let bbox = &s["active_index_bbox"];
    assert_eq!(
        (lo, hi),
        (ivec(&bbox["min"]), ivec(&bbox["max"])),
        "{name}: active bbox"
    );
    let (min, max, mean) = g.active_stats().expect("active voxels");
    let range = &s["min_max_active"];
    // The sidecar holds float32 values as JSON numbers: compare as float32.
    let f32_of = |v: &Value| v.as_f64().unwrap() as f32;
    assert_eq!(min, f32_of(&range[0]), "{name}: min");
    assert_eq!(max, f32_of(&range[1]), "{name}: max");
    // The sidecar sums the same float32 values in float64 in another order.
    let sum = mean * g.active_voxels() as f64;
    let want = s["sum_active_float64"].as_f64().unwrap();
    assert!(
        (sum - want).abs() <= 1e-9 * want,
        "{name}: sum {sum} vs {want}"
    );
    let m = &s["index_to_world_row_major_4x4"];
    let row = |r: usize| {
        DVec3::new(
            m[r][0].as_f64().unwrap(),
            m[r][1].as_f64().unwrap(),
            m[r][2].as_f64().unwrap(),
        )
    };
    let want = DAffine3::from_mat3_translation(DMat3::from_cols(row(0), row(1), row(2)), row(3));
    assert!(
        g.index_to_world.abs_diff_eq(want, 1e-12),
        "{name}: transform {:?}",
        g.index_to_world
    );
    for p in s["probes"].as_array().unwrap() {
        let ijk = ivec(&p["ijk"]);
        assert_eq!(g.value(ijk), f32_of(&p["value"]), "{name}: value at {ijk}");
        assert_eq!(
            g.is_active(ijk),
            p["active"].as_bool().unwrap(),
            "{name}: active at {ijk}"
        );
    }
}

#[test]
fn plume_512_matches_its_sidecar() {
    matches_sidecar("plume_512");
}

#[test]
fn cloud_1024_matches_its_sidecar() {
    matches_sidecar("cloud_1024");
}

/// On the 1024^3 cloud at a dense scale: every leaf's majorant bounds, and its minorant
/// underbounds, the trilinear sigma_t at random points (the walk's decisions rest on
/// both), and the walk covers each ray's span of the root without gaps. The tree is as
/// deep as a render's (cells of 4 voxels at this size).
#[test]
fn octree_bounds_and_walk_hold_on_the_large_cloud() {
    let Some((g, _)) = load("cloud_1024") else {
        return;
    };
    let m = GridMedium::new(
        Arc::new(g),
        DAffine3::IDENTITY,
        40.0,
        Vec3::ONE,
        Phase::ISOTROPIC,
        "cloud_1024".into(),
        [0; 32],
    );
    assert_eq!(
        depth_for(&m, DEFAULT_MAX_DEPTH),
        8,
        "a 1024^3 grid gets the budget's depth"
    );
    let t = Octree::build(&m, DEFAULT_MAX_DEPTH);
    assert!(t.leaf_count() > 1000, "{} leaves", t.leaf_count());
    let [lo, hi] = m.bounds;
    let mut rng = Rng::new(7, 7);
    let mut inside_cloud = 0;
    for _ in 0..300_000 {
        let p = lo + (hi - lo) * Vec3::new(rng.f32(), rng.f32(), rng.f32());
        let leaf = leaf_for_point(&t, p).expect("inside the root");
        let s = m.sigma_t(p);
        inside_cloud += (s > 0.0) as u32;
        assert!(
            s <= leaf.majorant * (1.0 + 1e-5) + 1e-6,
            "{s} > {} at {p}",
            leaf.majorant
        );
        assert!(
            s >= leaf.minorant * (1.0 - 1e-5) - 1e-6,
            "{s} < {} at {p}",
            leaf.minorant
        );
    }
    assert!(
        inside_cloud > 10_000,
        "only {inside_cloud} probes in the cloud"
    );
    for _ in 0..2000 {
        let o = Vec3::new(rng.f32() * 8.0 - 4.0, rng.f32() * 4.0, 6.0);
        let target = lo + (hi - lo) * Vec3::new(rng.f32(), rng.f32(), rng.f32());
        let ray = Ray::new(o, (target - o).normalize());
        let Some((a, b)) = root_span(&t, &ray, 100.0) else {
            continue;
        };
        let mut last = a;
        t.walk(&ray, 100.0, |_, s0, s1| {
            assert!((s0 - last).abs() < 1e-4, "gap {last} -> {s0}");
            assert!(s1 >= s0);
            last = s1;
            true
        });
        assert!(
            (last - b).abs() < 1e-4,
            "walk ended at {last}, span ends at {b}"
        );
    }
}
