//! Part files: one task's fixed-point film sums over a range of passes, with what a merge
//! must check (scene and asset hash, settings, size, seed, frame, version). Written
//! atomically; a torn, truncated or foreign file is refused (a checksum covers all of it).
//!
//! Layout: `PPBPART4`, the header's length (u32 LE), the header (JSON), the sums
//! (width x height x RGB, i128 LE), the sums of the odd passes alone (the same), the
//! beams' and then the photons' nested sums of all and of the odd passes (the same four
//! times), a transparent film's alpha sums (width x height, i128 LE), then the blake3
//! hash of everything before it.
use std::path::{Path, PathBuf};

use crate::core::fs::write_atomic;
use crate::error::{Error, Result};
use crate::film::{error::Bandwidth, Counts, Film, Halves};
use crate::output::ExrMeta;

use super::tasks::PassRange;

const MAGIC: &[u8; 8] = b"PPBPART4";
/// Bytes of RGB sums a pixel: the image's, the beams' and the photons' nested ones, each
/// of all passes and of the odd ones.
const RGB_BYTES: u64 = 6 * 48;
/// Largest header accepted (JSON; a real one is about 2 KB).
const MAX_HEADER: usize = 1 << 20;

/// What a part file says about its sums.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PartHeader {
    /// ppb version that rendered it.
    pub version: String,
    /// The scene as the task was given it (for messages only).
    pub scene: String,
    /// blake3 of the scene file and every asset it read, in reading order.
    pub scene_hash: String,
    /// The render settings that change pixels (all but the pass count and exposure).
    pub settings: String,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    pub frame: Option<u32>,
    /// Passes of the whole frame (a merge must cover `0..passes`).
    pub passes: u32,
    /// The task's pass range, and how many of its passes are in the sums (all of them
    /// unless the task was interrupted).
    pub range: PassRange,
    pub done: u32,
    /// How many of them are odd (`PassPlan::odd`): the second half-film's passes.
    pub odd_done: u32,
    /// How many of them added the nested sums (the beams estimated on the CPU).
    pub nested_done: u32,
    /// Render seconds spent on these passes (over every run of the task).
    pub seconds: f64,
    /// PNG exposure of the merged image.
    pub exposure: f32,
    /// How the merged film becomes the image.
    pub bandwidth: Bandwidth,
    /// The pixels that see a light directly, left out of the error estimate.
    #[serde(default)]
    pub lights: Vec<u32>,
    /// EXR header attributes of the merged image.
    pub exr: ExrMeta,
}

impl PartHeader {
    /// The first field in which `o` is of another render than `self` (ppb version, scene
    /// hash, size, pixel settings, seed, frame, pass count), with both values; None when
    /// both are parts of one render. The one identity check of a merge and of a resumed
    /// task.
    pub fn differs(&self, o: &PartHeader) -> Option<(&'static str, String, String)> {
        let size = |h: &PartHeader| format!("{}x{}", h.width, h.height);
        [
            ("ppb version", self.version.clone(), o.version.clone()),
            (
                "scene hash (the scene or an asset changed)",
                self.scene_hash.clone(),
                o.scene_hash.clone(),
            ),
            ("resolution", size(self), size(o)),
            ("settings", self.settings.clone(), o.settings.clone()),
            ("seed", self.seed.to_string(), o.seed.to_string()),
            (
                "frame",
                format!("{:?}", self.frame),
                format!("{:?}", o.frame),
            ),
            ("pass count", self.passes.to_string(), o.passes.to_string()),
        ]
        .into_iter()
        .find(|(_, a, b)| a != b)
    }

    /// Whether every pass of its range is in the sums.
    pub fn complete(&self) -> bool {
        self.done == self.range.len()
    }

    /// The passes in the sums.
    pub fn finished(&self) -> PassRange {
        PassRange {
            start: self.range.start,
            end: self.range.start + self.done,
        }
    }
}

/// A part file read back.
#[derive(Clone, Debug)]
pub struct Part {
    pub path: PathBuf,
    pub header: PartHeader,
    pub film: Film,
}

