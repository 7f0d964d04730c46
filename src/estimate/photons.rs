//! Surface photon maps of one pass: a hashed uniform grid with cells twice as wide as the
//! lookup radius, so a lookup's ball touches 2 cells along each axis (3 at most): 8
//! hashed reads where cells as wide as the radius took 27, most of them empty with the
//! few photons of a pass (cloud-hg: about 1,000). Photons are counting-sorted by cell,
//! which keeps the order (and the float sums) independent of the thread count. Sharp photons
//! (direct light and caustics) and smooth ones (after a diffuse or medium scattering)
//! go to two maps with their own radii: smooth light tolerates a wider kernel, which
//! lowers its noise, while a caustic's edges need the narrow one.
use glam::{IVec3, Vec3};

use crate::core::{floor_ivec3, Nested, Rgb};
use crate::transport::{Photon, SurfaceEstimate};

pub struct PhotonMap {
    photons: Vec<Photon>,
    /// Start of each hash bucket in `photons`; `len() == buckets + 1`.
    starts: Vec<u32>,
    mask: u64,
    cell: f32,
    radius: f32,
}

fn hash(c: IVec3) -> u64 {
    let h = (c.x as i64 as u64).wrapping_mul(73_856_093)
        ^ (c.y as i64 as u64).wrapping_mul(19_349_663)
        ^ (c.z as i64 as u64).wrapping_mul(83_492_791);
    crate::sampling::mix64(h)
}

impl PhotonMap {
    pub fn build(photons: &[Photon], radius: f32) -> Self {
        let buckets = (photons.len() * 2).next_power_of_two().max(64);
        let mask = buckets as u64 - 1;
        let cell = 2.0 * radius;
        let key = |p: &Photon| (hash(cell_of(Vec3::from(p.position), cell)) & mask) as usize;
        let mut starts = vec![0u32; buckets + 1];
        for p in photons {
            starts[key(p) + 1] += 1;
        }
        for i in 0..buckets {
            starts[i + 1] += starts[i];
        }
        let mut fill = starts.clone();
        let mut sorted = vec![Photon::default(); photons.len()];
        for p in photons {
            let k = key(p);
            sorted[fill[k] as usize] = *p;
            fill[k] += 1;
        }
        PhotonMap {
            photons: sorted,
            starts,
            mask,
            cell,
            radius,
        }
    }

    /// Reflected radiance at `x` seen from the side of `n` for a Lambert surface with
    /// reflectance `rho`: (rho / pi) * sum(power) / (pi r^2) over photons within r that
    /// arrived on the same side (a normalized 2D box kernel).
    pub fn radiance(&self, x: Vec3, n: Vec3, rho: Rgb, lookups: &mut u64) -> Rgb {
        self.nested_radiance(x, n, rho, lookups).l
    }

    /// [`Self::radiance`] and its nested half-radius difference ([`Nested`]).
    pub fn nested_radiance(&self, x: Vec3, n: Vec3, rho: Rgb, lookups: &mut u64) -> Nested {
        *lookups += 1;
        let mut sum = Nested::default();
        if self.photons.is_empty() {
            return sum;
        }
        let r2 = self.radius * self.radius;
        let (lo, hi) = ball_cells(x, self.radius, self.cell);
        let mut seen = [u64::MAX; 27];
        let mut k = 0;
        // Bit b mod 64 of each bucket read: the list is searched only when that bit is
        // set.
        let mut seen_bits = 0u64;
        for z in lo.z..=hi.z {
            for y in lo.y..=hi.y {
                for x_cell in lo.x..=hi.x {
                    let b = hash(IVec3::new(x_cell, y, z)) & self.mask;
                    // Two cells may share a bucket: read each bucket once.
                    let bit = 1u64 << (b & 63);
                    if seen_bits & bit != 0 && seen[..k].contains(&b) {
                        continue;
                    }
                    seen_bits |= bit;
                    seen[k] = b;
                    k += 1;
                    let (s, e) = (self.starts[b as usize], self.starts[b as usize + 1]);
                    for p in &self.photons[s as usize..e as usize] {
                        let d2 = (Vec3::from(p.position) - x).length_squared();
                        if d2 < r2 && Vec3::from(p.normal).dot(n) > 0.5 {
                            sum.add_in((Vec3::from(p.power), 4.0 * d2 < r2), 4.0);
                        }
                    }
                }
            }
        }
        rho / (std::f32::consts::PI * std::f32::consts::PI * r2) * sum
    }
}

/// A pass's surface photons: the sharp ones and the smooth ones, each with its radius.
pub struct Photons {
    sharp: PhotonMap,
    smooth: PhotonMap,
}

