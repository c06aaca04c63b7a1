//! Errors of the calibration layer: observations or settings that cannot be calibrated from.

/// Which image of a stereo view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The first camera of the pair (the master in a stereo rig).
    Left,
    /// The second camera of the pair.
    Right,
}

impl Side {
    /// `left` or `right`, as in the observations file.
    pub fn name(self) -> &'static str {
        match self {
            Self::Left => "left",
            Self::Right => "right",
        }
    }
}

/// Observations or options from which no calibration can be made. Each variant names the view,
/// image and corner it is about; [`CalibError::field`] gives the observations-file path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibError {
    /// The board has no corners or a square that is not a positive length.
    #[error("board: {reason}")]
    BadBoard {
        /// What is wrong.
        reason: String,
    },
    /// Not one view.
    #[error("no views: calibration needs stereo views of the board (at least 3, 10-20 recommended)")]
    NoViews,
    /// A view holds a different number of corners than the board has.
    #[error("view {view}: the {} image has {got} corners, the board has {expected} (rows × cols)", side.name())]
    CornerCount {
        /// 0-based view index.
        view: usize,
        /// Which image.
        side: Side,
        /// Corners given.
        got: usize,
        /// rows × cols.
        expected: usize,
    },
    /// A corner detected in one image only (the contract: `null` in both).
    #[error("view {view}: corner {corner} is null in the {} image but not in the other; a corner that was not detected must be null in both", missing.name())]
    CornerInOneImage {
        /// 0-based view index.
        view: usize,
        /// 0-based corner index (row-major).
        corner: usize,
        /// The image where it is null.
        missing: Side,
    },
    /// A corner that is NaN or infinite.
    #[error("view {view}: {} corner {corner} is not finite: [{u}, {v}]", side.name())]
    CornerNotFinite {
        /// 0-based view index.
        view: usize,
        /// Which image.
        side: Side,
        /// 0-based corner index.
        corner: usize,
        /// u as given.
        u: f64,
        /// v as given.
        v: f64,
    },
    /// A corner outside its image.
    #[error("view {view}: {} corner {corner} at ({u}, {v}) px lies outside the {width}×{height} image", side.name())]
    CornerOutsideImage {
        /// 0-based view index.
        view: usize,
        /// Which image.
        side: Side,
        /// 0-based corner index.
        corner: usize,
        /// u as given.
        u: f64,
        /// v as given.
        v: f64,
        /// Image width, pixels.
        width: u32,
        /// Image height, pixels.
        height: u32,
    },
    /// A view with too few corners, or corners that do not span the board's plane.
    #[error("view {view}: {reason}")]
    UnusableView {
        /// 0-based view index.
        view: usize,
        /// What is wrong.
        reason: String,
    },
    /// Fewer views than the calibration needs.
    #[error("{usable} usable view(s): calibration needs at least {needed}")]
    TooFewViews {
        /// Views that can be used.
        usable: usize,
        /// The minimum.
        needed: usize,
    },
    /// The rig or the observations' camera names do not give a stereo pair.
    #[error("{0}")]
    Cameras(String),
    /// No axis within the search bound explains the observations (every candidate failed).
    #[error("no candidate axis within a tilt of {bound_deg}° lets both cameras triangulate the board: {reason}")]
    NoSolution {
        /// The search bound, degrees.
        bound_deg: f64,
        /// What failed.
        reason: String,
    },
    /// An option out of range.
    #[error("{0}")]
    Options(String),
    /// The GPU backend failed (a kernel it cannot run, a failed read-back): the
    /// [`GpuError`](crate::gpu::GpuError)'s message.
    #[error("GPU backend: {0}")]
    Gpu(String),
}

impl From<crate::gpu::GpuError> for CalibError {
    fn from(error: crate::gpu::GpuError) -> Self {
        Self::Gpu(error.to_string())
    }
}

impl CalibError {
    /// The observations-file path this error is about (`views[3].left[12]`), empty when none.
    pub fn field(&self) -> String {
        match self {
            Self::BadBoard { .. } => "board".into(),
            Self::NoViews | Self::TooFewViews { .. } => "views".into(),
            Self::CornerCount { view, side, .. } => format!("views[{view}].{}", side.name()),
            Self::CornerInOneImage { view, corner, missing } => format!("views[{view}].{}[{corner}]", missing.name()),
            Self::CornerNotFinite { view, side, corner, .. } | Self::CornerOutsideImage { view, side, corner, .. } => {
                format!("views[{view}].{}[{corner}]", side.name())
            }
            Self::UnusableView { view, .. } => format!("views[{view}]"),
            Self::Cameras(_) => "cameras".into(),
            Self::NoSolution { .. } | Self::Options(_) | Self::Gpu(_) => String::new(),
        }
    }
}
