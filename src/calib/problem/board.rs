//! The rigid fit of a board model (the corner grid of a [`Board`](crate::base::Board)) to
//! measured 3-D corners (Kabsch).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// The board's corner grid, at home in [`crate::base`] (render and detect use it too).
pub use crate::base::Board;

/// The rigid motion `master_from_board` that best maps board-frame points onto measured points
/// (least squares, Kabsch/Umeyama without scale), with the RMS of the remaining distances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidFit {
    /// X_master = R·X_board + t.
    pub master_from_board: Isometry3<f64>,
    /// √(Σ|R·Pᵢ + t − Xᵢ|² / N), metres.
    pub rms: f64,
    /// Σ|R·Pᵢ + t − Xᵢ|², m².
    pub sum_squares: f64,
}

/// Kabsch fit of `model` (board frame) onto `measured` (master frame), pairs in order. `None` with
/// fewer than 3 pairs or when the model points are collinear (the rotation is undetermined).
pub fn fit_rigid(model: &[Point3<f64>], measured: &[Point3<f64>]) -> Option<RigidFit> {
    let count = model.len();
    if count < 3 || measured.len() != count {
        return None;
    }
    let inv = 1.0 / count as f64;
    let mean_model = model.iter().fold(Vector3::zeros(), |a, p| a + p.coords) * inv;
    let mean_measured = measured.iter().fold(Vector3::zeros(), |a, p| a + p.coords) * inv;
    // H = Σ (Xᵢ − X̄)(Pᵢ − P̄)ᵀ; R = U diag(1, 1, det(UVᵀ)) Vᵀ from H = U S Vᵀ.
    let mut h = Matrix3::zeros();
    for (p, x) in model.iter().zip(measured) {
        h += (x.coords - mean_measured) * (p.coords - mean_model).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut singular = svd.singular_values;
    // Collinear model points leave two singular values at zero.
    singular.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if !(singular[1] > 1e-12 * singular[0]) {
        return None;
    }
    let sign = (u * v_t).determinant().signum();
    let rotation = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, sign)) * v_t;
    let rotation = Rotation3::from_matrix_unchecked(rotation);
    let translation = mean_measured - rotation * mean_model;
    let master_from_board = Isometry3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_rotation_matrix(&rotation),
    );
    let sum_squares: f64 = model
        .iter()
        .zip(measured)
        .map(|(p, x)| (master_from_board * p - x).norm_squared())
        .sum();
    Some(RigidFit {
        master_from_board,
        rms: (sum_squares * inv).sqrt(),
        sum_squares,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kabsch_recovers_a_known_motion() {
        let board = Board {
            rows: 4,
            cols: 5,
            square: 0.03,
        };
        let model: Vec<_> = (0..board.corners())
            .map(|i| board.point_in_board(i))
            .collect();
        let motion = Isometry3::new(Vector3::new(0.1, -0.2, 0.9), Vector3::new(0.3, -2.8, 0.5));
        let measured: Vec<_> = model.iter().map(|p| motion * p).collect();
        let fit = fit_rigid(&model, &measured).unwrap();
        assert!(fit.rms < 1e-14, "{}", fit.rms);
        assert!((fit.master_from_board.to_homogeneous() - motion.to_homogeneous()).norm() < 1e-13);
        // The mirror image of a non-planar set is no rotation of it: the fit stays proper
        // (det +1) and leaves a residual. (A planar set's mirror image is a rotation of it.)
        let mut solid = model.clone();
        solid.push(Point3::new(0.05, 0.05, 0.1));
        let mirrored: Vec<_> = solid
            .iter()
            .map(|p| motion * Point3::new(-p.x, p.y, p.z))
            .collect();
        let fit = fit_rigid(&solid, &mirrored).unwrap();
        assert!(
            fit.master_from_board
                .rotation
                .to_rotation_matrix()
                .matrix()
                .determinant()
                > 0.0
        );
        assert!(fit.rms > 1e-3);
        // Collinear points leave the rotation undetermined.
        let line: Vec<_> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(fit_rigid(&line, &line).is_none());
    }
}
