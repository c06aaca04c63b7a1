//! The report of a dense stereo run (`flatport stereo … --report-dir DIR`): one page
//! (`DIR/index.html`, offline, no framework) with the depth range and sampling each frame chose
//! and why, the completeness per frame, and each frame's depth and confidence as pictures; the
//! numbers as `frames.csv`.
//!
//! It reads each frame's `depth.npy` and `confidence.npy` back from the run's output folder, so
//! frames skipped by `--resume` are shown as well as those computed.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::html::{CHECK_SCRIPT, STYLE, escape, figure, number};
use super::pictures::{Area, ImageChart, Picture, file_safe, picture, plot_chart, text};
use super::{ReportError, Written};
use crate::io::npy::read_npy_f32;
use crate::io::stereo_files::{MapScale, write_map_png};
use crate::io::{IoError, write_atomic};

/// Frames drawn as pictures at most (spread evenly over the run); every frame is in the table.
pub const MAX_FRAME_PICTURES: usize = 12;

/// Completeness below which a frame is named under the warnings.
const LOW_COMPLETENESS: f64 = 0.3;

/// One frame of a stereo run, as its report shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoFrame {
    /// The frame's name (its output folder's).
    pub name: String,
    /// The folder holding its `depth.npy` and `confidence.npy`.
    pub folder: PathBuf,
    /// Share of the reference image's pixels with a point.
    pub valid_fraction: f64,
    /// Points returned.
    pub points: usize,
    /// Seconds the frame took (when it was computed).
    pub seconds: f64,
    /// Depth hypotheses per pixel.
    pub hypotheses: usize,
    /// The depth range swept, z in the reference camera, metres.
    pub depth_range_m: (f64, f64),
    /// How the range was chosen: `given`, `found` (a coarse sweep), or a fallback with its reason.
    pub range_how: String,
    /// The coarse sweep's confident depths between which the range was set (its quantiles),
    /// metres, where a sweep ran.
    pub quantiles_m: Option<(f64, f64)>,
    /// How the hypotheses were counted: `given` or `step rule`.
    pub count_how: String,
    /// The step rule's largest step between hypotheses, pixels, where the rule chose.
    pub largest_step_px: Option<f64>,
}

/// Everything a stereo report is made from.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoInput {
    /// The command that ran.
    pub command: String,
    /// The reference camera's name.
    pub reference: String,
    /// Where the sweep ran.
    pub device: String,
    /// The ZNCC window's side, pixels.
    pub window: usize,
    /// Least confidence of a returned point.
    pub min_confidence: f64,
    /// The frames, in order.
    pub frames: Vec<StereoFrame>,
}

/// The indices of at most `most` of `count` items, spread evenly (first and last included).
fn spread(count: usize, most: usize) -> Vec<usize> {
    if count <= most {
        return (0..count).collect();
    }
    let mut picked: Vec<usize> = (0..most)
        .map(|i| (i as f64 * (count - 1) as f64 / (most - 1).max(1) as f64).round() as usize)
        .collect();
    picked.dedup();
    picked
}

/// A frame's map read back: (height, width, values).
fn read_map(path: &Path) -> Result<(usize, usize, Vec<f64>), ReportError> {
    let (shape, values) = read_npy_f32(path)?;
    match shape[..] {
        [h, w] if h * w == values.len() => Ok((h, w, values.into_iter().map(f64::from).collect())),
        _ => Err(IoError::Invalid {
            path: path.to_path_buf(),
            field: "shape".into(),
            reason: format!("a map of shape (height, width) expected, found {shape:?}"),
        }
        .into()),
    }
}

