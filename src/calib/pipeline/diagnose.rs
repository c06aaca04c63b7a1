//! What the data look like when nothing fits: cheap tests of the usual mistakes, each run on
//! the observations as given and as the mistake would have them, without any refraction model.
//!
//! - **Swapped images**: the two air rays of a corner, from the camera centres C_l and C_r with
//!   the rig's in-air extrinsics, must meet in front of both cameras (refraction moves the point
//!   along its object axis, never behind the cameras). With the left and right images exchanged
//!   the disparity changes sign and the rays meet behind. A view whose rays mostly meet behind as
//!   given, and in front once exchanged (each pixel undistorted by the other camera), has its
//!   images swapped.
//! - **Reversed corner order in one image** (OpenCV may start a symmetric board at the opposite
//!   corner): pairing corner i of one image with corner N − 1 − i of the other makes the rays
//!   meet where they did not.
//! - **Square size or baseline unit**: the adjacent corners, triangulated under a candidate
//!   interface, must lie one square apart; a median ratio far from 1 says the board's square (or
//!   the baseline, which scales every triangulated length) is wrong.
//!
//! The in-air rays miss each other by the refraction's effect (a few milliradians); the tests
//! compare a pairing with its alternative, never with an absolute bound alone.

use nalgebra::{Point2, Point3, Unit, Vector3};

use super::report::Report;
use super::{MIN_VIEWS, Options};
use crate::calib::costs::triangulate_corner;
use crate::calib::problem::data::{CameraPair, Candidate, StereoData};
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::observations::view_list;
use crate::calib::problem::target::Target;
use crate::model::{Ports, Rig};
use crate::model::{Ray, triangulate_rays};

/// How the in-air rays of one view's corners meet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Meeting {
    /// Corners compared.
    pub corners: usize,
    /// Corners whose two rays meet in front of both cameras.
    pub in_front: usize,
    /// Median angle between the rays' closest approach, radians (gap / distance from the left
    /// camera), over the corners that meet in front; +∞ when none does.
    pub median_gap: f64,
}

impl Meeting {
    /// The share of corners whose rays meet in front.
    pub fn front_share(&self) -> f64 {
        if self.corners == 0 {
            0.0
        } else {
            self.in_front as f64 / self.corners as f64
        }
    }

    fn fits(&self) -> bool {
        self.front_share() >= FRONT_SHARE
    }
}

/// Share of corners meeting in front for a pairing to fit.
pub const FRONT_SHARE: f64 = 0.9;

/// Factor by which an alternative pairing must bring the rays closer to count as the right one.
pub const CLOSER: f64 = 5.0;

/// Ratio of the triangulated to the board's square beyond which (either way) the scale is wrong.
pub const SCALE_TOLERANCE: f64 = 0.05;

fn meeting(
    centres: &[Point3<f64>; 2],
    pairs: impl Iterator<Item = Option<[Unit<Vector3<f64>>; 2]>>,
) -> Meeting {
    let (mut corners, mut gaps) = (0, Vec::new());
    for pair in pairs {
        corners += 1;
        let Some([left, right]) = pair else { continue };
        let a = Ray {
            origin: centres[0],
            dir: left,
        };
        let b = Ray {
            origin: centres[1],
            dir: right,
        };
        if let Ok(t) = triangulate_rays(&a, &b) {
            let distance = (t.point - centres[0]).norm();
            if distance > 0.0 {
                gaps.push(t.residual / distance);
            }
        }
    }
    let in_front = gaps.len();
    gaps.sort_by(f64::total_cmp);
    let median_gap = gaps.get(gaps.len() / 2).copied().unwrap_or(f64::INFINITY);
    Meeting {
        corners,
        in_front,
        median_gap,
    }
}

/// The in-air air direction of a raw pixel of rig camera `camera`, master frame.
fn dir(data: &StereoData, camera: usize, pixel: &Point2<f64>) -> Option<Unit<Vector3<f64>>> {
    data.rig
        .refractive_camera(camera)
        .dir_in_air_from_img(pixel)
        .ok()
}

