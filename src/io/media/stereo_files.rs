//! Files of `flatport stereo` and textured `flatport render`: images read as f32 grey (and RGB for
//! colouring points), float32 `.npy` arrays, the binary point cloud (PLY), the colour-mapped depth
//! picture. Every output is written whole or not at all ([`OutputFile`]).

use std::io::Write;
use std::path::Path;

use image::DynamicImage;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Header, PropertyAccess, PropertyDef, PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use super::npy::{NpyDtype, npy_header_of};
use crate::base::GreyImage;
use crate::io::{IoError, OutputFile, write_atomic};

/// An image read for stereo: grey levels 0 … 1 (colour as luma with Rec. 709 weights, 16-bit
/// scaled to 0 … 1) and its colours as 8-bit RGB (grey repeated for a grey image).
#[derive(Debug, Clone, PartialEq)]
pub struct ColourImage {
    /// The grey levels.
    pub grey: GreyImage,
    /// `width · height` RGB triples, row-major.
    pub rgb: Vec<[u8; 3]>,
}

fn decode(path: &Path) -> Result<DynamicImage, IoError> {
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

/// Reads a PNG, JPEG or TIFF (8 or 16 bit, grey or colour) as grey levels 0 … 1.
///
/// Errors: [`IoError::Read`] when the file cannot be read, [`IoError::Invalid`] naming it when it
/// does not decode.
pub fn read_grey_f32(path: &Path) -> Result<GreyImage, IoError> {
    let image = decode(path)?;
    let luma = image.to_luma32f();
    Ok(GreyImage {
        width: luma.width(),
        height: luma.height(),
        pixels: luma.into_raw(),
    })
}

/// Reads an image as grey levels and RGB colours ([`ColourImage`]).
///
/// Errors as [`read_grey_f32`].
pub fn read_colour_image(path: &Path) -> Result<ColourImage, IoError> {
    let image = decode(path)?;
    let luma = image.to_luma32f();
    let rgb = image
        .to_rgb8()
        .pixels()
        .map(|p| p.0)
        .collect::<Vec<[u8; 3]>>();
    Ok(ColourImage {
        grey: GreyImage {
            width: luma.width(),
            height: luma.height(),
            pixels: luma.into_raw(),
        },
        rgb,
    })
}

/// Writes a little-endian float32 `.npy` array of `shape` (C order) atomically.
///
/// Panics if `values` does not hold the shape's count.
pub fn write_npy_f32(path: &Path, shape: &[usize], values: &[f32]) -> Result<(), IoError> {
    assert_eq!(
        shape.iter().product::<usize>(),
        values.len(),
        "values for the whole shape"
    );
    let mut bytes = npy_header_of(shape, NpyDtype::F32);
    bytes.reserve(values.len() * 4);
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    write_atomic(path, &bytes)
}

/// A vertex of a PLY point cloud: `float` properties ([`CloudVertex::FLOATS`]: a position, then
/// any normal), then `uchar red green blue`. [`write_point_cloud_ply`] writes the properties in
/// that order.
pub trait CloudVertex: Copy + Default {
    /// The names of the `float` properties, in file order.
    const FLOATS: &'static [&'static str];
    /// The value of the `float` property `FLOATS[i]`.
    fn float(&self, i: usize) -> f32;
    /// Red, green, blue.
    fn colour(&self) -> [u8; 3];
}

/// The names of the `uchar` colour properties, in file order.
const COLOURS: [&str; 3] = ["red", "green", "blue"];

/// One vertex of the point cloud: `float x y z`, `uchar red green blue`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CloudPoint {
    /// x, y, z, metres.
    pub position: [f32; 3],
    /// Red, green, blue.
    pub colour: [u8; 3],
}

impl CloudVertex for CloudPoint {
    const FLOATS: &'static [&'static str] = &["x", "y", "z"];

    fn float(&self, i: usize) -> f32 {
        self.position[i]
    }

    fn colour(&self) -> [u8; 3] {
        self.colour
    }
}

/// One vertex of an oriented point cloud (a fused cloud): `float x y z nx ny nz`,
/// `uchar red green blue`, the layout Open3D, MeshLab and CloudCompare read as positions, normals
/// and colours.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OrientedCloudPoint {
    /// x, y, z, metres.
    pub position: [f32; 3],
    /// Unit normal nx, ny, nz.
    pub normal: [f32; 3],
    /// Red, green, blue.
    pub colour: [u8; 3],
}

impl CloudVertex for OrientedCloudPoint {
    const FLOATS: &'static [&'static str] = &["x", "y", "z", "nx", "ny", "nz"];

    fn float(&self, i: usize) -> f32 {
        if i < 3 {
            self.position[i]
        } else {
            self.normal[i - 3]
        }
    }

    fn colour(&self) -> [u8; 3] {
        self.colour
    }
}

/// A [`CloudVertex`] as `ply-rs-bw`'s writer reads it: each property by its name.
#[derive(Clone, Copy)]
struct PlyVertex<P>(P);

