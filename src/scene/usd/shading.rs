//! UsdPreviewSurface materials reached by `material:binding` (see the module's rule).
use super::*;

impl Ctx<'_> {
    /// Index of the material bound to the prim or its nearest bound ancestor.
    pub(super) fn bound_material(&mut self, p: &sdf::Path) -> Result<usize> {
        let mut cur = Some(p.clone());
        while let Some(q) = cur {
            if q.is_abs_root() {
                break;
            }
            if let Some(t) = self.targets(&q, "material:binding")?.into_iter().next() {
                return self.material(&t);
            }
            cur = q.parent();
        }
        self.material_default()
    }

    pub(super) fn material_default(&mut self) -> Result<usize> {
        let m = Material::Lambert {
            reflectance: Vec3::splat(DEFAULT_DIFFUSE as f32),
        };
        Ok(self.add_material("usd:default".into(), m))
    }

    pub(super) fn add_material(&mut self, name: String, material: Material) -> usize {
        if let Some(&i) = self.materials.get(&name) {
            return i;
        }
        let i = self.out.materials.len();
        self.out.materials.push(NamedMaterial {
            name: name.clone(),
            material,
        });
        self.materials.insert(name, i);
        i
    }

    /// Converts a Material prim's UsdPreviewSurface (see the module doc for the rule).
    pub(super) fn material(&mut self, m: &sdf::Path) -> Result<usize> {
        let key = m.to_string();
        if let Some(&i) = self.materials.get(&key) {
            return Ok(i);
        }
        let Some(shader) = self.surface_shader(m)? else {
            self.note(format!(
                "ignored Material {m}: no UsdPreviewSurface; using grey Lambert"
            ));
            return self.material_default();
        };
        let s = &shader;
        let diffuse = self.vec3_or(s, &["inputs:diffuseColor"], DVec3::splat(DEFAULT_DIFFUSE))?;
        let opacity = self.f64_or(s, &["inputs:opacity"], 1.0)?;
        let ior = self.f64_or(s, &["inputs:ior"], 1.5)?;
        let metallic = self.f64_or(s, &["inputs:metallic"], 0.0)?;
        let tint = diffuse.clamp(DVec3::ZERO, DVec3::ONE).as_vec3();
        let material = if opacity < 1.0 {
            let ior = if ior > 0.0 { ior } else { 1.5 };
            Material::Dielectric { ior: ior as f32 }
        } else if metallic >= 0.5 {
            Material::Mirror { reflectance: tint }
        } else {
            Material::Lambert { reflectance: tint }
        };
        Ok(self.add_material(key, material))
    }

    /// The UsdPreviewSurface shader feeding `outputs:surface`, if any.
    pub(super) fn surface_shader(&self, m: &sdf::Path) -> Result<Option<sdf::Path>> {
        let conns = self
            .stage
            .prim(m.clone())
            .attribute("outputs:surface")
            .connections()
            .map_err(|e| self.err(m, format!("outputs:surface: {e:#}")))?;
        let Some(src) = conns.first() else {
            return Ok(None);
        };
        let shader = src.prim_path();
        let id = self.token(&shader, "info:id")?;
        Ok((id.as_deref() == Some("UsdPreviewSurface")).then_some(shader))
    }

    // ---- lights and camera --------------------------------------------------------
}
