//! Heterogeneous media: a density grid placed in the world, sigma_t(x) = density_scale *
//! density(x) (trilinear), with its own albedo and phase function.
use glam::{DAffine3, DVec3, Vec3};
use std::sync::Arc;

use super::grid::Grid;
use super::Phase;
use crate::geometry::Ray;
use crate::media::homogeneous::ray_box;
use crate::scene::Rgb;

#[derive(Clone, Debug)]
pub struct GridMedium {
    pub grid: Arc<Grid>,
    /// World to the grid's index space (the file's map and the scene's transform).
    pub world_to_index: DAffine3,
    pub density_scale: f32,
    pub albedo: Rgb,
    pub phase: Phase,
    /// World box outside which the density is the background 0.
    pub bounds: [Vec3; 2],
    /// Largest voxel value: trilinear interpolation never exceeds it.
    pub max_density: f32,
    /// Where the grid came from, for `ppb info` and errors.
    pub source: String,
    /// blake3 of everything the field depends on (file bytes, grid name, scale,
    /// transform, or procedural parameters): the octree cache key.
    pub source_hash: [u8; 32],
}

impl GridMedium {
    /// Places `grid` with an extra world transform applied after its index-to-world map.
    pub fn new(
        grid: Arc<Grid>,
        transform: DAffine3,
        density_scale: f32,
        albedo: Rgb,
        phase: Phase,
        source: String,
        source_hash: [u8; 32],
    ) -> Self {
        let index_to_world = transform * grid.index_to_world;
        let (max_density, bounds) = extent(&grid, &index_to_world);
        GridMedium {
            world_to_index: index_to_world.inverse(),
            grid,
            density_scale,
            albedo,
            phase,
            bounds,
            max_density,
            source,
            source_hash,
        }
    }

    /// Extinction (1/m) at a world point.
    pub fn sigma_t(&self, p: Vec3) -> f32 {
        if p.cmplt(self.bounds[0]).any() || p.cmpgt(self.bounds[1]).any() {
            return 0.0;
        }
        let q = self.world_to_index.transform_point3(p.as_dvec3());
        self.density_scale * self.grid.sample_index(q).max(0.0)
    }

    /// A constant that bounds sigma_t everywhere (1/m).
    pub fn majorant(&self) -> f32 {
        self.density_scale * self.max_density
    }

    pub fn interval(&self, ray: &Ray, tmax: f32) -> Option<(f32, f32)> {
        ray_box(ray, &self.bounds, 0.0, tmax)
    }
}

/// Max voxel value and the world box of all non-background voxels, padded by one voxel
/// (the trilinear support).
fn extent(grid: &Grid, index_to_world: &DAffine3) -> (f32, [Vec3; 2]) {
    let mut max = grid.background.max(0.0);
    let mut lo = DVec3::splat(f64::MAX);
    let mut hi = DVec3::splat(f64::MIN);
    let mut grow = |a: DVec3, b: DVec3| {
        lo = lo.min(a);
        hi = hi.max(b);
    };
    for (origin, leaf) in grid.leaves() {
        let m = leaf.values.iter().fold(0.0f32, |a, &v| a.max(v));
        if m > 0.0 {
            max = max.max(m);
            grow(origin.as_dvec3(), (origin + 7).as_dvec3());
        }
    }
    for t in grid.tiles().iter().filter(|t| t.value > 0.0) {
        max = max.max(t.value);
        grow(t.min.as_dvec3(), t.max.as_dvec3());
    }
    if lo.x > hi.x {
        return (max, [Vec3::ZERO, Vec3::ZERO]);
    }
    let (lo, hi) = (lo - 1.0, hi + 1.0);
    let mut wlo = DVec3::splat(f64::MAX);
    let mut whi = DVec3::splat(f64::MIN);
    for c in 0..8 {
        let corner = DVec3::new(
            if c & 1 == 0 { lo.x } else { hi.x },
            if c & 2 == 0 { lo.y } else { hi.y },
            if c & 4 == 0 { lo.z } else { hi.z },
        );
        let w = index_to_world.transform_point3(corner);
        wlo = wlo.min(w);
        whi = whi.max(w);
    }
    (max, [wlo.as_vec3(), whi.as_vec3()])
}
