//! Reading and writing grayscale images, with errors that name the file.

use super::FloatImage;
use crate::error::{Error, Result};
use ::image::{DynamicImage, ImageBuffer, ImageError, ImageFormat, Luma};
use std::path::{Path, PathBuf};

/// Reads an image (PNG, TIFF or BMP; 8- or 16-bit, gray or colour) as
/// intensities in [0, 1]. Colour images are converted to luma.
pub fn load_gray(path: &Path) -> Result<FloatImage> {
    let reader = ::image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let decoded = reader.decode().map_err(|e| image_error(path, e))?;
    let image = match decoded {
        DynamicImage::ImageLuma8(g) => to_float(&g, 255.0),
        DynamicImage::ImageLuma16(g) => to_float(&g, 65535.0),
        other => other.to_luma32f(),
    };
    if image.width() == 0 || image.height() == 0 {
        return Err(Error::data(path, None, None, "the image is empty"));
    }
    Ok(image)
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
            format!("unsupported image format ({u}); use PNG, TIFF or BMP"),
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
