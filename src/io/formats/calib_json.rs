//! Calibration files: observations (the corners of stereo views of a board), the truth of a
//! simulated scene, and the calibration report. JSON; unknown keys are rejected by name.

use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Point2, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::rig_json::{MAX_CAMERA_NAME_BYTES, interface_to_file};
use crate::calib::{Board, CameraKey, Estimated, Image, Observations, Report, Target, View};
use crate::io::error::{EXCERPT_CHARS, excerpt};
use crate::io::{IoError, read_text, write_atomic};
use crate::model::{Interface, Rig};

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardFile {
    rows: usize,
    cols: usize,
    square: f64,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ViewFile {
    left: Vec<Option<[f64; 2]>>,
    right: Vec<Option<[f64; 2]>>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObservationsFile {
    board: BoardFile,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::rig_json::present"
    )]
    cameras: Option<[String; 2]>,
    views: Vec<ViewFile>,
}

/// Observations of two cameras in the stereo form, `{"board", "cameras"?: [A, B], "views":
/// [{"left": [...], "right": [...]}]}`, one view per line, every value at full f64 precision: the
/// first image of each view is `left`, the second `right`; `"cameras"` names them when
/// `name_cameras`, or when they are not the rig cameras `left` and `right` (for which the stereo
/// form is the general form itself). `None` unless the target is a board and every view holds
/// exactly two images of the same two cameras.
pub fn stereo_observations_to_json_string(
    observations: &Observations,
    name_cameras: bool,
) -> Option<String> {
    let Target::Board(board) = &observations.target else {
        return None;
    };
    let first = observations.views.first()?;
    let [left, right] = first.images.as_slice() else {
        return None;
    };
    let names = [left.key.as_str(), right.key.as_str()];
    let same = |v: &View| {
        v.images.len() == 2 && v.images[0].key == names[0] && v.images[1].key == names[1]
    };
    if !observations.views.iter().all(same) {
        return None;
    }
    let views: Vec<[&[Option<Point2<f64>>]; 2]> = observations
        .views
        .iter()
        .map(|v| {
            [
                v.images[0].corners.as_slice(),
                v.images[1].corners.as_slice(),
            ]
        })
        .collect();
    Some(stereo_form_text(board, names, &views, name_cameras))
}

/// The stereo form's text of `views` of `board` by the cameras `names` (left, right); see
/// [`stereo_observations_to_json_string`].
pub fn stereo_form_text(
    board: &Board,
    names: [&str; 2],
    views: &[[&[Option<Point2<f64>>]; 2]],
    name_cameras: bool,
) -> String {
    let corners = |c: &[Option<Point2<f64>>]| c.iter().map(|p| p.map(|p| [p.x, p.y])).collect();
    let file = ObservationsFile {
        board: BoardFile {
            rows: board.rows,
            cols: board.cols,
            square: board.square,
        },
        cameras: (name_cameras || names != ["left", "right"]).then(|| names.map(str::to_string)),
        views: views
            .iter()
            .map(|[left, right]| ViewFile {
                left: corners(left),
                right: corners(right),
            })
            .collect(),
    };
    let mut text = serde_json::to_string(&file).expect("plain data always serialises");
    // One view per line keeps the file readable and diffable.
    text = text.replace("{\"left\":", "\n  {\"left\":");
    text.push('\n');
    text
}

/// Writes observations atomically in the stereo form with `"cameras"`
/// ([`stereo_observations_to_json_string`]); observations that are not two cameras' views of a
/// board are written in the general form.
pub fn write_stereo_observations(path: &Path, observations: &Observations) -> Result<(), IoError> {
    let text = stereo_observations_to_json_string(observations, true)
        .unwrap_or_else(|| observations_to_json_string(observations));
    write_atomic(path, text.as_bytes())
}

/// Writes observations atomically in the general form ([`observations_to_json_string`]).
pub fn write_observations(path: &Path, observations: &Observations) -> Result<(), IoError> {
    write_atomic(path, observations_to_json_string(observations).as_bytes())
}

/// A view of the general form: camera name → corners, in file order; a key given twice is an
/// error (a map type would keep only the last silently).
#[derive(Debug, Default)]
struct GeneralView(Vec<(String, Vec<Option<[f64; 2]>>)>);

impl<'de> Deserialize<'de> for GeneralView {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = GeneralView;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "an object whose keys are camera names, each holding a list of [u, v] or null",
                )
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<GeneralView, A::Error> {
                let mut images: Vec<(String, Vec<Option<[f64; 2]>>)> = Vec::new();
                while let Some(key) = map.next_key::<String>()? {
                    if images.iter().any(|(k, _)| *k == key) {
                        return Err(serde::de::Error::custom(format!(
                            "camera '{}' appears twice in this view",
                            excerpt(&key, EXCERPT_CHARS)
                        )));
                    }
                    let corners = map.next_value()?;
                    images.push((key, corners));
                }
                Ok(GeneralView(images))
            }
        }
        deserializer.deserialize_map(Visitor)
    }
}

