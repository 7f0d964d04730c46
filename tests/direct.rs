//! The hybrid method's split of the light: next-event estimation takes the direct light,
//! photons and beams the rest. Light through glass must stay with the photons: under the
//! glass-caustic sphere the shadow rays see nothing, and the photons there are exactly
//! those of the pure method.
use glam::Vec3;
use std::path::Path;

use ppb::estimate::photons::Photons;
use ppb::geometry::Geometry;
use ppb::majorant::Mode;
use ppb::media::Media;
use ppb::sampling::Rng;
use ppb::scene::toml::load;
use ppb::transport::direct::Direct;
use ppb::transport::freepath::FreePath;
use ppb::transport::light::{LightSampler, LightTracer};
use ppb::transport::Counters;
use ppb::transport::SurfaceEstimate;

const RHO: Vec3 = Vec3::splat(0.5);

#[test]
fn light_through_glass_reaches_the_floor_only_through_photons() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/glass-caustic/scene.toml");
    let scene = load(&path).expect("scene loads").scene;
    let geometry = Geometry::new(&scene).expect("geometry");
    let media = Media::new(scene.media.clone());
    let bounds = geometry.bounds().expect("surfaces");
    let lights = LightSampler::new(&scene.lights, bounds);
    let free_path = FreePath {
        media: &media,
        mode: Mode::Adaptive,
    };
    let direct = Direct {
        lights: &lights,
        geometry: &geometry,
        free_path,
        samples: 1,
    };
    // (0, 0, 0) is in the shadow of the glass sphere (centre (0, 1, 0), radius 0.5) for
    // every point of the light (centre (0, 2.4, 0), radius 0.05); (1.5, 0, 0) is not.
    let (under, open) = (Vec3::ZERO, Vec3::new(1.5, 0.0, 0.0));
    let mut rng = Rng::new(3, 1);
    let mut c = Counters::default();
    let mut nee = |p: Vec3| -> f32 {
        (0..2000)
            .map(|_| direct.at_surface(p, Vec3::Y, RHO, &mut rng, &mut c).x)
            .sum()
    };
    assert_eq!(nee(under), 0.0, "a shadow ray got through glass");
    assert!(nee(open) > 0.0, "the open floor gets direct light");

    let photons = |skip_direct: bool| {
        let tracer = LightTracer {
            lights: &lights,
            geometry: &geometry,
            media: &media,
            support: &media.support(1.0),
            free_path,
            beam_radius: 0.01,
            smooth_beam_scale: 1.0,
            skip_direct,
        };
        let pass = tracer.trace_pass(7, 1, 200_000);
        // One radius for both kinds: the maps differ only in which photons they hold.
        (Photons::build(&pass.photons, 0.05, 0.05), pass.beams.len())
    };
    let ((hybrid, hybrid_beams), (pure, pure_beams)) = (photons(true), photons(false));
    let mut n = 0;
    let radiance = |m: &Photons, p: Vec3, n: &mut u64| m.radiance(p, Vec3::Y, RHO, n).l.x;
    // Under the glass: the caustic, the same photons whichever method traced them.
    let (h, p) = (
        radiance(&hybrid, under, &mut n),
        radiance(&pure, under, &mut n),
    );
    assert!(p > 0.0, "no caustic photons under the sphere");
    assert_eq!(h, p, "the hybrid lost or added photons under the glass");
    // In the open: the hybrid leaves the direct photons to NEE, so far less remains.
    let (h, p) = (
        radiance(&hybrid, open, &mut n),
        radiance(&pure, open, &mut n),
    );
    assert!(h < 0.5 * p, "direct photons kept: {h} vs {p}");
    // The light's first segments are not beams for the hybrid.
    assert!(hybrid_beams < pure_beams, "{hybrid_beams} vs {pure_beams}");
}
