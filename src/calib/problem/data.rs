//! Observations of a camera pair prepared for cost evaluation: the air rays of every corner seen
//! in both images, which do not depend on the port, computed once; and the candidate port poses
//! the costs are evaluated at.

use std::ops::Range;

use nalgebra::{Matrix3x2, Point2, Unit, Vector3};

use crate::base::Board;
use crate::calib::error::CalibError;
use crate::calib::problem::observations::{MIN_VIEW_CORNERS, SeenView, pair_views};
use crate::model::{Interface, Ports, RefractiveCamera, Rig};

/// A candidate interface pose: system axis and air layer (master frame); the layers and indices
/// are the rig's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Unit system axis, pointing into the water.
    pub normal: Unit<Vector3<f64>>,
    /// Air layer d, metres.
    pub air_distance: f64,
}

impl Candidate {
    /// The candidate of an interface.
    pub fn of(interface: &Interface) -> Self {
        Self {
            normal: *interface.normal(),
            air_distance: interface.air_distance(),
        }
    }

    /// Tilt from the master z axis, radians.
    pub fn tilt(&self) -> f64 {
        self.normal.z.clamp(-1.0, 1.0).acos()
    }

    /// Azimuth atan2(n_y, n_x), radians.
    pub fn azimuth(&self) -> f64 {
        self.normal.y.atan2(self.normal.x)
    }
}

/// One board corner seen in both images of a pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    /// 0-based view of the pair ([`StereoData::views`]; [`StereoData::view_numbers`] gives the
    /// observations' number).
    pub view: usize,
    /// Corner index on the board (row-major).
    pub index: usize,
    /// Observed raw pixel in the first and the second camera's image.
    pub pixels: [Point2<f64>; 2],
    /// Unit air direction from each camera centre, master frame (undistorted).
    pub dirs: [Unit<Vector3<f64>>; 2],
    /// ∂dir/∂(u, v) of each image, master frame, per pixel.
    pub dir_jacobians: [Matrix3x2<f64>; 2],
}

/// Two cameras of a rig by their index in it, in order: the pair whose shared corners the pair
/// costs compare (the first is the reference). `[a, b]` converts into one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CameraPair {
    /// The first camera's index.
    pub first: usize,
    /// The second camera's index.
    pub second: usize,
}

impl CameraPair {
    /// Cameras `first` and `second`.
    pub fn new(first: usize, second: usize) -> Self {
        Self { first, second }
    }

    /// `[first, second]`.
    pub fn indices(self) -> [usize; 2] {
        [self.first, self.second]
    }

    /// `f` of each camera index, in order.
    pub fn map<T>(self, f: impl FnMut(usize) -> T) -> [T; 2] {
        self.indices().map(f)
    }
}

impl From<[usize; 2]> for CameraPair {
    fn from([first, second]: [usize; 2]) -> Self {
        Self { first, second }
    }
}

/// `pair[0]` is the first camera's index, `pair[1]` the second's.
impl std::ops::Index<usize> for CameraPair {
    type Output = usize;

    fn index(&self, side: usize) -> &usize {
        match side {
            0 => &self.first,
            1 => &self.second,
            _ => panic!("a camera pair has sides 0 and 1, not {side}"),
        }
    }
}

/// The observations of one pair of rig cameras and the rig they were taken with, ready for batch
/// cost evaluation by the pair costs ([`costs`](crate::calib::costs)): every corner both cameras
/// saw, with its air rays, which do not depend on the port.
#[derive(Debug, Clone)]
pub struct StereoData {
    /// The rig (its ports are the start guess; layers and indices are known values).
    pub rig: Rig,
    /// The pair's cameras.
    pub cameras: CameraPair,
    /// The board.
    pub board: Board,
    /// Every corner seen in both images, view by view.
    pub corners: Vec<Corner>,
    /// `corners[views[v].clone()]` are the corners of the pair's view v.
    pub views: Vec<Range<usize>>,
    /// The observations' number of each of the pair's views (views that one of the two cameras
    /// did not see, or that hold fewer than [`MIN_VIEW_CORNERS`] corners both saw, are not the
    /// pair's).
    pub view_numbers: Vec<usize>,
}

