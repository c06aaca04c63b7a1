//! Fusion of one frame's depth maps (every camera the reference in turn) into one oriented,
//! coloured point cloud.
//!
//! 1. `confirm`: a point of camera k's map is kept when another camera j's map agrees: the point
//!    is projected exactly into j (through j's port), and one of the 2 × 2 pixels around its
//!    projection holds a depth within `depth_tolerance` (relative) of the point's own depth z_j in
//!    j's frame. A point that no other map confirms (a mismatch, or a surface only one camera
//!    sees) is dropped.
//! 2. `merge`: the kept points, most confident first, each take the nearest not yet merged point
//!    of every other map within `merge_pixels` footprints of a pixel (z_k / f_k, the size of a
//!    pixel of camera k at the point's depth), found through a k-d tree (`kiddo`); the merged point is
//!    the confidence-weighted mean of their positions and colours. Points of one map are never
//!    merged with each other: the cloud keeps each camera's sampling, without the copies of a
//!    surface that several cameras see.
//! 3. `normals`: the normal of a merged point is the direction of least spread (principal
//!    component analysis) of its `normal_neighbours` nearest merged points, turned toward the
//!    centre of the camera whose point seeded it. Where fewer than 3 neighbours or a line of them
//!    give no plane, the normal is the unit direction from the point to that camera.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Point2, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use thiserror::Error;

use crate::model::{RefractiveCamera, Rig};

use super::DepthMap;

/// How to fuse.
#[derive(Debug, Clone, PartialEq)]
pub struct FuseOptions {
    /// Largest relative difference between a point's depth in another camera and that camera's
    /// depth map there for the other map to confirm it.
    pub depth_tolerance: f64,
    /// Points of different maps closer than this many pixel footprints are merged.
    pub merge_pixels: f64,
    /// Merged points whose spread gives a point's normal.
    pub normal_neighbours: usize,
}

impl Default for FuseOptions {
    /// Confirmation within 1 % of the depth, merging within one pixel footprint, normals from
    /// 64 neighbours: a plane's normals scatter as the depth noise over the neighbourhood's
    /// size; on a rendered plane at 160 × 128 pixels (0.1 % depth noise) their median error was
    /// 4.2° from 16 neighbours, 3.0° from 32, 2.2° from 64 and 1.6° from 128.
    fn default() -> Self {
        Self {
            depth_tolerance: 0.01,
            merge_pixels: 1.0,
            normal_neighbours: 64,
        }
    }
}

/// Why depth maps cannot be fused.
#[derive(Debug, Error)]
pub enum FuseError {
    /// Fewer than two maps, two maps of one camera, a map of a camera the rig lacks, or a map
    /// whose size is not its camera's.
    #[error("fusing depth maps: {0}")]
    Maps(String),
    /// An option out of range.
    #[error("fuse option {option}: {reason}")]
    Option {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// One camera's depth map of the frame and the colour of each of its pixels.
#[derive(Debug, Clone, Copy)]
pub struct FuseView<'a> {
    /// The map ([`DepthMap::reference`] names its camera).
    pub map: &'a DepthMap,
    /// `width · height` RGB colours, row-major.
    pub colours: &'a [[u8; 3]],
}

/// A point of the fused cloud.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusedPoint {
    /// Position, master frame, metres.
    pub position: [f64; 3],
    /// Unit normal, master frame, toward the camera that saw the point.
    pub normal: [f64; 3],
    /// Colour: the confidence-weighted mean of the merged points'.
    pub colour: [u8; 3],
    /// How many maps' points were merged into it (1 … cameras).
    pub views: usize,
    /// The confidence of the point that seeded it (the most confident of them).
    pub confidence: f32,
}

/// A point kept by the confirmation.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    position: [f64; 3],
    colour: [u8; 3],
    confidence: f32,
    view: usize,
    /// Merge radius, metres.
    radius: f64,
}

