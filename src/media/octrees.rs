//! The one builder of a scene's media with their majorant octrees ([`OctreeStore`]): a
//! medium whose field is unchanged since the last build keeps its octree in memory; a new
//! one goes through the disk cache (built and stored only on a miss), or is built in
//! memory when there is no cache folder. `render`, `build`, `watch` and the benchmarks
//! all ask it.
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use super::{GridMedium, Heterogeneous, Media, MediumDesc};
use crate::error::Result;
use crate::majorant::{cache, Octree};

/// Where a medium's octree came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// Kept from the previous load (same cache key).
    Reused,
    /// Read from the cache folder (file read, checks and the walk's cell table).
    Cached { seconds: f64 },
    /// Built now; `why` says why a cache file was not used, `stored` where it went.
    Built {
        seconds: f64,
        nodes: usize,
        why: Option<String>,
        stored: std::result::Result<String, String>,
    },
}

/// Loads the octree of `g` from the cache folder, else builds and stores it.
pub fn load_or_build(dir: &Path, g: &GridMedium, depth: u32) -> (Octree, Origin) {
    let start = Instant::now();
    let (status, tree) = cache::load(dir, g, depth);
    if let Some(t) = tree {
        let seconds = start.elapsed().as_secs_f64();
        return (t, Origin::Cached { seconds });
    }
    let start = Instant::now();
    let t = Octree::build(g, depth);
    let stored = cache::store(dir, g, depth, &t);
    let origin = Origin::Built {
        seconds: start.elapsed().as_secs_f64(),
        nodes: t.nodes.len(),
        why: match status {
            cache::Status::Invalid(w) => Some(w),
            _ => None,
        },
        stored: stored
            .map(|p| p.display().to_string())
            .map_err(|e| e.to_string()),
    };
    (t, origin)
}

/// The octree of `g` built now and kept in memory only.
fn build_in_memory(g: &GridMedium, depth: u32) -> (Octree, Origin) {
    let start = Instant::now();
    let t = Octree::build(g, depth);
    let origin = Origin::Built {
        seconds: start.elapsed().as_secs_f64(),
        nodes: t.nodes.len(),
        why: None,
        stored: Err("kept in memory".into()),
    };
    (t, origin)
}

/// The log line for medium `i`: "octree built in ..." marks every build (tests count it).
pub fn describe(i: usize, g: &GridMedium, origin: &Origin) -> String {
    match origin {
        Origin::Reused => format!("medium {i} ({}): octree reused (field unchanged)", g.source),
        Origin::Cached { seconds } => format!(
            "medium {i} ({}): octree loaded from cache in {:.1} ms",
            g.source,
            seconds * 1e3
        ),
        Origin::Built {
            seconds,
            nodes,
            why,
            stored,
        } => {
            let why = why
                .as_ref()
                .map_or(String::new(), |w| format!(" (cache invalid: {w})"));
            let where_ = match stored {
                Ok(p) => format!("stored in {p}"),
                Err(e) => format!("not stored: {e}"),
            };
            format!(
                "medium {i} ({}): octree built in {seconds:.2} s, {nodes} nodes{why}; {where_}",
                g.source
            )
        }
    }
}

/// The octrees of the current scene, by cache key.
#[derive(Default)]
pub struct OctreeStore {
    trees: HashMap<[u8; 32], Arc<Octree>>,
}

impl OctreeStore {
    pub fn new() -> Self {
        Self::default()
    }

    /// The homogeneous `boxes` and the grid `fields`, every grid with its octree (kept,
    /// loaded from the cache folder `dir` or built and stored there; built in memory
    /// without a folder); `report` hears where each came from. Afterwards only these
    /// fields' octrees are kept.
    pub fn media(
        &mut self,
        boxes: &[MediumDesc],
        fields: &[GridMedium],
        depth: u32,
        dir: Option<&Path>,
        mut report: impl FnMut(usize, &GridMedium, &Origin),
    ) -> Result<Media> {
        let mut kept = HashMap::new();
        let mut grids = Vec::with_capacity(fields.len());
        for (i, g) in fields.iter().enumerate() {
            let key = cache::key(g, depth);
            let (tree, origin) = match self.trees.get(&key).or_else(|| kept.get(&key)) {
                Some(t) => (t.clone(), Origin::Reused),
                None => {
                    let (t, origin) = match dir {
                        Some(dir) => load_or_build(dir, g, depth),
                        None => build_in_memory(g, depth),
                    };
                    (Arc::new(t), origin)
                }
            };
            report(i, g, &origin);
            kept.insert(key, tree.clone());
            grids.push(Heterogeneous::new(g.clone(), tree)?);
        }
        self.trees = kept;
        Ok(Media::with_grids(boxes.to_vec(), grids))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::scene::Scene;

    /// A scene with two small noise media, the first with `seed`.
    fn scene(seed: u32) -> Scene {
        let medium = |seed: u32| {
            format!(
                "[[medium]]\ntype = \"noise\"\npreset = \"cloud\"\nbounds = [[-1, 0, -1], [1, 1, 1]]\n\
                 resolution = 8\nseed = {seed}\ndensity_scale = 1.0\nalbedo = [0.9, 0.9, 0.9]\n"
            )
        };
        let text = format!(
            "[camera]\norigin = [0, 1, 5]\ntarget = [0, 0, 0]\nvfov = 40\n\
             [[light]]\ntype = \"point\"\nposition = [0, 2, 0]\nintensity = [1, 1, 1]\n{}{}",
            medium(seed),
            medium(99)
        );
        crate::scene::toml::parse(Path::new("noise.toml"), &text)
            .unwrap()
            .scene
    }

    fn origins(store: &mut OctreeStore, scene: &Scene, dir: &Path) -> Vec<Origin> {
        let mut out = Vec::new();
        store
            .media(&scene.media, &scene.grid_media, 3, Some(dir), |_, _, o| {
                out.push(o.clone())
            })
            .unwrap();
        out
    }

    #[test]
    fn keeps_unchanged_octrees_and_builds_only_changed_ones() {
        let dir = std::env::temp_dir().join(format!("ppb-octrees-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut store = OctreeStore::new();
        let built = |o: &Origin| matches!(o, Origin::Built { .. });
        let first = origins(&mut store, &scene(1), &dir);
        assert!(first.iter().all(built), "{first:?}");
        assert_eq!(
            origins(&mut store, &scene(1), &dir),
            [Origin::Reused, Origin::Reused]
        );
        let changed = origins(&mut store, &scene(2), &dir);
        assert!(
            built(&changed[0]) && changed[1] == Origin::Reused,
            "{changed:?}"
        );
        // Back to the first field: not in memory any more, but in the disk cache.
        let back = origins(&mut store, &scene(1), &dir);
        assert!(
            matches!(back[..], [Origin::Cached { .. }, Origin::Reused]),
            "{back:?}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