/// Writes the report of a stereo run into `dir` (created).
pub fn write_stereo_report(dir: &Path, input: &StereoInput) -> Result<Written, ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    let mut overall = Vec::new();
    if !input.frames.is_empty() {
        picture(dir, "completeness.png", (960, 420), &mut files, |area| {
            completeness(area, input)
        })?;
        overall.push(Picture {
            file: "completeness.png".into(),
            caption: "Share of the reference image's pixels with a point, per frame.".into(),
        });
        picture(dir, "ranges.png", (960, 420), &mut files, |area| {
            ranges(area, input)
        })?;
        overall.push(Picture {
            file: "ranges.png".into(),
            caption: "The depth range each frame swept (bar) and the coarse sweep's confident depths it was set from (dots).".into(),
        });
    }
    let mut per_frame: Vec<(usize, Vec<Picture>)> = Vec::new();
    for i in spread(input.frames.len(), MAX_FRAME_PICTURES) {
        let frame = &input.frames[i];
        let name = file_safe(&frame.name);
        let mut own = Vec::new();
        for (file, label, unit, range, what) in [
            (
                "depth",
                "depth z",
                " m",
                None,
                "depth z in the reference camera (near dark, far bright; black: no point)",
            ),
            (
                "confidence",
                "confidence",
                "",
                Some((0.0, 1.0)),
                "confidence of each pixel's depth (0 to 1; a point is returned above the least confidence)",
            ),
        ] {
            let (h, w, values) = read_map(&frame.folder.join(format!("{file}.npy")))?;
            let out = format!("{file}_{i}_{name}.png");
            let path = dir.join(&out);
            write_map_png(
                &path,
                w as u32,
                h as u32,
                &values,
                &format!("{}: {label}", frame.name),
                &MapScale { label, unit, range },
            )?;
            files.push(path);
            own.push(Picture {
                file: out,
                caption: format!("{}: {what}.", frame.name),
            });
        }
        per_frame.push((i, own));
    }
    let page = page(input, &overall, &per_frame);
    let index = dir.join("index.html");
    write_atomic(&index, page.as_bytes())?;
    files.push(index.clone());
    let mut csv = String::from(
        "frame,valid_fraction,points,seconds,depth_min_m,depth_max_m,range_chosen,confident_low_m,confident_high_m,hypotheses,hypotheses_chosen,largest_step_px\n",
    );
    for f in &input.frames {
        let _ = writeln!(
            csv,
            "{},{:.5},{},{:.3},{:.5},{:.5},{},{},{},{},{},{}",
            f.name.replace(',', ";"),
            f.valid_fraction,
            f.points,
            f.seconds,
            f.depth_range_m.0,
            f.depth_range_m.1,
            f.range_how.replace(',', ";"),
            f.quantiles_m
                .map_or(String::new(), |q| format!("{:.5}", q.0)),
            f.quantiles_m
                .map_or(String::new(), |q| format!("{:.5}", q.1)),
            f.hypotheses,
            f.count_how.replace(',', ";"),
            f.largest_step_px
                .map_or(String::new(), |s| format!("{s:.3}")),
        );
    }
    let path = dir.join("frames.csv");
    write_atomic(&path, csv.as_bytes())?;
    files.push(path);
    Ok(Written {
        index,
        files,
        advice: None,
    })
}

/// The page.
fn page(input: &StereoInput, overall: &[Picture], per_frame: &[(usize, Vec<Picture>)]) -> String {
    let mut out = String::new();
    let title = "flatport dense stereo";
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title><style>{STYLE}</style><script>{CHECK_SCRIPT}</script></head><body>\n<h1>{title}</h1>\n"
    );
    if !input.command.is_empty() {
        let _ = writeln!(out, "<p><code>{}</code></p>", escape(&input.command));
    }
    let frames = &input.frames;
    let mean = |f: &dyn Fn(&StereoFrame) -> f64| {
        frames.iter().map(f).sum::<f64>() / frames.len().max(1) as f64
    };
    let _ = writeln!(
        out,
        "<p>{} frame(s), reference camera <b>{}</b>, {}; ZNCC window {w}×{w} px, least confidence {}. Mean completeness {} %.</p>",
        frames.len(),
        escape(&input.reference),
        escape(&input.device),
        number(input.min_confidence, 2),
        number(100.0 * mean(&|f| f.valid_fraction), 1),
        w = input.window,
    );
    out.push_str("<h2 id=\"sampling\">Range and sampling</h2>\n");
    let found = frames.iter().filter(|f| f.range_how == "found").count();
    let given = frames.iter().filter(|f| f.range_how == "given").count();
    let fallback = frames.len() - found - given;
    let _ = writeln!(
        out,
        "<p>Depth range: {found} frame(s) found it from their own images (a coarse sweep at most 160 px wide from where the cameras' views overlap out to 20 m; the range of its confident depths, padded), {given} were given it (<code>--depth</code>){}. Hypotheses: uniform in 1/z; {}.</p>",
        if fallback > 0 {
            format!(
                ", {fallback} fell back to the default range (too few confident depths: see the warnings)"
            )
        } else {
            String::new()
        },
        if frames.iter().all(|f| f.count_how == "given") {
            "as given (<code>--hypotheses</code>)".to_string()
        } else {
            "by the step rule: the fewest for which one step moves a hypothesis by at most 0.8 px in every voting camera over the whole range and image, 16 to 512".to_string()
        }
    );
    for p in overall {
        figure(&mut out, p);
    }
    out.push_str("<h2 id=\"frames\">Frames</h2>\n<table><tr><th class=\"l\">frame</th><th>pixels with a point (%)</th><th>points</th><th>depth range (m)</th><th class=\"l\">range</th><th>confident depths (m)</th><th>hypotheses</th><th>largest step (px)</th><th>seconds</th></tr>\n");
    for f in frames {
        let _ = writeln!(
            out,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{} – {}</td><td class=\"l\">{}</td><td>{}</td><td>{} ({})</td><td>{}</td><td>{}</td></tr>",
            escape(&f.name),
            number(100.0 * f.valid_fraction, 1),
            f.points,
            number(f.depth_range_m.0, 3),
            number(f.depth_range_m.1, 3),
            escape(&f.range_how),
            f.quantiles_m.map_or("—".into(), |q| format!(
                "{} – {}",
                number(q.0, 3),
                number(q.1, 3)
            )),
            f.hypotheses,
            escape(&f.count_how),
            f.largest_step_px.map_or("—".into(), |s| number(s, 2)),
            number(f.seconds, 1)
        );
    }
    out.push_str("</table>\n");
    out.push_str("<h2 id=\"maps\">Depth and confidence</h2>\n");
    if per_frame.len() < frames.len() {
        let _ = writeln!(
            out,
            "<p>{} of the {} frames, spread over the run; every frame's maps are in its folder (depth.npy, confidence.npy, depth.png).</p>",
            per_frame.len(),
            frames.len()
        );
    }
    for (i, pictures) in per_frame {
        let _ = writeln!(out, "<h3>{}</h3>", escape(&frames[*i].name));
        for p in pictures {
            figure(&mut out, p);
        }
    }
    let warnings: Vec<String> = frames
        .iter()
        .filter_map(|f| {
            if f.range_how != "found" && f.range_how != "given" {
                Some(format!(
                    "{}: the depth range was not found from the images ({}); set --depth MIN:MAX if the scene lies elsewhere",
                    f.name, f.range_how
                ))
            } else if f.valid_fraction < LOW_COMPLETENESS {
                Some(format!(
                    "{}: only {:.1} % of the pixels have a point: little texture, the views overlap little, or the range misses the scene",
                    f.name,
                    100.0 * f.valid_fraction
                ))
            } else {
                None
            }
        })
        .collect();
    if !warnings.is_empty() {
        out.push_str("<h2 id=\"notes\">Warnings</h2><ul>\n");
        for w in &warnings {
            let _ = writeln!(out, "<li>{}</li>", escape(w));
        }
        out.push_str("</ul>\n");
    }
    out.push_str("<h2>Files</h2><p>The numbers: <a href=\"frames.csv\">frames.csv</a>.</p>\n</body></html>\n");
    out
}

