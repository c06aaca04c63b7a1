//! The report's pictures, drawn with plotters into memory and written as PNG (the plot module's
//! font and encoder): the rig from the top and the side, per camera the residual quiver, the
//! spatial error map, the coverage over the image and over distance and tilt, the RMS per frame,
//! the error histogram and the held-out frames by depth.

use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector3};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::advice::{CandidateKind, CandidateView, TEXTURE_GRID};
use super::{Facts, ReportError};
use crate::io::plot::{encode, register_font, viridis};

/// A picture on the page.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Picture {
    /// File name in the report's folder.
    pub file: String,
    /// What it shows, one sentence.
    pub caption: String,
}

/// The pictures of the report, by section.
#[derive(Debug, Clone, Default)]
pub(crate) struct Pictures {
    pub rig: Vec<Picture>,
    /// Per camera (rig order): its pictures.
    pub cameras: Vec<Vec<Picture>>,
    pub overall: Vec<Picture>,
}

pub(crate) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Colours of the cameras, in rig order, cycling.
const CAMERA_COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn colour(k: usize) -> RGBColor {
    CAMERA_COLOURS[k % CAMERA_COLOURS.len()]
}

/// A camera's name made safe for a file name.
pub(crate) fn file_safe(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Draws a picture of `size` into `dir/file` by `draw` and encodes it.
pub(crate) fn picture(
    dir: &Path,
    file: &str,
    size: (u32, u32),
    files: &mut Vec<PathBuf>,
    draw: impl FnOnce(&Area) -> Result<(), String>,
) -> Result<(), ReportError> {
    register_font();
    let path = dir.join(file);
    let mut buffer = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        let drawn = root
            .fill(&WHITE)
            .map_err(|e| e.to_string())
            .and_then(|()| draw(&root))
            .and_then(|()| root.present().map_err(|e| e.to_string()));
        drawn.map_err(|reason| ReportError::Draw {
            path: path.clone(),
            reason,
        })?;
    }
    encode(&path, &buffer, size)?;
    files.push(path);
    Ok(())
}

pub(crate) fn text(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// A range of `values` padded by 5 % (or ±1 around a single value, 0..1 when empty).
fn padded(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        low = low.min(v);
        high = high.max(v);
    }
    if !low.is_finite() {
        return (0.0, 1.0);
    }
    if high - low < 1e-9 {
        return (low - 1.0, high + 1.0);
    }
    let pad = 0.05 * (high - low);
    (low - pad, high + pad)
}

