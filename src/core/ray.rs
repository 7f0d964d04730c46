//! Rays and the ray-box slab test, with the one 1/d rule the CPU and the WGSL share.
use glam::Vec3;

#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub o: Vec3,
    /// Unit direction.
    pub d: Vec3,
}

/// Smallest |d| a direction component keeps in [`Ray::inv_d`]; smaller ones (zero
/// included) become +MIN_DIR, so no slab product is 0 * inf = NaN.
pub const MIN_DIR: f32 = 1e-30;

impl Ray {
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Ray { o, d }
    }

    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }

    /// 1/d per component, a component under [`MIN_DIR`] in magnitude taken as +`MIN_DIR`
    /// (`safe_inv` in `shaders/media.wgsl` is the same rule). A ray parallel to an axis
    /// is then slab-tested as if tilted a hair towards +axis: never NaN, and one lying in
    /// a face's plane is inside the box whose lower face that is and outside the box whose
    /// upper face it is, so two boxes sharing the face count it once.
    #[inline]
    pub fn inv_d(&self) -> Vec3 {
        Vec3::select(
            self.d.abs().cmplt(Vec3::splat(MIN_DIR)),
            Vec3::splat(MIN_DIR),
            self.d,
        )
        .recip()
    }
}

/// Parametric overlap of the ray (`o`, `inv` = [`Ray::inv_d`]) with the box [lo, hi],
/// clipped to [t0, t1]; `None` when empty. For loops that reuse one `inv`.
#[inline]
pub fn slab(o: Vec3, inv: Vec3, lo: Vec3, hi: Vec3, t0: f32, t1: f32) -> Option<(f32, f32)> {
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let near = a.min(b).max_element().max(t0);
    let far = a.max(b).min_element().min(t1);
    (near < far).then_some((near, far))
}

/// Parametric overlap of `ray` with the box `b`, clipped to [tmin, tmax].
#[inline]
pub fn ray_box(ray: &Ray, b: &[Vec3; 2], tmin: f32, tmax: f32) -> Option<(f32, f32)> {
    slab(ray.o, ray.inv_d(), b[0], b[1], tmin, tmax)
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT: [Vec3; 2] = [Vec3::ZERO, Vec3::ONE];

    #[test]
    fn rays_parallel_to_a_face() {
        let along_x = |o: Vec3| ray_box(&Ray::new(o, Vec3::X), &UNIT, 0.0, 10.0);
        // Inside the slab of the zero components: the x extent.
        assert_eq!(along_x(Vec3::new(-1.0, 0.5, 0.5)), Some((1.0, 2.0)));
        // Outside it: no overlap, however far the ray runs.
        assert_eq!(along_x(Vec3::new(-1.0, 1.5, 0.5)), None);
        assert_eq!(along_x(Vec3::new(-1.0, 0.5, -0.1)), None);
        // In a lower face's plane: inside; in an upper face's plane: outside, so a box
        // sharing that face with the first counts the ray instead.
        assert_eq!(along_x(Vec3::new(-1.0, 0.0, 0.5)), Some((1.0, 2.0)));
        assert_eq!(along_x(Vec3::new(-1.0, 1.0, 0.5)), None);
        assert_eq!(along_x(Vec3::new(-1.0, 0.5, 1.0)), None);
        let above = [Vec3::new(0.0, 1.0, 0.0), Vec3::new(1.0, 2.0, 1.0)];
        let r = Ray::new(Vec3::new(-1.0, 1.0, 0.5), Vec3::X);
        assert_eq!(ray_box(&r, &above, 0.0, 10.0), Some((1.0, 2.0)));
        // Negative zero components and reversed direction.
        let r = Ray::new(Vec3::new(3.0, 0.5, 0.5), Vec3::new(-1.0, -0.0, 0.0));
        assert_eq!(ray_box(&r, &UNIT, 0.0, 10.0), Some((2.0, 3.0)));
        assert!(r.inv_d().is_finite());
    }

    #[test]
    fn clipped_to_the_interval() {
        let r = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z);
        assert_eq!(ray_box(&r, &UNIT, 0.0, 1.5), Some((1.0, 1.5)));
        assert_eq!(ray_box(&r, &UNIT, 0.0, 0.5), None);
        assert_eq!(ray_box(&r, &UNIT, 1.25, 10.0), Some((1.25, 2.0)));
    }
}
