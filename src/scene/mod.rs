//! Scene import: every source (TOML scene file, OBJ, glTF, USD) ends up as one [`Scene`].
//!
//! Units: metres, radiometric (W, W/sr, W/m^2, W/(m^2 sr)); right-handed, +Y up.
pub mod assets;
pub mod environment;
pub mod files;
pub mod format;
pub mod gltf;
pub mod grids;
pub mod medium;
pub mod obj;
pub mod sky;
pub mod toml;
pub mod usd;

pub use environment::{EnvMap, Environment};
pub use format::Format;

use glam::Vec3;

use crate::core::Rgb;
use crate::media::{GridMedium, MediumDesc};

/// Pinhole camera as SPEC.md defines it (vertical field of view).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub origin: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view, degrees.
    pub vfov_deg: f32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Diffuse, BRDF = reflectance / pi, reflects on both sides.
    Lambert { reflectance: Rgb },
    /// Smooth Fresnel dielectric (exterior IOR 1), clear inside.
    Dielectric { ior: f32 },
    /// Perfect specular reflector.
    Mirror { reflectance: Rgb },
}

#[derive(Clone, Debug, PartialEq)]
pub struct NamedMaterial {
    pub name: String,
    pub material: Material,
}

/// Triangle mesh in world space.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (same length as `positions`), or empty for flat shading.
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Index into the material list of whatever holds the mesh ([`Imported`] or [`Scene`]).
    pub material: usize,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Light {
    /// Isotropic point light, radiant intensity W/sr.
    Point { position: Vec3, intensity: Rgb },
    /// Spot light: intensity W/sr on the axis, full inside `inner_deg`, falling linearly in
    /// cos(angle) to zero at `outer_deg` (half-angles, degrees).
    Spot {
        position: Vec3,
        direction: Vec3,
        intensity: Rgb,
        inner_deg: f32,
        outer_deg: f32,
    },
    /// Delta direction of travel, irradiance W/m^2 on a plane perpendicular to it.
    Directional { direction: Vec3, irradiance: Rgb },
    /// Opaque black sphere emitting uniform radiance W/(m^2 sr) outward; visible to the camera.
    Sphere {
        center: Vec3,
        radius: f32,
        radiance: Rgb,
    },
    /// Radiance W/(m^2 sr) arriving from every direction at infinity (a constant sky or
    /// a lat-long map); camera rays that leave the scene see it.
    Environment(Environment),
}

/// What one imported file (OBJ, glTF, USD) contributes; mesh materials index `materials`.
#[derive(Clone, Debug, Default)]
pub struct Imported {
    pub materials: Vec<NamedMaterial>,
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub camera: Option<Camera>,
    /// Grid media placed by the file (USD Volume prims).
    pub grid_media: Vec<GridMedium>,
    /// One line per prim imported or ignored, with its path, for `ppb info`.
    pub notes: Vec<String>,
    /// Files read besides the imported file itself (glTF buffers, .mtl, USD layers, VDB
    /// assets): `ppb watch` watches them and the asset cache hashes them.
    pub files: Vec<std::path::PathBuf>,
}

/// Everything the renderer needs, in world space.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    pub camera: Camera,
    pub materials: Vec<NamedMaterial>,
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub media: Vec<MediumDesc>,
    pub grid_media: Vec<GridMedium>,
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            origin: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 40.0,
        }
    }
}