impl Part {
    /// Writes `film` (its passes are `header.done`) atomically to `path`.
    pub fn write(path: &Path, header: &PartHeader, film: &Film) -> Result<()> {
        let json = serde_json::to_vec(header).map_err(|e| Error::format(path, e.to_string()))?;
        let pixels = film.sums().all.len();
        let mut bytes = Vec::with_capacity(12 + json.len() + pixels * 304 + 32);
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&(json.len() as u32).to_le_bytes());
        bytes.extend_from_slice(&json);
        let sets = [film.sums(), film.nested_sums(), film.photon_sums()];
        let rgb = sets.into_iter().flat_map(|s| [&s.all, &s.odd]);
        for px in rgb.into_iter().flatten() {
            for c in px {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
        for a in film.alpha_sums() {
            bytes.extend_from_slice(&a.to_le_bytes());
        }
        let hash = blake3::hash(&bytes);
        bytes.extend_from_slice(hash.as_bytes());
        write_atomic(path, |tmp| {
            std::fs::write(tmp, &bytes).map_err(|e| Error::io(tmp, e))
        })
    }

    /// Reads and checks a part file.
    pub fn read(path: &Path) -> Result<Part> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let bad = |msg: &str| Error::format(path, format!("not a valid ppb part file: {msg}"));
        if bytes.len() < MAGIC.len() + 4 + 32 || &bytes[..8] != MAGIC {
            return Err(bad(if bytes.starts_with(b"PPBPART") {
                "written by another version of ppb's part format (PPBPART4 expected)"
            } else {
                "no PPBPART4 signature"
            }));
        }
        let (body, hash) = bytes.split_at(bytes.len() - 32);
        if blake3::hash(body).as_bytes() != hash {
            return Err(bad("checksum mismatch (truncated or damaged)"));
        }
        let len = u32::from_le_bytes(body[8..12].try_into().unwrap_or_default()) as usize;
        if len > MAX_HEADER || 12 + len > body.len() {
            return Err(bad("header length out of range"));
        }
        let header: PartHeader = serde_json::from_slice(&body[12..12 + len])
            .map_err(|e| bad(&format!("header: {e}")))?;
        let data = &body[12 + len..];
        let pixels = header.width as u64 * header.height as u64;
        // RGB sums (RGB_BYTES a pixel), then alpha sums (16) for a transparent film.
        let rgb = pixels.checked_mul(RGB_BYTES);
        let with_alpha = pixels.checked_mul(RGB_BYTES + 16);
        if rgb != Some(data.len() as u64) && with_alpha != Some(data.len() as u64) {
            return Err(bad(&format!(
                "{} bytes of sums for {}x{} pixels",
                data.len(),
                header.width,
                header.height
            )));
        }
        if header.done > header.range.len() {
            return Err(bad("more passes done than its range holds"));
        }
        if header.odd_done > header.done || header.nested_done > header.done {
            return Err(bad("more odd or nested passes than passes done"));
        }
        let (data, alpha) = data.split_at(rgb.unwrap_or(0) as usize);
        let sixth = data.len() / 6;
        let sums = |d: &[u8]| -> Vec<[i128; 3]> {
            d.chunks_exact(48)
                .map(|px| {
                    [0, 1, 2].map(|c| {
                        i128::from_le_bytes(px[c * 16..c * 16 + 16].try_into().unwrap_or_default())
                    })
                })
                .collect()
        };
        let halves = |k: usize| Halves {
            all: sums(&data[2 * k * sixth..(2 * k + 1) * sixth]),
            odd: sums(&data[(2 * k + 1) * sixth..(2 * k + 2) * sixth]),
        };
        let counts = Counts {
            passes: header.done,
            odd: header.odd_done,
            nested: header.nested_done,
        };
        let (image, nested, photons) = (halves(0), halves(1), halves(2));
        let mut film = Film::from_sums(header.width, header.height, counts, image, nested, photons)
            .ok_or_else(|| bad("size does not match the sums"))?
            .with_lights(header.lights.clone());
        if !alpha.is_empty() {
            let alpha = alpha
                .chunks_exact(16)
                .map(|a| i128::from_le_bytes(a.try_into().unwrap_or_default()))
                .collect();
            film = film
                .with_alpha_sums(alpha)
                .ok_or_else(|| bad("alpha sums do not match the size"))?;
        }
        Ok(Part {
            path: path.to_path_buf(),
            header,
            film,
        })
    }
}

