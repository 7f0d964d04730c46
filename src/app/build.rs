//! `ppb build`: bakes the majorant octrees of a scene's grid media into the cache, or
//! says which are stale.
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

use ppb::majorant::cache;

use super::{cache_dir_for, cached_media, load_scene};

#[derive(Args)]
pub struct BuildArgs {
    /// Scene file (.toml).
    pub scene: PathBuf,
    /// Cache folder (default: .ppb-cache/ beside the scene).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Only report whether each medium's cached octree is fresh; exit 1 if any is stale.
    #[arg(long)]
    pub check: bool,
}

pub fn build(args: BuildArgs) -> Result<ExitCode> {
    let file = load_scene(&args.scene)?;
    let depth = file.settings.octree_depth;
    let dir = cache_dir_for(&args.scene, args.cache_dir.as_ref());
    if args.check {
        let mut stale = false;
        for (i, g) in file.scene.grid_media.iter().enumerate() {
            let (status, _) = cache::load(&dir, g, depth);
            let word = match &status {
                cache::Status::Fresh => "fresh".to_string(),
                cache::Status::Missing => "stale (no cache)".to_string(),
                cache::Status::Invalid(w) => format!("stale ({w})"),
            };
            stale |= status != cache::Status::Fresh;
            println!("medium {i} ({}): {word}", g.source);
        }
        return Ok(if stale {
            ExitCode::from(1)
        } else {
            ExitCode::SUCCESS
        });
    }
    cached_media(&file, depth, &dir, false)?;
    Ok(ExitCode::SUCCESS)
}
