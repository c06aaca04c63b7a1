//! The observations file that `flatport detect` and `flatport render` write: the corners every
//! camera found, per view. One function writes it ([`detections_to_json_string`]), so that the
//! form can follow the reader.
//!
//! The general form (docs/DESIGN.md §3b) is `{"board": {rows, cols, square}, "views": [{CAMERA:
//! [[u, v] | null, …], …}, …]}`, keys the rig's camera names, a camera that did not see a view
//! absent from it. For two cameras it writes the stereo form (keys `left` and `right` in every
//! view, `"cameras": [A, B]` naming the rig cameras when they are not called `left` and `right`;
//! the form tools written for the thesis' stereo pipeline read, and for cameras named `left` and
//! `right` the general form itself) and leaves out the views only one camera saw (returned, for
//! the caller to report); for any other number of cameras it writes the general form.

use std::path::Path;

use nalgebra::Point2;
use serde_json::{Map, Value, json};

use super::calib_json::stereo_form_text;
use crate::calib::Board;
use crate::io::{IoError, write_atomic};

/// Corners of one view: per camera (in the order of the camera names), the camera's corners
/// (row-major, `rows · cols`, `None` for a corner it did not see: a ChArUco board's partial view)
/// or `None` when it did not see the board.
pub type DetectedView = Vec<Option<Vec<Option<Point2<f64>>>>>;

/// The file's text and the views left out of it (indices into `views`).
pub fn detections_to_json_string(
    board: &Board,
    cameras: &[String],
    views: &[DetectedView],
) -> (String, Vec<usize>) {
    if let [a, b] = cameras {
        let mut left_out = Vec::new();
        let mut stereo = Vec::new();
        for (v, view) in views.iter().enumerate() {
            match (&view[0], &view[1]) {
                (Some(l), Some(r)) => stereo.push([l.clone(), r.clone()]),
                _ => left_out.push(v),
            }
        }
        let borrowed: Vec<[&[Option<Point2<f64>>]; 2]> = stereo
            .iter()
            .map(|[l, r]| [l.as_slice(), r.as_slice()])
            .collect();
        let text = stereo_form_text(board, [a.as_str(), b.as_str()], &borrowed, false);
        return (text, left_out);
    }
    let mut text = format!(
        "{{\"board\": {},\n \"views\": [",
        json!({"rows": board.rows, "cols": board.cols, "square": board.square})
    );
    for (v, view) in views.iter().enumerate() {
        let mut map = Map::new();
        for (name, corners) in cameras.iter().zip(view) {
            if let Some(corners) = corners {
                map.insert(
                    name.clone(),
                    Value::Array(
                        corners
                            .iter()
                            .map(|p| p.map_or(Value::Null, |p| json!([p.x, p.y])))
                            .collect(),
                    ),
                );
            }
        }
        text += if v == 0 { "\n  " } else { ",\n  " };
        text += &Value::Object(map).to_string();
    }
    text += "]}\n";
    (text, Vec::new())
}

/// Writes the file atomically; returns the views left out ([`detections_to_json_string`]).
pub fn write_detections(
    path: &Path,
    board: &Board,
    cameras: &[String],
    views: &[DetectedView],
) -> Result<Vec<usize>, IoError> {
    let (text, left_out) = detections_to_json_string(board, cameras, views);
    write_atomic(path, text.as_bytes())?;
    Ok(left_out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::observations_from_json_str;

    #[test]
    fn two_cameras_write_the_stereo_form_and_leave_out_one_sided_views() {
        let board = Board {
            rows: 2,
            cols: 2,
            square: 0.05,
        };
        let corners = |x: f64| {
            Some(
                (0..4)
                    .map(|i| Some(Point2::new(x + i as f64, 2.0 * i as f64)))
                    .collect::<Vec<_>>(),
            )
        };
        let views = vec![
            vec![corners(1.0), corners(5.0)],
            vec![corners(1.0), None],
            vec![corners(2.0), corners(7.5)],
        ];
        let names = ["left".to_string(), "right".to_string()];
        let (text, left_out) = detections_to_json_string(&board, &names, &views);
        assert_eq!(left_out, vec![1]);
        assert!(!text.contains("cameras"), "{text}");
        let read = observations_from_json_str(&text, "x".as_ref()).unwrap();
        assert_eq!(read.views.len(), 2);
        assert_eq!(read.views[1].images[1].key, "right");
        assert_eq!(
            read.views[1].images[1].corners[3],
            Some(Point2::new(10.5, 6.0))
        );
        assert!(read.stereo_form);

        let names = ["port".to_string(), "starboard".to_string()];
        let (text, _) = detections_to_json_string(&board, &names, &views);
        assert!(text.contains(r#""cameras":["port","starboard"]"#), "{text}");
        let read = observations_from_json_str(&text, "x".as_ref()).unwrap();
        assert_eq!(
            read.views[0].images[0].camera,
            crate::calib::CameraKey::Name("port".into())
        );
    }

    #[test]
    fn other_camera_counts_write_the_general_form() {
        let board = Board {
            rows: 2,
            cols: 2,
            square: 0.05,
        };
        let corners = Some(vec![Some(Point2::new(1.0, 2.0)); 4]);
        let mut partial = corners.clone();
        if let Some(c) = partial.as_mut() {
            c[1] = None;
        }
        let views = vec![vec![corners, None, partial]];
        let names = ["a".to_string(), "b".to_string(), "c".to_string()];
        let (text, left_out) = detections_to_json_string(&board, &names, &views);
        assert!(left_out.is_empty());
        let value: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(value["board"]["cols"], 2);
        let view = value["views"][0].as_object().unwrap();
        assert_eq!(view.keys().collect::<Vec<_>>(), vec!["a", "c"]);
        assert_eq!(view["c"][3], json!([1.0, 2.0]));
        assert_eq!(view["c"][1], Value::Null, "a corner not seen is null");
        assert_eq!(view["a"][1], json!([1.0, 2.0]));
    }
}
