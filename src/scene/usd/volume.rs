//! Volume prims: the density field's OpenVDBAsset, its grid and placement.
use super::*;

impl Ctx<'_> {
    /// Volume -> grid medium. The `field:density` relationship (else the first `field:*`)
    /// must name an OpenVDBAsset; its `filePath` resolves against the stage file's
    /// folder and `fieldName` (fallback: the field's relationship name) picks the grid.
    /// The grid's own index-to-world map is followed by the Volume prim's world
    /// transform. Medium parameters come from custom attributes on the Volume prim,
    /// `ppb:densityScale` (1), `ppb:albedo` (0.9 grey) and `ppb:g` (0), checked by
    /// [`MediumSpec::check`] as a TOML medium's are; a volume material is not read;
    /// extra media can come from a `<stem>.ppb.toml` sidecar. Grid values times
    /// `ppb:densityScale` are extinction in 1/m whatever metersPerUnit is. A missing or
    /// unreadable .vdb is an error naming the prim. The VDB is read once (through
    /// [`Files`]) for both the grid and the octree cache key.
    pub(super) fn volume(&mut self, p: &sdf::Path) -> Result<()> {
        let Some((rel, field)) = self.volume_field(p)? else {
            self.note(format!("ignored Volume {p}: no field:* relationship"));
            return Ok(());
        };
        let ft = self.stage.prim(field.clone()).type_name().ok().flatten();
        if ft.as_ref().map(|t| t.to_string()).as_deref() != Some("OpenVDBAsset") {
            self.note(format!(
                "ignored Volume {p}: field {field} is not an OpenVDBAsset"
            ));
            return Ok(());
        }
        let file = self.asset_path(&field, "filePath")?;
        let name = self.token(&field, "fieldName")?.filter(|s| !s.is_empty());
        let name = name.unwrap_or(rel);
        let spec = MediumSpec {
            density_scale: self.f64_opt(p, "ppb:densityScale")?.map(|x| x as f32),
            albedo: self.vec3_opt(p, "ppb:albedo")?.map(|a| a.map(|x| x as f32)),
            g: self.f64_opt(p, "ppb:g")?.map(|x| x as f32),
            transform: Some(TransformSpec::Matrix(DAffine3::from_mat4(self.world(p)?))),
            ..Default::default()
        };
        let mp = spec.check(self.path, usd_field(p))?;
        if self.probe {
            if !file.is_file() {
                return Err(self.err(&field, format!("{} does not exist", file.display())));
            }
            return Ok(());
        }
        // An OpenVDBAsset is OpenVDB by its schema, whatever the file's extension.
        let cannot = |e: Error| self.err(&field, format!("cannot load the VDB: {e}"));
        let bytes = self.files.read(&file).map_err(cannot)?;
        let grid = crate::media::openvdb::load_grid_from(&file, &bytes, &name).map_err(cannot)?;
        let mut h = self.files.hasher(&file)?;
        let (scale, xf) = (mp.density_scale, mp.transform);
        self.out.files.push(file.clone());
        h.update(format!("{name} {scale} {xf:?}").as_bytes());
        self.out.grid_media.push(GridMedium::new(
            Arc::new(grid),
            xf,
            scale,
            mp.albedo,
            mp.phase,
            format!("{} [{name}] ({p})", file.display()),
            *h.finalize().as_bytes(),
        ));
        self.note(format!(
            "imported Volume {p} (grid \"{name}\" from {})",
            file.display()
        ));
        Ok(())
    }

    /// (relationship suffix, target) of the density field, else the first field.
    pub(super) fn volume_field(&self, p: &sdf::Path) -> Result<Option<(String, sdf::Path)>> {
        let names = self
            .stage
            .prim(p.clone())
            .property_names()
            .map_err(|e| self.err(p, format!("{e:#}")))?;
        let mut fields: Vec<String> = names
            .iter()
            .map(|n| n.to_string())
            .filter(|n| n.starts_with("field:"))
            .collect();
        fields.sort_by_key(|n| n != "field:density");
        for f in fields {
            if let Some(t) = self.targets(p, &f)?.into_iter().next() {
                return Ok(Some((f["field:".len()..].to_string(), t)));
            }
        }
        Ok(None)
    }

    /// An asset attribute as a file path, relative paths against the stage's folder.
    pub(super) fn asset_path(&self, p: &sdf::Path, name: &str) -> Result<PathBuf> {
        let a = match self.value(p, name)? {
            Some(sdf::Value::AssetPath(a)) => a,
            Some(sdf::Value::String(s)) => sdf::AssetPath::new(s),
            _ => return Err(self.err(p, format!("{name}: no asset path"))),
        };
        if let Some(r) = a.resolved_path().filter(|r| !r.is_empty()) {
            return Ok(PathBuf::from(self.files.at_frame(r)));
        }
        Ok(self.dir.join(self.files.at_frame(&a.authored_path)))
    }
}
