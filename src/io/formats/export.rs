//! Exports of a rig into the files other tools read: colmap_underwater's `cameras.txt` with its
//! `FLATPORT` refractive model and a rig configuration, and OpenCV FileStorage YAML.
//!
//! Each writer returns the file's text; the caller writes it through
//! [`write_atomic`](crate::io::write_atomic).
//!
//! ## colmap_underwater's format (read from its source, not guessed)
//!
//! - `cameras.txt` line (`Reconstruction::ReadCamerasText`, `src/colmap/scene/reconstruction.cc`
//!   of colmap_underwater, COLMAP 3.9 based; e.g. github.com/hendrick404/clomp_underwater):
//!   `CAMERA_ID MODEL WIDTH HEIGHT PARAMS…` with exactly the model's number of parameters, then,
//!   when the line goes on, the refractive model's name and its parameters. Items are split at
//!   single spaces, so there is exactly one space between items and none at the end.
//! - `FLATPORT` parameters (`src/colmap/sensor/models_refrac.h`): `Nx Ny Nz int_dist int_thick
//!   na ng nw`. N is the unit interface normal in the camera's own frame; `FlatPort::CamFromImg`
//!   intersects the pixel's ray from the camera centre with the plane {X : N·X = int_dist}
//!   (`RayPlaneIntersection` in `src/colmap/sensor/ray3d.h`: point `dist · normal` on the plane),
//!   refracts na → ng, intersects the plane N·X = int_dist + int_thick, refracts ng → nw. So
//!   int_dist is flatport's own air layer of that camera, d_k = d − n·C_k, N = R_k n, int_thick the
//!   glass thickness and na, ng, nw the indices of air, glass and water.
//! - Pixels: COLMAP's models put the centre of the top-left pixel at (0.5, 0.5) (the comment at the
//!   top of `models_refrac.h`, as in COLMAP's `models.h`); flatport's is (0, 0), so cx, cy gain 0.5.
//! - `OPENCV` is fx fy cx cy k1 k2 p1 p2; `FULL_OPENCV` fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 with the
//!   rational radial term (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶), which is
//!   OpenCV's 5-term model when k4 = k5 = k6 = 0 (COLMAP `src/colmap/sensor/models.h`).
//! - The COLMAP 3.12 based port of colmap_underwater (e.g. github.com/gargakshit/colmap,
//!   `ReadCamerasText` in `src/colmap/scene/reconstruction_io_text.cc`) reads the same line with the
//!   token `REFRAC` before the refractive model's name ([`ColmapDialect::RefracToken`]), and rigs
//!   from `rigs.txt` (`ReadRigsText`, same file): `RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID`
//!   then per other sensor `SENSOR_TYPE SENSOR_ID HAS_POSE QW QX QY QZ TX TY TZ`, the pose being
//!   sensor_from_rig.
//! - Rig: COLMAP's `rig_bundle_adjuster --rig_config_path` JSON (`ReadCameraRigConfig`,
//!   `src/colmap/exe/sfm.cc`): a list of rigs `{"ref_camera_id", "cameras": [{"camera_id",
//!   "image_prefix", …}]}` with each camera's pose relative to the reference camera as cam_from_rig
//!   (X_cam = R·X_rig + t, quaternion w, x, y, z): `rel_qvec` / `rel_tvec` in COLMAP 3.9 (the base
//!   of colmap_underwater) and `cam_from_rig_rotation` / `cam_from_rig_translation` in later
//!   releases. Both spellings are written; each reader ignores the other's keys.

use std::fmt::Write as _;

use nalgebra::{Matrix3, Vector3};

use crate::model::{PinholeCamera, Rig};

