//! AquaCal's `calibration.json` (PyPI `aquacal` 2.1, github.com/McGrathLab/AquaCal), the file
//! AquaCal writes for cameras in the air above one bare water surface and AquaMVS reads: read into
//! a flatport rig, and a rig written as one.
//!
//! ## AquaCal's format and conventions (read from its source, not guessed)
//!
//! - Writer and reader: `aquacal/io/serialization.py` (`save_calibration`, `load_calibration`):
//!   `{"version": "1.0", "cameras": {NAME: CAMERA, …}, "interface": {"normal", "n_air",
//!   "n_water"}, "board": {…}, "diagnostics": {…}, "metadata": {…}}`; the loader refuses any
//!   `version` but `"1.0"`. A camera is `{"name", "intrinsics": {"K" (3×3, rows), "dist_coeffs"
//!   (OpenCV order, 4 for fisheye, else 5 or 8), "image_size": [width, height], "is_fisheye"
//!   (written only when true)}, "extrinsics": {"R" (3×3, rows), "t" (3)}, "water_z",
//!   "is_auxiliary" (written only when true)}`.
//! - Frames (`aquacal/config/schema.py`): cameras are OpenCV cameras (x right, y down, z
//!   forward, pixel (0, 0) the centre of the top-left pixel: `Camera.project` is
//!   `cv2.projectPoints`); the world frame has its origin at the reference camera and Z down
//!   into the water; `R`, `t` map world to camera, X_cam = R·X_world + t, centre C = −Rᵀt.
//!   Lengths are metres.
//! - The surface (`aquacal/core/interface_model.py`, `refractive_geometry.py`): `normal` is the
//!   unit normal pointing from the water up into the air (`[0, 0, -1]`, the only value its
//!   calibration writes: `pipeline.py`; a tilt of the surface is carried by the reference camera's
//!   rotation). `water_z` is the world Z of the surface, per camera (the same for every camera
//!   unless `shared_interface=False`, an ablation mode). Camera k back-projects
//!   (`trace_ray_air_to_water`) by intersecting its ray with the plane through
//!   (C_x, C_y, water_z) with that normal, and refracts n_air → n_water there.
//!
//! ## The mapping onto a flatport rig (DESIGN.md §1, §3b)
//!
//! With ν = −normal/|normal| (into the water) camera k's surface is the plane ν·X = o_k,
//! o_k = ν·(C_x, C_y, water_z_k), in the world frame. The master (the first camera in file order, or
//! the one named) defines flatport's frame: X_master = R_m·X_world + t_m, so camera k's
//! extrinsics are R_k R_mᵀ and t_k − R_k R_mᵀ t_m. When every o_k is the master's (AquaCal's
//! shared surface) the rig gets one shared interface: normal n = R_m ν, distance
//! d = o_m − ν·C_m, no layers, `index_air` = n_air, `index_water` = n_water. Otherwise each camera
//! gets its own port in its own frame: normal R_k ν, distance o_k − ν·C_k.
//!
//! Writing, the world frame is the master's frame turned so that its Z is the rig's normal
//! (X axis: the master's x axis projected onto the surface; the identity for an untilted rig):
//! the master gets R = M (world → master, columns of M the world axes), t = 0, camera k
//! R_k·M and t_k, `normal` = [0, 0, −1] and `water_z` = d. A rig with glass layers, or with
//! per-camera ports that are not parallel bare surfaces in the same media, is refused
//! ([`AquaCalExportError`]): AquaCal models one bare water surface.

use std::path::Path;

use nalgebra::{Matrix3, Point3, Unit, Vector3};
use serde::de::{IgnoredAny, MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::rig_json::{MAX_CAMERA_NAME_BYTES, parse_json};
use crate::io::error::{EXCERPT_CHARS, excerpt};
use crate::io::{IoError, read_text};
use crate::model::{Interface, ModelError, PinholeCamera, Ports, Rig, RigCamera};

/// The only `version` AquaCal's `load_calibration` accepts (`SERIALIZATION_VERSION`).
pub const AQUACAL_VERSION: &str = "1.0";

/// Largest difference between two cameras' surface offsets o_k (metres) that still reads as one
/// shared surface. AquaCal writes the same `water_z` float for every camera of a shared surface
/// (o_k then equals it exactly); this only absorbs the rounding of a hand-written file.
pub const SHARED_SURFACE_TOLERANCE_M: f64 = 1e-12;

/// Largest difference between two per-camera ports' unit normals (master frame) that still
/// writes them as one AquaCal surface normal.
pub const PARALLEL_NORMAL_TOLERANCE: f64 = 1e-12;

/// Why a rig cannot be written as an AquaCal `calibration.json`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AquaCalExportError {
    /// AquaCal's surface is bare: air straight into water.
    #[error(
        "AquaCal models cameras in the air above one bare water surface; the port of camera '{camera}' has {layers} layer(s) (glass, acrylic) between air and water, which it cannot represent"
    )]
    Layers {
        /// A camera looking through the layers.
        camera: String,
        /// Layers of that port.
        layers: usize,
    },
    /// Per-camera ports that are not one surface orientation.
    #[error(
        "AquaCal's cameras share one surface normal; the ports of cameras '{first}' and '{other}' are not parallel (their normals differ by {difference:e} in the master frame)"
    )]
    NotParallel {
        /// The master camera.
        first: String,
        /// A camera whose port is tilted against the master's.
        other: String,
        /// |n_other − n_first|.
        difference: f64,
    },
    /// Per-camera ports in different media.
    #[error(
        "AquaCal's cameras share one n_air and one n_water; the ports of cameras '{first}' and '{other}' differ in them ({first_indices:?} against {other_indices:?})"
    )]
    Media {
        /// The master camera.
        first: String,
        /// A camera whose indices differ.
        other: String,
        /// (index_air, index_water) of the master's port.
        first_indices: (f64, f64),
        /// (index_air, index_water) of the other port.
        other_indices: (f64, f64),
    },
}

