//! The start of every calibration: each view's target pose from the camera that saw most of it,
//! by the pinhole model alone (a homography for a planar target, the direct linear transform for
//! a 3-D one); the pipeline then fits the poses through the start port.

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3,
};

use super::bundle::{Bundle, State, fit_briefly};
use crate::calib::error::CalibError;
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::calib::solvers::lm::LeastSquares;
pub use crate::model::snell::bent_into_water;
use crate::model::{Interface, Ports, Rig};

/// Each view's target pose (master frame) from the camera that saw most of it: the pinhole pose of
/// its undistorted corners (homography for a planar target, DLT for a 3-D one).
pub fn initial_poses(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
) -> Result<Vec<Isometry3<f64>>, CalibError> {
    view_poses(rig, target, views, false)
}

/// As [`initial_poses`], each corner's direction first bent into the water at its camera's port
/// ([`bent_into_water`], the port's axis in that camera's frame through the rig's extrinsics):
/// the start of a rig whose ports are calibrated, where the pixels' own directions place the
/// apparent board.
pub fn water_poses(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
) -> Result<Vec<Isometry3<f64>>, CalibError> {
    view_poses(rig, target, views, true)
}

/// Levenberg–Marquardt steps of the fits of the board poses alone.
pub(super) const POSE_ITERATIONS: usize = 30;

/// `state` with the target pose of every view whose corners it cannot project placed again by
/// [`water_poses`] through the state's own ports, then every pose fitted briefly, with how many
/// views were placed (the maximum likelihood's starts and the axis search's cells use it):
/// `pose_only` is the poses-only bundle of `views` (cameras of `rig`, target `target`). The
/// state comes back as it was when every view is defined, or when placing them again does not
/// make the cost defined.
pub(super) fn place_undefined_views(
    pose_only: &Bundle,
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    state: State,
) -> (State, usize) {
    let undefined = match pose_only.undefined_views(&state) {
        Some(views) if !views.is_empty() => views,
        _ => return (state, 0),
    };
    let Some(Ok(in_water)) = state.rig(rig).map(|rig| water_poses(&rig, target, views)) else {
        return (state, 0);
    };
    let mut placed = state.clone();
    for &v in &undefined {
        placed.poses[v] = in_water[v];
    }
    if pose_only.cost(&placed).is_none_or(|c| !c.is_finite()) {
        return (state, 0);
    }
    (
        fit_briefly(pose_only, placed, POSE_ITERATIONS),
        undefined.len(),
    )
}

fn view_poses(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    in_water: bool,
) -> Result<Vec<Isometry3<f64>>, CalibError> {
    views
        .iter()
        .enumerate()
        .map(|(v, view)| {
            let (k, corners) = view.cameras.iter().max_by_key(|(_, c)| c.len()).expect("a resolved view has a camera");
            let camera = &rig.cameras()[*k];
            let axis = in_water.then(|| port_axis(rig, *k, &camera.cam_from_master.rotation));
            let mut object = Vec::with_capacity(corners.len());
            let mut image = Vec::with_capacity(corners.len());
            for (i, pixel) in corners {
                let Some(x) = corner_direction(rig, *k, pixel, axis.as_ref()) else { continue };
                object.push(target.point(*i));
                image.push(x);
            }
            let cam_from_target = pinhole_pose(&object, &image).ok_or_else(|| CalibError::UnusableView {
                view: v,
                reason: format!("no pose of the target fits camera '{}''s corners (are they in target order?)", camera.name),
            })?;
            Ok(camera.cam_from_master.inverse() * cam_from_target)
        })
        .collect()
}

/// Camera `k`'s port: the shared one, or its own.
pub fn port_of(rig: &Rig, k: usize) -> &Interface {
    match rig.ports() {
        Ports::Shared(port) => port,
        Ports::PerCamera(ports) => &ports[k],
    }
}