/// blake3 over the contents of `paths` (a scene file and the assets it read, in reading
/// order): what a part file's scene hash is. Names are left out, so a farm that mounts the
/// project elsewhere hashes the same.
pub fn content_hash(paths: &[PathBuf]) -> Result<String> {
    let mut all = blake3::Hasher::new();
    for p in paths {
        let mut h = blake3::Hasher::new();
        h.update_reader(std::fs::File::open(p).map_err(|e| Error::io(p, e))?)
            .map_err(|e| Error::io(p, e))?;
        all.update(h.finalize().as_bytes());
    }
    Ok(all.finalize().to_hex().to_string())
}

/// Merges the parts of one frame into one film, after checking that they belong together
/// and cover the frame's passes `0..passes` once each; returns the first part's header
/// with the merged range and summed seconds.
pub fn merge(mut parts: Vec<Part>) -> Result<(PartHeader, Film)> {
    let Some(first) = parts.first() else {
        return Err(Error::Other("no part files to merge".into()));
    };
    let h0 = first.header.clone();
    let p0 = first.path.clone();
    for p in &parts {
        let h = &p.header;
        if let Some((field, a, b)) = h0.differs(h) {
            return Err(Error::Other(format!(
                "{} and {} do not belong to one render: {field} differs ({a} vs {b})",
                p0.display(),
                p.path.display()
            )));
        }
        if !h.complete() {
            return Err(Error::Other(format!(
                "{} is partial: it holds passes {} of its range {} (the task was interrupted); run the task again to finish it",
                p.path.display(),
                h.finished(),
                h.range
            )));
        }
    }
    parts.sort_by_key(|p| p.header.range);
    let mut next = 0;
    for (i, p) in parts.iter().enumerate() {
        let r = p.header.range;
        if r.start > next {
            return Err(Error::Other(format!(
                "passes {next}..{} are missing (no part covers them)",
                r.start
            )));
        }
        if r.start < next {
            return Err(Error::Other(format!(
                "{} (passes {r}) overlaps {} (passes {})",
                p.path.display(),
                parts[i - 1].path.display(),
                parts[i - 1].header.range
            )));
        }
        next = r.end;
    }
    if next != h0.passes {
        return Err(Error::Other(format!(
            "passes {next}..{} are missing (no part covers them)",
            h0.passes
        )));
    }
    let mut film = Film::new(h0.width, h0.height).with_lights(h0.lights.clone());
    for p in &parts {
        film.merge(&p.film);
    }
    let header = PartHeader {
        range: PassRange {
            start: 0,
            end: h0.passes,
        },
        done: h0.passes,
        odd_done: film.odd_passes(),
        nested_done: film.counts().nested,
        seconds: parts.iter().map(|p| p.header.seconds).sum(),
        ..h0
    };
    Ok((header, film))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn header(range: (u32, u32), done: u32) -> PartHeader {
        PartHeader {
            version: "0".into(),
            scene: "s.toml".into(),
            scene_hash: "h".into(),
            settings: "s".into(),
            width: 2,
            height: 1,
            seed: 1,
            frame: Some(3),
            passes: 4,
            range: PassRange {
                start: range.0,
                end: range.1,
            },
            done,
            odd_done: 0,
            nested_done: 0,
            seconds: 1.0,
            exposure: 0.0,
            bandwidth: Bandwidth::Fixed,
            lights: vec![1],
            exr: ExrMeta::default(),
        }
    }

    fn part(dir: &Path, range: (u32, u32)) -> Part {
        let mut film = Film::new(2, 1).with_lights(vec![1]);
        for i in range.0..range.1 {
            film.add_pass(i % 2 == 0, &[Vec3::splat(i as f32 * 0.1), Vec3::ONE]);
            film.add_nested(i % 2 == 0, &[Vec3::splat(-0.01 * i as f32), Vec3::ZERO]);
            film.add_photon_nested(i % 2 == 0, &[Vec3::ZERO, Vec3::splat(0.02 * i as f32)]);
        }
        let path = dir.join(format!("p{}-{}.ppbpart", range.0, range.1));
        let h = PartHeader {
            odd_done: film.odd_passes(),
            nested_done: film.counts().nested,
            ..header(range, range.1 - range.0)
        };
        Part::write(&path, &h, &film).unwrap();
        let part = Part::read(&path).unwrap();
        // The half-film and nested sums and their pass counts come back too.
        assert_eq!(part.film, film);
        part
    }

    #[test]
    fn parts_round_trip_merge_and_refuse_gaps_overlaps_and_damage() {
        let dir = std::env::temp_dir().join(format!("ppb-part-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (part(&dir, (0, 1)), part(&dir, (1, 4)));
        let whole = part(&dir, (0, 4));
        let (h, film) = merge(vec![b.clone(), a.clone()]).unwrap();
        assert_eq!(film, whole.film);
        assert_eq!((h.range, h.done, h.seconds), (whole.header.range, 4, 2.0));
        let msg = |parts: Vec<Part>| merge(parts).unwrap_err().to_string();
        assert!(msg(vec![b.clone()]).contains("passes 0..1 are missing"));
        assert!(msg(vec![a.clone()]).contains("passes 1..4 are missing"));
        assert!(msg(vec![a.clone(), b.clone(), whole.clone()]).contains("overlaps"));
        let mut other = a.clone();
        other.header.scene_hash = "g".into();
        assert!(msg(vec![other, b.clone()]).contains("scene hash"));
        let mut partial = b.clone();
        partial.header.done = 2;
        assert!(msg(vec![a.clone(), partial]).contains("partial"));
        // A flipped byte or a cut file is refused.
        let mut bytes = std::fs::read(&a.path).unwrap();
        let n = bytes.len();
        bytes[n / 2] ^= 4;
        std::fs::write(&a.path, &bytes).unwrap();
        assert!(Part::read(&a.path)
            .unwrap_err()
            .to_string()
            .contains("checksum"));
        std::fs::write(&a.path, &bytes[..n - 40]).unwrap();
        assert!(Part::read(&a.path).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A transparent film's alpha sums travel in its part and merge like the colour.
    #[test]
    fn alpha_sums_round_trip_and_merge() {
        let dir = std::env::temp_dir().join(format!("ppb-part-alpha-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let film = |range: (u32, u32)| {
            let mut f = Film::new(2, 1).with_lights(vec![1]);
            for i in range.0..range.1 {
                f.add_pass(i % 2 == 0, &[Vec3::splat(i as f32), Vec3::ONE]);
                f.add_alpha(&[0.25 * i as f32, 1.0]);
            }
            f
        };
        let write = |range: (u32, u32)| {
            let path = dir.join(format!("a{}-{}.ppbpart", range.0, range.1));
            let f = film(range);
            let h = PartHeader {
                odd_done: f.odd_passes(),
                ..header(range, range.1 - range.0)
            };
            Part::write(&path, &h, &f).unwrap();
            Part::read(&path).unwrap()
        };
        let (a, b, whole) = (write((0, 1)), write((1, 4)), write((0, 4)));
        assert_eq!(whole.film, film((0, 4)));
        let (_, merged) = merge(vec![a, b]).unwrap();
        assert_eq!(merged, whole.film);
        let alpha = merged.alpha().expect("a transparent film");
        assert!((alpha[0] - 0.375).abs() < 1e-6 && (alpha[1] - 1.0).abs() < 1e-6);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