/// Every picture of `facts` into `dir`.
pub(crate) fn draw_all(
    dir: &Path,
    facts: &Facts,
    files: &mut Vec<PathBuf>,
) -> Result<Pictures, ReportError> {
    let mut pictures = Pictures::default();
    for (file, caption, axes) in [
        (
            "rig_top.png",
            "The rig from above (x across, z forward, master frame, metres): cameras with their axes (x red, y green, z blue), the ports' planes, the board poses.",
            (0usize, 2usize, 1.0),
        ),
        (
            "rig_side.png",
            "The rig from the side (z forward, y down, master frame, metres).",
            (2, 1, -1.0),
        ),
    ] {
        picture(dir, file, (800, 640), files, |area| {
            rig_view(area, facts, axes)
        })?;
        pictures.rig.push(Picture {
            file: file.into(),
            caption: caption.into(),
        });
    }
    // What the coverage and distance pictures show: the kept matches on the targetless route,
    // the corners and board poses otherwise.
    let (coverage_says, depth_says) = if facts.input.targetless.is_some() {
        (
            "where the matches fell over the image; the advised texture outlined in red.",
            "the matched points by their distance from this camera; the advised texture's distance as a red triangle.",
        )
    } else {
        (
            "where the corners fell over the image, in air (grey) and under water (blue); the advised view's board outlined in red.",
            "the fitted frames by the board's distance and tilt from this camera; the advised view as a red triangle.",
        )
    };
    for (k, camera) in facts.input.rig.cameras().iter().enumerate() {
        let name = file_safe(&camera.name);
        let mut own = Vec::new();
        let corners: Vec<_> = facts.corners.iter().filter(|c| c.camera == k).collect();
        let (w, h) = (
            f64::from(camera.intrinsics.width),
            f64::from(camera.intrinsics.height),
        );
        let size = image_picture_size(w, h);
        let quiver = format!("quiver_{k}_{name}.png");
        let scale = arrow_scale(&corners, w);
        picture(dir, &quiver, size, files, |area| {
            let mut chart = image_chart(
                area,
                &format!("{}: residuals ×{scale:.0}", camera.name),
                w,
                h,
            )?;
            chart
                .draw_series(corners.iter().map(|c| {
                    let end = c.observed + c.residual * scale;
                    let style = if c.outlier { RED } else { BLUE };
                    PathElement::new(vec![(c.observed.x, c.observed.y), (end.x, end.y)], style)
                }))
                .map_err(text)?;
            chart
                .draw_series(
                    corners
                        .iter()
                        .map(|c| Circle::new((c.observed.x, c.observed.y), 1, BLACK.filled())),
                )
                .map_err(text)?;
            if corners.is_empty() {
                no_data(area)?;
            }
            Ok(())
        })?;
        own.push(Picture {
            file: quiver,
            caption: format!(
                "{}: each corner's residual (projected − found) drawn {scale:.0} times longer, outliers in red.",
                camera.name
            ),
        });
        let errors = format!("errors_{k}_{name}.png");
        picture(dir, &errors, size, files, |area| {
            error_map(area, &camera.name, &corners, w, h)
        })?;
        own.push(Picture {
            file: errors,
            caption: format!(
                "{}: RMS residual over each cell of an 8 × 6 grid of the image (grey: no corner there).",
                camera.name
            ),
        });
        let coverage = format!("coverage_{k}_{name}.png");
        picture(dir, &coverage, size, files, |area| {
            coverage_map(area, facts, k, w, h)
        })?;
        own.push(Picture {
            file: coverage,
            caption: format!("{}: {coverage_says}", camera.name),
        });
        let depth = format!("depth_tilt_{k}_{name}.png");
        picture(dir, &depth, (640, 480), files, |area| {
            depth_tilt(area, facts, k)
        })?;
        own.push(Picture {
            file: depth,
            caption: format!("{}: {depth_says}", camera.name),
        });
        pictures.cameras.push(own);
    }
    if !facts.frame_rms.is_empty() {
        picture(dir, "frames_rms.png", (960, 420), files, |area| {
            frames_rms(area, facts)
        })?;
        pictures.overall.push(Picture {
            file: "frames_rms.png".into(),
            caption: "RMS reprojection error per fitted frame and camera.".into(),
        });
    }
    if !facts.corners.is_empty() {
        picture(dir, "histogram.png", (640, 420), files, |area| {
            histogram(area, facts)
        })?;
        pictures.overall.push(Picture {
            file: "histogram.png".into(),
            caption: "The residuals' lengths over every corner of every camera.".into(),
        });
    }
    if facts.held_out.iter().any(|f| f.depth_m.is_some()) {
        picture(dir, "held_out.png", (640, 420), files, |area| {
            held_out(area, facts)
        })?;
        pictures.overall.push(Picture {
            file: "held_out.png".into(),
            caption: "Held-out frames: the triangulated squares' error against the board's distance from the master camera.".into(),
        });
    }
    Ok(pictures)
}

/// A picture size of an image's aspect, 640 wide.
fn image_picture_size(w: f64, h: f64) -> (u32, u32) {
    let aspect = if w > 0.0 && h > 0.0 { h / w } else { 0.75 };
    (640, (560.0 * aspect + 80.0).clamp(200.0, 900.0) as u32)
}

/// The arrow scale of a quiver: the 95th percentile residual drawn as 4 % of the width.
fn arrow_scale(corners: &[&super::Corner], w: f64) -> f64 {
    let mut lengths: Vec<f64> = corners.iter().map(|c| c.residual.norm()).collect();
    lengths.sort_by(f64::total_cmp);
    let p95 = lengths
        .get((lengths.len() as f64 * 0.95) as usize)
        .or(lengths.last())
        .copied()
        .unwrap_or(1.0);
    if p95 > 0.0 && p95.is_finite() {
        (0.04 * w / p95).clamp(1.0, 10_000.0).round()
    } else {
        1.0
    }
}