/// How the rays of every view meet as given, with the images exchanged, and with one image's
/// corner order reversed: (as given, exchanged, reversed) per view.
pub fn pairings(data: &StereoData) -> Vec<[Meeting; 3]> {
    let centres = data.centres();
    let swapped_centres = [centres[1], centres[0]];
    let n = data.board.corners();
    data.views
        .iter()
        .map(|range| {
            let corners = &data.corners[range.clone()];
            let given = meeting(&centres, corners.iter().map(|c| Some(c.dirs)));
            // Exchanged: the left list was the second camera's image and the right list the first's.
            let exchanged = meeting(
                &swapped_centres,
                corners.iter().map(|c| {
                    Some([
                        dir(data, data.cameras[1], &c.pixels[0])?,
                        dir(data, data.cameras[0], &c.pixels[1])?,
                    ])
                }),
            );
            let by_index: std::collections::HashMap<usize, usize> = corners
                .iter()
                .enumerate()
                .map(|(j, c)| (c.index, j))
                .collect();
            let reversed = meeting(
                &centres,
                corners.iter().map(|c| {
                    by_index
                        .get(&(n - 1 - c.index))
                        .map(|&j| [c.dirs[0], corners[j].dirs[1]])
                }),
            );
            [given, exchanged, reversed]
        })
        .collect()
}

/// Findings about how the images of each view are paired: views whose images look swapped, views
/// whose corner order looks reversed in one image. Empty when every view looks right.
pub fn pairing_findings(data: &StereoData) -> Vec<String> {
    let meetings = pairings(data);
    let mut swapped = Vec::new();
    let mut reversed = Vec::new();
    for (v, [given, exchanged, flipped]) in meetings.iter().enumerate() {
        if !given.fits() && exchanged.fits() {
            swapped.push(v);
        } else if flipped.fits()
            && (!given.fits() || flipped.median_gap * CLOSER < given.median_gap)
        {
            reversed.push(v);
        }
    }
    let mut findings = Vec::new();
    let names = data.cameras.map(|k| data.rig.cameras()[k].name.as_str());
    if !swapped.is_empty() {
        let share: f64 = swapped
            .iter()
            .map(|&v| meetings[v][0].front_share())
            .sum::<f64>()
            / swapped.len() as f64;
        findings.push(format!(
            "the left and right images look swapped (views {}): as given, the two cameras' rays meet in front of both for only {:.0} % of the corners; exchanged, for {:.0} %. Exchange the \"left\" and \"right\" lists, or the \"cameras\" order ({}, {})",
            view_list(&swapped),
            100.0 * share,
            100.0 * swapped.iter().map(|&v| meetings[v][1].front_share()).sum::<f64>() / swapped.len() as f64,
            names[0],
            names[1]
        ));
    }
    if !reversed.is_empty() {
        findings.push(format!(
            "the corner order of one image looks reversed (views {}): corner 0 of one image matches the last corner of the other (the rays meet {:.0}× closer paired that way); detect both images with the same corner order",
            view_list(&reversed),
            reversed.iter().map(|&v| meetings[v][0].median_gap / meetings[v][2].median_gap).fold(f64::INFINITY, f64::min).min(1e6)
        ));
    }
    findings
}

/// The median ratio of the distances between adjacent triangulated corners (along rows and
/// columns) to the board's square under `candidate`; `None` when the candidate puts a camera
/// outside the air or no adjacent pair triangulates.
pub fn square_ratio(data: &StereoData, candidate: &Candidate) -> Option<f64> {
    let cameras = data.cameras_behind(candidate)?;
    let mut ratios = Vec::new();
    for range in &data.views {
        let corners = &data.corners[range.clone()];
        let points: std::collections::HashMap<usize, Point3<f64>> = corners
            .iter()
            .filter_map(|c| triangulate_corner(&cameras, c).map(|t| (c.index, t.point)))
            .collect();
        for (&i, p) in &points {
            let (r, c) = data.board.grid_position(i);
            let right = (c + 1 < data.board.cols).then(|| i + 1);
            let below = (r + 1 < data.board.rows).then(|| i + data.board.cols);
            for q in [right, below]
                .into_iter()
                .flatten()
                .filter_map(|j| points.get(&j))
            {
                ratios.push((q - p).norm() / data.board.square);
            }
        }
    }
    if ratios.is_empty() {
        return None;
    }
    ratios.sort_by(f64::total_cmp);
    Some(ratios[ratios.len() / 2])
}