/// The axis of camera `k`'s port in that camera's frame: its housing's, or the shared port's
/// (master frame) turned by the camera's `cam_from_master` rotation.
pub fn port_axis(rig: &Rig, k: usize, cam_from_master: &UnitQuaternion<f64>) -> Vector3<f64> {
    match rig.ports() {
        Ports::Shared(port) => cam_from_master * port.normal().into_inner(),
        Ports::PerCamera(ports) => ports[k].normal().into_inner(),
    }
}

/// A corner at `pixel` of camera `k` as undistorted normalised coordinates, bent into the water
/// at its port's `axis` (camera frame, [`port_axis`]) where given ([`bent_into_water`]); `None`
/// where the lens or the port gives it no direction.
pub fn corner_direction(
    rig: &Rig,
    k: usize,
    pixel: &nalgebra::Point2<f64>,
    axis: Option<&Vector3<f64>>,
) -> Option<Vector2<f64>> {
    let x = rig.cameras()[k].intrinsics.normalized_from_img(pixel)?;
    match axis {
        Some(axis) => {
            let port = port_of(rig, k);
            bent_into_water(&x, axis, port.index_air() / port.index_water())
        }
        None => Some(x),
    }
}

/// The pinhole pose cam_from_target of `object` points seen at undistorted normalised `image`
/// coordinates: a homography when the points are coplanar, the DLT otherwise. `None` when
/// degenerate.
pub fn pinhole_pose(object: &[Point3<f64>], image: &[Vector2<f64>]) -> Option<Isometry3<f64>> {
    if object.len() < 4 {
        return None;
    }
    // The points' own frame: centroid and principal axes; a plane has a vanishing third axis.
    let n = object.len() as f64;
    let centre = object.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let scatter = object.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p.coords - centre;
        a + d * d.transpose()
    });
    let eigen = scatter.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let mut axes = Matrix3::from_columns(&order.map(|i| eigen.eigenvectors.column(i).into_owned()));
    if axes.determinant() < 0.0 {
        axes.column_mut(2).neg_mut();
    }
    let scale = (eigen.eigenvalues[order[0]] / n).sqrt().max(1e-12);
    // local = axesᵀ (X − c) / scale; X = c + scale · axes · local.
    let local: Vec<Vector3<f64>> = object
        .iter()
        .map(|p| axes.transpose() * (p.coords - centre) / scale)
        .collect();
    let planar = eigen.eigenvalues[order[2]] <= 1e-12 * eigen.eigenvalues[order[0]];
    let (rotation, translation) = if planar {
        homography_pose(&local, image)?
    } else {
        dlt_pose(&local, image)?
    };
    // x ~ R_l·local + t_l, and scaling the right side by `scale` changes no image point:
    // X_cam = R_l·axesᵀ·(X − c) + scale·t_l, a rigid pose.
    let r = rotation * axes.transpose();
    let t = translation * scale - r * centre;
    Some(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    ))
}

/// Pose (R, t) of points on z = 0 of their (scaled) local frame from a homography.
fn homography_pose(
    local: &[Vector3<f64>],
    image: &[Vector2<f64>],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let mut a = DMatrix::zeros(2 * local.len(), 9);
    for (i, (p, x)) in local.iter().zip(image).enumerate() {
        let (u, v) = (x.x, x.y);
        let row = [p.x, p.y, 1.0];
        for j in 0..3 {
            a[(2 * i, j)] = row[j];
            a[(2 * i, 6 + j)] = -u * row[j];
            a[(2 * i + 1, 3 + j)] = row[j];
            a[(2 * i + 1, 6 + j)] = -v * row[j];
        }
    }
    let h = smallest_right_singular_vector(&a)?;
    let mut hm = Matrix3::from_row_slice(h.as_slice());
    let (h1, h2) = (hm.column(0).norm(), hm.column(1).norm());
    let lambda = 2.0 / (h1 + h2);
    hm *= lambda;
    if hm[(2, 2)] < 0.0 {
        hm = -hm;
    }
    let r1 = hm.column(0).into_owned();
    let r2 = hm.column(1).into_owned();
    let r = orthonormal(&Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]))?;
    Some((r, hm.column(2).into_owned()))
}

