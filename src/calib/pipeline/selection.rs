//! Which board views to use when there are more than a calibration needs (`--max-frames`):
//! the ones that spread over the image and over board poses, chosen greedily.
//!
//! Each image of a board is described by five numbers from its corners alone (no camera model):
//! where the board is in the image (the corners' centroid over the image size, two numbers), how
//! large it appears (a quarter of the log of a square's area in the image, from the affine map
//! board → image fitted to the corners: halving the distance adds 0.35), and how it
//! is turned (the affine map's foreshortening 1 − σ₂/σ₁ along its direction, as a vector in the
//! doubled angle, two numbers: a board turned by θ and by θ + 180° look alike). A frame of a rig
//! puts its cameras' descriptions side by side (a camera that did not see the board counts as far
//! from every other image). The first view taken is the one with the most corners; then, again
//! and again, the view farthest from all those taken (the largest smallest distance, plus a
//! small bonus per camera that saw it, so frames that link cameras are preferred), until the cap.
//! Farthest-point selection covers the image and the poses evenly, and keeps the extremes (the
//! most tilted, nearest, farthest boards) that pin down distortion and focal length.

use nalgebra::{Matrix2, Point2, Vector2};

use crate::base::Board;

/// Distance bonus of a frame per camera that saw it (in units of the description).
const LINK_BONUS: f64 = 0.25;

/// The description of one image of `board` (`corners`: (corner index, pixel)) in a
/// `width` × `height` image; `None` with fewer than 3 corners or corners on one line.
pub fn describe_image(
    board: &Board,
    corners: &[(usize, Point2<f64>)],
    width: u32,
    height: u32,
) -> Option<[f64; 5]> {
    if corners.len() < 3 {
        return None;
    }
    let n = corners.len() as f64;
    let (mut board_mean, mut pixel_mean) = (Vector2::zeros(), Vector2::zeros());
    for (i, p) in corners {
        let q = board.point_in_board(*i);
        board_mean += Vector2::new(q.x, q.y) / n;
        pixel_mean += p.coords / n;
    }
    // Least-squares affine map A: pixel − mean ≈ A (board − mean).
    let (mut bb, mut pb) = (Matrix2::zeros(), Matrix2::zeros());
    for (i, p) in corners {
        let q = board.point_in_board(*i);
        let b = Vector2::new(q.x, q.y) - board_mean;
        bb += b * b.transpose();
        pb += (p.coords - pixel_mean) * b.transpose();
    }
    let a = pb * bb.try_inverse()?;
    let svd = a.svd(true, false);
    let (s1, s2) = (svd.singular_values[0], svd.singular_values[1]);
    if !(s2 > 0.0 && s1.is_finite()) {
        return None;
    }
    let u = svd.u?;
    // The direction of the strongest foreshortening (the smaller singular value's image axis).
    let minor = u.column(1);
    let angle = 2.0 * minor.y.atan2(minor.x);
    let foreshortening = 1.0 - s2 / s1;
    Some([
        pixel_mean.x / f64::from(width),
        pixel_mean.y / f64::from(height),
        0.25 * (s1 * s2 * board.square * board.square).max(1e-300).ln(),
        foreshortening * angle.cos(),
        foreshortening * angle.sin(),
    ])
}

