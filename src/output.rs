//! Image files: EXR (float32 linear R, G, B plus render metadata as header attributes) and
//! PNG previews (exposure, clamp, sRGB). Both are written to a temporary file in the target
//! folder and renamed into place, so a reader never sees a partial image.
use std::path::Path;

use exr::prelude::*;

use crate::core::fs::write_atomic;
use crate::error::{Error, Result};

/// A linear RGB image, row-major, top row first.
#[derive(Clone, Debug)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
    /// Coverage of each pixel, written as the EXR's A channel (transparent film only).
    pub alpha: Option<Vec<f32>>,
}

/// An EXR header besides the pixels: OpenEXR's standard attributes where one exists,
/// and `ppb/...` text attributes for the rest. The capture date (UTC, `utcOffset` 0) is
/// the moment of writing.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExrMeta {
    pub owner: Option<String>,
    pub comments: Option<String>,
    pub frames_per_second: Option<f64>,
    /// Imath's row-vector convention (translation in the last row), camera looking down -Z.
    pub world_to_camera: Option<[f32; 16]>,
    pub world_to_ndc: Option<[f32; 16]>,
    /// (name, value) text attributes.
    pub text: Vec<(String, String)>,
}

impl ExrMeta {
    /// Only text attributes.
    pub fn text(text: &[(&str, String)]) -> Self {
        ExrMeta {
            text: text
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect(),
            ..Default::default()
        }
    }

    /// Sets (or adds) text attribute `name`.
    pub fn set(&mut self, name: &str, value: String) {
        match self.text.iter_mut().find(|(k, _)| k == name) {
            Some((_, v)) => *v = value,
            None => self.text.push((name.to_string(), value)),
        }
    }

    fn layer_attributes(&self) -> LayerAttributes {
        let mut a = LayerAttributes::named("");
        let text = |s: &Option<String>| s.as_deref().map(Text::from);
        a.owner = text(&self.owner);
        a.comments = text(&self.comments);
        a.capture_date = Some(Text::from(capture_date().as_str()));
        a.utc_offset = Some(0.0);
        a.frames_per_second = self.frames_per_second.map(rational);
        a.world_to_camera = self.world_to_camera;
        a.world_to_normalized_device = self.world_to_ndc;
        a.software_name = Some(Text::from(concat!("ppb ", env!("CARGO_PKG_VERSION"))));
        for (k, v) in &self.text {
            a.other.insert(
                Text::from(k.as_str()),
                AttributeValue::Text(Text::from(v.as_str())),
            );
        }
        a
    }
}

