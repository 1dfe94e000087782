//! Image files: PNG (8/16-bit grey or RGB, values in [0, 1]) and single-channel float32 EXR depth.
//! Every write goes to a temporary file in the target directory and is renamed into place, so a
//! reader never sees a half-written file.

use std::fs;
use std::path::{Path, PathBuf};

use exr::prelude::{
    read_first_flat_layer_from_file, AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer,
    LayerAttributes, WritableImage,
};
use image::{DynamicImage, ImageBuffer, ImageFormat, Luma, Rgb};

#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {what}")]
    File { path: String, what: String },
    #[error("image data has {got} values, expected {expected} for {height}x{width}x{channels}")]
    Shape {
        got: usize,
        expected: usize,
        height: usize,
        width: usize,
        channels: usize,
    },
    #[error("{0} channels are not supported; use 1 (grey) or 3 (RGB)")]
    Channels(usize),
}

fn file_err(path: &Path, what: impl std::fmt::Display) -> IoError {
    IoError::File {
        path: path.display().to_string(),
        what: what.to_string(),
    }
}

/// A decoded image: row-major, `channels` interleaved float32 values per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatImage {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp{}", std::process::id()))
}

/// Run `write` on a temporary sibling of `path`, then rename it over `path`.
fn atomically(path: &Path, write: impl FnOnce(&Path) -> Result<(), String>) -> Result<(), IoError> {
    let tmp = temp_path(path);
    match write(&tmp) {
        Ok(()) => fs::rename(&tmp, path).map_err(|e| {
            let _ = fs::remove_file(&tmp);
            file_err(path, e)
        }),
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(file_err(path, e))
        }
    }
}

fn check_shape(data: &[f32], width: usize, height: usize, channels: usize) -> Result<(), IoError> {
    if data.len() != width * height * channels {
        return Err(IoError::Shape {
            got: data.len(),
            expected: width * height * channels,
            height,
            width,
            channels,
        });
    }
    Ok(())
}

/// Write values in [0, 1] (clamped; NaN -> 0) as a PNG of 8 or 16 bits per sample.
pub fn write_png(
    path: &Path,
    data: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    bits16: bool,
) -> Result<(), IoError> {
    check_shape(data, width, height, channels)?;
    let (w, h) = (width as u32, height as u32);
    let q = |v: f32, max: f32| (if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * max).round();
    let img = match (channels, bits16) {
        (1, false) => DynamicImage::ImageLuma8(
            ImageBuffer::<Luma<u8>, _>::from_vec(
                w,
                h,
                data.iter().map(|&v| q(v, 255.0) as u8).collect(),
            )
            .ok_or_else(|| file_err(path, "buffer size"))?,
        ),
        (1, true) => DynamicImage::ImageLuma16(
            ImageBuffer::<Luma<u16>, _>::from_vec(
                w,
                h,
                data.iter().map(|&v| q(v, 65535.0) as u16).collect(),
            )
            .ok_or_else(|| file_err(path, "buffer size"))?,
        ),
        (3, false) => DynamicImage::ImageRgb8(
            ImageBuffer::<Rgb<u8>, _>::from_vec(
                w,
                h,
                data.iter().map(|&v| q(v, 255.0) as u8).collect(),
            )
            .ok_or_else(|| file_err(path, "buffer size"))?,
        ),
        (3, true) => DynamicImage::ImageRgb16(
            ImageBuffer::<Rgb<u16>, _>::from_vec(
                w,
                h,
                data.iter().map(|&v| q(v, 65535.0) as u16).collect(),
            )
            .ok_or_else(|| file_err(path, "buffer size"))?,
        ),
        (c, _) => return Err(IoError::Channels(c)),
    };
    atomically(path, |tmp| {
        img.save_with_format(tmp, ImageFormat::Png)
            .map_err(|e| e.to_string())
    })
}

