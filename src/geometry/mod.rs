//! Surfaces: triangle meshes in an obvhs BVH. Sphere lights are analytic spheres seen by
//! rays but not surfaces: they neither block nor reflect light (the conformance SPEC, and
//! Mitsuba's emitter sphere with a `null` BSDF), so the fog behind a light shows through it.
use glam::{Vec3, Vec3A};
use obvhs::{bvh2::builder::build_bvh2_from_tris, bvh2::Bvh2, ray::RayHit, triangle::Triangle};
use std::time::Duration;

use crate::core::{ray_box, Ray, Rgb};
use crate::error::{Error, Result};
use crate::scene::{Light, Material, Scene};

#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub p: Vec3,
    /// Geometric normal (unit, as wound: outward for CCW triangles).
    pub ng: Vec3,
    /// Interpolated shading normal, on the same side as `ng`.
    pub ns: Vec3,
    pub material: Material,
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
    /// The triangles' bounds, grown so that a ray the BVH could hit always overlaps them:
    /// most rays of a light path inside a medium miss every surface, and this one box test
    /// is cheaper than the BVH's ray set-up (a floor under a cloud: 7 % of a pass).
    reach: [Vec3; 2],
    spheres: Vec<SphereEmitter>,
}

/// Up to this many triangles a ray tests each of them, skipping the BVH's traversal set-up
/// and stack (a floor of two triangles under a cloud, met by most of a light path's hops).
const TEST_ALL_UP_TO: usize = 8;

/// Offset used to leave a surface without re-hitting it (m).
pub const EPS: f32 = 1e-4;

/// The smallest box holding all of `boxes` (lo, hi), if there are any.
fn enclosing(boxes: impl Iterator<Item = (Vec3, Vec3)>) -> Option<[Vec3; 2]> {
    boxes.fold(None, |b, (lo, hi)| {
        Some(match b {
            None => [lo, hi],
            Some([a, c]) => [a.min(lo), c.max(hi)],
        })
    })
}

fn triangle_boxes(tris: &[Triangle]) -> impl Iterator<Item = (Vec3, Vec3)> + '_ {
    tris.iter().map(|t| {
        let a = t.aabb();
        (a.min.into(), a.max.into())
    })
}

/// `[lo, hi]` grown on every side by a margin relative to its size (and at least 1e-4 m),
/// so that a flat box (a floor) has volume and rounding in the slab test never rejects a
/// ray that meets a triangle inside it.
fn grown([lo, hi]: [Vec3; 2]) -> [Vec3; 2] {
    let size = (hi - lo)
        .max_element()
        .max(lo.abs().max(hi.abs()).max_element());
    let margin = (size * 1e-4).max(1e-4);
    [lo - margin, hi + margin]
}

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
        // Without triangles there is no BVH, and intersect never reads it.
        let reach = enclosing(triangle_boxes(&tris)).map_or([Vec3::ZERO; 2], grown);
        Ok(Geometry {
            tris,
            info,
            bvh,
            reach,
            spheres,
        })
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Bounds of all surfaces, if any.
    pub fn bounds(&self) -> Option<[Vec3; 2]> {
        let spheres = self
            .spheres
            .iter()
            .map(|s| (s.center - s.radius, s.center + s.radius));
        enclosing(triangle_boxes(&self.tris).chain(spheres))
    }

    /// Closest surface hit in (EPS-free) range (0, tmax); sphere lights are not surfaces.
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        ray_box(ray, &self.reach, 0.0, tmax)?;
        let mut r = obvhs::ray::Ray::new(Vec3A::from(ray.o), Vec3A::from(ray.d), 0.0, tmax);
        if self.tris.len() <= TEST_ALL_UP_TO {
            // The nearest as the BVH finds it: a hit must come strictly before the last.
            let mut nearest = None;
            for (id, tri) in self.tris.iter().enumerate() {
                let t = tri.intersect(&r);
                if t < r.tmax {
                    r.tmax = t;
                    nearest = Some(id);
                }
            }
            return nearest.map(|id| self.triangle_hit(ray, id, r.tmax));
        }
        let mut hit = RayHit::none();
        bvh.ray_traverse(r, &mut hit, |r, id| {
            self.tris[bvh.primitive_indices[id] as usize].intersect(r)
        })
        .then(|| {
            let id = bvh.primitive_indices[hit.primitive_id as usize] as usize;
            self.triangle_hit(ray, id, hit.t)
        })
    }

    /// Whether a ray within `margin` radians of `ray` could meet a sphere light.
    pub fn lights_near(&self, ray: &Ray, margin: f32) -> bool {
        self.spheres.iter().any(|s| {
            let v = s.center - ray.o;
            let d = v.length();
            d <= s.radius || {
                let half = (s.radius / d).asin() + margin;
                half >= std::f32::consts::PI || v.dot(ray.d) / d >= half.cos()
            }
        })
    }

    /// The sphere lights `ray` enters in (EPS, tmax), with the radiance each shows there:
    /// where it enters, the sphere's outward face looks back along the ray. A ray leaving
    /// a sphere from inside sees nothing of it (emission is outward only).
    pub fn lights_seen(&self, ray: &Ray, tmax: f32) -> impl Iterator<Item = (f32, Rgb)> + '_ {
        let ray = *ray;
        self.spheres.iter().filter_map(move |s| {
            let t = sphere_entry(&ray, s.center, s.radius)?;
            (t > EPS && t < tmax).then_some((t, s.radiance))
        })
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
            material: info.material,
        }
    }
}

