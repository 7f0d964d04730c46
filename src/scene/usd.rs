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
//! - **Lights**: see [`sphere_light`] and [`distant_light`] for the unit rules.
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

use super::files::Files;
use super::medium::{usd_field, MediumSpec, TransformSpec};
use super::{Camera, Imported, Light, Material, Mesh, NamedMaterial};
use crate::error::{Error, Result};
use crate::media::GridMedium;

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

    /// The composed default value of `prim.name`, or None when unauthored or blocked.
    fn value(&self, p: &sdf::Path, name: &str) -> Result<Option<sdf::Value>> {
        let v = self
            .stage
            .prim(p.clone())
            .attribute(name)
            .get::<sdf::Value>()
            .map_err(|e| self.err(p, format!("{name}: {e:#}")))?;
        Ok(v.filter(|v| !matches!(v, sdf::Value::ValueBlock | sdf::Value::None)))
    }

    /// The first authored of `names` (UsdLux renamed `intensity` to `inputs:intensity`).
    fn value_any(&self, p: &sdf::Path, names: &[&str]) -> Result<Option<sdf::Value>> {
        for n in names {
            if let Some(v) = self.value(p, n)? {
                return Ok(Some(v));
            }
        }
        Ok(None)
    }

    /// The value of `prim.name` as a number, unchecked (None when unauthored).
    fn f64_opt(&self, p: &sdf::Path, name: &str) -> Result<Option<f64>> {
        self.value(p, name)?
            .map(|v| v.cast::<f64>())
            .transpose()
            .map_err(|e| self.err(p, format!("{name}: {e}")))
    }

    /// The value of `prim.name` as a triple, unchecked (None when unauthored).
    fn vec3_opt(&self, p: &sdf::Path, name: &str) -> Result<Option<[f64; 3]>> {
        self.value(p, name)?
            .map(|v| v.cast::<[f64; 3]>())
            .transpose()
            .map_err(|e| self.err(p, format!("{name}: {e}")))
    }

    fn f64_or(&self, p: &sdf::Path, names: &[&str], default: f64) -> Result<f64> {
        match self.value_any(p, names)? {
            None => Ok(default),
            Some(v) => {
                let x = v
                    .cast::<f64>()
                    .map_err(|e| self.err(p, format!("{}: {e}", names[0])))?;
                if x.is_finite() {
                    Ok(x)
                } else {
                    Err(self.err(p, format!("{}: not finite", names[0])))
                }
            }
        }
    }

    fn bool_or(&self, p: &sdf::Path, name: &str, default: bool) -> Result<bool> {
        match self.value(p, name)? {
            None => Ok(default),
            Some(sdf::Value::Bool(b)) => Ok(b),
            Some(v) => v
                .cast::<f64>()
                .map(|x| x != 0.0)
                .map_err(|e| self.err(p, format!("{name}: {e}"))),
        }
    }

    fn vec3_or(&self, p: &sdf::Path, names: &[&str], default: DVec3) -> Result<DVec3> {
        match self.value_any(p, names)? {
            None => Ok(default),
            Some(v) => {
                let a = v
                    .cast::<[f64; 3]>()
                    .map_err(|e| self.err(p, format!("{}: {e}", names[0])))?;
                let d = DVec3::from(a);
                if d.is_finite() {
                    Ok(d)
                } else {
                    Err(self.err(p, format!("{}: not finite", names[0])))
                }
            }
        }
    }

    fn token(&self, p: &sdf::Path, name: &str) -> Result<Option<String>> {
        match self.value(p, name)? {
            None => Ok(None),
            Some(v) => v
                .cast::<String>()
                .map(Some)
                .map_err(|e| self.err(p, format!("{name}: {e}"))),
        }
    }

    fn points(&self, p: &sdf::Path, name: &str) -> Result<Option<Vec<DVec3>>> {
        match self.value(p, name)? {
            None => Ok(None),
            Some(v) => {
                let pts = v
                    .cast::<Vec<gf::Vec3f>>()
                    .map_err(|e| self.err(p, format!("{name}: {e}")))?;
                let pts: Vec<DVec3> = pts
                    .iter()
                    .map(|q| DVec3::new(q.x as f64, q.y as f64, q.z as f64))
                    .collect();
                if pts.iter().all(|q| q.is_finite()) {
                    Ok(Some(pts))
                } else {
                    Err(self.err(p, format!("{name}: a value is not finite")))
                }
            }
        }
    }

    fn ints(&self, p: &sdf::Path, name: &str) -> Result<Option<Vec<i64>>> {
        Ok(match self.value(p, name)? {
            None => None,
            Some(sdf::Value::IntVec(v)) => Some(v.into_iter().map(i64::from).collect()),
            Some(sdf::Value::Int64Vec(v)) => Some(v),
            Some(sdf::Value::UintVec(v)) => Some(v.into_iter().map(i64::from).collect()),
            Some(v) => {
                let kind: &'static str = (&v).into();
                return Err(self.err(p, format!("{name}: expected an int array, got {kind}")));
            }
        })
    }

    fn targets(&self, p: &sdf::Path, rel: &str) -> Result<Vec<sdf::Path>> {
        self.stage
            .prim(p.clone())
            .relationship(rel)
            .targets()
            .map_err(|e| self.err(p, format!("{rel}: {e:#}")))
    }

    // ---- transforms -------------------------------------------------------------

    /// metersPerUnit (USD fallback 0.01) and upAxis (fallback Y) as one matrix.
    fn stage_root(&self) -> Result<DMat4> {
        let meta = |k: &str| {
            self.stage
                .stage_metadata(k)
                .map_err(|e| Error::format(self.path, format!("{k}: {e:#}")))
        };
        let mpu = match meta("metersPerUnit")? {
            None => 0.01,
            Some(v) => v
                .cast::<f64>()
                .map_err(|e| Error::field(self.path, "metersPerUnit", e.to_string()))?,
        };
        if !(mpu.is_finite() && mpu > 0.0) {
            return Err(Error::field(self.path, "metersPerUnit", "expected > 0"));
        }
        let up = match meta("upAxis")? {
            None => "Y".to_string(),
            Some(v) => v
                .cast::<String>()
                .map_err(|e| Error::field(self.path, "upAxis", e.to_string()))?,
        };
        Ok(DMat4::from_scale(DVec3::splat(mpu)) * up_axis_rotation(self.path, &up)?)
    }

    /// The prim's local-to-world transform in ppb space (root correction included).
    fn world(&mut self, p: &sdf::Path) -> Result<DMat4> {
        Ok(self.root * self.stage_world(p)?)
    }

    /// Local-to-world in stage units, composing the parent chain (cached).
    fn stage_world(&mut self, p: &sdf::Path) -> Result<DMat4> {
        if p.is_abs_root() || p.is_empty() {
            return Ok(DMat4::IDENTITY);
        }
        if let Some(m) = self.world.get(p) {
            return Ok(*m);
        }
        let (local, reset) = self.local(p)?;
        let m = match p.parent() {
            Some(parent) if !reset => self.stage_world(&parent)? * local,
            _ => local,
        };
        self.world.insert(p.clone(), m);
        Ok(m)
    }

    /// The prim's xformOps in xformOpOrder (column-vector form: the first op is
    /// outermost), and whether `!resetXformStack!` cuts the parent chain.
    fn local(&self, p: &sdf::Path) -> Result<(DMat4, bool)> {
        let order = match self.value(p, "xformOpOrder")? {
            None => return Ok((DMat4::IDENTITY, false)),
            Some(v) => v
                .cast::<Vec<String>>()
                .map_err(|e| self.err(p, format!("xformOpOrder: {e}")))?,
        };
        let mut m = DMat4::IDENTITY;
        let mut reset = false;
        for op in &order {
            if op == "!resetXformStack!" {
                m = DMat4::IDENTITY;
                reset = true;
                continue;
            }
            let (name, invert) = match op.strip_prefix("!invert!") {
                Some(n) => (n, true),
                None => (op.as_str(), false),
            };
            let mut x = self.op(p, name)?;
            if invert {
                x = x.inverse();
            }
            m *= x;
        }
        if !m.is_finite() {
            return Err(self.err(p, "the composed transform is not finite"));
        }
        Ok((m, reset))
    }

    /// One xformOp (`xformOp:KIND[:suffix]`) as a matrix.
    fn op(&self, p: &sdf::Path, name: &str) -> Result<DMat4> {
        let kind = name.split(':').nth(1).unwrap_or("");
        let v = self
            .value(p, name)?
            .ok_or_else(|| self.err(p, format!("{name} is in xformOpOrder but has no value")))?;
        let bad = |e: &dyn std::fmt::Display| self.err(p, format!("{name}: {e}"));
        let v3 = |v: sdf::Value| v.cast::<[f64; 3]>().map(DVec3::from).map_err(|e| bad(&e));
        let s = |v: sdf::Value| v.cast::<f64>().map_err(|e| bad(&e));
        Ok(match kind {
            "translate" => DMat4::from_translation(v3(v)?),
            "scale" => DMat4::from_scale(v3(v)?),
            "rotateX" => DMat4::from_rotation_x(s(v)?.to_radians()),
            "rotateY" => DMat4::from_rotation_y(s(v)?.to_radians()),
            "rotateZ" => DMat4::from_rotation_z(s(v)?.to_radians()),
            "orient" => DMat4::from_quat(quat(v).ok_or_else(|| bad(&"expected a quaternion"))?),
            "transform" => match v {
                sdf::Value::Matrix4d(m) => row_matrix(&m),
                _ => return Err(bad(&"expected a matrix4d")),
            },
            k if k.len() == 9 && k.starts_with("rotate") => {
                rotate3(&k[6..], v3(v)?).ok_or_else(|| bad(&"unknown rotation order"))?
            }
            _ => return Err(bad(&"unsupported xformOp type")),
        })
    }

    // ---- geometry -----------------------------------------------------------------

    fn mesh(&mut self, p: &sdf::Path) -> Result<()> {
        let Some(points) = self.points(p, "points")? else {
            self.note(format!("ignored Mesh {p}: no points"));
            return Ok(());
        };
        let counts = self.ints(p, "faceVertexCounts")?.unwrap_or_default();
        let indices = self.ints(p, "faceVertexIndices")?.unwrap_or_default();
        let mut tris = triangulate(&counts, &indices, points.len()).map_err(|m| self.err(p, m))?;
        let normals = self.mesh_normals(p, &points, &indices)?;
        let xf = self.world(p)?;
        let left = self.token(p, "orientation")?.as_deref() == Some("leftHanded");
        if left != (xf.determinant() < 0.0) {
            tris.iter_mut().for_each(|t| t.swap(1, 2));
        }
        let n = tris.len();
        self.push_mesh(p, xf, &points, normals, tris)?;
        self.note(format!("imported Mesh {p} ({n} triangles)"));
        Ok(())
    }

    /// Per-vertex normals in local space, or empty when none can be kept.
    fn mesh_normals(&self, p: &sdf::Path, points: &[DVec3], indices: &[i64]) -> Result<Vec<DVec3>> {
        let (name, vals) = match self.points(p, "primvars:normals")? {
            Some(v) => ("primvars:normals", v),
            None => match self.points(p, "normals")? {
                Some(v) => ("normals", v),
                None => return Ok(Vec::new()),
            },
        };
        let vals = match self.ints(p, &format!("{name}:indices"))? {
            Some(ix) => ix
                .iter()
                .map(|&i| usize::try_from(i).ok().and_then(|i| vals.get(i).copied()))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| self.err(p, format!("{name}:indices out of range")))?,
            None => vals,
        };
        let interp = self
            .stage
            .prim(p.clone())
            .attribute(name)
            .get_metadata::<sdf::Value>("interpolation")
            .ok()
            .flatten()
            .and_then(|v| v.cast::<String>().ok())
            .unwrap_or_else(|| "vertex".into());
        Ok(match interp.as_str() {
            "vertex" | "varying" if vals.len() == points.len() => vals,
            "faceVarying" if vals.len() == indices.len() => {
                face_varying_to_vertex(&vals, indices, points.len()).unwrap_or_default()
            }
            _ => Vec::new(),
        })
    }

    /// Transforms a local mesh to world space and appends it with its bound material.
    fn push_mesh(
        &mut self,
        p: &sdf::Path,
        xf: DMat4,
        points: &[DVec3],
        normals: Vec<DVec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<()> {
        let nm = DMat3::from_mat4(xf).inverse().transpose();
        let material = self.bound_material(p)?;
        self.out.meshes.push(Mesh {
            name: p.to_string(),
            positions: points
                .iter()
                .map(|&q| xf.transform_point3(q).as_vec3())
                .collect(),
            normals: normals
                .iter()
                .map(|&n| (nm * n).normalize_or_zero().as_vec3())
                .collect(),
            triangles,
            material,
        });
        Ok(())
    }

    /// Sphere gprim (radius fallback 1), tessellated as a UV sphere.
    fn sphere(&mut self, p: &sdf::Path) -> Result<()> {
        let r = self.f64_or(p, &["radius"], 1.0)?;
        if r <= 0.0 {
            self.note(format!("ignored Sphere {p}: radius {r} <= 0"));
            return Ok(());
        }
        let (points, normals, tris) = uv_sphere(r, SPHERE_SEGMENTS);
        let xf = self.world(p)?;
        let n = tris.len();
        let mut tris = tris;
        if xf.determinant() < 0.0 {
            tris.iter_mut().for_each(|t| t.swap(1, 2));
        }
        self.push_mesh(p, xf, &points, normals, tris)?;
        self.note(format!("imported Sphere {p} (tessellated, {n} triangles)"));
        Ok(())
    }

    // ---- materials ----------------------------------------------------------------

    /// Index of the material bound to the prim or its nearest bound ancestor.
    fn bound_material(&mut self, p: &sdf::Path) -> Result<usize> {
        let mut cur = Some(p.clone());
        while let Some(q) = cur {
            if q.is_abs_root() {
                break;
            }
            if let Some(t) = self.targets(&q, "material:binding")?.into_iter().next() {
                return self.material(&t);
            }
            cur = q.parent();
        }
        self.material_default()
    }

    fn material_default(&mut self) -> Result<usize> {
        let m = Material::Lambert {
            reflectance: Vec3::splat(DEFAULT_DIFFUSE as f32),
        };
        Ok(self.add_material("usd:default".into(), m))
    }

    fn add_material(&mut self, name: String, material: Material) -> usize {
        if let Some(&i) = self.materials.get(&name) {
            return i;
        }
        let i = self.out.materials.len();
        self.out.materials.push(NamedMaterial {
            name: name.clone(),
            material,
        });
        self.materials.insert(name, i);
        i
    }

    /// Converts a Material prim's UsdPreviewSurface (see the module doc for the rule).
    fn material(&mut self, m: &sdf::Path) -> Result<usize> {
        let key = m.to_string();
        if let Some(&i) = self.materials.get(&key) {
            return Ok(i);
        }
        let Some(shader) = self.surface_shader(m)? else {
            self.note(format!(
                "ignored Material {m}: no UsdPreviewSurface; using grey Lambert"
            ));
            return self.material_default();
        };
        let s = &shader;
        let diffuse = self.vec3_or(s, &["inputs:diffuseColor"], DVec3::splat(DEFAULT_DIFFUSE))?;
        let opacity = self.f64_or(s, &["inputs:opacity"], 1.0)?;
        let ior = self.f64_or(s, &["inputs:ior"], 1.5)?;
        let metallic = self.f64_or(s, &["inputs:metallic"], 0.0)?;
        let tint = diffuse.clamp(DVec3::ZERO, DVec3::ONE).as_vec3();
        let material = if opacity < 1.0 {
            let ior = if ior > 0.0 { ior } else { 1.5 };
            Material::Dielectric { ior: ior as f32 }
        } else if metallic >= 0.5 {
            Material::Mirror { reflectance: tint }
        } else {
            Material::Lambert { reflectance: tint }
        };
        Ok(self.add_material(key, material))
    }

    /// The UsdPreviewSurface shader feeding `outputs:surface`, if any.
    fn surface_shader(&self, m: &sdf::Path) -> Result<Option<sdf::Path>> {
        let conns = self
            .stage
            .prim(m.clone())
            .attribute("outputs:surface")
            .connections()
            .map_err(|e| self.err(m, format!("outputs:surface: {e:#}")))?;
        let Some(src) = conns.first() else {
            return Ok(None);
        };
        let shader = src.prim_path();
        let id = self.token(&shader, "info:id")?;
        Ok((id.as_deref() == Some("UsdPreviewSurface")).then_some(shader))
    }

    // ---- lights and camera --------------------------------------------------------

    /// `intensity * 2^exposure * color`, UsdLux's radiance (nits, read as W/(m^2 sr)).
    fn lux_radiance(&self, p: &sdf::Path) -> Result<DVec3> {
        let i = self.f64_or(p, &["inputs:intensity", "intensity"], 1.0)?;
        let e = self.f64_or(p, &["inputs:exposure", "exposure"], 0.0)?;
        let c = self.vec3_or(p, &["inputs:color", "color"], DVec3::ONE)?;
        Ok(c * i * 2f64.powf(e))
    }

    /// SphereLight (radius fallback 0.5). Radiance `L` = [`Self::lux_radiance`], divided
    /// by the area 4 pi r^2 when `normalize` is on. World radius r = radius * the
    /// transform's mean scale, in metres.
    ///
    /// - `treatAsPoint` or r < [`POINT_LIGHT_RADIUS`]: `Light::Point` with the radiant
    ///   intensity the sphere would have, `L * pi * r^2` W/sr (for r = 0 exactly,
    ///   where that is zero, the intensity is read directly as W/sr).
    /// - otherwise `Light::Sphere` with radiance `L`.
    fn sphere_light(&mut self, p: &sdf::Path) -> Result<()> {
        let mut l = self.lux_radiance(p)?;
        let r0 = self.f64_or(p, &["inputs:radius", "radius"], 0.5)?.max(0.0);
        let point = self.bool_or(p, "treatAsPoint", false)?;
        let normalize = self.bool_or(p, "inputs:normalize", false)?;
        let xf = self.world(p)?;
        let r = r0 * xf.determinant().abs().cbrt();
        if normalize && r > 0.0 {
            l /= 4.0 * PI * r * r;
        }
        let center = xf.transform_point3(DVec3::ZERO).as_vec3();
        let light = if point || r < POINT_LIGHT_RADIUS {
            let i = if r > 0.0 { l * PI * r * r } else { l };
            Light::Point {
                position: center,
                intensity: i.as_vec3(),
            }
        } else {
            Light::Sphere {
                center,
                radius: r as f32,
                radiance: l.as_vec3(),
            }
        };
        self.out.lights.push(light);
        self.note(format!("imported SphereLight {p} as {light:?}"));
        Ok(())
    }

    /// DistantLight: shines along the prim's world -Z. Its `intensity * 2^exposure *
    /// color` is taken as the irradiance (W/m^2) on a plane facing the light, i.e. as
    /// if `normalize` were on: the literal radiance over a 0.53 degree sun would give
    /// almost no light, and renderers (Karma, Cycles, RenderMan) normalize sun lights.
    fn distant_light(&mut self, p: &sdf::Path) -> Result<()> {
        let e = self.lux_radiance(p)?;
        let xf = self.world(p)?;
        let d = xf.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
        if d == DVec3::ZERO {
            return Err(self.err(p, "the transform collapses the light direction"));
        }
        let light = Light::Directional {
            direction: d.as_vec3(),
            irradiance: e.as_vec3(),
        };
        self.out.lights.push(light);
        self.note(format!("imported DistantLight {p} as {light:?}"));
        Ok(())
    }

    /// Camera: vfov = 2 atan(verticalAperture / (2 focalLength)) (fallbacks 15.2908 and
    /// 50, both in tenths of a scene unit, so their ratio is unit-free); looks down the
    /// prim's world -Z with world +Y up. Only the first camera is used.
    fn camera(&mut self, p: &sdf::Path) -> Result<()> {
        if self.out.camera.is_some() {
            self.note(format!("ignored Camera {p}: only the first camera is used"));
            return Ok(());
        }
        let fl = self.f64_or(p, &["focalLength"], 50.0)?;
        let va = self.f64_or(p, &["verticalAperture"], 15.2908)?;
        if fl <= 0.0 || va <= 0.0 {
            return Err(self.err(p, "focalLength and verticalAperture must be > 0"));
        }
        if let Some(proj) = self.token(p, "projection")? {
            if proj != "perspective" {
                self.note(format!(
                    "camera {p}: projection {proj} rendered as perspective"
                ));
            }
        }
        let xf = self.world(p)?;
        let origin = xf.transform_point3(DVec3::ZERO);
        let fwd = xf.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
        let up = xf.transform_vector3(DVec3::Y).normalize_or_zero();
        if fwd == DVec3::ZERO || up == DVec3::ZERO {
            return Err(self.err(p, "the camera transform is degenerate"));
        }
        let vfov = 2.0 * (va / (2.0 * fl)).atan();
        let cam = Camera {
            origin: origin.as_vec3(),
            target: (origin + fwd).as_vec3(),
            up: up.as_vec3(),
            vfov_deg: vfov.to_degrees() as f32,
        };
        self.out.camera = Some(cam);
        self.note(format!(
            "imported Camera {p} (vfov {:.3} deg)",
            cam.vfov_deg
        ));
        Ok(())
    }

    // ---- volumes ------------------------------------------------------------------

    /// Volume -> grid medium. The `field:density` relationship (else the first `field:*`)
    /// must name an OpenVDBAsset; its `filePath` resolves against the stage file's
    /// folder and `fieldName` (fallback: the field's relationship name) picks the grid.
    /// The grid's own index-to-world map is followed by the Volume prim's world
    /// transform. Medium parameters come from custom attributes on the Volume prim,
    /// `ppb:densityScale` (1), `ppb:albedo` (0.9 grey) and `ppb:g` (0), checked by
    /// [`MediumSpec::check`] as a TOML medium's are; a volume material is not read;
    /// extra media can come from a `<stem>.ppb.toml` sidecar. Grid values times
    /// `ppb:densityScale` are extinction in 1/m whatever metersPerUnit is. A missing or
    /// unreadable .vdb is an error naming the prim. The VDB is read once (through
    /// [`Files`]) for both the grid and the octree cache key.
    fn volume(&mut self, p: &sdf::Path) -> Result<()> {
        let Some((rel, field)) = self.volume_field(p)? else {
            self.note(format!("ignored Volume {p}: no field:* relationship"));
            return Ok(());
        };
        let ft = self.stage.prim(field.clone()).type_name().ok().flatten();
        if ft.as_ref().map(|t| t.to_string()).as_deref() != Some("OpenVDBAsset") {
            self.note(format!(
                "ignored Volume {p}: field {field} is not an OpenVDBAsset"
            ));
            return Ok(());
        }
        let file = self.asset_path(&field, "filePath")?;
        let name = self.token(&field, "fieldName")?.filter(|s| !s.is_empty());
        let name = name.unwrap_or(rel);
        let spec = MediumSpec {
            density_scale: self.f64_opt(p, "ppb:densityScale")?.map(|x| x as f32),
            albedo: self.vec3_opt(p, "ppb:albedo")?.map(|a| a.map(|x| x as f32)),
            g: self.f64_opt(p, "ppb:g")?.map(|x| x as f32),
            transform: Some(TransformSpec::Matrix(DAffine3::from_mat4(self.world(p)?))),
            ..Default::default()
        };
        let mp = spec.check(self.path, usd_field(p))?;
        if self.probe {
            if !file.is_file() {
                return Err(self.err(&field, format!("{} does not exist", file.display())));
            }
            return Ok(());
        }
        // An OpenVDBAsset is OpenVDB by its schema, whatever the file's extension.
        let cannot = |e: Error| self.err(&field, format!("cannot load the VDB: {e}"));
        let bytes = self.files.read(&file).map_err(cannot)?;
        let grid = crate::media::openvdb::load_grid_from(&file, &bytes, &name).map_err(cannot)?;
        let mut h = self.files.hasher(&file)?;
        let (scale, xf) = (mp.density_scale, mp.transform);
        self.out.files.push(file.clone());
        h.update(format!("{name} {scale} {xf:?}").as_bytes());
        self.out.grid_media.push(GridMedium::new(
            Arc::new(grid),
            xf,
            scale,
            mp.albedo,
            mp.phase,
            format!("{} [{name}] ({p})", file.display()),
            *h.finalize().as_bytes(),
        ));
        self.note(format!(
            "imported Volume {p} (grid \"{name}\" from {})",
            file.display()
        ));
        Ok(())
    }

    /// (relationship suffix, target) of the density field, else the first field.
    fn volume_field(&self, p: &sdf::Path) -> Result<Option<(String, sdf::Path)>> {
        let names = self
            .stage
            .prim(p.clone())
            .property_names()
            .map_err(|e| self.err(p, format!("{e:#}")))?;
        let mut fields: Vec<String> = names
            .iter()
            .map(|n| n.to_string())
            .filter(|n| n.starts_with("field:"))
            .collect();
        fields.sort_by_key(|n| n != "field:density");
        for f in fields {
            if let Some(t) = self.targets(p, &f)?.into_iter().next() {
                return Ok(Some((f["field:".len()..].to_string(), t)));
            }
        }
        Ok(None)
    }

    /// An asset attribute as a file path, relative paths against the stage's folder.
    fn asset_path(&self, p: &sdf::Path, name: &str) -> Result<PathBuf> {
        let a = match self.value(p, name)? {
            Some(sdf::Value::AssetPath(a)) => a,
            Some(sdf::Value::String(s)) => sdf::AssetPath::new(s),
            _ => return Err(self.err(p, format!("{name}: no asset path"))),
        };
        if let Some(r) = a.resolved_path().filter(|r| !r.is_empty()) {
            return Ok(PathBuf::from(self.files.at_frame(r)));
        }
        Ok(self.dir.join(self.files.at_frame(&a.authored_path)))
    }
}

