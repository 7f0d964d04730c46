//! SphereLight, DistantLight and DomeLight in ppb's units (radiance = intensity x
//! 2^exposure x color), and the camera.
use super::*;

impl Ctx<'_> {
    /// `intensity * 2^exposure * color`, UsdLux's radiance (nits, read as W/(m^2 sr)).
    pub(super) fn lux_radiance(&self, p: &sdf::Path) -> Result<DVec3> {
        let i = self.f64_or(p, &["inputs:intensity", "intensity"], 1.0)?;
        let e = self.f64_or(p, &["inputs:exposure", "exposure"], 0.0)?;
        let c = self.vec3_or(p, &["inputs:color", "color"], DVec3::ONE)?;
        Ok(c * i * 2f64.powf(e))
    }

    /// SphereLight (radius fallback 0.5). Radiance `L` = [`Self::lux_radiance`], divided
    /// by the area 4 pi r^2 when `normalize` is on. World radius r = radius * the
    /// transform's mean scale, in metres.
    ///
    /// - `treatAsPoint` or r < [`POINT_LIGHT_RADIUS`]: `Light::Point` with the radiant
    ///   intensity the sphere would have, `L * pi * r^2` W/sr (for r = 0 exactly,
    ///   where that is zero, the intensity is read directly as W/sr).
    /// - otherwise `Light::Sphere` with radiance `L`.
    pub(super) fn sphere_light(&mut self, p: &sdf::Path) -> Result<()> {
        let mut l = self.lux_radiance(p)?;
        let r0 = self.f64_or(p, &["inputs:radius", "radius"], 0.5)?.max(0.0);
        let point = self.bool_or(p, "treatAsPoint", false)?;
        let normalize = self.bool_or(p, "inputs:normalize", false)?;
        let xf = self.world(p)?;
        let r = r0 * xf.determinant().abs().cbrt();
        if normalize && r > 0.0 {
            l /= 4.0 * PI * r * r;
        }
        let center = xf.transform_point3(DVec3::ZERO).as_vec3();
        let light = if point || r < POINT_LIGHT_RADIUS {
            let i = if r > 0.0 { l * PI * r * r } else { l };
            Light::Point {
                position: center,
                intensity: i.as_vec3(),
            }
        } else {
            Light::Sphere {
                center,
                radius: r as f32,
                radiance: l.as_vec3(),
            }
        };
        self.note(format!("imported SphereLight {p} as {light:?}"));
        self.out.lights.push(light);
        Ok(())
    }

    /// DistantLight: shines along the prim's world -Z. Its `intensity * 2^exposure *
    /// color` is taken as the irradiance (W/m^2) on a plane facing the light, i.e. as
    /// if `normalize` were on: the literal radiance over a 0.53 degree sun would give
    /// almost no light, and renderers (Karma, Cycles, RenderMan) normalize sun lights.
    pub(super) fn distant_light(&mut self, p: &sdf::Path) -> Result<()> {
        let e = self.lux_radiance(p)?;
        let xf = self.world(p)?;
        let d = xf.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
        if d == DVec3::ZERO {
            return Err(self.err(p, "the transform collapses the light direction"));
        }
        let light = Light::Directional {
            direction: d.as_vec3(),
            irradiance: e.as_vec3(),
        };
        self.note(format!("imported DistantLight {p} as {light:?}"));
        self.out.lights.push(light);
        Ok(())
    }

    /// DomeLight: radiance [`Self::lux_radiance`] times its lat-long texture, if any
    /// (`inputs:texture:file`, format `latlong` or `automatic`; UsdLux's lat-long is
    /// OpenEXR's, the same as ppb's), turned by the rotation of the prim's world
    /// transform (its scale dropped; a shear is an error). Other texture formats are
    /// left out with a note.
    pub(super) fn dome_light(&mut self, p: &sdf::Path) -> Result<()> {
        let radiance = self.lux_radiance(p)?.as_vec3();
        let to_world = self.dome_rotation(p)?;
        let names = ["inputs:texture:file", "texture:file"];
        let map = match names
            .iter()
            .find(|n| matches!(self.value(p, n), Ok(Some(_))))
        {
            None => None,
            Some(name) => {
                let format = match self.token(p, "inputs:texture:format")? {
                    Some(f) => Some(f),
                    None => self.token(p, "texture:format")?,
                };
                let format = format.unwrap_or_else(|| "automatic".into());
                if !matches!(format.as_str(), "automatic" | "latlong") {
                    self.note(format!(
                        "ignored DomeLight {p}: texture format \"{format}\" (only latlong maps are read)"
                    ));
                    return Ok(());
                }
                let file = self.asset_path(p, name)?;
                if self.probe {
                    if !file.is_file() {
                        return Err(
                            self.err(p, format!("{name}: {} does not exist", file.display()))
                        );
                    }
                    return Ok(());
                }
                let cannot = |e: Error| self.err(p, format!("{name}: cannot load the map: {e}"));
                let bytes = self.files.read(&file).map_err(cannot)?;
                let map = EnvMap::decode(&file, &bytes).map_err(cannot)?;
                self.out.files.push(file);
                Some(Arc::new(map))
            }
        };
        let light = Light::Environment(Environment {
            radiance,
            map,
            to_world,
        });
        self.note(format!("imported DomeLight {p} as {light:?}"));
        self.out.lights.push(light);
        Ok(())
    }

    /// The rotation of the prim's world transform: its columns normalised, which must
    /// then be orthonormal (a rotation, or a mirror, with any scale per axis).
    fn dome_rotation(&mut self, p: &sdf::Path) -> Result<glam::Mat3> {
        let m = glam::DMat3::from_mat4(self.world(p)?);
        let cols = [m.x_axis, m.y_axis, m.z_axis].map(|c| c.normalize_or_zero());
        let orthonormal = cols.iter().all(|c| c.length() > 0.5)
            && cols[0].dot(cols[1]).abs() < 1e-4
            && cols[1].dot(cols[2]).abs() < 1e-4
            && cols[0].dot(cols[2]).abs() < 1e-4;
        if !orthonormal {
            return Err(self.err(
                p,
                "the transform shears or collapses the dome (expected a rotation, with any scale)",
            ));
        }
        Ok(glam::DMat3::from_cols(cols[0], cols[1], cols[2]).as_mat3())
    }

    /// Camera: vfov = 2 atan(verticalAperture / (2 focalLength)) (fallbacks 15.2908 and
    /// 50, both in tenths of a scene unit, so their ratio is unit-free); looks down the
    /// prim's world -Z with world +Y up. Only the first camera is used.
    pub(super) fn camera(&mut self, p: &sdf::Path) -> Result<()> {
        if self.out.camera.is_some() {
            self.note(format!("ignored Camera {p}: only the first camera is used"));
            return Ok(());
        }
        let fl = self.f64_or(p, &["focalLength"], 50.0)?;
        let va = self.f64_or(p, &["verticalAperture"], 15.2908)?;
        if fl <= 0.0 || va <= 0.0 {
            return Err(self.err(p, "focalLength and verticalAperture must be > 0"));
        }
        if let Some(proj) = self.token(p, "projection")? {
            if proj != "perspective" {
                self.note(format!(
                    "camera {p}: projection {proj} rendered as perspective"
                ));
            }
        }
        let xf = self.world(p)?;
        let origin = xf.transform_point3(DVec3::ZERO);
        let fwd = xf.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
        let up = xf.transform_vector3(DVec3::Y).normalize_or_zero();
        if fwd == DVec3::ZERO || up == DVec3::ZERO {
            return Err(self.err(p, "the camera transform is degenerate"));
        }
        let vfov = 2.0 * (va / (2.0 * fl)).atan();
        let cam = Camera {
            origin: origin.as_vec3(),
            target: (origin + fwd).as_vec3(),
            up: up.as_vec3(),
            vfov_deg: vfov.to_degrees() as f32,
        };
        self.out.camera = Some(cam);
        self.note(format!(
            "imported Camera {p} (vfov {:.3} deg)",
            cam.vfov_deg
        ));
        Ok(())
    }

    // ---- volumes ------------------------------------------------------------------
}
