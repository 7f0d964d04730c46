//! glTF 2.0 import (.gltf and .glb): meshes, materials, KHR_lights_punctual lights and the
//! first perspective camera of the default scene, all baked into world space.
use std::path::Path;

use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::camera::Projection;
use ::gltf::khr_lights_punctual::{self as punctual, Kind};
use ::gltf::mesh::Mode;
use ::gltf::{buffer, Accessor, Document, Node, Primitive, Semantic};
use glam::{Mat3, Mat4, Vec3};

use super::files::Files;
use super::{Camera, Imported, Light, Material, Mesh, NamedMaterial};
use crate::error::{Error, Result};

/// Luminous efficacy (lm/W) that turns glTF's photometric light units into radiometric ones.
const LM_PER_W: f32 = 683.0;
/// glTF's IOR when a material has no KHR_materials_ior.
const DEFAULT_IOR: f32 = 1.5;
/// Reflectance of the material given to primitives that have none.
const DEFAULT_GREY: f32 = 0.8;
/// Required extensions whose absence would change what we import: anything else is refused.
const SUPPORTED_REQUIRED: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_mesh_quantization",
    "KHR_materials_emissive_strength",
];

/// Loads a .gltf or .glb file; lights are converted from photometric units (cd, lux) to
/// W/sr and W/m^2 at 683 lm/W.
pub fn load_gltf(path: &Path) -> Result<Imported> {
    read_gltf(path, &Files::new())
}

/// [`load_gltf`] reading the file and its external buffers through `files` (once each
/// per load).
pub fn read_gltf(path: &Path, files: &Files) -> Result<Imported> {
    let (document, buffers) = open(path, files)?;
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next())
        .ok_or_else(|| Error::field(path, "scenes", "no scene to import"))?;
    let mut walker = Walker {
        path,
        buffers: &buffers,
        parent: vec![None; document.nodes().len()],
        default_material: None,
        out: Imported {
            materials: document.materials().map(|m| convert_material(&m)).collect(),
            ..Default::default()
        },
    };
    walker.walk(scene.nodes())?;
    walker.out.files = external_files(path, &document);
    Ok(walker.out)
}

/// Buffers and images referenced by relative URI (not `data:`), resolved against the file's
/// folder: re-exporting a glTF rewrites them too, so they are watched with it.
fn external_files(path: &Path, document: &Document) -> Vec<std::path::PathBuf> {
    let dir = path.parent().unwrap_or(Path::new(""));
    let buffers = document.buffers().filter_map(|b| match b.source() {
        ::gltf::buffer::Source::Uri(u) => Some(u.to_string()),
        ::gltf::buffer::Source::Bin => None,
    });
    let images = document.images().filter_map(|i| match i.source() {
        ::gltf::image::Source::Uri { uri, .. } => Some(uri.to_string()),
        ::gltf::image::Source::View { .. } => None,
    });
    buffers
        .chain(images)
        .filter(|u| !u.starts_with("data:") && !u.contains("://"))
        .map(|u| dir.join(u))
        .collect()
}

