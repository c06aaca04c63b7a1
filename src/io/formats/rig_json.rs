//! The rig file (DESIGN.md §1, §3b): JSON with `cameras` (master first) and the top-level
//! `interface` shared by every camera, or an `interface` in every camera (its own port).
//! Unknown keys are rejected by name; the model validates the values.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::opencv::MAX_BASELINE_M;
use crate::io::error::{EXCERPT_CHARS, excerpt, shorten_quoted};
use crate::io::{IoError, read_text, write_atomic};
use crate::model::interface::{DEFAULT_INDEX_AIR, DEFAULT_INDEX_WATER};
use crate::model::{Interface, Layer, ModelError, PinholeCamera, Ports, Rig, RigCamera};

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RigFile {
    cameras: Vec<CameraFile>,
    /// The port shared by every camera (master frame); absent when every camera has its own.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present"
    )]
    interface: Option<InterfaceFile>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    name: String,
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    #[serde(default)]
    distortion: Vec<f64>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present"
    )]
    rotation: Option<[[f64; 3]; 3]>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present"
    )]
    translation: Option<[f64; 3]>,
    /// This camera's own port, in its own frame (DESIGN.md §3b).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present"
    )]
    interface: Option<InterfaceFile>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct InterfaceFile {
    normal: [f64; 3],
    distance: f64,
    #[serde(default)]
    layers: Vec<LayerFile>,
    #[serde(default = "default_index_air")]
    index_air: f64,
    #[serde(default = "default_index_water")]
    index_water: f64,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LayerFile {
    thickness: f64,
    index: f64,
}

/// An optional key that, when present, must hold a value: `null` is an error (naming the key),
/// not the same as leaving the key out.
pub(crate) fn present<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(
    deserializer: D,
) -> Result<Option<T>, D::Error> {
    T::deserialize(deserializer).map(Some)
}

fn default_index_air() -> f64 {
    DEFAULT_INDEX_AIR
}

fn default_index_water() -> f64 {
    DEFAULT_INDEX_WATER
}

/// Parses JSON text into `T`, naming the file, line, column and JSON path of any error; only
/// whitespace may follow the value.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(
    text: &str,
    path: &Path,
) -> Result<T, IoError> {
    // serde_json quotes the offending key or string whole, and serde_path_to_error ends the path
    // with an unknown key: both are cut to their start (a 1 MB key must not fill the message).
    let json_error = |field: String, error: serde_json::Error| IoError::Json {
        path: path.to_path_buf(),
        field: if field == "." {
            String::new()
        } else {
            excerpt(&field, 2 * EXCERPT_CHARS)
        },
        line: error.line(),
        column: error.column(),
        reason: shorten_quoted(&strip_position(&error.to_string()), EXCERPT_CHARS),
    };
    // A UTF-8 byte order mark (Windows editors write one) is not JSON but carries no meaning:
    // skip it, as the CSV reader does.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let value: T = serde_path_to_error::deserialize(&mut deserializer).map_err(|e| {
        let field = e.path().to_string();
        json_error(field, e.into_inner())
    })?;
    deserializer
        .end()
        .map_err(|e| json_error(String::new(), e))?;
    Ok(value)
}

/// Longest camera name of a rig file, bytes: a name is a folder's name (the images of
/// `flatport render` and `detect`, colmap's image prefix), which file systems keep to 255 bytes,
/// and a longer one would be copied into every message about the camera.
pub const MAX_CAMERA_NAME_BYTES: usize = 255;

/// Parses and validates a rig from JSON text; `path` only labels errors.
pub fn rig_from_json_str(text: &str, path: &Path) -> Result<Rig, IoError> {
    rig_from_file(&parse_json(text, path)?, path)
}

