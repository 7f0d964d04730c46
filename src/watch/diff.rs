//! What an edit changed between two loads of a scene, so the watch loop restarts only
//! when the image changes and names what it reloaded.
use crate::media::GridMedium;
use crate::scene::{Mesh, Scene};
use crate::settings::RenderSettings;

/// The parts of a scene that differ between two loads.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    /// Render settings that change pixels ([`RenderSettings::pixel_key`]); a new pass
    /// count only moves where the render stops.
    pub settings: bool,
    /// Only tone mapping: the accumulated image stays valid.
    pub exposure: bool,
    pub camera: bool,
    pub lights: bool,
    pub materials: bool,
    pub meshes: bool,
    /// Homogeneous media.
    pub media: bool,
    /// Indices (in the new scene) of grid media whose density field is new or changed:
    /// the ones that need an octree.
    pub grids: Vec<usize>,
    /// Grid media added, removed or with a new albedo or phase.
    pub grid_params: bool,
}

impl Changes {
    pub fn between(
        old: &Scene,
        old_s: &RenderSettings,
        new: &Scene,
        new_s: &RenderSettings,
    ) -> Self {
        Changes {
            settings: old_s.pixel_key() != new_s.pixel_key(),
            exposure: old_s.exposure != new_s.exposure,
            camera: old.camera != new.camera,
            lights: old.lights != new.lights,
            materials: old.materials != new.materials,
            meshes: old.meshes.len() != new.meshes.len()
                || old
                    .meshes
                    .iter()
                    .zip(&new.meshes)
                    .any(|(a, b)| !mesh_eq(a, b)),
            media: old.media != new.media,
            grids: new_fields(&old.grid_media, &new.grid_media),
            grid_params: old.grid_media.len() != new.grid_media.len()
                || old
                    .grid_media
                    .iter()
                    .zip(&new.grid_media)
                    .any(|(a, b)| !grid_eq(a, b)),
        }
    }

    /// Whether the accumulated image is stale (anything but the exposure changed).
    pub fn restart(&self) -> bool {
        self.settings
            || self.camera
            || self.lights
            || self.materials
            || self.meshes
            || self.media
            || self.grid_params
            || !self.grids.is_empty()
    }

    /// The changed parts, comma-separated ("nothing" when none).
    pub fn describe(&self) -> String {
        let grids = format!("grid media {:?}", self.grids);
        let parts: Vec<&str> = [
            (self.settings, "settings"),
            (self.exposure, "exposure"),
            (self.camera, "camera"),
            (self.lights, "lights"),
            (self.materials, "materials"),
            (self.meshes, "meshes"),
            (self.media, "homogeneous media"),
            (!self.grids.is_empty(), grids.as_str()),
            (
                self.grid_params && self.grids.is_empty(),
                "grid medium parameters",
            ),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect();
        if parts.is_empty() {
            "nothing".into()
        } else {
            parts.join(", ")
        }
    }
}

fn mesh_eq(a: &Mesh, b: &Mesh) -> bool {
    a.name == b.name
        && a.material == b.material
        && a.positions == b.positions
        && a.normals == b.normals
        && a.triangles == b.triangles
}

fn grid_eq(a: &GridMedium, b: &GridMedium) -> bool {
    a.source_hash == b.source_hash && a.albedo == b.albedo && a.phase == b.phase
}

/// New grid media whose field (file bytes, grid, scale, transform) no old one has.
fn new_fields(old: &[GridMedium], new: &[GridMedium]) -> Vec<usize> {
    (0..new.len())
        .filter(|&i| !old.iter().any(|o| o.source_hash == new[i].source_hash))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Light;
    use glam::Vec3;

    fn scene() -> Scene {
        Scene {
            lights: vec![Light::Point {
                position: Vec3::Y,
                intensity: Vec3::ONE,
            }],
            ..Default::default()
        }
    }

    #[test]
    fn light_edit_is_only_a_light_change() {
        let s = RenderSettings::default();
        let (a, mut b) = (scene(), scene());
        assert_eq!(Changes::between(&a, &s, &b, &s).describe(), "nothing");
        assert!(!Changes::between(&a, &s, &b, &s).restart());
        b.lights[0] = Light::Point {
            position: Vec3::Y,
            intensity: Vec3::splat(2.0),
        };
        let c = Changes::between(&a, &s, &b, &s);
        assert_eq!(c.describe(), "lights");
        assert!(c.restart() && c.grids.is_empty());
    }

    #[test]
    fn exposure_alone_keeps_the_image() {
        let s = RenderSettings::default();
        let t = RenderSettings {
            exposure: 1.0,
            ..s.clone()
        };
        let c = Changes::between(&scene(), &s, &scene(), &t);
        assert!(c.exposure && !c.settings && !c.restart());
        let u = RenderSettings { seed: 9, ..t };
        assert!(Changes::between(&scene(), &s, &scene(), &u).restart());
    }
}
