//! PNG pictures of cost surfaces: a heat map over tilt × azimuth and a polar view of the axis
//! (tilt as radius, azimuth as angle, as seen looking along the master camera: x right, y down).
//! Drawn with plotters into memory, encoded with png, written atomically; the font (DejaVu Sans)
//! is built in, so no system fonts are needed.
//!
//! The cells are painted pixel by pixel: each pixel takes the colour of the grid cell under its
//! centre (for the polar view, the cell whose tilt and azimuth edges hold the pixel's polar
//! coordinates), so every cell covers exactly its own area. Filled polygons approximated the
//! annular cells with chords and left seams and overlaps between them (striped arcs, saw-tooth
//! edges). The polar view shows the whole disc when the grid covers every azimuth and is zoomed to
//! the grid's sector (and the marks) otherwise. Cells without a finite cost are [`NO_ANSWER`] grey,
//! named in the legend with their count and shown under the colour bar.

use std::path::Path;

use plotters::coord::ReverseCoordTranslate;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::io::{IoError, write_atomic};

/// One surface over tilt × azimuth.
#[derive(Debug, Clone)]
pub struct CostMap<'a> {
    /// Tilt values of the rows, degrees (ascending).
    pub tilts_deg: &'a [f64],
    /// Azimuth values of the columns, degrees (ascending).
    pub azimuths_deg: &'a [f64],
    /// values[row · azimuths + column]; non-finite cells are drawn [`NO_ANSWER`] grey.
    pub values: &'a [f64],
    /// Title over the picture.
    pub title: String,
    /// Label of the colour bar (the cost and its unit).
    pub cost_label: String,
    /// The minimum to mark (tilt°, azimuth°).
    pub minimum: Option<(f64, f64)>,
    /// The truth to mark (tilt°, azimuth°).
    pub truth: Option<(f64, f64)>,
}

const FONT: &[u8] = include_bytes!("../../../data/fonts/DejaVuSans.ttf");

pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and valid; a failure would only lose the labels.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Viridis, sampled at 9 points (matplotlib's table) and interpolated linearly.
pub(crate) fn viridis(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 9] = [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ];
    let x = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let mix = |a: u8, b: u8| (a as f64 + (b as f64 - a as f64) * f).round() as u8;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Colour of the cells without a finite cost (a candidate under which some corner has no
/// answer), named in the legend as [`NO_ANSWER_NAME`].
pub const NO_ANSWER: RGBColor = RGBColor(190, 190, 190);
/// The name of [`NO_ANSWER`] in the legend.
pub const NO_ANSWER_NAME: &str = "grey";

/// The legend entry for the cells without a finite cost, `None` when every cell has one.
pub fn no_answer_label(values: &[f64]) -> Option<String> {
    let n = values.iter().filter(|v| !v.is_finite()).count();
    (n > 0).then(|| {
        format!(
            "{NO_ANSWER_NAME}: no finite cost ({n} of {} cells)",
            values.len()
        )
    })
}

/// How values map to colours: linear, or log10 when positive and spanning over two decades.
struct Scale {
    low: f64,
    high: f64,
    log: bool,
}

/// A tick of the colour bar: its place on the bar's axis (the value, or its log10 on a log scale)
/// and its label.
#[derive(Debug, Clone, PartialEq)]
struct Tick {
    at: f64,
    label: String,
}

/// 1, 2 or 5 × 10^k, the smallest of them ≥ `raw` (> 0).
fn nice_step(raw: f64) -> f64 {
    let base = 10f64.powf(raw.log10().floor());
    let m = raw / base;
    base * if m <= 1.0 + 1e-9 {
        1.0
    } else if m <= 2.0 + 1e-9 {
        2.0
    } else if m <= 5.0 + 1e-9 {
        5.0
    } else {
        10.0
    }
}

/// `value`, a multiple of `step`, with just the digits that tell multiples of `step` apart:
/// fixed point for ordinary magnitudes, else scientific notation.
fn format_multiple(value: f64, step: f64) -> String {
    let step_exponent = step.log10().floor() as i32;
    let magnitude = value.abs().max(step);
    let text = if (1e-4..1e6).contains(&magnitude) {
        format!("{value:.*}", (-step_exponent).max(0) as usize)
    } else {
        let value_exponent = magnitude.log10().floor() as i32;
        format!(
            "{value:.*e}",
            (value_exponent - step_exponent).max(0) as usize
        )
    };
    // No "-0.00".
    if text.starts_with('-') && text[1..].chars().all(|c| matches!(c, '0' | '.' | 'e')) {
        text[1..].to_string()
    } else {
        text
    }
}

/// 10^k with the exponent in superscript digits ("10⁻²").
fn power_of_ten(k: i32) -> String {
    const DIGITS: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    let mut text = String::from("10");
    if k < 0 {
        text.push('⁻');
    }
    text.extend(
        k.unsigned_abs()
            .to_string()
            .chars()
            .map(|c| DIGITS[c.to_digit(10).unwrap_or(0) as usize]),
    );
    text
}

impl Scale {
    fn of(values: &[f64]) -> Self {
        let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        let low = finite.iter().copied().fold(f64::INFINITY, f64::min);
        let high = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if finite.is_empty() {
            return Self {
                low: 0.0,
                high: 1.0,
                log: false,
            };
        }
        let log = low > 0.0 && high / low > 100.0;
        let (low, high) = if log {
            (low.log10(), high.log10())
        } else {
            (low, high)
        };
        let (low, high) = if !(high > low) {
            // One value: a range around it that its ticks can resolve.
            let half = if low == 0.0 { 0.5 } else { low.abs() * 0.05 };
            (low - half, low + half)
        } else {
            (low, high)
        };
        Self { low, high, log }
    }

    fn colour(&self, v: f64) -> RGBColor {
        if !v.is_finite() {
            return NO_ANSWER;
        }
        let x = if self.log { v.log10() } else { v };
        viridis((x - self.low) / (self.high - self.low))
    }

    /// Ticks of the colour bar: 4–9 multiples of a 1-2-5 step, labelled with the digits that
    /// tell them apart; on a log scale the powers of ten as such ("10⁻²"), with 2· and 5· between
    /// them when fewer than three powers fall in the range.
    fn ticks(&self) -> Vec<Tick> {
        let inside = |x: f64| {
            x >= self.low - 1e-9 * (self.high - self.low)
                && x <= self.high + 1e-9 * (self.high - self.low)
        };
        if !self.log {
            let step = nice_step((self.high - self.low) / 8.0);
            let first = (self.low / step).ceil() as i64;
            let last = (self.high / step).floor() as i64;
            return (first..=last)
                .map(|k| k as f64 * step)
                .filter(|&x| inside(x))
                .map(|x| Tick {
                    at: x.clamp(self.low, self.high),
                    label: format_multiple(x, step),
                })
                .collect();
        }
        let (first, last) = (self.low.ceil() as i32, self.high.floor() as i32);
        let every = ((last - first + 1) as f64 / 8.0).ceil().max(1.0) as i32;
        let mut ticks: Vec<Tick> = (first..=last)
            .filter(|k| (k - first) % every == 0)
            .map(|k| Tick {
                at: k as f64,
                label: power_of_ten(k),
            })
            .collect();
        if ticks.len() < 3 {
            for k in first - 1..=last {
                for m in [2.0f64, 5.0] {
                    let at = k as f64 + m.log10();
                    if inside(at) {
                        ticks.push(Tick {
                            at,
                            label: format!("{m}·{}", power_of_ten(k)),
                        });
                    }
                }
            }
            ticks.sort_by(|a, b| a.at.total_cmp(&b.at));
        }
        ticks
    }
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn draw_error(e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(format!("drawing failed: {e}"))
}

/// The colour bar at the right of a picture, with a swatch of [`NO_ANSWER`] under it when some
/// cells have no finite cost.
fn colour_bar(
    area: &Area,
    scale: &Scale,
    label: &str,
    no_answer: bool,
) -> Result<(), std::io::Error> {
    let ticks = scale.ticks();
    let mut chart = ChartBuilder::on(area)
        .margin_top(50)
        .margin_bottom(if no_answer { 90 } else { 60 })
        .margin_right(10)
        .y_label_area_size(75)
        .build_cartesian_2d(0.0..1.0, scale.low..scale.high)
        .map_err(draw_error)?;
    // The ticks are drawn here rather than by the mesh: plotters picks its own key points, which
    // on a log scale are fractional exponents.
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(0)
        .y_desc(if scale.log {
            format!("{label}, log scale")
        } else {
            label.to_string()
        })
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(draw_error)?;
    let base = area.get_base_pixel();
    for tick in &ticks {
        let (x, y) = chart.backend_coord(&(0.0, tick.at));
        let (x, y) = (x - base.0, y - base.1);
        area.draw(&PathElement::new(vec![(x - 6, y), (x, y)], BLACK))
            .map_err(draw_error)?;
        let style = ("sans-serif", 14)
            .into_font()
            .color(&BLACK)
            .pos(Pos::new(HPos::Right, VPos::Center));
        area.draw(&Text::new(tick.label.clone(), (x - 9, y), style))
            .map_err(draw_error)?;
    }
    let steps = 200;
    chart
        .draw_series((0..steps).map(|i| {
            let y0 = scale.low + (scale.high - scale.low) * i as f64 / steps as f64;
            let y1 = scale.low + (scale.high - scale.low) * (i + 1) as f64 / steps as f64;
            Rectangle::new(
                [(0.0, y0), (1.0, y1)],
                viridis(i as f64 / (steps - 1) as f64).filled(),
            )
        }))
        .map_err(draw_error)?;
    if no_answer {
        let (x, y) = chart.plotting_area().get_pixel_range();
        let (x0, y0) = (
            x.start - area.get_base_pixel().0,
            y.end - area.get_base_pixel().1 + 14,
        );
        area.draw(&Rectangle::new(
            [(x0, y0), (x.end - area.get_base_pixel().0, y0 + 22)],
            NO_ANSWER.filled(),
        ))
        .map_err(draw_error)?;
        area.draw(&Text::new(
            "no finite",
            (x0 - 8, y0 + 26),
            ("sans-serif", 13),
        ))
        .map_err(draw_error)?;
        area.draw(&Text::new(
            "cost (inf)",
            (x0 - 8, y0 + 40),
            ("sans-serif", 13),
        ))
        .map_err(draw_error)?;
    }
    Ok(())
}

/// Cell edges: midpoints between values, half a step beyond the ends.
fn edges(values: &[f64]) -> Vec<f64> {
    let n = values.len();
    if n == 1 {
        return vec![values[0] - 0.5, values[0] + 0.5];
    }
    let mut e = Vec::with_capacity(n + 1);
    e.push(values[0] - (values[1] - values[0]) / 2.0);
    for i in 0..n - 1 {
        e.push((values[i] + values[i + 1]) / 2.0);
    }
    e.push(values[n - 1] + (values[n - 1] - values[n - 2]) / 2.0);
    e
}

/// The cell of `edges` (ascending or descending) that holds `v`, `None` outside them.
fn cell_of(edges: &[f64], v: f64) -> Option<usize> {
    let n = edges.len() - 1;
    let (first, last) = (edges[0], edges[n]);
    let (lo, hi) = (first.min(last), first.max(last));
    if !(v >= lo && v <= hi) {
        return None;
    }
    let k = if first <= last {
        edges.partition_point(|&e| e <= v)
    } else {
        edges.partition_point(|&e| e >= v)
    };
    Some(k.saturating_sub(1).min(n - 1))
}

pub(crate) fn encode(
    path: &Path,
    buffer: &[u8],
    (width, height): (u32, u32),
) -> Result<(), IoError> {
    let err = |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder
            .write_header()
            .map_err(|e| err(std::io::Error::other(e)))?;
        writer
            .write_image_data(buffer)
            .map_err(|e| err(std::io::Error::other(e)))?;
    }
    write_atomic(path, &bytes)
}

/// Paints every pixel of the chart's plotting area with the colour of the cell under it
/// (`cell` maps chart coordinates to a value index), so each cell covers exactly its own area:
/// no seams between cells, no overlaps. Returns the count of painted pixels in each corner box
/// (upper left, upper right, lower left, lower right; 45 % × 22 % of the area), for placing the
/// legend where it hides the least.
fn paint_cells(
    chart: &Chart,
    map: &CostMap,
    scale: &Scale,
    cell: impl Fn(f64, f64) -> Option<usize>,
) -> Result<[usize; 4], std::io::Error> {
    let area = chart.plotting_area();
    let (xs, ys) = area.get_pixel_range();
    let plain = area.strip_coord_spec();
    let (w, h) = ((xs.end - xs.start) as f64, (ys.end - ys.start) as f64);
    let mut corners = [0usize; 4];
    for py in ys.clone() {
        for px in xs.clone() {
            let Some((x, y)) = chart.as_coord_spec().reverse_translate((px, py)) else {
                continue;
            };
            let Some(k) = cell(x, y) else { continue };
            plain
                .draw_pixel((px - xs.start, py - ys.start), &scale.colour(map.values[k]))
                .map_err(draw_error)?;
            let (fx, fy) = ((px - xs.start) as f64 / w, (py - ys.start) as f64 / h);
            let column = if fx < 0.45 {
                Some(0)
            } else if fx > 0.55 {
                Some(1)
            } else {
                None
            };
            let row = if fy < 0.22 {
                Some(0)
            } else if fy > 0.78 {
                Some(2)
            } else {
                None
            };
            if let (Some(c), Some(r)) = (column, row) {
                corners[r + c] += 1;
            }
        }
    }
    Ok(corners)
}

/// Truth (circle), minimum (cross) and the cells without a finite cost in the legend, placed in
/// the corner of the plot where the fewest cells lie under it.
fn markers(
    chart: &mut Chart,
    map: &CostMap,
    at: impl Fn(f64, f64) -> (f64, f64),
    corners: [usize; 4],
) -> Result<(), std::io::Error> {
    if let Some((t, a)) = map.truth {
        chart
            .draw_series([Circle::new(
                at(t, a),
                9,
                ShapeStyle::from(&RED).stroke_width(3),
            )])
            .map_err(draw_error)?
            .label("truth")
            .legend(|(x, y)| Circle::new((x + 8, y), 6, ShapeStyle::from(&RED).stroke_width(3)));
    }
    if let Some((t, a)) = map.minimum {
        chart
            .draw_series([Cross::new(
                at(t, a),
                8,
                ShapeStyle::from(&WHITE).stroke_width(3),
            )])
            .map_err(draw_error)?
            .label(format!("minimum: tilt {t:.2}°, azimuth {a:.2}°"))
            .legend(|(x, y)| Cross::new((x + 8, y), 6, ShapeStyle::from(&BLACK).stroke_width(3)));
    }
    let no_answer = no_answer_label(map.values);
    if let Some(label) = &no_answer {
        chart
            .draw_series(std::iter::empty::<Rectangle<(f64, f64)>>())
            .map_err(draw_error)?
            .label(label)
            .legend(|(x, y)| Rectangle::new([(x + 1, y - 6), (x + 15, y + 6)], NO_ANSWER.filled()));
    }
    if map.truth.is_some() || map.minimum.is_some() || no_answer.is_some() {
        let positions = [
            SeriesLabelPosition::UpperLeft,
            SeriesLabelPosition::UpperRight,
            SeriesLabelPosition::LowerLeft,
            SeriesLabelPosition::LowerRight,
        ];
        // Upper right unless another corner is clearly emptier.
        let best = (0..4).min_by_key(|&i| (corners[i], i != 1)).unwrap_or(1);
        let best = if corners[best] * 10 < corners[1] * 9 {
            best
        } else {
            1
        };
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(positions[best].clone())
            .draw()
            .map_err(draw_error)?;
    }
    Ok(())
}

/// Renders a picture of `size`: the area left of the colour bar is drawn by `draw` with the
/// map's colour scale; then the colour bar, PNG encoding and an atomic write.
fn render(
    path: &Path,
    size: (u32, u32),
    map: &CostMap,
    draw: impl FnOnce(&Area, &Scale) -> Result<(), std::io::Error>,
) -> Result<(), IoError> {
    register_font();
    let mut buffer = vec![0u8; (size.0 * size.1 * 3) as usize];
    let err = |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        root.fill(&WHITE).map_err(draw_error).map_err(err)?;
        let (main, bar) = root.split_horizontally(size.0 - 130);
        let scale = Scale::of(map.values);
        draw(&main, &scale).map_err(err)?;
        colour_bar(
            &bar,
            &scale,
            &map.cost_label,
            map.values.iter().any(|v| !v.is_finite()),
        )
        .map_err(err)?;
        root.present().map_err(draw_error).map_err(err)?;
    }
    encode(path, &buffer, size)
}

/// Heat map: azimuth across, tilt up, colour bar at the right, the minimum marked with a cross and
/// the truth with a circle.
pub fn write_heatmap(path: &Path, map: &CostMap) -> Result<(), IoError> {
    render(path, (960, 720), map, |main, scale| {
        let (xe, ye) = (edges(map.azimuths_deg), edges(map.tilts_deg));
        let span = |e: &[f64]| e[0].min(e[e.len() - 1])..e[0].max(e[e.len() - 1]);
        let mut chart = ChartBuilder::on(main)
            .caption(&map.title, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(span(&xe), span(&ye))
            .map_err(draw_error)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("azimuth of the axis (°)")
            .y_desc("tilt of the axis (°)")
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 16))
            .draw()
            .map_err(draw_error)?;
        let columns = map.azimuths_deg.len();
        let corners = paint_cells(&chart, map, scale, |a, t| {
            Some(cell_of(&ye, t)? * columns + cell_of(&xe, a)?)
        })?;
        markers(&mut chart, map, |t, a| (a, t), corners)
    })
}