/// Validates a parsed rig file; `path` only labels errors.
pub(crate) fn rig_from_file(file: &RigFile, path: &Path) -> Result<Rig, IoError> {
    let invalid = |field: String, error: ModelError| IoError::Invalid {
        path: path.to_path_buf(),
        field,
        reason: error.to_string(),
    };

    let mut cameras = Vec::with_capacity(file.cameras.len());
    for (i, c) in file.cameras.iter().enumerate() {
        let field = format!("cameras[{i}]");
        if c.name.len() > MAX_CAMERA_NAME_BYTES {
            return Err(IoError::Invalid {
                path: path.to_path_buf(),
                field: format!("{field}.name"),
                reason: format!(
                    "'{}' is longer than a camera name may be ({MAX_CAMERA_NAME_BYTES} bytes: it names the folder of the camera's images, and every message about the camera)",
                    excerpt(&c.name, EXCERPT_CHARS)
                ),
            });
        }
        if c.distortion.len() > 5 {
            return Err(IoError::Invalid {
                path: path.to_path_buf(),
                field: format!("{field}.distortion"),
                reason: format!(
                    "has {} terms; flatport supports OpenCV's 5-term model [k1, k2, p1, p2, k3]",
                    c.distortion.len()
                ),
            });
        }
        let mut distortion = [0.0; 5];
        distortion[..c.distortion.len()].copy_from_slice(&c.distortion);
        let intrinsics = PinholeCamera::new(
            &c.name, c.width, c.height, c.fx, c.fy, c.cx, c.cy, distortion,
        )
        .map_err(|e| match &e {
            ModelError::BadIntrinsics { field: name, .. } => invalid(format!("{field}.{name}"), e),
            _ => invalid(field.clone(), e),
        })?;
        let r = c
            .rotation
            .unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        // Rows of the JSON matrix are rows of R.
        let rotation = Matrix3::new(
            r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
        );
        let translation = Vector3::from(c.translation.unwrap_or([0.0; 3]));
        let camera =
            RigCamera::new(&c.name, intrinsics, rotation, translation).map_err(|e| match &e {
                ModelError::NotARotation { .. } => invalid(format!("{field}.rotation"), e),
                _ => invalid(field.clone(), e),
            })?;
        cameras.push(camera);
    }
    let ports = ports_from_file(file, path)?;
    let names: Vec<&str> = file.cameras.iter().map(|c| c.name.as_str()).collect();
    Rig::with_ports(cameras, ports).map_err(|e| {
        let mut error = invalid(rig_field(&e, &names), e.clone());
        // A camera in the water is most often a translation in millimetres.
        if let (ModelError::CameraNotInAir { camera, .. }, IoError::Invalid { reason, .. }) =
            (&e, &mut error)
            && let Some(c) = file.cameras.iter().find(|c| &c.name == camera)
            && let Some(t) = c.translation
            && Vector3::from(t).norm() > MAX_BASELINE_M
        {
            reason.push_str(&format!(
                "; its translation puts it {:.3} m from the master, which looks like millimetres: translations are metres (`flatport rig from-opencv --unit mm` converts)",
                Vector3::from(t).norm()
            ));
        }
        error
    })
}

/// The rig's ports: the top-level `interface`, or an `interface` in every camera; both at once, or
/// ports on some cameras only, is an error that names the cameras.
fn ports_from_file(file: &RigFile, path: &Path) -> Result<Ports, IoError> {
    let mixed = |field: &str, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: field.into(),
        reason,
    };
    let with: Vec<usize> = (0..file.cameras.len())
        .filter(|&k| file.cameras[k].interface.is_some())
        .collect();
    let without: Vec<String> = file
        .cameras
        .iter()
        .filter(|c| c.interface.is_none())
        .map(|c| format!("'{}'", c.name))
        .collect();
    match &file.interface {
        Some(_) if !with.is_empty() => Err(mixed(
            &format!("cameras[{}].interface", with[0]),
            "a rig has either the top-level interface (one port shared by every camera) or an interface in every camera (a port each), not both".into(),
        )),
        Some(shared) => Ok(Ports::Shared(interface_from_file(shared, "interface", path)?)),
        None if with.is_empty() => Err(mixed(
            "interface",
            "missing: give the top-level interface (one port shared by every camera, master frame) or an interface in every camera (its own port, in its own frame)".into(),
        )),
        None if !without.is_empty() => Err(mixed(
            &format!("cameras[{}].interface", file.cameras.iter().position(|c| c.interface.is_none()).expect("one lacks it")),
            format!(
                "with per-camera ports every camera needs its own interface; {} {} none",
                without.join(", "),
                if without.len() == 1 { "has" } else { "have" }
            ),
        )),
        None => file
            .cameras
            .iter()
            .enumerate()
            .map(|(k, c)| interface_from_file(c.interface.as_ref().expect("every camera has one"), &format!("cameras[{k}].interface"), path))
            .collect::<Result<Vec<_>, _>>()
            .map(Ports::PerCamera),
    }
}

