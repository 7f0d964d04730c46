//! The checked values of the scene file's tables: `[render]`, materials, lights, the
//! camera.
use super::*;

pub(super) fn render_settings(ck: &Check, r: &FileRender) -> Result<RenderSettings> {
    let d = RenderSettings::default();
    let radius = |field: &str, v: &Option<FileRadius>| -> Result<Radius> {
        match v {
            None => Ok(Radius::Auto),
            Some(FileRadius::Word(w)) if w == "auto" => Ok(Radius::Auto),
            Some(FileRadius::Word(w)) => Err(ck.err(
                field,
                format!("expected \"auto\" or a radius in m, got \"{w}\""),
            )),
            Some(FileRadius::Value(x)) => Ok(Radius::Fixed(ck.positive(field, *x)?)),
        }
    };
    let s = RenderSettings {
        width: r.width.unwrap_or(d.width),
        height: r.height.unwrap_or(d.height),
        passes: r.passes.unwrap_or(d.passes),
        light_paths: r.light_paths.or(r.beams_per_pass).unwrap_or(d.light_paths),
        alpha: r.alpha.unwrap_or(d.alpha),
        photon_alpha: r.photon_alpha.unwrap_or(d.photon_alpha),
        beam_radius: radius("render.beam_radius", &r.beam_radius)?,
        photon_radius: radius("render.photon_radius", &r.photon_radius)?,
        smooth_photon_radius: radius("render.smooth_photon_radius", &r.smooth_photon_radius)?,
        seed: r.seed.unwrap_or(d.seed),
        exposure: r.exposure.unwrap_or(d.exposure),
        tr_samples: r.tr_samples.unwrap_or(d.tr_samples),
        nee_samples: r.nee_samples.unwrap_or(d.nee_samples),
        transparent: r.transparent.unwrap_or(d.transparent),
        tr_block: r.tr_block.unwrap_or(d.tr_block),
        tr_mode: ck.word(
            "render.transmittance",
            r.transmittance.as_deref(),
            d.tr_mode,
        )?,
        free_path: ck.word("render.free_path", r.free_path.as_deref(), d.free_path)?,
        method: ck.word("render.method", r.method.as_deref(), d.method)?,
        bandwidth: ck.word("render.bandwidth", r.bandwidth.as_deref(), d.bandwidth)?,
        beam_kernel: match r.beam_kernel.as_deref() {
            None | Some("auto") => None,
            Some(w) => Some(
                <BeamKernel as clap::ValueEnum>::from_str(w, false).map_err(|_| {
                    let msg = format!("expected auto, line or tube, got \"{w}\"");
                    ck.err("render.beam_kernel", msg)
                })?,
            ),
        },
        ..d
    };
    s.validate()
        .map_err(|e| ck.err(&format!("render.{}", e.field), e.msg))?;
    Ok(s)
}

pub(super) fn material(ck: &Check, i: usize, m: &FileMaterial) -> Result<NamedMaterial> {
    let f = |k: &str| format!("material[{i}].{k}");
    let (name, material) = match m {
        FileMaterial::Lambert { name, reflectance } => {
            let r = ck.nonneg3(&f("reflectance"), *reflectance)?;
            if r.max_element() > 1.0 {
                return Err(ck.err(
                    &f("reflectance"),
                    format!("expected values in [0, 1], got {reflectance:?}"),
                ));
            }
            (name, Material::Lambert { reflectance: r })
        }
        FileMaterial::Dielectric { name, ior } => {
            let ior = ck.positive(&f("ior"), ior.unwrap_or(1.5))?;
            (name, Material::Dielectric { ior })
        }
        FileMaterial::Mirror { name, reflectance } => {
            let r = ck.nonneg3(&f("reflectance"), reflectance.unwrap_or([1.0; 3]))?;
            (
                name,
                Material::Mirror {
                    reflectance: r.min(Vec3::ONE),
                },
            )
        }
    };
    Ok(NamedMaterial {
        name: name.clone(),
        material,
    })
}

pub(super) fn find_material(ck: &Check, scene: &Scene, i: usize, name: &str) -> Result<usize> {
    scene
        .materials
        .iter()
        .position(|m| m.name == name)
        .ok_or_else(|| {
            let known: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
            ck.err(
                &format!("mesh[{i}].material"),
                format!(
                    "unknown material \"{name}\" (defined: {})",
                    known.join(", ")
                ),
            )
        })
}

