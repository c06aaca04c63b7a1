//! Import of OpenCV `stereoCalibrate` results saved with `cv::FileStorage` as YAML
//! (`%YAML:1.0`, `!!opencv-matrix` entries). Only that subset of YAML is read: top-level keys with
//! scalars, flow sequences or `!!opencv-matrix` blocks. Other keys (E, F, R1, P1, Q, …) are ignored.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::{IoError, read_text};
use crate::model::{Interface, PinholeCamera, Rig, RigCamera};

/// The two cameras of an OpenCV stereo calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenCvStereo {
    /// Camera matrices K of the first (master) and second camera.
    pub camera_matrix: [Matrix3<f64>; 2],
    /// Distortion `[k1, k2, p1, p2, k3]` of both cameras.
    pub distortion: [[f64; 5]; 2],
    /// R: rotation from the first camera's frame to the second's.
    pub rotation: Matrix3<f64>,
    /// T: X₂ = R·X₁ + T, metres (in the unit the calibration board was given in).
    pub translation: Vector3<f64>,
    /// Image size (width, height) when the file has one.
    pub image_size: Option<(u32, u32)>,
}

#[derive(Debug)]
enum Value {
    Scalar(String),
    Numbers(Vec<f64>),
    Matrix { rows: usize, cols: usize, data: Vec<f64> },
    Other,
}

#[derive(Debug)]
struct Entry {
    line: usize,
    value: Value,
}

/// Reads and parses an OpenCV FileStorage YAML file.
pub fn read_opencv_stereo(path: &Path) -> Result<OpenCvStereo, IoError> {
    parse_opencv_stereo(&read_text(path)?, path)
}

fn parse_numbers(text: &str, line: usize, path: &Path) -> Result<Vec<f64>, IoError> {
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>().map_err(|_| IoError::OpenCv {
                path: path.to_path_buf(),
                line,
                reason: format!("'{s}' is not a number"),
            })
        })
        .collect()
}

fn parse_entries(text: &str, path: &Path) -> Result<HashMap<String, Entry>, IoError> {
    let err = |line: usize, reason: String| IoError::OpenCv { path: path.to_path_buf(), line, reason };
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    let first = lines.by_ref().find(|(_, l)| !l.trim().is_empty());
    match first {
        Some((_, l)) if l.trim_start().starts_with("%YAML") => {}
        Some((n, _)) => return Err(err(n, "not an OpenCV FileStorage YAML file: it must start with %YAML:1.0".into())),
        None => return Err(err(1, "file is empty".into())),
    }
    let mut entries: HashMap<String, Entry> = HashMap::new();
    // (key, line, rows, cols, data text) of the !!opencv-matrix being read.
    let mut matrix: Option<(String, usize, Option<usize>, Option<usize>, Option<String>)> = None;
    let mut collecting_data = false;
    let finish = |m: (String, usize, Option<usize>, Option<usize>, Option<String>),
                  entries: &mut HashMap<String, Entry>|
     -> Result<(), IoError> {
        let (key, line, rows, cols, data) = m;
        let missing = |what: &str| err(line, format!("{key}: opencv-matrix without '{what}'"));
        let (rows, cols) = (rows.ok_or_else(|| missing("rows"))?, cols.ok_or_else(|| missing("cols"))?);
        let data = data.ok_or_else(|| missing("data"))?;
        let inner = data.trim().trim_start_matches('[').trim_end_matches(']');
        let numbers = parse_numbers(inner, line, path)?;
        if numbers.len() != rows * cols {
            return Err(err(line, format!("{key}: {rows}x{cols} matrix with {} values", numbers.len())));
        }
        entries.insert(key, Entry { line, value: Value::Matrix { rows, cols, data: numbers } });
        Ok(())
    };
    for (n, raw) in lines {
        let line = raw.split('#').next().unwrap_or("");
        if collecting_data {
            let m = matrix.as_mut().expect("collecting data only inside a matrix");
            let data = m.4.get_or_insert_with(String::new);
            data.push(' ');
            data.push_str(line.trim());
            if line.contains(']') {
                collecting_data = false;
            }
            continue;
        }
        if line.trim().is_empty() || line.trim() == "---" {
            continue;
        }
        let indented = line.starts_with(' ') || line.starts_with('\t');
        let (key, rest) = line
            .trim()
            .split_once(':')
            .ok_or_else(|| err(n, format!("expected 'key: value', found '{}'", line.trim())))?;
        let (key, rest) = (key.trim().to_string(), rest.trim());
        if indented {
            let Some(m) = matrix.as_mut() else { continue }; // inside a mapping we do not read
            let parse_count = |s: &str| s.parse::<usize>().map_err(|_| err(n, format!("{key}: '{s}' is not a count")));
            match key.as_str() {
                "rows" => m.2 = Some(parse_count(rest)?),
                "cols" => m.3 = Some(parse_count(rest)?),
                "dt" if rest != "d" && rest != "f" => {
                    return Err(err(n, format!("{}: element type '{rest}' (expected d or f)", m.0)));
                }
                "data" => {
                    m.4 = Some(rest.to_string());
                    collecting_data = !rest.contains(']');
                }
                _ => {}
            }
            continue;
        }
        if let Some(m) = matrix.take() {
            finish(m, &mut entries)?;
        }
        if rest.starts_with("!!opencv-matrix") {
            matrix = Some((key, n, None, None, None));
        } else if rest.starts_with('[') {
            let inner = rest.trim_start_matches('[').trim_end_matches(']');
            entries.insert(key, Entry { line: n, value: Value::Numbers(parse_numbers(inner, n, path)?) });
        } else if rest.is_empty() || rest.starts_with('!') || rest.starts_with('{') {
            entries.insert(key, Entry { line: n, value: Value::Other });
        } else {
            entries.insert(key, Entry { line: n, value: Value::Scalar(rest.trim_matches('"').to_string()) });
        }
    }
    if collecting_data {
        let key = matrix.as_ref().map(|m| m.0.clone()).unwrap_or_default();
        return Err(err(0, format!("{key}: data list is not closed with ']'")));
    }
    if let Some(m) = matrix.take() {
        finish(m, &mut entries)?;
    }
    Ok(entries)
}