/// The ChArUco board an AquaCal file records (AquaCal's `BoardConfig`; DESIGN.md §3c's board file
/// uses the same key names). AquaCal's loader needs the `board` object; flatport does not use it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AquaCalBoard {
    /// Squares along the board's x (columns).
    pub squares_x: u32,
    /// Squares along the board's y (rows).
    pub squares_y: u32,
    /// Side of a square, metres.
    pub square_size: f64,
    /// Side of an ArUco marker, metres.
    pub marker_size: f64,
    /// OpenCV dictionary name (`DICT_4X4_50`).
    pub dictionary: String,
    /// OpenCV's pre-4.6 layout (a marker in the top-left square).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub legacy_pattern: bool,
}

impl AquaCalBoard {
    /// AquaCal's board object for a board read by [`crate::io::read_board`] (the shared
    /// `BOARD.json` reader, which checks it); `path` only labels errors. A chessboard is refused:
    /// AquaCal's file records ChArUco boards only. `legacy_pattern` is written `false`: the shared
    /// reader accepts OpenCV's legacy layout only where it is the same board as today's.
    #[cfg(feature = "images")]
    pub fn from_board(
        board: &crate::base::board_spec::BoardSpec,
        path: &Path,
    ) -> Result<AquaCalBoard, IoError> {
        use crate::base::board_spec::BoardSpec;
        let invalid = |field: &str, reason: String| IoError::Invalid {
            path: path.to_path_buf(),
            field: field.into(),
            reason,
        };
        let spec = match board {
            BoardSpec::Charuco(spec) => spec,
            BoardSpec::Chessboard(_) => {
                return Err(invalid(
                    "type",
                    "\"chessboard\": AquaCal's calibration.json records a ChArUco board only"
                        .into(),
                ));
            }
        };
        let squares = |field: &str, n: usize| {
            u32::try_from(n).map_err(|_| invalid(field, format!("{n}: too many squares")))
        };
        Ok(AquaCalBoard {
            squares_x: squares("squares_x", spec.squares_x)?,
            squares_y: squares("squares_y", spec.squares_y)?,
            square_size: spec.square_size_m,
            marker_size: spec.marker_size_m,
            dictionary: spec.dictionary.name().to_string(),
            legacy_pattern: false,
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibrationFile {
    version: String,
    cameras: OrderedCameras,
    interface: InterfaceParamsFile,
    // Calibration records flatport has no use for, accepted and skipped; AquaCal's own loader
    // needs them, flatport's does not (a hand-written file may leave them out).
    #[serde(default, rename = "board")]
    _board: Option<IgnoredAny>,
    #[serde(default, rename = "diagnostics")]
    _diagnostics: Option<IgnoredAny>,
    #[serde(default, rename = "metadata")]
    _metadata: Option<IgnoredAny>,
}

/// AquaCal's `cameras` object in file order (Python dicts keep it; the first camera is the
/// reference camera AquaCal wrote first, and flatport's master).
#[derive(Debug)]
struct OrderedCameras(Vec<(String, CameraFile)>);

impl<'de> Deserialize<'de> for OrderedCameras {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Ordered;
        impl<'de> Visitor<'de> for Ordered {
            type Value = OrderedCameras;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object of cameras by name")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
                let mut cameras = Vec::new();
                while let Some(name) = map.next_key::<String>()? {
                    let camera = map.next_value::<CameraFile>()?;
                    cameras.push((name, camera));
                }
                Ok(OrderedCameras(cameras))
            }
        }
        deserializer.deserialize_map(Ordered)
    }
}

impl Serialize for OrderedCameras {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, camera) in &self.0 {
            map.serialize_entry(name, camera)?;
        }
        map.end()
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    intrinsics: IntrinsicsFile,
    extrinsics: ExtrinsicsFile,
    water_z: f64,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    is_auxiliary: bool,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct IntrinsicsFile {
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    dist_coeffs: Vec<f64>,
    image_size: [u32; 2],
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    is_fisheye: bool,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExtrinsicsFile {
    #[serde(rename = "R")]
    r: [[f64; 3]; 3],
    t: TranslationFile,
}

/// `t` as AquaCal writes it (a vector of 3) or as a 3×1 OpenCV column (`tvec.tolist()`).
#[derive(Debug, Serialize, Deserialize)]
#[serde(untagged)]
enum TranslationFile {
    Vector([f64; 3]),
    Column([[f64; 1]; 3]),
}

impl TranslationFile {
    fn vector(&self) -> Vector3<f64> {
        match self {
            Self::Vector(t) => Vector3::from(*t),
            Self::Column(t) => Vector3::new(t[0][0], t[1][0], t[2][0]),
        }
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct InterfaceParamsFile {
    normal: [f64; 3],
    n_air: f64,
    n_water: f64,
}

/// One camera of the file, in AquaCal's world frame.
struct WorldCamera {
    camera_from_world: (Matrix3<f64>, Vector3<f64>),
    intrinsics: PinholeCamera,
    /// o_k: the camera's surface is ν·X_world = o_k.
    surface_offset: f64,
    centre: Point3<f64>,
}

/// Parses an AquaCal `calibration.json` into a rig (the mapping is in the module docs); `master`
/// names the camera that becomes the rig's master (default: the first in the file). `path` only
/// labels errors, which name the JSON path (`cameras.cam1.intrinsics.K`) and the value.
pub fn rig_from_aquacal_str(text: &str, path: &Path, master: Option<&str>) -> Result<Rig, IoError> {
    let file: CalibrationFile = parse_json(text, path)?;
    let invalid = |field: String, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field,
        reason,
    };
    if file.version != AQUACAL_VERSION {
        return Err(invalid(
            "version".into(),
            format!(
                "'{}': AquaCal's calibration.json has version \"{AQUACAL_VERSION}\" (the only one its loader reads)",
                excerpt(&file.version, EXCERPT_CHARS)
            ),
        ));
    }
    if file.cameras.0.is_empty() {
        return Err(invalid("cameras".into(), "holds no camera".into()));
    }

    // ν: the surface normal into the water (AquaCal's points up into the air).
    let normal_up = Vector3::from(file.interface.normal);
    let length = normal_up.norm();
    if !(length.is_finite() && length > 0.0) {
        return Err(invalid(
            "interface.normal".into(),
            format!(
                "{:?} is no direction (it points from the water into the air, [0, 0, -1] for a level surface)",
                file.interface.normal
            ),
        ));
    }
    let into_water = -normal_up / length;

    let mut world_cameras = Vec::with_capacity(file.cameras.0.len());
    for (name, camera) in &file.cameras.0 {
        world_cameras.push(world_camera(name, camera, &into_water, path)?);
    }
    let names: Vec<&str> = file.cameras.0.iter().map(|(n, _)| n.as_str()).collect();
    let m = match master {
        None => 0,
        Some(wanted) => names.iter().position(|n| *n == wanted).ok_or_else(|| {
            invalid(
                "cameras".into(),
                format!(
                    "has no camera '{}' to be the master (it has {})",
                    excerpt(wanted, EXCERPT_CHARS),
                    names.join(", ")
                ),
            )
        })?,
    };
    // The master first, the others in file order.
    let order: Vec<usize> = std::iter::once(m)
        .chain((0..names.len()).filter(|&k| k != m))
        .collect();

    let (master_rotation, master_translation) = world_cameras[m].camera_from_world;
    let mut cameras = Vec::with_capacity(order.len());
    for &k in &order {
        let (rotation, translation) = world_cameras[k].camera_from_world;
        let (rotation, translation) = if k == m {
            (Matrix3::identity(), Vector3::zeros())
        } else {
            let cam_from_master = rotation * master_rotation.transpose();
            (
                cam_from_master,
                translation - cam_from_master * master_translation,
            )
        };
        let camera =
            RigCamera::new(names[k], world_cameras[k].intrinsics, rotation, translation)
                .map_err(|e| invalid(format!("cameras.{}.extrinsics", names[k]), e.to_string()))?;
        cameras.push(camera);
    }

    let surface = |normal: Vector3<f64>, distance: f64, k: usize| {
        Interface::new(
            normal,
            distance,
            Vec::new(),
            file.interface.n_air,
            file.interface.n_water,
        )
        .map_err(|e| surface_error(&e, names[k], &world_cameras[k], &file.interface, path))
    };
    let master_offset = world_cameras[m].surface_offset;
    let shared = world_cameras
        .iter()
        .all(|c| (c.surface_offset - master_offset).abs() <= SHARED_SURFACE_TOLERANCE_M);
    let ports = if shared {
        let master_camera = &world_cameras[m];
        Ports::Shared(surface(
            master_rotation * into_water,
            master_offset - into_water.dot(&master_camera.centre.coords),
            m,
        )?)
    } else {
        Ports::PerCamera(
            order
                .iter()
                .map(|&k| {
                    let c = &world_cameras[k];
                    surface(
                        c.camera_from_world.0 * into_water,
                        c.surface_offset - into_water.dot(&c.centre.coords),
                        k,
                    )
                })
                .collect::<Result<_, _>>()?,
        )
    };
    Rig::with_ports(cameras, ports).map_err(|e| match &e {
        ModelError::CameraNotInAir {
            camera,
            air_distance,
        } => invalid(
            format!("cameras.{camera}.water_z"),
            format!(
                "camera '{camera}' is not above the water surface: its centre is {air_distance} m from the surface along the normal (must be > 0; water_z is the surface's world Z, and Z points down into the water)"
            ),
        ),
        _ => invalid("cameras".into(), e.to_string()),
    })
}

/// A surface error of camera `name`, named by the field that causes it.
fn surface_error(
    error: &ModelError,
    name: &str,
    camera: &WorldCamera,
    interface: &InterfaceParamsFile,
    path: &Path,
) -> IoError {
    let (field, reason) = match error {
        ModelError::NormalAwayFromWater { .. } => (
            "interface.normal".to_string(),
            format!(
                "{:?}: camera '{name}' looks away from the water through it (flatport's cameras look into the water: the normal has a positive component along the camera's z axis)",
                interface.normal
            ),
        ),
        ModelError::NonPositiveAirDistance { value } => (
            format!("cameras.{name}.water_z"),
            format!(
                "camera '{name}' (centre {:?}) is not above the water surface: {value} m from it along the normal (must be > 0; water_z is the surface's world Z, and Z points down into the water)",
                [camera.centre.x, camera.centre.y, camera.centre.z]
            ),
        ),
        ModelError::IndexBelowOne { medium, .. } => (
            format!(
                "interface.{}",
                if medium == "index_air" {
                    "n_air"
                } else {
                    "n_water"
                }
            ),
            error.to_string(),
        ),
        _ => ("interface".to_string(), error.to_string()),
    };
    IoError::Invalid {
        path: path.to_path_buf(),
        field,
        reason,
    }
}

/// Validates one camera of the file.
fn world_camera(
    name: &str,
    camera: &CameraFile,
    into_water: &Vector3<f64>,
    path: &Path,
) -> Result<WorldCamera, IoError> {
    let field = |rest: &str| format!("cameras.{}.{rest}", excerpt(name, EXCERPT_CHARS));
    let invalid = |rest: &str, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: field(rest),
        reason,
    };
    if name.len() > MAX_CAMERA_NAME_BYTES {
        return Err(invalid(
            "",
            format!("the name is longer than a camera name may be ({MAX_CAMERA_NAME_BYTES} bytes)"),
        ));
    }
    if let Some(inner) = &camera.name
        && inner != name
    {
        return Err(invalid(
            "name",
            format!(
                "'{}' differs from the camera's key '{}'",
                excerpt(inner, EXCERPT_CHARS),
                excerpt(name, EXCERPT_CHARS)
            ),
        ));
    }
    let i = &camera.intrinsics;
    if i.is_fisheye {
        return Err(invalid(
            "intrinsics.is_fisheye",
            "true: flatport's cameras are pinhole cameras with OpenCV's 5-term distortion, not fisheye".into(),
        ));
    }
    let k = &i.k;
    for (row, col, want) in [
        (0, 1, 0.0),
        (1, 0, 0.0),
        (2, 0, 0.0),
        (2, 1, 0.0),
        (2, 2, 1.0),
    ] {
        if k[row][col] != want {
            return Err(invalid(
                &format!("intrinsics.K[{row}][{col}]"),
                format!(
                    "{}: flatport's intrinsics are fx, fy, cx, cy (K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], no skew), so this must be {want}",
                    k[row][col]
                ),
            ));
        }
    }
    let coefficients = &i.dist_coeffs;
    if let Some((extra, value)) = coefficients
        .iter()
        .enumerate()
        .skip(5)
        .find(|(_, v)| **v != 0.0)
    {
        return Err(invalid(
            &format!("intrinsics.dist_coeffs[{extra}]"),
            format!(
                "{value}: flatport supports OpenCV's 5-term model [k1, k2, p1, p2, k3]; the rational and thin-prism terms beyond it must be 0"
            ),
        ));
    }
    let mut distortion = [0.0; 5];
    for (d, v) in distortion.iter_mut().zip(coefficients) {
        *d = *v;
    }
    let intrinsics = PinholeCamera::new(
        name,
        i.image_size[0],
        i.image_size[1],
        k[0][0],
        k[1][1],
        k[0][2],
        k[1][2],
        distortion,
    )
    .map_err(|e| invalid("intrinsics", e.to_string()))?;
    let r = &camera.extrinsics.r;
    let rotation = Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    );
    let translation = camera.extrinsics.t.vector();
    // RigCamera checks the rotation (orthonormal, det +1) and finiteness.
    let checked = RigCamera::new(name, intrinsics, rotation, translation)
        .map_err(|e| invalid("extrinsics", e.to_string()))?;
    if !camera.water_z.is_finite() {
        return Err(invalid(
            "water_z",
            format!("{}: not finite", camera.water_z),
        ));
    }
    // The rotation as flatport holds it (projected onto the nearest rotation).
    let rotation = checked
        .cam_from_master
        .rotation
        .to_rotation_matrix()
        .into_inner();
    let centre = checked.centre_in_master();
    // AquaCal's plane point for this camera: (C_x, C_y, water_z).
    let surface_offset = into_water.dot(&Vector3::new(centre.x, centre.y, camera.water_z));
    Ok(WorldCamera {
        camera_from_world: (rotation, translation),
        intrinsics,
        surface_offset,
        centre,
    })
}

/// Reads an AquaCal `calibration.json` (`-` = standard input) into a rig; see
/// [`rig_from_aquacal_str`].
pub fn read_aquacal(path: &Path, master: Option<&str>) -> Result<Rig, IoError> {
    rig_from_aquacal_str(&read_text(path)?, path, master)
}

/// The world frame written for a rig whose surface normal (master frame) is `normal`: the columns
/// of M are the world axes in the master frame, Z = n, X the master's x axis projected onto the
/// surface (|x − (x·n)n| = √(1 − n_x²) > 0 since n_z > 0), Y = Z × X. X_master = M·X_world.
fn master_from_world(normal: &Unit<Vector3<f64>>) -> Matrix3<f64> {
    let z = normal.into_inner();
    let x = (Vector3::x() - z * z.x).normalize();
    let y = z.cross(&x);
    Matrix3::from_columns(&[x, y, z])
}

#[derive(Debug, Serialize)]
struct CalibrationOut<'a> {
    version: &'static str,
    cameras: OrderedCameras,
    interface: InterfaceParamsFile,
    board: BoardOut<'a>,
    diagnostics: DiagnosticsOut,
    metadata: MetadataOut,
}

/// AquaCal's `board` object: the board given, or every value `null` (none known).
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum BoardOut<'a> {
    Known(&'a AquaCalBoard),
    Unknown {
        squares_x: Option<u32>,
        squares_y: Option<u32>,
        square_size: Option<f64>,
        marker_size: Option<f64>,
        dictionary: Option<String>,
    },
}

/// AquaCal's `diagnostics` keys, which its loader requires: flatport's export has no calibration
/// residuals to put there, so they are `null` (none per camera).
#[derive(Debug, Serialize)]
struct DiagnosticsOut {
    reprojection_error_rms: Option<f64>,
    reprojection_error_per_camera: std::collections::BTreeMap<String, f64>,
    validation_3d_error_mean: Option<f64>,
    validation_3d_error_std: Option<f64>,
}

/// AquaCal's `metadata` keys, which its loader requires; the values flatport does not know are
/// `null`.
#[derive(Debug, Serialize)]
struct MetadataOut {
    calibration_date: Option<String>,
    software_version: String,
    config_hash: Option<String>,
    num_frames_used: Option<u64>,
    num_frames_holdout: Option<u64>,
    seed: Option<u64>,
}

/// The rig as AquaCal's `calibration.json` (pretty JSON, full f64 precision, cameras in rig
/// order): the mapping is in the module docs. `board` fills AquaCal's `board` object (its values
/// are `null` without one); `diagnostics` and `metadata` hold `null`s and flatport's version.
/// Errors: layers, or per-camera ports that are not parallel bare surfaces in the same media.
pub fn aquacal_json(rig: &Rig, board: Option<&AquaCalBoard>) -> Result<String, AquaCalExportError> {
    let cameras = rig.cameras();
    let ports: Vec<Interface> = (0..cameras.len()).map(|k| rig.port_in_master(k)).collect();
    for (camera, port) in cameras.iter().zip(&ports) {
        if !port.layers().is_empty() {
            return Err(AquaCalExportError::Layers {
                camera: camera.name.clone(),
                layers: port.layers().len(),
            });
        }
    }
    let first = &ports[0];
    if let Ports::PerCamera(_) = rig.ports() {
        for (camera, port) in cameras.iter().zip(&ports).skip(1) {
            let difference = (port.normal().into_inner() - first.normal().into_inner()).norm();
            if difference > PARALLEL_NORMAL_TOLERANCE {
                return Err(AquaCalExportError::NotParallel {
                    first: cameras[0].name.clone(),
                    other: camera.name.clone(),
                    difference,
                });
            }
            let indices = |p: &Interface| (p.index_air(), p.index_water());
            if indices(port) != indices(first) {
                return Err(AquaCalExportError::Media {
                    first: cameras[0].name.clone(),
                    other: camera.name.clone(),
                    first_indices: indices(first),
                    other_indices: indices(port),
                });
            }
        }
    }
    let m = master_from_world(first.normal());
    let rows = |r: &Matrix3<f64>| {
        [
            [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
            [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
            [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
        ]
    };
    let out_cameras = cameras
        .iter()
        .zip(&ports)
        .map(|(camera, port)| {
            let i = &camera.intrinsics;
            let cam_from_master = camera
                .cam_from_master
                .rotation
                .to_rotation_matrix()
                .into_inner();
            let t = camera.cam_from_master.translation.vector;
            (
                camera.name.clone(),
                CameraFile {
                    name: Some(camera.name.clone()),
                    intrinsics: IntrinsicsFile {
                        k: [[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]],
                        dist_coeffs: i.distortion.to_vec(),
                        image_size: [i.width, i.height],
                        is_fisheye: false,
                    },
                    extrinsics: ExtrinsicsFile {
                        r: rows(&(cam_from_master * m)),
                        t: TranslationFile::Vector([t.x, t.y, t.z]),
                    },
                    // The plane n·X_master = d is Z_world = d.
                    water_z: port.air_distance(),
                    is_auxiliary: false,
                },
            )
        })
        .collect();
    let out = CalibrationOut {
        version: AQUACAL_VERSION,
        cameras: OrderedCameras(out_cameras),
        interface: InterfaceParamsFile {
            normal: [0.0, 0.0, -1.0],
            n_air: first.index_air(),
            n_water: first.index_water(),
        },
        board: match board {
            Some(board) => BoardOut::Known(board),
            None => BoardOut::Unknown {
                squares_x: None,
                squares_y: None,
                square_size: None,
                marker_size: None,
                dictionary: None,
            },
        },
        diagnostics: DiagnosticsOut {
            reprojection_error_rms: None,
            reprojection_error_per_camera: Default::default(),
            validation_3d_error_mean: None,
            validation_3d_error_std: None,
        },
        metadata: MetadataOut {
            calibration_date: None,
            software_version: format!("flatport {}", env!("CARGO_PKG_VERSION")),
            config_hash: None,
            num_frames_used: None,
            num_frames_holdout: None,
            seed: None,
        },
    };
    let mut text = serde_json::to_string_pretty(&out).expect("plain data always serialises");
    text.push('\n');
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rig_from_json_str;
    use nalgebra::{Point2, Rotation3};

    fn path() -> &'static Path {
        Path::new("calibration.json")
    }

    fn rig_json(text: &str) -> Rig {
        rig_from_json_str(text, Path::new("rig.json")).unwrap()
    }

    /// Three cameras behind one tilted surface, with distortion and rotated extrinsics.
    const TILTED: &str = r#"{"cameras": [
        {"name": "a", "width": 1280, "height": 1024, "fx": 864.91, "fy": 865.5, "cx": 640.25, "cy": 511.75,
         "distortion": [-0.1, 0.01, 0.0005, -0.0025, 0.001]},
        {"name": "b", "width": 1920, "height": 1080, "fx": 1400, "fy": 1401, "cx": 960, "cy": 540,
         "rotation": [[0.9998468789078377, -0.017499106784510807, 0.0], [0.017499106784510807, 0.9998468789078377, 0.0], [0.0, 0.0, 1.0]],
         "translation": [-0.06, 0.001, 0.002]},
        {"name": "c", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240,
         "rotation": [[0.9950041652780258, 0.0, 0.09983341664682815], [0.0, 1.0, 0.0], [-0.09983341664682815, 0.0, 0.9950041652780258]],
         "translation": [0.03, -0.08, 0.01]}],
      "interface": {"normal": [0.12, -0.07, 1.0], "distance": 0.043, "index_air": 1.0003, "index_water": 1.341}}"#;

    /// Points in the water in front of the rig, master frame.
    fn points() -> Vec<Point3<f64>> {
        let mut points = Vec::new();
        for x in [-0.3, -0.05, 0.0, 0.2] {
            for y in [-0.2, 0.0, 0.15] {
                for z in [0.3, 0.8, 2.0] {
                    points.push(Point3::new(x, y, z));
                }
            }
        }
        points
    }

    /// Same cameras, intrinsics, extrinsics and ports to 1e-12, and the same pixels and rays.
    fn assert_same_rig(a: &Rig, b: &Rig) {
        assert_eq!(a.cameras().len(), b.cameras().len());
        for (k, (ca, cb)) in a.cameras().iter().zip(b.cameras()).enumerate() {
            assert_eq!(ca.name, cb.name);
            assert_eq!(ca.intrinsics, cb.intrinsics, "camera {k}");
            let ra = ca
                .cam_from_master
                .rotation
                .to_rotation_matrix()
                .into_inner();
            let rb = cb
                .cam_from_master
                .rotation
                .to_rotation_matrix()
                .into_inner();
            assert!((ra - rb).amax() < 1e-12, "camera {k}: {ra} against {rb}");
            let dt = ca.cam_from_master.translation.vector - cb.cam_from_master.translation.vector;
            assert!(dt.amax() < 1e-12, "camera {k}: translation off by {dt}");
            let (pa, pb) = (a.port_in_master(k), b.port_in_master(k));
            assert!((pa.normal().into_inner() - pb.normal().into_inner()).amax() < 1e-12);
            assert!((pa.air_distance() - pb.air_distance()).abs() < 1e-12);
            assert_eq!(
                (pa.index_air(), pa.index_water()),
                (pb.index_air(), pb.index_water())
            );
            let (va, vb) = (a.refractive_camera(k), b.refractive_camera(k));
            let mut projected = 0;
            for point in points() {
                match (va.project(&point), vb.project(&point)) {
                    (Ok(pa), Ok(pb)) => {
                        // Pixels of about 1e3 whose rays agree to 1e-12: 1e-9 px.
                        assert!(
                            (pa - pb).norm() < 1e-9,
                            "camera {k} {point}: {pa} against {pb}"
                        );
                        let (ra, rb) = (va.backproject(&pa).unwrap(), vb.backproject(&pa).unwrap());
                        assert!((ra.origin - rb.origin).norm() < 1e-12);
                        assert!((ra.dir.into_inner() - rb.dir.into_inner()).norm() < 1e-12);
                        projected += 1;
                    }
                    (Err(ea), Err(eb)) => assert_eq!(ea, eb),
                    (ra, rb) => panic!("camera {k} {point}: {ra:?} against {rb:?}"),
                }
            }
            assert!(
                projected > 20,
                "camera {k}: only {projected} points projected"
            );
        }
    }

    fn round_trip(rig: &Rig) -> Rig {
        let text = aquacal_json(rig, None).unwrap();
        rig_from_aquacal_str(&text, path(), None).unwrap()
    }

    #[test]
    fn round_trip_of_a_tilted_three_camera_rig() {
        let rig = rig_json(TILTED);
        let back = round_trip(&rig);
        assert!(back.shared_interface().is_some());
        assert_same_rig(&rig, &back);
    }

    #[test]
    fn an_untilted_rig_is_written_in_its_master_frame() {
        let text = TILTED.replace("[0.12, -0.07, 1.0]", "[0, 0, 1]");
        let rig = rig_json(&text);
        let written: serde_json::Value =
            serde_json::from_str(&aquacal_json(&rig, None).unwrap()).unwrap();
        // AquaCal's world is the master's frame: the master's R = I, t = 0, water_z = distance.
        let a = &written["cameras"]["a"];
        assert_eq!(
            a["extrinsics"]["R"],
            serde_json::json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        );
        assert_eq!(a["extrinsics"]["t"], serde_json::json!([0.0, 0.0, 0.0]));
        assert_eq!(a["water_z"], 0.043);
        assert_eq!(written["cameras"]["c"]["water_z"], 0.043);
        assert_eq!(
            written["interface"]["normal"],
            serde_json::json!([0.0, 0.0, -1.0])
        );
        assert_eq!(written["version"], "1.0");
        assert_same_rig(&rig, &round_trip(&rig));
    }

    #[test]
    fn parallel_ports_round_trip_as_per_camera_water_z() {
        // The same surface orientation (n = R_k n_master) at another height for camera b.
        let rig = rig_json(TILTED);
        let shared = rig.shared_interface().unwrap();
        let ports: Vec<Interface> = (0..3)
            .map(|k| {
                let camera = &rig.cameras()[k];
                let extra = if k == 1 { 0.011 } else { 0.0 };
                Interface::new(
                    shared.normal().into_inner(),
                    shared.air_distance() + extra,
                    Vec::new(),
                    shared.index_air(),
                    shared.index_water(),
                )
                .unwrap()
                .transformed(&camera.cam_from_master)
            })
            .collect();
        let rig = rig.with_new_ports(Ports::PerCamera(ports)).unwrap();
        let back = round_trip(&rig);
        assert!(matches!(back.ports(), Ports::PerCamera(_)));
        assert_same_rig(&rig, &back);
    }

    #[test]
    fn rigs_aquacal_cannot_hold_are_refused_saying_why() {
        let glass = TILTED.replace(
            r#""distance": 0.043,"#,
            r#""distance": 0.043, "layers": [{"thickness": 0.01, "index": 1.49}],"#,
        );
        let message = aquacal_json(&rig_json(&glass), None)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("1 layer(s)") && message.contains("bare"),
            "{message}"
        );

        let rig = rig_json(TILTED);
        let tilted = Rotation3::from_euler_angles(0.02, 0.0, 0.0);
        let ports: Vec<Interface> = (0..3)
            .map(|k| {
                let normal = if k == 2 {
                    tilted * rig.shared_interface().unwrap().normal().into_inner()
                } else {
                    rig.shared_interface().unwrap().normal().into_inner()
                };
                Interface::new(normal, 0.05, Vec::new(), 1.0, 1.333)
                    .unwrap()
                    .transformed(&rig.cameras()[k].cam_from_master)
            })
            .collect();
        let rig = rig.with_new_ports(Ports::PerCamera(ports)).unwrap();
        let message = aquacal_json(&rig, None).unwrap_err().to_string();
        assert!(
            message.contains("'a' and 'c' are not parallel"),
            "{message}"
        );
    }

