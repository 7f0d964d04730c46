//! The TOML scene file. Relative paths resolve against the file's folder; unknown keys are
//! errors; every value is checked and a bad one is reported as `file: field: problem`.
use glam::Vec3;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod check;
mod fields;
mod media;
mod schema;

use super::assets::AssetCache;
use super::grids::GridFile;
use super::medium::{toml_field, MediumSpec, TransformSpec};
use super::sky::Sky;
use super::{Camera, EnvMap, Environment, Format, Imported, Light, Material, NamedMaterial, Scene};
use crate::core::frames::{self, at_frame};
use crate::error::{Error, Result};
use crate::media::procedural::{self, NoiseParams, Preset, DEFAULT_RESOLUTION};
use crate::media::{GridMedium, MediumDesc};
use crate::settings::{BeamKernel, Radius, RenderSettings};
use check::{line_of, Check};
use fields::*;
use glam::DAffine3;
use media::*;
use schema::*;

/// A parsed scene file: settings from `[render]` and the assembled scene.
pub struct SceneFile {
    pub path: PathBuf,
    pub settings: RenderSettings,
    pub scene: Scene,
    /// Every file the scene read (the scene file first), for watching and cache keys.
    pub sources: Vec<PathBuf>,
    /// What imported files (USD stages) took and left out, one line per prim.
    pub notes: Vec<String>,
    /// Deprecated keys and the like: one line each, for the command line to print.
    pub warnings: Vec<String>,
}

/// Loads a scene file; a USD stage (.usd, .usda, .usdc, .usdz) is loaded as a scene of
/// its own, see [`load_usd_scene`].
pub fn load(path: &Path) -> Result<SceneFile> {
    load_cached(path, &mut AssetCache::new())
}

/// [`load`], reusing the imports and grids of earlier loads through `cache` when their
/// files are unchanged (`ppb watch`); `cache.loaded()` then lists what was read anew.
///
/// Every file is read from disk at most once per load (`cache.files_read()` lists them).
pub fn load_cached(path: &Path, cache: &mut AssetCache) -> Result<SceneFile> {
    load_with(path, cache, None)
}

/// Frame `frame` of a scene: the frame token (a run of `#`, see [`crate::core::frames`])
/// in the scene's path and in the paths it names (imports, meshes, grid media) becomes
/// the frame number. Without a frame, paths are taken as written.
pub fn load_frame(path: &Path, frame: Option<u32>) -> Result<SceneFile> {
    let path = at_frame(path, frame);
    load_with(&path, &mut AssetCache::new(), frame)
}

/// Checks, before any work starts, that every file a frame's paths name exists for every
/// frame in `frames`; the error names the frame, the field and the missing file.
pub fn check_frames(path: &Path, frames: &[u32]) -> Result<()> {
    for &f in frames {
        let scene = at_frame(path, Some(f));
        if !scene.is_file() {
            return Err(Error::Other(format!(
                "frame {f}: scene file {} does not exist",
                scene.display()
            )));
        }
        let frame_err = |e: Error| Error::Other(format!("frame {f}: {e}"));
        if Format::of_scene(&scene)? == Format::Usd {
            super::usd::check_frame(&scene, f).map_err(frame_err)?;
            continue;
        }
        let text = std::fs::read_to_string(&scene).map_err(|e| Error::io(&scene, e))?;
        let file = parse_file(&scene, &text)?;
        let dir = scene.parent().unwrap_or(Path::new("."));
        for (field, p) in file.paths() {
            let p = dir.join(at_frame(p, Some(f)));
            if !p.exists() {
                return Err(Error::field(
                    &scene,
                    field,
                    format!("frame {f}: {} does not exist", p.display()),
                ));
            }
            if Format::detect(&p) == Some(Format::Usd) {
                super::usd::check_frame(&p, f).map_err(frame_err)?;
            }
        }
    }
    Ok(())
}