/// Fuses the depth maps of one frame (see the [module docs](self)); the points in the order
/// they were seeded (most confident first).
///
/// Errors: [`FuseError::Maps`] for fewer than two maps, two of one camera, a camera the rig lacks
/// or a size that is not the camera's (maps or colours); [`FuseError::Option`] for a tolerance or
/// radius that is not a positive number, or fewer than 3 normal neighbours.
pub fn fuse(
    rig: &Rig,
    views: &[FuseView],
    options: &FuseOptions,
) -> Result<Vec<FusedPoint>, FuseError> {
    check(rig, views, options)?;
    let cameras: Vec<RefractiveCamera> = views
        .iter()
        .map(|v| rig.refractive_camera(v.map.reference))
        .collect();
    let candidates = confirm(&cameras, views, options);
    let merged = merge(&candidates, views.len());
    Ok(with_normals(merged, &cameras, options.normal_neighbours))
}

fn check(rig: &Rig, views: &[FuseView], options: &FuseOptions) -> Result<(), FuseError> {
    let bad = |option, reason: String| Err(FuseError::Option { option, reason });
    if !(options.depth_tolerance > 0.0 && options.depth_tolerance.is_finite()) {
        return bad(
            "depth_tolerance",
            format!("a relative depth > 0, got {}", options.depth_tolerance),
        );
    }
    if !(options.merge_pixels > 0.0 && options.merge_pixels.is_finite()) {
        return bad(
            "merge_pixels",
            format!("> 0 pixels, got {}", options.merge_pixels),
        );
    }
    if options.normal_neighbours < 3 {
        return bad(
            "normal_neighbours",
            format!("at least 3 (a plane), got {}", options.normal_neighbours),
        );
    }
    if views.len() < 2 {
        return Err(FuseError::Maps(format!(
            "{} depth map(s): fusing needs two or more, one per camera",
            views.len()
        )));
    }
    let mut seen = vec![false; rig.cameras().len()];
    for view in views {
        let k = view.map.reference;
        let Some(camera) = rig.cameras().get(k) else {
            return Err(FuseError::Maps(format!(
                "a map of camera {k}; the rig has {}",
                rig.cameras().len()
            )));
        };
        if std::mem::replace(&mut seen[k], true) {
            return Err(FuseError::Maps(format!(
                "two maps of camera '{}'",
                camera.name
            )));
        }
        let (w, h) = (
            camera.intrinsics.width as usize,
            camera.intrinsics.height as usize,
        );
        let m = view.map;
        if (m.width, m.height) != (w, h)
            || m.depth.len() != w * h
            || m.points.len() != w * h
            || m.confidence.len() != w * h
            || view.colours.len() != w * h
        {
            return Err(FuseError::Maps(format!(
                "the map or colours of camera '{}' are not of its {w} × {h} pixels",
                camera.name
            )));
        }
    }
    Ok(())
}

/// Stage 1: the points of every map that another map confirms.
fn confirm(
    cameras: &[RefractiveCamera],
    views: &[FuseView],
    options: &FuseOptions,
) -> Vec<Candidate> {
    let tolerance = options.depth_tolerance;
    let mut candidates = Vec::new();
    for (k, view) in views.iter().enumerate() {
        let map = view.map;
        let focal = cameras[k].intrinsics().fx.max(cameras[k].intrinsics().fy);
        let kept: Vec<Candidate> = (0..map.width * map.height)
            .into_par_iter()
            .filter_map(|i| {
                let depth = f64::from(map.depth[i]);
                if !depth.is_finite() {
                    return None;
                }
                let p = map.points[i].map(f64::from);
                let point = Point3::from(p);
                let confirmed = views
                    .iter()
                    .enumerate()
                    .any(|(j, other)| j != k && agrees(&cameras[j], other.map, &point, tolerance));
                confirmed.then(|| Candidate {
                    position: p,
                    colour: view.colours[i],
                    confidence: map.confidence[i],
                    view: k,
                    radius: options.merge_pixels * depth / focal,
                })
            })
            .collect();
        candidates.extend(kept);
    }
    candidates
}

