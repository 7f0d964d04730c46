//! `ppb info`: what a scene, grid file or USD stage holds.
use anyhow::Result;
use std::path::Path;
use std::process::ExitCode;

/// Prints one loaded grid: bounds, voxel size, counts, value range and memory.
fn print_grid(g: &ppb::media::grid::Grid) {
    let m = g.index_to_world.matrix3;
    let voxel = glam::DVec3::new(m.x_axis.length(), m.y_axis.length(), m.z_axis.length());
    println!(
        "  voxel size   {:.6} {:.6} {:.6}",
        voxel.x, voxel.y, voxel.z
    );
    if let Some((lo, hi)) = g.active_bbox() {
        let wlo = g.index_to_world.transform_point3(lo.as_dvec3());
        let whi = g.index_to_world.transform_point3(hi.as_dvec3());
        println!("  index bbox   {lo} .. {hi} (inclusive)");
        println!("  world bbox   {wlo:.4} .. {whi:.4} (voxel centres)");
    }
    let active = g.active_voxels();
    println!(
        "  active       {active} voxels, {} leaves, {} tiles",
        g.leaf_count(),
        g.tiles().len()
    );
    if let Some((lo, hi, mean)) = g.active_stats() {
        println!("  values       min {lo} max {hi} mean {mean:.6} (active voxels)");
    }
    let bytes = g.memory_bytes();
    println!(
        "  memory       {:.2} MiB, {:.2} bytes per active voxel",
        bytes as f64 / (1 << 20) as f64,
        bytes as f64 / active.max(1) as f64
    );
}

fn info_grid_file(path: &Path) -> Result<ExitCode> {
    let file = ppb::scene::grids::GridFile::open(path)?;
    println!("file         {}", path.display());
    for g in file.grids()? {
        println!("grid \"{}\": {}", g.name, g.kind);
        if g.loadable {
            print_grid(&file.load(&g.name)?);
        }
    }
    Ok(ExitCode::SUCCESS)
}

pub fn info(scene: &Path) -> Result<ExitCode> {
    if ppb::scene::Format::detect(scene).is_some_and(ppb::scene::Format::is_grid) {
        return info_grid_file(scene);
    }
    let file = super::load_scene(scene)?;
    let s = &file.scene;
    println!("scene      {}", scene.display());
    println!(
        "image      {}x{}, {} passes, {} light paths per pass",
        file.settings.width, file.settings.height, file.settings.passes, file.settings.light_paths
    );
    println!(
        "camera     origin {:?} target {:?} vfov {}",
        s.camera.origin, s.camera.target, s.camera.vfov_deg
    );
    for m in &s.materials {
        println!("material   {}: {:?}", m.name, m.material);
    }
    for m in &s.meshes {
        println!(
            "mesh       {}: {} triangles, material {}",
            m.name,
            m.triangles.len(),
            s.materials.get(m.material).map_or("?", |x| x.name.as_str())
        );
    }
    for l in &s.lights {
        println!("light      {l:?}");
    }
    for m in &s.media {
        println!(
            "medium     homogeneous {:?}..{:?} sigma_t {} albedo {:?} g {}",
            m.bounds[0], m.bounds[1], m.sigma_t, m.albedo, m.phase.g
        );
    }
    for g in &s.grid_media {
        println!(
            "medium       grid {}: bounds {:?}..{:?}, density_scale {}, majorant {} 1/m, albedo {:?} g {}",
            g.source, g.bounds[0], g.bounds[1], g.density_scale, g.majorant(), g.albedo, g.phase.g
        );
        print_grid(&g.grid);
    }
    for p in &file.sources[1..] {
        println!("source     {}", p.display());
    }
    for n in &file.notes {
        println!("usd        {n}");
    }
    Ok(ExitCode::SUCCESS)
}