/// Read a PNG as floats in [0, 1]: grey images give 1 channel, colour images 3 (alpha dropped).
pub fn read_png(path: &Path) -> Result<FloatImage, IoError> {
    let img = image::ImageReader::open(path)
        .map_err(|e| file_err(path, e))?
        .with_guessed_format()
        .map_err(|e| file_err(path, e))?
        .decode()
        .map_err(|e| file_err(path, format!("not a readable image ({e})")))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let (channels, data) = if img.color().has_color() {
        (3, img.to_rgb32f().into_raw())
    } else {
        (
            1,
            img.into_luma16()
                .into_raw()
                .into_iter()
                .map(|v| v as f32 / 65535.0)
                .collect(),
        )
    };
    Ok(FloatImage {
        width,
        height,
        channels,
        data,
    })
}

/// Name of the depth channel in the EXR files we write (OpenEXR's convention for depth).
const DEPTH_CHANNEL: &str = "Z";

/// Write a float32 depth map as a one-channel ("Z") EXR, ZIP-compressed (lossless).
pub fn write_exr(path: &Path, depth: &[f32], width: usize, height: usize) -> Result<(), IoError> {
    check_shape(depth, width, height, 1)?;
    let channel = AnyChannel::new(DEPTH_CHANNEL, FlatSamples::F32(depth.to_vec()));
    let layer = Layer::new(
        (width, height),
        LayerAttributes::named("depth"),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(smallvec_one(channel)),
    );
    let image = Image::from_layer(layer);
    atomically(path, |tmp| {
        image.write().to_file(tmp).map_err(|e| e.to_string())
    })
}

fn smallvec_one(
    c: AnyChannel<FlatSamples>,
) -> exr::prelude::SmallVec<[AnyChannel<FlatSamples>; 4]> {
    let mut v = exr::prelude::SmallVec::new();
    v.push(c);
    v
}

/// Read the "Z" channel of an EXR (or its only channel) as float32.
pub fn read_exr(path: &Path) -> Result<FloatImage, IoError> {
    let image = read_first_flat_layer_from_file(path)
        .map_err(|e| file_err(path, format!("not a readable EXR ({e})")))?;
    let layer = image.layer_data;
    let list = &layer.channel_data.list;
    let channel = list
        .iter()
        .find(|c| c.name.to_string() == DEPTH_CHANNEL)
        .or(if list.len() == 1 { list.first() } else { None })
        .ok_or_else(|| {
            file_err(
                path,
                format!("no '{DEPTH_CHANNEL}' channel among {} channels", list.len()),
            )
        })?;
    let data: Vec<f32> = channel.sample_data.values_as_f32().collect();
    Ok(FloatImage {
        width: layer.size.width(),
        height: layer.size.height(),
        channels: 1,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("evsplat-io-{name}-{}", std::process::id()));
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn png16_round_trip_is_within_quantisation() {
        let d = tmpdir("png");
        let data: Vec<f32> = (0..4 * 3 * 3).map(|i| i as f32 / 35.0).collect();
        write_png(&d.join("a.png"), &data, 4, 3, 3, true).unwrap();
        let img = read_png(&d.join("a.png")).unwrap();
        assert_eq!((img.width, img.height, img.channels), (4, 3, 3));
        assert!(img
            .data
            .iter()
            .zip(&data)
            .all(|(a, b)| (a - b).abs() <= 0.5 / 65535.0 + 1e-7));
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1); // no temporary left behind
    }

    #[test]
    fn exr_round_trip_is_exact() {
        let d = tmpdir("exr");
        let data: Vec<f32> = (0..5 * 7).map(|i| 0.5 + i as f32 * 0.123).collect();
        write_exr(&d.join("z.exr"), &data, 5, 7).unwrap();
        let img = read_exr(&d.join("z.exr")).unwrap();
        assert_eq!((img.width, img.height), (5, 7));
        assert_eq!(img.data, data);
    }
}