    /// A file in AquaCal's own format, as `save_calibration` (aquacal 2.1,
    /// aquacal/io/serialization.py) writes it: the reference camera `cam0` at the world origin
    /// looking straight down (R = I), `cam1` 0.1 m along world X, the surface 0.25 m below them.
    const AQUACAL_LEVEL: &str = r#"{
  "version": "1.0",
  "cameras": {
    "cam0": {
      "name": "cam0",
      "intrinsics": {"K": [[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]],
                     "dist_coeffs": [0.0, 0.0, 0.0, 0.0, 0.0], "image_size": [1280, 960]},
      "extrinsics": {"R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t": [0.0, 0.0, 0.0]},
      "water_z": 0.25
    },
    "cam1": {
      "name": "cam1",
      "intrinsics": {"K": [[900.0, 0.0, 650.0], [0.0, 910.0, 470.0], [0.0, 0.0, 1.0]],
                     "dist_coeffs": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "image_size": [1280, 960]},
      "extrinsics": {"R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t": [[-0.1], [0.0], [0.0]]},
      "water_z": 0.25
    }
  },
  "interface": {"normal": [0.0, 0.0, -1.0], "n_air": 1.0, "n_water": 1.333},
  "board": {"squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4X4_50"},
  "diagnostics": {"reprojection_error_rms": 0.31, "reprojection_error_per_camera": {"cam0": 0.3, "cam1": 0.32},
                  "validation_3d_error_mean": 0.0012, "validation_3d_error_std": 0.0004},
  "metadata": {"calibration_date": "2026-01-01T00:00:00", "software_version": "2.1.0", "config_hash": "abc",
               "num_frames_used": 40, "num_frames_holdout": 10, "seed": 42}
}"#;

    /// The point in the water seen under air angle `a` in azimuth `phi` (world frame, Z down)
    /// from a camera `height` above the surface, `depth` below it, relative to the camera centre:
    /// r = h tan a + x tan θ_w with sin θ_w = (n_air/n_water) sin a (Snell).
    fn point_under(a: f64, phi: f64, height: f64, depth: f64, ratio: f64) -> Vector3<f64> {
        let theta_water = (ratio * a.sin()).asin();
        let r = height * a.tan() + depth * theta_water.tan();
        Vector3::new(r * phi.cos(), r * phi.sin(), height + depth)
    }

    #[test]
    fn an_aquacal_file_projects_and_backprojects_as_snells_law_says() {
        let rig = rig_from_aquacal_str(AQUACAL_LEVEL, path(), None).unwrap();
        assert_eq!(rig.cameras()[0].name, "cam0");
        let interface = rig.shared_interface().unwrap();
        assert_eq!(interface.normal().into_inner(), Vector3::z());
        assert_eq!(interface.air_distance(), 0.25);
        assert!(interface.layers().is_empty());
        assert_eq!(
            (interface.index_air(), interface.index_water()),
            (1.0, 1.333)
        );
        let ratio = 1.0 / 1.333;
        for (k, centre, (fx, fy, cx, cy)) in [
            (0, Vector3::zeros(), (1000.0, 1000.0, 640.0, 480.0)),
            (1, Vector3::new(0.1, 0.0, 0.0), (900.0, 910.0, 650.0, 470.0)),
        ] {
            let camera = rig.refractive_camera(k);
            for (a, phi, depth) in [(0.0, 0.0, 0.5), (0.3, 0.4, 0.7), (0.45, -2.0, 1.5)] {
                let point = Point3::from(centre + point_under(a, phi, 0.25, depth, ratio));
                let pixel = camera.project(&point).unwrap();
                // The air ray (sin a cos φ, sin a sin φ, cos a) in an unrotated camera.
                let expected =
                    Point2::new(cx + fx * a.tan() * phi.cos(), cy + fy * a.tan() * phi.sin());
                assert!(
                    (pixel - expected).norm() < 1e-9,
                    "camera {k}: {pixel} against {expected}"
                );
                let ray = camera.backproject(&expected).unwrap();
                // Origin on the surface Z = 0.25 above the point, direction at θ_w.
                let theta = (ratio * a.sin()).asin();
                let dir = Vector3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                assert!((ray.origin.z - 0.25).abs() < 1e-12);
                assert!(
                    (ray.dir.into_inner() - dir).norm() < 1e-12,
                    "{} against {dir}",
                    ray.dir.into_inner()
                );
                let along = (point - ray.origin).normalize();
                assert!((along - dir).norm() < 1e-9);
            }
        }
    }

    #[test]
    fn a_tilted_reference_camera_tilts_the_rigs_normal() {
        // AquaCal carries a tilted surface as the reference camera's rotation (world → cam0).
        let tilt = Rotation3::from_euler_angles(0.15, -0.08, 0.3);
        let r = tilt.matrix();
        let rows = |r: &Matrix3<f64>| {
            format!(
                "[[{}, {}, {}], [{}, {}, {}], [{}, {}, {}]]",
                r[(0, 0)],
                r[(0, 1)],
                r[(0, 2)],
                r[(1, 0)],
                r[(1, 1)],
                r[(1, 2)],
                r[(2, 0)],
                r[(2, 1)],
                r[(2, 2)]
            )
        };
        let text = AQUACAL_LEVEL.replacen(
            r#""R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t": [0.0, 0.0, 0.0]"#,
            &format!(r#""R": {}, "t": [0.0, 0.0, 0.0]"#, rows(r)),
            1,
        );
        assert_ne!(text, AQUACAL_LEVEL);
        let rig = rig_from_aquacal_str(&text, path(), None).unwrap();
        // n = R_0 · (0, 0, 1): the world's Z seen from the master.
        let n = rig.shared_interface().unwrap().normal().into_inner();
        assert!((n - r.column(2)).norm() < 1e-15);
        // A point under air angle a in the world: its pixel is the air ray R_0 d_world.
        let ratio = 1.0 / 1.333;
        for (a, phi, depth) in [(0.0, 0.0, 0.4), (0.35, 1.0, 0.9)] {
            let in_world = point_under(a, phi, 0.25, depth, ratio);
            let in_master = Point3::from(r * in_world);
            let pixel = rig.refractive_camera(0).project(&in_master).unwrap();
            let d = r * Vector3::new(a.sin() * phi.cos(), a.sin() * phi.sin(), a.cos());
            let expected = Point2::new(640.0 + 1000.0 * d.x / d.z, 480.0 + 1000.0 * d.y / d.z);
            assert!(
                (pixel - expected).norm() < 1e-9,
                "{pixel} against {expected}"
            );
            // cam1 (untilted, 0.1 m along world X) sees it as in the level file.
            // (The level file's master frame is the world.)
            let level = rig_from_aquacal_str(AQUACAL_LEVEL, path(), None).unwrap();
            let p1 = rig.refractive_camera(1).project(&in_master).unwrap();
            let q1 = level
                .refractive_camera(1)
                .project(&Point3::from(in_world))
                .unwrap();
            assert!((p1 - q1).norm() < 1e-9, "{p1} against {q1}");
        }
    }

    #[test]
    fn per_camera_water_z_gives_a_port_per_camera_and_master_can_be_chosen() {
        let text = AQUACAL_LEVEL.replacen(r#""water_z": 0.25"#, r#""water_z": 0.27"#, 2);
        // Only cam1's (the second occurrence) should differ: put cam0's back.
        let text = text.replacen(r#""water_z": 0.27"#, r#""water_z": 0.25"#, 1);
        let rig = rig_from_aquacal_str(&text, path(), None).unwrap();
        let Ports::PerCamera(ports) = rig.ports() else {
            panic!("expected a port per camera")
        };
        assert_eq!(ports[0].air_distance(), 0.25);
        assert!((ports[1].air_distance() - 0.27).abs() < 1e-15);

        let swapped = rig_from_aquacal_str(AQUACAL_LEVEL, path(), Some("cam1")).unwrap();
        assert_eq!(swapped.cameras()[0].name, "cam1");
        // cam0 sits 0.1 m along −X of the new master.
        let c0 = swapped.cameras()[1].centre_in_master();
        assert!((c0 - Point3::new(-0.1, 0.0, 0.0)).norm() < 1e-15);
        let message = rig_from_aquacal_str(AQUACAL_LEVEL, path(), Some("cam9"))
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("no camera 'cam9'") && message.contains("cam0, cam1"),
            "{message}"
        );
    }

    fn error_of(from: &str, to: &str) -> String {
        assert!(
            AQUACAL_LEVEL.contains(from),
            "test edit {from:?} does not apply"
        );
        let text = AQUACAL_LEVEL.replacen(from, to, 1);
        rig_from_aquacal_str(&text, path(), None)
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn files_flatport_cannot_use_are_refused_naming_path_and_value() {
        for (from, to, wanted) in [
            (
                r#""version": "1.0""#,
                r#""version": "2.0""#,
                vec!["version", "'2.0'"],
            ),
            (
                r#""image_size": [1280, 960]}"#,
                r#""image_size": [1280, 960], "is_fisheye": true}"#,
                vec!["cameras.cam0.intrinsics.is_fisheye"],
            ),
            (
                "[[1000.0, 0.0, 640.0]",
                "[[1000.0, 0.5, 640.0]",
                vec!["cameras.cam0.intrinsics.K[0][1]", "0.5"],
            ),
            (
                "[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
                "[0.0, 0.0, 0.0, 0.0, 0.0, 0.02, 0.0, 0.0]",
                vec!["cameras.cam1.intrinsics.dist_coeffs[5]", "0.02"],
            ),
            (
                r#""water_z": 0.25"#,
                r#""water_z": -0.1"#,
                vec!["cameras.cam0.water_z", "not above the water"],
            ),
            (
                r#""normal": [0.0, 0.0, -1.0]"#,
                r#""normal": [0.0, 0.0, 1.0]"#,
                vec!["interface.normal", "looks away from the water"],
            ),
            (
                r#""normal": [0.0, 0.0, -1.0]"#,
                r#""normal": [0.0, 0.0, 0.0]"#,
                vec!["interface.normal", "no direction"],
            ),
            (
                r#""n_water": 1.333"#,
                r#""n_water": 0.9"#,
                vec!["interface.n_water"],
            ),
            (
                r#""name": "cam0""#,
                r#""name": "left""#,
                vec!["cameras.cam0.name", "'left'"],
            ),
            (
                r#""water_z": 0.25"#,
                r#""water_zz": 0.25"#,
                vec!["cameras.cam0", "water_zz"],
            ),
            (
                "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], \"t\": [0.0",
                "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]], \"t\": [0.0",
                vec!["cameras.cam0.extrinsics", "rotation"],
            ),
        ] {
            let message = error_of(from, to);
            for w in wanted {
                assert!(
                    message.contains(w) && message.contains("calibration.json"),
                    "{w:?} not in {message}"
                );
            }
        }
    }

    #[cfg(feature = "images")]
    #[test]
    fn board_files_fill_the_board_object() {
        let file = Path::new("board.json");
        let read = |text: &str| {
            crate::io::board_from_json_str(text, file)
                .and_then(|board| AquaCalBoard::from_board(&board, file))
        };
        let board = read(
            r#"{"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4X4_50", "legacy_pattern": false}"#,
        )
        .unwrap();
        let rig = rig_from_aquacal_str(AQUACAL_LEVEL, path(), None).unwrap();
        let written: serde_json::Value =
            serde_json::from_str(&aquacal_json(&rig, Some(&board)).unwrap()).unwrap();
        assert_eq!(
            written["board"],
            serde_json::json!({"squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4X4_50"})
        );
        let without: serde_json::Value =
            serde_json::from_str(&aquacal_json(&rig, None).unwrap()).unwrap();
        assert_eq!(without["board"]["squares_x"], serde_json::Value::Null);
        let message =
            read(r#"{"type": "chessboard", "squares_x": 10, "squares_y": 7, "square_size": 0.03}"#)
                .unwrap_err()
                .to_string();
        assert!(
            message.contains("board.json") && message.contains("ChArUco"),
            "{message}"
        );
    }
}
