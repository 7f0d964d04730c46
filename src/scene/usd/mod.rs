//! USD stage import (.usda, .usdc, .usdz) through the `openusd` crate.
//!
//! The crate composes the stage but applies no schema fallbacks, so every unauthored
//! attribute here takes USD's documented default, and world transforms are composed
//! from the xformOps by this module. What is read:
//!
//! - **Stage**: `metersPerUnit` (USD fallback 0.01) scales positions to metres; a Z-up
//!   stage (`upAxis = "Z"`) is turned Y-up with (x, y, z) -> (x, z, -y).
//! - **Mesh**: points, faceVertexCounts/Indices (polygons fan-triangulated), normals
//!   (`primvars:normals` over `normals`; vertex/varying kept, faceVarying kept only if
//!   every corner of a vertex agrees, else flat), `orientation`, the composed transform.
//! - **Sphere** gprims are tessellated, since a glass ball is the commonest gprim.
//! - **Materials**: UsdPreviewSurface reached via `material:binding` (inherited from
//!   ancestors). Rule: `opacity < 1` -> Dielectric with `inputs:ior` (default 1.5);
//!   else `metallic >= 0.5` -> Mirror tinted by diffuseColor; else Lambert with
//!   `diffuseColor` (default 0.18 grey). Unbound meshes get the 0.18 grey Lambert.
//! - **Lights**: see [`sphere_light`], [`distant_light`] and [`dome_light`] for the unit
//!   rules (a textured DomeLight is left out: maps are not read yet).
//! - **Camera**: the first Camera prim; see [`camera`].
//! - **Volume**: the `field:density` (else first) OpenVDBAsset; see [`volume`].
//!
//! Prims that are invisible (inherited `visibility`) or of `guide`/`proxy` purpose are
//! skipped. Anything else with a prim type is listed in [`Imported::notes`] as ignored.
//! Not read: time samples (default values only), DistantLight `angle` (the sun stays a
//! delta light), the camera's horizontalAperture (the render settings set the aspect),
//! textures feeding UsdPreviewSurface inputs (their fallbacks apply), and volume
//! materials.
use glam::{DAffine3, DMat3, DMat4, DQuat, DVec3, Vec3};
use openusd::{ar, gf, sdf, usd};
use std::collections::HashMap;
use std::f64::consts::PI;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod attributes;
mod geometry;
mod lights;
mod resolver;
mod shading;
mod transforms;
mod volume;

use super::files::Files;
use super::medium::{usd_field, MediumSpec, TransformSpec};
use super::{Camera, EnvMap, Environment, Imported, Light, Material, Mesh, NamedMaterial};
use crate::error::{Error, Result};
use crate::media::GridMedium;
use resolver::ReadOnce;

/// UsdPreviewSurface's fallback diffuseColor.
const DEFAULT_DIFFUSE: f64 = 0.18;
/// A SphereLight smaller than this (metres, after units) renders as a point light.
pub const POINT_LIGHT_RADIUS: f64 = 1e-3;
/// Tessellation of Sphere gprims (longitude segments; latitude is half).
const SPHERE_SEGMENTS: u32 = 48;

/// Loads a USD stage as an [`Imported`] set of world-space meshes, lights, camera and
/// grid media. The `openusd` crate is run under `catch_unwind`, so a file that makes
/// it panic is reported as a format error; a corrupt .usdc whose counts ask the crate
/// for a huge allocation would abort the process (allocation failure is not a panic),
/// so when a [`Probe`] is installed ([`set_probe`]; `ppb` installs one that parses the
/// stage in a child process first) the stage is parsed here only after it succeeded.
pub fn load_usd(path: &Path) -> Result<Imported> {
    read_usd(path, &Files::new())
}

/// Parses a stage (at a frame) before this process does; an error stops the load.
pub type Probe = fn(&Path, Option<u32>) -> Result<()>;

static PROBE: std::sync::OnceLock<Probe> = std::sync::OnceLock::new();

/// Installs the probe every later [`read_usd`] runs first (once per process).
pub fn set_probe(probe: Probe) {
    let _ = PROBE.set(probe);
}

/// [`load_usd`] reading the stage's layers and its volumes' VDBs through `files`: each
/// is read from disk once per load, however often the USD reader opens it.
pub fn read_usd(path: &Path, files: &Files) -> Result<Imported> {
    if let Some(probe) = PROBE.get() {
        probe(path, files.frame())?;
    }
    guarded(path, |path_str| import(path, path_str, files, false))
}

/// Parses the stage's layers and reads every prim as [`read_usd`] does at `frame`,
/// without loading VDB assets: what a probe's child process runs.
pub fn probe_usd(path: &Path, frame: Option<u32>) -> Result<()> {
    let files = Files::new();
    files.set_frame(frame);
    guarded(path, |path_str| {
        import(path, path_str, &files, true).map(|_| ())
    })
}

/// Checks that frame `frame` of a stage composes and that the VDB files it names exist,
/// through the installed [`Probe`] (without one, nothing is checked here: the load will
/// tell).
pub fn check_frame(path: &Path, frame: u32) -> Result<()> {
    match PROBE.get() {
        Some(probe) => probe(path, Some(frame)),
        None => Ok(()),
    }
}

