//! PNG pictures of cost surfaces: a heat map over tilt × azimuth and a polar view of the axis
//! (tilt as radius, azimuth as angle, as seen looking along the master camera: x right, y down).
//! Drawn with plotters into memory, encoded with png, written atomically; the font (DejaVu Sans)
//! is built in, so no system fonts are needed.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{IoError, write_atomic};

/// One surface over tilt × azimuth.
#[derive(Debug, Clone)]
pub struct CostMap<'a> {
    /// Tilt values of the rows, degrees (ascending).
    pub tilts_deg: &'a [f64],
    /// Azimuth values of the columns, degrees (ascending).
    pub azimuths_deg: &'a [f64],
    /// values[row · azimuths + column]; non-finite cells are drawn grey.
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

const FONT: &[u8] = include_bytes!("../../data/fonts/DejaVuSans.ttf");

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and valid; a failure would only lose the labels.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Viridis, sampled at 9 points (matplotlib's table) and interpolated linearly.
fn viridis(t: f64) -> RGBColor {
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

/// How values map to colours: linear, or log10 when positive and spanning over two decades.
struct Scale {
    low: f64,
    high: f64,
    log: bool,
}

impl Scale {
    fn of(values: &[f64]) -> Self {
        let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        let low = finite.iter().copied().fold(f64::INFINITY, f64::min);
        let high = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let log = low > 0.0 && high / low > 100.0;
        let (low, high) = if log { (low.log10(), high.log10()) } else { (low, high) };
        let (low, high) = if !(high > low) { (low - 0.5, low + 0.5) } else { (low, high) };
        Self { low, high, log }
    }

    fn colour(&self, v: f64) -> RGBColor {
        if !v.is_finite() {
            return RGBColor(190, 190, 190);
        }
        let x = if self.log { v.log10() } else { v };
        viridis((x - self.low) / (self.high - self.low))
    }
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

fn draw_error(e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(format!("drawing failed: {e}"))
}

/// The colour bar at the right of a picture.
fn colour_bar(area: &Area, scale: &Scale, label: &str) -> Result<(), std::io::Error> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(50)
        .margin_bottom(60)
        .margin_right(10)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, scale.low..scale.high)
        .map_err(draw_error)?;
    let log = scale.log;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(if log { format!("log₁₀ {label}") } else { label.to_string() })
        .y_label_formatter(&|v| format!("{v:.3}"))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(draw_error)?;
    let steps = 200;
    chart
        .draw_series((0..steps).map(|i| {
            let y0 = scale.low + (scale.high - scale.low) * i as f64 / steps as f64;
            let y1 = scale.low + (scale.high - scale.low) * (i + 1) as f64 / steps as f64;
            Rectangle::new([(0.0, y0), (1.0, y1)], viridis(i as f64 / (steps - 1) as f64).filled())
        }))
        .map_err(draw_error)?;
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

fn encode(path: &Path, buffer: &[u8], (width, height): (u32, u32)) -> Result<(), IoError> {
    let err = |source| IoError::Write { path: path.to_path_buf(), source };
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| err(std::io::Error::other(e)))?;
        writer.write_image_data(buffer).map_err(|e| err(std::io::Error::other(e)))?;
    }
    write_atomic(path, &bytes)
}