/// A relative file URI as a path under `dir` (percent-escapes decoded, as the gltf
/// crate's importer does); None for `data:` and other schemes.
fn relative_file(dir: &Path, uri: &str) -> Option<std::path::PathBuf> {
    if uri.contains(':') {
        return None;
    }
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (b[i], b.get(i + 1).copied(), b.get(i + 2).copied()) {
            (b'%', Some(h), Some(l)) if hex(h).is_some() && hex(l).is_some() => {
                out.push((hex(h)? * 16 + hex(l)?) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    Some(dir.join(String::from_utf8(out).ok()?))
}

/// Parses and validates the document and loads its buffers (never its images).
///
/// `extensionsRequired` is checked here rather than by the gltf crate, which would reject
/// KHR_mesh_quantization even though [`read_components`] decodes quantized attributes.
fn open(path: &Path, files: &Files) -> Result<(Document, Vec<buffer::Data>)> {
    let bytes = files.read(path)?;
    let crate_err = |e: ::gltf::Error| Error::format(path, e.to_string());
    let ::gltf::Gltf { document, blob } =
        ::gltf::Gltf::from_slice_without_validation(&bytes).map_err(crate_err)?;
    let mut root = document.into_json();
    if let Some(ext) = root
        .extensions_required
        .iter()
        .find(|e| !SUPPORTED_REQUIRED.contains(&e.as_str()))
    {
        let msg = format!("unsupported extension {ext}");
        return Err(Error::field(path, "extensionsRequired", msg));
    }
    root.extensions_required.clear();
    let document = Document::from_json(root).map_err(crate_err)?;
    let buffers = import_buffers(path, &document, blob, files)?;
    Ok((document, buffers))
}

/// `gltf::import_buffers`, with buffers in files next to the glTF read through `files`.
fn import_buffers(
    path: &Path,
    document: &Document,
    mut blob: Option<Vec<u8>>,
    files: &Files,
) -> Result<Vec<buffer::Data>> {
    let dir = path.parent().unwrap_or(Path::new(""));
    let crate_err = |e: ::gltf::Error| Error::format(path, e.to_string());
    let mut out = Vec::new();
    for b in document.buffers() {
        let file = match b.source() {
            buffer::Source::Uri(u) => relative_file(dir, u),
            buffer::Source::Bin => None,
        };
        let data = match file {
            Some(f) => {
                let bytes = files.read(&f)?;
                let mut v = Vec::with_capacity(bytes.len() + 3);
                v.extend_from_slice(&bytes);
                while v.len() % 4 != 0 {
                    v.push(0);
                }
                buffer::Data(v)
            }
            None => buffer::Data::from_source_and_blob(b.source(), path.parent(), &mut blob)
                .map_err(crate_err)?,
        };
        if data.len() < b.length() {
            let e = ::gltf::Error::BufferLength {
                buffer: b.index(),
                expected: b.length(),
                actual: data.len(),
            };
            return Err(crate_err(e));
        }
        out.push(data);
    }
    Ok(out)
}

/// Transmissive materials become smooth dielectrics, everything else Lambert with the base
/// colour factor; roughness, metalness and textures have no counterpart in our model.
fn convert_material(m: &::gltf::Material) -> NamedMaterial {
    let transmissive = m
        .transmission()
        .is_some_and(|t| t.transmission_factor() > 0.0);
    let material = if transmissive {
        Material::Dielectric {
            ior: m.ior().unwrap_or(DEFAULT_IOR),
        }
    } else {
        let [r, g, b, _] = m.pbr_metallic_roughness().base_color_factor();
        Material::Lambert {
            reflectance: Vec3::new(r, g, b),
        }
    };
    let name = m
        .name()
        .map(str::to_owned)
        .unwrap_or_else(|| format!("material{}", m.index().unwrap_or_default()));
    NamedMaterial { name, material }
}

/// Depth-first walk of the scene graph that accumulates world transforms.
struct Walker<'a> {
    path: &'a Path,
    buffers: &'a [buffer::Data],
    /// Per node: not reached yet (`None`), reached as a scene root (`Some(None)`) or as a
    /// child of node `p` (`Some(Some(p))`). glTF's node hierarchy is a set of disjoint
    /// strict trees, so a node reached twice is refused: a cycle, or a node shared by two
    /// parents (a file of a few hundred bytes could otherwise share nodes so that the walk
    /// visits them exponentially often).
    parent: Vec<Option<Option<usize>>>,
    default_material: Option<usize>,
    out: Imported,
}

impl Walker<'_> {
    /// Depth-first, parents before children and siblings in file order, with an explicit
    /// stack: a chain of nodes as deep as the file is long cannot overflow the call stack.
    fn walk<'d>(&mut self, roots: impl Iterator<Item = Node<'d>>) -> Result<()> {
        let mut stack: Vec<(Node, Option<usize>, Mat4)> =
            roots.map(|n| (n, None, Mat4::IDENTITY)).collect();
        stack.reverse();
        while let Some((node, from, parent)) = stack.pop() {
            let i = node.index();
            if self.parent[i].is_some() {
                return Err(self.reached_twice(i, from));
            }
            self.parent[i] = Some(from);
            let world = self.visit(&node, parent)?;
            let first = stack.len();
            stack.extend(node.children().map(|c| (c, Some(i), world)));
            stack[first..].reverse();
        }
        Ok(())
    }

    /// Node `i`, already imported, reached again from `from`: a cycle when `i` is an
    /// ancestor of `from`, else a node with two parents.
    fn reached_twice(&self, i: usize, from: Option<usize>) -> Error {
        let mut up = from;
        let mut steps = 0;
        while let Some(p) = up {
            if p == i {
                let msg = "node hierarchy has a cycle";
                return Error::field(self.path, format!("nodes[{i}]"), msg);
            }
            steps += 1;
            up = self.parent[p]
                .flatten()
                .filter(|_| steps <= self.parent.len());
        }
        let msg = "node is reached more than once (two parents, or a scene root that is \
                   also a child); glTF node hierarchies must be strict trees";
        Error::field(self.path, format!("nodes[{i}]"), msg)
    }

    /// Imports what node `node` holds; returns its world transform.
    fn visit(&mut self, node: &Node, parent: Mat4) -> Result<Mat4> {
        let i = node.index();
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            self.add_mesh(node, &mesh, world)?;
        }
        if let Some(light) = node.light() {
            let light = convert_light(&light, world).ok_or_else(|| {
                Error::field(
                    self.path,
                    format!("nodes[{i}]"),
                    "light has no direction (zero scale)",
                )
            })?;
            self.out.lights.push(light);
        }
        if self.out.camera.is_none() {
            self.out.camera = node.camera().and_then(|c| convert_camera(&c, world));
        }
        Ok(world)
    }

    /// One [`Mesh`] per primitive, named after the node (else the mesh), suffixed `.j` when
    /// the mesh has several primitives.
    fn add_mesh(&mut self, node: &Node, mesh: &::gltf::Mesh, world: Mat4) -> Result<()> {
        let base = node
            .name()
            .or(mesh.name())
            .map(str::to_owned)
            .unwrap_or_else(|| format!("mesh{}", mesh.index()));
        let several = mesh.primitives().len() > 1;
        for prim in mesh.primitives() {
            let field =
                |f: &str| format!("meshes[{}].primitives[{}].{f}", mesh.index(), prim.index());
            let mut out = self.read_primitive(&prim, &field, world)?;
            if out.triangles.is_empty() {
                continue;
            }
            out.name = if several {
                format!("{base}.{}", prim.index())
            } else {
                base.clone()
            };
            out.material = match prim.material().index() {
                Some(i) => i,
                None => self.default_material(),
            };
            self.out.meshes.push(out);
        }
        Ok(())
    }

    fn read_primitive(
        &self,
        prim: &Primitive,
        field: &dyn Fn(&str) -> String,
        world: Mat4,
    ) -> Result<Mesh> {
        if prim.mode() != Mode::Triangles {
            let msg = format!("{:?} is not supported, only Triangles", prim.mode());
            return Err(Error::field(self.path, field("mode"), msg));
        }
        let pos_field = field("attributes.POSITION");
        let accessor = prim
            .get(&Semantic::Positions)
            .ok_or_else(|| Error::field(self.path, &pos_field, "missing"))?;
        let positions: Vec<Vec3> = self
            .read_vec3(&accessor, &pos_field)?
            .into_iter()
            .map(|p| world.transform_point3(p))
            .collect();
        let normals = match prim.get(&Semantic::Normals) {
            Some(a) => world_normals(self.read_vec3(&a, &field("attributes.NORMAL"))?, world),
            None => Vec::new(),
        };
        if !normals.is_empty() && normals.len() != positions.len() {
            let msg = "NORMAL count differs from POSITION count";
            return Err(Error::field(self.path, field("attributes.NORMAL"), msg));
        }
        let triangles = self.read_triangles(prim, &field("indices"), positions.len())?;
        Ok(Mesh {
            positions,
            normals,
            triangles,
            ..Default::default()
        })
    }

    fn read_vec3(&self, accessor: &Accessor, field: &str) -> Result<Vec<Vec3>> {
        if accessor.dimensions() != Dimensions::Vec3 {
            return Err(Error::field(self.path, field, "expected a VEC3 accessor"));
        }
        let values = read_components(self.path, field, accessor, self.buffers)?;
        Ok(values
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
            .collect())
    }

    /// Triangles from the index accessor, or consecutive vertices when there is none.
    fn read_triangles(
        &self,
        prim: &Primitive,
        field: &str,
        vertex_count: usize,
    ) -> Result<Vec<[u32; 3]>> {
        let err = |msg: String| Error::field(self.path, field, msg);
        let n = u32::try_from(vertex_count).map_err(|_| err("too many vertices".into()))?;
        let indices: Vec<u32> = match prim.indices() {
            None => (0..n).collect(),
            Some(a) => {
                let integer = matches!(a.data_type(), DataType::U8 | DataType::U16 | DataType::U32);
                if a.dimensions() != Dimensions::Scalar || !integer {
                    return Err(err("expected a SCALAR accessor of unsigned integers".into()));
                }
                let values = read_components(self.path, field, &a, self.buffers)?;
                values.into_iter().map(|v| v as u32).collect()
            }
        };
        if let Some(bad) = indices.iter().find(|&&i| i >= n) {
            return Err(err(format!("index {bad} out of range ({n} vertices)")));
        }
        Ok(indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect())
    }

    /// Index of the shared "default" material, appended on first use.
    fn default_material(&mut self) -> usize {
        let materials = &mut self.out.materials;
        *self.default_material.get_or_insert_with(|| {
            materials.push(NamedMaterial {
                name: "default".into(),
                material: Material::Lambert {
                    reflectance: Vec3::splat(DEFAULT_GREY),
                },
            });
            materials.len() - 1
        })
    }
}

