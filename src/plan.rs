//! What pass i of a progressive render is: its global index, random stream, radii (eq. 3)
//! and light-path count, as a pure function of the settings and i. A pass therefore
//! renders the same wherever and whenever it runs: alone, inside a longer render, or on
//! another machine.
use crate::estimate::radius;

/// The fixed part of a render's passes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plan {
    /// Seed of every random stream (`[render].seed`).
    pub seed: u64,
    /// Radius reduction of eq. 3: beams, photons.
    pub alpha: f32,
    pub photon_alpha: f32,
    /// R1 of the beams and of the photons (m).
    pub beam_r1: f32,
    pub photon_r1: f32,
    /// R1 of the smooth photons (after a diffuse or medium scattering).
    pub smooth_photon_r1: f32,
    /// Light paths per pass.
    pub light_paths: usize,
    /// Passes in a group that share samples (a stratified transmittance block shares its
    /// jitter and free paths), 1 when passes are independent. Groups, not passes, are what
    /// the film's half-films interleave, so the halves stay independent.
    pub group: u32,
}

/// One pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassPlan {
    /// Global 1-based pass index: keys every random stream of the pass and its radii.
    pub index: u32,
    pub seed: u64,
    pub beam_radius: f32,
    pub photon_radius: f32,
    pub smooth_photon_radius: f32,
    /// Light paths traced (each an unbiased estimate whatever the count).
    pub light_paths: usize,
    /// Whether the pass is in an odd-numbered group of [`Plan::group`] passes: the
    /// film's second half-film.
    pub odd: bool,
}

impl Plan {
    /// Pass `index` (1-based) with all the light paths.
    pub fn pass(&self, index: u32) -> PassPlan {
        self.pass_with_paths(index, self.light_paths)
    }

    /// Pass `index` tracing `light_paths` paths (the watch ramp's shorter passes).
    pub fn pass_with_paths(&self, index: u32, light_paths: usize) -> PassPlan {
        PassPlan {
            index,
            seed: self.seed,
            beam_radius: radius::beam_radius(self.beam_r1, index, self.alpha),
            photon_radius: radius::photon_radius(self.photon_r1, index, self.photon_alpha),
            smooth_photon_radius: radius::photon_radius(
                self.smooth_photon_r1,
                index,
                self.photon_alpha,
            ),
            light_paths: light_paths.max(1),
            odd: ((index.max(1) - 1) / self.group.max(1)).is_multiple_of(2),
        }
    }
}

/// Light-path counts of the passes after a (re)start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ramp {
    /// Every pass traces all the light paths.
    Off,
    /// `ppb watch`'s ramp (see [`ramp_paths`]).
    Doubling,
}

/// Passes are kept near this long (s) by the ramp: an edit waits for at most one pass.
pub const PASS_TARGET: f64 = 0.3;

/// Light paths of pass `i` after a (re)start under the ramp, given the previous pass's
/// paths and seconds: 1/8 of the full count first, then doubled while a pass takes under
/// half of [`PASS_TARGET`], up to all of them. The first preview comes after a short pass
/// and, on a heavy scene, passes stay short so a save is never stuck behind a long one.
/// Every pass is an unbiased estimate whatever its path count, so the progressive mean
/// stays consistent; the count chosen is part of the pass's [`PassPlan`].
pub fn ramp_paths(full: usize, i: u32, last_paths: usize, last_seconds: f64) -> usize {
    if i <= 1 || last_paths == 0 {
        return (full >> 3).max(1);
    }
    if last_seconds < 0.5 * PASS_TARGET {
        (last_paths * 2).min(full)
    } else {
        last_paths.min(full)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fast passes double up to the full count; slow ones stay put.
    #[test]
    fn ramp_doubles_while_passes_are_short() {
        let (mut beams, mut seen) = (0, Vec::new());
        for i in 1..=5 {
            beams = ramp_paths(100_000, i, beams, 0.01);
            seen.push(beams);
        }
        assert_eq!(seen, [12_500, 25_000, 50_000, 100_000, 100_000]);
        assert_eq!(ramp_paths(3, 1, 0, 0.0), 1);
        assert_eq!(ramp_paths(100_000, 3, 25_000, 0.2), 25_000);
        assert_eq!(ramp_paths(100_000, 1, 25_000, 0.01), 12_500);
    }

    /// A pass is a function of the plan and its index alone.
    #[test]
    fn passes_follow_eq3_from_their_index() {
        let plan = Plan {
            seed: 3,
            alpha: 0.9,
            photon_alpha: 2.0 / 3.0,
            beam_r1: 0.5,
            photon_r1: 0.2,
            smooth_photon_r1: 0.6,
            light_paths: 1000,
            group: 1,
        };
        let p = plan.pass(2);
        assert_eq!(p, plan.pass(2));
        assert_eq!((p.index, p.seed, p.light_paths), (2, 3, 1000));
        assert!((p.beam_radius - 0.5 * 0.95).abs() < 1e-6);
        // Photons follow their own alpha: (1 + 2/3) / 2 for pass 2.
        assert!((p.photon_radius - 0.2 * (5.0f32 / 6.0).sqrt()).abs() < 1e-6);
        assert_eq!(plan.pass_with_paths(2, 0).light_paths, 1);
        // Half-films: odd passes, or odd-numbered groups of passes.
        assert_eq!([1, 2, 3].map(|i| plan.pass(i).odd), [true, false, true]);
        let blocks = Plan { group: 4, ..plan };
        assert_eq!(
            [1, 4, 5, 8, 9].map(|i| blocks.pass(i).odd),
            [true, true, false, false, true]
        );
    }
}
