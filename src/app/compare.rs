//! `ppb compare`: image metrics of a candidate against a reference.
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

use ppb::compare::{block_mean, compare as metrics, read_mask};
use ppb::output;

#[derive(Args)]
pub struct CompareArgs {
    /// Candidate EXR.
    pub a: PathBuf,
    /// Reference EXR.
    pub b: PathBuf,
    /// Exit with code 1 when rel_l1 is above this.
    #[arg(long)]
    pub max_rel_l1: Option<f64>,
    /// PNG mask: white pixels are left out of the metrics.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Also compare means over K x K pixel blocks (regional error, less sensitive to noise).
    #[arg(long, value_name = "K")]
    pub block: Option<usize>,
}

pub fn compare(args: CompareArgs) -> Result<ExitCode> {
    let a = output::read_exr(&args.a)?;
    let b = output::read_exr(&args.b)?;
    let mask = match &args.mask {
        Some(p) => {
            let (w, h, m) = read_mask(p)?;
            if (w, h) != (b.width, b.height) {
                anyhow::bail!(
                    "{}: mask is {w}x{h}, images are {}x{}",
                    p.display(),
                    b.width,
                    b.height
                );
            }
            Some(m)
        }
        None => None,
    };
    let m = metrics(&a, &b, mask.as_deref())?;
    if let Some(k) = args.block.filter(|&k| k > 1) {
        let block_skip = mask.as_ref().map(|m| block_mask(m, b.width, k));
        let bm = metrics(
            &block_mean(&a, k),
            &block_mean(&b, k),
            block_skip.as_deref(),
        )?;
        println!("rel_l1 of {k}x{k} block means {:.6}", bm.rel_l1);
    }
    println!("rel_l1     {:.6}", m.rel_l1);
    println!("rel_rmse   {:.6}", m.rel_rmse);
    println!(
        "mean       {:.6} {:.6} {:.6}",
        m.mean[0], m.mean[1], m.mean[2]
    );
    println!(
        "mean_ref   {:.6} {:.6} {:.6}",
        m.mean_ref[0], m.mean_ref[1], m.mean_ref[2]
    );
    println!("pixels     {}", m.pixels);
    if let Some(max) = args.max_rel_l1 {
        if m.rel_l1 > max {
            println!("FAIL: rel_l1 {:.6} > {max}", m.rel_l1);
            return Ok(ExitCode::from(1));
        }
        println!("ok: rel_l1 {:.6} <= {max}", m.rel_l1);
    }
    Ok(ExitCode::SUCCESS)
}

/// A block is left out when any of its pixels is.
fn block_mask(mask: &[bool], width: usize, k: usize) -> Vec<bool> {
    let bw = width / k;
    let bh = mask.len() / width / k;
    let mut out = vec![false; bw * bh];
    for (i, &m) in mask.iter().enumerate() {
        let (x, y) = (i % width / k, i / width / k);
        if m && x < bw && y < bh {
            out[y * bw + x] = true;
        }
    }
    out
}
