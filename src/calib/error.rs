//! Errors of the calibration layer: observations or settings that cannot be calibrated from.

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
    #[error("no views: calibration needs views of the target (at least 3, 10-20 recommended)")]
    NoViews,
    /// A view holds a different number of corners than the board has.
    #[error("view {view}: the {image} image has {got} corners, the target has {expected}")]
    CornerCount {
        /// 0-based view index.
        view: usize,
        /// The image's key in the file (`left`, or a camera name).
        image: String,
        /// Corners given.
        got: usize,
        /// rows × cols.
        expected: usize,
    },
    /// A corner detected in one image only (the contract: `null` in both).
    #[error(
        "view {view}: corner {corner} is null in the {missing} image but not in the other; in the stereo form a corner that was not detected must be null in both"
    )]
    CornerInOneImage {
        /// 0-based view index.
        view: usize,
        /// 0-based corner index (row-major).
        corner: usize,
        /// The key of the image where it is null.
        missing: String,
    },
    /// A corner that is NaN or infinite.
    #[error("view {view}: {image} corner {corner} is not finite: [{u}, {v}]")]
    CornerNotFinite {
        /// 0-based view index.
        view: usize,
        /// The image's key in the file.
        image: String,
        /// 0-based corner index.
        corner: usize,
        /// u as given.
        u: f64,
        /// v as given.
        v: f64,
    },
    /// A corner outside its image.
    #[error("view {view}: {image} corner {corner} at ({}, {}) px lies outside the {width}×{height} image", number(*u), number(*v))]
    CornerOutsideImage {
        /// 0-based view index.
        view: usize,
        /// The image's key in the file.
        image: String,
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
    /// The rig or the observations' camera names do not give the cameras asked for.
    #[error("{0}")]
    Cameras(String),
    /// No axis within the search bound explains the observations (every candidate failed). The
    /// reason ends with what the data look like ([`diagnose`](crate::calib::pipeline::diagnose)).
    #[error("no port axis within a tilt of {}° explains the corners: {reason}", degrees(*bound_deg))]
    NoSolution {
        /// The search bound, degrees.
        bound_deg: f64,
        /// What failed.
        reason: String,
    },
    /// A view that repeats an earlier one: every corner it shares with it lies within
    /// [`REPEAT_PX`](crate::calib::problem::observations::REPEAT_PX) in both images, far below any detector's
    /// noise, so it is a copy of the same frame, not a second measurement.
    #[error("views[{view}] repeats views[{earlier}] (every corner within {max_px:.1e} px in both images){}: a copy of the same frame adds no information and would make the reported standard deviations too small; remove the copies", more_repeats(*more))]
    RepeatedView {
        /// 0-based index of the copy.
        view: usize,
        /// 0-based index of the view it repeats.
        earlier: usize,
        /// Largest coordinate difference between the two, pixels.
        max_px: f64,
        /// Further repeated views beyond this one.
        more: usize,
    },
    /// The views show too few distinct target poses to constrain the port.
    #[error(
        "the {views} views show only {distinct} distinct board pose(s) ({groups}): calibration needs at least {needed} poses at varied angles and depths"
    )]
    TooFewPoses {
        /// Views given.
        views: usize,
        /// Distinct poses among them.
        distinct: usize,
        /// The groups of views that show one pose, as text (`views 0–14 within 0.258 px RMS`).
        groups: String,
        /// The minimum.
        needed: usize,
    },
    /// An option out of range.
    #[error("{0}")]
    Options(String),
    /// Something the data do not determine (a lens from underwater frames alone), named, with
    /// what would determine it.
    #[error("{0}")]
    NotDetermined(String),
    /// The GPU backend failed (a kernel it cannot run, a failed read-back): the
    /// [`GpuError`](crate::gpu::GpuError)'s message.
    #[error("GPU backend: {0}")]
    Gpu(String),
    /// Something wrong with one image (or one corner) of a view in the general observations form,
    /// at observations-file path `field` (`views[3].cam2[12]`).
    #[error("{field}: {reason}")]
    Observation {
        /// The observations-file path.
        field: String,
        /// What is wrong.
        reason: String,
    },
}

/// An angle in degrees as a reader wants it: at most 6 decimals, no trailing zeros
/// (`30`, `1.5`, `0.001`), scientific below 0.001 (`2.5e-5`); the rounding of a conversion
/// (29.999999999999996) never shows.
pub fn degrees(value: f64) -> String {
    number(value)
}

/// A number as a reader wants it in a message: at most 6 decimals, no trailing zeros,
/// scientific below 0.001 and from 10⁶ on (`1.000e300`, not three hundred digits).
pub fn number(value: f64) -> String {
    if !value.is_finite() {
        return format!("{value}");
    }
    if value != 0.0 && value.abs() < 1e-3 {
        return format!("{value:.2e}");
    }
    if value.abs() >= 1e6 {
        return format!("{value:.3e}");
    }
    let text = format!("{value:.6}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".into()
    } else {
        text.into()
    }
}

fn more_repeats(more: usize) -> String {
    match more {
        0 => String::new(),
        n => format!(" and {n} more view(s) repeat earlier ones"),
    }
}

#[cfg(feature = "gpu")]
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
            Self::CornerCount { view, image, .. } => format!("views[{view}].{image}"),
            Self::CornerInOneImage {
                view,
                corner,
                missing,
            } => format!("views[{view}].{missing}[{corner}]"),
            Self::CornerNotFinite {
                view,
                image,
                corner,
                ..
            }
            | Self::CornerOutsideImage {
                view,
                image,
                corner,
                ..
            } => format!("views[{view}].{image}[{corner}]"),
            Self::UnusableView { view, .. } | Self::RepeatedView { view, .. } => {
                format!("views[{view}]")
            }
            Self::TooFewPoses { .. } => "views".into(),
            Self::Cameras(_) => "cameras".into(),
            Self::Observation { field, .. } => field.clone(),
            Self::NoSolution { .. } | Self::Options(_) | Self::NotDetermined(_) | Self::Gpu(_) => {
                String::new()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::degrees;

    #[test]
    fn degrees_read_cleanly() {
        assert_eq!(degrees(29.999999999999996), "30");
        assert_eq!(degrees(30f64.to_radians().to_degrees()), "30");
        assert_eq!(degrees(1.5), "1.5");
        assert_eq!(degrees(0.001), "0.001");
        assert_eq!(degrees(-5.0), "-5");
        assert_eq!(degrees(-1e-12), "-1.00e-12");
        assert_eq!(degrees(0.0), "0");
        assert_eq!(degrees(f64::NAN), "NaN");
    }
}