/// A chart over `n` frames (x: the frame, labelled from 1) and 0..`top` (y), its mesh drawn.
fn frames_chart<'a, 'b>(
    area: &'a Area<'b>,
    caption: &str,
    n: usize,
    top: f64,
    y_desc: &str,
) -> Result<ImageChart<'a, 'b>, String> {
    plot_chart(
        area,
        caption,
        -0.5..(n as f64 - 0.5),
        0.0..top,
        ("frame (in order, from 1)", y_desc),
        Some(n),
    )
}

/// Completeness per frame, as bars.
fn completeness(area: &Area, input: &StereoInput) -> Result<(), String> {
    let mut chart = frames_chart(
        area,
        "Completeness per frame",
        input.frames.len(),
        100.0,
        "pixels with a point (%)",
    )?;
    chart
        .draw_series(input.frames.iter().enumerate().map(|(i, f)| {
            let x = i as f64;
            let colour = if f.valid_fraction < LOW_COMPLETENESS {
                RED
            } else {
                RGBColor(31, 119, 180)
            };
            Rectangle::new(
                [(x - 0.4, 0.0), (x + 0.4, 100.0 * f.valid_fraction)],
                colour.filled(),
            )
        }))
        .map_err(text)?;
    Ok(())
}

/// The depth range per frame (a bar from near to far) and the coarse sweep's confident depths.
fn ranges(area: &Area, input: &StereoInput) -> Result<(), String> {
    let n = input.frames.len();
    let high = input
        .frames
        .iter()
        .map(|f| f.depth_range_m.1)
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        .max(1e-3)
        * 1.08;
    let mut chart = frames_chart(
        area,
        "Depth range per frame",
        n,
        high,
        "depth z in the reference camera (m)",
    )?;
    chart
        .draw_series(input.frames.iter().enumerate().map(|(i, f)| {
            let x = i as f64;
            Rectangle::new(
                [(x - 0.3, f.depth_range_m.0), (x + 0.3, f.depth_range_m.1)],
                RGBColor(31, 119, 180).mix(0.5).filled(),
            )
        }))
        .map_err(text)?;
    chart
        .draw_series(
            input
                .frames
                .iter()
                .enumerate()
                .filter_map(|(i, f)| f.quantiles_m.map(|q| (i, q)))
                .flat_map(|(i, q)| {
                    [q.0, q.1].map(|y| Circle::new((i as f64, y), 4, BLACK.filled()))
                }),
        )
        .map_err(text)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_spread_with_both_ends() {
        assert_eq!(spread(3, 12), vec![0, 1, 2]);
        let picked = spread(100, 12);
        assert_eq!(picked.len(), 12);
        assert_eq!((picked[0], picked[11]), (0, 99));
        assert!(picked.windows(2).all(|w| w[0] < w[1]));
    }
}