/// Pixel step of the central differences for ∂dir/∂pixel (error ~1e-12 relative).
const PIXEL_STEP: f64 = 1e-3;

impl StereoData {
    /// The corners both cameras `cameras` of `rig` saw in `seen` (observations of `board`
    /// resolved against `rig`, [`Observations::resolve`](crate::calib::Observations::resolve)),
    /// prepared.
    ///
    /// Errors: a corner that the lens model cannot undistort (beyond the fold of the radial
    /// distortion), named by view, camera and corner.
    pub fn new(
        rig: &Rig,
        cameras: impl Into<CameraPair>,
        board: &Board,
        seen: &[SeenView],
    ) -> Result<Self, CalibError> {
        let cameras = cameras.into();
        let refractive = cameras.map(|k| rig.refractive_camera(k));
        let pairs = pair_views(seen, cameras[0], cameras[1]);
        let mut corners = Vec::with_capacity(pairs.iter().map(|(_, c)| c.len()).sum());
        let mut views = Vec::with_capacity(pairs.len());
        let mut view_numbers = Vec::with_capacity(pairs.len());
        for (pair_view, (v, matched)) in pairs.into_iter().enumerate() {
            let start = corners.len();
            for (i, pixels) in matched {
                let mut dirs = [Unit::new_unchecked(Vector3::z()); 2];
                let mut dir_jacobians = [Matrix3x2::zeros(); 2];
                for k in 0..2 {
                    let camera = &refractive[k];
                    let unusable = || CalibError::UnusableView {
                        view: v,
                        reason: format!(
                            "camera '{}' corner {i} at ({}, {}) px lies beyond the lens model's one-to-one region (check the distortion coefficients)",
                            rig.cameras()[cameras[k]].name,
                            pixels[k].x,
                            pixels[k].y
                        ),
                    };
                    let dir =
                        |p: Point2<f64>| camera.dir_in_air_from_img(&p).map_err(|_| unusable());
                    dirs[k] = dir(pixels[k])?;
                    for axis in 0..2 {
                        let mut step = nalgebra::Vector2::zeros();
                        step[axis] = PIXEL_STEP;
                        let plus = dir(pixels[k] + step)?;
                        let minus = dir(pixels[k] - step)?;
                        dir_jacobians[k].set_column(
                            axis,
                            &((plus.into_inner() - minus.into_inner()) / (2.0 * PIXEL_STEP)),
                        );
                    }
                }
                corners.push(Corner {
                    view: pair_view,
                    index: i,
                    pixels,
                    dirs,
                    dir_jacobians,
                });
            }
            views.push(start..corners.len());
            view_numbers.push(v);
        }
        Ok(Self {
            rig: rig.clone(),
            cameras,
            board: *board,
            corners,
            views,
            view_numbers,
        })
    }

    /// [`StereoData::new`] from observations of a board not yet resolved against `rig`
    /// ([`Observations::resolve`](crate::calib::Observations::resolve) runs here).
    ///
    /// Errors: observations that do not fit `rig` or a target that is not a board.
    pub fn from_observations(
        rig: &Rig,
        cameras: impl Into<CameraPair>,
        observations: &crate::calib::Observations,
    ) -> Result<Self, CalibError> {
        let Some(board) = observations.target.board() else {
            return Err(CalibError::BadBoard {
                reason: "the pair costs need a board, not a 3-D target".into(),
            });
        };
        let seen = observations.resolve(rig)?;
        Self::new(rig, cameras, board, &seen)
    }

    /// The same pair with only the corners `keep` accepts (by position in
    /// [`corners`](Self::corners)); a view left with fewer than [`MIN_VIEW_CORNERS`] corners is
    /// dropped. `None` when no view is left.
    pub fn keeping(&self, keep: impl Fn(usize) -> bool) -> Option<Self> {
        let mut corners = Vec::with_capacity(self.corners.len());
        let mut views = Vec::with_capacity(self.views.len());
        let mut view_numbers = Vec::with_capacity(self.views.len());
        for (range, &number) in self.views.iter().zip(&self.view_numbers) {
            let kept: Vec<Corner> = range
                .clone()
                .filter(|&j| keep(j))
                .map(|j| self.corners[j])
                .collect();
            if kept.len() < MIN_VIEW_CORNERS {
                continue;
            }
            let start = corners.len();
            let pair_view = views.len();
            corners.extend(kept.into_iter().map(|c| Corner {
                view: pair_view,
                ..c
            }));
            views.push(start..corners.len());
            view_numbers.push(number);
        }
        (!views.is_empty()).then(|| Self {
            rig: self.rig.clone(),
            cameras: self.cameras,
            board: self.board,
            corners,
            views,
            view_numbers,
        })
    }