/// The nearer root of |o + t d - c| = r (unit d): where the line enters the sphere.
fn sphere_entry(ray: &Ray, c: Vec3, r: f32) -> Option<f32> {
    let oc = ray.o - c;
    let b = oc.dot(ray.d);
    let disc = b * b - (oc.length_squared() - r * r);
    (disc >= 0.0).then(|| -b - disc.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use crate::scene::{Mesh, NamedMaterial};

    /// A flat 6 m floor at y = 0 (alone, its bounds have no height) and, with `bits`, 20
    /// triangles above it.
    fn scene(with_bits: bool) -> Scene {
        let grey = Material::Lambert {
            reflectance: Vec3::splat(0.5),
        };
        let floor = Mesh {
            name: "floor".into(),
            positions: vec![
                Vec3::new(-3.0, 0.0, -3.0),
                Vec3::new(3.0, 0.0, -3.0),
                Vec3::new(3.0, 0.0, 3.0),
                Vec3::new(-3.0, 0.0, 3.0),
            ],
            triangles: vec![[0, 3, 2], [0, 2, 1]],
            ..Default::default()
        };
        let mut rng = Rng::new(5, 0);
        let mut bits = Mesh {
            name: "bits".into(),
            ..Default::default()
        };
        for i in 0..20u32 {
            let c = Vec3::new(
                rng.f32() * 4.0 - 2.0,
                1.0 + rng.f32(),
                rng.f32() * 4.0 - 2.0,
            );
            for _ in 0..3 {
                let d = Vec3::new(rng.f32(), rng.f32(), rng.f32()) - 0.5;
                bits.positions.push(c + d * 0.6);
            }
            bits.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        Scene {
            materials: vec![NamedMaterial {
                name: "grey".into(),
                material: grey,
            }],
            meshes: if with_bits {
                vec![floor, bits]
            } else {
                vec![floor]
            },
            ..Default::default()
        }
    }

    /// The box test before the BVH rejects no ray that meets a triangle: every ray's hit
    /// equals the nearest over all triangles (the test the BVH runs on each), for rays
    /// from inside and outside the bounds, grazing the flat floor, ending just past or just
    /// short of a hit, and along the axes; for the floor alone (whose two triangles are
    /// tested one by one) and with 20 more (the BVH).
    #[test]
    fn bounds_keep_every_hit() {
        for with_bits in [false, true] {
            hits_equal_the_nearest_triangle(&Geometry::new(&scene(with_bits)).unwrap());
        }
    }

    fn hits_equal_the_nearest_triangle(g: &Geometry) {
        let mut rng = Rng::new(11, 0);
        let (mut hits, mut misses) = (0, 0);
        for i in 0..40_000 {
            let mut o = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 10.0 - 5.0;
            let aim = Vec3::new(
                rng.f32() * 6.0 - 3.0,
                rng.f32() * 2.0,
                rng.f32() * 6.0 - 3.0,
            );
            let d = match i % 4 {
                // Grazing the floor: from just above or below it, nearly in its plane.
                0 => {
                    o.y = (rng.f32() - 0.5) * 1e-3;
                    Vec3::new(aim.x - o.x, (rng.f32() - 0.5) * 1e-3, aim.z - o.z)
                }
                1 => [Vec3::X, Vec3::NEG_Y, Vec3::Z, Vec3::Y][(rng.f32() * 4.0) as usize % 4],
                2 => aim - o,
                _ => crate::sampling::uniform_sphere(rng.vec2()),
            };
            let ray = Ray::new(o, d.normalize());
            let brute = |tmax: f32| {
                let r = obvhs::ray::Ray::new(Vec3A::from(ray.o), Vec3A::from(ray.d), 0.0, tmax);
                g.tris
                    .iter()
                    .map(|t| t.intersect(&r))
                    .fold(f32::INFINITY, f32::min)
            };
            let full = brute(f32::INFINITY);
            // Cut just past or just short of the nearest hit, or not at all.
            let tmax = match (i / 4) % 3 {
                0 if full.is_finite() => full * (1.0 + 1e-6) + 1e-6,
                1 if full.is_finite() => full * (1.0 - 1e-6),
                _ => f32::INFINITY,
            };
            let want = brute(tmax);
            let got = g.intersect(&ray, tmax).map_or(f32::INFINITY, |h| h.t);
            assert_eq!(got, want, "ray {i}: {ray:?} up to {tmax}");
            if want.is_finite() {
                hits += 1;
            } else {
                misses += 1;
            }
        }
        assert!(
            hits > 5_000 && misses > 5_000,
            "{hits} hits, {misses} misses"
        );
    }
}