/// Parses the text of an OpenCV FileStorage YAML file; `path` labels errors.
///
/// Keys: `M1 D1 M2 D2 R T`, or `K1`/`K2`, or `cameraMatrix1`/`distCoeffs1`/…; image size from
/// `image_width` + `image_height`, or `imageSize`. Distortion may have 4, 5, 8, 12 or 14
/// coefficients; coefficients past the fifth must be zero (flatport models `[k1, k2, p1, p2, k3]`).
pub fn parse_opencv_stereo(text: &str, path: &Path) -> Result<OpenCvStereo, IoError> {
    let entries = parse_entries(text, path)?;
    let err = |line: usize, reason: String| IoError::OpenCv { path: path.to_path_buf(), line, reason };
    fn find<'a>(entries: &'a HashMap<String, Entry>, names: &[&'static str]) -> Option<(&'static str, &'a Entry)> {
        names.iter().find_map(|n| entries.get(*n).map(|e| (*n, e)))
    }
    let find = |names: &[&'static str]| find(&entries, names);
    let matrix = |names: &[&'static str], rows: usize, cols: usize| -> Result<Vec<f64>, IoError> {
        let (name, entry) = find(names).ok_or_else(|| err(0, format!("missing key {}", names.join(" or "))))?;
        match &entry.value {
            Value::Matrix { rows: r, cols: c, data } if r * c == rows * cols && (*r == rows || *r == cols) => {
                Ok(data.clone())
            }
            Value::Matrix { rows: r, cols: c, .. } => {
                Err(err(entry.line, format!("{name} is {r}x{c}, expected {rows}x{cols}")))
            }
            _ => Err(err(entry.line, format!("{name} is not an !!opencv-matrix"))),
        }
    };
    let distortion = |names: &[&'static str]| -> Result<[f64; 5], IoError> {
        let (name, entry) = find(names).ok_or_else(|| err(0, format!("missing key {}", names.join(" or "))))?;
        let Value::Matrix { data, .. } = &entry.value else {
            return Err(err(entry.line, format!("{name} is not an !!opencv-matrix")));
        };
        if ![4, 5, 8, 12, 14].contains(&data.len()) {
            return Err(err(entry.line, format!("{name} has {} coefficients (OpenCV uses 4, 5, 8, 12 or 14)", data.len())));
        }
        if let Some(i) = data.iter().skip(5).position(|&k| k != 0.0) {
            return Err(err(
                entry.line,
                format!(
                    "{name}: coefficient {} is {} but flatport supports only [k1, k2, p1, p2, k3]",
                    i + 6,
                    data[i + 5]
                ),
            ));
        }
        let mut d = [0.0; 5];
        for (slot, k) in d.iter_mut().zip(data) {
            *slot = *k;
        }
        Ok(d)
    };
    let camera_matrix = |names: &[&'static str]| -> Result<Matrix3<f64>, IoError> {
        let data = matrix(names, 3, 3)?;
        let k = Matrix3::from_row_slice(&data);
        let line = find(names).map_or(0, |(_, e)| e.line);
        if k[(0, 1)] != 0.0 {
            return Err(err(line, format!("{}: skew {} is not supported", names[0], k[(0, 1)])));
        }
        if k[(1, 0)] != 0.0 || k[(2, 0)] != 0.0 || k[(2, 1)] != 0.0 || k[(2, 2)] != 1.0 {
            return Err(err(line, format!("{}: not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]", names[0])));
        }
        Ok(k)
    };
    let image_size = match (entries.get("image_width"), entries.get("image_height"), entries.get("imageSize")) {
        (Some(w), Some(h), _) => Some((size(w, "image_width", path)?, size(h, "image_height", path)?)),
        (_, _, Some(Entry { value: Value::Numbers(v), line })) | (_, _, Some(Entry { value: Value::Matrix { data: v, .. }, line }))
            if v.len() == 2 =>
        {
            let whole = |x: f64| (x >= 1.0 && x.fract() == 0.0 && x <= u32::MAX as f64).then_some(x as u32);
            Some((
                whole(v[0]).ok_or_else(|| err(*line, format!("imageSize width {} is not a pixel count", v[0])))?,
                whole(v[1]).ok_or_else(|| err(*line, format!("imageSize height {} is not a pixel count", v[1])))?,
            ))
        }
        _ => None,
    };
    Ok(OpenCvStereo {
        camera_matrix: [
            camera_matrix(&["M1", "K1", "cameraMatrix1"])?,
            camera_matrix(&["M2", "K2", "cameraMatrix2"])?,
        ],
        distortion: [distortion(&["D1", "distCoeffs1"])?, distortion(&["D2", "distCoeffs2"])?],
        rotation: Matrix3::from_row_slice(&matrix(&["R"], 3, 3)?),
        translation: Vector3::from_column_slice(&matrix(&["T"], 3, 1)?),
        image_size,
    })
}

fn size(entry: &Entry, name: &str, path: &Path) -> Result<u32, IoError> {
    match &entry.value {
        Value::Scalar(s) => s.parse::<u32>().ok().filter(|&v| v > 0),
        _ => None,
    }
    .ok_or_else(|| IoError::OpenCv {
        path: path.to_path_buf(),
        line: entry.line,
        reason: format!("{name} must be a positive whole number of pixels"),
    })
}

impl OpenCvStereo {
    /// A rig with cameras `names[0]` (the master, identity) and `names[1]` (R, T) behind
    /// `interface`. `image_size` overrides the file's; one of them must be given.
    pub fn to_rig(
        &self,
        names: [&str; 2],
        image_size: Option<(u32, u32)>,
        interface: Interface,
        path: &Path,
    ) -> Result<Rig, IoError> {
        let invalid = |field: String, reason: String| IoError::Invalid { path: path.to_path_buf(), field, reason };
        let (width, height) = image_size.or(self.image_size).ok_or_else(|| {
            invalid(
                "image size".into(),
                "the file has no image_width/image_height or imageSize; give --size WIDTHxHEIGHT".into(),
            )
        })?;
        let mut cameras = Vec::with_capacity(2);
        for (i, name) in names.iter().enumerate() {
            let k = &self.camera_matrix[i];
            let intrinsics = PinholeCamera::new(
                name,
                width,
                height,
                k[(0, 0)],
                k[(1, 1)],
                k[(0, 2)],
                k[(1, 2)],
                self.distortion[i],
            )
            .map_err(|e| invalid(format!("camera {}", i + 1), e.to_string()))?;
            let (rotation, translation) =
                if i == 0 { (Matrix3::identity(), Vector3::zeros()) } else { (self.rotation, self.translation) };
            cameras.push(
                RigCamera::new(name, intrinsics, rotation, translation)
                    .map_err(|e| invalid("R, T".into(), e.to_string()))?,
            );
        }
        Rig::new(cameras, interface).map_err(|e| invalid("rig".into(), e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STEREO: &str = "%YAML:1.0
---
image_width: 1280
image_height: 1024
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 8.6491000000000003e+02, 0., 640., 0., 8.6491000000000003e+02,
       512., 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -1.0e-01, 1.0000000000000000e-02, 0., 0., 0. ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 870., 0., 630., 0., 870., 500., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 1
   cols: 8
   dt: d
   data: [ -0.09, 0.011, 0., 0., 0., 0., 0., 0. ]
R: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
T: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -6.0e-02, 0., 0. ]
E: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 0., 0., 0., 0., 0., 0.06, 0., -0.06, 0. ]
";

    fn parse(text: &str) -> Result<OpenCvStereo, IoError> {
        parse_opencv_stereo(text, Path::new("stereo.yml"))
    }

    #[test]
    fn reads_a_stereo_calibration() {
        let s = parse(STEREO).unwrap();
        // The file's 17-digit text, not the literal 864.91.
        assert_eq!(s.camera_matrix[0][(0, 0)], 8.6491000000000003e+02);
        assert_eq!(s.camera_matrix[0][(1, 2)], 512.0);
        assert_eq!(s.camera_matrix[1][(0, 2)], 630.0);
        assert_eq!(s.distortion[0], [-0.1, 0.01, 0.0, 0.0, 0.0]);
        assert_eq!(s.distortion[1][1], 0.011);
        assert_eq!(s.translation, Vector3::new(-0.06, 0.0, 0.0));
        assert_eq!(s.image_size, Some((1280, 1024)));
        let interface = Interface::new(Vector3::z(), 0.02, vec![], 1.0, 1.333).unwrap();
        let rig = s.to_rig(["left", "right"], None, interface, Path::new("stereo.yml")).unwrap();
        assert_eq!(rig.cameras()[1].intrinsics.fx, 870.0);
        assert!((rig.cameras()[1].centre_in_master() - nalgebra::Point3::new(0.06, 0.0, 0.0)).norm() < 1e-15);
    }

    #[test]
    fn k_names_and_image_size_sequence_are_accepted() {
        let text = STEREO.replace("M1:", "K1:").replace("M2:", "K2:").replace(
            "image_width: 1280\nimage_height: 1024\n",
            "imageSize: [ 640, 480 ]\n",
        );
        assert_eq!(parse(&text).unwrap().image_size, Some((640, 480)));
    }

    #[test]
    fn problems_are_named() {
        let m = parse(&STEREO.replace("T: !!", "T_other: !!")).unwrap_err().to_string();
        assert!(m.contains("missing key T"), "{m}");
        let m = parse(&STEREO.replace("0., 0., 0., 0., 0., 0. ]", "0., 0., 0., 0.1, 0., 0. ]")).unwrap_err().to_string();
        assert!(m.contains("D2") && m.contains("coefficient 6"), "{m}");
        let m = parse(&STEREO.replace("%YAML:1.0\n", "")).unwrap_err().to_string();
        assert!(m.contains("%YAML"), "{m}");
        let m = parse(&STEREO.replace("0., 1. ]", "0., x ]")).unwrap_err().to_string();
        assert!(m.contains("'x' is not a number"), "{m}");
        let no_size = parse(&STEREO.replace("image_width: 1280\nimage_height: 1024\n", "")).unwrap();
        assert_eq!(no_size.image_size, None);
        let interface = Interface::new(Vector3::z(), 0.02, vec![], 1.0, 1.333).unwrap();
        let m = no_size.to_rig(["l", "r"], None, interface, Path::new("stereo.yml")).unwrap_err().to_string();
        assert!(m.contains("--size"), "{m}");
    }
}