/// (x, y, z) -> (x, z, -y) for a Z-up stage; identity for Y-up.
fn up_axis_rotation(path: &Path, up: &str) -> Result<DMat4> {
    match up {
        "Y" => Ok(DMat4::IDENTITY),
        "Z" => Ok(DMat4::from_cols(
            glam::DVec4::X,
            glam::DVec4::new(0.0, 0.0, -1.0, 0.0),
            glam::DVec4::new(0.0, 1.0, 0.0, 0.0),
            glam::DVec4::W,
        )),
        other => Err(Error::field(
            path,
            "upAxis",
            format!("expected \"Y\" or \"Z\", got {other:?}"),
        )),
    }
}

/// USD matrices are row-major for row vectors; read as columns that is the transpose,
/// which is exactly glam's column-vector matrix.
fn row_matrix(m: &gf::Matrix4d) -> DMat4 {
    DMat4::from_cols_array(&m.0)
}

fn quat(v: sdf::Value) -> Option<DQuat> {
    let q = match v {
        sdf::Value::Quatf(q) => DQuat::from_xyzw(q.x as f64, q.y as f64, q.z as f64, q.w as f64),
        sdf::Value::Quatd(q) => DQuat::from_xyzw(q.x, q.y, q.z, q.w),
        sdf::Value::Quath(q) => DQuat::from_xyzw(
            f64::from(q.x),
            f64::from(q.y),
            f64::from(q.z),
            f64::from(q.w),
        ),
        _ => return None,
    };
    (q.length() > 0.0).then(|| q.normalize())
}

