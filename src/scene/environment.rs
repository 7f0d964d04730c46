//! The environment: radiance arriving from infinitely far away, constant or read from a
//! lat-long (equirectangular) map, turned about +Y and scaled.
//!
//! Map convention, the one Mitsuba 3's `envmap` reads (checked with its renders): +Y is
//! up; a direction d looks up u = atan2(d.x, -d.z) / (2 pi) mod 1 (u = 0 towards -Z, 0.25
//! towards +X) and v = acos(d.y) / pi (row 0, the top of the image, is +Y). Texel (i, j) of
//! a W x H map is centred at ((i + 0.5) / W, (j + 0.5) / H) and radiance between centres is
//! bilinear, periodic in u. (Mitsuba puts row j at v = j / (H - 1) instead, a shift of at
//! most half a row at the poles.)
//!
//! Sampling: the map is cut into one cell per texel, each a band of (phi, cos theta), and a
//! cell is drawn with probability proportional to its solid angle times the mean of the
//! bilinear luminance over it, then a direction uniformly in solid angle inside the cell.
//! Every direction the bilinear radiance can light has a positive density, so the estimate
//! is unbiased, and its density follows the map's luminance.
use glam::{Mat3, Vec2, Vec3};
use std::f32::consts::PI;
use std::fmt;
use std::path::Path;
use std::sync::Arc;

use crate::core::Rgb;
use crate::error::{Error, Result};
use crate::sampling::{uniform_sphere, Discrete};

/// Rec. 709 luminance weights: every channel counts, so a texel with any light is drawn.
const LUMINANCE: Vec3 = Vec3::new(0.2126, 0.7152, 0.0722);

/// A lat-long radiance map with its sampling distribution.
pub struct EnvMap {
    texels: Texels,
    cells: Discrete,
    /// The integral of the map's radiance over the sphere (piecewise constant texels).
    integral: Rgb,
    /// blake3 of the texels: two maps are equal when their texels are.
    hash: [u8; 32],
    /// Where the map came from, for `ppb info` and errors.
    pub name: String,
}

impl fmt::Debug for EnvMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "EnvMap({} x {} from {})",
            self.texels.width, self.texels.height, self.name
        )
    }
}

impl PartialEq for EnvMap {
    fn eq(&self, other: &Self) -> bool {
        (self.size(), self.hash) == (other.size(), other.hash)
    }
}

/// The map's u, v of a unit direction (map space).
pub fn dir_to_uv(d: Vec3) -> Vec2 {
    let u = d.x.atan2(-d.z) / (2.0 * PI);
    let v = d.y.clamp(-1.0, 1.0).acos() / PI;
    Vec2::new(u - u.floor(), v)
}

/// The unit direction at the map's (u, v).
pub fn uv_to_dir(uv: Vec2) -> Vec3 {
    let (sin_t, cos_t) = (PI * uv.y).sin_cos();
    let (sin_p, cos_p) = (2.0 * PI * uv.x).sin_cos();
    Vec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
}

/// The direction texel (i, j) of a `width` x `height` map stands for (its centre).
pub fn texel_direction(i: usize, j: usize, width: usize, height: usize) -> Vec3 {
    uv_to_dir(Vec2::new(
        (i as f32 + 0.5) / width as f32,
        (j as f32 + 0.5) / height as f32,
    ))
}