/// Why a rig cannot be written in a format.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExportError {
    /// colmap_underwater's FLATPORT model has one glass layer.
    #[error(
        "colmap_underwater's FLATPORT model holds one glass layer (int_thick, ng); this port has {layers} layers, which it cannot represent"
    )]
    Layers {
        /// Layers of the rig's port.
        layers: usize,
    },
    /// The cameras of an OpenCV stereo file share one image size.
    #[error(
        "cameras '{a}' ({a_size:?}) and '{b}' ({b_size:?}) differ in image size; an OpenCV stereo file holds one"
    )]
    ImageSize {
        /// First camera.
        a: String,
        /// Its (width, height).
        a_size: (u32, u32),
        /// Second camera.
        b: String,
        /// Its (width, height).
        b_size: (u32, u32),
    },
    /// A camera index beyond the rig.
    #[error("the rig has {cameras} cameras, there is no camera {index}")]
    NoCamera {
        /// The index asked for.
        index: usize,
        /// Cameras in the rig.
        cameras: usize,
    },
}

/// How a `cameras.txt` line introduces the refractive model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColmapDialect {
    /// colmap_underwater (COLMAP 3.9 based): `… PARAMS FLATPORT …`.
    #[default]
    Legacy,
    /// Its COLMAP 3.12 based port: `… PARAMS REFRAC FLATPORT …`.
    RefracToken,
}

/// colmap_underwater's `cameras.txt` for every camera of `rig`, camera k with CAMERA_ID k + 1:
/// its lens as `OPENCV` (k3 = 0) or `FULL_OPENCV`, then `FLATPORT` with the shared port expressed
/// in that camera's own frame (N = R_k n, int_dist = d_k = d − n·C_k).
///
/// A port without layers is written exactly as a glass of thickness 0 whose index is the water's
/// (both refractions then give the one air → water refraction). Errors: more than one layer.
pub fn colmap_cameras_txt(rig: &Rig) -> Result<String, ExportError> {
    colmap_cameras_txt_as(rig, ColmapDialect::Legacy)
}

/// [`colmap_cameras_txt`] in either dialect.
pub fn colmap_cameras_txt_as(rig: &Rig, dialect: ColmapDialect) -> Result<String, ExportError> {
    let mut text = String::from(
        "# Camera list with one line of data per camera, written by flatport export colmap:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[], REFRAC_MODEL, REFRAC_PARAMS[]\n\
         #   (FLATPORT: Nx Ny Nz int_dist int_thick na ng nw, the port in that camera's frame)\n",
    );
    let _ = writeln!(text, "# Number of cameras: {}", rig.cameras().len());
    for (k, camera) in rig.cameras().iter().enumerate() {
        let interface = rig.port_in_master(k);
        let (thickness, index_glass) = match interface.layers() {
            [] => (0.0, interface.index_water()),
            [glass] => (glass.thickness, glass.index),
            layers => {
                return Err(ExportError::Layers {
                    layers: layers.len(),
                });
            }
        };
        let view = rig.refractive_camera(k);
        let normal_in_cam = view.master_from_cam().transpose() * view.normal().into_inner();
        let (model, lens) = colmap_lens(&camera.intrinsics);
        let i = &camera.intrinsics;
        let mut items: Vec<String> = vec![
            (k + 1).to_string(),
            model.to_string(),
            i.width.to_string(),
            i.height.to_string(),
        ];
        items.extend(lens.iter().map(|v| v.to_string()));
        if dialect == ColmapDialect::RefracToken {
            items.push("REFRAC".into());
        }
        items.push("FLATPORT".into());
        let port = [
            normal_in_cam.x,
            normal_in_cam.y,
            normal_in_cam.z,
            view.air_distance(),
            thickness,
            interface.index_air(),
            index_glass,
            interface.index_water(),
        ];
        items.extend(port.iter().map(|v| v.to_string()));
        let _ = writeln!(text, "{}", items.join(" "));
    }
    Ok(text)
}

/// COLMAP's lens model and its parameters, principal point moved to COLMAP's pixel convention.
fn colmap_lens(i: &PinholeCamera) -> (&'static str, Vec<f64>) {
    let [k1, k2, p1, p2, k3] = i.distortion;
    let (cx, cy) = (i.cx + 0.5, i.cy + 0.5);
    if k3 == 0.0 {
        ("OPENCV", vec![i.fx, i.fy, cx, cy, k1, k2, p1, p2])
    } else {
        (
            "FULL_OPENCV",
            vec![i.fx, i.fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0],
        )
    }
}