/// rotateABC: angles are always (x, y, z) degrees; axis A is applied first, so the
/// column-vector matrix is R_C * R_B * R_A.
fn rotate3(order: &str, deg: DVec3) -> Option<DMat4> {
    let mut m = DMat4::IDENTITY;
    for axis in order.chars() {
        let r = match axis {
            'X' => DMat4::from_rotation_x(deg.x.to_radians()),
            'Y' => DMat4::from_rotation_y(deg.y.to_radians()),
            'Z' => DMat4::from_rotation_z(deg.z.to_radians()),
            _ => return None,
        };
        m = r * m;
    }
    Some(m)
}

/// Fan-triangulates polygons, checking counts against indices and indices against
/// the point count; faces with fewer than 3 corners are skipped.
pub fn triangulate(
    counts: &[i64],
    indices: &[i64],
    n_points: usize,
) -> std::result::Result<Vec<[u32; 3]>, String> {
    let total: i64 = counts.iter().map(|&c| c.max(0)).sum();
    if counts.iter().any(|&c| c < 0) || total != indices.len() as i64 {
        return Err(format!(
            "faceVertexCounts sum to {total} but there are {} faceVertexIndices",
            indices.len()
        ));
    }
    let idx = indices
        .iter()
        .map(|&i| u32::try_from(i).ok().filter(|&i| (i as usize) < n_points))
        .collect::<Option<Vec<u32>>>()
        .ok_or_else(|| format!("a faceVertexIndex is outside 0..{n_points}"))?;
    let mut tris = Vec::new();
    let mut at = 0usize;
    for &c in counts {
        let c = c as usize;
        let f = &idx[at..at + c];
        for k in 1..c.saturating_sub(1) {
            tris.push([f[0], f[k], f[k + 1]]);
        }
        at += c;
    }
    Ok(tris)
}

