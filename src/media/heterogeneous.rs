//! Heterogeneous media: a density grid placed in the world, sigma_t(x) = density_scale *
//! density(x) (trilinear), with its own albedo and phase function.
use glam::{DAffine3, DVec3, IVec3, Vec3};
use std::sync::Arc;

use super::grid::Grid;
use super::Phase;
use crate::core::ray_box;
use crate::core::Ray;
use crate::core::Rgb;
use crate::error::{Error, Result};
use crate::majorant::Mode;
use crate::majorant::{Field, LeafBounds, Octree};

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
    #[inline]
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

impl Field for GridMedium {
    fn bounds(&self) -> [Vec3; 2] {
        self.bounds
    }
    fn world_to_index(&self) -> DAffine3 {
        self.world_to_index
    }
    fn density_scale(&self) -> f32 {
        self.density_scale
    }
    fn fill_block(&self, lo: IVec3, hi: IVec3, out: &mut Vec<f32>) -> bool {
        self.grid.fill_block(lo, hi, out)
    }
    fn background(&self) -> f32 {
        self.grid.background
    }
    fn source_hash(&self) -> [u8; 32] {
        self.source_hash
    }
}

/// A grid medium ready for transport: its field and the majorant octree baked for it.
/// It cannot be made without its majorants, so nothing pairs media and octrees by their
/// position in a list (pbrt-v4's media own their majorant grids the same way).
#[derive(Clone, Debug)]
pub struct Heterogeneous {
    field: GridMedium,
    octree: Arc<Octree>,
}

impl std::ops::Deref for Heterogeneous {
    type Target = GridMedium;
    fn deref(&self) -> &GridMedium {
        &self.field
    }
}

impl Heterogeneous {
    /// `field` with an octree built for it (from the cache or just now); an octree over
    /// another box is refused.
    pub fn new(field: GridMedium, octree: Arc<Octree>) -> Result<Self> {
        let root = octree.root();
        let [lo, hi] = field.bounds;
        // The builder's box arithmetic may round the root's faces by an ulp or two.
        let tol = 1e-5 * (hi - lo).max_element().max(1e-6);
        let off = (Vec3::from(root.min) - lo)
            .abs()
            .max((Vec3::from(root.max) - hi).abs())
            .max_element();
        if off.is_nan() || off > tol {
            return Err(Error::Other(format!(
                "{}: the majorant octree covers {:?}..{:?}, the medium {:?}..{:?}",
                field.source, root.min, root.max, field.bounds[0], field.bounds[1]
            )));
        }
        Ok(Heterogeneous { field, octree })
    }

    /// `field` with its octree baked now (no cache), `depth` levels deep.
    pub fn build(field: GridMedium, depth: u32) -> Self {
        let octree = Arc::new(Octree::build(&field, depth));
        Heterogeneous { field, octree }
    }

    pub fn field(&self) -> &GridMedium {
        &self.field
    }

    pub fn octree(&self) -> &Octree {
        &self.octree
    }

    /// The majorant segments of the ray over [0, tmax], front to back, as `f(bounds, t0,
    /// t1)`, until `f` returns false: one segment at the global majorant (Woodcock), or
    /// the octree leaves the ray crosses (adaptive). Returns the segments visited.
    pub fn majorants(
        &self,
        ray: &Ray,
        tmax: f32,
        mode: Mode,
        mut f: impl FnMut(LeafBounds, f32, f32) -> bool,
    ) -> u64 {
        match mode {
            Mode::Woodcock => {
                let Some((t0, t1)) = self.interval(ray, tmax) else {
                    return 0;
                };
                let b = LeafBounds {
                    majorant: self.majorant(),
                    minorant: 0.0,
                };
                f(b, t0, t1);
                1
            }
            Mode::Adaptive => {
                let mut steps = 0;
                self.octree.walk(ray, tmax, |b, t0, t1| {
                    steps += 1;
                    f(b, t0, t1)
                });
                steps
            }
        }
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
        let m = leaf.values().fold(0.0f32, f32::max);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::grid::GridBuilder;
    use glam::IVec3;

    /// 8^3 voxels of density 1 + i, 0.1 m apart, shifted by `offset` (m) along x.
    fn field(offset: f64) -> GridMedium {
        let xf = DAffine3::from_translation(DVec3::new(offset, 0.0, 0.0))
            * DAffine3::from_scale(DVec3::splat(0.1));
        let mut b = GridBuilder::new("density", 0.0, xf);
        for i in 0..8 {
            for j in 0..8 {
                for k in 0..8 {
                    b.set(IVec3::new(i, j, k), 1.0 + i as f32, true);
                }
            }
        }
        let g = Arc::new(b.finish());
        let (one, name) = (Vec3::ONE, "test".to_string());
        GridMedium::new(
            g,
            DAffine3::IDENTITY,
            2.0,
            one,
            Phase::ISOTROPIC,
            name,
            [0; 32],
        )
    }

    /// A medium refuses an octree baked for another field's box; its own is accepted.
    #[test]
    fn a_medium_takes_only_its_own_majorants() {
        let (a, b) = (field(0.0), field(0.5));
        let other = Arc::new(Octree::build(&b, 3));
        let err = Heterogeneous::new(a.clone(), other)
            .unwrap_err()
            .to_string();
        assert!(err.contains("test") && err.contains("octree"), "{err}");
        assert!(Heterogeneous::new(a.clone(), Arc::new(Octree::build(&a, 3))).is_ok());
    }

    /// Woodcock hands out one segment at the global majorant over the medium's span; the
    /// octree's segments tile the same span, front to back, each bounding sigma_t.
    #[test]
    fn majorant_segments_cover_the_span() {
        let h = Heterogeneous::build(field(0.0), 3);
        let ray = Ray::new(
            Vec3::new(-1.0, 0.33, 0.41),
            Vec3::new(1.0, 0.02, 0.01).normalize(),
        );
        let (t0, t1) = h.interval(&ray, 10.0).expect("the ray crosses the medium");
        let mut global = Vec::new();
        let n = h.majorants(&ray, 10.0, Mode::Woodcock, |b, a, c| {
            global.push((b, a, c));
            true
        });
        assert_eq!(n, 1);
        assert_eq!(global[0].0.majorant, h.majorant());
        assert_eq!((global[0].1, global[0].2), (t0, t1));
        let mut leaves = Vec::new();
        let n = h.majorants(&ray, 10.0, Mode::Adaptive, |b, a, c| {
            leaves.push((b, a, c));
            true
        });
        assert!(n > 1 && n as usize == leaves.len());
        assert!((leaves[0].1 - t0).abs() < 1e-5 && (leaves[n as usize - 1].2 - t1).abs() < 1e-5);
        for w in leaves.windows(2) {
            assert!((w[0].2 - w[1].1).abs() < 1e-5, "segments are contiguous");
        }
        for (b, a, c) in &leaves {
            for k in 0..=8 {
                let t = a + (c - a) * k as f32 / 8.0;
                assert!(h.sigma_t(ray.at(t)) <= b.majorant * (1.0 + 1e-5));
            }
        }
        // Stopping early visits no more segments.
        let mut seen = 0;
        h.majorants(&ray, 10.0, Mode::Adaptive, |_, _, _| {
            seen += 1;
            false
        });
        assert_eq!(seen, 1);
    }
}
