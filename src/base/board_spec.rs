//! The calibration boards flatport reads, detects, renders and calibrates with: a plain chessboard or a ChArUco
//! board (a chessboard with ArUco markers in its white squares), as a `BOARD.json` describes
//! them (docs/DESIGN.md §3c; the file is read by [`crate::io::read_board`]).
//!
//! **Frames and numbering.** A board has `squares_x × squares_y` squares of side `square_size`
//! (metres); its corner grid for the calibration is the inner corners, [`Board`] with
//! `rows = squares_y − 1`, `cols = squares_x − 1`: corner `r·cols + c` at `(c·s, r·s, 0)`, row 0
//! at the board's top edge. For a ChArUco board this is OpenCV's numbering (≥ 4.6): ChArUco
//! corner id = `row·(squares_x − 1) + col`, at OpenCV's object point minus `(s, s, 0)`.
//!
//! **ChArUco layout (OpenCV ≥ 4.6).** The top-left square is black; the white squares, those with
//! `a + b` odd (square column a, row b), carry the markers, numbered 0, 1, … row-major. A marker
//! of side `marker_size` sits centred in its square: `bits + 2` cells across (the dictionary's
//! bits and a black border of one cell), cell `(cx, cy)` of the bits black when bit
//! `cy·bits + cx` of the dictionary's code is 1 (calib-targets' codes, the same bits OpenCV draws;
//! tests/charuco.rs holds the pattern to OpenCV's `generateImage` pixel for pixel).

use calib_targets::aruco::{Dictionary, builtins};
use calib_targets::charuco::{CharucoBoardSpec, MarkerLayout};

use super::board::Board;
use super::text::excerpt;

/// A board that a `BOARD.json` describes.
#[derive(Debug, Clone, PartialEq)]
pub enum BoardSpec {
    /// A plain chessboard: its inner corner grid (whole boards only; corner 0 by the rules of
    /// [`crate::detect`]).
    Chessboard(Board),
    /// A ChArUco board: every corner carries its id, so partial views are usable.
    Charuco(CharucoSpec),
}

impl BoardSpec {
    /// The calibration's corner grid: the inner corners, row-major from the board's top edge.
    pub fn corner_grid(&self) -> Board {
        match self {
            BoardSpec::Chessboard(board) => *board,
            BoardSpec::Charuco(spec) => spec.corner_grid(),
        }
    }

    /// "chessboard" or "charuco", as the file's `type` names it.
    pub fn kind(&self) -> &'static str {
        match self {
            BoardSpec::Chessboard(_) => "chessboard",
            BoardSpec::Charuco(_) => "charuco",
        }
    }
}

/// Why a board description is not a board flatport can use. `field` is the `BOARD.json` key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoardError {
    /// A value out of range.
    #[error("{field} = {value}: {reason}")]
    Value {
        /// The key.
        field: &'static str,
        /// The value given.
        value: String,
        /// What it must be.
        reason: String,
    },
    /// A dictionary name that calib-targets does not know.
    #[error("dictionary = \"{name}\": unknown dictionary; known: {known}")]
    UnknownDictionary {
        /// The name given.
        name: String,
        /// The known names, comma-separated.
        known: String,
    },
    /// OpenCV's pre-4.6 layout on a board with an even number of rows, which calib-targets does
    /// not read.
    #[error(
        "legacy_pattern = true: with squares_y = {squares_y} (even) OpenCV's pre-4.6 layout starts with a white square \
         and numbers its markers differently, and the detector (calib-targets) reads only the current layout; \
         print the board with OpenCV >= 4.6 (or with setLegacyPattern(false)) and set \"legacy_pattern\": false"
    )]
    LegacyPattern {
        /// The board's rows of squares.
        squares_y: usize,
    },
}

/// Smallest number of squares along either side: the calibration needs at least 2 × 2 inner
/// corners.
pub const MIN_SQUARES: usize = 3;

/// The names of the dictionaries calib-targets knows (OpenCV's names), in natural order
/// (`DICT_4X4_50` before `DICT_4X4_100`).
pub fn dictionary_names() -> Vec<&'static str> {
    let mut names = builtins::BUILTIN_DICTIONARY_NAMES.to_vec();
    let key = |name: &&'static str| {
        let stem = name.trim_end_matches(|c: char| c.is_ascii_digit());
        (stem, name[stem.len()..].parse::<u32>().unwrap_or(0))
    };
    names.sort_by_key(key);
    names
}

/// A ChArUco board (OpenCV ≥ 4.6 layout, see the module's documentation).
#[derive(Debug, Clone, Copy)]
pub struct CharucoSpec {
    /// Squares across (OpenCV's `size.width`).
    pub squares_x: usize,
    /// Squares down (OpenCV's `size.height`).
    pub squares_y: usize,
    /// Side of a square, metres.
    pub square_size_m: f64,
    /// Side of a marker (its black border included), metres.
    pub marker_size_m: f64,
    /// The ArUco dictionary of the markers.
    pub dictionary: Dictionary,
}