pub(crate) type ImageChart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// A chart of `caption` over `x` × `y` with its light grid and axis names drawn. With
/// `frames: Some(n)`, x is n frames at 0, 1, …, labelled from 1.
pub(crate) fn plot_chart<'a, 'b>(
    area: &'a Area<'b>,
    caption: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    (x_desc, y_desc): (&str, &str),
    frames: Option<usize>,
) -> Result<ImageChart<'a, 'b>, String> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x, y)
        .map_err(text)?;
    let mut mesh = chart.configure_mesh();
    mesh.max_light_lines(0)
        .bold_line_style(RGBColor(225, 225, 225))
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 12));
    if let Some(n) = frames {
        mesh.x_labels((n + 1).min(21))
            .x_label_formatter(&frame_label);
    }
    mesh.draw().map_err(text)?;
    Ok(chart)
}

/// An x tick of a chart over frames: the 1-based frame at whole positions, nothing between.
fn frame_label(x: &f64) -> String {
    if (x - x.round()).abs() < 1e-6 && *x >= 0.0 {
        format!("{}", x.round() as i64 + 1)
    } else {
        String::new()
    }
}

/// A chart over an image: u across, v down, the image's border drawn.
fn image_chart<'a, 'b>(
    area: &'a Area<'b>,
    title: &str,
    w: f64,
    h: f64,
) -> Result<ImageChart<'a, 'b>, String> {
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..w.max(1.0), h.max(1.0)..0.0)
        .map_err(text)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(text)?;
    chart
        .draw_series([Rectangle::new([(0.0, 0.0), (w, h)], BLACK.stroke_width(1))])
        .map_err(text)?;
    Ok(chart)
}

fn no_data(area: &Area) -> Result<(), String> {
    area.draw(&Text::new(
        "no corners",
        (20, 40),
        ("sans-serif", 20).into_font().color(&RED),
    ))
    .map_err(text)
}

/// RMS residual per cell of an 8 × 6 grid.
fn error_map(
    area: &Area,
    name: &str,
    corners: &[&super::Corner],
    w: f64,
    h: f64,
) -> Result<(), String> {
    const COLUMNS: usize = 8;
    const ROWS: usize = 6;
    let mut sums = [[(0.0, 0usize); COLUMNS]; ROWS];
    for c in corners.iter().filter(|c| !c.outlier) {
        let i = ((c.observed.x / w * COLUMNS as f64) as usize).min(COLUMNS - 1);
        let j = ((c.observed.y / h * ROWS as f64) as usize).min(ROWS - 1);
        sums[j][i].0 += c.residual.norm_squared() / 2.0;
        sums[j][i].1 += 1;
    }
    let rms: Vec<Vec<Option<f64>>> = sums
        .iter()
        .map(|row| {
            row.iter()
                .map(|&(s, n)| (n > 0).then(|| (s / n as f64).sqrt()))
                .collect()
        })
        .collect();
    let high = rms
        .iter()
        .flatten()
        .flatten()
        .copied()
        .fold(0.0, f64::max)
        .max(1e-6);
    let (main, bar) = area.split_horizontally(area.dim_in_pixel().0 - 90);
    let mut chart = image_chart(&main, &format!("{name}: RMS per cell (px)"), w, h)?;
    for (j, row) in rms.iter().enumerate() {
        for (i, value) in row.iter().enumerate() {
            let (x0, x1) = (
                i as f64 * w / COLUMNS as f64,
                (i + 1) as f64 * w / COLUMNS as f64,
            );
            let (y0, y1) = (j as f64 * h / ROWS as f64, (j + 1) as f64 * h / ROWS as f64);
            let fill = value.map_or(RGBColor(200, 200, 200), |v| viridis(v / high));
            chart
                .draw_series([Rectangle::new([(x0, y0), (x1, y1)], fill.filled())])
                .map_err(text)?;
            if let Some(v) = value {
                chart
                    .draw_series([Text::new(
                        format!("{v:.2}"),
                        (x0 + 0.1 * (x1 - x0), 0.5 * (y0 + y1)),
                        ("sans-serif", 12).into_font().color(&WHITE),
                    )])
                    .map_err(text)?;
            }
        }
    }
    if corners.is_empty() {
        no_data(&main)?;
    }
    // The colour bar: 0 at the bottom, the largest cell at the top.
    let (bw, bh) = bar.dim_in_pixel();
    let top = 40i32;
    let bottom = bh as i32 - 40;
    for y in top..bottom {
        let t = f64::from(bottom - y) / f64::from(bottom - top);
        bar.draw(&Rectangle::new([(10, y), (30, y + 1)], viridis(t).filled()))
            .map_err(text)?;
    }
    let font = ("sans-serif", 12).into_font();
    bar.draw(&Text::new(
        format!("{high:.2} px"),
        (5, top - 18),
        font.clone(),
    ))
    .map_err(text)?;
    bar.draw(&Text::new("0", (35, bottom - 8), font))
        .map_err(text)?;
    let _ = bw;
    Ok(())
}