/// Whether `map` (of `camera`) holds, at one of the 2 × 2 pixels around the projection of
/// `point`, a depth within `tolerance` (relative) of the point's depth in that camera.
fn agrees(camera: &RefractiveCamera, map: &DepthMap, point: &Point3<f64>, tolerance: f64) -> bool {
    let z = (camera.cam_from_master() * (point - camera.centre())).z;
    if !(z > 0.0) {
        return false;
    }
    let Ok(pixel): Result<Point2<f64>, _> = camera.project(point) else {
        return false;
    };
    let (w, h) = (map.width as f64, map.height as f64);
    if !(pixel.x > -1.0 && pixel.y > -1.0 && pixel.x < w && pixel.y < h) {
        return false;
    }
    let (u0, v0) = (pixel.x.floor(), pixel.y.floor());
    [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
        .iter()
        .any(|(du, dv)| {
            let (u, v) = (u0 + du, v0 + dv);
            if !(u >= 0.0 && v >= 0.0 && u < w && v < h) {
                return false;
            }
            let d = f64::from(map.depth[v as usize * map.width + u as usize]);
            (d - z).abs() <= tolerance * z
        })
}

/// A merged point before its normal: the position, colour, views, seed confidence and seed view.
struct Merged {
    position: [f64; 3],
    colour: [u8; 3],
    views: usize,
    confidence: f32,
    seed_view: usize,
}

/// Stage 2: the merge (sequential, so that the result does not depend on the thread count).
fn merge(candidates: &[Candidate], view_count: usize) -> Vec<Merged> {
    if candidates.is_empty() {
        return Vec::new();
    }
    let positions: Vec<[f64; 3]> = candidates.iter().map(|c| c.position).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&positions);
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    // Most confident first; ties in input order (map, then pixel).
    order.sort_by(|&a, &b| {
        candidates[b]
            .confidence
            .total_cmp(&candidates[a].confidence)
            .then(a.cmp(&b))
    });
    let mut taken = vec![false; candidates.len()];
    let mut merged = Vec::new();
    for seed in order {
        if taken[seed] {
            continue;
        }
        let s = &candidates[seed];
        // The nearest free point of every other map within the seed's radius.
        let mut nearest: Vec<Option<(f64, usize)>> = vec![None; view_count];
        for n in tree.within_unsorted::<SquaredEuclidean>(&s.position, s.radius * s.radius) {
            let j = n.item as usize;
            let c = &candidates[j];
            if taken[j] || c.view == s.view {
                continue;
            }
            let better = match nearest[c.view] {
                None => true,
                Some((d, i)) => (n.distance, j) < (d, i),
            };
            if better {
                nearest[c.view] = Some((n.distance, j));
            }
        }
        let members: Vec<usize> = std::iter::once(seed)
            .chain(nearest.iter().flatten().map(|&(_, j)| j))
            .collect();
        let mut sum = [0.0f64; 3];
        let mut colour = [0.0f64; 3];
        let mut weight = 0.0;
        for &m in &members {
            taken[m] = true;
            let c = &candidates[m];
            // A zero confidence still counts a little: every member is a point of the surface.
            let w = f64::from(c.confidence).max(1e-6);
            for a in 0..3 {
                sum[a] += w * c.position[a];
                colour[a] += w * f64::from(c.colour[a]);
            }
            weight += w;
        }
        merged.push(Merged {
            position: sum.map(|v| v / weight),
            colour: colour.map(|v| (v / weight).round().clamp(0.0, 255.0) as u8),
            views: members.len(),
            confidence: s.confidence,
            seed_view: s.view,
        });
    }
    merged
}