    /// The two cameras behind a candidate interface, or `None` when it puts a camera outside the
    /// air (or is not a valid interface).
    pub fn cameras_behind(&self, candidate: &Candidate) -> Option<[RefractiveCamera; 2]> {
        let rig = self.rig_behind(candidate)?;
        Some(self.cameras.map(|k| rig.refractive_camera(k)))
    }

    /// The port the candidates move: the shared one (master frame), or with a port per camera the
    /// first camera's own (in its frame; the other ports stay as the rig has them).
    pub fn port(&self) -> &Interface {
        match self.rig.ports() {
            Ports::Shared(interface) => interface,
            Ports::PerCamera(ports) => &ports[self.cameras[0]],
        }
    }

    /// The rig with [`Self::port`] moved to `candidate`, or `None` when it puts a camera outside
    /// the air (or is not a valid interface).
    pub fn rig_behind(&self, candidate: &Candidate) -> Option<Rig> {
        let port = self
            .port()
            .with_pose(candidate.normal.into_inner(), candidate.air_distance)
            .ok()?;
        match self.rig.ports() {
            Ports::Shared(_) => self.rig.with_interface(port).ok(),
            Ports::PerCamera(ports) => {
                let mut ports = ports.clone();
                ports[self.cameras[0]] = port;
                self.rig.with_new_ports(Ports::PerCamera(ports)).ok()
            }
        }
    }

    /// Whether both cameras look through one shared port: the binocular invariants (VOPs of
    /// the pair on one axis) need it.
    pub fn shared_port(&self) -> bool {
        matches!(self.rig.ports(), Ports::Shared(_))
    }

    /// The port a candidate puts the first camera behind, as a plane n·x = d of the master frame
    /// (n unit, as the rig normalises it): how the GPU kernels take candidates, moving the first
    /// camera's port and, behind a shared port, the second's ([`Self::ports_moved`]). `None` when
    /// the candidate puts a camera outside the air.
    pub fn master_plane(&self, candidate: &Candidate) -> Option<[f64; 4]> {
        let [first, _] = self.cameras_behind(candidate)?;
        let n = first.normal();
        let d = candidate.air_distance + self.master_plane_offset(&first);
        Some([n.x, n.y, n.z, d])
    }

    /// The master plane's air layer less the candidate's, for the first camera `first` behind a
    /// candidate: 0 behind a shared port (its air layer is the master plane's already), n·C of
    /// that camera behind its own port (whose air layer counts from its centre).
    pub fn master_plane_offset(&self, first: &RefractiveCamera) -> f64 {
        if self.shared_port() {
            0.0
        } else {
            first.normal().dot(&first.centre().coords)
        }
    }

    /// Whose port a candidate moves, left and right: both cameras' behind one shared port; behind
    /// a port each, the first camera's ([`Self::port`]; the second's stays as the rig has it).
    pub fn ports_moved(&self) -> [bool; 2] {
        [true, self.shared_port()]
    }

    /// Camera centres C_l, C_r in the master frame.
    pub fn centres(&self) -> [nalgebra::Point3<f64>; 2] {
        self.cameras
            .map(|k| self.rig.cameras()[k].centre_in_master())
    }

    /// The smallest air layer d that keeps both cameras in the air under `normal`: max_k n·C_k
    /// behind a shared port (a camera's own port only needs d > 0).
    pub fn min_air_distance(&self, normal: &Unit<Vector3<f64>>) -> f64 {
        if !self.shared_port() {
            return 0.0;
        }
        self.centres()
            .iter()
            .map(|c| normal.dot(&c.coords))
            .fold(0.0, f64::max)
    }
}