/// The interface of a rig file's `interface` object, validated.
/// `field` is where the object sits in the file (`interface`, `cameras[1].interface`).
pub(crate) fn interface_from_file(
    i: &InterfaceFile,
    field: &str,
    path: &Path,
) -> Result<Interface, IoError> {
    let layers = i
        .layers
        .iter()
        .map(|l| Layer {
            thickness: l.thickness,
            index: l.index,
        })
        .collect();
    Interface::new(
        Vector3::from(i.normal),
        i.distance,
        layers,
        i.index_air,
        i.index_water,
    )
    .map_err(|e| IoError::Invalid {
        path: path.to_path_buf(),
        field: interface_field(&e, field),
        reason: e.to_string(),
    })
}

/// The `interface` object of a rig file.
pub(crate) fn interface_to_file(i: &Interface) -> InterfaceFile {
    let n = i.normal();
    InterfaceFile {
        normal: [n.x, n.y, n.z],
        distance: i.air_distance(),
        layers: i
            .layers()
            .iter()
            .map(|l| LayerFile {
                thickness: l.thickness,
                index: l.index,
            })
            .collect(),
        index_air: i.index_air(),
        index_water: i.index_water(),
    }
}

/// The rig-file field an interface error is about.
fn interface_field(error: &ModelError, object: &str) -> String {
    match error {
        ModelError::ZeroNormal
        | ModelError::NormalLength { .. }
        | ModelError::NormalAwayFromWater { .. } => {
            format!("{object}.normal")
        }
        ModelError::NonPositiveAirDistance { .. } => format!("{object}.distance"),
        ModelError::NonPositiveThickness { layer, .. } => {
            format!("{object}.layers[{layer}].thickness")
        }
        ModelError::IndexBelowOne { medium, .. } => match medium.strip_prefix("layer ") {
            Some(layer) => format!("{object}.layers[{layer}].index"),
            None => format!("{object}.{medium}"),
        },
        _ => object.into(),
    }
}

/// The rig-file field a whole-rig error is about: the camera it names (its last occurrence for a
/// repeated name), else `cameras`.
fn rig_field(error: &ModelError, names: &[&str]) -> String {
    let camera = match error {
        ModelError::MasterNotIdentity { .. } => Some(0),
        ModelError::DuplicateCameraName { name }
        | ModelError::CameraNotInAir { camera: name, .. } => names.iter().rposition(|n| n == name),
        _ => None,
    };
    camera.map_or_else(|| "cameras".into(), |k| format!("cameras[{k}]"))
}

/// serde_json appends " at line L column C"; the error already carries them.
fn strip_position(message: &str) -> String {
    match message.rfind(" at line ") {
        Some(i) => message[..i].to_string(),
        None => message.to_string(),
    }
}

/// Reads and validates a rig file (`-` = standard input).
pub fn read_rig(path: &Path) -> Result<Rig, IoError> {
    rig_from_json_str(&read_text(path)?, path)
}

/// The rig as pretty JSON in the rig-file schema, every field written at full f64 precision.
pub fn rig_to_json_string(rig: &Rig) -> String {
    let mut text =
        serde_json::to_string_pretty(&rig_to_file(rig)).expect("plain data always serialises");
    text.push('\n');
    text
}

