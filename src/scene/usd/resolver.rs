//! The stage's asset resolver: every layer and VDB file read once per load, through the
//! load's [`Files`], however often the USD reader opens it.
use super::*;

/// The stage's assets read through [`Files`]: a layer the USD reader opens more than
/// once (a `.usd` is peeked for its format, then read) and a .usdz package opened per
/// packaged layer are read from disk once; resolution is the default resolver's.
pub(super) struct ReadOnce {
    pub(super) inner: ar::DefaultResolver,
    pub(super) files: Files,
}

/// A file's bytes shared with [`Files`], as a seekable asset.
struct Shared(io::Cursor<SharedBytes>);
struct SharedBytes(Arc<Vec<u8>>);

impl AsRef<[u8]> for SharedBytes {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

impl io::Read for Shared {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl io::Seek for Shared {
    fn seek(&mut self, pos: io::SeekFrom) -> io::Result<u64> {
        self.0.seek(pos)
    }
}

impl ar::Asset for Shared {
    fn size(&self) -> io::Result<u64> {
        Ok(self.0.get_ref().0.len() as u64)
    }
}

impl ReadOnce {
    fn bytes(&self, path: &Path) -> io::Result<Arc<Vec<u8>>> {
        self.files.read(path).map_err(|e| match e {
            Error::Io { cause, .. } => cause,
            other => io::Error::other(other.to_string()),
        })
    }

    /// The .usdz package at `path` as a zip archive over its bytes.
    fn package(&self, path: &Path) -> io::Result<zip::ZipArchive<io::Cursor<SharedBytes>>> {
        let bytes = self.bytes(path)?;
        zip::ZipArchive::new(io::Cursor::new(SharedBytes(bytes))).map_err(io::Error::other)
    }

    /// (package, entry) of `pkg.usdz[entry]`; None for a plain or nested path.
    fn packaged(path: &str) -> Option<(String, String)> {
        if !ar::is_package_relative_path(path) {
            return None;
        }
        let (package, entry) = ar::split_package_relative_path_outer(path)?;
        (!ar::is_package_relative_path(&entry)).then_some((package, entry))
    }
}

impl ar::Resolver for ReadOnce {
    /// The frame token in a layer or asset path becomes the load's frame.
    fn create_identifier(&self, asset_path: &str, anchor: Option<&ar::ResolvedPath>) -> String {
        self.inner
            .create_identifier(&self.files.at_frame(asset_path), anchor)
    }

    /// As the default resolver: a packaged path resolves when its package does and,
    /// if the package is a readable zip, holds the entry.
    fn resolve(&self, asset_path: &str) -> Option<ar::ResolvedPath> {
        let Some((package, entry)) = Self::packaged(asset_path) else {
            return self.inner.resolve(asset_path);
        };
        let package = self.inner.resolve(&package)?;
        let missing = self
            .package(&package)
            .is_ok_and(|zip| zip.index_for_name(&entry).is_none());
        if missing {
            return None;
        }
        let joined = ar::join_package_relative_path(&package.to_string_lossy(), &entry);
        Some(ar::ResolvedPath::new(joined))
    }

    fn resolve_for_new_asset(&self, asset_path: &str) -> Option<ar::ResolvedPath> {
        self.inner.resolve_for_new_asset(asset_path)
    }

    fn open_asset(&self, resolved: &ar::ResolvedPath) -> io::Result<Box<dyn ar::Asset>> {
        let s = resolved.to_string_lossy();
        if let Some((package, entry)) = Self::packaged(&s) {
            let mut zip = self.package(Path::new(&package))?;
            let mut file = zip.by_name(&entry).map_err(io::Error::other)?;
            let mut buf = Vec::new();
            io::Read::read_to_end(&mut file, &mut buf)?;
            return Ok(Box::new(io::Cursor::new(buf)));
        }
        if ar::is_package_relative_path(&s) {
            return self.inner.open_asset(resolved);
        }
        let bytes = self.bytes(resolved)?;
        Ok(Box::new(Shared(io::Cursor::new(SharedBytes(bytes)))))
    }

    fn identity(&self) -> String {
        self.inner.identity()
    }
}
