//! What the cameras look at: a planar chessboard, or a known 3-D target (several boards, a cube,
//! a rod: any layout of points).

use nalgebra::Point3;

use crate::base::Board;

/// A calibration target: its corners in its own frame, metres.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// A planar chessboard: rows × cols inner corners on z = 0, row-major.
    Board(Board),
    /// Any layout of points, in file order.
    Points(Vec<Point3<f64>>),
}

impl Target {
    /// Number of corners.
    pub fn len(&self) -> usize {
        match self {
            Self::Board(board) => board.corners(),
            Self::Points(points) => points.len(),
        }
    }

    /// Whether the target has no corner.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Corner `i` in the target frame.
    ///
    /// # Panics
    /// When `i` is out of range.
    pub fn point(&self, i: usize) -> Point3<f64> {
        match self {
            Self::Board(board) => board.point_in_board(i),
            Self::Points(points) => points[i],
        }
    }

    /// The board, for a planar chessboard.
    pub fn board(&self) -> Option<&Board> {
        match self {
            Self::Board(board) => Some(board),
            Self::Points(_) => None,
        }
    }

    /// Whether every corner lies on one plane (within 1e-9 of the target's extent): a planar
    /// target needs several views, a non-planar one fixes a pose from one.
    pub fn is_planar(&self) -> bool {
        match self {
            Self::Board(_) => true,
            Self::Points(points) => planar(points),
        }
    }
}

/// Whether `points` lie on one plane: the smallest singular value of their centred scatter is
/// at most 1e-9 of the largest.
fn planar(points: &[Point3<f64>]) -> bool {
    if points.len() < 4 {
        return true;
    }
    let centre = points
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / points.len() as f64;
    let scatter = points.iter().fold(nalgebra::Matrix3::zeros(), |a, p| {
        let d = p.coords - centre;
        a + d * d.transpose()
    });
    let values = scatter.symmetric_eigenvalues();
    values.min() <= 1e-18 * values.max()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cube_is_not_planar_and_a_board_is() {
        let board = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        assert!(board.is_planar());
        assert_eq!(board.len(), 54);
        let square: Vec<Point3<f64>> = (0..9)
            .map(|i| Point3::new((i % 3) as f64 * 0.1, (i / 3) as f64 * 0.1, 0.0))
            .collect();
        assert!(Target::Points(square.clone()).is_planar());
        let mut cube = square;
        cube.push(Point3::new(0.0, 0.0, 0.1));
        assert!(!Target::Points(cube).is_planar());
    }
}