/// Per-corner normals to per-vertex ones, or None when corners of a vertex disagree.
fn face_varying_to_vertex(vals: &[DVec3], indices: &[i64], n: usize) -> Option<Vec<DVec3>> {
    let mut out: Vec<Option<DVec3>> = vec![None; n];
    for (&i, &v) in indices.iter().zip(vals) {
        let slot = out.get_mut(usize::try_from(i).ok()?)?;
        match slot {
            None => *slot = Some(v),
            Some(w) if w.normalize_or_zero().dot(v.normalize_or_zero()) > 0.999 => {}
            Some(_) => return None,
        }
    }
    Some(out.into_iter().map(|v| v.unwrap_or(DVec3::ZERO)).collect())
}

/// UV sphere of radius `r` about the origin, counter-clockwise seen from outside.
fn uv_sphere(r: f64, seg: u32) -> (Vec<DVec3>, Vec<DVec3>, Vec<[u32; 3]>) {
    let rings = seg / 2;
    let mut pts = Vec::new();
    for i in 0..=rings {
        let th = PI * i as f64 / rings as f64;
        for j in 0..=seg {
            let ph = 2.0 * PI * j as f64 / seg as f64;
            pts.push(DVec3::new(
                th.sin() * ph.cos(),
                th.cos(),
                -th.sin() * ph.sin(),
            ));
        }
    }
    let w = seg + 1;
    let mut tris = Vec::new();
    for i in 0..rings {
        for j in 0..seg {
            let (a, b, c, d) = (
                i * w + j,
                (i + 1) * w + j,
                (i + 1) * w + j + 1,
                i * w + j + 1,
            );
            if i != 0 {
                tris.push([a, b, d]);
            }
            if i + 1 != rings {
                tris.push([b, c, d]);
            }
        }
    }
    let normals = pts.clone();
    (pts.iter().map(|&q| q * r).collect(), normals, tris)
}