impl Serialize for GeneralView {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (key, corners) in &self.0 {
            map.serialize_entry(key, corners)?;
        }
        map.end()
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TargetFile {
    points: Vec<[f64; 3]>,
}

/// The observations file in its general form (DESIGN.md §3b), the stereo form included.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GeneralFile {
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::rig_json::present"
    )]
    board: Option<BoardFile>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::rig_json::present"
    )]
    target: Option<TargetFile>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::rig_json::present"
    )]
    cameras: Option<[String; 2]>,
    views: Vec<GeneralView>,
}

/// Parses observations in the general form (views keyed by rig camera names, a board or a 3-D
/// target) or the stereo form (every view holding `left` and `right`, optional `"cameras": [A,
/// B]` naming their rig cameras, else rig cameras 0 and 1); `path` only labels errors. Camera
/// names and corners are checked against the rig later
/// ([`Observations::resolve`](crate::calib::Observations::resolve)).
pub fn observations_from_json_str(text: &str, path: &Path) -> Result<Observations, IoError> {
    let file: GeneralFile = super::rig_json::parse_json(text, path)?;
    let invalid = |field: &str, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: field.into(),
        reason,
    };
    let target = match (&file.board, &file.target) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                "target",
                "give either a board or a target, not both".into(),
            ));
        }
        (None, None) => {
            return Err(invalid(
                "board",
                "missing: give the board (rows, cols, square) or a target (points)".into(),
            ));
        }
        (Some(b), None) => {
            if b.rows < 2 || b.cols < 2 || !(b.square > 0.0 && b.square.is_finite()) {
                return Err(invalid(
                    "board",
                    format!(
                        "needs rows ≥ 2, cols ≥ 2 and a square > 0 m, got rows {}, cols {}, square {}",
                        b.rows, b.cols, b.square
                    ),
                ));
            }
            Target::Board(Board {
                rows: b.rows,
                cols: b.cols,
                square: b.square,
            })
        }
        (None, Some(t)) => target_from_file(t, "target.", path)?,
    };
    // The stereo form: "cameras" given, or every view holding exactly "left" and "right" of a
    // board (then rig cameras 0 and 1, as the stereo form has always read them).
    let stereo_form = file.cameras.is_some()
        || (matches!(target, Target::Board(_))
            && !file.views.is_empty()
            && file.views.iter().all(|v| {
                let mut keys: Vec<&str> = v.0.iter().map(|(k, _)| k.as_str()).collect();
                keys.sort_unstable();
                keys == ["left", "right"]
            }));
    let mut views = Vec::with_capacity(file.views.len());
    for (v, view) in file.views.iter().enumerate() {
        let mut images = Vec::with_capacity(view.0.len());
        for (key, corners) in &view.0 {
            if key.len() > MAX_CAMERA_NAME_BYTES {
                return Err(invalid(
                    &format!("views[{v}]"),
                    format!(
                        "the key '{}' is longer than a camera name may be ({MAX_CAMERA_NAME_BYTES} bytes)",
                        excerpt(key, EXCERPT_CHARS)
                    ),
                ));
            }
            let camera = match (&file.cameras, key.as_str()) {
                (Some(names), "left") => CameraKey::Name(names[0].clone()),
                (Some(names), "right") => CameraKey::Name(names[1].clone()),
                (Some(_), _) => {
                    return Err(invalid(&format!("views[{v}].{key}"), "with \"cameras\": [A, B] (the stereo form) a view holds only \"left\" and \"right\"".into()));
                }
                (None, "left") if stereo_form => CameraKey::Position(0),
                (None, "right") if stereo_form => CameraKey::Position(1),
                (None, name) => CameraKey::Name(name.to_string()),
            };
            let corners = corners
                .iter()
                .map(|c| c.map(|[u, v]| Point2::new(u, v)))
                .collect();
            images.push(Image {
                camera,
                key: key.clone(),
                corners,
            });
        }
        if stereo_form {
            // Left before right, whatever the file's key order.
            images.sort_by_key(|i| i.key != "left");
        }
        views.push(View { images });
    }
    Ok(Observations {
        target,
        views,
        stereo_form,
    })
}

/// A 3-D target's points, checked: finite, at least 4. `prefix` leads the JSON path in errors.
fn target_from_file(t: &TargetFile, prefix: &str, path: &Path) -> Result<Target, IoError> {
    let invalid = |field: String, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field,
        reason,
    };
    if let Some(i) = t
        .points
        .iter()
        .position(|p| !p.iter().all(|x| x.is_finite()))
    {
        return Err(invalid(
            format!("{prefix}points[{i}]"),
            format!("{:?} is not finite", t.points[i]),
        ));
    }
    if t.points.len() < 4 {
        return Err(invalid(
            format!("{prefix}points"),
            format!("{} points: a target needs at least 4", t.points.len()),
        ));
    }
    Ok(Target::Points(
        t.points
            .iter()
            .map(|&p| nalgebra::Point3::from(p))
            .collect(),
    ))
}

