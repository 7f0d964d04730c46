//! Attribute readers: a prim's authored value of a name, typed, with USD's fallback where
//! the caller gives one; errors name the prim and the attribute.
use super::*;

impl Ctx<'_> {
    /// The composed default value of `prim.name`, or None when unauthored or blocked.
    pub(super) fn value(&self, p: &sdf::Path, name: &str) -> Result<Option<sdf::Value>> {
        let v = self
            .stage
            .prim(p.clone())
            .attribute(name)
            .get::<sdf::Value>()
            .map_err(|e| self.err(p, format!("{name}: {e:#}")))?;
        Ok(v.filter(|v| !matches!(v, sdf::Value::ValueBlock | sdf::Value::None)))
    }

    /// The first authored of `names` (UsdLux renamed `intensity` to `inputs:intensity`).
    pub(super) fn value_any(&self, p: &sdf::Path, names: &[&str]) -> Result<Option<sdf::Value>> {
        for n in names {
            if let Some(v) = self.value(p, n)? {
                return Ok(Some(v));
            }
        }
        Ok(None)
    }

    /// The value of `prim.name` as a number, unchecked (None when unauthored).
    pub(super) fn f64_opt(&self, p: &sdf::Path, name: &str) -> Result<Option<f64>> {
        self.value(p, name)?
            .map(|v| v.cast::<f64>())
            .transpose()
            .map_err(|e| self.err(p, format!("{name}: {e}")))
    }

    /// The value of `prim.name` as a triple, unchecked (None when unauthored).
    pub(super) fn vec3_opt(&self, p: &sdf::Path, name: &str) -> Result<Option<[f64; 3]>> {
        self.value(p, name)?
            .map(|v| v.cast::<[f64; 3]>())
            .transpose()
            .map_err(|e| self.err(p, format!("{name}: {e}")))
    }

    pub(super) fn f64_or(&self, p: &sdf::Path, names: &[&str], default: f64) -> Result<f64> {
        match self.value_any(p, names)? {
            None => Ok(default),
            Some(v) => {
                let x = v
                    .cast::<f64>()
                    .map_err(|e| self.err(p, format!("{}: {e}", names[0])))?;
                if x.is_finite() {
                    Ok(x)
                } else {
                    Err(self.err(p, format!("{}: not finite", names[0])))
                }
            }
        }
    }

    pub(super) fn bool_or(&self, p: &sdf::Path, name: &str, default: bool) -> Result<bool> {
        match self.value(p, name)? {
            None => Ok(default),
            Some(sdf::Value::Bool(b)) => Ok(b),
            Some(v) => v
                .cast::<f64>()
                .map(|x| x != 0.0)
                .map_err(|e| self.err(p, format!("{name}: {e}"))),
        }
    }

    pub(super) fn vec3_or(&self, p: &sdf::Path, names: &[&str], default: DVec3) -> Result<DVec3> {
        match self.value_any(p, names)? {
            None => Ok(default),
            Some(v) => {
                let a = v
                    .cast::<[f64; 3]>()
                    .map_err(|e| self.err(p, format!("{}: {e}", names[0])))?;
                let d = DVec3::from(a);
                if d.is_finite() {
                    Ok(d)
                } else {
                    Err(self.err(p, format!("{}: not finite", names[0])))
                }
            }
        }
    }

    pub(super) fn token(&self, p: &sdf::Path, name: &str) -> Result<Option<String>> {
        match self.value(p, name)? {
            None => Ok(None),
            Some(v) => v
                .cast::<String>()
                .map(Some)
                .map_err(|e| self.err(p, format!("{name}: {e}"))),
        }
    }

    pub(super) fn points(&self, p: &sdf::Path, name: &str) -> Result<Option<Vec<DVec3>>> {
        match self.value(p, name)? {
            None => Ok(None),
            Some(v) => {
                let pts = v
                    .cast::<Vec<gf::Vec3f>>()
                    .map_err(|e| self.err(p, format!("{name}: {e}")))?;
                let pts: Vec<DVec3> = pts
                    .iter()
                    .map(|q| DVec3::new(q.x as f64, q.y as f64, q.z as f64))
                    .collect();
                if pts.iter().all(|q| q.is_finite()) {
                    Ok(Some(pts))
                } else {
                    Err(self.err(p, format!("{name}: a value is not finite")))
                }
            }
        }
    }

    pub(super) fn ints(&self, p: &sdf::Path, name: &str) -> Result<Option<Vec<i64>>> {
        Ok(match self.value(p, name)? {
            None => None,
            Some(sdf::Value::IntVec(v)) => Some(v.into_iter().map(i64::from).collect()),
            Some(sdf::Value::Int64Vec(v)) => Some(v),
            Some(sdf::Value::UintVec(v)) => Some(v.into_iter().map(i64::from).collect()),
            Some(v) => {
                let kind: &'static str = (&v).into();
                return Err(self.err(p, format!("{name}: expected an int array, got {kind}")));
            }
        })
    }

    pub(super) fn targets(&self, p: &sdf::Path, rel: &str) -> Result<Vec<sdf::Path>> {
        self.stage
            .prim(p.clone())
            .relationship(rel)
            .targets()
            .map_err(|e| self.err(p, format!("{rel}: {e:#}")))
    }

    // ---- transforms -------------------------------------------------------------
}
