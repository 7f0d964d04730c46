//! The one place a file's format is told from its extension.
use std::path::Path;

use crate::error::{Error, Result};

/// Every file format ppb reads, by extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Format {
    /// A ppb scene file (.toml).
    Toml,
    /// A USD stage (.usd, .usda, .usdc, .usdz).
    Usd,
    /// glTF 2.0 (.gltf, .glb).
    Gltf,
    /// Wavefront OBJ (.obj).
    Obj,
    /// OpenVDB grids (.vdb).
    OpenVdb,
    /// NanoVDB grids (.nvdb).
    NanoVdb,
}

impl Format {
    pub const ALL: [Format; 6] = [
        Format::Toml,
        Format::Usd,
        Format::Gltf,
        Format::Obj,
        Format::OpenVdb,
        Format::NanoVdb,
    ];
    /// What can be rendered, watched or shown by `ppb info` as a scene.
    pub const SCENES: [Format; 2] = [Format::Toml, Format::Usd];
    /// What a scene's `[[import]]` or `[[mesh]]` can name.
    pub const IMPORTS: [Format; 3] = [Format::Obj, Format::Gltf, Format::Usd];
    /// What a grid medium's `path` can name.
    pub const GRIDS: [Format; 2] = [Format::OpenVdb, Format::NanoVdb];

    /// The extensions of the format, lowercase, without the dot.
    pub fn extensions(self) -> &'static [&'static str] {
        match self {
            Format::Toml => &["toml"],
            Format::Usd => &["usd", "usda", "usdc", "usdz"],
            Format::Gltf => &["gltf", "glb"],
            Format::Obj => &["obj"],
            Format::OpenVdb => &["vdb"],
            Format::NanoVdb => &["nvdb"],
        }
    }

    /// The format of `path` by its extension, or None for any other extension or none.
    pub fn detect(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_string_lossy().to_ascii_lowercase();
        Format::ALL
            .into_iter()
            .find(|f| f.extensions().contains(&ext.as_str()))
    }

    /// The format of `path`; an error naming the file and every known extension when
    /// the extension is none of them.
    pub fn of(path: &Path) -> Result<Format> {
        Format::of_kind(path, &Format::ALL)
    }

    /// The format of `path` if it is one of `allowed`; else an error naming the file
    /// and the allowed extensions ("expected a .vdb or .nvdb file").
    pub fn of_kind(path: &Path, allowed: &[Format]) -> Result<Format> {
        Format::detect(path)
            .filter(|f| allowed.contains(f))
            .ok_or_else(|| Error::format(path, Format::expected(allowed)))
    }

    /// How a scene path is read: a USD stage, or TOML (the default for a scene file
    /// whose extension is not a known format); an error for a mesh or grid file.
    pub fn of_scene(path: &Path) -> Result<Format> {
        match Format::detect(path) {
            None | Some(Format::Toml) => Ok(Format::Toml),
            Some(Format::Usd) => Ok(Format::Usd),
            Some(_) => Err(Error::format(
                path,
                format!("not a scene file; {}", Format::expected(&Format::SCENES)),
            )),
        }
    }

    pub fn is_grid(self) -> bool {
        Format::GRIDS.contains(&self)
    }

    /// "expected a .obj, .gltf, .glb, .usd, .usda, .usdc or .usdz file".
    pub fn expected(allowed: &[Format]) -> String {
        let exts: Vec<String> = allowed
            .iter()
            .flat_map(|f| f.extensions())
            .map(|e| format!(".{e}"))
            .collect();
        let list = match exts.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            Some((last, _)) => last.clone(),
            None => String::new(),
        };
        format!("expected a {list} file")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatches_on_the_extension_only() {
        let f = |s: &str| Format::detect(Path::new(s));
        assert_eq!(f("a/scene.TOML"), Some(Format::Toml));
        assert_eq!(f("shot.usdz"), Some(Format::Usd));
        assert_eq!(f("m.GLB"), Some(Format::Gltf));
        assert_eq!(f("floor.obj"), Some(Format::Obj));
        assert_eq!(f("smoke.vdb"), Some(Format::OpenVdb));
        assert_eq!(f("smoke.nvdb"), Some(Format::NanoVdb));
        assert_eq!(f("notes.txt"), None);
        assert_eq!(f("Makefile"), None);
        assert_eq!(
            Format::of_scene(Path::new("scene")).unwrap(),
            Format::Toml,
            "a scene file without a known extension is TOML"
        );
        assert_eq!(Format::of_scene(Path::new("s.usda")).unwrap(), Format::Usd);
    }

    #[test]
    fn errors_name_the_file_and_the_expected_extensions() {
        let e = Format::of_kind(Path::new("d/floor.ply"), &Format::IMPORTS)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "d/floor.ply: expected a .obj, .gltf, .glb, .usd, .usda, .usdc or .usdz file"
        );
        let e = Format::of_kind(Path::new("smoke.obj"), &Format::GRIDS)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "smoke.obj: expected a .vdb or .nvdb file");
        let e = Format::of_scene(Path::new("smoke.vdb"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("smoke.vdb: not a scene file"), "{e}");
        assert!(e.contains(".toml, .usd"), "{e}");
        assert!(Format::of(Path::new("x.txt")).is_err());
    }
}