impl EnvMap {
    /// A map of `width` x `height` linear RGB texels, row 0 at the top. Negative values
    /// (resampling ringing) read as 0; a non-finite texel is an error naming it.
    pub fn new(
        width: usize,
        height: usize,
        pixels: &[[f32; 3]],
        name: &str,
    ) -> std::result::Result<Self, String> {
        if width < 1 || height < 1 || pixels.len() != width * height {
            return Err(format!(
                "expected a lat-long map of at least 1 x 1 texels, got {width} x {height} with {} texels",
                pixels.len()
            ));
        }
        if let Some(i) = pixels.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(format!(
                "texel ({}, {}) is not finite: {:?}",
                i % width,
                i / width,
                pixels[i]
            ));
        }
        let texels = Texels {
            width,
            height,
            data: pixels
                .iter()
                .map(|p| Vec3::from(*p).max(Vec3::ZERO))
                .collect(),
        };
        let mut hasher = blake3::Hasher::new();
        hasher.update(bytemuck::cast_slice(pixels));
        hasher.update(&(width as u64).to_le_bytes());
        Ok(EnvMap {
            cells: Discrete::new(texels.cell_weights()).ok_or("the map is black everywhere")?,
            integral: texels.integral(),
            texels,
            hash: *hasher.finalize().as_bytes(),
            name: name.to_string(),
        })
    }

    /// Reads an OpenEXR (`.exr`) or Radiance (`.hdr`, `.pic`) lat-long map from its bytes.
    pub fn decode(path: &Path, bytes: &[u8]) -> Result<Self> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        let (width, height, pixels) = match ext.as_deref() {
            Some("exr") => {
                let img = crate::output::decode_exr(path, bytes)?;
                (img.width, img.height, img.pixels)
            }
            Some("hdr") | Some("pic") => decode_hdr(path, bytes)?,
            _ => {
                return Err(Error::format(
                    path,
                    "expected a lat-long environment map ending in .exr, .hdr or .pic",
                ))
            }
        };
        EnvMap::new(width, height, &pixels, &path.display().to_string())
            .map_err(|msg| Error::format(path, msg))
    }

    pub fn size(&self) -> (usize, usize) {
        (self.texels.width, self.texels.height)
    }

    /// Radiance seen along unit map-space direction `d` (bilinear).
    pub fn eval(&self, d: Vec3) -> Rgb {
        self.texels.eval(d)
    }

    /// Integral of the radiance over the sphere of directions (W/m^2 per channel).
    pub fn integral(&self) -> Rgb {
        self.integral
    }

    /// A map-space direction drawn by the cells' distribution, with its solid-angle pdf.
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let (cell, prob, rest) = self.cells.sample(u.x);
        let (i, j) = (cell % self.texels.width, cell / self.texels.width);
        let (c0, c1) = self.texels.row_cos(j);
        let cos_t = c0 + (c1 - c0) * u.y;
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = 2.0 * PI * (i as f32 + rest) / self.texels.width as f32;
        let d = Vec3::new(sin_t * phi.sin(), cos_t, -sin_t * phi.cos());
        (d, prob / self.texels.cell_solid_angle(j))
    }

    /// The solid-angle pdf of [`Self::sample`] drawing map-space direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        let uv = dir_to_uv(d);
        let i = ((uv.x * self.texels.width as f32) as usize).min(self.texels.width - 1);
        let j = ((uv.y * self.texels.height as f32) as usize).min(self.texels.height - 1);
        self.cells.prob(j * self.texels.width + i) / self.texels.cell_solid_angle(j)
    }
}

/// A map's texels, row-major with row 0 at +Y: its lookup and its cells' geometry.
struct Texels {
    width: usize,
    height: usize,
    data: Vec<Rgb>,
}

impl Texels {
    /// Texel (i, j): periodic in i, clamped in j.
    fn texel(&self, i: isize, j: isize) -> Rgb {
        let i = i.rem_euclid(self.width as isize) as usize;
        let j = j.clamp(0, self.height as isize - 1) as usize;
        self.data[j * self.width + i]
    }

    /// cos theta at the top and bottom of row j.
    fn row_cos(&self, j: usize) -> (f32, f32) {
        let h = self.height as f32;
        ((PI * j as f32 / h).cos(), (PI * (j + 1) as f32 / h).cos())
    }

    fn cell_solid_angle(&self, j: usize) -> f32 {
        let (c0, c1) = self.row_cos(j);
        2.0 * PI / self.width as f32 * (c0 - c1)
    }

