//! World transforms composed from xformOps (the crate applies none), and the stage's
//! metersPerUnit and up-axis correction.
use super::*;

impl Ctx<'_> {
    /// metersPerUnit (USD fallback 0.01) and upAxis (fallback Y) as one matrix.
    pub(super) fn stage_root(&self) -> Result<DMat4> {
        let meta = |k: &str| {
            self.stage
                .stage_metadata(k)
                .map_err(|e| Error::format(self.path, format!("{k}: {e:#}")))
        };
        let mpu = match meta("metersPerUnit")? {
            None => 0.01,
            Some(v) => v
                .cast::<f64>()
                .map_err(|e| Error::field(self.path, "metersPerUnit", e.to_string()))?,
        };
        if !(mpu.is_finite() && mpu > 0.0) {
            return Err(Error::field(self.path, "metersPerUnit", "expected > 0"));
        }
        let up = match meta("upAxis")? {
            None => "Y".to_string(),
            Some(v) => v
                .cast::<String>()
                .map_err(|e| Error::field(self.path, "upAxis", e.to_string()))?,
        };
        Ok(DMat4::from_scale(DVec3::splat(mpu)) * up_axis_rotation(self.path, &up)?)
    }

    /// The prim's local-to-world transform in ppb space (root correction included).
    pub(super) fn world(&mut self, p: &sdf::Path) -> Result<DMat4> {
        Ok(self.root * self.stage_world(p)?)
    }

    /// Local-to-world in stage units, composing the parent chain (cached).
    pub(super) fn stage_world(&mut self, p: &sdf::Path) -> Result<DMat4> {
        if p.is_abs_root() || p.is_empty() {
            return Ok(DMat4::IDENTITY);
        }
        if let Some(m) = self.world.get(p) {
            return Ok(*m);
        }
        let (local, reset) = self.local(p)?;
        let m = match p.parent() {
            Some(parent) if !reset => self.stage_world(&parent)? * local,
            _ => local,
        };
        self.world.insert(p.clone(), m);
        Ok(m)
    }

    /// The prim's xformOps in xformOpOrder (column-vector form: the first op is
    /// outermost), and whether `!resetXformStack!` cuts the parent chain.
    pub(super) fn local(&self, p: &sdf::Path) -> Result<(DMat4, bool)> {
        let order = match self.value(p, "xformOpOrder")? {
            None => return Ok((DMat4::IDENTITY, false)),
            Some(v) => v
                .cast::<Vec<String>>()
                .map_err(|e| self.err(p, format!("xformOpOrder: {e}")))?,
        };
        let mut m = DMat4::IDENTITY;
        let mut reset = false;
        for op in &order {
            if op == "!resetXformStack!" {
                m = DMat4::IDENTITY;
                reset = true;
                continue;
            }
            let (name, invert) = match op.strip_prefix("!invert!") {
                Some(n) => (n, true),
                None => (op.as_str(), false),
            };
            let mut x = self.op(p, name)?;
            if invert {
                x = x.inverse();
            }
            m *= x;
        }
        if !m.is_finite() {
            return Err(self.err(p, "the composed transform is not finite"));
        }
        Ok((m, reset))
    }

    /// One xformOp (`xformOp:KIND[:suffix]`) as a matrix.
    pub(super) fn op(&self, p: &sdf::Path, name: &str) -> Result<DMat4> {
        let kind = name.split(':').nth(1).unwrap_or("");
        let v = self
            .value(p, name)?
            .ok_or_else(|| self.err(p, format!("{name} is in xformOpOrder but has no value")))?;
        let bad = |e: &dyn std::fmt::Display| self.err(p, format!("{name}: {e}"));
        let v3 = |v: sdf::Value| v.cast::<[f64; 3]>().map(DVec3::from).map_err(|e| bad(&e));
        let s = |v: sdf::Value| v.cast::<f64>().map_err(|e| bad(&e));
        Ok(match kind {
            "translate" => DMat4::from_translation(v3(v)?),
            "scale" => DMat4::from_scale(v3(v)?),
            "rotateX" => DMat4::from_rotation_x(s(v)?.to_radians()),
            "rotateY" => DMat4::from_rotation_y(s(v)?.to_radians()),
            "rotateZ" => DMat4::from_rotation_z(s(v)?.to_radians()),
            "orient" => DMat4::from_quat(quat(v).ok_or_else(|| bad(&"expected a quaternion"))?),
            "transform" => match v {
                sdf::Value::Matrix4d(m) => row_matrix(&m),
                _ => return Err(bad(&"expected a matrix4d")),
            },
            k if k.len() == 9 && k.starts_with("rotate") => {
                rotate3(&k[6..], v3(v)?).ok_or_else(|| bad(&"unknown rotation order"))?
            }
            _ => return Err(bad(&"unsupported xformOp type")),
        })
    }

    // ---- geometry -----------------------------------------------------------------
}

/// (x, y, z) -> (x, z, -y) for a Z-up stage; identity for Y-up.
pub(super) fn up_axis_rotation(path: &Path, up: &str) -> Result<DMat4> {
    match up {
        "Y" => Ok(DMat4::IDENTITY),
        "Z" => Ok(DMat4::from_cols(
            glam::DVec4::X,
            glam::DVec4::new(0.0, 0.0, -1.0, 0.0),
            glam::DVec4::new(0.0, 1.0, 0.0, 0.0),
            glam::DVec4::W,
        )),
        other => Err(Error::field(
            path,
            "upAxis",
            format!("expected \"Y\" or \"Z\", got {other:?}"),
        )),
    }
}

/// USD matrices are row-major for row vectors; read as columns that is the transpose,
/// which is exactly glam's column-vector matrix.
pub(super) fn row_matrix(m: &gf::Matrix4d) -> DMat4 {
    DMat4::from_cols_array(&m.0)
}

pub(super) fn quat(v: sdf::Value) -> Option<DQuat> {
    let q = match v {
        sdf::Value::Quatf(q) => DQuat::from_xyzw(q.x as f64, q.y as f64, q.z as f64, q.w as f64),
        sdf::Value::Quatd(q) => DQuat::from_xyzw(q.x, q.y, q.z, q.w),
        sdf::Value::Quath(q) => DQuat::from_xyzw(
            f64::from(q.x),
            f64::from(q.y),
            f64::from(q.z),
            f64::from(q.w),
        ),
        _ => return None,
    };
    (q.length() > 0.0).then(|| q.normalize())
}

/// rotateABC: angles are always (x, y, z) degrees; axis A is applied first, so the
/// column-vector matrix is R_C * R_B * R_A.
pub(super) fn rotate3(order: &str, deg: DVec3) -> Option<DMat4> {
    let mut m = DMat4::IDENTITY;
    for axis in order.chars() {
        let r = match axis {
            'X' => DMat4::from_rotation_x(deg.x.to_radians()),
            'Y' => DMat4::from_rotation_y(deg.y.to_radians()),
            'Z' => DMat4::from_rotation_z(deg.z.to_radians()),
            _ => return None,
        };
        m = r * m;
    }
    Some(m)
}