/// Normals through the inverse transpose; empty (flat shading) if the transform is
/// singular or a normal degenerates.
fn world_normals(normals: Vec<Vec3>, world: Mat4) -> Vec<Vec3> {
    let m = Mat3::from_mat4(world).inverse().transpose();
    normals
        .into_iter()
        .map(|n| (m * n).try_normalize())
        .collect::<Option<Vec<_>>>()
        .unwrap_or_default()
}

/// Reads an accessor's components as f64 (exact for u32 indices), dequantizing normalized
/// integers as KHR_mesh_quantization specifies.
///
/// Bounds are checked here because the gltf crate's own readers panic on some malformed
/// files (bad component types, zero counts, short strides).
fn read_components(
    path: &Path,
    field: &str,
    accessor: &Accessor,
    buffers: &[buffer::Data],
) -> Result<Vec<f64>> {
    let err = |msg: &str| Error::field(path, field, msg);
    if accessor.sparse().is_some() {
        return Err(err("sparse accessors are not supported"));
    }
    let view = accessor
        .view()
        .ok_or_else(|| err("accessor has no bufferView"))?;
    let ty = accessor.data_type();
    let (n, size, count) = (
        accessor.dimensions().multiplicity(),
        ty.size(),
        accessor.count(),
    );
    let element = n * size;
    let stride = view.stride().unwrap_or(element);
    if stride < element {
        return Err(err("byteStride is smaller than an element"));
    }
    let span = match count.checked_sub(1) {
        None => 0,
        Some(last) => last
            .checked_mul(stride)
            .and_then(|s| s.checked_add(element))
            .ok_or_else(|| err("accessor too large"))?,
    };
    let bytes = buffers
        .get(view.buffer().index())
        .and_then(|b| {
            b.0.get(view.offset()..view.offset().checked_add(view.length())?)
        })
        .and_then(|v| v.get(accessor.offset()..accessor.offset().checked_add(span)?))
        .ok_or_else(|| err("accessor runs past its bufferView or buffer"))?;
    let normalized = accessor.normalized();
    Ok((0..count)
        .flat_map(|i| (0..n).map(move |c| i * stride + c * size))
        .map(|at| decode(&bytes[at..at + size], ty, normalized))
        .collect())
}