impl SurfaceEstimate for Photons {
    /// The sum of both maps' estimates (see [`PhotonMap::nested_radiance`]).
    fn radiance(&self, x: Vec3, n: Vec3, rho: Rgb, lookups: &mut u64) -> Nested {
        let mut sum = self.sharp.nested_radiance(x, n, rho, lookups);
        sum += self.smooth.nested_radiance(x, n, rho, lookups);
        sum
    }
}

impl Photons {
    pub fn build(photons: &[Photon], sharp_radius: f32, smooth_radius: f32) -> Self {
        let (smooth, sharp): (Vec<Photon>, Vec<Photon>) =
            photons.iter().partition(|p| p.smooth != 0);
        Photons {
            sharp: PhotonMap::build(&sharp, sharp_radius),
            smooth: PhotonMap::build(&smooth, smooth_radius),
        }
    }
}

fn cell_of(p: Vec3, cell: f32) -> IVec3 {
    floor_ivec3(p / cell)
}

/// The cells the ball of radius `r` around `x` can reach, as the lowest and highest cell
/// along each axis: 2 per axis (cells are 2 r wide), 3 where the ball's box, widened
/// against rounding by a part in 10^4 of r and a few ulps of x, touches a third (never
/// more: a lookup reads at most 27 cells).
fn ball_cells(x: Vec3, r: f32, cell: f32) -> (IVec3, IVec3) {
    let reach = Vec3::splat(r * 1.0001 + x.abs().max_element() * 4.0 * f32::EPSILON);
    let lo = cell_of(x - reach, cell);
    (lo, cell_of(x + reach, cell).min(lo + 2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// Uniform photons of total power P on a plane of area A give irradiance P/A, so
    /// radiance rho/pi * P/A; the box-kernel estimate is unbiased away from the edges.
    /// `n` photons of total power `total`, uniform over the `side` x `side` square of the
    /// plane y = 0 (stream `seed`); every other one smooth when `split`.
    fn uniform_photons(seed: u64, n: usize, side: f32, total: f32, split: bool) -> Vec<Photon> {
        let mut rng = Rng::new(seed, 3);
        (0..n)
            .map(|i| {
                let u = rng.vec2() * side;
                let p = Vec3::new(u.x, 0.0, u.y);
                Photon::new(
                    p,
                    Vec3::Y,
                    Vec3::splat(total / n as f32),
                    split && i % 2 == 0,
                )
            })
            .collect()
    }

    #[test]
    fn uniform_irradiance_estimate() {
        let (n, side, total) = (400_000, 4.0f32, 10.0f32);
        let photons = uniform_photons(3, n, side, total, false);
        let r = 0.1;
        let map = PhotonMap::build(&photons, r);
        let rho = Vec3::splat(0.5);
        let expect = 0.5 / std::f32::consts::PI * total / (side * side);
        let mut lookups = 0;
        let mut mean = 0.0;
        let m = 50;
        for i in 0..m {
            let x = Vec3::new(1.0 + 0.04 * i as f32, 0.0, 2.0);
            mean += map.radiance(x, Vec3::Y, rho, &mut lookups).x / m as f32;
        }
        // Photons per disc: n * pi r^2 / A = 785, so one estimate's rel. sd is 1/sqrt(785)
        // = 3.6 %; the 50 overlapping lookups are correlated, so bound by 5 single sd.
        assert!(
            (mean / expect - 1.0).abs() < 5.0 * 0.036,
            "{mean} vs {expect}"
        );
        // The other side of the surface sees nothing.
        assert_eq!(
            map.radiance(Vec3::new(2.0, 0.0, 2.0), -Vec3::Y, rho, &mut lookups),
            Vec3::ZERO
        );
    }

    /// The nested difference of a 2D kernel: zero on average where the irradiance is
    /// even, and at the edge of a lit half-plane the sign of the blur's bias. Just
    /// outside the edge (0.75 r from it) no photon is within r/2, so the difference is
    /// exactly -L; just inside, the r/2 disc is all lit while the r one is not, so the
    /// difference is positive. Bounds: 5 single-lookup sds of the r/2 estimate (twice the
    /// r one's 3.6 %, its disc holding a quarter of the photons).
    #[test]
    fn nested_difference_of_the_photon_kernel() {
        let (n, side, total, r) = (400_000, 4.0f32, 10.0f32, 0.1f32);
        let photons = uniform_photons(4, n, side, total, false);
        let rho = Vec3::splat(0.5);
        let expect = 0.5 / std::f32::consts::PI * total / (side * side);
        let even = PhotonMap::build(&photons, r);
        let mut lookups = 0;
        let m = 50;
        let d: f32 = (0..m)
            .map(|i| {
                let x = Vec3::new(1.0 + 0.04 * i as f32, 0.0, 2.0);
                even.nested_radiance(x, Vec3::Y, rho, &mut lookups).d.x / m as f32
            })
            .sum();
        assert!(d.abs() < 5.0 * 0.072 * expect, "{d} vs 0");
        let half: Vec<Photon> = photons
            .into_iter()
            .filter(|p| p.position[0] < 2.0)
            .collect();
        let edge = PhotonMap::build(&half, r);
        let mut at =
            |x: f32| edge.nested_radiance(Vec3::new(x, 0.0, 2.0), Vec3::Y, rho, &mut lookups);
        let outside = at(2.0 + 0.75 * r);
        assert!(outside.l.x > 0.0 && outside.d == -outside.l, "{outside:?}");
        let inside = at(2.0 - 0.75 * r);
        assert!(inside.d.x > 0.0, "{inside:?}");
    }

    /// A lookup sums each photon within r once, however its cells fall into buckets:
    /// against a sum over all photons, with 64 buckets (cells share buckets at many
    /// lookups) and with a table too big for that.
    #[test]
    fn lookups_read_each_photon_within_r_once() {
        let mut rng = Rng::new(11, 2);
        let mut v = || Vec3::new(rng.f32(), rng.f32(), rng.f32());
        let r = 0.25;
        for n in [20, 3000] {
            let photons: Vec<Photon> = (0..n)
                .map(|_| {
                    let p = (v() - Vec3::splat(0.5)) * 2.0;
                    Photon::new(p, Vec3::Y, v() + Vec3::splat(0.1), false)
                })
                .collect();
            let map = PhotonMap::build(&photons, r);
            let mut shared = 0;
            for _ in 0..300 {
                let x = (v() - Vec3::splat(0.5)) * 2.0;
                let (lo, hi) = ball_cells(x, r, map.cell);
                let cells = (hi - lo + IVec3::ONE).element_product() as usize;
                let mut buckets: Vec<u64> = (lo.z..=hi.z)
                    .flat_map(|z| {
                        (lo.y..=hi.y)
                            .flat_map(move |y| (lo.x..=hi.x).map(move |x| IVec3::new(x, y, z)))
                    })
                    .map(|c| hash(c) & map.mask)
                    .collect();
                buckets.sort();
                buckets.dedup();
                shared += usize::from(buckets.len() < cells);
                let mut brute = Vec3::ZERO;
                for p in &photons {
                    if (Vec3::from(p.position) - x).length_squared() < r * r {
                        brute += Vec3::from(p.power);
                    }
                }
                let brute = Vec3::ONE / (std::f32::consts::PI.powi(2) * r * r) * brute;
                let got = map.radiance(x, Vec3::Y, Vec3::ONE, &mut 0);
                assert!(
                    (got - brute).abs().max_element() <= 1e-5 * brute.max_element().max(1.0),
                    "{got} vs {brute}"
                );
            }
            // The small table shares buckets at many lookups (8 cells in 64 buckets: 37 %,
            // 110 of 300, sd 8.4), the big one at few.
            if n == 20 {
                assert!(shared > 60, "{shared}");
            }
        }
    }

    /// Split maps: half the photons smooth, half sharp, uniform over the plane; the two
    /// maps' estimates add up to the irradiance of all, each with its own radius (the
    /// bound as above, for the 4x smaller photon count of the sharp half's disc).
    #[test]
    fn split_maps_add_up() {
        let (n, side, total) = (400_000, 4.0f32, 10.0f32);
        let photons = uniform_photons(5, n, side, total, true);
        let maps = Photons::build(&photons, 0.1, 0.3);
        let expect = 0.5 / std::f32::consts::PI * total / (side * side);
        let mut lookups = 0;
        let m = 50;
        let mean: f32 = (0..m)
            .map(|i| {
                let x = Vec3::new(1.0 + 0.04 * i as f32, 0.0, 2.0);
                maps.radiance(x, Vec3::Y, Vec3::splat(0.5), &mut lookups)
                    .l
                    .x
                    / m as f32
            })
            .sum();
        assert!(
            (mean / expect - 1.0).abs() < 5.0 * 0.05,
            "{mean} vs {expect}"
        );
        assert_eq!(lookups, 2 * m);
        // The smooth map alone holds half the power.
        let half = maps.smooth.radiance(
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::Y,
            Vec3::splat(0.5),
            &mut lookups,
        );
        assert!((half.x / (0.5 * expect) - 1.0).abs() < 5.0 * 0.02, "{half}");
    }
}
