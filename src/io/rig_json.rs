//! The rig file (DESIGN.md §1): JSON with `cameras` (master first) and `interface`.
//! Unknown keys are rejected by name; the model validates the values.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::{IoError, read_text, write_atomic};
use crate::model::interface::{DEFAULT_INDEX_AIR, DEFAULT_INDEX_WATER};
use crate::model::{Interface, Layer, PinholeCamera, Rig, RigCamera};

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    cameras: Vec<CameraFile>,
    interface: InterfaceFile,
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
    #[serde(default, skip_serializing_if = "Option::is_none")]
    rotation: Option<[[f64; 3]; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    translation: Option<[f64; 3]>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct InterfaceFile {
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

fn default_index_air() -> f64 {
    DEFAULT_INDEX_AIR
}

fn default_index_water() -> f64 {
    DEFAULT_INDEX_WATER
}

/// Parses and validates a rig from JSON text; `path` only labels errors.
pub fn rig_from_json_str(text: &str, path: &Path) -> Result<Rig, IoError> {
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let file: RigFile = serde_path_to_error::deserialize(&mut deserializer).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        IoError::Json {
            path: path.to_path_buf(),
            field: if field == "." { String::new() } else { field },
            line: inner.line(),
            column: inner.column(),
            reason: strip_position(&inner.to_string()),
        }
    })?;
    let invalid = |field: String, reason: String| IoError::Invalid { path: path.to_path_buf(), field, reason };

    let mut cameras = Vec::with_capacity(file.cameras.len());
    for (i, c) in file.cameras.iter().enumerate() {
        let field = format!("cameras[{i}]");
        if c.distortion.len() > 5 {
            return Err(invalid(
                format!("{field}.distortion"),
                format!(
                    "has {} terms; flatport supports OpenCV's [k1, k2, p1, p2, k3]",
                    c.distortion.len()
                ),
            ));
        }
        let mut distortion = [0.0; 5];
        distortion[..c.distortion.len()].copy_from_slice(&c.distortion);
        let intrinsics = PinholeCamera::new(&c.name, c.width, c.height, c.fx, c.fy, c.cx, c.cy, distortion)
            .map_err(|e| invalid(field.clone(), e.to_string()))?;
        let r = c.rotation.unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let rotation = Matrix3::new(r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2]);
        let translation = Vector3::from(c.translation.unwrap_or([0.0; 3]));
        cameras.push(
            RigCamera::new(&c.name, intrinsics, rotation, translation).map_err(|e| invalid(field, e.to_string()))?,
        );
    }
    let i = &file.interface;
    let layers = i.layers.iter().map(|l| Layer { thickness: l.thickness, index: l.index }).collect();
    let interface = Interface::new(Vector3::from(i.normal), i.distance, layers, i.index_air, i.index_water)
        .map_err(|e| invalid("interface".into(), e.to_string()))?;
    Rig::new(cameras, interface).map_err(|e| invalid("cameras".into(), e.to_string()))
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
                    Some([[r[(0, 0)], r[(0, 1)], r[(0, 2)]], [r[(1, 0)], r[(1, 1)], r[(1, 2)]], [r[(2, 0)], r[(2, 1)], r[(2, 2)]]]),
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
            }
        })
        .collect();
    let i = rig.interface();
    let n = i.normal();
    let file = RigFile {
        cameras,
        interface: InterfaceFile {
            normal: [n.x, n.y, n.z],
            distance: i.air_distance(),
            layers: i.layers().iter().map(|l| LayerFile { thickness: l.thickness, index: l.index }).collect(),
            index_air: i.index_air(),
            index_water: i.index_water(),
        },
    };
    let mut text = serde_json::to_string_pretty(&file).expect("plain data always serialises");
    text.push('\n');
    text
}

