//! Image metrics used by `ppb compare` and the conformance tests:
//! rel_l1 = sum|x - ref| / sum|ref| over all pixels and channels (SPEC.md),
//! rel_rmse = sqrt(mean (x - ref)^2) / mean |ref|.
use crate::core::Rgb;
use crate::error::{Error, Result};
use crate::output::Image;

#[derive(Clone, Debug, serde::Serialize)]
pub struct Metrics {
    pub rel_l1: f64,
    pub rel_rmse: f64,
    pub mean: [f64; 3],
    pub mean_ref: [f64; 3],
    pub pixels: usize,
}

/// Compares `x` to `reference`, skipping pixels where `skip` is true.
pub fn compare(x: &Image, reference: &Image, skip: Option<&[bool]>) -> Result<Metrics> {
    if (x.width, x.height) != (reference.width, reference.height) {
        return Err(Error::Other(format!(
            "image sizes differ: {}x{} vs {}x{}",
            x.width, x.height, reference.width, reference.height
        )));
    }
    let (mut abs, mut sq, mut sum_ref) = (0.0f64, 0.0f64, 0.0f64);
    let mut mean = [0.0f64; 3];
    let mut mean_ref = [0.0f64; 3];
    let mut n = 0usize;
    for (i, (a, b)) in x.pixels.iter().zip(&reference.pixels).enumerate() {
        if skip.is_some_and(|s| s[i]) {
            continue;
        }
        n += 1;
        for c in 0..3 {
            let (a, b) = (a[c] as f64, b[c] as f64);
            abs += (a - b).abs();
            sq += (a - b) * (a - b);
            sum_ref += b.abs();
            mean[c] += a;
            mean_ref[c] += b;
        }
    }
    let nf = n.max(1) as f64;
    let mean_abs_ref = sum_ref / (3.0 * nf);
    Ok(Metrics {
        rel_l1: abs / sum_ref.max(f64::MIN_POSITIVE),
        rel_rmse: (sq / (3.0 * nf)).sqrt() / mean_abs_ref.max(f64::MIN_POSITIVE),
        mean: mean.map(|m| m / nf),
        mean_ref: mean_ref.map(|m| m / nf),
        pixels: n,
    })
}

/// How far the GPU's per-pixel beam estimate is from the CPU's, summed over passes.
#[derive(Clone, Copy, Debug, Default)]
pub struct DeviceDiff {
    /// sum |gpu - cpu| and sum |cpu| over pixels and channels.
    pub diff: f64,
    pub total: f64,
    /// Pixels where some channel differs by more than 1e-3 of max(its CPU value, 1e-3 of
    /// the image's largest): a crossing at distance ~r or at a beam piece's end can be
    /// decided differently by float32 rounding on the two devices, moving one whole term.
    pub off_pixels: usize,
    /// Pixels with any CPU radiance.
    pub lit_pixels: usize,
}

impl DeviceDiff {
    /// Adds one pass: `cpu` per-pixel radiance, `gpu` the accumulator (w is not radiance).
    pub fn add(&mut self, cpu: &[Rgb], gpu: &[[f32; 4]]) {
        let top = cpu.iter().map(|c| c.max_element()).fold(0.0f32, f32::max) as f64;
        for (c, g) in cpu.iter().zip(gpu) {
            let mut off = false;
            for k in 0..3 {
                let (a, b) = (c[k] as f64, g[k] as f64);
                self.diff += (a - b).abs();
                self.total += a.abs();
                off |= (a - b).abs() > 1e-3 * a.abs().max(1e-3 * top);
            }
            self.off_pixels += usize::from(off);
            self.lit_pixels += usize::from(c.max_element() > 0.0);
        }
    }

    /// sum |gpu - cpu| / sum |cpu|.
    pub fn rel_l1(&self) -> f64 {
        self.diff / self.total.max(1e-300)
    }
}

/// Means over `k` x `k` pixel blocks (the image size must divide by k).
pub fn block_mean(img: &Image, k: usize) -> Image {
    let (w, h) = (img.width / k, img.height / k);
    let mut pixels = vec![[0f32; 3]; w * h];
    for y in 0..h * k {
        for x in 0..w * k {
            let p = img.pixels[y * img.width + x];
            let o = &mut pixels[(y / k) * w + x / k];
            for c in 0..3 {
                o[c] += p[c] / (k * k) as f32;
            }
        }
    }
    Image {
        width: w,
        height: h,
        pixels,
        alpha: None,
    }
}

/// Reads a mask PNG: true where the pixel is bright (> 127 in its first channel).
pub fn read_mask(path: &std::path::Path) -> Result<(usize, usize, Vec<bool>)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec
        .read_info()
        .map_err(|e| Error::format(path, e.to_string()))?;
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| Error::format(path, e.to_string()))?;
    let ch = info.color_type.samples();
    let (w, h) = (info.width as usize, info.height as usize);
    let mask = (0..w * h).map(|i| buf[i * ch] > 127).collect();
    Ok((w, h, mask))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rel_l1_definition() {
        let r = Image {
            width: 2,
            height: 1,
            pixels: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            alpha: None,
        };
        let mut x = r.clone();
        x.pixels[0][0] = 2.0;
        let m = compare(&x, &r, None).unwrap();
        assert!((m.rel_l1 - 1.0 / 21.0).abs() < 1e-12);
        let m = compare(&x, &r, Some(&[true, false])).unwrap();
        assert_eq!(m.rel_l1, 0.0);
        let b = block_mean(
            &Image {
                width: 2,
                height: 2,
                pixels: vec![[1.0; 3], [3.0; 3], [5.0; 3], [7.0; 3]],
                alpha: None,
            },
            2,
        );
        assert_eq!(b.pixels, vec![[4.0; 3]]);
    }
}