/// Parses a 3-D target file, `{"points": [[x, y, z], …]}` (metres, the target's own frame);
/// `path` only labels errors. At least 4 finite points; unknown keys are an error.
pub fn target_from_json_str(text: &str, path: &Path) -> Result<Target, IoError> {
    let file: TargetFile = super::rig_json::parse_json(text, path)?;
    target_from_file(&file, "", path)
}

/// Reads a 3-D target file (`-` = standard input), see [`target_from_json_str`].
pub fn read_target(path: &Path) -> Result<Target, IoError> {
    target_from_json_str(&read_text(path)?, path)
}

/// Reads an observations file in either form (`-` = standard input).
pub fn read_observations(path: &Path) -> Result<Observations, IoError> {
    observations_from_json_str(&read_text(path)?, path)
}

/// Observations in the general form, one view per line, every value at full f64 precision; each
/// image under its key as given (a camera name).
pub fn observations_to_json_string(observations: &Observations) -> String {
    let (board, target) = match &observations.target {
        Target::Board(b) => (
            Some(BoardFile {
                rows: b.rows,
                cols: b.cols,
                square: b.square,
            }),
            None,
        ),
        Target::Points(points) => (
            None,
            Some(TargetFile {
                points: points.iter().map(|p| [p.x, p.y, p.z]).collect(),
            }),
        ),
    };
    let views = observations
        .views
        .iter()
        .map(|v| {
            GeneralView(
                v.images
                    .iter()
                    .map(|i| {
                        (
                            i.key.clone(),
                            i.corners.iter().map(|p| p.map(|p| [p.x, p.y])).collect(),
                        )
                    })
                    .collect(),
            )
        })
        .collect();
    let file = GeneralFile {
        board,
        target,
        cameras: None,
        views,
    };
    let mut text = serde_json::to_string(&file).expect("plain data always serialises");
    // One view per line keeps the file readable and diffable.
    text = text
        .replacen("\"views\":[", "\"views\":[\n  ", 1)
        .replace("]]},{", "]]},\n  {")
        .replace("null]},{", "null]},\n  {");
    text.push('\n');
    text
}

#[derive(Debug, Serialize)]
struct EstimatedFile {
    value: f64,
    std: Option<f64>,
}

#[derive(Debug, Serialize)]
struct PortReportFile<'a> {
    name: &'a str,
    normal: [f64; 3],
    tilt_deg: EstimatedFile,
    azimuth_deg: EstimatedFile,
    distance: EstimatedFile,
    thicknesses: Vec<EstimatedFile>,
}

#[derive(Debug, Serialize)]
struct CameraReportFile<'a> {
    name: &'a str,
    views: usize,
    observations: usize,
    rms_px: Option<f64>,
    inlier_rms_px: Option<f64>,
    rotation_std_deg: Option<[f64; 3]>,
    translation_std_m: Option<[f64; 3]>,
    /// σ of fx, fy, cx, cy (px), k1, k2, p1, p2, k3 when the intrinsics were estimated (null for a
    /// lens term held at 0); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    intrinsics_std: Option<IntrinsicsStdFile>,
}

/// σ of a camera's intrinsics in a report file.
#[derive(Debug, Serialize)]
struct IntrinsicsStdFile {
    fx: Option<f64>,
    fy: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    k1: Option<f64>,
    k2: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
    k3: Option<f64>,
}

impl IntrinsicsStdFile {
    fn of(std: &[Option<f64>; 9]) -> Self {
        let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = *std;
        Self {
            fx,
            fy,
            cx,
            cy,
            k1,
            k2,
            p1,
            p2,
            k3,
        }
    }
}

/// A board pose in a file: X_master = R·X_board + t, R as rows.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseFile {
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
}

fn pose_to_file(pose: &Isometry3<f64>) -> PoseFile {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let t = pose.translation.vector;
    PoseFile {
        rotation: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
        translation: [t.x, t.y, t.z],
    }
}

fn pose_from_file(pose: &PoseFile) -> Isometry3<f64> {
    let r = pose.rotation;
    let m = Matrix3::from_fn(|i, j| r[i][j]);
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&m));
    Isometry3::from_parts(
        Translation3::from(Vector3::from(pose.translation)),
        rotation,
    )
}

/// The truth of a simulated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The port of the master camera, in the master frame (behind a shared port: the port).
    pub interface: Interface,
    /// X_master = R·X_target + t per view (the board's or the 3-D target's pose).
    pub master_from_board: Vec<Isometry3<f64>>,
    /// Pixel noise added, pixels.
    pub noise_px: f64,
    /// Seed of the simulation.
    pub seed: u64,
    /// The whole true rig (every camera's extrinsics and port, the layers), which a calibration of
    /// any rig is checked against; `None` in truth files written before it was added.
    pub rig: Option<Rig>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthFile {
    interface: super::rig_json::InterfaceFile,
    tilt_deg: f64,
    azimuth_deg: f64,
    noise_px: f64,
    seed: u64,
    board_poses: Vec<PoseFile>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::rig_json::present"
    )]
    rig: Option<super::rig_json::RigFile>,
}

