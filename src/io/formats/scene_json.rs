//! The scene file of `flatport render --scene`: textured surfaces in the water, optionally the
//! rig that looks at them, and frames. Unknown keys are errors naming their JSON path, as in the
//! rig file; values out of range are errors naming theirs.
//!
//! ```json
//! {
//!   "rig": "../example_rig.json",
//!   "background": 0.4,
//!   "frames": [{"offset": [0, 0, 0]}, {"offset": [0.02, 0, 0]}],
//!   "surfaces": [
//!     {"height_field": {"origin": [0, 0, 1.6], "normal": [0, 0, -1],
//!                       "relief": {"amplitude": 0.04, "wavelength": 0.5, "waves": 6, "seed": 2},
//!                       "texture": {"noise": {"scale": 0.08, "octaves": 5, "contrast": 3, "seed": 1}}}},
//!     {"sphere": {"centre": [0.1, 0, 1.3], "radius": 0.15,
//!                 "texture": {"noise": {"scale": 0.05, "seed": 7}}}},
//!     {"plane": {"point": [0, 0, 2.5], "normal": [0, 0, 1], "extent": [[-1, 1], [-1, 1]],
//!                "texture": {"image": {"path": "gravel.png", "metres_per_pixel": 0.002}}}}
//!   ]
//! }
//! ```
//! - `rig`: a rig file's path (relative to the scene file) or a rig object (the rig file's
//!   keys); optional when the command gives `--rig`.
//! - `background`: grey level 0 … 1 where a ray hits nothing (default 0.4).
//! - `frames`: the whole scene moved by `offset` (metres, master frame) per frame; default one
//!   frame, not moved.
//! - `surfaces`: `plane` (`point`, `normal`, optional `extent` [[s₀, s₁], [t₀, t₁]] in metres
//!   along the plane's axes), `height_field` (`origin`, `normal` = up, `relief`: `amplitude` m of
//!   the largest wave, `wavelength` m of the longest, `waves` (default 6), `seed`; optional
//!   `extent`), `sphere` (`centre`, `radius`). Every surface has a `texture`: `noise` (`scale` m
//!   of the largest features, `octaves` default 5, `contrast` default 3, `seed`) or `image`
//!   (`path` relative to the scene file, `metres_per_pixel`; planes and height fields only).

use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector3};
use serde::Deserialize;
use serde::de::{self, MapAccess, Visitor};

use super::rig_json::{RigFile, parse_json, present, rig_from_file};
use crate::io::{IoError, read_rig, read_text};
use crate::model::Rig;
use crate::render::{
    Extent, ImageTexture, Relief, Shape, Sphere, Surface, SurfaceFrame, Texture, TexturedScene,
};

/// A scene file read: the scene, and the rig when the file names or holds one.
#[derive(Debug, Clone)]
pub struct SceneFileContents {
    /// The surfaces, background and frames.
    pub scene: TexturedScene,
    /// The rig of the file's `rig` key.
    pub rig: Option<Rig>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    #[serde(default, deserialize_with = "present")]
    rig: Option<RigRef>,
    #[serde(default = "default_background")]
    background: f64,
    surfaces: Vec<SurfaceFile>,
    #[serde(default, deserialize_with = "present")]
    frames: Option<Vec<FrameFile>>,
}

fn default_background() -> f64 {
    0.4
}

/// `rig`: a path or an inline rig object (read with the rig file's own schema, so an unknown key
/// inside it is named by its full path, `rig.cameras[0].fz`).
#[derive(Debug)]
enum RigRef {
    Path(String),
    Inline(Box<RigFile>),
}

