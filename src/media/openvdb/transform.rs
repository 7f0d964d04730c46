//! The grid transform (`math::Transform::read`): a map type name, then that map's fields.
//! OpenVDB maps act on row vectors (`world = [i j k 1] * M`, translation in the last row);
//! glam's `DAffine3` acts on column vectors, so row `r` of `M` becomes column `r`.
use super::bytes::{Parse, Reader};
use glam::{DAffine3, DMat3, DVec3};

/// Reads a transform and returns index-to-world; only linear maps are accepted.
pub fn read(r: &mut Reader) -> Parse<DAffine3> {
    let kind = r.string("transform map type")?;
    let m = match kind.as_str() {
        "UniformScaleMap" | "ScaleMap" => scale_translate(r, false)?,
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => scale_translate(r, true)?,
        "TranslationMap" => DAffine3::from_translation(DVec3::from(r.vec3d("translation")?)),
        "AffineMap" | "UnitaryMap" => affine(r)?,
        "NonlinearFrustumMap" => {
            return Err("transform map NonlinearFrustumMap is not linear; not supported".into())
        }
        other => return Err(format!("unknown transform map type {other:?}")),
    };
    check(&kind, m)
}

/// ScaleMap's fields: scale, voxel size, inverse scale, 1/scale², 1/(2 scale); the
/// translate variants put the translation first. Only scale and translation are used.
fn scale_translate(r: &mut Reader, translated: bool) -> Parse<DAffine3> {
    let t = if translated {
        DVec3::from(r.vec3d("translation")?)
    } else {
        DVec3::ZERO
    };
    let s = DVec3::from(r.vec3d("scale")?);
    r.take(4 * 24, "scale map derived fields")?;
    let mut m = DAffine3::from_scale(s);
    m.translation = t;
    Ok(m)
}

/// A row-major 4x4 matrix whose last column must be (0, 0, 0, 1).
fn affine(r: &mut Reader) -> Parse<DAffine3> {
    let mut m = [[0.0f64; 4]; 4];
    for row in m.iter_mut() {
        for v in row.iter_mut() {
            *v = r.f64("affine matrix")?;
        }
    }
    let last = [m[0][3], m[1][3], m[2][3], m[3][3]];
    if last != [0.0, 0.0, 0.0, 1.0] {
        return Err(format!(
            "affine map matrix is not affine (last column {last:?})"
        ));
    }
    let row = |i: usize| DVec3::new(m[i][0], m[i][1], m[i][2]);
    Ok(DAffine3 {
        matrix3: DMat3::from_cols(row(0), row(1), row(2)),
        translation: row(3),
    })
}

fn check(kind: &str, m: DAffine3) -> Parse<DAffine3> {
    let det = m.matrix3.determinant();
    if !m.is_finite() || !det.is_finite() || det == 0.0 {
        return Err(format!("{kind} is singular or not finite: {m:?}"));
    }
    Ok(m)
}
