//! Mesh and Sphere gprims: points, fan-triangulated faces, normals, the bound material.
use super::*;

impl Ctx<'_> {
    pub(super) fn mesh(&mut self, p: &sdf::Path) -> Result<()> {
        let Some(points) = self.points(p, "points")? else {
            self.note(format!("ignored Mesh {p}: no points"));
            return Ok(());
        };
        let counts = self.ints(p, "faceVertexCounts")?.unwrap_or_default();
        let indices = self.ints(p, "faceVertexIndices")?.unwrap_or_default();
        let mut tris = triangulate(&counts, &indices, points.len()).map_err(|m| self.err(p, m))?;
        let normals = self.mesh_normals(p, &points, &indices)?;
        let xf = self.world(p)?;
        let left = self.token(p, "orientation")?.as_deref() == Some("leftHanded");
        if left != (xf.determinant() < 0.0) {
            tris.iter_mut().for_each(|t| t.swap(1, 2));
        }
        let n = tris.len();
        self.push_mesh(p, xf, &points, normals, tris)?;
        self.note(format!("imported Mesh {p} ({n} triangles)"));
        Ok(())
    }

    /// Per-vertex normals in local space, or empty when none can be kept.
    pub(super) fn mesh_normals(
        &self,
        p: &sdf::Path,
        points: &[DVec3],
        indices: &[i64],
    ) -> Result<Vec<DVec3>> {
        let (name, vals) = match self.points(p, "primvars:normals")? {
            Some(v) => ("primvars:normals", v),
            None => match self.points(p, "normals")? {
                Some(v) => ("normals", v),
                None => return Ok(Vec::new()),
            },
        };
        let vals = match self.ints(p, &format!("{name}:indices"))? {
            Some(ix) => ix
                .iter()
                .map(|&i| usize::try_from(i).ok().and_then(|i| vals.get(i).copied()))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| self.err(p, format!("{name}:indices out of range")))?,
            None => vals,
        };
        let interp = self
            .stage
            .prim(p.clone())
            .attribute(name)
            .get_metadata::<sdf::Value>("interpolation")
            .ok()
            .flatten()
            .and_then(|v| v.cast::<String>().ok())
            .unwrap_or_else(|| "vertex".into());
        Ok(match interp.as_str() {
            "vertex" | "varying" if vals.len() == points.len() => vals,
            "faceVarying" if vals.len() == indices.len() => {
                face_varying_to_vertex(&vals, indices, points.len()).unwrap_or_default()
            }
            _ => Vec::new(),
        })
    }

    /// Transforms a local mesh to world space and appends it with its bound material.
    pub(super) fn push_mesh(
        &mut self,
        p: &sdf::Path,
        xf: DMat4,
        points: &[DVec3],
        normals: Vec<DVec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<()> {
        let nm = DMat3::from_mat4(xf).inverse().transpose();
        let material = self.bound_material(p)?;
        self.out.meshes.push(Mesh {
            name: p.to_string(),
            positions: points
                .iter()
                .map(|&q| xf.transform_point3(q).as_vec3())
                .collect(),
            normals: normals
                .iter()
                .map(|&n| (nm * n).normalize_or_zero().as_vec3())
                .collect(),
            triangles,
            material,
        });
        Ok(())
    }

    /// Sphere gprim (radius fallback 1), tessellated as a UV sphere.
    pub(super) fn sphere(&mut self, p: &sdf::Path) -> Result<()> {
        let r = self.f64_or(p, &["radius"], 1.0)?;
        if r <= 0.0 {
            self.note(format!("ignored Sphere {p}: radius {r} <= 0"));
            return Ok(());
        }
        let (points, normals, tris) = uv_sphere(r, SPHERE_SEGMENTS);
        let xf = self.world(p)?;
        let n = tris.len();
        let mut tris = tris;
        if xf.determinant() < 0.0 {
            tris.iter_mut().for_each(|t| t.swap(1, 2));
        }
        self.push_mesh(p, xf, &points, normals, tris)?;
        self.note(format!("imported Sphere {p} (tessellated, {n} triangles)"));
        Ok(())
    }

    // ---- materials ----------------------------------------------------------------
}

/// Fan-triangulates polygons, checking counts against indices and indices against
/// the point count; faces with fewer than 3 corners are skipped.
pub fn triangulate(
    counts: &[i64],
    indices: &[i64],
    n_points: usize,
) -> std::result::Result<Vec<[u32; 3]>, String> {
    let total: i64 = counts.iter().map(|&c| c.max(0)).sum();
    if counts.iter().any(|&c| c < 0) || total != indices.len() as i64 {
        return Err(format!(
            "faceVertexCounts sum to {total} but there are {} faceVertexIndices",
            indices.len()
        ));
    }
    let idx = indices
        .iter()
        .map(|&i| u32::try_from(i).ok().filter(|&i| (i as usize) < n_points))
        .collect::<Option<Vec<u32>>>()
        .ok_or_else(|| format!("a faceVertexIndex is outside 0..{n_points}"))?;
    let mut tris = Vec::new();
    let mut at = 0usize;
    for &c in counts {
        let c = c as usize;
        let f = &idx[at..at + c];
        for k in 1..c.saturating_sub(1) {
            tris.push([f[0], f[k], f[k + 1]]);
        }
        at += c;
    }
    Ok(tris)
}

/// Per-corner normals to per-vertex ones, or None when corners of a vertex disagree.
pub(super) fn face_varying_to_vertex(
    vals: &[DVec3],
    indices: &[i64],
    n: usize,
) -> Option<Vec<DVec3>> {
    let mut out: Vec<Option<DVec3>> = vec![None; n];
    for (&i, &v) in indices.iter().zip(vals) {
        let slot = out.get_mut(usize::try_from(i).ok()?)?;
        match slot {
            None => *slot = Some(v),
            Some(w) if w.normalize_or_zero().dot(v.normalize_or_zero()) > 0.999 => {}
            Some(_) => return None,
        }
    }
    Some(out.into_iter().map(|v| v.unwrap_or(DVec3::ZERO)).collect())
}

/// UV sphere of radius `r` about the origin, counter-clockwise seen from outside.
pub(super) fn uv_sphere(r: f64, seg: u32) -> (Vec<DVec3>, Vec<DVec3>, Vec<[u32; 3]>) {
    let rings = seg / 2;
    let mut pts = Vec::new();
    for i in 0..=rings {
        let th = PI * i as f64 / rings as f64;
        for j in 0..=seg {
            let ph = 2.0 * PI * j as f64 / seg as f64;
            pts.push(DVec3::new(
                th.sin() * ph.cos(),
                th.cos(),
                -th.sin() * ph.sin(),
            ));
        }
    }
    let w = seg + 1;
    let mut tris = Vec::new();
    for i in 0..rings {
        for j in 0..seg {
            let (a, b, c, d) = (
                i * w + j,
                (i + 1) * w + j,
                (i + 1) * w + j + 1,
                i * w + j + 1,
            );
            if i != 0 {
                tris.push([a, b, d]);
            }
            if i + 1 != rings {
                tris.push([b, c, d]);
            }
        }
    }
    let normals = pts.clone();
    (pts.iter().map(|&q| q * r).collect(), normals, tris)
}