fn decode(b: &[u8], ty: DataType, normalized: bool) -> f64 {
    let (v, max) = match ty {
        DataType::I8 => (f64::from(b[0] as i8), 127.0),
        DataType::U8 => (f64::from(b[0]), 255.0),
        DataType::I16 => (f64::from(i16::from_le_bytes([b[0], b[1]])), 32767.0),
        DataType::U16 => (f64::from(u16::from_le_bytes([b[0], b[1]])), 65535.0),
        DataType::U32 => (f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])), 1.0),
        DataType::F32 => (f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])), 1.0),
    };
    if normalized {
        (v / max).max(-1.0)
    } else {
        v
    }
}

/// Light at the node; `None` when a directed light's node transform has no -Z direction.
fn convert_light(light: &punctual::Light, world: Mat4) -> Option<Light> {
    let radiometric = Vec3::from(light.color()) * light.intensity() / LM_PER_W;
    let position = world.transform_point3(Vec3::ZERO);
    let direction = || world.transform_vector3(Vec3::NEG_Z).try_normalize();
    Some(match light.kind() {
        Kind::Point => Light::Point {
            position,
            intensity: radiometric,
        },
        Kind::Directional => Light::Directional {
            direction: direction()?,
            irradiance: radiometric,
        },
        Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => Light::Spot {
            position,
            direction: direction()?,
            intensity: radiometric,
            inner_deg: inner_cone_angle.to_degrees(),
            outer_deg: outer_cone_angle.to_degrees(),
        },
    })
}

/// Camera looking down the node's -Z with its +Y up; `None` for orthographic cameras or a
/// degenerate transform.
fn convert_camera(camera: &::gltf::Camera, world: Mat4) -> Option<Camera> {
    let Projection::Perspective(p) = camera.projection() else {
        return None;
    };
    let origin = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z).try_normalize()?;
    Some(Camera {
        origin,
        target: origin + forward,
        up: world.transform_vector3(Vec3::Y).try_normalize()?,
        vfov_deg: p.yfov().to_degrees(),
    })
}
