//! Wavefront OBJ import (with its .mtl): triangle meshes and materials, no lights or camera.
use std::path::Path;

use glam::Vec3;

use super::files::Files;
use super::{Imported, Material, Mesh, NamedMaterial};
use crate::error::{Error, Result};

/// Index of refraction when the .mtl gives no `Ni`.
const DEFAULT_IOR: f32 = 1.5;
/// Reflectance of the fallback material for faces the .mtl does not cover.
const DEFAULT_GREY: f32 = 0.8;

/// Loads an OBJ file into world-space meshes (OBJ has no transforms) and its .mtl materials.
///
/// Faces are triangulated and vertices single-indexed so positions and normals share indices.
/// Meshes without a triangle are skipped; a file with none at all is an error. A missing or
/// unreadable .mtl is not an error: affected meshes use a grey Lambert material "default".
pub fn load_obj(path: &Path) -> Result<Imported> {
    read_obj(path, &Files::new())
}

/// [`load_obj`] reading the OBJ and its .mtl through `files` (once each per load).
pub fn read_obj(path: &Path, files: &Files) -> Result<Imported> {
    let bytes = files.read(path)?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let dir = path.parent().unwrap_or(Path::new(""));
    let mtl_files = std::cell::RefCell::new(Vec::new());
    let mtl_error = std::cell::RefCell::new(None);
    let loaded = tobj::load_obj_buf(&mut &bytes[..], &options, |mtl_path| {
        let p = dir.join(mtl_path);
        mtl_files.borrow_mut().push(p.clone());
        match files.read(&p) {
            Ok(mtl) => match check_mtl(&p, &mtl) {
                Ok(()) => tobj::load_mtl_buf(&mut &mtl[..]),
                Err(e) => {
                    mtl_error.borrow_mut().get_or_insert(e);
                    Err(tobj::LoadError::MaterialParseError)
                }
            },
            Err(_) => Err(tobj::LoadError::OpenFileFailed),
        }
    });
    if let Some(e) = mtl_error.into_inner() {
        return Err(e);
    }
    let (models, mtl) = loaded.map_err(|e| Error::format(path, e.to_string()))?;

    let mut out = Imported {
        materials: mtl
            .unwrap_or_default()
            .iter()
            .map(convert_material)
            .collect(),
        files: mtl_files.into_inner(),
        ..Default::default()
    };
    let mut default = None;
    for model in &models {
        if let Some(mut mesh) = convert_mesh(path, model)? {
            mesh.material =
                material_index(&mut out.materials, &mut default, model.mesh.material_id);
            out.meshes.push(mesh);
        }
    }
    if out.meshes.is_empty() {
        return Err(Error::format(path, "no triangles"));
    }
    Ok(out)
}

/// Refuses the .mtl lines that make tobj panic instead of returning an error: a colour
/// (`Ka`, `Kd`, `Ks`, `Ke`) with fewer than three numbers. Lines are split as tobj splits
/// them (`BufRead::lines`, then whitespace).
fn check_mtl(path: &Path, mtl: &[u8]) -> Result<()> {
    for (i, line) in mtl.split(|&b| b == b'\n').enumerate() {
        let Ok(line) = std::str::from_utf8(line) else {
            continue;
        };
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            if words.count() < 3 {
                let msg = format!("line {}: {key} needs three numbers (r g b)", i + 1);
                return Err(Error::format(path, msg));
            }
        }
    }
    Ok(())
}

/// Maps an .mtl entry to our material model.
///
/// Dielectric when the material is see-through by the MTL conventions (`d` < 1, or `illum`
/// 4, 6 or 7) or when its name contains "glass" (any case): Blender writes glass as an
/// opaque `illum 2` material with Kd 1 1 1, so the name is the only hint it carries. The
/// dielectric's IOR is `Ni` (1.5 when absent). Everything else is Lambert with `Kd`.
fn convert_material(m: &tobj::Material) -> NamedMaterial {
    let see_through = m.dissolve.is_some_and(|d| d < 1.0)
        || matches!(m.illumination_model, Some(4 | 6 | 7))
        || m.name.to_lowercase().contains("glass");
    let material = if see_through {
        Material::Dielectric {
            ior: m.optical_density.unwrap_or(DEFAULT_IOR),
        }
    } else {
        Material::Lambert {
            reflectance: Vec3::from(m.diffuse.unwrap_or([DEFAULT_GREY; 3])),
        }
    };
    NamedMaterial {
        name: m.name.clone(),
        material,
    }
}

/// Index of the mesh's material, appending the shared "default" material when it has none.
fn material_index(
    materials: &mut Vec<NamedMaterial>,
    default: &mut Option<usize>,
    id: Option<usize>,
) -> usize {
    if let Some(id) = id.filter(|&id| id < materials.len()) {
        return id;
    }
    *default.get_or_insert_with(|| {
        materials.push(NamedMaterial {
            name: "default".into(),
            material: Material::Lambert {
                reflectance: Vec3::splat(DEFAULT_GREY),
            },
        });
        materials.len() - 1
    })
}

/// Converts one tobj model; `None` when it has no triangle.
fn convert_mesh(path: &Path, model: &tobj::Model) -> Result<Option<Mesh>> {
    let m = &model.mesh;
    let positions: Vec<Vec3> = m
        .positions
        .chunks_exact(3)
        .map(|p| Vec3::new(p[0], p[1], p[2]))
        .collect();
    let triangles: Vec<[u32; 3]> = m
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    if triangles.is_empty() {
        return Ok(None);
    }
    if let Some(&bad) = m.indices.iter().find(|&&i| i as usize >= positions.len()) {
        let msg = format!("object {}: vertex index {bad} out of range", model.name);
        return Err(Error::format(path, msg));
    }
    Ok(Some(Mesh {
        name: model.name.clone(),
        normals: unit_normals(&m.normals, positions.len()),
        positions,
        triangles,
        material: 0,
    }))
}

/// Normalized per-vertex normals, or empty (flat shading) when they are absent, do not
/// match the vertex count, or include a zero vector.
fn unit_normals(flat: &[f32], vertex_count: usize) -> Vec<Vec3> {
    if flat.len() != 3 * vertex_count {
        return Vec::new();
    }
    flat.chunks_exact(3)
        .map(|n| Vec3::new(n[0], n[1], n[2]).try_normalize())
        .collect::<Option<Vec<_>>>()
        .unwrap_or_default()
}
