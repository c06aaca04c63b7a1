//! The planar calibration board's corner grid: `rows × cols` inner corners `square` metres apart,
//! in the board frame. What a `BOARD.json` says about the board's look (chessboard or ChArUco,
//! markers, dictionary) is [`super::board_spec`].

use nalgebra::Point3;

/// A chessboard of `rows` × `cols` inner corners spaced `square` metres apart.
///
/// Corner `i = r·cols + c` (row-major, as OpenCV `findChessboardCorners` orders them) lies at
/// (c·square, r·square, 0) in the board frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Board {
    /// Inner corners per column (number of rows).
    pub rows: usize,
    /// Inner corners per row (number of columns).
    pub cols: usize,
    /// Distance between adjacent corners, metres.
    pub square: f64,
}

impl Board {
    /// Number of corners, rows × cols.
    pub fn corners(&self) -> usize {
        self.rows * self.cols
    }

    /// Corner `i` in the board frame: (c·s, r·s, 0) with r = i / cols, c = i % cols.
    pub fn point_in_board(&self, i: usize) -> Point3<f64> {
        let (r, c) = (i / self.cols, i % self.cols);
        Point3::new(c as f64 * self.square, r as f64 * self.square, 0.0)
    }

    /// (row, column) of corner `i`.
    pub fn grid_position(&self, i: usize) -> (usize, usize) {
        (i / self.cols, i % self.cols)
    }

    /// Centre of the corner grid in the board frame.
    pub fn centre_in_board(&self) -> Point3<f64> {
        Point3::new(
            (self.cols - 1) as f64 * self.square / 2.0,
            (self.rows - 1) as f64 * self.square / 2.0,
            0.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_are_row_major() {
        let board = Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        };
        assert_eq!(board.corners(), 54);
        assert_eq!(board.point_in_board(10), Point3::new(0.04, 0.04, 0.0));
        assert_eq!(board.grid_position(53), (5, 8));
        assert_eq!(board.centre_in_board(), Point3::new(0.16, 0.1, 0.0));
    }
}