impl<P: CloudVertex> PropertyAccess for PlyVertex<P> {
    fn new() -> Self {
        Self(P::default())
    }

    fn get_float(&self, name: &str) -> Option<f32> {
        let i = P::FLOATS.iter().position(|f| *f == name)?;
        Some(self.0.float(i))
    }

    fn get_uchar(&self, name: &str) -> Option<u8> {
        let i = COLOURS.iter().position(|c| *c == name)?;
        Some(self.0.colour()[i])
    }
}

/// Writes a binary little-endian PLY point cloud (`element vertex` with the `float`
/// [`CloudVertex::FLOATS`], then `uchar red green blue`: `float x y z` for [`CloudPoint`],
/// `float x y z nx ny nz` for [`OrientedCloudPoint`]) atomically, through `ply-rs-bw`'s writer;
/// `comments` go into the header.
pub fn write_point_cloud_ply<P: CloudVertex>(
    path: &Path,
    points: &[P],
    comments: &[String],
) -> Result<(), IoError> {
    let mut header = Header::new();
    header.encoding = Encoding::BinaryLittleEndian;
    header.comments = comments.to_vec();
    let mut vertex = ElementDef::new("vertex".to_string());
    vertex.count = points.len();
    for name in P::FLOATS {
        vertex.properties.add(PropertyDef::new(
            name.to_string(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    for name in COLOURS {
        vertex.properties.add(PropertyDef::new(
            name.to_string(),
            PropertyType::Scalar(ScalarType::UChar),
        ));
    }
    header.elements.add(vertex.clone());
    let writer = Writer::<PlyVertex<P>>::new();
    let mut out = OutputFile::create(Some(path))?;
    let points: Vec<PlyVertex<P>> = points.iter().copied().map(PlyVertex).collect();
    writer
        .write_header(&mut out, &header)
        .and_then(|_| writer.write_payload_of_element(&mut out, &points, &vertex, &header))
        .and_then(|_| out.flush().map(|_| 0))
        .map_err(|source| out.write_error(source))?;
    out.finish()
}

/// Viridis (matplotlib's table) at 1 − t: t = 0 is the bright yellow end, t = 1 the dark one.
fn colour_of(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 9] = [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ];
    let x = (1.0 - t.clamp(0.0, 1.0)) * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let mix = |a: u8, b: u8| (a as f64 + (b as f64 - a as f64) * f).round() as u8;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Colour of pixels without a depth.
const NO_DEPTH: RGBColor = RGBColor(0, 0, 0);

/// Writes a depth map as a PNG: each pixel coloured by its depth between the 1st and 99th
/// percentile of the depths (near dark, far bright; black where there is no depth), a colour bar
/// with its depths in metres at the right, `title` above it.
///
/// Panics if `depth` is not `width · height` long.
pub fn write_depth_png(
    path: &Path,
    width: u32,
    height: u32,
    depth: &[f32],
    title: &str,
) -> Result<(), IoError> {
    let values: Vec<f64> = depth.iter().map(|&d| f64::from(d)).collect();
    write_map_png(
        path,
        width,
        height,
        &values,
        title,
        &MapScale {
            label: "depth z",
            unit: " m",
            range: None,
        },
    )
}

/// How [`write_map_png`] colours its values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapScale<'a> {
    /// Above the colour bar (`depth z`, `confidence`).
    pub label: &'a str,
    /// After each tick's value (` m`, or empty).
    pub unit: &'a str,
    /// The values at the bar's ends; `None`: the 1st and 99th percentile of the finite values.
    pub range: Option<(f64, f64)>,
}

/// Writes a map of one value per pixel as a PNG: each pixel coloured by viridis over `scale`'s
/// range (low dark, high bright; black where the value is not finite), a colour bar with its
/// values at the right, `title` above it.
///
/// Panics if `values` is not `width · height` long.
pub fn write_map_png(
    path: &Path,
    width: u32,
    height: u32,
    values: &[f64],
    title: &str,
    scale: &MapScale,
) -> Result<(), IoError> {
    let depth = values;
    assert_eq!(
        depth.len(),
        width as usize * height as usize,
        "a value per pixel"
    );
    let mut finite: Vec<f64> = depth.iter().copied().filter(|d| d.is_finite()).collect();
    finite.sort_by(f64::total_cmp);
    let (low, high) = match scale.range {
        Some(range) => range,
        None if finite.is_empty() => (0.0, 1.0),
        None => {
            let at = |q: f64| finite[((finite.len() - 1) as f64 * q).round() as usize];
            let (a, b) = (at(0.01), at(0.99));
            if b > a { (a, b) } else { (a - 0.5, a + 0.5) }
        }
    };

    let bar_width = 150u32;
    let title_height = 30u32;
    let size = (width + bar_width, (height + title_height).max(260));
    let mut buffer = vec![0u8; (size.0 * size.1 * 3) as usize];
    let err = |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    let draw_error =
        |e: &dyn std::fmt::Display| std::io::Error::other(format!("drawing failed: {e}"));
    crate::io::plots::plot::register_font();
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(draw_error(&e)))?;
        root.draw(&Text::new(
            title.to_string(),
            (8, 6),
            ("sans-serif", 16).into_font().color(&BLACK),
        ))
        .map_err(|e| err(draw_error(&e)))?;
        // The bar: 200 steps from far (bottom) to near (top) with 5 labelled ticks.
        let (bar_x, bar_top, bar_bottom) = (
            width as i32 + 20,
            title_height as i32 + 20,
            size.1 as i32 - 30,
        );
        let steps = 200;
        for i in 0..steps {
            let t0 = i as f64 / steps as f64;
            let y0 = bar_bottom - ((bar_bottom - bar_top) as f64 * t0) as i32;
            let y1 =
                bar_bottom - ((bar_bottom - bar_top) as f64 * (i + 1) as f64 / steps as f64) as i32;
            // Bottom of the bar = the low end of the values (dark), top = the high end.
            root.draw(&Rectangle::new(
                [(bar_x, y1), (bar_x + 24, y0)],
                colour_of(1.0 - t0).filled(),
            ))
            .map_err(|e| err(draw_error(&e)))?;
        }
        for k in 0..=4 {
            let t = k as f64 / 4.0;
            let value = high - (high - low) * t;
            let y = bar_top + ((bar_bottom - bar_top) as f64 * t) as i32;
            root.draw(&PathElement::new(
                vec![(bar_x + 24, y), (bar_x + 30, y)],
                BLACK,
            ))
            .map_err(|e| err(draw_error(&e)))?;
            let style = ("sans-serif", 14)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Left, VPos::Center));
            root.draw(&Text::new(
                format!("{value:.3}{}", scale.unit),
                (bar_x + 34, y),
                style,
            ))
            .map_err(|e| err(draw_error(&e)))?;
        }
        root.draw(&Text::new(
            scale.label,
            (bar_x, bar_top - 16),
            ("sans-serif", 14).into_font().color(&BLACK),
        ))
        .map_err(|e| err(draw_error(&e)))?;
        root.present().map_err(|e| err(draw_error(&e)))?;
    }
    // The depth pixels, written straight into the buffer.
    let stride = size.0 as usize * 3;
    for v in 0..height as usize {
        for u in 0..width as usize {
            let d = depth[v * width as usize + u];
            let c = if d.is_finite() {
                colour_of(1.0 - (d - low) / (high - low))
            } else {
                NO_DEPTH
            };
            let at = (v + title_height as usize) * stride + u * 3;
            buffer[at..at + 3].copy_from_slice(&[c.0, c.1, c.2]);
        }
    }
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, size.0, size.1);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder
            .write_header()
            .map_err(|e| err(std::io::Error::other(e)))?;
        writer
            .write_image_data(&buffer)
            .map_err(|e| err(std::io::Error::other(e)))?;
    }
    write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ply_has_its_header_and_little_endian_vertices() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ply");
        let points = [
            CloudPoint {
                position: [1.0, -2.0, 3.5],
                colour: [10, 20, 30],
            },
            CloudPoint {
                position: [0.25, 0.5, 0.75],
                colour: [255, 0, 7],
            },
        ];
        write_point_cloud_ply(&path, &points, &["made by a test".into()]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let end = b"end_header\n";
        let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let header = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(
            header.starts_with("ply\nformat binary_little_endian 1.0\n"),
            "{header}"
        );
        assert!(header.contains("element vertex 2\n"), "{header}");
        assert!(
            header.contains(
                "property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            ),
            "{header}"
        );
        let body = &bytes[at..];
        assert_eq!(body.len(), 2 * 15);
        assert_eq!(f32::from_le_bytes(body[8..12].try_into().unwrap()), 3.5);
        assert_eq!(&body[12..15], &[10, 20, 30]);
        assert_eq!(f32::from_le_bytes(body[15..19].try_into().unwrap()), 0.25);
    }

    #[test]
    fn an_oriented_ply_has_normals_between_positions_and_colours() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("o.ply");
        let points = [OrientedCloudPoint {
            position: [1.0, -2.0, 3.5],
            normal: [0.0, 0.6, -0.8],
            colour: [10, 20, 30],
        }];
        write_point_cloud_ply(&path, &points, &[]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let end = b"end_header\n";
        let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let header = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(
            header.contains(
                "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            ),
            "{header}"
        );
        let body = &bytes[at..];
        assert_eq!(body.len(), 6 * 4 + 3);
        assert_eq!(f32::from_le_bytes(body[16..20].try_into().unwrap()), 0.6);
        assert_eq!(&body[24..27], &[10, 20, 30]);
    }

    #[test]
    fn a_depth_picture_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        let depth: Vec<f32> = (0..64 * 48)
            .map(|i| {
                if i % 7 == 0 {
                    f32::NAN
                } else {
                    1.0 + (i % 64) as f32 * 0.01
                }
            })
            .collect();
        write_depth_png(&path, 64, 48, &depth, "frame").unwrap();
        let (w, h) = image::image_dimensions(&path).unwrap();
        assert_eq!((w, h), (64 + 150, 260));
    }
}
