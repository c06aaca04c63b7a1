//! Images: reading any PNG, JPEG or TIFF (8 or 16 bit, grey or colour) as 8-bit grey for the
//! corner detector, and writing grey and colour PNGs. Decoding and encoding are the `image`
//! crate's.

use std::path::Path;

use image::{DynamicImage, GrayImage, ImageEncoder, RgbImage};

use crate::io::{IoError, write_atomic};

/// Reads an image file as 8-bit grey: colour becomes luma (Rec. 709 weights, the `image` crate's),
/// 16-bit values are scaled to 8 bits. A file that does not decode (unknown format, truncated) is
/// an error naming it.
pub fn read_grey_image(path: &Path) -> Result<GrayImage, IoError> {
    Ok(read_image(path)?.to_luma8())
}

/// Reads and decodes an image file (PNG, JPEG, TIFF; the format from its content). A file that
/// does not decode (unknown format, truncated) is an error naming it.
pub(crate) fn read_image(path: &Path) -> Result<DynamicImage, IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let invalid = |reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason,
    };
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| invalid(format!("cannot read the image: {e}")))?;
    if reader.format().is_none() {
        return Err(invalid(
            "not an image in a known format (PNG, JPEG, TIFF)".into(),
        ));
    }
    reader
        .decode()
        .map_err(|e| invalid(format!("cannot decode the image: {e}")))
}

/// The size of an image file (width, height) from its header, without decoding it.
pub fn image_size(path: &Path) -> Result<(u32, u32), IoError> {
    image::image_dimensions(path).map_err(|e| IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason: format!("cannot read the image: {e}"),
    })
}

fn png_bytes(
    path: &Path,
    data: &[u8],
    width: u32,
    height: u32,
    colour: image::ExtendedColorType,
) -> Result<Vec<u8>, IoError> {
    let mut bytes = Vec::new();
    // Fast compression: rendered images and overlays are written by the dozen.
    let encoder = image::codecs::png::PngEncoder::new_with_quality(
        &mut bytes,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    encoder
        .write_image(data, width, height, colour)
        .map_err(|e| IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::other(e),
        })?;
    Ok(bytes)
}

/// Writes an 8-bit grey PNG atomically (`pixels`: width · height values, row-major).
pub fn write_grey_png(path: &Path, pixels: &[u8], width: u32, height: u32) -> Result<(), IoError> {
    write_atomic(
        path,
        &png_bytes(path, pixels, width, height, image::ExtendedColorType::L8)?,
    )
}

/// Writes a 16-bit grey PNG atomically (`pixels`: width · height values, row-major).
pub fn write_grey16_png(
    path: &Path,
    pixels: &[u16],
    width: u32,
    height: u32,
) -> Result<(), IoError> {
    // The encoder takes 16-bit samples as native-endian bytes (it writes PNG's big-endian).
    let native: Vec<u8> = pixels.iter().flat_map(|p| p.to_ne_bytes()).collect();
    write_atomic(
        path,
        &png_bytes(path, &native, width, height, image::ExtendedColorType::L16)?,
    )
}

/// Writes an RGB JPEG (quality 90) atomically: overlays are for the eye, and a noisy image as a
/// PNG takes ten times the bytes and the time.
pub fn write_rgb_jpeg(path: &Path, image: &RgbImage) -> Result<(), IoError> {
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(path, &bytes)
}
