//! What a majorant octree is built over: a density field placed in the world. The media
//! that own octrees implement it ([`crate::media::GridMedium`]), so the builder and the
//! cache see voxels and a map, never a medium.
use glam::{DAffine3, IVec3, Vec3};

pub trait Field: Sync {
    /// World box outside which the field is its background (m).
    fn bounds(&self) -> [Vec3; 2];
    /// World to the grid's index space.
    fn world_to_index(&self) -> DAffine3;
    /// sigma_t per unit of voxel value (1/m).
    fn density_scale(&self) -> f32;
    /// The voxel values of the index box [lo, hi] (x slowest) into `out`; false, with `out`
    /// empty, when the box holds only background.
    fn fill_block(&self, lo: IVec3, hi: IVec3, out: &mut Vec<f32>) -> bool;
    /// Value of voxels no leaf or tile holds.
    fn background(&self) -> f32;
    /// blake3 of everything the field depends on: the octree cache's key.
    fn source_hash(&self) -> [u8; 32];
}