/// What the polar view shows: a square of half-width `half` (degrees of tilt) around `centre`,
/// the whole disc when the grid covers every azimuth, else the grid's annular sector (and the
/// marks) with a margin for the labels.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PolarView {
    centre: (f64, f64),
    half: f64,
    /// Tilt range of the cells (degrees, ≥ 0).
    tilt: (f64, f64),
    /// Azimuth range of the cells (degrees).
    azimuth: (f64, f64),
    full_turn: bool,
}

/// Polar position of (tilt°, azimuth°): x = tilt·cos a, y = −tilt·sin a (azimuth from +x toward
/// +y of the camera, which is down in its image).
fn polar_at(t: f64, a: f64) -> (f64, f64) {
    let a = a.to_radians();
    (t.max(0.0) * a.cos(), -t.max(0.0) * a.sin())
}

fn polar_view(map: &CostMap) -> PolarView {
    let (ae, te) = (edges(map.azimuths_deg), edges(map.tilts_deg));
    let tilt = (
        te[0].min(te[te.len() - 1]).max(0.0),
        te[0].max(te[te.len() - 1]).max(1e-9),
    );
    let azimuth = (ae[0].min(ae[ae.len() - 1]), ae[0].max(ae[ae.len() - 1]));
    let full_turn = azimuth.1 - azimuth.0 >= 360.0 - 1e-9;
    let disc = PolarView {
        centre: (0.0, 0.0),
        half: tilt.1 * 1.16,
        tilt,
        azimuth,
        full_turn,
    };
    if full_turn {
        return disc;
    }
    // The sector's outline, and the marks.
    let samples = 180;
    let mut points: Vec<(f64, f64)> = (0..=samples)
        .flat_map(|i| {
            let a = azimuth.0 + (azimuth.1 - azimuth.0) * i as f64 / samples as f64;
            [polar_at(tilt.0, a), polar_at(tilt.1, a)]
        })
        .collect();
    points.extend(
        map.truth
            .iter()
            .chain(&map.minimum)
            .map(|&(t, a)| polar_at(t, a)),
    );
    let (x0, x1) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.0), hi.max(p.0))
        });
    let (y0, y1) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.1), hi.max(p.1))
        });
    let half = (x1 - x0).max(y1 - y0) / 2.0 * 1.22;
    if half >= disc.half * 0.8 {
        return disc;
    }
    PolarView {
        centre: ((x0 + x1) / 2.0, (y0 + y1) / 2.0),
        half,
        tilt,
        azimuth,
        full_turn,
    }
}

