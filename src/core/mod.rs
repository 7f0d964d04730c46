//! The ground floor: types and rules every layer uses and none owns ([`Ray`] and its one
//! box test, [`Rgb`] and the [`Nested`] kernel estimate, atomic file writes, the frame
//! token). Imports nothing of the crate
//! but [`crate::error`].
pub mod frames;
pub mod fs;
pub mod ray;
pub mod simd;

pub use ray::{ray_box, slab, Ray};

/// Linear RGB: radiance (W/(m^2 sr)), albedo or throughput per channel.
pub type Rgb = glam::Vec3;

/// floor(p) per component as integers, by truncation and a compare: without SSE4.1 (the
/// portable build) glam's `floor` is a libm call per component (`floorf` took 1.8 % of a
/// fog-box profile, from photon lookups and the splat's rows). Exact for |p| < 2^30;
/// beyond, clamped there.
#[inline]
pub fn floor_ivec3(p: glam::Vec3) -> glam::IVec3 {
    use glam::{IVec3, Vec3};
    let limit = Vec3::splat((1u32 << 30) as f32);
    let p = p.clamp(-limit, limit);
    let t = p.as_ivec3();
    t - IVec3::select(t.as_vec3().cmpgt(p), IVec3::ONE, IVec3::ZERO)
}

/// A kernel estimate at the pass radius r, and beside it the same estimate at r/2 minus
/// it: the nested radius whose difference estimates the kernel's bias (`film::error`).
/// The beams' 1D kernel is twice as high at r/2, the photons' 2D kernel four times: a
/// term l that counts at r/2 too adds (2 - 1) l or (4 - 1) l to the difference, one that
/// does not adds -l.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Nested {
    pub l: Rgb,
    pub d: Rgb,
}

impl Nested {
    /// Adds a beam term (`estimate::eq2::nested_term`): l, and whether it counts at r/2.
    pub fn add(&mut self, term: (Rgb, bool)) {
        self.add_in(term, 2.0);
    }

    /// Adds a term whose kernel at r/2 is `ratio` times as high as at r.
    pub fn add_in(&mut self, (l, inner): (Rgb, bool), ratio: f32) {
        self.l += l;
        self.d += if inner { (ratio - 1.0) * l } else { -l };
    }
}

impl std::ops::AddAssign for Nested {
    fn add_assign(&mut self, o: Nested) {
        self.l += o.l;
        self.d += o.d;
    }
}

impl std::ops::Mul<Nested> for Rgb {
    type Output = Nested;
    fn mul(self, n: Nested) -> Nested {
        Nested {
            l: self * n.l,
            d: self * n.d,
        }
    }
}