/// Truth as JSON: `interface` (the master camera's port in the master frame, as in a rig file),
/// `tilt_deg`, `azimuth_deg` (of that port), `noise_px`, `seed`, `board_poses` [{rotation (rows),
/// translation}] with X_master = R·X_target + t (a board's or a 3-D target's poses), and `rig`:
/// the whole true rig in the rig-file schema (optional: files without it are read).
pub fn truth_to_json_string(truth: &Truth) -> String {
    let file = TruthFile {
        interface: interface_to_file(&truth.interface),
        tilt_deg: truth.interface.tilt().to_degrees(),
        azimuth_deg: truth.interface.azimuth().to_degrees(),
        noise_px: truth.noise_px,
        seed: truth.seed,
        board_poses: truth.master_from_board.iter().map(pose_to_file).collect(),
        rig: truth.rig.as_ref().map(super::rig_json::rig_to_file),
    };
    let mut text = serde_json::to_string_pretty(&file).expect("plain data always serialises");
    text.push('\n');
    text
}

/// Writes a truth file atomically.
pub fn write_truth(path: &Path, truth: &Truth) -> Result<(), IoError> {
    write_atomic(path, truth_to_json_string(truth).as_bytes())
}

/// Reads a truth file.
pub fn read_truth(path: &Path) -> Result<Truth, IoError> {
    let file: TruthFile = super::rig_json::parse_json(&read_text(path)?, path)?;
    let interface = super::rig_json::interface_from_file(&file.interface, "interface", path)?;
    let rig = match &file.rig {
        None => None,
        Some(rig) => Some(
            super::rig_json::rig_from_file(rig, path).map_err(|e| match e {
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
            })?,
        ),
    };
    Ok(Truth {
        interface,
        master_from_board: file.board_poses.iter().map(pose_from_file).collect(),
        noise_px: file.noise_px,
        seed: file.seed,
        rig,
    })
}

#[derive(Debug, Serialize)]
struct StdFile {
    tilt_deg: Option<f64>,
    azimuth_deg: Option<f64>,
    air_distance: Option<f64>,
}

#[derive(Debug, Serialize)]
struct StageFile<'a> {
    name: &'a str,
    tilt_deg: Option<f64>,
    azimuth_deg: Option<f64>,
    air_distance: Option<f64>,
    cost: f64,
    unit: &'a str,
    iterations: usize,
    seconds: f64,
}

#[derive(Debug, Serialize)]
struct ScatterFile<'a> {
    parameter: &'a str,
    factor: f64,
}

#[derive(Debug, Serialize)]
struct OutlierFile<'a> {
    view: usize,
    image: &'a str,
    camera: &'a str,
    corner: usize,
    residual_px: f64,
    screened: bool,
}

#[derive(Debug, Serialize)]
struct ReportFile<'a> {
    method: &'a str,
    strategy: &'a str,
    estimate: String,
    normal: [f64; 3],
    tilt_deg: f64,
    azimuth_deg: f64,
    air_distance: f64,
    std: Option<StdFile>,
    ports: Vec<PortReportFile<'a>>,
    cameras: Vec<CameraReportFile<'a>>,
    sigma_px: Option<f64>,
    sigma_from_scatter: Option<ScatterFile<'a>>,
    noise_px: Option<f64>,
    rms_px: Vec<f64>,
    rms_px_all: f64,
    inlier_rms_px: Vec<f64>,
    rms_px_per_view: Vec<Vec<f64>>,
    scene_cameras: Option<&'a [String; 2]>,
    scene_rms_m: Option<f64>,
    square_deviation_rms_m: Option<f64>,
    views: usize,
    corners: usize,
    observations: usize,
    iterations: usize,
    termination: &'a str,
    seconds: f64,
    backend: &'a str,
    fits: bool,
    warnings: &'a [String],
    diagnosis: &'a [String],
    outliers: Vec<OutlierFile<'a>>,
    stages: Vec<StageFile<'a>>,
    target_poses: Vec<PoseFile>,
    #[serde(skip_serializing_if = "Option::is_none")]
    board_poses: Option<Vec<PoseFile>>,
}

