//! Overlays of detected corners on their image, for a person to check the detection: the
//! corners joined row by row in the order written (rows in changing colours, as OpenCV's
//! `drawChessboardCorners` draws them), corner 0 circled in red, the first row's direction as an
//! arrow, and a caption. Drawn with plotters.

use image::{GrayImage, RgbImage};
use nalgebra::Point2;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Colours of successive rows.
const ROW_COLOURS: [RGBColor; 6] = [
    RGBColor(255, 40, 40),
    RGBColor(255, 160, 0),
    RGBColor(220, 220, 0),
    RGBColor(40, 200, 40),
    RGBColor(0, 160, 255),
    RGBColor(190, 80, 255),
];

/// The image in colour with `corners` (row-major, `cols` per row; empty when none) drawn on it
/// and `caption` at the top; `warning` draws the caption in red.
pub fn overlay(
    image: &GrayImage,
    corners: &[Point2<f64>],
    cols: usize,
    caption: &str,
    warning: bool,
) -> RgbImage {
    super::plot::register_font();
    let (width, height) = image.dimensions();
    let mut buffer: Vec<u8> = image.as_raw().iter().flat_map(|&g| [g, g, g]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let at = |p: &Point2<f64>| (p.x.round() as i32, p.y.round() as i32);
        // Size of the marks from the spacing of the corners.
        let spacing = if corners.len() > 1 {
            (corners[1] - corners[0]).norm()
        } else {
            20.0
        };
        let radius = (spacing / 6.0).clamp(2.0, 8.0) as i32;
        for (r, row) in corners.chunks(cols.max(1)).enumerate() {
            let colour = ROW_COLOURS[r % ROW_COLOURS.len()];
            let _ = root.draw(&PathElement::new(
                row.iter().map(at).collect::<Vec<_>>(),
                colour.stroke_width(1),
            ));
            for p in row {
                let _ = root.draw(&Circle::new(at(p), radius, colour.stroke_width(1)));
            }
            // Join to the next row's first corner, as OpenCV does.
            if let (Some(last), Some(next)) = (row.last(), corners.get((r + 1) * cols)) {
                let _ = root.draw(&PathElement::new(
                    vec![at(last), at(next)],
                    colour.mix(0.5).stroke_width(1),
                ));
            }
        }
        if corners.len() >= cols && cols >= 2 {
            let (p0, p1) = (corners[0], corners[cols - 1]);
            let _ = root.draw(&Circle::new(at(&p0), 3 * radius, RED.stroke_width(3)));
            // The row direction: an arrow along the first row, from corner 0 to its last corner.
            let _ = root.draw(&PathElement::new(
                vec![at(&p0), at(&p1)],
                GREEN.stroke_width(3),
            ));
            let d = (p1 - p0).normalize();
            let n = nalgebra::Vector2::new(-d.y, d.x);
            let head = 4.0 * radius as f64;
            let wing = |s: f64| at(&(p1 - d * head + n * (s * head * 0.5)));
            let _ = root.draw(&PathElement::new(
                vec![wing(1.0), at(&p1), wing(-1.0)],
                GREEN.stroke_width(3),
            ));
            let label = ("sans-serif", 18)
                .into_font()
                .color(&RED)
                .pos(Pos::new(HPos::Left, VPos::Bottom));
            let _ = root.draw(&Text::new(
                "0",
                (at(&p0).0 + 3 * radius, at(&p0).1 - 3 * radius),
                label,
            ));
        }
        draw_caption(&root, width, caption, warning);
        let _ = root.present();
    }
    RgbImage::from_raw(width, height, buffer).expect("3 bytes a pixel")
}

/// The caption bar at the top, in red when `warning`.
fn draw_caption(
    root: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    width: u32,
    caption: &str,
    warning: bool,
) {
    let colour = if warning { RED } else { RGBColor(0, 220, 255) };
    let _ = root.draw(&Rectangle::new(
        [(0, 0), (width as i32, 30)],
        BLACK.mix(0.6).filled(),
    ));
    let style = ("sans-serif", 20)
        .into_font()
        .color(&colour)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let _ = root.draw(&Text::new(caption.to_string(), (8, 15), style));
}

/// The image in colour with corners that carry ids (a ChArUco board's: id = row·`cols` + column)
/// drawn on it, each row in its colour, neighbours in a row joined, every corner labelled with
/// its id; `caption` at the top, in red when `warning`.
pub fn overlay_ids(
    image: &GrayImage,
    corners: &[(usize, Point2<f64>)],
    cols: usize,
    caption: &str,
    warning: bool,
) -> RgbImage {
    super::plot::register_font();
    let (width, height) = image.dimensions();
    let cols = cols.max(1);
    let mut buffer: Vec<u8> = image.as_raw().iter().flat_map(|&g| [g, g, g]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let at = |p: &Point2<f64>| (p.x.round() as i32, p.y.round() as i32);
        // Size of the marks from the spacing of neighbours in a row.
        let spacing = corners
            .windows(2)
            .find(|w| w[1].0 == w[0].0 + 1 && w[1].0 % cols != 0)
            .map_or(20.0, |w| (w[1].1 - w[0].1).norm());
        let radius = (spacing / 6.0).clamp(2.0, 8.0) as i32;
        for (k, &(id, p)) in corners.iter().enumerate() {
            let colour = ROW_COLOURS[(id / cols) % ROW_COLOURS.len()];
            let _ = root.draw(&Circle::new(at(&p), radius, colour.stroke_width(2)));
            if let Some(&(next, q)) = corners.get(k + 1)
                && next == id + 1
                && next % cols != 0
            {
                let _ = root.draw(&PathElement::new(
                    vec![at(&p), at(&q)],
                    colour.stroke_width(1),
                ));
            }
            let label = ("sans-serif", 14)
                .into_font()
                .color(&colour)
                .pos(Pos::new(HPos::Left, VPos::Bottom));
            let _ = root.draw(&Text::new(
                id.to_string(),
                (at(&p).0 + radius, at(&p).1 - radius),
                label,
            ));
        }
        draw_caption(&root, width, caption, warning);
        let _ = root.present();
    }
    RgbImage::from_raw(width, height, buffer).expect("3 bytes a pixel")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_with_ids_are_drawn_where_they_are_and_nowhere_else() {
        let image = GrayImage::from_pixel(200, 160, image::Luma([128]));
        let corners = [(0, Point2::new(60.0, 80.0)), (1, Point2::new(100.0, 80.0))];
        let drawn = overlay_ids(&image, &corners, 6, "view 0", false);
        let grey = |x: u32, y: u32| {
            let p = drawn.get_pixel(x, y).0;
            p[0] == p[1] && p[1] == p[2]
        };
        // The circle of radius 40 / 6 ≈ 6 px round each corner is coloured, as is the row line.
        assert!(!grey(66, 80) && !grey(54, 80) && !grey(80, 80));
        assert!(grey(150, 140) && grey(20, 140), "far from the corners");
        assert!(
            drawn.get_pixel(5, 5).0[0] < 100,
            "the caption bar darkens the top"
        );
    }
}