/// What the data look like, one finding per entry: the pairing findings, the scale of the
/// triangulated board under `candidate` (or the rig's interface), and a summary line of the
/// data (views, corners, the corner noise `noise_px` seen in the images when known, how the
/// in-air rays meet).
pub fn explain(
    data: &StereoData,
    candidate: Option<&Candidate>,
    noise_px: Option<f64>,
) -> Vec<String> {
    let mut findings = pairing_findings(data);
    let pairing = !findings.is_empty();
    findings.extend(scale_finding(data, candidate, pairing));
    findings.push(summary(data, noise_px));
    findings
}

/// The scale of the triangulated board under `candidate` (or the rig's interface) when it is off
/// by more than [`SCALE_TOLERANCE`]; `pairing` says whether the images' pairing already looks
/// wrong (then a large factor is not put down to a unit).
pub fn scale_finding(
    data: &StereoData,
    candidate: Option<&Candidate>,
    pairing: bool,
) -> Option<String> {
    let rig_candidate = Candidate::of(data.port());
    let under = candidate.copied().unwrap_or(rig_candidate);
    let ratio = square_ratio(data, &under)?;
    if (ratio - 1.0).abs() <= SCALE_TOLERANCE {
        return None;
    }
    let what = if candidate.is_some() {
        "under the fitted interface"
    } else {
        "under the rig's start interface"
    };
    let hint = if !(0.2..=5.0).contains(&ratio) && !pairing {
        " (a factor this large suggests a unit: a baseline or square in millimetres instead of metres?)"
    } else {
        ""
    };
    Some(format!(
        "the triangulated board's squares measure {:.2} mm {what} (median), the observations give {:.2} mm: check the board's \"square\" (metres) and the rig's baseline{hint}",
        ratio * data.board.square * 1e3,
        data.board.square * 1e3
    ))
}

/// One line of what the data are: views, corners, the corner noise `noise_px` seen in the images
/// when known, how the in-air rays meet.
pub fn summary(data: &StereoData, noise_px: Option<f64>) -> String {
    let meetings = pairings(data);
    let corners: usize = meetings.iter().map(|m| m[0].corners).sum();
    let in_front: usize = meetings.iter().map(|m| m[0].in_front).sum();
    let mut gaps: Vec<f64> = meetings
        .iter()
        .map(|m| m[0].median_gap)
        .filter(|g| g.is_finite())
        .collect();
    gaps.sort_by(f64::total_cmp);
    let gap = gaps.get(gaps.len() / 2).map_or("none meet".into(), |g| {
        format!("median gap {:.2} mrad", g * 1e3)
    });
    format!(
        "{} views of a {}×{} board ({} mm squares), {} corners seen in both images{}; in air, {:.0} % of the corners' two rays meet in front of both cameras ({gap})",
        data.views.len(),
        data.board.cols,
        data.board.rows,
        data.board.square * 1e3,
        data.corners.len(),
        noise_px.map_or(String::new(), |s| format!(
            ", scattered σ ≈ {s:.3} px about the board's smooth shape in each image"
        )),
        100.0 * in_front as f64 / corners.max(1) as f64,
    )
}

