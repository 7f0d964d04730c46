//! The beam estimate of one traced pass on the CPU: primary segments by splatting (cheapest
//! on a CPU, see `splat`), segments after specular bounces through the beam BVH. The GPU
//! path (`gpu::beams`) computes the same sums.
use rayon::prelude::*;
use std::time::Instant;

use super::beams::{BeamMap, MapNeed};
use super::eq2::BeamKernel;
use super::splat::splat;
use super::{beam_reach, Estimator, TracedPass, View};
use crate::core::simd;
use crate::core::Nested;
use crate::core::Rgb;
use crate::error::Result;
use crate::film::{Film, Held};
use crate::media::Media;
use crate::transport::camera::Secondary;
use crate::transport::transmittance::camera_tr;
use glam::Vec3;

/// The beam estimate on the CPU, added to the film pass by pass.
pub struct CpuBeams;

impl Estimator for CpuBeams {
    fn describe(&self) -> String {
        "cpu".into()
    }

    fn beam_map(&self) -> MapNeed {
        MapNeed::CPU
    }

    fn estimate(
        &mut self,
        view: View,
        t: &TracedPass,
        film: &mut Film,
        _traced: (Instant, Instant),
    ) -> Result<u64> {
        let (img, evals) = nested_beam_image(view, t);
        film.add_beams(t.odd, &img);
        Ok(evals)
    }

    fn held(&mut self) -> Result<Option<Held>> {
        Ok(None)
    }

    fn clear(&mut self) -> Result<()> {
        Ok(())
    }
}

/// Per-pixel beam radiance of a traced pass on the CPU alone (without the camera paths'
/// photon estimate) and the number of kernel evaluations.
pub fn beam_image(view: View, t: &TracedPass) -> (Vec<Rgb>, u64) {
    let (img, evals) = nested_beam_image(view, t);
    (img.par_iter().map(|n| n.l).collect(), evals)
}

/// [`beam_image`] with each pixel's nested half-radius difference.
pub fn nested_beam_image(view: View, t: &TracedPass) -> (Vec<Nested>, u64) {
    let View {
        camera,
        media,
        kernel,
    } = view;
    let (pass, beams, radius) = (&t.camera, &t.beams, t.beam_radius);
    let pixels = pass.primaries.len();
    if media.is_empty() || beams.is_empty() {
        return (vec![Nested::default(); pixels], 0);
    }
    let isa = simd::isa();
    let (mut img, mut evals) = splat(camera, &pass.primaries, beams, (radius, kernel), media, isa);
    if let Some(map) = &t.beam_map {
        let bounds = media.bounds();
        let per_segment: Vec<(Nested, u64)> = pass
            .secondary
            .par_iter()
            .map(|s| secondary_radiance(media, bounds.as_ref(), (map, kernel), s))
            .collect();
        for (s, (l, e)) in pass.secondary.iter().zip(per_segment) {
            img[s.pixel as usize] += l;
            evals += e;
        }
    }
    (img, evals)
}

/// beta times the beams' in-scattered radiance along one secondary segment.
fn secondary_radiance(
    media: &Media,
    bounds: Option<&[Vec3; 2]>,
    (map, kernel): (&BeamMap, BeamKernel),
    s: &Secondary,
) -> (Nested, u64) {
    let ray = &s.ray;
    let mut evals = 0;
    let mut l = Nested::default();
    if let Some(t1) = beam_reach(bounds, ray, s.tr.seen_until(s.t_surf)) {
        let tr = |t| camera_tr(&s.chords, &s.tr, t);
        let scatter = |x, cos| media.in_scatter(x, cos);
        l += map.nested_radiance(ray, (0.0, t1), kernel, scatter, tr, &mut evals);
    }
    (s.beta * l, evals)
}