/// The index into `values` of the cell under the polar position (x, y), `None` outside the grid.
fn polar_cell(
    view: &PolarView,
    tilt_edges: &[f64],
    azimuth_edges: &[f64],
    x: f64,
    y: f64,
) -> Option<usize> {
    let t = x.hypot(y);
    if t < view.tilt.0 || t > view.tilt.1 {
        return None;
    }
    let a = (-y).atan2(x).to_degrees();
    let a = [a, a + 360.0, a - 360.0]
        .into_iter()
        .find(|b| *b >= view.azimuth.0 && *b <= view.azimuth.1)?;
    // Near the centre every azimuth is the same axis: tilts below the first cell's edge (≤ 0)
    // belong to the first row.
    let lowest = tilt_edges[0].min(tilt_edges[tilt_edges.len() - 1]);
    Some(
        cell_of(tilt_edges, t.max(lowest))? * (azimuth_edges.len() - 1)
            + cell_of(azimuth_edges, a)?,
    )
}

/// Polar view: the axis as a point on the disc of tilts, azimuth measured from +x toward +y of
/// the master camera (x right, y down as in its image), zoomed to the grid's sector; rings of
/// equal tilt and spokes of equal azimuth, labelled, the ring labels beside the data or on the
/// spoke farthest from the marks so that no mark hides them.
pub fn write_polar(path: &Path, map: &CostMap) -> Result<(), IoError> {
    render(path, (860, 720), map, |main, scale| {
        let (ae, te) = (edges(map.azimuths_deg), edges(map.tilts_deg));
        let view = polar_view(map);
        let titled = main
            .titled(&map.title, ("sans-serif", 20))
            .map_err(draw_error)?;
        let note = "tilt (rings) and azimuth (spokes) of the axis in degrees, seen along the master camera: +x right, +y down";
        let plot = titled
            .titled(note, ("sans-serif", 13))
            .map_err(draw_error)?;
        let (w, h) = plot.dim_in_pixel();
        let side = (w.min(h) as i32 - 12).max(16);
        let (left, top) = ((w as i32 - side) / 2, 4);
        let square = plot.margin(top, h as i32 - top - side, left, w as i32 - left - side);
        let (cx, cy, s) = (view.centre.0, view.centre.1, view.half);
        let mut chart = ChartBuilder::on(&square)
            .build_cartesian_2d(cx - s..cx + s, cy - s..cy + s)
            .map_err(draw_error)?;
        let cell = |x: f64, y: f64| polar_cell(&view, &te, &ae, x, y);
        let corners = paint_cells(&chart, map, scale, cell)?;
        let per_pixel = 2.0 * s / side as f64;
        let (t0, t1) = view.tilt;
        let (a0, a1) = if view.full_turn {
            (-180.0, 180.0)
        } else {
            view.azimuth
        };
        // Opaque: a translucent polyline darkens where its segments overlap (dotted rings).
        let line = RGBColor(225, 225, 225);
        let label_style = |size: u32| {
            ("sans-serif", size)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Center, VPos::Center))
        };
        let boxed = |text: String, at: (f64, f64)| {
            let (tw, th) = (text.chars().count() as i32 * 7 + 6, 16);
            EmptyElement::at(at)
                + Rectangle::new(
                    [(-tw / 2, -th / 2), (tw / 2, th / 2)],
                    WHITE.mix(0.75).filled(),
                )
                + Text::new(text, (0, 0), label_style(13))
        };
        // Spokes of equal azimuth, labelled beyond the rim, and rings of equal tilt.
        let azimuth_step = if view.full_turn {
            45.0
        } else {
            nice_step((a1 - a0) / 5.0)
        };
        let spokes: Vec<f64> = (((a0 / azimuth_step).ceil() as i64)
            ..=((a1 / azimuth_step).floor() as i64))
            .map(|k| k as f64 * azimuth_step)
            .filter(|&a| !(view.full_turn && a <= -180.0))
            .collect();
        let ring_step = nice_step(if view.full_turn && t0 < 0.3 * t1 {
            t1 / 5.0
        } else {
            (t1 - t0) / 5.0
        });
        let rings: Vec<f64> = (((t0 / ring_step).ceil() as i64).max(1)
            ..=(t1 / ring_step + 1e-9).floor() as i64)
            .map(|k| k as f64 * ring_step)
            .collect();
        // Drawn pixel by pixel, as the cells are: plotters' lines made of short segments drop
        // pixels (dashed rings).
        let on_line = |x: f64, y: f64| {
            let t = x.hypot(y);
            if t < t0 - per_pixel || t > t1 + per_pixel {
                return false;
            }
            let a = (-y).atan2(x).to_degrees();
            let in_sector = view.full_turn
                || [a, a + 360.0, a - 360.0]
                    .iter()
                    .any(|b| *b >= a0 && *b <= a1);
            let ring = in_sector && rings.iter().any(|r| (t - r).abs() < 0.6 * per_pixel);
            let spoke = t >= t0
                && t <= t1
                && spokes.iter().any(|s| {
                    let d = (a - s).to_radians();
                    d.cos() > 0.0 && (t * d.sin()).abs() < 0.6 * per_pixel
                });
            ring || spoke
        };
        {
            let area = chart.plotting_area();
            let (xs, ys) = area.get_pixel_range();
            let plain = area.strip_coord_spec();
            for py in ys.clone() {
                for px in xs.clone() {
                    if let Some((x, y)) = chart.as_coord_spec().reverse_translate((px, py))
                        && on_line(x, y)
                    {
                        plain
                            .draw_pixel((px - xs.start, py - ys.start), &line)
                            .map_err(draw_error)?;
                    }
                }
            }
        }
        for &a in &spokes {
            let shown = if a > 180.0 {
                a - 360.0
            } else if a <= -180.0 {
                a + 360.0
            } else {
                a
            };
            let text = format!("{}°", format_multiple(shown, azimuth_step));
            chart
                .draw_series([Text::new(
                    text,
                    polar_at(t1 + 16.0 * per_pixel, a),
                    label_style(14),
                )])
                .map_err(draw_error)?;
        }
        // Ring labels: beside the sector (outside the data, where no mark can be), or on the
        // whole disc along the half-way spoke farthest from the marks.
        let label_azimuth = |t: f64| {
            if view.full_turn {
                let marks: Vec<f64> = map.truth.iter().chain(&map.minimum).map(|m| m.1).collect();
                let distance = |a: f64| {
                    marks
                        .iter()
                        .map(|m| ((a - m).rem_euclid(360.0)).min((m - a).rem_euclid(360.0)))
                        .fold(360.0, f64::min)
                };
                (0..8)
                    .map(|k| -157.5 + 45.0 * k as f64)
                    .max_by(|x, y| distance(*x).total_cmp(&distance(*y)))
                    .unwrap_or(22.5)
            } else {
                // 20 px beyond the sector's edge, on the side of the larger azimuth.
                a1 + (20.0 * per_pixel / t.max(1e-9)).to_degrees()
            }
        };
        for &t in &rings {
            let text = format!("{}°", format_multiple(t, ring_step));
            chart
                .draw_series([boxed(text, polar_at(t, label_azimuth(t)))])
                .map_err(draw_error)?;
        }
        markers(&mut chart, map, polar_at, corners)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pictures_are_pngs_of_the_stated_size() {
        let tilts: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let azimuths: Vec<f64> = (0..36).map(|i| -180.0 + 10.0 * i as f64).collect();
        let values: Vec<f64> = (0..tilts.len() * azimuths.len())
            .map(|k| {
                if k == 5 {
                    f64::INFINITY
                } else {
                    1.0 + k as f64
                }
            })
            .collect();
        let map = CostMap {
            tilts_deg: &tilts,
            azimuths_deg: &azimuths,
            values: &values,
            title: "test".into(),
            cost_label: "cost".into(),
            minimum: Some((3.0, 40.0)),
            truth: Some((8.0, 45.0)),
        };
        let dir = tempfile::tempdir().unwrap();
        for (name, size) in [("h.png", (960, 720)), ("p.png", (860, 720))] {
            let path = dir.path().join(name);
            if name == "h.png" {
                write_heatmap(&path, &map).unwrap()
            } else {
                write_polar(&path, &map).unwrap()
            }
            let decoder = png::Decoder::new(std::fs::File::open(&path).unwrap());
            let reader = decoder.read_info().unwrap();
            assert_eq!((reader.info().width, reader.info().height), size);
        }
        assert!((viridis(0.0).0, viridis(1.0).1) == (68, 231));
    }

    /// The value a tick label spells: plain numbers, "10⁻²" and "2·10⁻²".
    fn spelled(label: &str) -> f64 {
        const SUPER: &str = "⁰¹²³⁴⁵⁶⁷⁸⁹";
        if let Some((mantissa, power)) = label
            .split_once("10")
            .filter(|_| label.contains(|c: char| SUPER.contains(c)))
        {
            let mantissa: f64 = if mantissa.is_empty() {
                1.0
            } else {
                mantissa.trim_end_matches('·').parse().unwrap()
            };
            let exponent: String = power
                .chars()
                .map(|c| {
                    if c == '⁻' {
                        '-'
                    } else {
                        char::from_digit(SUPER.chars().position(|d| d == c).unwrap() as u32, 10)
                            .unwrap()
                    }
                })
                .collect();
            return mantissa * 10f64.powi(exponent.parse().unwrap());
        }
        label.parse().unwrap()
    }

    #[test]
    fn colour_bar_ticks_are_distinct_and_say_their_value() {
        // Ranges of the kinds that printed "0.005" five times, large and tiny magnitudes, one value.
        for values in [
            vec![0.00495, 0.0053],
            vec![0.0049995, 0.0050005],
            vec![1.21e7, 1.2600001e7],
            vec![1.0e-9, 3.0e-9],
            vec![-0.5, 0.25],
            vec![0.017, 0.017],
            vec![0.0, 0.0],
        ] {
            let scale = Scale::of(&values);
            assert!(!scale.log);
            let ticks = scale.ticks();
            assert!((3..=10).contains(&ticks.len()), "{values:?}: {ticks:?}");
            let labels: std::collections::HashSet<&str> =
                ticks.iter().map(|t| t.label.as_str()).collect();
            assert_eq!(
                labels.len(),
                ticks.len(),
                "{values:?}: labels repeat: {ticks:?}"
            );
            for t in &ticks {
                assert!(
                    t.at >= scale.low && t.at <= scale.high,
                    "{t:?} outside the bar"
                );
                let step = ticks[1].at - ticks[0].at;
                assert!(
                    (spelled(&t.label) - t.at).abs() <= 1e-9 * step.abs(),
                    "{values:?}: {t:?}"
                );
            }
        }
    }

    #[test]
    fn log_scale_ticks_are_powers_of_ten_not_exponents() {
        for (values, majors) in [
            (vec![0.013, 25.0], 3),
            (vec![2e-7, 3e4], 5),
            (vec![0.05, 6.0], 1),
        ] {
            let scale = Scale::of(&values);
            assert!(scale.log, "{values:?}");
            let ticks = scale.ticks();
            assert!(ticks.len() >= 3, "{ticks:?}");
            let powers = ticks.iter().filter(|t| t.label.starts_with("10")).count();
            assert!(powers >= majors, "{values:?}: {ticks:?}");
            for t in &ticks {
                // The label is the value at that place of the bar (10^at), never the exponent.
                let value = 10f64.powf(t.at);
                assert!(
                    (spelled(&t.label) / value - 1.0).abs() < 1e-9,
                    "{values:?}: {t:?}"
                );
                assert!(
                    value >= values[0] * (1.0 - 1e-9) && value <= values[1] * (1.0 + 1e-9),
                    "{t:?}"
                );
            }
        }
    }

    #[test]
    fn cells_without_a_finite_cost_are_named_and_counted() {
        let values = [1.0, f64::INFINITY, 2.0, f64::NAN, f64::INFINITY];
        assert_eq!(
            no_answer_label(&values).unwrap(),
            "grey: no finite cost (3 of 5 cells)"
        );
        assert_eq!(no_answer_label(&[1.0, 2.0]), None);
        assert_eq!(Scale::of(&values).colour(f64::INFINITY), NO_ANSWER);
        // No viridis colour is that grey.
        assert!((0..=1000).all(|i| viridis(i as f64 / 1000.0) != NO_ANSWER));
    }

    fn sweep_map<'a>(
        tilts: &'a [f64],
        azimuths: &'a [f64],
        values: &'a [f64],
        truth: Option<(f64, f64)>,
    ) -> CostMap<'a> {
        CostMap {
            tilts_deg: tilts,
            azimuths_deg: azimuths,
            values,
            title: "t".into(),
            cost_label: "c".into(),
            minimum: None,
            truth,
        }
    }

    fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    }

    #[test]
    fn the_polar_view_follows_the_data() {
        // The demo's close sweep: ±1° of tilt around 8°, ±7.4° of azimuth around 45°.
        let (tilts, azimuths) = (linspace(7.0, 9.0, 64), linspace(37.6, 52.4, 64));
        let values = vec![1.0; 64 * 64];
        let view = polar_view(&sweep_map(&tilts, &azimuths, &values, None));
        assert!(!view.full_turn);
        // The whole disc would be 2·9.03° wide; the sector is about 2.4° × 2.4°.
        assert!(view.half < 2.0, "{view:?}");
        let inside = |(x, y): (f64, f64)| {
            (x - view.centre.0).abs() <= view.half && (y - view.centre.1).abs() <= view.half
        };
        for &t in &[7.0 - 1.0 / 63.0, 9.0 + 1.0 / 63.0] {
            for &a in &linspace(37.6 - 0.12, 52.4 + 0.12, 50) {
                assert!(inside(polar_at(t, a)), "({t}, {a}) outside {view:?}");
            }
        }
        // The data cover at least a third of the square.
        let n = 200;
        let covered = (0..n * n)
            .filter(|k| {
                let x =
                    view.centre.0 - view.half + 2.0 * view.half * ((k % n) as f64 + 0.5) / n as f64;
                let y =
                    view.centre.1 - view.half + 2.0 * view.half * ((k / n) as f64 + 0.5) / n as f64;
                polar_cell(&view, &edges(&tilts), &edges(&azimuths), x, y).is_some()
            })
            .count();
        assert!(covered * 3 > n * n, "{covered} of {}", n * n);
        // A truth outside the grid is still in the picture.
        let view = polar_view(&sweep_map(&tilts, &azimuths, &values, Some((10.0, 60.0))));
        let (x, y) = polar_at(10.0, 60.0);
        assert!((x - view.centre.0).abs() < view.half && (y - view.centre.1).abs() < view.half);
        // Every azimuth: the whole disc.
        let (tilts, azimuths) = (linspace(0.0, 20.0, 96), linspace(-180.0, 180.0, 96));
        let values = vec![1.0; 96 * 96];
        let view = polar_view(&sweep_map(&tilts, &azimuths, &values, None));
        assert!(
            view.full_turn && view.centre == (0.0, 0.0) && view.half > 20.0,
            "{view:?}"
        );
    }

    #[test]
    fn every_point_of_the_polar_grid_lies_in_its_own_cell() {
        let (tilts, azimuths) = (linspace(0.0, 20.0, 21), linspace(-180.0, 180.0, 21));
        let values = vec![1.0; 21 * 21];
        let view = polar_view(&sweep_map(&tilts, &azimuths, &values, None));
        let (te, ae) = (edges(&tilts), edges(&azimuths));
        // A fine grid over the disc (independent of the cells' edges): inside the outer edge every
        // point has a cell, and that cell's edges hold the point's tilt and azimuth.
        for i in 0..400 {
            for j in 0..400 {
                let (x, y) = (
                    -21.0 + 42.0 * i as f64 / 399.0,
                    -21.0 + 42.0 * j as f64 / 399.0,
                );
                let (t, a) = (x.hypot(y), (-y).atan2(x).to_degrees());
                let cell = polar_cell(&view, &te, &ae, x, y);
                if t > te[21] {
                    assert_eq!(cell, None);
                    continue;
                }
                let k = cell.unwrap_or_else(|| panic!("no cell at ({x}, {y})"));
                let (r, c) = (k / 21, k % 21);
                assert!(
                    t >= te[r].max(0.0) - 1e-12 && t <= te[r + 1] + 1e-12,
                    "tilt {t} in row {r}"
                );
                let held = [a, a + 360.0, a - 360.0]
                    .iter()
                    .any(|b| *b >= ae[c] - 1e-12 && *b <= ae[c + 1] + 1e-12);
                assert!(held, "azimuth {a} in column {c}");
            }
        }
    }

    #[test]
    fn pictures_draw_cells_without_a_finite_cost_in_grey() {
        let (tilts, azimuths) = (linspace(0.0, 20.0, 21), linspace(-180.0, 180.0, 21));
        let grey_pixels = |values: &[f64]| {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("p.png");
            write_polar(&path, &sweep_map(&tilts, &azimuths, values, None)).unwrap();
            let mut reader = png::Decoder::new(std::fs::File::open(&path).unwrap())
                .read_info()
                .unwrap();
            let mut buffer = vec![0; reader.output_buffer_size()];
            reader.next_frame(&mut buffer).unwrap();
            buffer
                .chunks(3)
                .filter(|p| p == &[NO_ANSWER.0, NO_ANSWER.1, NO_ANSWER.2])
                .count()
        };
        let mut values: Vec<f64> = (0..21 * 21).map(|k| 1.0 + k as f64).collect();
        // (Anti-aliased text may hit that grey in a few pixels.)
        assert!(grey_pixels(&values) < 50);
        // The outer ring of cells has no answer: a band of grey pixels (plus legend and swatch).
        for v in values[20 * 21..].iter_mut() {
            *v = f64::INFINITY;
        }
        assert!(grey_pixels(&values) > 5000);
    }
}