/// Stage 3: the normals.
fn with_normals(
    merged: Vec<Merged>,
    cameras: &[RefractiveCamera],
    neighbours: usize,
) -> Vec<FusedPoint> {
    if merged.is_empty() {
        return Vec::new();
    }
    let positions: Vec<[f64; 3]> = merged.iter().map(|m| m.position).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&positions);
    let count = std::num::NonZero::new(neighbours.min(positions.len())).expect("points exist");
    merged
        .par_iter()
        .map(|m| {
            let p = Vector3::from(m.position);
            let towards_camera = cameras[m.seed_view].centre().coords - p;
            let near = tree.nearest_n::<SquaredEuclidean>(&m.position, count);
            let normal = plane_normal(
                near.iter()
                    .map(|n| Vector3::from(positions[n.item as usize])),
            )
            .map(|n| if n.dot(&towards_camera) < 0.0 { -n } else { n })
            .unwrap_or_else(|| towards_camera.normalize());
            FusedPoint {
                position: m.position,
                normal: [normal.x, normal.y, normal.z],
                colour: m.colour,
                views: m.views,
                confidence: m.confidence,
            }
        })
        .collect()
}

/// The unit normal of the plane through `points` (the eigenvector of their covariance with the
/// least eigenvalue), or `None` for fewer than 3 points or points along a line (the middle
/// eigenvalue below 1e-6 of the largest).
fn plane_normal(points: impl Iterator<Item = Vector3<f64>>) -> Option<Vector3<f64>> {
    let points: Vec<Vector3<f64>> = points.collect();
    if points.len() < 3 {
        return None;
    }
    let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let covariance = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>();
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let (least, middle, largest) = (
        eigen.eigenvalues[order[0]],
        eigen.eigenvalues[order[1]],
        eigen.eigenvalues[order[2]],
    );
    if !(largest > 0.0 && middle > 1e-6 * largest && least.is_finite()) {
        return None;
    }
    let normal = eigen.eigenvectors.column(order[0]).into_owned();
    (normal.norm() > 0.0).then(|| normal.normalize())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rig_from_json_str;
    use crate::stereo::rays::reference_rays;

    /// Two cameras 0.1 m apart behind one flat port with glass, 64 × 48.
    fn rig() -> Rig {
        rig_from_json_str(
            r#"{"cameras": [
              {"name": "a", "width": 64, "height": 48, "fx": 60, "fy": 60, "cx": 31.5, "cy": 23.5},
              {"name": "b", "width": 64, "height": 48, "fx": 60, "fy": 60, "cx": 31.5, "cy": 23.5,
               "translation": [-0.1, 0, 0]}],
             "interface": {"normal": [0, 0, 1], "distance": 0.03,
                           "layers": [{"thickness": 0.01, "index": 1.5}], "index_water": 1.333}}"#,
            std::path::Path::new("fuse-test.json"),
        )
        .unwrap()
    }

    /// The exact depth map of camera `k` of the plane z = `z` (master frame; both cameras'
    /// frames are the master's turned by nothing), by exact back-projection; `wrong` pixels get
    /// a depth 20 % short.
    fn plane_map(rig: &Rig, k: usize, z: f64, wrong: impl Fn(usize, usize) -> bool) -> DepthMap {
        let camera = rig.refractive_camera(k);
        let rays = reference_rays(&camera);
        let (w, h) = (rays.width, rays.height);
        let mut depth = vec![f32::NAN; w * h];
        let mut points = vec![[f32::NAN; 3]; w * h];
        let mut valid = 0;
        for i in 0..w * h {
            let zi = if wrong(i % w, i / w) { 0.8 * z } else { z };
            if let Some(p) = rays.point_at_depth(i, zi) {
                depth[i] = zi as f32;
                points[i] = p.map(|v| v as f32);
                valid += 1;
            }
        }
        DepthMap {
            width: w,
            height: h,
            reference: k,
            depth,
            points,
            confidence: vec![0.9; w * h],
            valid,
            depth_range: (0.5, 2.0),
            hypotheses: 64,
            sampling: crate::stereo::range::Sampling {
                depth_range: (0.5, 2.0),
                range: crate::stereo::range::RangeChoice::Given,
                hypotheses: 64,
                count: crate::stereo::range::CountChoice::Given,
            },
            consistency_px: 1.0,
            runs: 2,
            stage_seconds: Vec::new(),
        }
    }

    #[test]
    fn two_maps_of_a_plane_fuse_onto_it_with_its_normal_and_without_the_unconfirmed_patch() {
        let rig = rig();
        let z = 1.0;
        // A patch of camera a's map 20 % short: no other map confirms it.
        let maps = [
            plane_map(&rig, 0, z, |u, v| {
                (10..20).contains(&u) && (10..20).contains(&v)
            }),
            plane_map(&rig, 1, z, |_, _| false),
        ];
        let colours = vec![[200u8, 100, 50]; 64 * 48];
        let views: Vec<FuseView> = maps
            .iter()
            .map(|map| FuseView {
                map,
                colours: &colours,
            })
            .collect();
        let cloud = fuse(&rig, &views, &FuseOptions::default()).unwrap();
        assert!(!cloud.is_empty());
        for p in &cloud {
            // On the plane (f32 points), never on the wrong patch at z = 0.8.
            assert!((p.position[2] - z).abs() < 1e-5, "{p:?}");
            // Facing the cameras: −z, to well within a degree (the points are exact).
            assert!(p.normal[2] < -0.9999, "{p:?}");
            assert_eq!(p.colour, [200, 100, 50]);
        }
        // Where both cameras see the plane, their points are merged in pairs: fewer points than
        // the two maps hold, at least as many as one map's.
        let both = cloud.iter().filter(|p| p.views == 2).count();
        let total: usize = maps.iter().map(|m| m.valid).sum();
        assert!(
            cloud.len() < total && cloud.len() >= maps[1].valid / 2,
            "{}",
            cloud.len()
        );
        assert!(both > cloud.len() / 3, "{both} of {}", cloud.len());
        // Every kept point of a map lies in the other camera's view: the overlap of the two
        // images of the plane.
        assert!(cloud.len() <= total - 100);
    }

    #[test]
    fn a_point_is_merged_only_with_other_maps_within_its_radius() {
        // Greedy merging by hand: three maps' candidates at known distances.
        let c = |x: f64, view: usize, confidence: f32| Candidate {
            position: [x, 0.0, 1.0],
            colour: [10 * view as u8, 0, 0],
            confidence,
            view,
            radius: 0.01,
        };
        let candidates = [
            c(0.0, 0, 0.9),
            c(0.004, 1, 0.5),
            c(0.002, 0, 0.8),
            c(0.008, 2, 0.5),
            c(0.006, 2, 0.4),
            c(0.05, 1, 0.7),
        ];
        let merged = merge(&candidates, 3);
        // Seeds in confidence order: 0 takes 1 (map 1) and 4 (map 2's nearer, 0.006 against
        // 0.008), never 2 (its own map); 2 takes 3 (0.006 away); 5 is alone (1 is taken).
        let views: Vec<usize> = merged.iter().map(|m| m.views).collect();
        assert_eq!(views, vec![3, 2, 1]);
        let first = &merged[0];
        // The weights are the f32 confidences.
        let (w0, w1, w4) = (f64::from(0.9f32), f64::from(0.5f32), f64::from(0.4f32));
        let expected = (w0 * 0.0 + w1 * 0.004 + w4 * 0.006) / (w0 + w1 + w4);
        assert!((first.position[0] - expected).abs() < 1e-15);
        assert_eq!(merged[1].seed_view, 0);
        assert!((merged[2].position[0] - 0.05).abs() < 1e-15);
    }

    #[test]
    fn bad_maps_and_options_are_refused() {
        let rig = rig();
        let map = plane_map(&rig, 0, 1.0, |_, _| false);
        let colours = vec![[0u8; 3]; 64 * 48];
        let view = FuseView {
            map: &map,
            colours: &colours,
        };
        let error = fuse(&rig, &[view], &FuseOptions::default()).unwrap_err();
        assert!(error.to_string().contains("two or more"), "{error}");
        let error = fuse(&rig, &[view, view], &FuseOptions::default()).unwrap_err();
        assert!(
            error.to_string().contains("two maps of camera 'a'"),
            "{error}"
        );
        let options = FuseOptions {
            depth_tolerance: 0.0,
            ..FuseOptions::default()
        };
        let error = fuse(&rig, &[view, view], &options).unwrap_err();
        assert!(error.to_string().contains("depth_tolerance"), "{error}");
    }
}
