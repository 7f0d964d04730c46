//! Surfaces: triangle meshes in an obvhs BVH, plus analytic spheres for sphere lights.
use glam::{Vec3, Vec3A};
use obvhs::{bvh2::builder::build_bvh2_from_tris, bvh2::Bvh2, ray::RayHit, triangle::Triangle};
use std::time::Duration;

use crate::core::{Ray, Rgb};
use crate::error::{Error, Result};
use crate::scene::{Light, Material, Scene};

/// What a ray hit.
#[derive(Clone, Copy, Debug)]
pub enum Surface {
    Material(Material),
    /// A sphere light: opaque, black, emitting this radiance outward.
    Emitter(Rgb),
}

#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub p: Vec3,
    /// Geometric normal (unit, as wound: outward for CCW triangles).
    pub ng: Vec3,
    /// Interpolated shading normal, on the same side as `ng`.
    pub ns: Vec3,
    pub surface: Surface,
}

struct TriInfo {
    material: Material,
    /// Vertex normals, or all equal to the face normal.
    n: [Vec3; 3],
}

struct SphereEmitter {
    center: Vec3,
    radius: f32,
    radiance: Rgb,
}

pub struct Geometry {
    tris: Vec<Triangle>,
    info: Vec<TriInfo>,
    bvh: Option<Bvh2>,
    spheres: Vec<SphereEmitter>,
}

/// Offset used to leave a surface without re-hitting it (m).
pub const EPS: f32 = 1e-4;

impl Geometry {
    pub fn new(scene: &Scene) -> Result<Self> {
        let mut tris = Vec::new();
        let mut info = Vec::new();
        for mesh in &scene.meshes {
            let material = scene
                .materials
                .get(mesh.material)
                .ok_or_else(|| {
                    Error::Other(format!("mesh '{}': material index out of range", mesh.name))
                })?
                .material;
            for tri in &mesh.triangles {
                let v = tri.map(|i| mesh.positions.get(i as usize).copied());
                let [Some(a), Some(b), Some(c)] = v else {
                    return Err(Error::Other(format!(
                        "mesh '{}': vertex index out of range",
                        mesh.name
                    )));
                };
                let face = (b - a).cross(c - a);
                if face.length_squared() == 0.0 || !face.is_finite() {
                    continue;
                }
                let face = face.normalize();
                let n = if mesh.normals.len() == mesh.positions.len() {
                    tri.map(|i| {
                        let n = mesh.normals[i as usize];
                        if n.dot(face) < 0.0 {
                            -n
                        } else {
                            n
                        }
                    })
                } else {
                    [face; 3]
                };
                tris.push(Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                });
                info.push(TriInfo { material, n });
            }
        }
        let bvh = (!tris.is_empty()).then(|| {
            build_bvh2_from_tris(
                &tris,
                obvhs::BvhBuildParams::medium_build(),
                &mut Duration::default(),
            )
        });
        let spheres = scene
            .lights
            .iter()
            .filter_map(|l| match *l {
                Light::Sphere {
                    center,
                    radius,
                    radiance,
                } => Some(SphereEmitter {
                    center,
                    radius,
                    radiance,
                }),
                _ => None,
            })
            .collect();
        Ok(Geometry {
            tris,
            info,
            bvh,
            spheres,
        })
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Bounds of all surfaces, if any.
    pub fn bounds(&self) -> Option<[Vec3; 2]> {
        let mut b: Option<[Vec3; 2]> = None;
        let mut add = |lo: Vec3, hi: Vec3| {
            b = Some(match b {
                None => [lo, hi],
                Some([a, c]) => [a.min(lo), c.max(hi)],
            })
        };
        for t in &self.tris {
            let a = t.aabb();
            add(a.min.into(), a.max.into());
        }
        for s in &self.spheres {
            add(s.center - s.radius, s.center + s.radius);
        }
        b
    }

    /// Closest hit in (EPS-free) range (0, tmax).
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = tmax;
        if let Some(bvh) = &self.bvh {
            let r = obvhs::ray::Ray::new(Vec3A::from(ray.o), Vec3A::from(ray.d), 0.0, tmax);
            let mut hit = RayHit::none();
            if bvh.ray_traverse(r, &mut hit, |r, id| {
                self.tris[bvh.primitive_indices[id] as usize].intersect(r)
            }) {
                let id = bvh.primitive_indices[hit.primitive_id as usize] as usize;
                tmax = hit.t;
                best = Some(self.triangle_hit(ray, id, hit.t));
            }
        }
        for s in &self.spheres {
            if let Some(t) = sphere_hit(ray, s.center, s.radius, tmax) {
                tmax = t;
                let p = ray.at(t);
                let n = (p - s.center).normalize();
                best = Some(Hit {
                    t,
                    p,
                    ng: n,
                    ns: n,
                    surface: Surface::Emitter(s.radiance),
                });
            }
        }
        best
    }

    fn triangle_hit(&self, ray: &Ray, id: usize, t: f32) -> Hit {
        let tri = &self.tris[id];
        let info = &self.info[id];
        let p = ray.at(t);
        let (a, b, c): (Vec3, Vec3, Vec3) = (tri.v0.into(), tri.v1.into(), tri.v2.into());
        let ng_raw = (b - a).cross(c - a);
        let ng = ng_raw.normalize();
        // Barycentrics from sub-triangle areas.
        let inv = 1.0 / ng_raw.length_squared();
        let w1 = (c - a).cross(p - a).dot(ng_raw) * -inv;
        let w2 = (b - a).cross(p - a).dot(ng_raw) * inv;
        let w0 = 1.0 - w1 - w2;
        let mut ns = (info.n[0] * w0 + info.n[1] * w1 + info.n[2] * w2).normalize_or_zero();
        if ns == Vec3::ZERO {
            ns = ng;
        }
        Hit {
            t,
            p,
            ng,
            ns,
            surface: Surface::Material(info.material),
        }
    }
}

fn sphere_hit(ray: &Ray, c: Vec3, r: f32, tmax: f32) -> Option<f32> {
    let oc = ray.o - c;
    let b = oc.dot(ray.d);
    let cc = oc.length_squared() - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    [-b - s, -b + s].into_iter().find(|&t| t > EPS && t < tmax)
}
