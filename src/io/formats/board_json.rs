//! `BOARD.json`: the calibration board (docs/DESIGN.md §3c, AquaCal's key names).
//!
//! ```json
//! {"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04,
//!  "marker_size": 0.03, "dictionary": "DICT_4X4_50", "legacy_pattern": false}
//! {"type": "chessboard", "squares_x": 10, "squares_y": 7, "square_size": 0.04}
//! ```
//!
//! Squares, not inner corners; metres; OpenCV's dictionary names. Without `"type"`, a
//! `"marker_size"` means ChArUco and its absence a chessboard. `legacy_pattern` is optional
//! (false). Unknown keys are errors, as in every file flatport reads.

use std::path::Path;

use serde::Deserialize;

use super::rig_json::parse_json;
use crate::base::board_spec::{BoardError, BoardSpec, CharucoSpec, chessboard};
use crate::io::{IoError, read_text};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardFile {
    #[serde(rename = "type")]
    kind: Option<String>,
    squares_x: usize,
    squares_y: usize,
    square_size: f64,
    marker_size: Option<f64>,
    dictionary: Option<String>,
    legacy_pattern: Option<bool>,
}

/// Reads and checks a `BOARD.json`; errors name the file, the key and the value.
pub fn read_board(path: &Path) -> Result<BoardSpec, IoError> {
    board_from_json_str(&read_text(path)?, path)
}

/// Parses and checks a `BOARD.json` text; `path` only labels errors.
pub fn board_from_json_str(text: &str, path: &Path) -> Result<BoardSpec, IoError> {
    let file: BoardFile = parse_json(text, path)?;
    let invalid = |field: &str, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: field.to_string(),
        reason,
    };
    let from_board_error = |e: BoardError| {
        let field = match &e {
            BoardError::Value { field, .. } => field,
            BoardError::UnknownDictionary { .. } => "dictionary",
            BoardError::LegacyPattern { .. } => "legacy_pattern",
        };
        invalid(field, e.to_string())
    };
    let charuco = match file.kind.as_deref() {
        Some("charuco") => true,
        Some("chessboard") => false,
        Some(other) => {
            return Err(invalid(
                "type",
                format!(
                    "\"{}\": a board is \"charuco\" or \"chessboard\"",
                    crate::io::error::excerpt(other, 40)
                ),
            ));
        }
        None => file.marker_size.is_some(),
    };
    if charuco {
        let Some(marker_size) = file.marker_size else {
            return Err(invalid(
                "marker_size",
                "missing: a ChArUco board needs the side of its markers (metres)".into(),
            ));
        };
        let Some(dictionary) = &file.dictionary else {
            return Err(invalid(
                "dictionary",
                "missing: a ChArUco board needs its ArUco dictionary (e.g. \"DICT_4X4_50\")".into(),
            ));
        };
        CharucoSpec::new(
            file.squares_x,
            file.squares_y,
            file.square_size,
            marker_size,
            dictionary,
            file.legacy_pattern.unwrap_or(false),
        )
        .map(BoardSpec::Charuco)
        .map_err(from_board_error)
    } else {
        for (field, given) in [
            ("marker_size", file.marker_size.is_some()),
            ("dictionary", file.dictionary.is_some()),
            ("legacy_pattern", file.legacy_pattern.is_some()),
        ] {
            if given {
                return Err(invalid(
                    field,
                    "a chessboard has no markers (for a ChArUco board set \"type\": \"charuco\")"
                        .into(),
                ));
            }
        }
        chessboard(file.squares_x, file.squares_y, file.square_size)
            .map(BoardSpec::Chessboard)
            .map_err(from_board_error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::Board;

    fn read(text: &str) -> Result<BoardSpec, IoError> {
        board_from_json_str(text, Path::new("board.json"))
    }

    #[test]
    fn the_contract_examples_read() {
        let charuco = read(
            r#"{"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04,
                "marker_size": 0.03, "dictionary": "DICT_4X4_50", "legacy_pattern": false}"#,
        )
        .unwrap();
        let BoardSpec::Charuco(spec) = &charuco else {
            panic!("{charuco:?}")
        };
        assert_eq!(
            (spec.squares_x, spec.squares_y, spec.marker_size_m),
            (7, 5, 0.03)
        );
        assert_eq!(spec.dictionary.name(), "DICT_4X4_50");
        assert_eq!(
            charuco.corner_grid(),
            Board {
                rows: 4,
                cols: 6,
                square: 0.04
            }
        );
        // No type, a marker size: ChArUco.
        let untyped = read(
            r#"{"squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4X4_50"}"#,
        )
        .unwrap();
        assert_eq!(untyped, charuco);
        let chess = read(
            r#"{"type": "chessboard", "squares_x": 10, "squares_y": 7, "square_size": 0.025}"#,
        )
        .unwrap();
        assert_eq!(
            chess,
            BoardSpec::Chessboard(Board {
                rows: 6,
                cols: 9,
                square: 0.025
            })
        );
        let untyped = read(r#"{"squares_x": 10, "squares_y": 7, "square_size": 0.025}"#).unwrap();
        assert_eq!(untyped, chess);
    }

    #[test]
    fn errors_name_the_file_the_key_and_the_value() {
        let e = read(r#"{"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4x4_50"}"#)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("board.json: dictionary: ")
                && e.contains("\"DICT_4x4_50\"")
                && e.contains(
                    "known: DICT_4X4_50, DICT_4X4_100, DICT_4X4_250, DICT_4X4_1000, DICT_5X5_50"
                ),
            "{e}"
        );
        let e =
            read(r#"{"squares_x": 7, "squares_y": 5, "square_size": 0.04, "markersize": 0.03}"#)
                .unwrap_err();
        assert!(
            matches!(&e, IoError::Json { field, .. } if field == "markersize"),
            "{e}"
        );
        assert!(e.to_string().contains("unknown field `markersize`"), "{e}");
        let e = read(r#"{"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04, "dictionary": "DICT_4X4_50"}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("marker_size: missing"), "{e}");
        let e = read(r#"{"type": "circles", "squares_x": 7, "squares_y": 5, "square_size": 0.04}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("type: \"circles\""), "{e}");
        let e =
            read(r#"{"type": "chessboard", "squares_x": 7, "squares_y": 2, "square_size": 0.04}"#)
                .unwrap_err()
                .to_string();
        assert!(
            e.contains("squares_y: squares_y = 2: 3 to 1000 squares"),
            "{e}"
        );
        let e = read(r#"{"type": "chessboard", "squares_x": 7, "squares_y": 5, "square_size": 0.04, "dictionary": "DICT_4X4_50"}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("dictionary: a chessboard has no markers"), "{e}");
        let e = read(r#"{"type": "charuco", "squares_x": 8, "squares_y": 6, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_4X4_50", "legacy_pattern": true}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("legacy_pattern: legacy_pattern = true"), "{e}");
        let e = read(r#"{"squares_x": 7, "squares_y": 5.5, "square_size": 0.04}"#).unwrap_err();
        assert!(
            matches!(&e, IoError::Json { field, line: 1, .. } if field == "squares_y"),
            "{e}"
        );
    }
}