/// Writes a rig file atomically.
pub fn write_rig(path: &Path, rig: &Rig) -> Result<(), IoError> {
    write_atomic(path, rig_to_json_string(rig).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn message(text: &str) -> String {
        parse(text).expect_err("should be rejected").to_string()
    }

    #[test]
    fn design_example_parses_with_normalised_normal() {
        let rig = parse(EXAMPLE).unwrap();
        let n = rig.interface().normal();
        assert!((n.x - 0.1 / 1.02f64.sqrt()).abs() < 1e-15);
        assert_eq!(rig.cameras().len(), 2);
        assert_eq!(rig.interface().index_air(), 1.003);
        assert_eq!(rig.cameras()[1].centre_in_master(), nalgebra::Point3::new(0.06, 0.0, 0.0));
    }

    #[test]
    fn defaults_apply_to_optional_fields() {
        let text = r#"{"cameras": [{"name": "c", "width": 10, "height": 10, "fx": 5, "fy": 5, "cx": 5, "cy": 5,
            "distortion": [0.1]}], "interface": {"normal": [0, 0, 1], "distance": 0.01}}"#;
        let rig = parse(text).unwrap();
        assert_eq!(rig.cameras()[0].intrinsics.distortion, [0.1, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(rig.interface().index_water(), DEFAULT_INDEX_WATER);
        assert!(rig.interface().layers().is_empty());
    }

    #[test]
    fn write_then_read_gives_the_same_rig() {
        let rotated = EXAMPLE.replace(
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
            "[[0.9998476951563913, 0, 0.01745240643728351], [0, 1, 0], [-0.01745240643728351, 0, 0.9998476951563913]]",
        );
        let rig = parse(&rotated).unwrap();
        let back = parse(&rig_to_json_string(&rig)).unwrap();
        let (a, b) = (rig.interface(), back.interface());
        // Renormalising an already unit normal may move its last bit.
        assert!((a.normal().into_inner() - b.normal().into_inner()).norm() < 1e-15);
        assert_eq!((a.air_distance(), a.layers(), a.index_air(), a.index_water()), (b.air_distance(), b.layers(), b.index_air(), b.index_water()));
        for (a, b) in rig.cameras().iter().zip(back.cameras()) {
            assert_eq!(a.intrinsics, b.intrinsics);
            // The rotation is stored as a quaternion: matrix → quaternion → matrix moves entries by a few ulp.
            assert!((a.cam_from_master.to_matrix() - b.cam_from_master.to_matrix()).norm() < 1e-14);
        }
    }

    #[test]
    fn unknown_keys_are_named_at_every_level() {
        let m = message(&EXAMPLE.replace("\"interface\"", "\"colour\": 1, \"interface\""));
        assert!(m.contains("colour"), "{m}");
        let m = message(&EXAMPLE.replace("\"fy\": 864.91, \"cx\": 640.0, \"cy\": 512.0,\n     \"rotation\"", "\"fy\": 864.91, \"cx\": 640.0, \"cy\": 512.0, \"skew\": 0,\n     \"rotation\""));
        assert!(m.contains("skew") && m.contains("cameras[1]"), "{m}");
        let m = message(&EXAMPLE.replace("\"index_water\"", "\"index_watr\""));
        assert!(m.contains("index_watr") && m.contains("interface"), "{m}");
        let m = message(&EXAMPLE.replace("\"index\": 1.473", "\"index\": 1.473, \"n\": 2"));
        assert!(m.contains("interface.layers[0]") && m.contains("`n`"), "{m}");
    }

    #[test]
    fn schema_errors_name_the_field_and_position() {
        let m = message(&EXAMPLE.replacen("\"fx\": 864.91, ", "", 1));
        assert!(m.contains("cameras[0]") && m.contains("fx"), "{m}");
        let m = message(&EXAMPLE.replace("[[1, 0, 0], [0, 1, 0], [0, 0, 1]]", "[[1, 0, 0], [0, 1, 0]]"));
        assert!(m.contains("cameras[1].rotation"), "{m}");
        let m = message(&EXAMPLE.replace("\"cameras\": [", "\"cameras\": [,"));
        assert!(m.starts_with("rig.json:2:"), "{m}");
        let m = message(&EXAMPLE.replace("\"fx\": 864.91", "\"fx\": \"big\""));
        assert!(m.contains("cameras[0].fx"), "{m}");
    }

    #[test]
    fn invalid_values_name_the_field() {
        let m = message(&EXAMPLE.replace("[0, 0, 0, 0, 0]", "[0, 0, 0, 0, 0, 0.1]"));
        assert!(m.contains("cameras[0].distortion") && m.contains("6 terms"), "{m}");
        let m = message(&EXAMPLE.replace("[0.1, 0.1, 1.0]", "[0, 0, 0]"));
        assert!(m.contains("interface") && m.contains("normal"), "{m}");
        let m = message(&EXAMPLE.replace("[0.1, 0.1, 1.0]", "[0.1, 0.1, -1.0]"));
        assert!(m.contains("into the water"), "{m}");
        let m = message(&EXAMPLE.replace("[-0.06, 0, 0]", "[0, 0, -0.5]"));
        assert!(m.contains("'right' is not in the air"), "{m}");
        let m = message(&EXAMPLE.replace("\"fx\": 864.91", "\"fx\": -1"));
        assert!(m.contains("cameras[0]") && m.contains("fx"), "{m}");
        let m = message(&EXAMPLE.replace("[[1, 0, 0], [0, 1, 0], [0, 0, 1]]", "[[1, 0.2, 0], [0, 1, 0], [0, 0, 1]]"));
        assert!(m.contains("cameras[1]") && m.contains("rotation"), "{m}");
    }
}