impl PartialEq for CharucoSpec {
    fn eq(&self, other: &Self) -> bool {
        self.squares_x == other.squares_x
            && self.squares_y == other.squares_y
            && self.square_size_m == other.square_size_m
            && self.marker_size_m == other.marker_size_m
            && self.dictionary.name() == other.dictionary.name()
    }
}

/// A chessboard of `squares_x × squares_y` squares of side `square_size_m`, checked.
pub fn chessboard(
    squares_x: usize,
    squares_y: usize,
    square_size_m: f64,
) -> Result<Board, BoardError> {
    check_squares(squares_x, squares_y, square_size_m)?;
    Ok(Board {
        rows: squares_y - 1,
        cols: squares_x - 1,
        square: square_size_m,
    })
}

fn check_squares(squares_x: usize, squares_y: usize, square_size_m: f64) -> Result<(), BoardError> {
    for (field, n) in [("squares_x", squares_x), ("squares_y", squares_y)] {
        if !(MIN_SQUARES..=1000).contains(&n) {
            return Err(BoardError::Value {
                field,
                value: n.to_string(),
                reason: format!(
                    "{MIN_SQUARES} to 1000 squares (the calibration needs at least 2 × 2 inner corners)"
                ),
            });
        }
    }
    if !(square_size_m > 0.0 && square_size_m.is_finite()) {
        return Err(BoardError::Value {
            field: "square_size",
            value: square_size_m.to_string(),
            reason: "a positive length in metres".into(),
        });
    }
    Ok(())
}

impl CharucoSpec {
    /// A checked ChArUco board: squares as [`chessboard`]; `0 < marker_size_m < square_size_m`;
    /// `dictionary` one of [`dictionary_names`] (OpenCV's names, e.g. `DICT_4X4_50`) with a code
    /// for every marker; `legacy_pattern` (OpenCV's pre-4.6 layout) only where it equals the
    /// current one (an odd number of rows), else [`BoardError::LegacyPattern`].
    pub fn new(
        squares_x: usize,
        squares_y: usize,
        square_size_m: f64,
        marker_size_m: f64,
        dictionary: &str,
        legacy_pattern: bool,
    ) -> Result<Self, BoardError> {
        check_squares(squares_x, squares_y, square_size_m)?;
        if !(marker_size_m > 0.0 && marker_size_m < square_size_m) {
            return Err(BoardError::Value {
                field: "marker_size",
                value: marker_size_m.to_string(),
                reason: format!(
                    "a positive length in metres below the square_size ({square_size_m})"
                ),
            });
        }
        let dictionary = builtins::builtin_dictionary(dictionary).ok_or_else(|| {
            BoardError::UnknownDictionary {
                name: excerpt(dictionary, 40),
                known: dictionary_names().join(", "),
            }
        })?;
        // OpenCV's setLegacyPattern: "white box in the upper left corner if there is an even
        // row count of chessboard boxes, otherwise it starts with a black box" — the same board
        // as today's when the rows are odd.
        if legacy_pattern && squares_y.is_multiple_of(2) {
            return Err(BoardError::LegacyPattern { squares_y });
        }
        let spec = Self {
            squares_x,
            squares_y,
            square_size_m,
            marker_size_m,
            dictionary,
        };
        let (needed, available) = (spec.marker_count(), dictionary.codes().len());
        if needed > available {
            return Err(BoardError::Value {
                field: "dictionary",
                value: format!("\"{}\"", dictionary.name()),
                reason: format!(
                    "the board has {needed} markers and the dictionary {available} codes: take a larger dictionary"
                ),
            });
        }
        Ok(spec)
    }

    /// The inner corners: `Board { rows: squares_y − 1, cols: squares_x − 1, square }`; corner
    /// index = ChArUco corner id.
    pub fn corner_grid(&self) -> Board {
        Board {
            rows: self.squares_y - 1,
            cols: self.squares_x - 1,
            square: self.square_size_m,
        }
    }

    /// Number of markers: the white squares, ⌊squares_x·squares_y / 2⌋.
    pub fn marker_count(&self) -> usize {
        self.squares_x * self.squares_y / 2
    }

    /// Bits per side of a marker, without its border.
    pub fn marker_bits(&self) -> usize {
        self.dictionary.marker_size()
    }

    /// The marker in square (a, b) (column a from the left, row b from the top), `None` for a
    /// black square or one outside the board.
    pub fn marker_at_square(&self, a: usize, b: usize) -> Option<usize> {
        if a >= self.squares_x || b >= self.squares_y || (a + b).is_multiple_of(2) {
            return None;
        }
        // White squares before row b: ⌊squares_x / 2⌋ or ⌈squares_x / 2⌉ per row, alternately
        // (row b has its first white square at column (b + 1) mod 2).
        let before: usize = (0..b)
            .map(|row| (self.squares_x + row % 2) / 2)
            .sum::<usize>();
        Some(before + a / 2)
    }

