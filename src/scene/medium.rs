//! Medium parameters: one set of defaults and checks for every source. A TOML
//! `[[medium]]` table and a USD Volume prim's `ppb:*` attributes are each turned into a
//! [`MediumSpec`] (the values as written, absent ones `None`), and
//! [`MediumSpec::check`] turns that into [`MediumParams`] or an error naming the file,
//! the field in the source's own spelling, and what was expected.
use std::path::Path;

use glam::{DAffine3, DQuat, DVec3, EulerRot, Vec3};

use super::Rgb;
use crate::error::{Error, Result};
use crate::media::Phase;

/// One medium parameter, for naming it in errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    DensityScale,
    SigmaT,
    Albedo,
    G,
    Transform,
}

impl Param {
    /// The key in a TOML `[[medium]]` table.
    pub fn toml_key(self) -> &'static str {
        match self {
            Param::DensityScale => "density_scale",
            Param::SigmaT => "sigma_t",
            Param::Albedo => "albedo",
            Param::G => "phase.g",
            Param::Transform => "transform",
        }
    }

    /// The attribute on a USD Volume prim (the transform is the prim's xformOps).
    pub fn usd_attr(self) -> &'static str {
        match self {
            Param::DensityScale => "ppb:densityScale",
            Param::SigmaT => "ppb:sigmaT",
            Param::Albedo => "ppb:albedo",
            Param::G => "ppb:g",
            Param::Transform => "xformOpOrder",
        }
    }
}

/// Field names of the TOML table `medium[i]`: `medium[0].albedo`.
pub fn toml_field(i: usize) -> impl Fn(Param) -> String {
    move |p| format!("medium[{i}].{}", p.toml_key())
}

/// Field names on the USD prim `prim` (property paths): `/World/Smoke.ppb:albedo`.
pub fn usd_field(prim: impl std::fmt::Display) -> impl Fn(Param) -> String {
    let prim = prim.to_string();
    move |p| format!("{prim}.{}", p.usd_attr())
}

/// A placement as a source spells it.
#[derive(Clone, Debug, PartialEq)]
pub enum TransformSpec {
    /// translate * rotate (X, then Y, then Z, degrees) * uniform scale: TOML `transform`.
    Srt {
        translate: Option<[f64; 3]>,
        rotate_deg: Option<[f64; 3]>,
        scale: Option<f64>,
    },
    /// A composed matrix: a USD prim's world transform.
    Matrix(DAffine3),
}

/// Medium parameters as a source gives them; `None` takes [`MediumParams::default`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MediumSpec {
    /// Multiplies grid values into extinction (1/m).
    pub density_scale: Option<f32>,
    /// Extinction of a homogeneous medium (1/m).
    pub sigma_t: Option<f32>,
    pub albedo: Option<[f32; 3]>,
    /// Henyey-Greenstein g; none is isotropic.
    pub g: Option<f32>,
    /// Applied after a grid's own index-to-world map.
    pub transform: Option<TransformSpec>,
}

/// Checked medium parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MediumParams {
    /// Finite, >= 0 (default 1).
    pub density_scale: f32,
    /// Finite, >= 0 (default 0; the TOML schema requires it where it is used).
    pub sigma_t: f32,
    /// Each channel in [0, 1] (default 0.9 grey).
    pub albedo: Rgb,
    /// g in [-0.999, 0.999] (default isotropic).
    pub phase: Phase,
    /// Finite and invertible (default identity).
    pub transform: DAffine3,
}

impl Default for MediumParams {
    fn default() -> Self {
        MediumParams {
            density_scale: 1.0,
            sigma_t: 0.0,
            albedo: Vec3::splat(0.9),
            phase: Phase::ISOTROPIC,
            transform: DAffine3::IDENTITY,
        }
    }
}

impl MediumSpec {
    /// Checks every given value; errors are `file: field(param): expected ..., got ...`.
    pub fn check(&self, file: &Path, field: impl Fn(Param) -> String) -> Result<MediumParams> {
        let err = |p: Param, msg: String| Error::field(file, field(p), msg);
        let d = MediumParams::default();
        let nonneg = |p: Param, x: Option<f32>, default: f32, what: &str| match x {
            None => Ok(default),
            Some(x) if x.is_finite() && x >= 0.0 => Ok(x),
            Some(x) => Err(err(p, format!("expected {what}, got {x}"))),
        };
        let density_scale = nonneg(
            Param::DensityScale,
            self.density_scale,
            d.density_scale,
            "a finite number >= 0",
        )?;
        let sigma_t = nonneg(
            Param::SigmaT,
            self.sigma_t,
            d.sigma_t,
            "a finite number >= 0 (1/m)",
        )?;
        let albedo = match self.albedo {
            None => d.albedo,
            Some(a) if !a.iter().all(|x| x.is_finite() && *x >= 0.0) => {
                let msg = format!("expected finite numbers >= 0, got {a:?}");
                return Err(err(Param::Albedo, msg));
            }
            Some(a) if a.iter().any(|x| *x > 1.0) => {
                let msg = format!("expected values in [0, 1], got {a:?}");
                return Err(err(Param::Albedo, msg));
            }
            Some(a) => Vec3::from(a),
        };
        let phase = match self.g {
            None => d.phase,
            Some(g) if g.is_finite() && (-0.999..=0.999).contains(&g) => Phase { g },
            Some(g) => return Err(err(Param::G, format!("expected g in (-1, 1), got {g}"))),
        };
        let transform = match &self.transform {
            None => d.transform,
            Some(t) => transform(t).map_err(|m| err(Param::Transform, m))?,
        };
        Ok(MediumParams {
            density_scale,
            sigma_t,
            albedo,
            phase,
            transform,
        })
    }
}