/// Up to `cap` of `frames` (each a description per camera, `None` where that camera did not see
/// the board usefully, and its corner count), spread as the module documentation says; the
/// chosen indices in increasing order. All of them when there are no more than `cap`.
pub fn spread(frames: &[(Vec<Option<[f64; 5]>>, usize)], cap: usize) -> Vec<usize> {
    let usable: Vec<usize> = (0..frames.len())
        .filter(|&f| frames[f].0.iter().any(Option::is_some))
        .collect();
    if usable.len() <= cap {
        return usable;
    }
    let distance = |a: usize, b: usize| {
        frames[a]
            .0
            .iter()
            .zip(&frames[b].0)
            .map(|(x, y)| match (x, y) {
                (Some(x), Some(y)) => x.iter().zip(y).map(|(p, q)| (p - q).powi(2)).sum(),
                (None, None) => 0.0,
                // Seen by one camera and not the other: as far as a board across the image.
                _ => 1.0,
            })
            .sum::<f64>()
            .sqrt()
    };
    let seen = |f: usize| frames[f].0.iter().filter(|d| d.is_some()).count() as f64;
    let first = *usable
        .iter()
        .max_by_key(|&&f| {
            (
                frames[f].0.iter().filter(|d| d.is_some()).count(),
                frames[f].1,
            )
        })
        .unwrap_or(&usable[0]);
    let mut chosen = vec![first];
    let mut nearest: Vec<f64> = usable.iter().map(|&f| distance(f, first)).collect();
    while chosen.len() < cap {
        let Some((i, _)) = usable
            .iter()
            .enumerate()
            .filter(|(_, f)| !chosen.contains(f))
            .map(|(i, &f)| (i, nearest[i] + LINK_BONUS * seen(f)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            break;
        };
        let f = usable[i];
        chosen.push(f);
        for (j, &g) in usable.iter().enumerate() {
            nearest[j] = nearest[j].min(distance(g, f));
        }
    }
    chosen.sort_unstable();
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOARD: Board = Board {
        rows: 5,
        cols: 7,
        square: 0.03,
    };

    /// The board's corners under the affine map `a` about the image point `centre`.
    fn image(a: Matrix2<f64>, centre: [f64; 2]) -> Vec<(usize, Point2<f64>)> {
        (0..BOARD.corners())
            .map(|i| {
                let q = BOARD.point_in_board(i) - BOARD.centre_in_board();
                let p = a * Vector2::new(q.x, q.y);
                (i, Point2::new(centre[0] + p.x, centre[1] + p.y))
            })
            .collect()
    }

    #[test]
    fn descriptions_follow_position_size_and_turn() {
        let face_on = describe_image(
            &BOARD,
            &image(Matrix2::identity() * 4000.0, [320.0, 240.0]),
            640,
            480,
        )
        .unwrap();
        assert!((face_on[0] - 0.5).abs() < 1e-12 && (face_on[1] - 0.5).abs() < 1e-12);
        assert!(
            face_on[3].abs() < 1e-12 && face_on[4].abs() < 1e-12,
            "{face_on:?}"
        );
        // Foreshortened by half along x: the strongest foreshortening lies along x (angle 0).
        let turned = describe_image(
            &BOARD,
            &image(Matrix2::new(2000.0, 0.0, 0.0, 4000.0), [100.0, 400.0]),
            640,
            480,
        )
        .unwrap();
        assert!(
            (turned[3] - 0.5).abs() < 1e-9 && turned[4].abs() < 1e-9,
            "{turned:?}"
        );
        assert!(turned[2] < face_on[2]);
        // Corners on one line describe nothing.
        let line: Vec<_> = (0..7)
            .map(|i| (i, Point2::new(10.0 * i as f64, 5.0)))
            .collect();
        assert!(describe_image(&BOARD, &line, 640, 480).is_none());
    }

    #[test]
    fn the_spread_keeps_the_extremes_and_drops_repeats() {
        // Ten copies of one pose and three distinct poses: a cap of four takes one copy and the
        // three others.
        let same = describe_image(
            &BOARD,
            &image(Matrix2::identity() * 4000.0, [320.0, 240.0]),
            640,
            480,
        );
        let mut frames: Vec<(Vec<Option<[f64; 5]>>, usize)> = vec![(vec![same], 35); 10];
        for (a, c) in [
            (Matrix2::new(2000.0, 0.0, 0.0, 4000.0), [100.0, 100.0]),
            (Matrix2::new(4000.0, 0.0, 0.0, 1500.0), [540.0, 380.0]),
            (Matrix2::identity() * 1500.0, [540.0, 100.0]),
        ] {
            frames.push((vec![describe_image(&BOARD, &image(a, c), 640, 480)], 35));
        }
        let chosen = spread(&frames, 4);
        assert_eq!(chosen.len(), 4);
        assert_eq!(chosen.iter().filter(|&&f| f < 10).count(), 1, "{chosen:?}");
        assert!(chosen.ends_with(&[10, 11, 12]), "{chosen:?}");
        // No cap reached: every usable frame, in order; frames nobody saw are never chosen.
        frames.push((vec![None], 0));
        assert_eq!(spread(&frames, 100), (0..13).collect::<Vec<_>>());
    }
}