impl FileScene {
    /// Every path the file names, with its field.
    fn paths(&self) -> Vec<(String, &Path)> {
        let imports = self.import.iter().enumerate();
        let meshes = self.mesh.iter().enumerate();
        let media = self.medium.iter().enumerate().filter_map(|(i, m)| match m {
            FileMedium::Grid { path, .. } => Some((format!("medium[{i}].path"), path.as_path())),
            _ => None,
        });
        imports
            .map(|(i, m)| (format!("import[{i}].path"), m.path.as_path()))
            .chain(meshes.map(|(i, m)| (format!("mesh[{i}].path"), m.path.as_path())))
            .chain(media)
            .collect()
    }

    /// Without a frame: a path with the frame token that names no file is a sequence.
    fn check_no_sequence(&self, scene: &Path) -> Result<()> {
        let dir = scene.parent().unwrap_or(Path::new("."));
        for (field, p) in self.paths() {
            if frames::has_token(&p.to_string_lossy()) && !dir.join(p).exists() {
                return Err(Error::field(
                    scene,
                    field,
                    format!(
                        "{} names a frame sequence (# is the frame number): render it with --frames",
                        p.display()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The file with the frame token in its paths replaced by `frame`.
    fn at_frame(mut self, frame: Option<u32>) -> Self {
        for m in &mut self.import {
            m.path = at_frame(&m.path, frame);
        }
        for m in &mut self.mesh {
            m.path = at_frame(&m.path, frame);
        }
        for m in &mut self.medium {
            if let FileMedium::Grid { path, .. } = m {
                *path = at_frame(path, frame);
            }
        }
        self
    }
}

fn load_with(path: &Path, cache: &mut AssetCache, frame: Option<u32>) -> Result<SceneFile> {
    cache.begin();
    cache.files().set_frame(frame);
    let file = (|| match Format::of_scene(path)? {
        Format::Usd => load_usd_scene_cached(path, cache),
        _ => {
            let text = cache.files().read_string(path)?;
            let file = parse_file(path, &text)?;
            if frame.is_none() {
                file.check_no_sequence(path)?;
            }
            build(path, file.at_frame(frame), cache)
        }
    })();
    match file {
        Ok(_) => cache.prune(),
        Err(_) => cache.abandon(),
    }
    file
}

/// `ppb render shot.usda`: the stage becomes the one `[[import]]` of a scene with
/// default render settings and the stage's camera, unless a sidecar `shot.ppb.toml`
/// sits next to it; then the sidecar is read as a normal scene file (settings, extra
/// lights, media, a camera that overrides the stage's) and the stage is added to its
/// imports.
pub fn load_usd_scene(path: &Path) -> Result<SceneFile> {
    load_usd_scene_cached(path, &mut AssetCache::new())
}

fn load_usd_scene_cached(path: &Path, cache: &mut AssetCache) -> Result<SceneFile> {
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let sidecar = path.with_file_name(format!("{stem}.ppb.toml"));
    let mut file = if sidecar.is_file() {
        let text = cache.files().read_string(&sidecar)?;
        parse_file(&sidecar, &text)?
    } else {
        FileScene::default()
    };
    let name = path.file_name().unwrap_or_default();
    file.import.push(FileImport { path: name.into() });
    let mut scene = build(path, file, cache)?;
    if sidecar.is_file() {
        scene.sources.push(sidecar);
    }
    Ok(scene)
}

/// Parses scene text as if it were the file at `path` (its folder resolves relative paths).
pub fn parse(path: &Path, text: &str) -> Result<SceneFile> {
    build(path, parse_file(path, text)?, &mut AssetCache::new())
}

fn parse_file(path: &Path, text: &str) -> Result<FileScene> {
    ::toml::from_str(text).map_err(|e| {
        let line = e.span().map(|s| line_of(text, s.start));
        let msg = e.message().replace('\n', " ");
        match line {
            Some(l) => Error::format(path, format!("line {l}: {msg}")),
            None => Error::format(path, msg),
        }
    })
}

/// Assembles a parsed scene file; `path` is the file it came from.
fn build(path: &Path, file: FileScene, cache: &mut AssetCache) -> Result<SceneFile> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let ck = Check { path };
    let settings = render_settings(&ck, &file.render)?;
    let mut warnings = Vec::new();
    if file.render.beams_per_pass.is_some() {
        warnings.push(format!(
            "{}: render.beams_per_pass is deprecated, use render.light_paths (it counts light paths)",
            path.display()
        ));
    }
    let mut scene = Scene::default();
    let mut sources = vec![path.to_path_buf()];
    for (i, m) in file.material.iter().enumerate() {
        scene.materials.push(material(&ck, i, m)?);
    }
    let mut camera = None;
    let mut notes = Vec::new();
    for (i, imp) in file.import.iter().enumerate() {
        let p = dir.join(&imp.path);
        let mut imported = load_asset(&p, &format!("import[{i}].path"), path, cache)?;
        notes.append(&mut imported.notes);
        sources.push(p);
        sources.append(&mut imported.files);
        camera = camera.or(imported.camera);
        merge(&mut scene, imported, None);
    }
    for (i, m) in file.mesh.iter().enumerate() {
        let p = dir.join(&m.path);
        let mut imported = load_asset(&p, &format!("mesh[{i}].path"), path, cache)?;
        notes.append(&mut imported.notes);
        sources.push(p);
        sources.append(&mut imported.files);
        let over = match &m.material {
            Some(name) => Some(find_material(&ck, &scene, i, name)?),
            None => None,
        };
        merge(&mut scene, imported, over);
    }
    for (i, l) in file.light.iter().enumerate() {
        let mut light = light(&ck, i, l)?;
        if let (FileLight::Environment { map: Some(m), .. }, Light::Environment(env)) =
            (l, &mut light)
        {
            let p = dir.join(m);
            env.map = Some(environment_map(&ck, i, &p, cache)?);
            sources.push(p);
        }
        scene.lights.push(light);
    }
    for (i, m) in file.medium.iter().enumerate() {
        if let FileMedium::Grid { path: p, .. } = m {
            sources.push(dir.join(p));
        }
        match medium(&ck, dir, i, m, cache)? {
            Medium::Homogeneous(h) => scene.media.push(h),
            Medium::Grid(g) => scene.grid_media.push(g),
        }
    }
    scene.camera = match (&file.camera, camera) {
        (Some(c), _) => camera_from(&ck, c)?,
        (None, Some(c)) => c,
        (None, None) => {
            return Err(Error::field(
                path,
                "camera",
                "no [camera] table and no camera in an imported glTF or USD stage",
            ))
        }
    };
    if scene.lights.is_empty() {
        return Err(Error::field(path, "light", "the scene has no light"));
    }
    Ok(SceneFile {
        path: path.to_path_buf(),
        settings,
        scene,
        sources,
        notes,
        warnings,
    })
}

fn load_asset(
    p: &Path,
    field: &str,
    scene_path: &Path,
    cache: &mut AssetCache,
) -> Result<Imported> {
    let format = Format::of_kind(p, &Format::IMPORTS)
        .map_err(|e| Error::field(scene_path, field, e.to_string()))?;
    let imported = match format {
        Format::Obj => cache.import(p, |files| super::obj::read_obj(p, files))?,
        Format::Gltf => cache.import(p, |files| super::gltf::read_gltf(p, files))?,
        _ => cache.import(p, |files| super::usd::read_usd(p, files))?,
    };
    if imported.meshes.iter().all(|m| m.triangles.is_empty())
        && imported.lights.is_empty()
        && imported.grid_media.is_empty()
    {
        return Err(Error::format(p, "the file holds no triangles"));
    }
    Ok(imported)
}

/// Appends an imported file's materials, meshes, lights and grid media to the scene;
/// `over` replaces every mesh's material.
fn merge(scene: &mut Scene, imported: Imported, over: Option<usize>) {
    let base = scene.materials.len();
    if over.is_none() {
        scene.materials.extend(imported.materials);
    }
    for mut m in imported.meshes {
        m.material = over.unwrap_or(base + m.material);
        scene.meshes.push(m);
    }
    scene.lights.extend(imported.lights);
    scene.grid_media.extend(imported.grid_media);
}