fn transform(t: &TransformSpec) -> std::result::Result<DAffine3, String> {
    match *t {
        TransformSpec::Srt {
            translate,
            rotate_deg,
            scale,
        } => {
            let tr = translate.unwrap_or([0.0; 3]);
            let rot = rotate_deg.unwrap_or([0.0; 3]);
            let scale = scale.unwrap_or(1.0);
            let finite = tr.iter().chain(rot.iter()).all(|v| v.is_finite());
            if !(finite && scale.is_finite() && scale > 0.0) {
                return Err("expected finite translate/rotate_deg and a scale > 0".into());
            }
            let q = DQuat::from_euler(
                EulerRot::ZYX,
                rot[2].to_radians(),
                rot[1].to_radians(),
                rot[0].to_radians(),
            );
            Ok(DAffine3::from_scale_rotation_translation(
                DVec3::splat(scale),
                q,
                DVec3::from(tr),
            ))
        }
        TransformSpec::Matrix(m) => {
            let det = m.matrix3.determinant();
            if m.is_finite() && det.is_finite() && det != 0.0 {
                Ok(m)
            } else {
                Err("expected a finite, invertible transform".into())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_fill_what_a_source_leaves_out() {
        let p = MediumSpec::default()
            .check(Path::new("s.usda"), usd_field("/V"))
            .unwrap();
        assert_eq!(p, MediumParams::default());
        let spec = MediumSpec {
            density_scale: Some(8.0),
            albedo: Some([0.5, 0.6, 0.7]),
            g: Some(0.3),
            transform: Some(TransformSpec::Srt {
                translate: Some([1.0, 2.0, 3.0]),
                rotate_deg: None,
                scale: Some(2.0),
            }),
            ..Default::default()
        };
        let p = spec.check(Path::new("a.toml"), toml_field(0)).unwrap();
        assert_eq!(p.density_scale, 8.0);
        assert_eq!(p.albedo, Vec3::new(0.5, 0.6, 0.7));
        assert_eq!(p.phase.g, 0.3);
        assert_eq!(
            p.transform.transform_point3(DVec3::ONE),
            DVec3::new(3.0, 4.0, 5.0)
        );
    }

    #[test]
    fn errors_name_file_field_and_expectation_in_either_spelling() {
        let bad = |spec: MediumSpec| {
            let t = spec
                .check(Path::new("scene.toml"), toml_field(2))
                .unwrap_err()
                .to_string();
            let u = spec
                .check(Path::new("shot.usda"), usd_field("/World/Smoke"))
                .unwrap_err()
                .to_string();
            (t, u)
        };
        let (t, u) = bad(MediumSpec {
            density_scale: Some(-1.0),
            ..Default::default()
        });
        assert_eq!(
            t,
            "scene.toml: medium[2].density_scale: expected a finite number >= 0, got -1"
        );
        assert_eq!(
            u,
            "shot.usda: /World/Smoke.ppb:densityScale: expected a finite number >= 0, got -1"
        );
        let (t, u) = bad(MediumSpec {
            albedo: Some([0.5, 1.5, 0.5]),
            ..Default::default()
        });
        assert!(
            t.contains("medium[2].albedo: expected values in [0, 1]"),
            "{t}"
        );
        assert!(
            u.contains("/World/Smoke.ppb:albedo: expected values"),
            "{u}"
        );
        let (t, u) = bad(MediumSpec {
            g: Some(1.0),
            ..Default::default()
        });
        assert!(
            t.contains("medium[2].phase.g: expected g in (-1, 1)"),
            "{t}"
        );
        assert!(u.contains("/World/Smoke.ppb:g"), "{u}");
        let (t, _) = bad(MediumSpec {
            sigma_t: Some(f32::NAN),
            ..Default::default()
        });
        assert!(t.contains("medium[2].sigma_t: expected a finite"), "{t}");
        let (_, u) = bad(MediumSpec {
            transform: Some(TransformSpec::Matrix(DAffine3::from_scale(DVec3::ZERO))),
            ..Default::default()
        });
        assert!(u.contains("/World/Smoke.xformOpOrder: expected a finite, invertible"));
    }
}