/// Pose (R, t) of non-coplanar points (local frame) by the direct linear transform.
fn dlt_pose(
    local: &[Vector3<f64>],
    image: &[Vector2<f64>],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    if local.len() < 6 {
        return None;
    }
    let mut a = DMatrix::zeros(2 * local.len(), 12);
    for (i, (p, x)) in local.iter().zip(image).enumerate() {
        let row = [p.x, p.y, p.z, 1.0];
        for j in 0..4 {
            a[(2 * i, j)] = row[j];
            a[(2 * i, 8 + j)] = -x.x * row[j];
            a[(2 * i + 1, 4 + j)] = row[j];
            a[(2 * i + 1, 8 + j)] = -x.y * row[j];
        }
    }
    let p = smallest_right_singular_vector(&a)?;
    let mut m = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let mut t = Vector3::new(p[3], p[7], p[11]);
    if m.determinant() < 0.0 {
        m = -m;
        t = -t;
    }
    let scale = m.singular_values().mean();
    Some((orthonormal(&m)?, t / scale))
}

fn smallest_right_singular_vector(a: &DMatrix<f64>) -> Option<nalgebra::DVector<f64>> {
    // Of AᵀA: its eigenvector of the smallest eigenvalue (A has ≥ 8 rows and 9 or 12 columns).
    let ata = a.transpose() * a;
    let eigen = ata.symmetric_eigen();
    let i = eigen.eigenvalues.imin();
    let v = eigen.eigenvectors.column(i).into_owned();
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The rotation nearest `m` (polar decomposition); `None` when `m` is degenerate.
fn orthonormal(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        let mut u = u;
        u.column_mut(2).neg_mut();
        r = u * v_t;
    }
    r.iter().all(|x| x.is_finite()).then_some(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Layer, PinholeCamera, RefractiveCamera};
    use nalgebra::Unit;

    /// The direction [`bent_into_water`] gives is the one a ray traced through the port's
    /// interfaces ([`RefractiveCamera::trace_ray_in_water`], Snell at each) leaves in, for ports
    /// tilted 0–25° and rays up to 50° off the camera's axis.
    #[test]
    fn the_bent_direction_is_the_traced_rays() {
        let intrinsics =
            PinholeCamera::new("c", 640, 480, 500.0, 500.0, 320.0, 240.0, [0.0; 5]).unwrap();
        for (tilt_deg, azimuth_deg) in [(0.0f64, 0.0f64), (8.0, 30.0), (25.0, -120.0)] {
            let (t, a) = (tilt_deg.to_radians(), azimuth_deg.to_radians());
            let normal = Vector3::new(t.sin() * a.cos(), t.sin() * a.sin(), t.cos());
            let port = Interface::new(
                normal,
                0.02,
                vec![Layer {
                    thickness: 0.01,
                    index: 1.49,
                }],
                1.0,
                1.333,
            )
            .unwrap();
            let camera = RefractiveCamera::new(intrinsics, &Isometry3::identity(), &port);
            for (x, y) in [(0.0, 0.0), (0.3, -0.2), (-0.9, 0.5), (1.1, 0.4)] {
                let x = Vector2::new(x, y);
                let air = Unit::new_normalize(Vector3::new(x.x, x.y, 1.0));
                let traced = camera.trace_ray_in_water(&air).unwrap().dir;
                let bent = bent_into_water(&x, &normal, 1.0 / 1.333).unwrap();
                let bent = Vector3::new(bent.x, bent.y, 1.0).normalize();
                assert!(
                    (bent - traced.into_inner()).norm() < 1e-12,
                    "tilt {tilt_deg}°, x {x:?}: bent {bent:?}, traced {traced:?}"
                );
            }
        }
    }
}