/// The corners over the image: in air grey, under water blue; the advised board in red.
fn coverage_map(area: &Area, facts: &Facts, k: usize, w: f64, h: f64) -> Result<(), String> {
    let name = &facts.input.rig.cameras()[k].name;
    let mut chart = image_chart(area, &format!("{name}: coverage"), w, h)?;
    if let Some(air) = facts.input.air.get(k) {
        chart
            .draw_series(
                air.iter()
                    .map(|p| Circle::new((p.x, p.y), 1, RGBColor(150, 150, 150).filled())),
            )
            .map_err(text)?;
    }
    chart
        .draw_series(
            facts
                .corners
                .iter()
                .filter(|c| c.camera == k)
                .map(|c| Circle::new((c.observed.x, c.observed.y), 1, BLUE.filled())),
        )
        .map_err(text)?;
    if let Some((candidate, _, _)) = facts.advice.as_ref().and_then(|a| a.best.as_ref())
        && let Some(corners) = candidate.view.corners_of(k)
    {
        let outline = outline(
            facts,
            candidate,
            corners.iter().map(|(i, p)| (*i, (p.x, p.y))),
        );
        chart
            .draw_series([PathElement::new(outline, RED.stroke_width(3))])
            .map_err(text)?;
        if candidate.camera == k {
            chart
                .draw_series([Text::new(
                    match candidate.kind {
                        CandidateKind::Board => "advised view",
                        CandidateKind::Texture { .. } => "advised texture",
                    },
                    (candidate.pixel.x, candidate.pixel.y),
                    ("sans-serif", 16).into_font().color(&RED),
                )])
                .map_err(text)?;
        }
    }
    Ok(())
}

/// The closed outline of an advised view in one camera, from its corners' pixels: through the
/// board's four outer corners, or the texture grid's.
fn outline(
    facts: &Facts,
    candidate: &CandidateView,
    corners: impl Iterator<Item = (usize, (f64, f64))>,
) -> Vec<(f64, f64)> {
    let all: Vec<(usize, (f64, f64))> = corners.collect();
    let (cols, n) = match candidate.kind {
        CandidateKind::Texture { .. } => (TEXTURE_GRID, TEXTURE_GRID * TEXTURE_GRID),
        CandidateKind::Board => match facts.input.target.as_ref().and_then(|t| t.board()) {
            Some(board) => (board.cols, board.corners()),
            None => return all.iter().map(|(_, p)| *p).collect(),
        },
    };
    let ids = [0, cols - 1, n - 1, n - cols, 0];
    ids.iter()
        .filter_map(|id| all.iter().find(|(i, _)| i == id).map(|(_, p)| *p))
        .collect()
}

/// Each fitted frame seen by camera `k`: its mean corner distance against the board's tilt.
fn depth_tilt(area: &Area, facts: &Facts, k: usize) -> Result<(), String> {
    if facts.input.targetless.is_some() {
        return distances(area, facts, k);
    }
    let name = &facts.input.rig.cameras()[k].name;
    let mut frames: std::collections::BTreeMap<usize, (f64, usize, f64)> = Default::default();
    for c in facts.corners.iter().filter(|c| c.camera == k) {
        let e = frames
            .entry(c.frame)
            .or_insert((0.0, 0, c.tilt_deg.unwrap_or(0.0)));
        e.0 += c.depth_m;
        e.1 += 1;
    }
    let points: Vec<(f64, f64)> = frames
        .values()
        .map(|(sum, n, tilt)| (sum / *n as f64, *tilt))
        .collect();
    let advised = facts
        .advice
        .as_ref()
        .and_then(|a| a.best.as_ref())
        .filter(|(c, _, _)| c.camera == k)
        .map(|(c, _, _)| (c.distance_m, c.tilt_deg.abs()));
    let (x0, x1) = padded(
        points
            .iter()
            .map(|p| p.0)
            .chain(advised.map(|a| a.0))
            .chain([0.0]),
    );
    // Room for the advised view's label at the right.
    let x1 = x1 + 0.12 * (x1 - x0);
    let mut chart = plot_chart(
        area,
        &format!("{name}: frames by distance and tilt"),
        x0.max(0.0)..x1,
        0.0..70.0,
        ("distance from the camera (m)", "board tilt (°)"),
        None,
    )?;
    chart
        .draw_series(
            points
                .iter()
                .map(|&(d, t)| Circle::new((d, t), 4, BLUE.filled())),
        )
        .map_err(text)?;
    if let Some((d, t)) = advised {
        chart
            .draw_series([TriangleMarker::new((d, t), 10, RED.filled())])
            .map_err(text)?;
        chart
            .draw_series([Text::new(
                "advised",
                (d, t + 3.0),
                ("sans-serif", 14).into_font().color(&RED),
            )])
            .map_err(text)?;
    }
    if points.is_empty() {
        no_data(area)?;
    }
    Ok(())
}

