//! Reading and writing grayscale images, with errors that name the file.

use super::FloatImage;
use crate::error::{Error, Result};
use ::image::{DynamicImage, ImageBuffer, ImageError, ImageFormat, Luma};
use std::path::{Path, PathBuf};

/// Which part of a colour image becomes the intensity that is analysed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Channel {
    Red,
    /// The default for `detect`: photoelastic analyses measure the fringe
    /// intensity in green (PeGS does), and a camera's Bayer sensor has twice as
    /// many green sites, so green is its sharpest, least noisy channel.
    #[default]
    Green,
    Blue,
    /// Luma, as the `image` crate weighs it (Rec. 709: 0.2126 R + 0.7152 G + 0.0722 B).
    Luma,
}

impl Channel {
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "red" | "r" => Ok(Channel::Red),
            "green" | "g" => Ok(Channel::Green),
            "blue" | "b" => Ok(Channel::Blue),
            "luma" | "gray" | "grey" => Ok(Channel::Luma),
            _ => Err(Error::Invalid(format!(
                "channel `{s}`: expected red, green, blue or luma"
            ))),
        }
    }
}

/// Reads an image (PNG, TIFF, BMP or JPEG; 8- or 16-bit, gray or colour) as
/// intensities in [0, 1]. Colour images are converted to luma.
pub fn load_gray(path: &Path) -> Result<FloatImage> {
    load_channel(path, Channel::Luma)
}

/// Reads an image as intensities in [0, 1]; a colour image is reduced to one
/// channel (gray images are read as they are, whatever the channel).
pub fn load_channel(path: &Path, channel: Channel) -> Result<FloatImage> {
    let reader = ::image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let decoded = reader.decode().map_err(|e| image_error(path, e))?;
    let image = match (decoded, channel) {
        (DynamicImage::ImageLuma8(g), _) => to_float(&g, 255.0),
        (DynamicImage::ImageLuma16(g), _) => to_float(&g, 65535.0),
        (other, Channel::Luma) => other.to_luma32f(),
        (DynamicImage::ImageRgb8(c), _) => pick(c.as_raw(), c.dimensions(), channel, 255.0),
        (DynamicImage::ImageRgb16(c), _) => pick(c.as_raw(), c.dimensions(), channel, 65535.0),
        (other, _) => {
            let c = other.to_rgb32f();
            pick(c.as_raw(), c.dimensions(), channel, 1.0)
        }
    };
    if image.width() == 0 || image.height() == 0 {
        return Err(Error::data(path, None, None, "the image is empty"));
    }
    Ok(image)
}

/// One channel (or the luma) of interleaved RGB samples, scaled to [0, 1],
/// without an intermediate float copy of all three channels.
fn pick<T: Copy + Into<f32>>(
    raw: &[T],
    (width, height): (u32, u32),
    channel: Channel,
    full_scale: f32,
) -> FloatImage {
    let data = raw
        .chunks_exact(3)
        .map(|p| {
            let [r, g, b]: [f32; 3] = [p[0].into(), p[1].into(), p[2].into()];
            let v = match channel {
                Channel::Red => r,
                Channel::Green => g,
                Channel::Blue => b,
                Channel::Luma => 0.2126 * r + 0.7152 * g + 0.0722 * b,
            };
            v / full_scale
        })
        .collect();
    FloatImage::from_raw(width, height, data).expect("same dimensions")
}

fn to_float<T: ::image::Primitive + Into<f32>>(
    g: &ImageBuffer<Luma<T>, Vec<T>>,
    full_scale: f32,
) -> FloatImage {
    let data = g.as_raw().iter().map(|&v| v.into() / full_scale).collect();
    FloatImage::from_raw(g.width(), g.height(), data).expect("same dimensions")
}

fn image_error(path: &Path, e: ImageError) -> Error {
    match e {
        ImageError::IoError(io) => Error::io(path, io),
        ImageError::Unsupported(u) => Error::data(
            path,
            None,
            None,
            format!("unsupported image format ({u}); use PNG, TIFF, BMP or JPEG"),
        ),
        other => Error::data(path, None, None, format!("cannot decode image: {other}")),
    }
}

/// Reads several images that must all have the same size (a sequence of frames).
pub fn load_gray_sequence(paths: &[PathBuf]) -> Result<Vec<FloatImage>> {
    let mut images: Vec<FloatImage> = Vec::with_capacity(paths.len());
    for path in paths {
        let image = load_gray(path)?;
        if let Some(first) = images.first() {
            check_same_size(first, &paths[0], &image, path)?;
        }
        images.push(image);
    }
    Ok(images)
}

/// An error naming both files when two images of a sequence differ in size.
pub fn check_same_size(
    first: &FloatImage,
    first_path: &Path,
    image: &FloatImage,
    path: &Path,
) -> Result<()> {
    if image.dimensions() != first.dimensions() {
        return Err(Error::data(
            path,
            None,
            None,
            format!(
                "the image is {}×{} px but {} is {}×{} px; all images of a sequence must have the same size",
                image.width(),
                image.height(),
                first_path.display(),
                first.width(),
                first.height()
            ),
        ));
    }
    Ok(())
}

/// Writes intensities in [0, 1] (clamped) as an 8- or 16-bit grayscale image;
/// the format follows the extension (PNG, TIFF or BMP).
pub fn save_gray(path: &Path, image: &FloatImage, bits: u8) -> Result<()> {
    let image: DynamicImage = match bits {
        8 => {
            let data = image.as_raw().iter().map(|&v| quantise(v, 255.0) as u8);
            ImageBuffer::<Luma<u8>, Vec<u8>>::from_raw(
                image.width(),
                image.height(),
                data.collect(),
            )
            .expect("same dimensions")
            .into()
        }
        16 => {
            let data = image.as_raw().iter().map(|&v| quantise(v, 65535.0) as u16);
            ImageBuffer::<Luma<u16>, Vec<u16>>::from_raw(
                image.width(),
                image.height(),
                data.collect(),
            )
            .expect("same dimensions")
            .into()
        }
        _ => {
            return Err(Error::Invalid(format!(
                "images are written with 8 or 16 bits per pixel, not {bits}"
            )))
        }
    };
    save_atomically(path, &image)
}

/// Encodes in memory in the format the extension names, then writes to a
/// temporary file that is renamed into place: a killed run leaves the old
/// file or none.
pub(crate) fn save_atomically(path: &Path, image: &DynamicImage) -> Result<()> {
    let format = ImageFormat::from_path(path)
        .map_err(|e| Error::data(path, None, None, format!("cannot write image: {e}")))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, format).map_err(|e| match e {
        ImageError::IoError(io) => Error::io(path, io),
        other => Error::data(path, None, None, format!("cannot write image: {other}")),
    })?;
    crate::scene::write_file_atomically(path, bytes.get_ref())
}

fn quantise(v: f32, full_scale: f32) -> f32 {
    (v.clamp(0.0, 1.0) * full_scale).round()
}