/// The stage's assets read through [`Files`]: a layer the USD reader opens more than
/// once (a `.usd` is peeked for its format, then read) and a .usdz package opened per
/// packaged layer are read from disk once; resolution is the default resolver's.
struct ReadOnce {
    inner: ar::DefaultResolver,
    files: Files,
}

/// A file's bytes shared with [`Files`], as a seekable asset.
struct Shared(io::Cursor<SharedBytes>);
struct SharedBytes(Arc<Vec<u8>>);

impl AsRef<[u8]> for SharedBytes {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

impl io::Read for Shared {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl io::Seek for Shared {
    fn seek(&mut self, pos: io::SeekFrom) -> io::Result<u64> {
        self.0.seek(pos)
    }
}

impl ar::Asset for Shared {
    fn size(&self) -> io::Result<u64> {
        Ok(self.0.get_ref().0.len() as u64)
    }
}

impl ReadOnce {
    fn bytes(&self, path: &Path) -> io::Result<Arc<Vec<u8>>> {
        self.files.read(path).map_err(|e| match e {
            Error::Io { cause, .. } => cause,
            other => io::Error::other(other.to_string()),
        })
    }

    /// The .usdz package at `path` as a zip archive over its bytes.
    fn package(&self, path: &Path) -> io::Result<zip::ZipArchive<io::Cursor<SharedBytes>>> {
        let bytes = self.bytes(path)?;
        zip::ZipArchive::new(io::Cursor::new(SharedBytes(bytes))).map_err(io::Error::other)
    }