fn markers<'c, DB: DrawingBackend + 'c>(
    chart: &mut ChartContext<'c, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>>,
    map: &CostMap,
    at: impl Fn(f64, f64) -> (f64, f64),
) -> Result<(), std::io::Error> {
    if let Some((t, a)) = map.truth {
        chart
            .draw_series([Circle::new(at(t, a), 9, ShapeStyle::from(&RED).stroke_width(3))])
            .map_err(draw_error)?
            .label("truth")
            .legend(|(x, y)| Circle::new((x + 8, y), 6, ShapeStyle::from(&RED).stroke_width(3)));
    }
    if let Some((t, a)) = map.minimum {
        chart
            .draw_series([Cross::new(at(t, a), 8, ShapeStyle::from(&WHITE).stroke_width(3))])
            .map_err(draw_error)?
            .label(format!("minimum: tilt {t:.2}°, azimuth {a:.2}°"))
            .legend(|(x, y)| Cross::new((x + 8, y), 6, ShapeStyle::from(&BLACK).stroke_width(3)));
    }
    if map.truth.is_some() || map.minimum.is_some() {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(SeriesLabelPosition::UpperRight)
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
    let err = |source| IoError::Write { path: path.to_path_buf(), source };
    {
        let root = BitMapBackend::with_buffer(&mut buffer, size).into_drawing_area();
        root.fill(&WHITE).map_err(draw_error).map_err(err)?;
        let (main, bar) = root.split_horizontally(size.0 - 130);
        let scale = Scale::of(map.values);
        draw(&main, &scale).map_err(err)?;
        colour_bar(&bar, &scale, &map.cost_label).map_err(err)?;
        root.present().map_err(draw_error).map_err(err)?;
    }
    encode(path, &buffer, size)
}

/// Heat map: azimuth across, tilt up, colour bar at the right, the minimum marked with a cross and
/// the truth with a circle.
pub fn write_heatmap(path: &Path, map: &CostMap) -> Result<(), IoError> {
    render(path, (960, 720), map, |main, scale| {
        let (xe, ye) = (edges(map.azimuths_deg), edges(map.tilts_deg));
        let mut chart = ChartBuilder::on(main)
            .caption(&map.title, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(xe[0]..*xe.last().expect("edges"), ye[0]..*ye.last().expect("edges"))
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
        chart
            .draw_series((0..map.values.len()).map(|k| {
                let (r, c) = (k / columns, k % columns);
                Rectangle::new([(xe[c], ye[r]), (xe[c + 1], ye[r + 1])], scale.colour(map.values[k]).filled())
            }))
            .map_err(draw_error)?;
        markers(&mut chart, map, |t, a| (a, t))
    })
}

/// Polar view: the axis as a point on the disc of tilts, azimuth measured from +x toward +y of
/// the master camera (x right, y down as in its image); rings every few degrees of tilt.
pub fn write_polar(path: &Path, map: &CostMap) -> Result<(), IoError> {
    render(path, (860, 720), map, |main, scale| {
        let (ae, te) = (edges(map.azimuths_deg), edges(map.tilts_deg));
        let radius = te.last().expect("edges").max(1e-9);
        let at = |t: f64, a: f64| {
            let a = a.to_radians();
            (t.max(0.0) * a.cos(), -t.max(0.0) * a.sin())
        };
        let mut chart = ChartBuilder::on(main)
            .caption(&map.title, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-radius..radius, -radius..radius)
            .map_err(draw_error)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("tilt toward +x (°)")
            .y_desc("tilt toward −y, up in the image (°)")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(draw_error)?;
        let columns = map.azimuths_deg.len();
        let arc = 4;
        chart
            .draw_series((0..map.values.len()).map(|k| {
                let (r, c) = (k / columns, k % columns);
                let (t0, t1) = (te[r].max(0.0), te[r + 1]);
                let mut points: Vec<(f64, f64)> = (0..=arc).map(|i| at(t1, ae[c] + (ae[c + 1] - ae[c]) * i as f64 / arc as f64)).collect();
                points.extend((0..=arc).rev().map(|i| at(t0, ae[c] + (ae[c + 1] - ae[c]) * i as f64 / arc as f64)));
                Polygon::new(points, scale.colour(map.values[k]).filled())
            }))
            .map_err(draw_error)?;
        // Rings of equal tilt, with labels.
        let ring_step = [1.0, 2.0, 5.0, 10.0, 15.0, 20.0].into_iter().find(|s| radius / s <= 6.0).unwrap_or(30.0);
        let mut t = ring_step;
        while t <= radius + 1e-9 {
            let ring: Vec<(f64, f64)> = (0..=120).map(|i| at(t, i as f64 * 3.0)).collect();
            chart.draw_series([PathElement::new(ring, WHITE.mix(0.6))]).map_err(draw_error)?;
            chart.draw_series([Text::new(format!("{t}°"), at(t, 45.0), ("sans-serif", 13).into_font().color(&WHITE))]).map_err(draw_error)?;
            t += ring_step;
        }
        markers(&mut chart, map, at)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pictures_are_pngs_of_the_stated_size() {
        let tilts: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let azimuths: Vec<f64> = (0..36).map(|i| -180.0 + 10.0 * i as f64).collect();
        let values: Vec<f64> = (0..tilts.len() * azimuths.len()).map(|k| if k == 5 { f64::INFINITY } else { 1.0 + k as f64 }).collect();
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
            if name == "h.png" { write_heatmap(&path, &map).unwrap() } else { write_polar(&path, &map).unwrap() }
            let decoder = png::Decoder::new(std::fs::File::open(&path).unwrap());
            let reader = decoder.read_info().unwrap();
            assert_eq!((reader.info().width, reader.info().height), size);
        }
        assert!((viridis(0.0).0, viridis(1.0).1) == (68, 231));
    }
}