impl<'de> Deserialize<'de> for RigRef {
    fn deserialize<D: de::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct RigVisitor;
        impl<'de> Visitor<'de> for RigVisitor {
            type Value = RigRef;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a rig file's path or a rig object")
            }
            fn visit_str<E: de::Error>(self, text: &str) -> Result<RigRef, E> {
                Ok(RigRef::Path(text.to_string()))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<RigRef, A::Error> {
                RigFile::deserialize(de::value::MapAccessDeserializer::new(map))
                    .map(|rig| RigRef::Inline(Box::new(rig)))
            }
        }
        deserializer.deserialize_any(RigVisitor)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FrameFile {
    offset: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
enum SurfaceFile {
    Plane(PlaneFile),
    HeightField(HeightFieldFile),
    Sphere(SphereFile),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaneFile {
    point: [f64; 3],
    normal: [f64; 3],
    #[serde(default, deserialize_with = "present")]
    extent: Option<[[f64; 2]; 2]>,
    texture: TextureFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct HeightFieldFile {
    origin: [f64; 3],
    normal: [f64; 3],
    relief: ReliefFile,
    #[serde(default, deserialize_with = "present")]
    extent: Option<[[f64; 2]; 2]>,
    texture: TextureFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReliefFile {
    amplitude: f64,
    wavelength: f64,
    #[serde(default = "default_waves")]
    waves: usize,
    #[serde(default)]
    seed: u64,
}

fn default_waves() -> usize {
    6
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SphereFile {
    centre: [f64; 3],
    radius: f64,
    texture: TextureFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
enum TextureFile {
    Noise(NoiseFile),
    Image(ImageFile),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseFile {
    scale: f64,
    #[serde(default = "default_octaves")]
    octaves: u32,
    #[serde(default = "default_contrast")]
    contrast: f64,
    #[serde(default)]
    seed: u64,
}

fn default_octaves() -> u32 {
    5
}

fn default_contrast() -> f64 {
    3.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImageFile {
    path: String,
    metres_per_pixel: f64,
}

/// Reads a scene file (see the [module docs](self)); relative paths in it are taken from its
/// folder.
///
/// Errors: [`IoError::Read`] when it (or a texture, or the rig it names) cannot be read;
/// [`IoError::Json`] naming file, line, column and JSON path for a syntax error or an unknown
/// key; [`IoError::Invalid`] naming the JSON path for a value out of range.
pub fn read_scene(path: &Path) -> Result<SceneFileContents, IoError> {
    scene_from_json_str(&read_text(path)?, path)
}

/// [`read_scene`] without the rig it names (its `rig` key is parsed but no rig file is read):
/// for a caller that has a rig of its own (`--rig`).
pub fn read_scene_without_rig(path: &Path) -> Result<TexturedScene, IoError> {
    Ok(parse_scene(&read_text(path)?, path, false)?.scene)
}

/// Parses a scene from JSON text; `path` labels errors and is where relative paths start.
pub fn scene_from_json_str(text: &str, path: &Path) -> Result<SceneFileContents, IoError> {
    parse_scene(text, path, true)
}

/// [`scene_from_json_str`] without the rig the text names (its `rig` key is parsed, no file is
/// read): for a scene built into the binary, whose rig is given by the caller.
pub fn scene_without_rig_from_json_str(text: &str, path: &Path) -> Result<TexturedScene, IoError> {
    Ok(parse_scene(text, path, false)?.scene)
}

fn parse_scene(text: &str, path: &Path, with_rig: bool) -> Result<SceneFileContents, IoError> {
    let file: SceneFile = parse_json(text, path)?;
    let folder = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let invalid = |field: String, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field,
        reason,
    };
    let finite = |field: &str, values: &[f64]| -> Result<(), IoError> {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(invalid(field.into(), "must be finite numbers".into()))
        }
    };
    let positive = |field: String, value: f64| -> Result<(), IoError> {
        if value > 0.0 && value.is_finite() {
            Ok(())
        } else {
            Err(invalid(field, format!("must be > 0, got {value}")))
        }
    };
    if !(0.0..=1.0).contains(&file.background) {
        return Err(invalid(
            "background".into(),
            format!("a grey level 0 to 1, got {}", file.background),
        ));
    }
    if file.surfaces.is_empty() {
        return Err(invalid(
            "surfaces".into(),
            "is empty: a scene needs at least one surface".into(),
        ));
    }
    let frame_of = |field: String, origin: [f64; 3], normal: [f64; 3]| {
        finite(&format!("{field}.origin"), &origin)?;
        finite(&format!("{field}.normal"), &normal)?;
        SurfaceFrame::new(Point3::from(origin), Vector3::from(normal))
            .ok_or_else(|| invalid(format!("{field}.normal"), "is zero".into()))
    };
    let extent_of = |field: String, extent: Option<[[f64; 2]; 2]>| match extent {
        None => Ok(None),
        Some([s, t]) => {
            finite(&field, &[s[0], s[1], t[0], t[1]])?;
            if !(s[0] < s[1] && t[0] < t[1]) {
                return Err(invalid(
                    field,
                    format!(
                        "[[s0, s1], [t0, t1]] with s0 < s1 and t0 < t1, got [[{}, {}], [{}, {}]]",
                        s[0], s[1], t[0], t[1]
                    ),
                ));
            }
            Ok(Some(Extent { s, t }))
        }
    };
    let texture_of = |field: String, texture: &TextureFile, sphere: bool| match texture {
        TextureFile::Noise(n) => {
            positive(format!("{field}.noise.scale"), n.scale)?;
            positive(format!("{field}.noise.contrast"), n.contrast)?;
            if !(1..=16).contains(&n.octaves) {
                return Err(invalid(
                    format!("{field}.noise.octaves"),
                    format!("1 to 16 octaves, got {}", n.octaves),
                ));
            }
            Ok(Texture::Noise {
                seed: n.seed,
                scale: n.scale,
                octaves: n.octaves,
                contrast: n.contrast,
            })
        }
        TextureFile::Image(image) => {
            if sphere {
                return Err(invalid(
                    format!("{field}.image"),
                    "image textures map onto planes and height fields; give a sphere a noise texture".into(),
                ));
            }
            positive(
                format!("{field}.image.metres_per_pixel"),
                image.metres_per_pixel,
            )?;
            let texture_path: PathBuf = folder.join(&image.path);
            let grey = crate::io::media::stereo_files::read_grey_f32(&texture_path)?;
            Ok(Texture::Image(ImageTexture {
                width: grey.width,
                height: grey.height,
                pixels: grey.pixels,
                metres_per_pixel: image.metres_per_pixel,
            }))
        }
    };
    let mut surfaces = Vec::with_capacity(file.surfaces.len());
    for (i, surface) in file.surfaces.iter().enumerate() {
        let surface = match surface {
            SurfaceFile::Plane(p) => {
                let field = format!("surfaces[{i}].plane");
                Surface {
                    shape: Shape::Plane {
                        frame: frame_of(field.clone(), p.point, p.normal)?,
                        extent: extent_of(format!("{field}.extent"), p.extent)?,
                    },
                    texture: texture_of(format!("{field}.texture"), &p.texture, false)?,
                }
            }
            SurfaceFile::HeightField(h) => {
                let field = format!("surfaces[{i}].height_field");
                let r = &h.relief;
                let relief_field = format!("{field}.relief");
                finite(&format!("{relief_field}.amplitude"), &[r.amplitude])?;
                if !(r.amplitude >= 0.0) {
                    return Err(invalid(
                        format!("{relief_field}.amplitude"),
                        format!("must be ≥ 0, got {}", r.amplitude),
                    ));
                }
                positive(format!("{relief_field}.wavelength"), r.wavelength)?;
                if !(1..=32).contains(&r.waves) {
                    return Err(invalid(
                        format!("{relief_field}.waves"),
                        format!("1 to 32 waves, got {}", r.waves),
                    ));
                }
                let relief = Relief::seeded(r.amplitude, r.wavelength, r.waves, r.seed)
                    .ok_or_else(|| invalid(relief_field, "has no finite waves".into()))?;
                Surface {
                    shape: Shape::HeightField {
                        frame: frame_of(field.clone(), h.origin, h.normal)?,
                        extent: extent_of(format!("{field}.extent"), h.extent)?,
                        relief,
                    },
                    texture: texture_of(format!("{field}.texture"), &h.texture, false)?,
                }
            }
            SurfaceFile::Sphere(s) => {
                let field = format!("surfaces[{i}].sphere");
                finite(&format!("{field}.centre"), &s.centre)?;
                positive(format!("{field}.radius"), s.radius)?;
                Surface {
                    shape: Shape::Sphere(Sphere {
                        centre: Point3::from(s.centre),
                        radius: s.radius,
                    }),
                    texture: texture_of(format!("{field}.texture"), &s.texture, true)?,
                }
            }
        };
        surfaces.push(surface);
    }
    let frames = match &file.frames {
        None => vec![Vector3::zeros()],
        Some(frames) if frames.is_empty() => {
            return Err(invalid(
                "frames".into(),
                "is empty: leave it out for one still frame".into(),
            ));
        }
        Some(frames) => {
            for (i, f) in frames.iter().enumerate() {
                finite(&format!("frames[{i}].offset"), &f.offset)?;
            }
            frames.iter().map(|f| Vector3::from(f.offset)).collect()
        }
    };
    let rig = match &file.rig {
        _ if !with_rig => None,
        None => None,
        Some(RigRef::Path(p)) => Some(read_rig(&folder.join(p))?),
        Some(RigRef::Inline(rig)) => Some(rig_from_file(rig, path).map_err(|e| match e {
            IoError::Invalid {
                path,
                field,
                reason,
            } => IoError::Invalid {
                path,
                field: if field.is_empty() {
                    "rig".into()
                } else {
                    format!("rig.{field}")
                },
                reason,
            },
            other => other,
        })?),
    };
    Ok(SceneFileContents {
        scene: TexturedScene {
            surfaces,
            background: file.background,
            frames,
        },
        rig,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPHERE: &str = r#"{"sphere": {"centre": [0, 0, 1], "radius": 0.2, "texture": {"noise": {"scale": 0.05}}}}"#;

    fn parse(text: &str) -> Result<SceneFileContents, IoError> {
        scene_from_json_str(text, Path::new("scene.json"))
    }

    #[test]
    fn a_small_scene_reads_with_its_defaults() {
        let read = parse(&format!(r#"{{"surfaces": [{SPHERE}]}}"#)).unwrap();
        assert!(read.rig.is_none());
        assert_eq!(read.scene.frames, vec![Vector3::zeros()]);
        assert_eq!(read.scene.background, 0.4);
        assert!(matches!(
            read.scene.surfaces[0].texture,
            Texture::Noise {
                octaves: 5,
                seed: 0,
                ..
            }
        ));
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named_by_their_path() {
        let error = parse(&format!(r#"{{"surfaces": [{SPHERE}], "colour": 1}}"#)).unwrap_err();
        assert!(error.to_string().contains("colour"), "{error}");
        let error = parse(
            r#"{"surfaces": [{"sphere": {"centre": [0, 0, 1], "radius": 0.2, "texture": {"noise": {"scale": 0.05, "octave": 3}}}}]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            error.contains("surfaces[0].sphere.texture.noise") && error.contains("octave"),
            "{error}"
        );
        let error = parse(
            r#"{"surfaces": [{"sphere": {"centre": [0, 0, 1], "radius": -0.2, "texture": {"noise": {"scale": 0.05}}}}]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("surfaces[0].sphere.radius"), "{error}");
        let error = parse(r#"{"surfaces": [{"cube": {}}]}"#)
            .unwrap_err()
            .to_string();
        assert!(error.contains("cube"), "{error}");
        let error = parse(
            r#"{"surfaces": [{"sphere": {"centre": [0, 0, 1], "radius": 0.2, "texture": {"image": {"path": "x.png", "metres_per_pixel": 0.001}}}}]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            error.contains("surfaces[0].sphere.texture.image"),
            "{error}"
        );
        // Inside an inline rig, the rig's own schema and the full path.
        let error = parse(&format!(
            r#"{{"rig": {{"cameras": [{{"name": "a", "width": 10, "height": 10, "fx": 10, "fy": 10, "cx": 5, "cy": 5, "fz": 1}}], "interface": {{"normal": [0, 0, 1], "distance": 0.01}}}}, "surfaces": [{SPHERE}]}}"#
        ))
        .unwrap_err()
        .to_string();
        assert!(
            error.contains("rig.cameras[0]") && error.contains("fz"),
            "{error}"
        );
    }

    #[test]
    fn an_inline_rig_is_read() {
        let read = parse(&format!(
            r#"{{"rig": {{"cameras": [{{"name": "a", "width": 10, "height": 10, "fx": 10, "fy": 10, "cx": 5, "cy": 5}}], "interface": {{"normal": [0, 0, 1], "distance": 0.01}}}}, "surfaces": [{SPHERE}], "frames": [{{"offset": [0, 0, 0]}}, {{"offset": [0.1, 0, 0]}}]}}"#
        ))
        .unwrap();
        assert_eq!(read.rig.unwrap().cameras()[0].name, "a");
        assert_eq!(read.scene.frames.len(), 2);
    }
}
