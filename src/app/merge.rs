//! `ppb merge`: sums a frame's part files into its image, bit-identical to one render,
//! after checking they are parts of one render that cover its passes once.
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use ppb::core::frames::at_frame;
use ppb::farm::{merge as merge_parts, Part};
use ppb::output::Image;

use super::render::frame_list;

#[derive(Args)]
pub struct MergeArgs {
    /// Part files of one frame. Without them, each frame's parts are found beside its
    /// output (or in --part-dir), named as `ppb render` names them.
    pub parts: Vec<PathBuf>,
    /// Output EXR (PNG preview beside it); a run of # is the frame number.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Frames to merge, e.g. 1-240,300 (finds each frame's parts by name).
    #[arg(long, value_name = "LIST", conflicts_with = "parts")]
    pub frames: Option<String>,
    /// Folder of the part files (default: beside the output).
    #[arg(long, value_name = "DIR")]
    pub part_dir: Option<PathBuf>,
    /// No status lines.
    #[arg(short, long)]
    pub quiet: bool,
}

pub fn merge(args: MergeArgs) -> Result<ExitCode> {
    if !args.parts.is_empty() {
        let parts = read_parts(&args.parts)?;
        let frame = parts.first().and_then(|p| p.header.frame);
        merge_frame(&args, parts, frame)?;
        return Ok(ExitCode::SUCCESS);
    }
    let frames = frame_list(args.frames.as_deref())?;
    let frames: Vec<Option<u32>> = match frames.as_slice() {
        [] => vec![None],
        f => f.iter().map(|&f| Some(f)).collect(),
    };
    // Every frame's parts are found and read before any image is written.
    let mut all = Vec::new();
    for &frame in &frames {
        let out = at_frame(&args.output, frame);
        let paths = find_parts(&out, args.part_dir.as_ref())?;
        all.push((frame, read_parts(&paths)?));
    }
    for (frame, parts) in all {
        merge_frame(&args, parts, frame)?;
    }
    Ok(ExitCode::SUCCESS)
}

fn read_parts(paths: &[PathBuf]) -> Result<Vec<Part>> {
    paths
        .iter()
        .map(|p| Part::read(p).map_err(anyhow::Error::from))
        .collect()
}

/// The part files `ppb render` writes for the frame whose output is `out`.
fn find_parts(out: &Path, dir: Option<&PathBuf>) -> Result<Vec<PathBuf>> {
    let stem = out.file_stem().unwrap_or_default().to_string_lossy();
    let prefix = format!("{stem}.passes-");
    let dir = match dir {
        Some(d) => d.clone(),
        None => out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf(),
    };
    let entries = std::fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))?;
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(&prefix) && n.ends_with(".ppbpart"))
        })
        .collect();
    found.sort();
    if found.is_empty() {
        anyhow::bail!(
            "no part files for {} (looked for {}/{prefix}*.ppbpart)",
            out.display(),
            dir.display()
        );
    }
    Ok(found)
}

/// Merges one frame's parts and writes its EXR and PNG.
fn merge_frame(args: &MergeArgs, parts: Vec<Part>, frame: Option<u32>) -> Result<()> {
    let n = parts.len();
    let (header, film) = merge_parts(parts)?;
    let out = at_frame(&args.output, frame.or(header.frame));
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let img = Image {
        width: film.width as usize,
        height: film.height as usize,
        pixels: film.image_with(header.bandwidth),
        alpha: film.alpha(),
    };
    let mut meta = header.exr.clone();
    meta.set("ppb/passes", header.passes.to_string());
    meta.set("ppb/pass_range", header.range.to_string());
    meta.set("ppb/render_seconds", format!("{:.3}", header.seconds));
    meta.set("ppb/scene_hash", header.scene_hash.clone());
    meta.set("ppb/merged_parts", n.to_string());
    super::set_error_estimate(&mut meta, &film, header.bandwidth);
    super::write_image(&out, &img, &meta, header.exposure).map_err(super::failed)?;
    if !args.quiet {
        eprintln!("{n} parts, passes {} -> {}", header.range, out.display());
    }
    Ok(())
}