/// The rig in the rig-file schema.
pub(crate) fn rig_to_file(rig: &Rig) -> RigFile {
    let cameras = rig
        .cameras()
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let i = &c.intrinsics;
            let (rotation, translation) = if k == 0 {
                (None, None)
            } else {
                let r = c.cam_from_master.rotation.to_rotation_matrix().into_inner();
                let t = c.cam_from_master.translation.vector;
                (
                    Some([
                        [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                        [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                        [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
                    ]),
                    Some([t.x, t.y, t.z]),
                )
            };
            CameraFile {
                name: c.name.clone(),
                width: i.width,
                height: i.height,
                fx: i.fx,
                fy: i.fy,
                cx: i.cx,
                cy: i.cy,
                distortion: i.distortion.to_vec(),
                rotation,
                translation,
                interface: match rig.ports() {
                    Ports::PerCamera(ports) => Some(interface_to_file(&ports[k])),
                    Ports::Shared(_) => None,
                },
            }
        })
        .collect();
    RigFile {
        cameras,
        interface: rig.shared_interface().map(interface_to_file),
    }
}

/// Writes a rig file atomically.
pub fn write_rig(path: &Path, rig: &Rig) -> Result<(), IoError> {
    write_atomic(path, rig_to_json_string(rig).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, UnitQuaternion};

    const EXAMPLE: &str = r#"{
  "cameras": [
    {"name": "left",  "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "distortion": [0, 0, 0, 0, 0]},
    {"name": "right", "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [-0.06, 0, 0]}
  ],
  "interface": {"normal": [0.1, 0.1, 1.0], "distance": 0.02,
                "layers": [{"thickness": 0.014, "index": 1.473}],
                "index_air": 1.003, "index_water": 1.333}
}"#;

    fn parse(text: &str) -> Result<Rig, IoError> {
        rig_from_json_str(text, Path::new("rig.json"))
    }

    #[test]
    fn a_byte_order_mark_is_accepted_and_null_is_not_missing() {
        let rig = parse(&format!("\u{feff}{EXAMPLE}")).unwrap();
        assert_eq!(rig.cameras().len(), 2);
        for key in ["translation", "rotation"] {
            let from = if key == "translation" {
                "\"translation\": [-0.06, 0, 0]"
            } else {
                "\"rotation\": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]"
            };
            let message = parse(&edited(from, &format!("\"{key}\": null")))
                .unwrap_err()
                .to_string();
            assert!(
                message.contains(&format!("cameras[1].{key}")) && message.contains("null"),
                "{message}"
            );
        }
    }

    /// The example with `from` replaced by `to` (which must occur).
    fn edited(from: &str, to: &str) -> String {
        assert!(EXAMPLE.contains(from), "test edit {from:?} does not apply");
        EXAMPLE.replacen(from, to, 1)
    }

    /// (field, line, message) of a JSON schema or syntax error.
    fn json_error(text: &str) -> (String, usize, String) {
        match parse(text) {
            Err(e @ IoError::Json { .. }) => {
                let message = e.to_string();
                let IoError::Json { field, line, .. } = e else {
                    unreachable!()
                };
                (field, line, message)
            }
            other => panic!("expected IoError::Json, got {other:?}"),
        }
    }

    /// (field, message) of a semantic error.
    fn invalid(text: &str) -> (String, String) {
        match parse(text) {
            Err(e @ IoError::Invalid { .. }) => {
                let message = e.to_string();
                let IoError::Invalid { field, .. } = e else {
                    unreachable!()
                };
                (field, message)
            }
            other => panic!("expected IoError::Invalid, got {other:?}"),
        }
    }

    #[test]
    fn design_example_parses_with_normalised_normal() {
        let rig = parse(EXAMPLE).unwrap();
        let n = rig.shared_interface().unwrap().normal();
        // (0.1, 0.1, 1) / √1.02
        let norm = 1.02f64.sqrt();
        assert!((n.into_inner() - Vector3::new(0.1 / norm, 0.1 / norm, 1.0 / norm)).norm() < 1e-15);
        assert_eq!(rig.cameras().len(), 2);
        assert_eq!(rig.cameras()[0].name, "left");
        assert_eq!(rig.cameras()[1].intrinsics.fx, 864.91);
        assert_eq!(rig.shared_interface().unwrap().air_distance(), 0.02);
        assert_eq!(
            rig.shared_interface().unwrap().layers(),
            &[Layer {
                thickness: 0.014,
                index: 1.473
            }]
        );
        assert_eq!(
            (
                rig.shared_interface().unwrap().index_air(),
                rig.shared_interface().unwrap().index_water()
            ),
            (1.003, 1.333)
        );
        // t = (−0.06, 0, 0), R = I ⇒ C = −Rᵀt = (0.06, 0, 0).
        assert_eq!(
            rig.cameras()[1].centre_in_master(),
            Point3::new(0.06, 0.0, 0.0)
        );
    }

    #[test]
    fn defaults_apply_to_optional_fields() {
        let text = r#"{"cameras": [{"name": "c", "width": 10, "height": 10, "fx": 5, "fy": 5, "cx": 5, "cy": 5,
            "distortion": [0.1]}], "interface": {"normal": [0, 0, 2], "distance": 0.01}}"#;
        let rig = parse(text).unwrap();
        assert_eq!(
            rig.cameras()[0].intrinsics.distortion,
            [0.1, 0.0, 0.0, 0.0, 0.0]
        );
        assert_eq!(
            rig.shared_interface().unwrap().index_air(),
            DEFAULT_INDEX_AIR
        );
        assert_eq!(
            rig.shared_interface().unwrap().index_water(),
            DEFAULT_INDEX_WATER
        );
        assert!(rig.shared_interface().unwrap().layers().is_empty());
        assert_eq!(
            rig.shared_interface().unwrap().normal().into_inner(),
            Vector3::z()
        );
    }

    #[test]
    fn rows_of_the_json_rotation_are_rows_of_r() {
        // R = rotation by +90° about z: row 0 = [0, −1, 0]. Camera centre C = −Rᵀt.
        let rig = parse(&edited(
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]], \"translation\": [-0.06, 0, 0]",
            "[[0, -1, 0], [1, 0, 0], [0, 0, 1]], \"translation\": [0, -0.06, 0]",
        ))
        .unwrap();
        let camera = &rig.cameras()[1];
        let x_in_camera = camera.cam_from_master.transform_vector(&Vector3::x());
        assert!((x_in_camera - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-15);
        // Rᵀt = (−0.06, 0, 0), so C = −Rᵀt = (0.06, 0, 0).
        assert!((camera.centre_in_master() - Point3::new(0.06, 0.0, 0.0)).norm() < 1e-15);
    }

    /// xorshift64: a deterministic stream of test values.
    fn next(state: &mut u64) -> f64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn write_then_read_gives_the_same_rig() {
        let mut state = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..200 {
            let mut v = || next(&mut state);
            let camera = |name: &str,
                          rotation: Matrix3<f64>,
                          translation: Vector3<f64>,
                          v: &mut dyn FnMut() -> f64| {
                let distortion = [v() - 0.5, v() * 0.1, v() * 1e-3, -v() * 1e-3, v() * 1e-2];
                let intrinsics = PinholeCamera::new(
                    name,
                    1920,
                    1080,
                    800.0 + v() * 400.0,
                    800.0 + v() * 400.0,
                    900.0 + v() * 100.0,
                    500.0 + v() * 80.0,
                    distortion,
                )
                .unwrap();
                RigCamera::new(name, intrinsics, rotation, translation).unwrap()
            };
            let master = camera("left", Matrix3::identity(), Vector3::zeros(), &mut v);
            let axis = Vector3::new(v() - 0.5, v() - 0.5, v() - 0.5);
            let rotation = UnitQuaternion::from_scaled_axis(axis)
                .to_rotation_matrix()
                .into_inner();
            let other = camera(
                "right",
                rotation,
                Vector3::new(-0.1 * v(), 0.01 * v(), 0.01 * v()),
                &mut v,
            );
            let normal = Vector3::new(0.2 * (v() - 0.5), 0.2 * (v() - 0.5), 1.0);
            let layers = vec![
                Layer {
                    thickness: 0.01 * v() + 1e-3,
                    index: 1.4 + 0.2 * v(),
                },
                Layer {
                    thickness: 1.0 + v(),
                    index: 1.333,
                },
            ];
            let interface = Interface::new(
                normal,
                0.05 + 0.01 * v(),
                layers,
                1.0 + 1e-3 * v(),
                1.0 + v(),
            )
            .unwrap();
            let rig = Rig::new(vec![master, other], interface).unwrap();

            let text = rig_to_json_string(&rig);
            let back = parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
            let (a, b) = (
                rig.shared_interface().unwrap(),
                back.shared_interface().unwrap(),
            );
            // The stored normal is already unit; normalising it again may move its last bit.
            assert!(
                (a.normal().into_inner() - b.normal().into_inner()).amax() <= 1e-15,
                "{text}"
            );
            // Every plain number must come back bit for bit (shortest round-trip text, exact parsing).
            assert_eq!(
                (a.air_distance(), a.layers(), a.index_air(), a.index_water()),
                (b.air_distance(), b.layers(), b.index_air(), b.index_water())
            );
            for (a, b) in rig.cameras().iter().zip(back.cameras()) {
                assert_eq!((&a.name, a.intrinsics), (&b.name, b.intrinsics));
                assert_eq!(a.cam_from_master.translation, b.cam_from_master.translation);
                let (ra, rb) = (
                    a.cam_from_master.rotation.to_rotation_matrix(),
                    b.cam_from_master.rotation.to_rotation_matrix(),
                );
                // The model stores R as a quaternion (`UnitQuaternion::from_matrix_eps` with eps 1e-15):
                // matrix → quaternion → matrix moves entries by up to ~1.3e-15 (measured on these 200 rigs).
                assert!((ra.matrix() - rb.matrix()).amax() <= 2e-15, "{ra} vs {rb}");
            }
        }
    }

    #[test]
    fn written_file_has_every_field_in_the_schema() {
        let rig = parse(EXAMPLE).unwrap();
        let text = rig_to_json_string(&rig);
        let value: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(
            value["cameras"][0]["distortion"],
            serde_json::json!([0.0, 0.0, 0.0, 0.0, 0.0])
        );
        assert!(
            value["cameras"][0].get("rotation").is_none(),
            "the master is the identity by definition"
        );
        assert_eq!(
            value["cameras"][1]["rotation"],
            serde_json::json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        );
        assert_eq!(
            value["cameras"][1]["translation"],
            serde_json::json!([-0.06, 0.0, 0.0])
        );
        assert_eq!(value["interface"]["index_air"], serde_json::json!(1.003));
        assert_eq!(
            value["interface"]["layers"],
            serde_json::json!([{"thickness": 0.014, "index": 1.473}])
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.json");
        write_rig(&path, &rig).unwrap();
        assert_eq!(read_rig(&path).unwrap(), parse(&text).unwrap());
        assert!(matches!(
            read_rig(&dir.path().join("none.json")),
            Err(IoError::Read { .. })
        ));
    }

    #[test]
    fn unknown_keys_are_named_at_every_level() {
        // serde_path_to_error ends the path with the unknown key itself.
        let (field, _, m) = json_error(&edited("\"interface\"", "\"colour\": 1, \"interface\""));
        assert_eq!(field, "colour");
        assert!(m.contains("unknown field `colour`"), "{m}");
        let (field, line, m) = json_error(&edited(
            "\"cy\": 512.0,\n     \"rotation\"",
            "\"cy\": 512.0, \"skew\": 0,\n     \"rotation\"",
        ));
        assert_eq!((field.as_str(), line), ("cameras[1].skew", 5));
        assert!(
            m.starts_with("rig.json:5:") && m.contains("cameras[1].skew: unknown field `skew`"),
            "{m}"
        );
        let (field, _, m) = json_error(&edited("\"index_water\"", "\"index_watr\""));
        assert_eq!(field, "interface.index_watr");
        assert!(m.contains("unknown field `index_watr`"), "{m}");
        let (field, _, m) = json_error(&edited("\"index\": 1.473", "\"index\": 1.473, \"n\": 2"));
        assert_eq!(field, "interface.layers[0].n");
        assert!(
            m.contains("unknown field `n`, expected `thickness` or `index`"),
            "{m}"
        );
    }

    #[test]
    fn schema_errors_name_the_field_and_position() {
        let (field, _, m) = json_error(&edited("\"fx\": 864.91, ", ""));
        assert_eq!(field, "cameras[0]");
        assert!(m.contains("missing field `fx`"), "{m}");
        let (field, line, m) = json_error(&edited(
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
            "[[1, 0, 0], [0, 1, 0]]",
        ));
        assert_eq!((field.as_str(), line), ("cameras[1].rotation", 6));
        assert!(m.contains("expected an array of length 3"), "{m}");
        let (field, _, _) = json_error(&edited(
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
            "[[1, 0], [0, 1, 0], [0, 0, 1]]",
        ));
        assert_eq!(field, "cameras[1].rotation[0]");
        let (field, _, m) = json_error(&edited("\"fx\": 864.91", "\"fx\": \"big\""));
        assert_eq!(field, "cameras[0].fx");
        assert!(m.contains("invalid type: string \"big\""), "{m}");
        let (field, _, _) = json_error(&edited("\"width\": 1280", "\"width\": -1"));
        assert_eq!(field, "cameras[0].width");
        let (field, _, _) = json_error(&edited("\"fx\": 864.91", "\"fx\": 1e999"));
        assert_eq!(field, "cameras[0].fx");
        let (field, _, m) = json_error(&edited("\"interface\": {", "\"interfaces\": {"));
        assert!(
            field == "interfaces" && m.contains("unknown field `interfaces`"),
            "{m}"
        );
        // No port at all: neither the shared one nor a port per camera.
        let (field, m) = invalid(&edited("\"interface\": {", "\"port\": {").replace(",\n  \"port\": {\"normal\": [0.1, 0.1, 1.0], \"distance\": 0.02,\n                \"layers\": [{\"thickness\": 0.014, \"index\": 1.473}],\n                \"index_air\": 1.003, \"index_water\": 1.333}", ""));
        assert!(
            field == "interface" && m.contains("missing"),
            "{field}: {m}"
        );
    }

    #[test]
    fn syntax_errors_give_line_and_column() {
        let (_, line, m) = json_error(&edited("\"cameras\": [", "\"cameras\": [,"));
        assert_eq!(line, 2);
        assert!(m.starts_with("rig.json:2:15: "), "{m}");
        let (_, line, m) = json_error("");
        assert!(line >= 1 && m.contains("EOF"), "{m}");
        let (_, _, m) = json_error(&format!("{EXAMPLE} trailing"));
        assert!(m.contains("trailing characters"), "{m}");
    }

    #[test]
    fn invalid_values_name_the_field() {
        let (field, m) = invalid(&edited("[0, 0, 0, 0, 0]", "[0, 0, 0, 0, 0, 0.1]"));
        assert_eq!(field, "cameras[0].distortion");
        assert!(m.contains("6 terms"), "{m}");
        let (field, m) = invalid(&edited("[0.1, 0.1, 1.0]", "[0, 0, 0]"));
        assert_eq!(field, "interface.normal");
        assert!(m.contains("must not be zero"), "{m}");
        let (field, m) = invalid(&edited("[0.1, 0.1, 1.0]", "[0.1, 0.1, -1.0]"));
        assert_eq!(field, "interface.normal");
        assert!(m.contains("into the water"), "{m}");
        let (field, m) = invalid(&edited("[-0.06, 0, 0]", "[0, 0, -0.5]"));
        assert_eq!(field, "cameras[1]");
        assert!(m.contains("'right' is not in the air"), "{m}");
        assert!(!m.contains("millimetres"), "{m}");
        // A baseline in millimetres puts the camera in the water: the error says so.
        let (field, m) = invalid(&edited("[-0.06, 0, 0]", "[-60, 0, 0]"));
        assert_eq!(field, "cameras[1]");
        assert!(
            m.contains("not in the air")
                && m.contains("60.000 m from the master")
                && m.contains("millimetres"),
            "{m}"
        );
        let (field, m) = invalid(&edited("\"fx\": 864.91", "\"fx\": -1"));
        assert_eq!(field, "cameras[0].fx");
        assert!(m.contains("must be > 0"), "{m}");
        let (field, m) = invalid(&edited(
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
            "[[1, 0.2, 0], [0, 1, 0], [0, 0, 1]]",
        ));
        assert_eq!(field, "cameras[1].rotation");
        assert!(m.contains("not a rotation matrix"), "{m}");
        let (field, _) = invalid(&edited("\"distance\": 0.02", "\"distance\": 0"));
        assert_eq!(field, "interface.distance");
        let (field, _) = invalid(&edited("\"thickness\": 0.014", "\"thickness\": 0"));
        assert_eq!(field, "interface.layers[0].thickness");
        let (field, _) = invalid(&edited("\"index\": 1.473", "\"index\": 0.5"));
        assert_eq!(field, "interface.layers[0].index");
        let (field, _) = invalid(&edited("\"index_water\": 1.333", "\"index_water\": 0.9"));
        assert_eq!(field, "interface.index_water");
        let (field, m) = invalid(&edited("\"name\": \"right\"", "\"name\": \"left\""));
        assert_eq!(field, "cameras[1]");
        assert!(m.contains("used twice"), "{m}");
        let (field, _) = invalid(&edited(
            "\"distortion\": [0, 0, 0, 0, 0]",
            "\"translation\": [0.1, 0, 0]",
        ));
        assert_eq!(field, "cameras[0]");
        let (field, _) =
            invalid(r#"{"cameras": [], "interface": {"normal": [0, 0, 1], "distance": 0.01}}"#);
        assert_eq!(field, "cameras");
    }

    const OWN_PORTS: &str = r#"{
  "cameras": [
    {"name": "a", "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "interface": {"normal": [0, 0, 1], "distance": 0.01, "layers": [{"thickness": 0.01, "index": 1.49}]}},
    {"name": "b", "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [-0.3, 0, 0],
     "interface": {"normal": [0.05, 0, 1], "distance": 0.02, "layers": [{"thickness": 0.012, "index": 1.49}]}}
  ]
}"#;

    #[test]
    fn a_port_per_camera_reads_writes_and_refuses_mixing() {
        let rig = parse(OWN_PORTS).unwrap();
        let Ports::PerCamera(ports) = rig.ports() else {
            panic!("per-camera ports expected")
        };
        assert_eq!(ports[1].air_distance(), 0.02);
        assert_eq!(ports[1].layers()[0].thickness, 0.012);
        // Camera b's own air layer is its port's distance, whatever its position.
        assert!((rig.refractive_camera(1).air_distance() - 0.02).abs() < 1e-15);
        // Written and read back: the same ports (the normal renormalised to the last bit).
        let back = parse(&rig_to_json_string(&rig)).unwrap();
        assert_eq!(back.cameras(), rig.cameras());
        let Ports::PerCamera(read) = back.ports() else {
            panic!("per-camera ports expected")
        };
        for (a, b) in ports.iter().zip(read) {
            assert!((a.normal().into_inner() - b.normal().into_inner()).norm() < 1e-15);
            assert_eq!(
                (a.air_distance(), a.layers()),
                (b.air_distance(), b.layers())
            );
        }
        // Both kinds at once.
        let both = OWN_PORTS.replacen(
            "\n  ]\n}",
            "\n  ],\n  \"interface\": {\"normal\": [0, 0, 1], \"distance\": 0.02}\n}",
            1,
        );
        let message = parse(&both).unwrap_err().to_string();
        assert!(
            message.contains("cameras[0].interface") && message.contains("not both"),
            "{message}"
        );
        // A port on one camera only.
        let one = OWN_PORTS.replacen(r#",
     "interface": {"normal": [0.05, 0, 1], "distance": 0.02, "layers": [{"thickness": 0.012, "index": 1.49}]}"#, "", 1);
        let message = parse(&one).unwrap_err().to_string();
        assert!(
            message.contains("cameras[1].interface") && message.contains("'b' has none"),
            "{message}"
        );
        // No port at all.
        let none = one.replacen(r#",
     "interface": {"normal": [0, 0, 1], "distance": 0.01, "layers": [{"thickness": 0.01, "index": 1.49}]}"#, "", 1);
        let message = parse(&none).unwrap_err().to_string();
        assert!(
            message.contains("interface") && message.contains("missing"),
            "{message}"
        );
        // A bad value names the camera's port.
        let bad = OWN_PORTS.replacen(r#""distance": 0.02"#, r#""distance": -0.02"#, 1);
        let message = parse(&bad).unwrap_err().to_string();
        assert!(
            message.contains("cameras[1].interface.distance"),
            "{message}"
        );
    }
}