/// Each camera's pose relative to the master as COLMAP writes poses: quaternion (w, x, y, z) with
/// w ≥ 0 (q and −q are one rotation) and translation, X_cam = R·X_master + t.
fn colmap_pose(camera: &crate::model::RigCamera) -> ([f64; 4], [f64; 3]) {
    let pose = &camera.cam_from_master;
    let q = pose.rotation.quaternion();
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = pose.translation.vector;
    (
        [sign * q.w, sign * q.i, sign * q.j, sign * q.k],
        [t.x, t.y, t.z],
    )
}

/// COLMAP 3.12's `rigs.txt` for `rig`: one rig, the master (CAMERA 1) its reference sensor, every
/// other camera k a sensor `CAMERA k+1` with its sensor_from_rig pose (cam_from_master).
pub fn colmap_rigs_txt(rig: &Rig) -> String {
    let mut text = String::from(
        "# Rig calib list with one line of data per calib, written by flatport export colmap:\n\
         #   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n\
         # Number of rigs: 1\n",
    );
    let mut items: Vec<String> = vec![
        "1".into(),
        rig.cameras().len().to_string(),
        "CAMERA".into(),
        "1".into(),
    ];
    for (k, camera) in rig.cameras().iter().enumerate().skip(1) {
        let (q, t) = colmap_pose(camera);
        items.extend(["CAMERA".to_string(), (k + 1).to_string(), "1".to_string()]);
        items.extend(q.iter().chain(&t).map(|v| v.to_string()));
    }
    let _ = writeln!(text, "{}", items.join(" "));
    text
}

/// COLMAP's rig configuration (JSON) for `rig`: one rig whose reference is the master (CAMERA_ID
/// 1), every camera with its cam_from_master pose and the image prefix `NAME/`.
pub fn colmap_rig_config(rig: &Rig) -> String {
    let cameras: Vec<serde_json::Value> = rig
        .cameras()
        .iter()
        .enumerate()
        .map(|(k, camera)| {
            let (wxyz, t) = colmap_pose(camera);
            serde_json::json!({
                "camera_id": k + 1,
                "image_prefix": format!("{}/", camera.name),
                "rel_qvec": wxyz,
                "rel_tvec": t,
                "cam_from_rig_rotation": wxyz,
                "cam_from_rig_translation": t,
            })
        })
        .collect();
    let config = serde_json::json!([{ "ref_camera_id": 1, "cameras": cameras }]);
    serde_json::to_string_pretty(&config).expect("JSON of numbers and strings") + "\n"
}

/// The in-air calibration of cameras `a` and `b` of `rig` as `cv::FileStorage` writes a stereo
/// calibration (`%YAML:1.0`; `M1 D1 M2 D2` as `!!opencv-matrix`, `R T` with X_b = R·X_a + T), the
/// file `flatport rig from-opencv` reads. `b = None` writes camera `a` alone (`M1 D1`).
///
/// Errors: an index beyond the rig; two cameras of different image sizes.
pub fn opencv_yaml(rig: &Rig, a: usize, b: Option<usize>) -> Result<String, ExportError> {
    let cameras = rig.cameras();
    for index in std::iter::once(a).chain(b) {
        if index >= cameras.len() {
            return Err(ExportError::NoCamera {
                index,
                cameras: cameras.len(),
            });
        }
    }
    let first = &cameras[a];
    let size = |i: &PinholeCamera| (i.width, i.height);
    let mut text = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(text, "image_width: {}", first.intrinsics.width);
    let _ = writeln!(text, "image_height: {}", first.intrinsics.height);
    let _ = writeln!(
        text,
        "camera_names: [ {}{} ]",
        yaml_quoted(&first.name),
        b.map(|b| format!(", {}", yaml_quoted(&cameras[b].name)))
            .unwrap_or_default()
    );
    write_matrix(&mut text, "M1", 3, 3, &camera_matrix(&first.intrinsics));
    write_matrix(&mut text, "D1", 1, 5, &first.intrinsics.distortion);
    if let Some(b) = b {
        let second = &cameras[b];
        if size(&first.intrinsics) != size(&second.intrinsics) {
            return Err(ExportError::ImageSize {
                a: first.name.clone(),
                a_size: size(&first.intrinsics),
                b: second.name.clone(),
                b_size: size(&second.intrinsics),
            });
        }
        // X_b = R_b·X_m + t_b and X_a = R_a·X_m + t_a give X_b = (R_b R_aᵀ)·X_a + t_b − R_b R_aᵀ t_a.
        let (pose_a, pose_b) = (&first.cam_from_master, &second.cam_from_master);
        let rotation: Matrix3<f64> = (pose_b.rotation * pose_a.rotation.inverse())
            .to_rotation_matrix()
            .into_inner();
        let translation: Vector3<f64> =
            pose_b.translation.vector - rotation * pose_a.translation.vector;
        write_matrix(&mut text, "M2", 3, 3, &camera_matrix(&second.intrinsics));
        write_matrix(&mut text, "D2", 1, 5, &second.intrinsics.distortion);
        let r: Vec<f64> = (0..9).map(|i| rotation[(i / 3, i % 3)]).collect();
        write_matrix(&mut text, "R", 3, 3, &r);
        write_matrix(&mut text, "T", 3, 1, translation.as_slice());
    }
    Ok(text)
}

