//! The grey image that the matcher reads (and `flatport render` draws): plain rows of `f32`,
//! so that the library and Python need no image-file crate to hold one.

/// A grey image, row-major, values 0 … 1.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width · height` values, row-major.
    pub pixels: Vec<f32>,
}

impl GreyImage {
    /// The image as 8-bit grey levels (rounded, clamped).
    pub fn to_u8(&self) -> Vec<u8> {
        self.pixels
            .iter()
            .map(|&p| (p * 255.0).round().clamp(0.0, 255.0) as u8)
            .collect()
    }

    /// The image as 16-bit grey levels (rounded, clamped).
    pub fn to_u16(&self) -> Vec<u16> {
        self.pixels
            .iter()
            .map(|&p| (p * 65535.0).round().clamp(0.0, 65535.0) as u16)
            .collect()
    }
}