    /// Each cell's solid angle times the mean of the bilinear luminance over it: the
    /// texels' luminance filtered by (1/8, 3/4, 1/8) in u and in v, the mean of a tent
    /// over one texel's width.
    fn cell_weights(&self) -> Vec<f64> {
        const TAPS: [(isize, f32); 3] = [(-1, 0.125), (0, 0.75), (1, 0.125)];
        let mut w = Vec::with_capacity(self.width * self.height);
        for j in 0..self.height {
            let omega = self.cell_solid_angle(j) as f64;
            for i in 0..self.width {
                let mut lum = 0.0f32;
                for (dj, wj) in TAPS {
                    for (di, wi) in TAPS {
                        let t = self.texel(i as isize + di, j as isize + dj);
                        lum += wi * wj * t.dot(LUMINANCE);
                    }
                }
                w.push(lum as f64 * omega);
            }
        }
        w
    }

    /// The integral of the radiance over the sphere, the texels piecewise constant.
    fn integral(&self) -> Rgb {
        (0..self.height)
            .map(|j| {
                let row: Rgb = (0..self.width)
                    .map(|i| self.texel(i as isize, j as isize))
                    .sum();
                row * self.cell_solid_angle(j)
            })
            .sum()
    }

    /// Radiance seen along unit map-space direction `d` (bilinear).
    fn eval(&self, d: Vec3) -> Rgb {
        let uv = dir_to_uv(d);
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        let (i, j) = (x.floor(), y.floor());
        let (fx, fy) = (x - i, y - j);
        let (i, j) = (i as isize, j as isize);
        let top = self.texel(i, j).lerp(self.texel(i + 1, j), fx);
        let bottom = self.texel(i, j + 1).lerp(self.texel(i + 1, j + 1), fx);
        top.lerp(bottom, fy)
    }
}

/// Radiance HDR through the `image` crate's decoder (RGBE, flat or run-length rows).
///
/// The header's size is checked against the file's before the pixels are allocated (12
/// bytes each), as for EXR: run-length rows pack at most 127 texels' bytes into 2, so a
/// file holds at most 64 texels per byte, and a damaged header claiming more is refused
/// instead of asking for an allocation that would abort the process.
fn decode_hdr(path: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    use image::ImageDecoder;
    let bad = |e: image::ImageError| Error::format(path, format!("reading Radiance HDR: {e}"));
    let dec = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(bytes)).map_err(bad)?;
    let (w, h) = dec.dimensions();
    let texels = w as u64 * h as u64;
    let limit = (1u64 << 22).max(bytes.len() as u64 * 64);
    if texels > limit {
        return Err(Error::format(
            path,
            format!(
                "Radiance HDR of {w} x {h} texels cannot be stored in {} bytes",
                bytes.len()
            ),
        ));
    }
    let mut buf = vec![0u8; dec.total_bytes() as usize];
    dec.read_image(&mut buf).map_err(bad)?;
    let floats: &[f32] = bytemuck::try_cast_slice(&buf)
        .map_err(|e| Error::format(path, format!("reading Radiance HDR: {e}")))?;
    let pixels = floats.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok((w as usize, h as usize, pixels))
}

/// Radiance arriving from every direction at infinity: `radiance` times the map (or
/// constant without one), the map's directions turned into the world's by `to_world`.
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    pub radiance: Rgb,
    pub map: Option<Arc<EnvMap>>,
    /// An orthonormal matrix, map space to world.
    pub to_world: Mat3,
}

impl Environment {
    pub fn constant(radiance: Rgb) -> Self {
        Environment {
            radiance,
            map: None,
            to_world: Mat3::IDENTITY,
        }
    }

    /// The map turned by `degrees` about +Y (right-handed: 90 brings the map's -Z, its
    /// u = 0, to world -X).
    pub fn turned_about_y(self, degrees: f32) -> Self {
        Environment {
            to_world: Mat3::from_rotation_y(degrees.to_radians()),
            ..self
        }
    }