/// `v` as C's `printf("%.16e", v)`: Rust's `{:.16e}` with the exponent signed and two digits at least.
fn c_exponential(v: f64) -> String {
    let text = format!("{v:.16e}");
    match text.split_once('e') {
        Some((mantissa, exponent)) => {
            let exponent: i32 = exponent.parse().expect("Rust writes an integer exponent");
            format!(
                "{mantissa}e{}{:02}",
                if exponent < 0 { '-' } else { '+' },
                exponent.abs()
            )
        }
        None => text, // inf, NaN
    }
}

/// `text` as a YAML double-quoted scalar: `"` and `\` escaped, and every character that YAML
/// or a reader may take for a line break or a control (C0, DEL, C1, U+2028, U+2029, U+FEFF) as
/// `\xXX` or `\uXXXX`, so that any camera name reads back as itself.
fn yaml_quoted(text: &str) -> String {
    let mut quoted = String::with_capacity(text.len() + 2);
    quoted.push('"');
    for c in text.chars() {
        match c {
            '"' => quoted.push_str("\\\""),
            '\\' => quoted.push_str("\\\\"),
            c if (c as u32) < 0x20 || ('\u{7f}'..='\u{9f}').contains(&c) => {
                let _ = write!(quoted, "\\x{:02x}", c as u32);
            }
            '\u{2028}' | '\u{2029}' | '\u{feff}' => {
                let _ = write!(quoted, "\\u{:04x}", c as u32);
            }
            c => quoted.push(c),
        }
    }
    quoted.push('"');
    quoted
}

/// K row-major.
fn camera_matrix(i: &PinholeCamera) -> [f64; 9] {
    [i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0]
}