    /// Whether cell (cx, cy) of marker `id` is black: cells 0 … bits + 1 across and down, the
    /// outer ring the black border, inside it bit `(cy − 1)·bits + (cx − 1)` of the code.
    /// `false` for an id or cell out of range.
    pub fn marker_cell_is_black(&self, id: usize, cx: usize, cy: usize) -> bool {
        let bits = self.marker_bits();
        if cx > bits + 1 || cy > bits + 1 {
            return false;
        }
        let Some(&code) = self.dictionary.codes().get(id) else {
            return false;
        };
        if cx == 0 || cy == 0 || cx == bits + 1 || cy == bits + 1 {
            return true;
        }
        (code >> ((cy - 1) * bits + (cx - 1))) & 1 == 1
    }

    /// calib-targets' description of the board (its lengths in metres, OpenCV's layout).
    pub fn to_calib_targets(&self) -> CharucoBoardSpec {
        CharucoBoardSpec::new(
            self.squares_y as u32,
            self.squares_x as u32,
            self.square_size_m as f32,
            (self.marker_size_m / self.square_size_m) as f32,
            self.dictionary,
        )
        .with_marker_layout(MarkerLayout::OpenCvCharuco)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(sx: usize, sy: usize) -> CharucoSpec {
        CharucoSpec::new(sx, sy, 0.04, 0.03, "DICT_4X4_50", false).unwrap()
    }

    #[test]
    fn markers_are_numbered_row_major_over_the_white_squares() {
        // 7 × 5: row 0 has white squares at columns 1, 3, 5 (ids 0, 1, 2), row 1 at 0, 2, 4, 6
        // (ids 3 … 6), as OpenCV numbers them (its docs' 5 × 7 example board).
        let s = spec(7, 5);
        assert_eq!(s.marker_count(), 17);
        assert_eq!(s.marker_at_square(0, 0), None);
        assert_eq!(s.marker_at_square(1, 0), Some(0));
        assert_eq!(s.marker_at_square(5, 0), Some(2));
        assert_eq!(s.marker_at_square(0, 1), Some(3));
        assert_eq!(s.marker_at_square(6, 1), Some(6));
        assert_eq!(s.marker_at_square(5, 4), Some(16));
        assert_eq!(s.marker_at_square(7, 0), None);
        // Every white square once, in order.
        let ids: Vec<usize> = (0..5)
            .flat_map(|b| (0..7).map(move |a| (a, b)))
            .filter_map(|(a, b)| s.marker_at_square(a, b))
            .collect();
        assert_eq!(ids, (0..17).collect::<Vec<_>>());
        let s = spec(6, 4);
        let ids: Vec<usize> = (0..4)
            .flat_map(|b| (0..6).map(move |a| (a, b)))
            .filter_map(|(a, b)| s.marker_at_square(a, b))
            .collect();
        assert_eq!(ids, (0..12).collect::<Vec<_>>());
    }

    #[test]
    fn the_corner_grid_is_the_inner_corners() {
        let s = spec(7, 5);
        assert_eq!(
            s.corner_grid(),
            Board {
                rows: 4,
                cols: 6,
                square: 0.04
            }
        );
        assert_eq!(BoardSpec::Charuco(s).corner_grid().corners(), 24);
    }

    #[test]
    fn bad_boards_are_refused_with_the_field_and_what_to_do() {
        let e = CharucoSpec::new(7, 5, 0.04, 0.03, "DICT_4X4_5O", false).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("DICT_4X4_5O") && text.contains("DICT_4X4_50, DICT_4X4_100"),
            "{text}"
        );
        let e = CharucoSpec::new(7, 5, 0.04, 0.04, "DICT_4X4_50", false).unwrap_err();
        assert!(matches!(
            e,
            BoardError::Value {
                field: "marker_size",
                ..
            }
        ));
        let e = CharucoSpec::new(12, 10, 0.04, 0.03, "DICT_4X4_50", false).unwrap_err();
        assert!(e.to_string().contains("60 markers"), "{e}");
        let e = CharucoSpec::new(7, 6, 0.04, 0.03, "DICT_4X4_50", true).unwrap_err();
        assert_eq!(e, BoardError::LegacyPattern { squares_y: 6 });
        assert!(e.to_string().contains("\"legacy_pattern\": false"));
        // Odd rows: the legacy layout is today's.
        assert_eq!(
            CharucoSpec::new(7, 5, 0.04, 0.03, "DICT_4X4_50", true).unwrap(),
            spec(7, 5)
        );
        assert!(chessboard(2, 5, 0.04).is_err());
        assert!(chessboard(7, 5, -0.04).is_err());
        assert_eq!(
            chessboard(10, 7, 0.04).unwrap(),
            Board {
                rows: 6,
                cols: 9,
                square: 0.04
            }
        );
    }

    #[test]
    fn marker_cells_have_a_black_border_and_the_code_inside() {
        let s = spec(7, 5);
        let bits = s.marker_bits();
        assert_eq!(bits, 4);
        for k in 0..bits + 2 {
            assert!(s.marker_cell_is_black(0, k, 0) && s.marker_cell_is_black(0, 0, k));
            assert!(s.marker_cell_is_black(0, k, bits + 1));
        }
        let code = s.dictionary.codes()[0];
        let inner: u64 = (0..bits * bits)
            .filter(|&i| s.marker_cell_is_black(0, i % bits + 1, i / bits + 1))
            .map(|i| 1u64 << i)
            .sum();
        assert_eq!(inner, code);
    }
}