/// What the data look like when the result does not fit. First what a camera pair's rays show
/// (swapped images, a reversed corner order, a triangulated board of the wrong scale); then the
/// usual input mistakes, each undone in turn and calibrated again ([`misfit`]), those whose
/// undoing explains the misfit (a scale finding that one of them names already is left out); or,
/// when none does, a summary of the data and the line that says so.
pub(super) fn diagnosis(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    report: &Report,
    options: &Options,
) -> Vec<String> {
    // The pair the 3-D errors are about, else the first that saw three views of a board together.
    let named =
        report
            .scene
            .as_ref()
            .and_then(|s| match s.cameras.clone().map(|n| rig.camera_index(&n)) {
                [Some(a), Some(b)] => Some(CameraPair::new(a, b)),
                _ => None,
            });
    let n = rig.cameras().len();
    let pair = target.board().and_then(|board| {
        named
            .into_iter()
            .chain((0..n).flat_map(|a| (a + 1..n).map(move |b| CameraPair::new(a, b))))
            .filter_map(|pair| StereoData::new(rig, pair, board, seen).ok())
            .find(|d| d.views.len() >= MIN_VIEWS)
    });
    let mut findings = Vec::new();
    let mut scale = None;
    if let Some(data) = &pair {
        findings = pairing_findings(data);
        // The fitted port where it is the pair's (a shared one), else the pair's start.
        let candidate = matches!(rig.ports(), Ports::Shared(_)).then(|| Candidate {
            normal: nalgebra::Unit::new_normalize(nalgebra::Vector3::from(report.port().normal)),
            air_distance: report.port().distance.value,
        });
        scale = scale_finding(data, candidate.as_ref(), !findings.is_empty());
    }
    match super::misfit::explain_misfit(rig, target, seen, options) {
        Ok(verified) => {
            let named_scale = verified.iter().any(|v| super::misfit::is_about_scale(v));
            if !named_scale {
                findings.extend(scale);
            }
            findings.extend(verified);
        }
        Err(unexplained) => {
            findings.extend(scale);
            if let Some(data) = &pair {
                findings.push(summary(data, report.noise_px));
            }
            findings.push(unexplained);
        }
    }
    findings
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Board, Observations, SceneSpec, Target, simulate};

    fn scene(seed: u64) -> (crate::model::Rig, Observations) {
        let rig = crate::io::rig_from_json_str(
            include_str!("../../../data/example_rig.json"),
            "example".as_ref(),
        )
        .unwrap();
        let board = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let scene = simulate(&rig, &SceneSpec::pair(board, 8, 0.2, seed, 0, 1)).unwrap();
        (rig, scene.observations)
    }

    #[test]
    fn correct_pairings_fit_and_their_alternatives_do_not() {
        for seed in 1..=4 {
            let (rig, observations) = scene(seed);
            let data = StereoData::from_observations(&rig, [0, 1], &observations).unwrap();
            for (v, [given, exchanged, reversed]) in pairings(&data).iter().enumerate() {
                println!("seed {seed} view {v}: {given:?} {exchanged:?} {reversed:?}");
                assert_eq!(given.in_front, given.corners);
                assert!(!exchanged.fits());
                assert!(!(reversed.fits() && reversed.median_gap * CLOSER < given.median_gap));
            }
            assert!(pairing_findings(&data).is_empty());
            let ratio =
                square_ratio(&data, &Candidate::of(rig.shared_interface().unwrap())).unwrap();
            assert!((ratio - 1.0).abs() < 0.01, "{ratio}");
        }
    }

    #[test]
    fn swapped_and_reversed_views_are_named() {
        let (rig, mut observations) = scene(7);
        for v in [1, 2, 3] {
            let [left, right] = observations.views[v].images.as_mut_slice() else {
                unreachable!("two images")
            };
            std::mem::swap(&mut left.corners, &mut right.corners);
        }
        observations.views[5].images[1].corners.reverse();
        let data = StereoData::from_observations(&rig, [0, 1], &observations).unwrap();
        let findings = pairing_findings(&data);
        assert_eq!(findings.len(), 2, "{findings:?}");
        assert!(
            findings[0].starts_with("the left and right images look swapped (views 1–3)"),
            "{findings:?}"
        );
        assert!(
            findings[1].starts_with("the corner order of one image looks reversed (views 5)"),
            "{findings:?}"
        );
    }

    #[test]
    fn a_wrong_square_is_measured() {
        let (rig, mut observations) = scene(3);
        observations.target = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.03,
        });
        let data = StereoData::from_observations(&rig, [0, 1], &observations).unwrap();
        let findings = explain(
            &data,
            Some(&Candidate::of(rig.shared_interface().unwrap())),
            Some(0.2),
        );
        assert!(
            findings[0].contains("measure 40.0") && findings[0].contains("give 30.00 mm"),
            "{findings:?}"
        );
        assert!(
            findings
                .last()
                .unwrap()
                .starts_with("8 views of a 9×6 board"),
            "{findings:?}"
        );
    }
}
