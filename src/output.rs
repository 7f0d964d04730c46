//! Image files: EXR (float32 linear R, G, B plus render metadata as header attributes) and
//! PNG previews (exposure, clamp, sRGB). Both are written to a temporary file in the target
//! folder and renamed into place, so a reader never sees a partial image.
use std::path::{Path, PathBuf};

use exr::prelude::*;

use crate::error::{Error, Result};

/// A linear RGB image, row-major, top row first.
#[derive(Clone, Debug)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Writes via `write` into a temp file beside `path`, then renames it over `path`.
pub fn write_atomic(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = temp_path(path);
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Writes an EXR with string attributes `meta` (name, value) in its header.
pub fn write_exr(path: &Path, img: &Image, meta: &[(String, String)]) -> Result<()> {
    write_atomic(path, |tmp| {
        let px = &img.pixels;
        let w = img.width;
        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
            let v = px[p.y() * w + p.x()];
            (v[0], v[1], v[2])
        });
        let mut layer_attrs = LayerAttributes::named("");
        for (k, v) in meta {
            layer_attrs.other.insert(
                Text::from(k.as_str()),
                AttributeValue::Text(Text::from(v.as_str())),
            );
        }
        let layer = Layer::new(
            (img.width, img.height),
            layer_attrs,
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        exr::prelude::Image::from_layer(layer)
            .write()
            .to_file(tmp)
            .map_err(|e| Error::format(path, format!("writing EXR: {e}")))
    })
}

/// Reads the R, G, B channels of the first layer of an EXR.
pub fn read_exr(path: &Path) -> Result<Image> {
    if !path.exists() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "file not found"),
        ));
    }
    let image = read_first_rgba_layer_from_file(
        path,
        |res, _| {
            let (w, h) = (res.width(), res.height());
            (w, vec![[0f32; 3]; w * h])
        },
        |(w, px), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = [r, g, b];
        },
    )
    .map_err(|e| Error::format(path, format!("reading EXR: {e}")))?;
    let size = image.layer_data.size;
    Ok(Image {
        width: size.width(),
        height: size.height(),
        pixels: image.layer_data.channel_data.pixels.1,
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

/// PNG preview: linear * 2^exposure, clamped, sRGB-encoded, 8 bit.
pub fn write_png(path: &Path, img: &Image, exposure: f32) -> Result<()> {
    let scale = 2f32.powf(exposure);
    let bytes: Vec<u8> = img
        .pixels
        .iter()
        .flat_map(|p| p.map(|c| srgb_encode(c * scale)))
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

    #[test]
    fn exr_round_trip_and_atomic_failure() {
        let dir = std::env::temp_dir().join(format!("ppb-out-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.exr");
        let img = Image {
            width: 3,
            height: 2,
            pixels: (0..6).map(|i| [i as f32, 0.5, -1.0]).collect(),
        };
        write_exr(&path, &img, &[("ppb.passes".into(), "7".into())]).unwrap();
        let back = read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.pixels, img.pixels);
        // A failing writer leaves the earlier file untouched and no temp file behind.
        let err = write_atomic(&path, |_| Err(Error::Other("boom".into())));
        assert!(err.is_err());
        assert_eq!(read_exr(&path).unwrap().pixels, img.pixels);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        write_png(&dir.join("a.png"), &img, 0.0).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