/// A calibration report as JSON, one schema for every rig:
/// - `method` (`consecutive`, `simultaneous`, `auto`), `strategy` (what ran, in words),
///   `estimate` (as `--estimate` takes it), `backend`;
/// - the first port (the shared one, or the master's own, in its frame): `normal`, `tilt_deg`,
///   `azimuth_deg`, `air_distance` (m), `std` {tilt_deg, azimuth_deg, air_distance} (null
///   without a maximum-likelihood fit);
/// - `ports` [{name, normal, tilt_deg, azimuth_deg, distance, thicknesses}, each value
///   `{value, std}`], `cameras` [{name, views, observations, rms_px, inlier_rms_px,
///   rotation_std_deg, translation_std_m}];
/// - `sigma_px` (σ̂ of the fit), `sigma_from_scatter` {parameter, factor} (where the views
///   scatter more than σ̂ says, every σ is raised to what they say: the parameter raised most;
///   null where none was), `noise_px` (corner noise seen in the images), `rms_px` and
///   `inlier_rms_px` per camera (rig order), `rms_px_all` over every corner image,
///   `rms_px_per_view` `[view][camera]` (null where a camera did not see a view);
/// - `scene_cameras`, `scene_rms_m`, `square_deviation_rms_m`: the 3-D errors of one pair's
///   triangulated corners (null without a pair and a board);
/// - `views`, `corners`, `observations`, `iterations`, `termination`, `seconds`, `fits`,
///   `warnings`, `diagnosis`, `outliers` [{view, image, camera, corner, residual_px, screened}],
///   `stages` [{name, tilt_deg, azimuth_deg, air_distance, cost, unit, iterations, seconds}],
///   `target_poses` [{rotation (rows), translation}] with X_master = R·X_target + t, and for a
///   board the same list as `board_poses` (the name the stereo reports gave it).
pub fn report_to_json_string(report: &Report) -> String {
    let degrees = |e: &Estimated| EstimatedFile {
        value: e.value.to_degrees(),
        std: e.std.map(f64::to_degrees),
    };
    let plain = |e: &Estimated| EstimatedFile {
        value: e.value,
        std: e.std,
    };
    let port = report.port();
    let finite = |v: f64| v.is_finite().then_some(v);
    let fit = report.sigma_px.is_some();
    let file = ReportFile {
        method: report.method.name(),
        strategy: &report.strategy,
        estimate: report.estimate.name(),
        normal: port.normal,
        tilt_deg: port.tilt.value.to_degrees(),
        azimuth_deg: port.azimuth.value.to_degrees(),
        air_distance: port.distance.value,
        std: fit.then(|| StdFile {
            tilt_deg: port.tilt.std.map(f64::to_degrees),
            azimuth_deg: port.azimuth.std.map(f64::to_degrees),
            air_distance: port.distance.std,
        }),
        ports: report
            .ports
            .iter()
            .map(|p| PortReportFile {
                name: &p.name,
                normal: p.normal,
                tilt_deg: degrees(&p.tilt),
                azimuth_deg: degrees(&p.azimuth),
                distance: plain(&p.distance),
                thicknesses: p.thicknesses.iter().map(plain).collect(),
            })
            .collect(),
        cameras: report
            .cameras
            .iter()
            .map(|c| CameraReportFile {
                name: &c.name,
                views: c.views,
                observations: c.observations,
                rms_px: finite(c.rms_px),
                inlier_rms_px: finite(c.inlier_rms_px),
                rotation_std_deg: c.extrinsics_std.map(|(r, _)| r.map(f64::to_degrees)),
                translation_std_m: c.extrinsics_std.map(|(_, t)| t),
                intrinsics_std: c.intrinsics_std.as_ref().map(IntrinsicsStdFile::of),
            })
            .collect(),
        sigma_px: report.sigma_px,
        sigma_from_scatter: report
            .sigma_from_scatter
            .as_ref()
            .map(|(parameter, factor)| ScatterFile {
                parameter,
                factor: *factor,
            }),
        noise_px: report.noise_px,
        rms_px: report.cameras.iter().map(|c| c.rms_px).collect(),
        rms_px_all: report.rms_px,
        inlier_rms_px: report.cameras.iter().map(|c| c.inlier_rms_px).collect(),
        rms_px_per_view: (0..report.views)
            .map(|v| {
                report
                    .cameras
                    .iter()
                    .map(|c| c.rms_px_per_view.get(v).copied().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect(),
        scene_cameras: report.scene.as_ref().map(|s| &s.cameras),
        scene_rms_m: report.scene.as_ref().map(|s| s.rms_m),
        square_deviation_rms_m: report.scene.as_ref().map(|s| s.square_deviation_rms_m),
        views: report.views,
        corners: report.corners,
        observations: report.observations,
        iterations: report.iterations,
        termination: &report.termination,
        seconds: report.seconds,
        backend: &report.backend,
        fits: report.fits,
        warnings: &report.warnings,
        diagnosis: &report.diagnosis,
        outliers: report
            .outliers
            .iter()
            .map(|o| OutlierFile {
                view: o.view,
                image: &o.image,
                camera: &o.camera,
                corner: o.corner,
                residual_px: o.residual_px,
                screened: o.screened,
            })
            .collect(),
        stages: report
            .stages
            .iter()
            .map(|s| StageFile {
                name: &s.name,
                tilt_deg: s.port.map(|c| c.tilt().to_degrees()),
                azimuth_deg: s.port.map(|c| c.azimuth().to_degrees()),
                air_distance: s.port.map(|c| c.air_distance),
                cost: s.cost,
                unit: s.unit,
                iterations: s.iterations,
                seconds: s.seconds,
            })
            .collect(),
        target_poses: report.poses.iter().map(pose_to_file).collect(),
        board_poses: report
            .board
            .then(|| report.poses.iter().map(pose_to_file).collect()),
    };
    // NaN (a camera that saw no view) is written as null.
    let mut text = serde_json::to_string_pretty(&file).expect("plain data always serialises");
    text.push('\n');
    text
}

/// Writes a calibration report atomically.
pub fn write_report(path: &Path, report: &Report) -> Result<(), IoError> {
    write_atomic(path, report_to_json_string(report).as_bytes())
}

/// The report of `flatport calibrate --images`: the calibration's report ([`write_report`]'s
/// keys), and beside them `intrinsics` (each camera's in-air fit: its values, σ, RMS, views
/// used and left out, the lens terms chosen and why), `held_out` (the held-out frames'
/// reprojection RMS and triangulated corner distances), `dropped_frames`, `dropped_corners` (the
/// corners left out after the first fit, a line each), `left_out_images`, `turned_images` (each
/// camera whose images' chessboard corner order was turned to agree with the other cameras of
/// their frames, a line each), `frames` (the labels of the frames fitted, in the report's view order) and `links` (how each
/// camera's extrinsics were started).
pub fn write_boards_report(
    path: &Path,
    result: &crate::calib::pipeline::boards::BoardsCalibration,
    names: &[String],
    intrinsics: &[(String, crate::calib::pipeline::intrinsics::IntrinsicsFit)],
) -> Result<(), IoError> {
    write_atomic(
        path,
        boards_report_to_json_string(result, names, intrinsics).as_bytes(),
    )
}

/// The text [`write_boards_report`] writes (the Python package hands it over as a dict).
pub fn boards_report_to_json_string(
    result: &crate::calib::pipeline::boards::BoardsCalibration,
    names: &[String],
    intrinsics: &[(String, crate::calib::pipeline::intrinsics::IntrinsicsFit)],
) -> String {
    use serde_json::json;
    let mut value: serde_json::Value =
        serde_json::from_str(&report_to_json_string(&result.calibration.report))
            .expect("the report's own JSON parses");
    let finite = |v: f64| v.is_finite().then_some(v);
    let fits: Vec<serde_json::Value> = intrinsics
        .iter()
        .map(|(name, fit)| {
            let c = &fit.camera;
            json!({
                "camera": name,
                "width": c.width, "height": c.height,
                "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                "distortion": c.distortion,
                "std": {"fx": fit.std[0], "fy": fit.std[1], "cx": fit.std[2], "cy": fit.std[3],
                        "distortion": &fit.std[4..]},
                "rms_px": finite(fit.rms_px),
                "view_rms_px": fit.view_rms_px.iter().map(|r| r.and_then(finite)).collect::<Vec<_>>(),
                "outliers": fit.outliers.iter().map(|(v, why)| json!({"view": v, "why": why})).collect::<Vec<_>>(),
                "excluded": fit.excluded.iter().map(|(v, why)| json!({"view": v, "why": why})).collect::<Vec<_>>(),
                "lens_terms": fit.model.terms.describe(),
                "lens_terms_why": fit.model.reason,
            })
        })
        .collect();
    let held_out = result.validation.as_ref().map(|v| {
        json!({
            "frames": v.frames,
            "rms_px": finite(v.rms_px),
            "corner_pairs": v.distances,
            "median_distance_error_mm": finite(v.median_error_m * 1e3),
            "median_distance_error_percent_of_square": finite(v.median_error_percent),
            "rms_distance_error_mm": finite(v.rms_error_m * 1e3),
            "frames_left_out": v.views_left_out,
            "corners_left_out": v.corners_left_out,
        })
    });
    let extra = json!({
        "verdict": {"grade": result.verdict.grade.name(), "why": result.verdict.why},
        "fitted_squares_median_error_percent": result.fitted_squares_percent.and_then(finite),
        "intrinsics": fits,
        "held_out": held_out,
        "dropped_frames": result.dropped.iter().map(|(f, why)| json!({"frame": f, "why": why})).collect::<Vec<_>>(),
        "dropped_corners": result.dropped_corners,
        "left_out_images": result.left_out,
        "turned_images": result.turned,
        "frames": result.fitted,
        "links": result.links.iter().map(|l| json!({"camera": names[l.camera], "via": names[l.via], "frames": l.frames})).collect::<Vec<_>>(),
    });
    if let (Some(object), serde_json::Value::Object(extra)) = (value.as_object_mut(), extra) {
        object.extend(extra);
    }
    serde_json::to_string_pretty(&value).expect("JSON values serialise")
}

/// The report of a targetless calibration (`flatport.calibrate_targetless`' report) as JSON:
/// - `ports` [{`name`, `normal` (the frame the rig file gives the port in), `tilt_deg`,
///   `azimuth_deg`, `axis_std_deg` (σ of the axis along its worst direction; null when not
///   estimated), `distance` {`value`, `std`} (metres; std null when not estimated),
///   `thicknesses` [{`value`, `std`}]}];
/// - `rms_px` (the final fit's RMS reprojection error), `candidates` (tracks matched), `tracks`
///   (tracks kept in the fit), `observations`, `matches_per_camera` (against the master; the
///   master's own entry 0), `starts`, `termination`, `overlap` (the σ's patch-overlap factor);
/// - `unpinned` [{`parameter`, `sigma` (degrees for an axis, metres otherwise), `limit`,
///   `reason`}] and `pinned` (whether that list is empty: the rig may be used).
pub fn targetless_report_to_json_string(
    result: &crate::calib::targetless::TargetlessCalibration,
) -> String {
    let ports: Vec<serde_json::Value> = result
        .ports
        .iter()
        .map(|p| {
            let n = p.port.normal();
            serde_json::json!({
                "name": p.name,
                "normal": [n.x, n.y, n.z],
                "tilt_deg": p.port.tilt().to_degrees(),
                "azimuth_deg": p.port.azimuth().to_degrees(),
                "axis_std_deg": p.axis_sigma_deg,
                "distance": {"value": p.port.air_distance(), "std": p.distance_sigma_m},
                "thicknesses": p
                    .port
                    .layers()
                    .iter()
                    .zip(&p.thickness_sigma_m)
                    .map(|(l, s)| serde_json::json!({"value": l.thickness, "std": s}))
                    .collect::<Vec<_>>(),
            })
        })
        .collect();
    let unpinned: Vec<serde_json::Value> = result
        .unpinned
        .iter()
        .map(|u| {
            serde_json::json!({
                "parameter": u.parameter,
                "sigma": u.sigma,
                "limit": u.limit,
                "reason": u.reason,
            })
        })
        .collect();
    let report = serde_json::json!({
        "ports": ports,
        "rms_px": result.rms_px,
        "candidates": result.candidates,
        "tracks": result.inliers,
        "observations": result.observations,
        "matches_per_camera": result.matches_per_camera,
        "starts": result.starts,
        "termination": result.termination.describe(),
        "overlap": result.overlap,
        "unpinned": unpinned,
        "pinned": result.unpinned.is_empty(),
    });
    let mut text = serde_json::to_string_pretty(&report).expect("plain data always serialises");
    text.push('\n');
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observations_round_trip_and_errors_name_the_place() {
        let text = r#"{"board": {"rows": 2, "cols": 3, "square": 0.05}, "cameras": ["left", "right"],
            "views": [{"left": [[1, 2], null, [3.5, 4], [5, 6], [7, 8], [9, 10]],
                       "right": [[1, 2], null, [3, 4], [5, 6], [7, 8], [9, 10.25]]}]}"#;
        let observations = observations_from_json_str(text, "obs.json".as_ref()).unwrap();
        assert!(observations.stereo_form);
        assert_eq!(observations.views[0].images[0].corners[1], None);
        assert_eq!(
            observations.views[0].images[1].corners[5],
            Some(Point2::new(9.0, 10.25))
        );
        let stereo = stereo_observations_to_json_string(&observations, true).unwrap();
        let again = observations_from_json_str(&stereo, "x".as_ref()).unwrap();
        assert_eq!(again, observations);
        // Without "cameras" the stereo form is rig cameras 0 and 1.
        let positional = observations_from_json_str(
            &stereo_observations_to_json_string(&observations, false).unwrap(),
            "x".as_ref(),
        )
        .unwrap();
        assert_eq!(positional.views[0].images[1].camera, CameraKey::Position(1));

        let typo = text.replace("\"square\"", "\"sqare\"");
        let error = observations_from_json_str(&typo, "obs.json".as_ref())
            .unwrap_err()
            .to_string();
        assert!(
            error.starts_with("obs.json:1:") && error.contains("sqare"),
            "{error}"
        );
        let bad_corner = text.replace("[3.5, 4]", "[3.5]");
        let error = observations_from_json_str(&bad_corner, "obs.json".as_ref())
            .unwrap_err()
            .to_string();
        assert!(error.contains("views[0].left[2]"), "{error}");
        let no_square = text.replace("0.05", "-1");
        let error = observations_from_json_str(&no_square, "obs.json".as_ref())
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("board") && error.contains("square -1"),
            "{error}"
        );
    }

    fn parse_general(text: &str) -> Result<Observations, IoError> {
        observations_from_json_str(text, Path::new("obs.json"))
    }

    #[test]
    fn the_general_form_reads_writes_and_names_what_is_wrong() {
        let text = r#"{"target": {"points": [[0,0,0],[0.1,0,0],[0,0.1,0],[0,0,0.1]]},
                       "views": [{"cam2": [[1,2],null,[3,4],[5,6]], "cam0": [[7,8],[9,10],null,null]}, {}]}"#;
        let observations = parse_general(text).unwrap();
        assert!(matches!(&observations.target, Target::Points(p) if p.len() == 4));
        assert_eq!(observations.views.len(), 2);
        // File order kept; keys are names.
        let keys: Vec<&str> = observations.views[0]
            .images
            .iter()
            .map(|i| i.key.as_str())
            .collect();
        assert_eq!(keys, ["cam2", "cam0"]);
        assert_eq!(
            observations.views[0].images[0].corners[2],
            Some(Point2::new(3.0, 4.0))
        );
        assert_eq!(
            parse_general(&observations_to_json_string(&observations)).unwrap(),
            observations
        );
        // The stereo form with "cameras" maps left/right onto the names.
        let stereo = parse_general(r#"{"board": {"rows": 2, "cols": 2, "square": 0.1}, "cameras": ["b", "a"], "views": [{"left": [null,null,null,null], "right": [null,null,null,null]}]}"#).unwrap();
        assert_eq!(
            stereo.views[0].images[0].camera,
            CameraKey::Name("b".into())
        );
        let cases = [
            (
                r#"{"board": {"rows": 2, "cols": 2, "square": 0.1}, "target": {"points": [[0,0,0],[1,0,0],[0,1,0],[0,0,1]]}, "views": []}"#,
                "not both",
            ),
            (r#"{"views": []}"#, "missing"),
            (
                r#"{"board": {"rows": 2, "cols": 2, "square": 0.1}, "views": [{"a": [], "a": []}]}"#,
                "appears twice",
            ),
            (
                r#"{"board": {"rows": 2, "cols": 2, "square": 0.1}, "cameras": ["a", "b"], "views": [{"c": []}]}"#,
                "views[0].c",
            ),
            (
                r#"{"target": {"points": [[0,0,0]]}, "views": []}"#,
                "at least 4",
            ),
        ];
        for (text, expected) in cases {
            let message = parse_general(text).unwrap_err().to_string();
            assert!(message.contains(expected), "{text}: {message}");
        }
    }

    #[test]
    fn truth_holds_the_rig_and_old_truth_files_still_read() {
        use crate::model::Ports;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("truth.json");
        let rig = crate::io::rig_from_json_str(
            r#"{"cameras": [
                {"name": "a", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240,
                 "interface": {"normal": [0.1, 0, 1], "distance": 0.02}},
                {"name": "b", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240,
                 "translation": [-0.1, 0, 0], "interface": {"normal": [0, 0.05, 1], "distance": 0.015}}]}"#,
            Path::new("rig.json"),
        )
        .unwrap();
        let pose = Isometry3::new(Vector3::new(0.1, -0.2, 1.5), Vector3::new(0.1, 0.2, -0.3));
        let truth = Truth {
            interface: rig.port_in_master(0),
            master_from_board: vec![pose],
            noise_px: 0.25,
            seed: 7,
            rig: Some(rig.clone()),
        };
        write_truth(&path, &truth).unwrap();
        let back = read_truth(&path).unwrap();
        // Normals are normalised again on reading: equal to an ulp.
        let same_port = |a: &Interface, b: &Interface| {
            (a.normal().into_inner() - b.normal().into_inner()).norm() < 1e-15
                && a.air_distance() == b.air_distance()
                && a.layers() == b.layers()
        };
        let back_rig = back.rig.as_ref().unwrap();
        assert_eq!(back_rig.cameras(), rig.cameras());
        match (back_rig.ports(), rig.ports()) {
            (Ports::PerCamera(a), Ports::PerCamera(b)) => {
                assert!(a.iter().zip(b).all(|(a, b)| same_port(a, b)))
            }
            _ => panic!("the ports changed kind"),
        }
        assert!(same_port(&back.interface, &truth.interface));
        assert!(
            (back.master_from_board[0].to_homogeneous() - pose.to_homogeneous()).norm() < 1e-15
        );
        // A file written before the rig was added (no "rig" key) reads, without a rig.
        let mut value: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        value.as_object_mut().unwrap().remove("rig");
        std::fs::write(&path, value.to_string()).unwrap();
        assert_eq!(read_truth(&path).unwrap().rig, None);
        // A bad rig inside names its place.
        let text = truth_to_json_string(&truth).replace("\"fx\": 500.0", "\"fx\": -500.0");
        std::fs::write(&path, text).unwrap();
        let error = read_truth(&path).unwrap_err().to_string();
        assert!(error.contains("rig.cameras[0].fx"), "{error}");
    }

    #[test]
    fn target_files_read_and_name_what_is_wrong() {
        let target = target_from_json_str(
            r#"{"points": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]}"#,
            Path::new("t.json"),
        )
        .unwrap();
        assert_eq!(target.len(), 4);
        assert!(!target.is_planar());
        for (text, place) in [
            (
                r#"{"points": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]}"#,
                "points",
            ),
            (
                r#"{"points": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0]]}"#,
                "points[3]",
            ),
            (r#"{"points": [], "board": 1}"#, "board"),
        ] {
            let error = target_from_json_str(text, Path::new("t.json"))
                .unwrap_err()
                .to_string();
            assert!(
                error.contains("t.json") && error.contains(place),
                "{text}: {error}"
            );
        }
    }
}