    /// (package, entry) of `pkg.usdz[entry]`; None for a plain or nested path.
    fn packaged(path: &str) -> Option<(String, String)> {
        if !ar::is_package_relative_path(path) {
            return None;
        }
        let (package, entry) = ar::split_package_relative_path_outer(path)?;
        (!ar::is_package_relative_path(&entry)).then_some((package, entry))
    }
}

impl ar::Resolver for ReadOnce {
    /// The frame token in a layer or asset path becomes the load's frame.
    fn create_identifier(&self, asset_path: &str, anchor: Option<&ar::ResolvedPath>) -> String {
        self.inner
            .create_identifier(&self.files.at_frame(asset_path), anchor)
    }

    /// As the default resolver: a packaged path resolves when its package does and,
    /// if the package is a readable zip, holds the entry.
    fn resolve(&self, asset_path: &str) -> Option<ar::ResolvedPath> {
        let Some((package, entry)) = Self::packaged(asset_path) else {
            return self.inner.resolve(asset_path);
        };
        let package = self.inner.resolve(&package)?;
        let missing = self
            .package(&package)
            .is_ok_and(|zip| zip.index_for_name(&entry).is_none());
        if missing {
            return None;
        }
        let joined = ar::join_package_relative_path(&package.to_string_lossy(), &entry);
        Some(ar::ResolvedPath::new(joined))
    }

    fn resolve_for_new_asset(&self, asset_path: &str) -> Option<ar::ResolvedPath> {
        self.inner.resolve_for_new_asset(asset_path)
    }

    fn open_asset(&self, resolved: &ar::ResolvedPath) -> io::Result<Box<dyn ar::Asset>> {
        let s = resolved.to_string_lossy();
        if let Some((package, entry)) = Self::packaged(&s) {
            let mut zip = self.package(Path::new(&package))?;
            let mut file = zip.by_name(&entry).map_err(io::Error::other)?;
            let mut buf = Vec::new();
            io::Read::read_to_end(&mut file, &mut buf)?;
            return Ok(Box::new(io::Cursor::new(buf)));
        }
        if ar::is_package_relative_path(&s) {
            return self.inner.open_asset(resolved);
        }
        let bytes = self.bytes(resolved)?;
        Ok(Box::new(Shared(io::Cursor::new(SharedBytes(bytes)))))
    }

    fn identity(&self) -> String {
        self.inner.identity()
    }
}