    fn to_map(&self, d: Vec3) -> Vec3 {
        self.to_world.transpose() * d
    }

    fn to_world(&self, m: Vec3) -> Vec3 {
        self.to_world * m
    }

    /// Radiance arriving from world direction `d` (W/(m^2 sr)).
    pub fn eval(&self, d: Vec3) -> Rgb {
        match &self.map {
            Some(m) => self.radiance * m.eval(self.to_map(d)),
            None => self.radiance,
        }
    }

    /// A world direction towards the environment, the radiance from it, and its
    /// solid-angle pdf: by the map's luminance, or uniform over the sphere.
    pub fn sample(&self, u: Vec2) -> (Vec3, Rgb, f32) {
        match &self.map {
            Some(m) => {
                let (d, pdf) = m.sample(u);
                (self.to_world(d), self.radiance * m.eval(d), pdf)
            }
            None => (uniform_sphere(u), self.radiance, 1.0 / (4.0 * PI)),
        }
    }

    /// The solid-angle pdf of [`Self::sample`] at world direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        match &self.map {
            Some(m) => m.pdf(self.to_map(d)),
            None => 1.0 / (4.0 * PI),
        }
    }

    /// Irradiance integrated over the sphere, int L dw (W/m^2 per channel).
    pub fn integral(&self) -> Rgb {
        match &self.map {
            Some(m) => self.radiance * m.integral(),
            None => self.radiance * (4.0 * PI),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// A 16 x 8 map: a gradient, a bright texel and a black band (every cell kind).
    fn test_map() -> EnvMap {
        let (w, h) = (16, 8);
        let px: Vec<[f32; 3]> = (0..w * h)
            .map(|k| {
                let (i, j) = (k % w, k / w);
                match (i, j) {
                    (5, 2) => [40.0, 30.0, 20.0],
                    (_, 6) => [0.0; 3],
                    _ => [0.1 + 0.05 * i as f32, 0.2, 0.3 + 0.1 * j as f32],
                }
            })
            .collect();
        EnvMap::new(w, h, &px, "test").expect("valid map")
    }

    fn lum(c: Rgb) -> f64 {
        c.dot(LUMINANCE) as f64
    }

    #[test]
    fn directions_and_uv_are_inverse_and_follow_the_convention() {
        let cases = [
            (Vec3::NEG_Z, 0.0, 0.5),
            (Vec3::X, 0.25, 0.5),
            (Vec3::Z, 0.5, 0.5),
            (Vec3::NEG_X, 0.75, 0.5),
        ];
        for (d, u, v) in cases {
            let uv = dir_to_uv(d);
            assert!((uv - Vec2::new(u, v)).length() < 1e-6, "{d}: {uv}");
        }
        assert!(dir_to_uv(Vec3::Y).y < 1e-6 && dir_to_uv(Vec3::NEG_Y).y > 1.0 - 1e-6);
        let mut rng = Rng::new(1, 2);
        for _ in 0..1000 {
            let d = uniform_sphere(rng.vec2());
            assert!((uv_to_dir(dir_to_uv(d)) - d).length() < 1e-5, "{d}");
        }
    }

    /// At a texel's centre the bilinear radiance is the texel; halfway between two
    /// neighbours across u = 0 it is their mean (periodic).
    #[test]
    fn lookup_is_bilinear_between_texel_centres_and_periodic() {
        let m = test_map();
        let centre = |i: usize, j: usize| {
            uv_to_dir(Vec2::new((i as f32 + 0.5) / 16.0, (j as f32 + 0.5) / 8.0))
        };
        assert!((m.eval(centre(5, 2)) - Vec3::new(40.0, 30.0, 20.0)).length() < 1e-3);
        assert!((m.eval(centre(3, 4)) - m.texels.texel(3, 4)).length() < 1e-5);
        let seam = m.eval(uv_to_dir(Vec2::new(0.0, 4.5 / 8.0)));
        let want = 0.5 * (m.texels.texel(0, 4) + m.texels.texel(15, 4));
        assert!((seam - want).length() < 1e-4, "{seam} vs {want}");
    }

    /// The pdf integrates to 1 over the sphere, and is the density `sample` reports.
    #[test]
    fn pdf_integrates_to_one_and_matches_the_samples() {
        let m = test_map();
        let (nc, np) = (800, 1600);
        let mut sum = 0.0f64;
        for a in 0..nc {
            let c = -1.0 + 2.0 * (a as f32 + 0.5) / nc as f32;
            let s = (1.0 - c * c).sqrt();
            for b in 0..np {
                let phi = 2.0 * PI * (b as f32 + 0.5) / np as f32;
                sum += m.pdf(Vec3::new(s * phi.sin(), c, -s * phi.cos())) as f64;
            }
        }
        let integral = sum * 4.0 * std::f64::consts::PI / (nc * np) as f64;
        assert!((integral - 1.0).abs() < 1e-3, "integral {integral}");
        let mut rng = Rng::new(3, 4);
        for _ in 0..10_000 {
            let (d, pdf) = m.sample(rng.vec2());
            assert!((d.length() - 1.0).abs() < 1e-5);
            assert!(
                (m.pdf(d) / pdf - 1.0).abs() < 1e-3,
                "{d}: {} vs {pdf}",
                m.pdf(d)
            );
        }
    }

    /// Chi-square of 400 000 samples over each cell's four quarters (halves in phi and
    /// in cos theta) against the stated density: a cell's share is its solid angle times
    /// the mean over the cell, in (u, v), of the bilinear luminance (here by a 16 x 16
    /// midpoint rule on `eval`), spread uniformly in solid angle inside it. The black
    /// band's neighbours get samples, the band's middle none.
    #[test]
    fn samples_follow_the_luminance_chi_square() {
        let m = test_map();
        let (w, h) = (16usize, 8usize);
        let q = 16;
        let mut share = vec![0.0f64; w * h];
        for j in 0..h {
            for i in 0..w {
                let mut mean = 0.0;
                for a in 0..q {
                    for b in 0..q {
                        let u = (i as f32 + (b as f32 + 0.5) / q as f32) / w as f32;
                        let v = (j as f32 + (a as f32 + 0.5) / q as f32) / h as f32;
                        mean += lum(m.eval(uv_to_dir(Vec2::new(u, v))));
                    }
                }
                share[j * w + i] = mean / (q * q) as f64 * m.texels.cell_solid_angle(j) as f64;
            }
        }
        let total: f64 = share.iter().sum();
        let n = 400_000;
        let mut counts = vec![0u32; 4 * w * h];
        let mut rng = Rng::new(11, 12);
        for _ in 0..n {
            let (d, _) = m.sample(rng.vec2());
            let uv = dir_to_uv(d);
            let x = ((uv.x * 2.0 * w as f32) as usize).min(2 * w - 1);
            let j = ((uv.y * h as f32) as usize).min(h - 1);
            let (c0, c1) = m.texels.row_cos(j);
            let lower = d.y < 0.5 * (c0 + c1);
            counts[(2 * j + lower as usize) * 2 * w + x] += 1;
        }
        let (mut chi2, mut dof) = (0.0, 0);
        for (k, &obs) in counts.iter().enumerate() {
            let (x, row) = (k % (2 * w), k / (2 * w));
            let expected = n as f64 * share[(row / 2) * w + x / 2] / total / 4.0;
            if expected == 0.0 {
                assert_eq!(obs, 0, "sub-cell {x}, {row} has no density");
                continue;
            }
            chi2 += (obs as f64 - expected).powi(2) / expected;
            dof += 1;
        }
        let dof = (dof - 1) as f64;
        // The chi-square's mean is dof, its standard deviation sqrt(2 dof).
        eprintln!("chi2 {chi2:.1} with {dof} degrees of freedom");
        assert!(
            chi2 < dof + 5.0 * (2.0 * dof).sqrt(),
            "chi2 {chi2}, dof {dof}"
        );
        let black_middle = (6 * w + 3..6 * w + 13).all(|c| share[c] > 0.0);
        assert!(black_middle, "the tent reaches into the black band's cells");
    }

    /// The integral is the texels' radiance times their solid angles; the turn about +Y
    /// carries the map's -Z to world -X at 90 degrees, and sampling turns with it.
    #[test]
    fn rotation_turns_lookup_and_sampling_together() {
        let m = Arc::new(test_map());
        let env = Environment {
            map: Some(m.clone()),
            ..Environment::constant(Vec3::splat(2.0))
        }
        .turned_about_y(90.0);
        let d = Vec3::new(0.3, 0.2, -0.9).normalize();
        let turned = Vec3::new(d.z, d.y, -d.x);
        assert!((env.eval(turned) - 2.0 * m.eval(d)).length() < 1e-4);
        assert!((env.pdf(turned) - m.pdf(d)).abs() < 1e-4 * m.pdf(d));
        let mut rng = Rng::new(7, 8);
        for _ in 0..100 {
            let (dir, radiance, pdf) = env.sample(rng.vec2());
            assert!((env.eval(dir) - radiance).length() < 1e-3 * radiance.length().max(1.0));
            assert!((env.pdf(dir) / pdf - 1.0).abs() < 1e-3);
        }
        let sum: Rgb = (0..8)
            .map(|j| {
                (0..16).map(|i| m.texels.texel(i, j)).sum::<Rgb>()
                    * m.texels.cell_solid_angle(j as usize)
            })
            .sum();
        assert!((env.integral() - 2.0 * sum).length() < 1e-4 * sum.length());
    }

    #[test]
    fn bad_maps_are_errors() {
        let nan = [[0.0, f32::NAN, 0.0]; 4];
        let e = EnvMap::new(2, 2, &nan, "x").unwrap_err();
        assert!(e.contains("texel (0, 0) is not finite"), "{e}");
        assert!(EnvMap::new(2, 2, &[[0.0; 3]; 4], "x")
            .unwrap_err()
            .contains("black"));
        assert!(EnvMap::new(3, 2, &[[1.0; 3]; 4], "x").is_err());
        let e = EnvMap::decode(Path::new("sky.png"), b"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("sky.png") && e.contains(".exr, .hdr"), "{e}");
        let e = EnvMap::decode(Path::new("sky.hdr"), b"#?RADIANCE\nbroken")
            .unwrap_err()
            .to_string();
        assert!(e.contains("sky.hdr") && e.contains("Radiance HDR"), "{e}");
        // A header claiming 10^10 texels in a few bytes is refused before any allocation.
        let huge = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n";
        let e = EnvMap::decode(Path::new("huge.hdr"), huge)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("huge.hdr") && e.contains("100000 x 100000"),
            "{e}"
        );
    }

    /// A Radiance file written by the `image` crate's encoder reads back within RGBE's
    /// 8-bit mantissa.
    #[test]
    fn radiance_hdr_reads_back() {
        let (w, h) = (6usize, 3usize);
        let px: Vec<image::Rgb<f32>> = (0..w * h)
            .map(|k| image::Rgb([0.5 + k as f32, 0.25, 3.0 / (1.0 + k as f32)]))
            .collect();
        let mut bytes = Vec::new();
        image::codecs::hdr::HdrEncoder::new(&mut bytes)
            .encode(&px, w, h)
            .expect("encodes");
        let m = EnvMap::decode(Path::new("t.hdr"), &bytes).expect("decodes");
        assert_eq!(m.size(), (w, h));
        for (k, p) in px.iter().enumerate() {
            let got = m.texels.texel((k % w) as isize, (k / w) as isize);
            let want = Vec3::from(p.0);
            // One exponent for the three channels: 8 bits relative to the largest.
            let tol = want.max_element() / 128.0;
            assert!((got - want).abs().max_element() < tol, "{got} vs {want}");
        }
    }
}