/// One `!!opencv-matrix` block of doubles, each value as C's `%.16e` writes it (17 significant
/// digits, `8.6490999999999997e+02`), as OpenCV writes doubles; it reads them back exactly.
fn write_matrix(text: &mut String, name: &str, rows: usize, cols: usize, values: &[f64]) {
    let data: Vec<String> = values.iter().map(|&v| c_exponential(v)).collect();
    let _ = write!(
        text,
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ "
    );
    for (i, chunk) in data.chunks(4).enumerate() {
        if i > 0 {
            text.push_str(",\n       ");
        }
        text.push_str(&chunk.join(", "));
    }
    text.push_str(" ]\n");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{parse_opencv_stereo, rig_from_json_str};
    use std::path::Path;

    fn rig(layers: &str, cameras: &str) -> Rig {
        let text = format!(
            r#"{{"cameras": {cameras}, "interface": {{"normal": [0.1, -0.05, 1.0], "distance": 0.02, "layers": {layers}, "index_air": 1.003, "index_water": 1.334}}}}"#
        );
        rig_from_json_str(&text, Path::new("test.json")).unwrap()
    }

    const STEREO: &str = r#"[
        {"name": "left", "width": 1280, "height": 1024, "fx": 864.91, "fy": 865.5, "cx": 640.25, "cy": 511.75, "distortion": [-0.1, 0.01, 0.0005, -0.0025, 0.001]},
        {"name": "right", "width": 1280, "height": 1024, "fx": 870, "fy": 870, "cx": 630, "cy": 500,
         "rotation": [[0.9998468789078377, -0.017499106784510807, 0.0], [0.017499106784510807, 0.9998468789078377, 0.0], [0.0, 0.0, 1.0]], "translation": [-0.06, 0.001, 0.002]}]"#;

    #[test]
    fn colmap_lines_have_one_space_between_items_and_the_colmap_pixel_centre() {
        let rig = rig(r#"[{"thickness": 0.014, "index": 1.473}]"#, STEREO);
        let text = colmap_cameras_txt(&rig).unwrap();
        let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
        assert_eq!(lines.len(), 2);
        let left: Vec<&str> = lines[0].split(' ').collect();
        // 4 + 12 FULL_OPENCV parameters + FLATPORT + 8.
        assert_eq!(left.len(), 4 + 12 + 1 + 8, "{}", lines[0]);
        assert_eq!(&left[..4], ["1", "FULL_OPENCV", "1280", "1024"]);
        assert_eq!(left[6], "640.75");
        assert_eq!(left[7], "512.25");
        assert_eq!(left[16], "FLATPORT");
        let right: Vec<&str> = lines[1].split(' ').collect();
        assert_eq!(right[1], "OPENCV");
        assert_eq!(right.len(), 4 + 8 + 1 + 8);
        // The right camera's own port: its normal is R n, its air layer d − n·C.
        let view = rig.refractive_camera(1);
        let n: Vec<f64> = right[13..16].iter().map(|s| s.parse().unwrap()).collect();
        let expected = rig.cameras()[1].cam_from_master.rotation
            * rig.shared_interface().unwrap().normal().into_inner();
        for i in 0..3 {
            assert!((n[i] - expected[i]).abs() < 1e-15, "{n:?} vs {expected}");
        }
        assert_eq!(right[16].parse::<f64>().unwrap(), view.air_distance());
        assert_eq!(&right[17..], ["0.014", "1.003", "1.473", "1.334"]);
    }

    #[test]
    fn colmap_refuses_two_layers_and_writes_none_as_a_zero_glass() {
        let two = rig(
            r#"[{"thickness": 0.01, "index": 1.5}, {"thickness": 0.01, "index": 1.4}]"#,
            STEREO,
        );
        assert_eq!(
            colmap_cameras_txt(&two),
            Err(ExportError::Layers { layers: 2 })
        );
        let none = rig("[]", STEREO);
        let text = colmap_cameras_txt(&none).unwrap();
        let last = text.lines().last().unwrap();
        assert!(last.ends_with(" 0 1.003 1.334 1.334"), "{last}");
    }

    #[test]
    fn doubles_are_written_as_c_writes_them() {
        assert_eq!(c_exponential(864.91), "8.6490999999999997e+02");
        assert_eq!(c_exponential(-2.5e-3), "-2.5000000000000001e-03");
        assert_eq!(c_exponential(1e-300), "1.0000000000000000e-300");
        assert_eq!(c_exponential(0.0), "0.0000000000000000e+00");
    }

    #[test]
    fn the_refrac_token_dialect_and_rigs_txt() {
        let rig = rig("[]", STEREO);
        let legacy = colmap_cameras_txt(&rig).unwrap();
        let token = colmap_cameras_txt_as(&rig, ColmapDialect::RefracToken).unwrap();
        assert_eq!(token, legacy.replace(" FLATPORT ", " REFRAC FLATPORT "));
        let rigs = colmap_rigs_txt(&rig);
        let line: Vec<&str> = rigs.lines().last().unwrap().split(' ').collect();
        assert_eq!(
            &line[..8],
            ["1", "2", "CAMERA", "1", "CAMERA", "2", "1", line[7]]
        );
        assert_eq!(line.len(), 4 + 3 + 7);
        assert_eq!(&line[11..], ["-0.06", "0.001", "0.002"]);
    }

    #[test]
    fn rig_config_holds_cam_from_master_in_both_spellings() {
        let rig = rig("[]", STEREO);
        let config: serde_json::Value = serde_json::from_str(&colmap_rig_config(&rig)).unwrap();
        let right = &config[0]["cameras"][1];
        assert_eq!(config[0]["ref_camera_id"], 1);
        assert_eq!(right["camera_id"], 2);
        assert_eq!(right["image_prefix"], "right/");
        assert_eq!(right["rel_tvec"], serde_json::json!([-0.06, 0.001, 0.002]));
        assert_eq!(right["rel_qvec"], right["cam_from_rig_rotation"]);
        let w = right["rel_qvec"][0].as_f64().unwrap();
        let z = right["rel_qvec"][3].as_f64().unwrap();
        // A rotation about z by 0.0175 rad.
        let angle = 0.0175f64;
        assert!((w - (angle / 2.0).cos()).abs() < 1e-12 && (z - (angle / 2.0).sin()).abs() < 1e-12);
    }

    #[test]
    fn opencv_yaml_reads_back_as_the_same_stereo_rig() {
        let rig = rig(r#"[{"thickness": 0.014, "index": 1.473}]"#, STEREO);
        let text = opencv_yaml(&rig, 0, Some(1)).unwrap();
        let stereo = parse_opencv_stereo(&text, Path::new("exported.yml")).unwrap();
        let back = stereo
            .to_rig(
                ["left", "right"],
                None,
                rig.shared_interface().unwrap().clone(),
                Path::new("exported.yml"),
            )
            .unwrap();
        assert_eq!(back.cameras()[0].intrinsics, rig.cameras()[0].intrinsics);
        assert_eq!(back.cameras()[1].intrinsics, rig.cameras()[1].intrinsics);
        let (a, b) = (
            &back.cameras()[1].cam_from_master,
            &rig.cameras()[1].cam_from_master,
        );
        assert!(
            (a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-15,
            "{a} vs {b}"
        );
    }

    #[test]
    fn camera_names_of_any_text_read_back_from_the_yaml() {
        // YAML's own characters, escapes, line breaks and controls in the names.
        let names = ["le\"ft: [x] # y", "ri\\ght\n\u{2028}\u{7}\u{85}é"];
        let cameras = STEREO
            .replacen("\"left\"", &serde_json::to_string(names[0]).unwrap(), 1)
            .replacen("\"right\"", &serde_json::to_string(names[1]).unwrap(), 1);
        let rig = rig("[]", &cameras);
        let text = opencv_yaml(&rig, 0, Some(1)).unwrap();
        parse_opencv_stereo(&text, Path::new("names.yml")).unwrap();
        // The camera_names sequence holds the names themselves.
        let events: Vec<String> =
            saphyr_parser::Parser::new_from_str(text.strip_prefix("%YAML:1.0\n").unwrap())
                .filter_map(|e| match e.unwrap().0 {
                    saphyr_parser::Event::Scalar(s, ..) => Some(s.into_owned()),
                    _ => None,
                })
                .collect();
        let at = events.iter().position(|s| s == "camera_names").unwrap();
        assert_eq!(&events[at + 1..at + 3], &names);
    }

    #[test]
    fn opencv_yaml_of_one_camera_and_of_a_reversed_pair() {
        let rig = rig("[]", STEREO);
        let one = opencv_yaml(&rig, 1, None).unwrap();
        assert!(
            one.contains("M1: !!opencv-matrix")
                && one.contains("D1: !!opencv-matrix")
                && !one.contains("M2")
        );
        assert!(
            one.contains("8.7000000000000000e+02") && one.contains("0.0000000000000000e+00"),
            "{one}"
        );
        // right → left: R, T invert the rig's extrinsics.
        let reversed =
            parse_opencv_stereo(&opencv_yaml(&rig, 1, Some(0)).unwrap(), Path::new("r.yml"))
                .unwrap();
        let pose = rig.cameras()[1].cam_from_master.inverse();
        let r = pose.rotation.to_rotation_matrix().into_inner();
        assert!((reversed.rotation - r).abs().max() < 1e-15);
        assert!((reversed.translation - pose.translation.vector).abs().max() < 1e-15);
        assert_eq!(
            opencv_yaml(&rig, 2, None),
            Err(ExportError::NoCamera {
                index: 2,
                cameras: 2
            })
        );
    }
}