/// Runs the USD reader on `path` with its panics turned into format errors.
fn guarded<T>(path: &Path, f: impl FnOnce(&str) -> Result<T>) -> Result<T> {
    std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let path_str = path
        .to_str()
        .ok_or_else(|| Error::format(path, "the path is not valid UTF-8"))?;
    let run = std::panic::AssertUnwindSafe(|| f(path_str));
    match std::panic::catch_unwind(run) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(Error::format(path, format!("USD reader failed: {msg}")))
        }
    }
}

fn import(path: &Path, path_str: &str, files: &Files, probe: bool) -> Result<Imported> {
    let resolver = ReadOnce {
        inner: ar::DefaultResolver::new(),
        files: files.clone(),
    };
    let stage = usd::Stage::builder()
        .resolver(resolver)
        .open(path_str)
        .map_err(|e| Error::format(path, format!("cannot open USD stage: {e:#}")))?;
    // Instance proxies are walked too, so instanced geometry is not silently lost.
    let mut prims = Vec::new();
    stage
        .traverse(usd::PrimPredicate::DEFAULT_PROXIES, |p| {
            prims.push(p.clone())
        })
        .map_err(|e| Error::format(path, format!("cannot traverse the stage: {e:#}")))?;
    let mut ctx = Ctx {
        stage: &stage,
        files,
        path,
        dir: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
        root: DMat4::IDENTITY,
        world: HashMap::new(),
        materials: HashMap::new(),
        out: Imported::default(),
        probe,
    };
    ctx.root = ctx.stage_root()?;
    for p in &prims {
        ctx.prim(p)?;
    }
    // Prims are indexed lazily, so arcs to missing layers surface only after the walk.
    if let Some(e) = stage.composition_errors().first() {
        // Paths in the message as this frame resolved them.
        let e = files.at_frame(&e.to_string());
        return Err(Error::format(path, format!("composition error: {e}")));
    }
    let mut out = ctx.out;
    let layers = stage.layer_identifiers().into_iter().map(PathBuf::from);
    let layers: Vec<PathBuf> = layers.filter(|l| l.is_file() && l != path).collect();
    out.files.splice(0..0, layers);
    Ok(out)
}

/// Import state: the stage, the stage-to-ppb root correction, caches and the output.
struct Ctx<'a> {
    stage: &'a usd::Stage,
    files: &'a Files,
    path: &'a Path,
    dir: PathBuf,
    /// metersPerUnit scale and up-axis rotation, applied after every world transform.
    root: DMat4,
    world: HashMap<sdf::Path, DMat4>,
    materials: HashMap<String, usize>,
    out: Imported,
    /// Reading prims only: VDB assets are not loaded.
    probe: bool,
}

/// Structural prim types that carry nothing to render by themselves.
fn is_structural(t: &str) -> bool {
    matches!(
        t,
        "" | "Xform"
            | "Scope"
            | "Material"
            | "Shader"
            | "NodeGraph"
            | "OpenVDBAsset"
            | "GeomSubset"
            | "RenderSettings"
            | "RenderProduct"
            | "RenderVar"
    )
}

impl<'a> Ctx<'a> {
    fn err(&self, prim: &sdf::Path, msg: impl std::fmt::Display) -> Error {
        Error::field(self.path, prim.to_string(), msg.to_string())
    }

    fn note(&mut self, s: String) {
        self.out.notes.push(s);
    }

    /// Dispatches one prim on its type name.
    fn prim(&mut self, p: &sdf::Path) -> Result<()> {
        let t = self
            .stage
            .prim(p.clone())
            .type_name()
            .map_err(|e| self.err(p, format!("{e:#}")))?
            .map(|t| t.to_string())
            .unwrap_or_default();
        if !is_structural(&t) && self.hidden(p)? {
            self.note(format!(
                "ignored {t} {p}: invisible, or guide/proxy purpose"
            ));
            return Ok(());
        }
        match t.as_str() {
            "Mesh" => self.mesh(p),
            "Sphere" => self.sphere(p),
            "SphereLight" => self.sphere_light(p),
            "DistantLight" => self.distant_light(p),
            "DomeLight" => self.dome_light(p),
            "Camera" => self.camera(p),
            "Volume" => self.volume(p),
            t if is_structural(t) => Ok(()),
            t => {
                self.note(format!("ignored {t} {p}: unsupported prim type"));
                Ok(())
            }
        }
    }

    /// Whether the prim is not rendered: `visibility = "invisible"` on it or an
    /// ancestor (visibility inherits), or a `guide`/`proxy` purpose (viewport only).
    fn hidden(&self, p: &sdf::Path) -> Result<bool> {
        let purpose = self.token(p, "purpose")?;
        if matches!(purpose.as_deref(), Some("guide" | "proxy")) {
            return Ok(true);
        }
        let mut cur = Some(p.clone());
        while let Some(q) = cur.filter(|q| !q.is_abs_root()) {
            if self.token(&q, "visibility")?.as_deref() == Some("invisible") {
                return Ok(true);
            }
            cur = q.parent();
        }
        Ok(false)
    }

    // ---- attribute access -------------------------------------------------------
}
