//! Progressive accumulation: the image is the mean of the pass images (each pass is an
//! independent estimate with its own radii, as in Knaus and Zwicker's formulation).
use crate::scene::Rgb;

#[derive(Clone, Debug)]
pub struct Film {
    pub width: u32,
    pub height: u32,
    sum: Vec<[f64; 3]>,
    passes: u32,
}

impl Film {
    pub fn new(width: u32, height: u32) -> Self {
        Film {
            width,
            height,
            sum: vec![[0.0; 3]; (width * height) as usize],
            passes: 0,
        }
    }

    /// Adds `img` to the current pass's sums (one pass adds several estimates).
    pub fn add(&mut self, img: &[Rgb]) {
        for (s, p) in self.sum.iter_mut().zip(img) {
            s[0] += p.x as f64;
            s[1] += p.y as f64;
            s[2] += p.z as f64;
        }
    }

    /// Adds `img` and counts a pass.
    pub fn add_pass(&mut self, img: &[Rgb]) {
        self.add(img);
        self.passes += 1;
    }

    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// The current estimate: mean over passes, row-major RGB.
    pub fn image(&self) -> Vec<[f32; 3]> {
        let inv = 1.0 / self.passes.max(1) as f64;
        self.sum
            .iter()
            .map(|s| {
                [
                    (s[0] * inv) as f32,
                    (s[1] * inv) as f32,
                    (s[2] * inv) as f32,
                ]
            })
            .collect()
    }

    /// The current estimate with `extra` (per-pixel sums over the same passes, e.g. the GPU's
    /// beam accumulator) added.
    pub fn image_plus(&self, extra: &[[f32; 4]]) -> Vec<[f32; 3]> {
        let inv = 1.0 / self.passes.max(1) as f64;
        self.sum
            .iter()
            .zip(extra)
            .map(|(s, e)| {
                [
                    ((s[0] + e[0] as f64) * inv) as f32,
                    ((s[1] + e[1] as f64) * inv) as f32,
                    ((s[2] + e[2] as f64) * inv) as f32,
                ]
            })
            .collect()
    }
}