/// Targetless: how far the matched points of camera `k` lie (a histogram of their distance from
/// the camera); the advised texture's distance as a red triangle.
fn distances(area: &Area, facts: &Facts, k: usize) -> Result<(), String> {
    let name = &facts.input.rig.cameras()[k].name;
    let depths: Vec<f64> = facts
        .corners
        .iter()
        .filter(|c| c.camera == k)
        .map(|c| c.depth_m)
        .filter(|d| d.is_finite())
        .collect();
    let advised = facts
        .advice
        .as_ref()
        .and_then(|a| a.best.as_ref())
        .filter(|(c, _, _)| c.camera == k)
        .map(|(c, _, _)| c.distance_m);
    let (x0, x1) = padded(depths.iter().copied().chain(advised).chain([0.0]));
    const BINS: usize = 30;
    let step = (x1 - x0) / BINS as f64;
    let mut counts = [0usize; BINS];
    for d in &depths {
        counts[(((d - x0) / step) as usize).min(BINS - 1)] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.25;
    let mut chart = plot_chart(
        area,
        &format!("{name}: matched points by distance"),
        x0.max(0.0)..x1,
        0.0..top,
        ("distance from the camera (m)", "matches"),
        None,
    )?;
    chart
        .draw_series(counts.iter().enumerate().map(|(i, &n)| {
            let left = x0 + i as f64 * step;
            Rectangle::new([(left, 0.0), (left + 0.9 * step, n as f64)], BLUE.filled())
        }))
        .map_err(text)?;
    if let Some(d) = advised {
        let y = top / 1.25;
        chart
            .draw_series([TriangleMarker::new((d, y), 10, RED.filled())])
            .map_err(text)?;
        chart
            .draw_series([Text::new(
                "advised",
                (d, top / 1.1),
                ("sans-serif", 14).into_font().color(&RED),
            )])
            .map_err(text)?;
    }
    if depths.is_empty() {
        no_data(area)?;
    }
    Ok(())
}

/// The RMS of every fitted frame per camera, as dots over the frame index.
fn frames_rms(area: &Area, facts: &Facts) -> Result<(), String> {
    let frames = facts.frame_rms.len();
    let high = facts
        .frame_rms
        .iter()
        .flatten()
        .flatten()
        .copied()
        .fold(0.0, f64::max)
        .max(1e-3)
        * 1.1;
    let mut chart = plot_chart(
        area,
        "RMS per fitted frame",
        -0.5..frames as f64 - 0.5,
        0.0..high,
        ("frame (report order)", "RMS (px)"),
        None,
    )?;
    let cameras = facts.input.rig.cameras().len();
    for k in 0..cameras {
        let width = 0.8 / cameras as f64;
        let offset = -0.4 + width * k as f64;
        chart
            .draw_series(facts.frame_rms.iter().enumerate().filter_map(|(f, rms)| {
                let r = rms.get(k).copied().flatten()?;
                let x = f as f64 + offset;
                Some(Rectangle::new(
                    [(x, 0.0), (x + width, r)],
                    colour(k).filled(),
                ))
            }))
            .map_err(text)?
            .label(facts.input.rig.cameras()[k].name.clone())
            .legend(move |(x, y)| {
                Rectangle::new([(x, y - 5), (x + 10, y + 5)], colour(k).filled())
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(text)
}

/// The residual lengths over every corner.
fn histogram(area: &Area, facts: &Facts) -> Result<(), String> {
    let lengths: Vec<f64> = facts.corners.iter().map(|c| c.residual.norm()).collect();
    let mut sorted = lengths.clone();
    sorted.sort_by(f64::total_cmp);
    let high = sorted
        .get((sorted.len() as f64 * 0.995) as usize)
        .or(sorted.last())
        .copied()
        .unwrap_or(1.0)
        .max(1e-6);
    const BINS: usize = 40;
    let mut counts = [0usize; BINS];
    for l in &lengths {
        counts[((l / high * BINS as f64) as usize).min(BINS - 1)] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.1;
    let mut chart = plot_chart(
        area,
        "Residual lengths",
        0.0..high,
        0.0..top,
        (
            "|residual| (px; the last bin holds everything beyond)",
            "corners",
        ),
        None,
    )?;
    let step = high / BINS as f64;
    chart
        .draw_series(counts.iter().enumerate().map(|(i, &n)| {
            Rectangle::new(
                [(i as f64 * step, 0.0), ((i as f64 + 0.9) * step, n as f64)],
                RGBColor(31, 119, 180).filled(),
            )
        }))
        .map_err(text)?;
    Ok(())
}

/// Held-out frames: squares' RMS error (mm) against the distance from the master camera.
fn held_out(area: &Area, facts: &Facts) -> Result<(), String> {
    let points: Vec<(f64, f64)> = facts
        .held_out
        .iter()
        .filter_map(|f| {
            let depth = f.depth_m?;
            let n = f.square_errors.len();
            (n > 0).then(|| {
                (
                    depth,
                    1e3 * (f.square_errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt(),
                )
            })
        })
        .collect();
    let (x0, x1) = padded(points.iter().map(|p| p.0));
    let high = points.iter().map(|p| p.1).fold(0.0, f64::max).max(1e-3) * 1.2;
    let mut chart = plot_chart(
        area,
        "Held-out frames: squares by distance",
        x0..x1,
        0.0..high,
        (
            "distance from the master camera (m)",
            "RMS square error (mm)",
        ),
        None,
    )?;
    chart
        .draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, 5, RGBColor(214, 39, 40).filled())),
        )
        .map_err(text)?;
    Ok(())
}

/// The part of the segment a–b inside the rectangle (x0, x1, y0, y1) (Liang–Barsky), `None`
/// when it misses it.
fn clip(
    a: (f64, f64),
    b: (f64, f64),
    (x0, x1, y0, y1): (f64, f64, f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a.0 - x0),
        (dx, x1 - a.0),
        (-dy, a.1 - y0),
        (dy, y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}

/// The rig projected on two master axes (`axes.0` across, `axes.1` up, times `axes.2`).
fn rig_view(area: &Area, facts: &Facts, axes: (usize, usize, f64)) -> Result<(), String> {
    let rig = facts.input.rig;
    let (a, b, sign) = axes;
    let project = |p: &Point3<f64>| (p[a], sign * p[b]);
    let names = ["x", "y", "z"];
    // The scene: cameras, the boards' outlines, the targetless points.
    let mut boards: Vec<Vec<(f64, f64)>> = Vec::new();
    if let Some(target) = &facts.input.target {
        let outline: Vec<Point3<f64>> = match target.board() {
            Some(board) => {
                let n = board.corners();
                [0, board.cols - 1, n - 1, n - board.cols, 0]
                    .iter()
                    .map(|&i| target.point(i))
                    .collect()
            }
            None => (0..target.len()).map(|i| target.point(i)).collect(),
        };
        for pose in &facts.poses {
            boards.push(outline.iter().map(|p| project(&(pose * p))).collect());
        }
    }
    let points: Vec<(f64, f64)> = facts.input.points.iter().map(project).collect();
    let centres: Vec<Point3<f64>> = rig.cameras().iter().map(|c| c.centre_in_master()).collect();
    let mut all: Vec<(f64, f64)> = centres.iter().map(project).collect();
    all.extend(boards.iter().flatten().copied());
    all.extend(points.iter().copied());
    let (mut x0, mut x1) = padded(all.iter().map(|p| p.0));
    let (mut y0, mut y1) = padded(all.iter().map(|p| p.1));
    // Equal scales on both axes: the picture is to scale.
    let (width, height) = area.dim_in_pixel();
    let per_pixel = ((x1 - x0) / f64::from(width - 80)).max((y1 - y0) / f64::from(height - 90));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    x0 = cx - 0.5 * per_pixel * f64::from(width - 80);
    x1 = cx + 0.5 * per_pixel * f64::from(width - 80);
    y0 = cy - 0.5 * per_pixel * f64::from(height - 90);
    y1 = cy + 0.5 * per_pixel * f64::from(height - 90);
    let title = if b == 2 || a == 0 {
        "The rig from above"
    } else {
        "The rig from the side"
    };
    let mut chart = plot_chart(
        area,
        title,
        x0..x1,
        y0..y1,
        (
            &format!("{} (m)", names[a]),
            &format!("{}{} (m)", if sign < 0.0 { "−" } else { "" }, names[b]),
        ),
        None,
    )?;
    // Ports: each plane's trace across the picture, the first interface and the water side.
    let span = 2.0 * (x1 - x0).max(y1 - y0);
    let ports = match rig.ports() {
        crate::model::Ports::Shared(_) => 1,
        crate::model::Ports::PerCamera(ports) => ports.len(),
    };
    for (k, centre) in centres.iter().enumerate().take(ports) {
        let port = rig.port_in_master(k);
        let n = port.normal().into_inner();
        let origin = match rig.ports() {
            crate::model::Ports::Shared(_) => Point3::origin(),
            crate::model::Ports::PerCamera(_) => *centre,
        };
        let np = Vector3::new(
            if a == 0 || b == 0 { n.x } else { 0.0 },
            if a == 1 || b == 1 { n.y } else { 0.0 },
            if a == 2 || b == 2 { n.z } else { 0.0 },
        );
        let projected = (np[a], sign * np[b]);
        let length = (projected.0 * projected.0 + projected.1 * projected.1).sqrt();
        if length < 1e-9 {
            continue;
        }
        let along = (-projected.1 / length, projected.0 / length);
        for (distance, style) in [
            (port.air_distance(), RGBColor(0, 120, 200).stroke_width(2)),
            (port.outer_distance(), RGBColor(0, 60, 160).stroke_width(1)),
        ] {
            let at = project(&(origin + n * distance));
            // Clipped here: plotters would clamp each end into the chart, turning the line.
            let Some(segment) = clip(
                (at.0 - span * along.0, at.1 - span * along.1),
                (at.0 + span * along.0, at.1 + span * along.1),
                (x0, x1, y0, y1),
            ) else {
                continue;
            };
            chart
                .draw_series([PathElement::new(vec![segment.0, segment.1], style)])
                .map_err(text)?;
        }
    }
    for outline in &boards {
        chart
            .draw_series([PathElement::new(outline.clone(), RGBColor(100, 100, 100))])
            .map_err(text)?;
    }
    chart
        .draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, 1, RGBColor(120, 120, 120).filled())),
        )
        .map_err(text)?;
    let axis_length = 0.08 * (x1 - x0).min(y1 - y0);
    for (k, camera) in rig.cameras().iter().enumerate() {
        let centre = centres[k];
        let master_from_cam = camera.cam_from_master.rotation.inverse();
        for (axis, c) in [
            (Vector3::x(), RED),
            (Vector3::y(), GREEN),
            (Vector3::z(), BLUE),
        ] {
            let end = centre + master_from_cam * axis * axis_length;
            chart
                .draw_series([PathElement::new(
                    vec![project(&centre), project(&end)],
                    c.stroke_width(2),
                )])
                .map_err(text)?;
        }
        chart
            .draw_series([Circle::new(project(&centre), 4, colour(k).filled())])
            .map_err(text)?;
        let p = project(&centre);
        chart
            .draw_series([Text::new(
                camera.name.clone(),
                (p.0, p.1),
                ("sans-serif", 14).into_font().color(&colour(k)),
            )])
            .map_err(text)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_is_clipped_to_the_chart_without_turning() {
        let ((ax, ay), (bx, by)) =
            clip((-10.0, -1.0), (10.0, 1.0), (-1.0, 1.0, -1.0, 1.0)).unwrap();
        assert!((ax + 1.0).abs() < 1e-12 && (ay + 0.1).abs() < 1e-12);
        assert!((bx - 1.0).abs() < 1e-12 && (by - 0.1).abs() < 1e-12);
        assert!(clip((-10.0, 5.0), (10.0, 5.0), (-1.0, 1.0, -1.0, 1.0)).is_none());
    }

    #[test]
    fn camera_names_become_file_names() {
        assert_eq!(file_safe("cam 1/ü"), "cam_1__");
    }
}
