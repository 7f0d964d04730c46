//! The TOML scene file. Relative paths resolve against the file's folder; unknown keys are
//! errors; every value is checked and a bad one is reported as `file: field: problem`.
use glam::Vec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

use super::assets::AssetCache;
use super::grids::GridFile;
use super::medium::{toml_field, MediumSpec, TransformSpec};
use super::{Camera, Format, Imported, Light, Material, NamedMaterial, Scene};
use crate::core::frames::{self, at_frame};
use crate::error::{Error, Result};
use crate::media::procedural::{self, NoiseParams, Preset, DEFAULT_RESOLUTION};
use crate::media::{GridMedium, MediumDesc};
use crate::settings::{Radius, RenderSettings};
use clap::ValueEnum;
use glam::DAffine3;

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileScene {
    #[serde(default)]
    render: FileRender,
    camera: Option<FileCamera>,
    #[serde(default)]
    material: Vec<FileMaterial>,
    #[serde(default)]
    mesh: Vec<FileMesh>,
    #[serde(default)]
    import: Vec<FileImport>,
    #[serde(default)]
    light: Vec<FileLight>,
    #[serde(default)]
    medium: Vec<FileMedium>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileRender {
    width: Option<u32>,
    height: Option<u32>,
    passes: Option<u32>,
    light_paths: Option<usize>,
    /// The old name of `light_paths` (it counts light paths, not beams).
    beams_per_pass: Option<usize>,
    alpha: Option<f32>,
    photon_alpha: Option<f32>,
    beam_radius: Option<FileRadius>,
    photon_radius: Option<FileRadius>,
    smooth_photon_radius: Option<FileRadius>,
    seed: Option<u64>,
    exposure: Option<f32>,
    tr_samples: Option<usize>,
    transmittance: Option<String>,
    tr_block: Option<usize>,
    free_path: Option<String>,
    method: Option<String>,
    nee_samples: Option<usize>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum FileRadius {
    Value(f32),
    Word(String),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileCamera {
    origin: [f32; 3],
    target: [f32; 3],
    up: Option<[f32; 3]>,
    vfov: f32,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum FileMaterial {
    Lambert {
        name: String,
        reflectance: [f32; 3],
    },
    Dielectric {
        name: String,
        ior: Option<f32>,
    },
    Mirror {
        name: String,
        reflectance: Option<[f32; 3]>,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileMesh {
    path: PathBuf,
    material: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileImport {
    path: PathBuf,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum FileLight {
    Point {
        position: [f32; 3],
        intensity: [f32; 3],
    },
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        intensity: [f32; 3],
        inner_deg: Option<f32>,
        outer_deg: Option<f32>,
    },
    Directional {
        direction: [f32; 3],
        irradiance: [f32; 3],
    },
    Sphere {
        center: [f32; 3],
        radius: f32,
        radiance: [f32; 3],
    },
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum FileMedium {
    Homogeneous {
        bounds: [[f32; 3]; 2],
        sigma_t: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
    },
    Grid {
        path: PathBuf,
        grid: Option<String>,
        density_scale: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
        transform: Option<FileTransform>,
    },
    Noise {
        preset: String,
        bounds: [[f32; 3]; 2],
        seed: Option<u32>,
        octaves: Option<usize>,
        frequency: Option<f64>,
        resolution: Option<u32>,
        density_scale: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
    },
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileTransform {
    translate: Option<[f64; 3]>,
    rotate_deg: Option<[f64; 3]>,
    scale: Option<f64>,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum FilePhase {
    Isotropic,
    Hg { g: f32 },
}

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

/// Checks of one value, each returning the field's error.
struct Check<'a> {
    path: &'a Path,
}

impl Check<'_> {
    fn err(&self, field: &str, msg: String) -> Error {
        Error::field(self.path, field, msg)
    }

    /// One of `T`'s values by its command-line name, or `default` when absent.
    fn word<T: ValueEnum>(&self, field: &str, v: Option<&str>, default: T) -> Result<T> {
        let Some(w) = v else { return Ok(default) };
        T::from_str(w, false).map_err(|_| {
            let names: Vec<String> = T::value_variants()
                .iter()
                .filter_map(|v| v.to_possible_value())
                .map(|p| p.get_name().to_string())
                .collect();
            let (last, rest) = names.split_last().expect("an enum has values");
            let list = if rest.is_empty() {
                last.clone()
            } else {
                format!("{} or {last}", rest.join(", "))
            };
            self.err(field, format!("expected {list}, got \"{w}\""))
        })
    }
    fn finite3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        if v.iter().all(|x| x.is_finite()) {
            Ok(Vec3::from(v))
        } else {
            Err(self.err(field, format!("expected finite numbers, got {v:?}")))
        }
    }
    fn nonneg3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        if v.iter().all(|x| x.is_finite() && *x >= 0.0) {
            Ok(Vec3::from(v))
        } else {
            Err(self.err(field, format!("expected finite numbers >= 0, got {v:?}")))
        }
    }
    fn unit3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        let v = self.finite3(field, v)?;
        if v.length_squared() > 0.0 {
            Ok(v.normalize())
        } else {
            Err(self.err(field, "expected a non-zero direction".into()))
        }
    }
    fn in_range(&self, field: &str, x: f32, lo: f32, hi: f32, what: &str) -> Result<f32> {
        if x.is_finite() && x >= lo && x <= hi {
            Ok(x)
        } else {
            Err(self.err(field, format!("expected {what}, got {x}")))
        }
    }
    fn positive(&self, field: &str, x: f32) -> Result<f32> {
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            Err(self.err(field, format!("expected a finite number > 0, got {x}")))
        }
    }
}

/// 1-based line of a byte offset, for parse errors.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
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
        scene.lights.push(light(&ck, i, l)?);
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

fn render_settings(ck: &Check, r: &FileRender) -> Result<RenderSettings> {
    let d = RenderSettings::default();
    let radius = |field: &str, v: &Option<FileRadius>| -> Result<Radius> {
        match v {
            None => Ok(Radius::Auto),
            Some(FileRadius::Word(w)) if w == "auto" => Ok(Radius::Auto),
            Some(FileRadius::Word(w)) => Err(ck.err(
                field,
                format!("expected \"auto\" or a radius in m, got \"{w}\""),
            )),
            Some(FileRadius::Value(x)) => Ok(Radius::Fixed(ck.positive(field, *x)?)),
        }
    };
    let s = RenderSettings {
        width: r.width.unwrap_or(d.width),
        height: r.height.unwrap_or(d.height),
        passes: r.passes.unwrap_or(d.passes),
        light_paths: r.light_paths.or(r.beams_per_pass).unwrap_or(d.light_paths),
        alpha: r.alpha.unwrap_or(d.alpha),
        photon_alpha: r.photon_alpha.unwrap_or(d.photon_alpha),
        beam_radius: radius("render.beam_radius", &r.beam_radius)?,
        photon_radius: radius("render.photon_radius", &r.photon_radius)?,
        smooth_photon_radius: radius("render.smooth_photon_radius", &r.smooth_photon_radius)?,
        seed: r.seed.unwrap_or(d.seed),
        exposure: r.exposure.unwrap_or(d.exposure),
        tr_samples: r.tr_samples.unwrap_or(d.tr_samples),
        nee_samples: r.nee_samples.unwrap_or(d.nee_samples),
        tr_block: r.tr_block.unwrap_or(d.tr_block),
        tr_mode: ck.word(
            "render.transmittance",
            r.transmittance.as_deref(),
            d.tr_mode,
        )?,
        free_path: ck.word("render.free_path", r.free_path.as_deref(), d.free_path)?,
        method: ck.word("render.method", r.method.as_deref(), d.method)?,
        ..d
    };
    s.validate()
        .map_err(|e| ck.err(&format!("render.{}", e.field), e.msg))?;
    Ok(s)
}

fn material(ck: &Check, i: usize, m: &FileMaterial) -> Result<NamedMaterial> {
    let f = |k: &str| format!("material[{i}].{k}");
    let (name, material) = match m {
        FileMaterial::Lambert { name, reflectance } => {
            let r = ck.nonneg3(&f("reflectance"), *reflectance)?;
            if r.max_element() > 1.0 {
                return Err(ck.err(
                    &f("reflectance"),
                    format!("expected values in [0, 1], got {reflectance:?}"),
                ));
            }
            (name, Material::Lambert { reflectance: r })
        }
        FileMaterial::Dielectric { name, ior } => {
            let ior = ck.positive(&f("ior"), ior.unwrap_or(1.5))?;
            (name, Material::Dielectric { ior })
        }
        FileMaterial::Mirror { name, reflectance } => {
            let r = ck.nonneg3(&f("reflectance"), reflectance.unwrap_or([1.0; 3]))?;
            (
                name,
                Material::Mirror {
                    reflectance: r.min(Vec3::ONE),
                },
            )
        }
    };
    Ok(NamedMaterial {
        name: name.clone(),
        material,
    })
}

fn find_material(ck: &Check, scene: &Scene, i: usize, name: &str) -> Result<usize> {
    scene
        .materials
        .iter()
        .position(|m| m.name == name)
        .ok_or_else(|| {
            let known: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
            ck.err(
                &format!("mesh[{i}].material"),
                format!(
                    "unknown material \"{name}\" (defined: {})",
                    known.join(", ")
                ),
            )
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

fn light(ck: &Check, i: usize, l: &FileLight) -> Result<Light> {
    let f = |k: &str| format!("light[{i}].{k}");
    Ok(match l {
        FileLight::Point {
            position,
            intensity,
        } => Light::Point {
            position: ck.finite3(&f("position"), *position)?,
            intensity: ck.nonneg3(&f("intensity"), *intensity)?,
        },
        FileLight::Spot {
            position,
            direction,
            intensity,
            inner_deg,
            outer_deg,
        } => {
            let outer = ck.in_range(
                &f("outer_deg"),
                outer_deg.unwrap_or(45.0),
                0.01,
                180.0,
                "an angle in (0, 180] degrees",
            )?;
            let inner = ck.in_range(
                &f("inner_deg"),
                inner_deg.unwrap_or(0.0),
                0.0,
                outer,
                "an angle in [0, outer_deg]",
            )?;
            Light::Spot {
                position: ck.finite3(&f("position"), *position)?,
                direction: ck.unit3(&f("direction"), *direction)?,
                intensity: ck.nonneg3(&f("intensity"), *intensity)?,
                inner_deg: inner,
                outer_deg: outer,
            }
        }
        FileLight::Directional {
            direction,
            irradiance,
        } => Light::Directional {
            direction: ck.unit3(&f("direction"), *direction)?,
            irradiance: ck.nonneg3(&f("irradiance"), *irradiance)?,
        },
        FileLight::Sphere {
            center,
            radius,
            radiance,
        } => Light::Sphere {
            center: ck.finite3(&f("center"), *center)?,
            radius: ck.positive(&f("radius"), *radius)?,
            radiance: ck.nonneg3(&f("radiance"), *radiance)?,
        },
    })
}

enum Medium {
    Homogeneous(MediumDesc),
    Grid(GridMedium),
}

fn medium(
    ck: &Check,
    dir: &Path,
    i: usize,
    m: &FileMedium,
    cache: &mut AssetCache,
) -> Result<Medium> {
    let g = |phase: &Option<FilePhase>| match phase {
        None | Some(FilePhase::Isotropic) => None,
        Some(FilePhase::Hg { g }) => Some(*g),
    };
    match m {
        FileMedium::Grid {
            path,
            grid,
            density_scale,
            albedo,
            phase,
            transform,
        } => {
            let spec = MediumSpec {
                density_scale: Some(*density_scale),
                albedo: Some(*albedo),
                g: g(phase),
                transform: transform.as_ref().map(|t| TransformSpec::Srt {
                    translate: t.translate,
                    rotate_deg: t.rotate_deg,
                    scale: t.scale,
                }),
                ..Default::default()
            };
            let name = grid.as_deref().unwrap_or("density");
            grid_medium(ck, i, &dir.join(path), name, spec, cache).map(Medium::Grid)
        }
        FileMedium::Homogeneous {
            bounds,
            sigma_t,
            albedo,
            phase,
        } => {
            let mp = MediumSpec {
                sigma_t: Some(*sigma_t),
                albedo: Some(*albedo),
                g: g(phase),
                ..Default::default()
            }
            .check(ck.path, toml_field(i))?;
            Ok(Medium::Homogeneous(MediumDesc {
                bounds: check_bounds(ck, &format!("medium[{i}].bounds"), bounds)?,
                sigma_t: mp.sigma_t,
                albedo: mp.albedo,
                phase: mp.phase,
            }))
        }
        FileMedium::Noise {
            preset,
            bounds,
            seed,
            octaves,
            frequency,
            resolution,
            density_scale,
            albedo,
            phase,
        } => {
            let params = NoiseParams {
                preset: noise_preset(ck, i, preset)?,
                bounds: check_bounds(ck, &format!("medium[{i}].bounds"), bounds)?,
                seed: seed.unwrap_or(1),
                octaves: octaves.unwrap_or(6),
                frequency: frequency.unwrap_or(2.0),
                resolution: resolution.unwrap_or(DEFAULT_RESOLUTION),
            };
            let spec = MediumSpec {
                density_scale: Some(*density_scale),
                albedo: Some(*albedo),
                g: g(phase),
                ..Default::default()
            };
            noise_medium(ck, i, params, spec, cache).map(Medium::Grid)
        }
    }
}

/// A grid medium from grid `name` of the file at `p` (read once: hashed and parsed from
/// the same bytes).
fn grid_medium(
    ck: &Check,
    i: usize,
    p: &Path,
    name: &str,
    spec: MediumSpec,
    cache: &mut AssetCache,
) -> Result<GridMedium> {
    let mp = spec.check(ck.path, toml_field(i))?;
    Format::of_kind(p, &Format::GRIDS)
        .map_err(|e| ck.err(&format!("medium[{i}].path"), e.to_string()))?;
    let (loaded, mut h) =
        cache.grid_file(p, name, |bytes| GridFile::from_bytes(p, bytes)?.load(name))?;
    let (scale, xf) = (mp.density_scale, mp.transform);
    h.update(format!("{name} {scale} {xf:?}").as_bytes());
    Ok(GridMedium::new(
        loaded,
        xf,
        scale,
        mp.albedo,
        mp.phase,
        format!("{} [{name}]", p.display()),
        *h.finalize().as_bytes(),
    ))
}

fn noise_preset(ck: &Check, i: usize, preset: &str) -> Result<Preset> {
    match preset {
        "cloud" => Ok(Preset::Cloud),
        "smoke" => Ok(Preset::Smoke),
        "fog" => Ok(Preset::Fog),
        other => Err(ck.err(
            &format!("medium[{i}].preset"),
            format!("expected cloud, smoke or fog, got \"{other}\""),
        )),
    }
}

/// A procedural noise medium (its grid built once per parameter set and kept).
fn noise_medium(
    ck: &Check,
    i: usize,
    params: NoiseParams,
    spec: MediumSpec,
    cache: &mut AssetCache,
) -> Result<GridMedium> {
    let f = |k: &str| format!("medium[{i}].{k}");
    if !(1..=12).contains(&params.octaves) {
        return Err(ck.err(
            &f("octaves"),
            format!("expected 1..=12, got {}", params.octaves),
        ));
    }
    if !(params.frequency.is_finite() && params.frequency > 0.0) {
        return Err(ck.err(&f("frequency"), "expected a finite number > 0".into()));
    }
    if !(2..=1024).contains(&params.resolution) {
        return Err(ck.err(
            &f("resolution"),
            format!("expected 2..=1024 voxels, got {}", params.resolution),
        ));
    }
    let mp = spec.check(ck.path, toml_field(i))?;
    let scale = mp.density_scale;
    let hash = blake3::hash(format!("noise {params:?} {scale}").as_bytes());
    let key = format!("noise {params:?}");
    let field_hash = *blake3::hash(key.as_bytes()).as_bytes();
    let grid = cache.grid(&key, field_hash, || Ok(procedural::build(&params)))?;
    Ok(GridMedium::new(
        grid,
        DAffine3::IDENTITY,
        scale,
        mp.albedo,
        mp.phase,
        format!("noise {:?} seed {}", params.preset, params.seed),
        *hash.as_bytes(),
    ))
}

fn check_bounds(ck: &Check, field: &str, bounds: &[[f32; 3]; 2]) -> Result<[Vec3; 2]> {
    let lo = ck.finite3(field, bounds[0])?;
    let hi = ck.finite3(field, bounds[1])?;
    if !lo.cmplt(hi).all() {
        return Err(ck.err(
            field,
            format!("expected min < max on every axis, got {bounds:?}"),
        ));
    }
    Ok([lo, hi])
}

fn camera_from(ck: &Check, c: &FileCamera) -> Result<Camera> {
    let origin = ck.finite3("camera.origin", c.origin)?;
    let target = ck.finite3("camera.target", c.target)?;
    let up = ck.unit3("camera.up", c.up.unwrap_or([0.0, 1.0, 0.0]))?;
    if (target - origin).length_squared() == 0.0 {
        return Err(ck.err("camera.target", "must differ from camera.origin".into()));
    }
    if (target - origin).normalize().cross(up).length_squared() < 1e-8 {
        return Err(ck.err(
            "camera.up",
            "must not be parallel to the view direction".into(),
        ));
    }
    let vfov_deg = ck.in_range(
        "camera.vfov",
        c.vfov,
        0.01,
        179.0,
        "a vertical field of view in (0, 179] degrees",
    )?;
    Ok(Camera {
        origin,
        target,
        up,
        vfov_deg,
    })
}