pub(super) fn light(ck: &Check, i: usize, l: &FileLight) -> Result<Light> {
    let f = |k: &str| format!("light[{i}].{k}");
    Ok(match l {
        FileLight::Point {
            position,
            intensity,
        } => Light::Point {
            position: ck.finite3(&f("position"), *position)?,
            intensity: ck.nonneg3(&f("intensity"), *intensity)?,
        },
        FileLight::Spot {
            position,
            direction,
            intensity,
            inner_deg,
            outer_deg,
        } => {
            let outer = ck.in_range(
                &f("outer_deg"),
                outer_deg.unwrap_or(45.0),
                0.01,
                180.0,
                "an angle in (0, 180] degrees",
            )?;
            let inner = ck.in_range(
                &f("inner_deg"),
                inner_deg.unwrap_or(0.0),
                0.0,
                outer,
                "an angle in [0, outer_deg]",
            )?;
            Light::Spot {
                position: ck.finite3(&f("position"), *position)?,
                direction: ck.unit3(&f("direction"), *direction)?,
                intensity: ck.nonneg3(&f("intensity"), *intensity)?,
                inner_deg: inner,
                outer_deg: outer,
            }
        }
        FileLight::Environment {
            radiance,
            map,
            rotation,
        } => {
            let radiance = match (radiance, map) {
                (Some(r), _) => ck.nonneg3(&f("radiance"), *r)?,
                (None, Some(_)) => Vec3::ONE,
                (None, None) => {
                    return Err(ck.err(
                        &f("radiance"),
                        "expected radiance = [r, g, b] (a constant sky) or a map".into(),
                    ))
                }
            };
            let rotation = match rotation {
                Some(r) => {
                    ck.in_range(&f("rotation"), *r, -360.0, 360.0, "degrees in [-360, 360]")?
                }
                None => 0.0,
            };
            Light::Environment(Environment::constant(radiance).turned_about_y(rotation))
        }
        FileLight::Sky {
            sun_elevation,
            sun_azimuth,
            turbidity,
            sun_size,
            radiance,
            resolution,
            ground,
        } => {
            let d = Sky::default();
            let sky = Sky {
                sun_elevation_deg: *sun_elevation,
                sun_azimuth_deg: sun_azimuth.unwrap_or(d.sun_azimuth_deg),
                turbidity: turbidity.unwrap_or(d.turbidity),
                sun_size_deg: sun_size.unwrap_or(d.sun_size_deg),
                ground: match ground {
                    Some(g) => ck.nonneg3(&f("ground"), *g)?.into(),
                    None => d.ground,
                },
            };
            sky.validate()
                .map_err(|(field, msg)| ck.err(&f(field), msg))?;
            let width = ck.in_range(
                &f("resolution"),
                resolution.unwrap_or(SKY_RESOLUTION) as f32,
                8.0,
                16384.0,
                "a map width in [8, 16384] texels",
            )? as usize;
            let height = width / 2;
            let texels = sky.bake(width, height);
            let name = format!(
                "Preetham sky, sun at {} deg elevation, {} deg azimuth, turbidity {}",
                sky.sun_elevation_deg, sky.sun_azimuth_deg, sky.turbidity
            );
            let map =
                EnvMap::new(width, height, &texels, &name).map_err(|m| ck.err(&f("type"), m))?;
            let radiance = match radiance {
                Some(r) => ck.nonneg3(&f("radiance"), *r)?,
                None => Vec3::ONE,
            };
            Light::Environment(Environment {
                map: Some(Arc::new(map)),
                ..Environment::constant(radiance)
            })
        }
        FileLight::Directional {
            direction,
            irradiance,
        } => Light::Directional {
            direction: ck.unit3(&f("direction"), *direction)?,
            irradiance: ck.nonneg3(&f("irradiance"), *irradiance)?,
        },
        FileLight::Sphere {
            center,
            radius,
            radiance,
        } => Light::Sphere {
            center: ck.finite3(&f("center"), *center)?,
            radius: ck.positive(&f("radius"), *radius)?,
            radiance: ck.nonneg3(&f("radiance"), *radiance)?,
        },
    })
}

pub(super) fn camera_from(ck: &Check, c: &FileCamera) -> Result<Camera> {
    let origin = ck.finite3("camera.origin", c.origin)?;
    let target = ck.finite3("camera.target", c.target)?;
    let up = ck.unit3("camera.up", c.up.unwrap_or([0.0, 1.0, 0.0]))?;
    if (target - origin).length_squared() == 0.0 {
        return Err(ck.err("camera.target", "must differ from camera.origin".into()));
    }
    if (target - origin).normalize().cross(up).length_squared() < 1e-8 {
        return Err(ck.err(
            "camera.up",
            "must not be parallel to the view direction".into(),
        ));
    }
    let vfov_deg = ck.in_range(
        "camera.vfov",
        c.vfov,
        0.01,
        179.0,
        "a vertical field of view in (0, 179] degrees",
    )?;
    Ok(Camera {
        origin,
        target,
        up,
        vfov_deg,
    })
}
pub(super) fn check_bounds(ck: &Check, field: &str, bounds: &[[f32; 3]; 2]) -> Result<[Vec3; 2]> {
    let lo = ck.finite3(field, bounds[0])?;
    let hi = ck.finite3(field, bounds[1])?;
    if !lo.cmplt(hi).all() {
        return Err(ck.err(
            field,
            format!("expected min < max on every axis, got {bounds:?}"),
        ));
    }
    Ok([lo, hi])
}

/// Texels across a baked sky map: 0.35 degrees each, about the real sun's diameter.
const SKY_RESOLUTION: u32 = 1024;

/// The lat-long map of environment light `i`, read through the load's file reader.
pub(super) fn environment_map(
    ck: &Check,
    i: usize,
    path: &Path,
    cache: &AssetCache,
) -> Result<Arc<EnvMap>> {
    let bytes = cache
        .files()
        .read(path)
        .map_err(|e| ck.err(&format!("light[{i}].map"), e.to_string()))?;
    Ok(Arc::new(EnvMap::decode(path, &bytes)?))
}