/// OpenEXR's capDate format, "YYYY:MM:DD hh:mm:ss", in UTC.
fn capture_date() -> String {
    let t = time::OffsetDateTime::now_utc();
    format!(
        "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
        t.year(),
        t.month() as u8,
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

/// Frames per second as a rational: 24 -> 24/1, 29.97 -> 2997/100 (NTSC 30000/1001 is
/// written as 2997/100, within 1e-5).
fn rational(fps: f64) -> (i32, u32) {
    let den = if fps.fract() == 0.0 { 1 } else { 1000 };
    ((fps * den as f64).round() as i32, den)
}

/// Writes an EXR with the header `meta`.
pub fn write_exr(path: &Path, img: &Image, meta: &ExrMeta) -> Result<()> {
    write_exr_with(path, img, meta, &[])
}

/// A float32 channel besides the image's own (`error.R`, ...), one value a pixel.
pub type Channel<'a> = (&'a str, Vec<f32>);

/// Writes an EXR with the header `meta` and `extra` channels after R, G, B (and A).
pub fn write_exr_with(path: &Path, img: &Image, meta: &ExrMeta, extra: &[Channel]) -> Result<()> {
    write_atomic(path, |tmp| write_any_channels(tmp, path, img, meta, extra))
}

/// An EXR whose channels are listed by name: the image's and `extra`.
fn write_any_channels(
    tmp: &Path,
    path: &Path,
    img: &Image,
    meta: &ExrMeta,
    extra: &[Channel],
) -> Result<()> {
    let rgb = |c: usize| img.pixels.iter().map(|p| p[c]).collect::<Vec<f32>>();
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = ["R", "G", "B"]
        .iter()
        .enumerate()
        .map(|(c, n)| AnyChannel::new(*n, FlatSamples::F32(rgb(c))))
        .collect();
    if let Some(a) = &img.alpha {
        list.push(AnyChannel::new("A", FlatSamples::F32(a.clone())));
    }
    for (name, v) in extra {
        if v.len() != img.pixels.len() {
            return Err(Error::Other(format!(
                "{}: channel {name} has {} values for {} pixels",
                path.display(),
                v.len(),
                img.pixels.len()
            )));
        }
        list.push(AnyChannel::new(*name, FlatSamples::F32(v.clone())));
    }
    let layer = Layer::new(
        (img.width, img.height),
        meta.layer_attributes(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    exr::prelude::Image::from_layer(layer)
        .write()
        .to_file(tmp)
        .map_err(|e| Error::format(path, format!("writing EXR: {e}")))
}

/// The text attributes of an EXR's first layer (name, value), sorted by name.
pub fn read_exr_text(path: &Path) -> Result<Vec<(String, String)>> {
    let meta = ::exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| Error::format(path, format!("reading EXR header: {e}")))?;
    let mut out: Vec<(String, String)> = meta
        .headers
        .first()
        .map(|h| {
            h.own_attributes
                .other
                .iter()
                .filter_map(|(k, v)| match v {
                    AttributeValue::Text(t) => Some((k.to_string(), t.to_string())),
                    _ => None,
                })
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    Ok(out)
}

/// Layers of at most this many pixels are read whatever the file's size.
const EXR_MIN_PIXEL_LIMIT: u64 = 1 << 22;
/// Larger layers need at least one file byte per this many pixels: a pixel's samples take
/// at least 2 bytes (one half channel) and deflate, the strongest of EXR's codecs, packs
/// at most about 1032 bytes into one.
const EXR_PIXELS_PER_BYTE: u64 = 1 << 10;

/// Reads the R, G, B channels of the first layer of an EXR.
///
/// The header's layer sizes are checked against the file's size first: the pixels are
/// allocated (12 bytes each) before any is read, so a damaged header claiming, say,
/// 100000 x 100000 pixels would otherwise ask for 120 GB and abort the process.
pub fn read_exr(path: &Path) -> Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_exr(path, &bytes)
}

/// [`read_exr`] of bytes already read from `path` (named in errors).
pub fn decode_exr(path: &Path, bytes: &[u8]) -> Result<Image> {
    let meta = ::exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| Error::format(path, format!("reading EXR header: {e}")))?;
    let limit = EXR_MIN_PIXEL_LIMIT.max((bytes.len() as u64).saturating_mul(EXR_PIXELS_PER_BYTE));
    for h in &meta.headers {
        let (w, ht) = (h.layer_size.width() as u64, h.layer_size.height() as u64);
        if w.saturating_mul(ht) > limit {
            return Err(Error::format(
                path,
                format!(
                    "EXR layer of {w} x {ht} pixels cannot be stored in {} bytes (limit {limit} pixels)",
                    bytes.len()
                ),
            ));
        }
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| {
                let (w, h) = (res.width(), res.height());
                (w, vec![[0f32; 3]; w * h])
            },
            |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| Error::format(path, format!("reading EXR: {e}")))?;
    let size = image.layer_data.size;
    Ok(Image {
        width: size.width(),
        height: size.height(),
        pixels: image.layer_data.channel_data.pixels.1,
        alpha: None,
    })
}

fn srgb_encode(x: f32) -> u8 {
    let x = x.clamp(0.0, 1.0);
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// The one tone map of every preview (the PNG and `ppb watch`'s window): linear radiance
/// times 2^exposure, clamped to [0, 1], sRGB-encoded to 8 bits; RGBA with alpha 255.
pub fn tone_map(pixels: &[[f32; 3]], exposure: f32) -> Vec<[u8; 4]> {
    let scale = 2f32.powf(exposure);
    pixels
        .iter()
        .map(|p| {
            let [r, g, b] = p.map(|c| srgb_encode(c * scale));
            [r, g, b, 255]
        })
        .collect()
}

/// PNG preview: the [`tone_map`] of the image, 8-bit RGB (a transparent film's image as
/// it is, over black: its alpha is in the EXR only).
pub fn write_png(path: &Path, img: &Image, exposure: f32) -> Result<()> {
    let bytes: Vec<u8> = tone_map(&img.pixels, exposure)
        .into_iter()
        .flat_map(|[r, g, b, _]| [r, g, b])
        .collect();
    write_atomic(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| Error::io(tmp, e))?;
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            img.width as u32,
            img.height as u32,
        );
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc
            .write_header()
            .map_err(|e| Error::format(path, e.to_string()))?;
        writer
            .write_image_data(&bytes)
            .map_err(|e| Error::format(path, e.to_string()))?;
        writer
            .finish()
            .map_err(|e| Error::format(path, e.to_string()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::fs::{sweep_temps, STALE_TEMP};

    #[test]
    fn exr_round_trip_and_atomic_failure() {
        let dir = std::env::temp_dir().join(format!("ppb-out-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.exr");
        let img = Image {
            width: 3,
            height: 2,
            pixels: (0..6).map(|i| [i as f32, 0.5, -1.0]).collect(),
            alpha: None,
        };
        let mut meta = ExrMeta::text(&[("ppb/passes", "7".into())]);
        meta.frames_per_second = Some(24.0);
        write_exr(&path, &img, &meta).unwrap();
        assert_eq!(
            read_exr_text(&path).unwrap(),
            [("ppb/passes".into(), "7".into())]
        );
        let back = read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.pixels, img.pixels);
        // A failing writer leaves the earlier file untouched and no temp file behind.
        let err = write_atomic(&path, |_| Err(Error::Other("boom".into())));
        assert!(err.is_err());
        assert_eq!(read_exr(&path).unwrap().pixels, img.pixels);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        write_png(&dir.join("a.png"), &img, 0.0).unwrap();
        // A killed writer's temp file goes once it is stale, a fresh one stays.
        let (stale, fresh) = (dir.join(".a.exr.1.tmp"), dir.join(".a.exr.2.tmp"));
        for t in [&stale, &fresh] {
            std::fs::write(t, b"half").unwrap();
        }
        let f = std::fs::File::options().write(true).open(&stale).unwrap();
        f.set_modified(std::time::SystemTime::now() - 2 * STALE_TEMP)
            .unwrap();
        sweep_temps(&dir, STALE_TEMP);
        assert!(!stale.exists() && fresh.exists() && path.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
