//! The report's page (plain HTML written here, no framework, no network) and its numbers (JSON,
//! CSV).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::json;

use super::advice::CandidateKind;
use super::pictures::{Picture, Pictures};
use super::{Facts, ReportError};
use crate::io::write_atomic;

/// `s` with the HTML specials escaped.
pub(crate) fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A number with `digits` decimals, `—` when not finite.
pub(crate) fn number(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "—".into()
    }
}

pub(crate) const STYLE: &str = "body{font-family:sans-serif;max-width:1400px;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.2em .5em;text-align:right}
th{background:#f0f0f0}td.l,th.l{text-align:left}figure{display:inline-block;margin:.5em;vertical-align:top;max-width:660px}
figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.85em;color:#555}
.good{color:#1a7f37}.usable{color:#b58100}.poor{color:#c62828}.verdict{font-size:1.3em;font-weight:bold}
.advice{background:#fff8e1;border-left:4px solid #f0a000;padding:.5em 1em}code{background:#f4f4f4;padding:0 .2em}";

/// A small script that writes each picture's decoded size into the page (`data-natural`), so a
/// headless browser's DOM says whether every picture loaded.
pub(crate) const CHECK_SCRIPT: &str = "window.addEventListener('load',function(){var n=0,imgs=document.images;for(var i=0;i<imgs.length;i++){var im=imgs[i];im.setAttribute('data-natural',im.naturalWidth+'x'+im.naturalHeight);if(im.complete&&im.naturalWidth>0){n++;}}document.body.setAttribute('data-images-loaded',n+'/'+imgs.length);});";

pub(crate) fn figure(out: &mut String, picture: &Picture) {
    let _ = writeln!(
        out,
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        escape(&picture.file),
        escape(&picture.caption),
        escape(&picture.caption)
    );
}

/// The page.
pub(crate) fn page(facts: &Facts, pictures: &Pictures) -> String {
    let input = facts.input;
    let rig = input.rig;
    let mut out = String::new();
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style><script>{CHECK_SCRIPT}</script></head><body>\n<h1>{}</h1>\n",
        escape(&input.title),
        escape(&input.title)
    );
    if !input.command.is_empty() {
        let _ = writeln!(out, "<p><code>{}</code></p>", escape(&input.command));
    }
    // The verdict.
    out.push_str("<h2 id=\"verdict\">Verdict</h2>\n");
    match &input.verdict {
        Some(v) => {
            let grade = v.grade.name();
            let _ = writeln!(
                out,
                "<p class=\"verdict {grade}\">{grade}</p><ul>{}</ul>",
                v.why
                    .iter()
                    .map(|w| format!("<li>{}</li>", escape(w)))
                    .collect::<String>()
            );
        }
        None => match input.report {
            Some(r) => {
                let _ = writeln!(
                    out,
                    "<p class=\"verdict {}\">{}</p><p>This route judges the fit by its own residuals alone (no held-out frames).</p>",
                    if r.fits { "usable" } else { "poor" },
                    if r.fits { "fits" } else { "does not fit" }
                );
            }
            None => out.push_str("<p>No verdict on this route.</p>\n"),
        },
    }
    // The advice.
    out.push_str("<h2 id=\"advice\">What footage to add</h2>\n<div class=\"advice\">\n");
    match &facts.advice {
        Some(a) => {
            for line in &a.text {
                let _ = writeln!(out, "<p>{}</p>", escape(line));
            }
            let what = if input.targetless.is_some() {
                "patches of texture (5 distances × 9 places in the master's image, each seen as the calibrated rig sees it, weighed as the matches your footage gives there per frame)"
            } else {
                "views (the board at 5 distances × 5 tilts × 9 places in each camera's image, posed from the calibrated rig)"
            };
            let _ = writeln!(
                out,
                "<p><small>From the fit's information matrix: {} candidate {what} were each added to the normal equations; the one that shrinks the worst parameter's σ most is advised.</small></p>",
                a.candidates
            );
        }
        None => out.push_str(
            "<p>No advice: this route keeps no information matrix of board views here.</p>\n",
        ),
    }
    out.push_str("</div>\n");
    // The rig.
    out.push_str("<h2 id=\"rig\">The rig</h2>\n");
    for p in &pictures.rig {
        figure(&mut out, p);
    }
    // Parameters.
    out.push_str("<h2 id=\"parameters\">Estimated parameters</h2>\n");
    match facts.advice.as_ref().filter(|a| !a.parameters.is_empty()) {
        Some(a) => {
            out.push_str("<table><tr><th class=\"l\">parameter</th><th>σ</th><th>needed</th><th>σ / needed</th><th class=\"l\">trades off with (ρ)</th></tr>\n");
            for (i, p) in a.parameters.iter().enumerate() {
                let worst = a.worst == Some(i);
                let _ = writeln!(
                    out,
                    "<tr{}><td class=\"l\">{}</td><td>{} {}</td><td>{} {}</td><td>{}</td><td class=\"l\">{}</td></tr>",
                    if worst {
                        " style=\"background:#fff3cd\""
                    } else {
                        ""
                    },
                    escape(&p.name),
                    number(p.sigma * p.scale, 4),
                    p.unit,
                    number(p.tolerance * p.scale, 4),
                    p.unit,
                    number(p.relative(), 2),
                    p.correlations
                        .iter()
                        .map(|(n, r)| format!("{} ({r:+.2})", escape(n)))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
            let eliminated = if input.targetless.is_some() {
                "the scene's points eliminated; σ̂² is the residual variance times the matches' patch overlap"
            } else {
                "board poses eliminated"
            };
            let _ = write!(
                out,
                "</table>\n<p><small>σ from the fit's information matrix ({eliminated}) times σ̂²;"
            );
            out.push_str(" an axis is moved in its tangent plane (two directions); “needed”: a third of issue 38's bounds for the ports (0.1° of axis, 1.5 mm of air, 0.3 mm for a surface), 0.02° and 0.5 mm for the extrinsics.</small></p>\n");
        }
        None if input.sigma_rows.is_empty() => {
            out.push_str("<p>No standard deviations on this route.</p>\n")
        }
        None => {}
    }
    if !input.sigma_rows.is_empty() {
        out.push_str("<table><tr><th class=\"l\">port</th><th>value</th><th>σ</th></tr>\n");
        for (n, v, s) in &input.sigma_rows {
            let _ = writeln!(
                out,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td></tr>",
                escape(n),
                escape(v),
                escape(s)
            );
        }
        out.push_str("</table>\n");
    }
    if let Some(report) = input.report {
        out.push_str("<table><tr><th class=\"l\">port</th><th>tilt (°)</th><th>azimuth (°)</th><th>air distance (mm)</th><th>layers (mm)</th></tr>\n");
        for p in &report.ports {
            let pm = |e: &crate::calib::pipeline::report::Estimated, scale: f64| {
                format!(
                    "{}{}",
                    number(e.value * scale, 3),
                    e.std
                        .map_or(String::new(), |s| format!(" ± {}", number(s * scale, 3)))
                )
            };
            let _ = writeln!(
                out,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                escape(&p.name),
                pm(&p.tilt, 180.0 / std::f64::consts::PI),
                pm(&p.azimuth, 180.0 / std::f64::consts::PI),
                pm(&p.distance, 1e3),
                p.thicknesses
                    .iter()
                    .map(|t| pm(t, 1e3))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        out.push_str("</table>\n");
    }
    // Per camera.
    out.push_str("<h2 id=\"cameras\">Per camera</h2>\n");
    if let Some(report) = input.report {
        out.push_str("<table><tr><th class=\"l\">camera</th><th>frames</th><th>corners</th><th>RMS (px)</th><th>RMS without outliers (px)</th></tr>\n");
        for c in &report.cameras {
            let _ = writeln!(
                out,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                escape(&c.name),
                c.views,
                c.observations,
                number(c.rms_px, 3),
                number(c.inlier_rms_px, 3)
            );
        }
        out.push_str("</table>\n");
        let _ = writeln!(
            out,
            "<p>σ̂ {} px; corner noise seen in the images {} px; RMS over every corner {} px.{}</p>",
            report.sigma_px.map_or("—".into(), |s| number(s, 3)),
            report.noise_px.map_or("—".into(), |s| number(s, 3)),
            number(report.rms_px, 3),
            report
                .sigma_from_scatter
                .as_ref()
                .map_or(String::new(), |(parameter, factor)| format!(
                    " The views scatter more than σ̂ says: σ raised to what they say, up to ×{} ({}).",
                    number(*factor, 2),
                    escape(parameter)
                ))
        );
    } else if !facts.corners.is_empty() {
        out.push_str(
            "<table><tr><th class=\"l\">camera</th><th>matches</th><th>RMS (px)</th></tr>\n",
        );
        for (k, c) in rig.cameras().iter().enumerate() {
            let own: Vec<f64> = facts
                .corners
                .iter()
                .filter(|x| x.camera == k)
                .map(|x| x.residual.norm_squared())
                .collect();
            let rms = (!own.is_empty())
                .then(|| (own.iter().sum::<f64>() / (2 * own.len()) as f64).sqrt());
            let _ = writeln!(
                out,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td></tr>",
                escape(&c.name),
                own.len(),
                rms.map_or("—".into(), |r| number(r, 3))
            );
        }
        out.push_str("</table>\n");
    }
    for (k, camera) in rig.cameras().iter().enumerate() {
        let _ = writeln!(out, "<h3>{}</h3>", escape(&camera.name));
        if !facts.corners.iter().any(|c| c.camera == k) {
            out.push_str("<p>This camera has no corner in the fitted frames at hand.</p>\n");
        }
        for p in pictures.cameras.get(k).into_iter().flatten() {
            figure(&mut out, p);
        }
    }
    // Frames.
    out.push_str("<h2 id=\"frames\">Frames</h2>\n");
    for p in &pictures.overall {
        figure(&mut out, p);
    }
    if !facts.frame_rms.is_empty() {
        let labels: Vec<&str> = facts.frame_labels.iter().map(String::as_str).collect();
        out.push_str("<table><tr><th class=\"l\">frame</th>");
        for c in rig.cameras() {
            let _ = write!(out, "<th>{} RMS (px)</th>", escape(&c.name));
        }
        out.push_str("<th class=\"l\">outlier corners</th></tr>\n");
        for (f, rms) in facts.frame_rms.iter().enumerate() {
            let _ = write!(
                out,
                "<tr><td class=\"l\">{}</td>",
                escape(labels.get(f).copied().unwrap_or("?"))
            );
            for r in rms {
                let _ = write!(out, "<td>{}</td>", r.map_or("—".into(), |r| number(r, 3)));
            }
            let outliers = facts
                .corners
                .iter()
                .filter(|c| c.frame == f && c.outlier)
                .map(|c| format!("{} #{}", rig.cameras()[c.camera].name, c.corner))
                .collect::<Vec<_>>();
            let _ = writeln!(
                out,
                "<td class=\"l\">{}</td></tr>",
                escape(&outliers.join(", "))
            );
        }
        out.push_str("</table>\n");
    }
    depth_table(&mut out, facts);
    if !input.left_out.is_empty() {
        out.push_str("<h3>Left out of the fit</h3><ul>\n");
        for (what, why) in &input.left_out {
            let _ = writeln!(
                out,
                "<li>{}{}</li>",
                escape(what),
                if why.is_empty() {
                    String::new()
                } else {
                    format!(": {}", escape(why))
                }
            );
        }
        out.push_str("</ul>\n");
    }
    // Held out.
    out.push_str("<h2 id=\"held-out\">Held-out frames</h2>\n");
    match &facts.held_out_note {
        Some(note) if facts.held_out.is_empty() => {
            let _ = writeln!(out, "<p>None: {}.</p>", escape(note));
        }
        _ => {
            out.push_str("<table><tr><th class=\"l\">frame</th><th>distance (m)</th><th>reprojection RMS (px)</th><th>squares</th><th>squares' RMS error (mm)</th></tr>\n");
            let mut rows: Vec<_> = facts.held_out.iter().collect();
            rows.sort_by(|a, b| {
                a.depth_m
                    .unwrap_or(f64::INFINITY)
                    .total_cmp(&b.depth_m.unwrap_or(f64::INFINITY))
            });
            for f in rows {
                let n = f.square_errors.len();
                let rms = (n > 0).then(|| {
                    1e3 * (f.square_errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt()
                });
                let _ = writeln!(
                    out,
                    "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{n}</td><td>{}</td></tr>",
                    escape(&f.label),
                    f.depth_m.map_or("—".into(), |d| number(d, 3)),
                    f.rms_px.map_or("—".into(), |r| number(r, 3)),
                    rms.map_or("—".into(), |r| number(r, 3))
                );
            }
            out.push_str("</table>\n");
        }
    }
    if !input.notes.is_empty() {
        out.push_str("<h2 id=\"notes\">Warnings</h2><ul>\n");
        for n in &input.notes {
            let _ = writeln!(out, "<li>{}</li>", escape(n));
        }
        out.push_str("</ul>\n");
    }
    out.push_str("<h2>Files</h2><p>The numbers: <a href=\"report.json\">report.json</a>, <a href=\"residuals.csv\">residuals.csv</a>, <a href=\"parameters.csv\">parameters.csv</a>, <a href=\"frames.csv\">frames.csv</a>.</p>\n</body></html>\n");
    out
}

/// Bins of the fitted corners' distance from their camera.
const DEPTH_BINS: usize = 5;

/// The fitted corners' RMS residual per camera over [`DEPTH_BINS`] equal bins of their distance
/// from the camera (outliers left out).
fn depth_table(out: &mut String, facts: &Facts) {
    let corners: Vec<_> = facts
        .corners
        .iter()
        .filter(|c| !c.outlier && c.depth_m.is_finite())
        .collect();
    let Some(low) = corners.iter().map(|c| c.depth_m).min_by(f64::total_cmp) else {
        return;
    };
    let high = corners.iter().map(|c| c.depth_m).fold(low, f64::max);
    let width = ((high - low) / DEPTH_BINS as f64).max(1e-9);
    let cameras = facts.input.rig.cameras();
    let mut sums = vec![vec![(0.0, 0usize); cameras.len()]; DEPTH_BINS];
    for c in &corners {
        let bin = (((c.depth_m - low) / width) as usize).min(DEPTH_BINS - 1);
        sums[bin][c.camera].0 += c.residual.norm_squared() / 2.0;
        sums[bin][c.camera].1 += 1;
    }
    out.push_str("<h3>Residuals by distance</h3>\n<table><tr><th class=\"l\">distance from the camera (m)</th>");
    for c in cameras {
        let _ = write!(out, "<th>{} RMS (px)</th><th>corners</th>", escape(&c.name));
    }
    out.push_str("</tr>\n");
    for (b, row) in sums.iter().enumerate() {
        let _ = write!(
            out,
            "<tr><td class=\"l\">{} – {}</td>",
            number(low + b as f64 * width, 2),
            number(low + (b + 1) as f64 * width, 2)
        );
        for &(sum, n) in row {
            let rms = if n > 0 {
                number((sum / n as f64).sqrt(), 3)
            } else {
                "—".into()
            };
            let _ = write!(out, "<td>{rms}</td><td>{n}</td>");
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</table>\n");
}

/// `report.json` (the summary, the parameters and the advice), `residuals.csv`,
/// `parameters.csv`, `frames.csv`.
pub(crate) fn write_numbers(
    dir: &Path,
    facts: &Facts,
    files: &mut Vec<PathBuf>,
) -> Result<(), ReportError> {
    let input = facts.input;
    let rig = input.rig;
    let mut write = |name: &str, text: String| -> Result<(), ReportError> {
        let path = dir.join(name);
        write_atomic(&path, text.as_bytes())?;
        files.push(path);
        Ok(())
    };
    let mut residuals =
        String::from("camera,frame,corner,u_px,v_px,du_px,dv_px,distance_m,tilt_deg,outlier\n");
    for c in &facts.corners {
        let _ = writeln!(
            residuals,
            "{},{},{},{:.4},{:.4},{:.5},{:.5},{:.4},{},{}",
            rig.cameras()[c.camera].name,
            facts
                .frame_labels
                .get(c.frame)
                .map_or("?", String::as_str)
                .replace(',', ";"),
            c.corner,
            c.observed.x,
            c.observed.y,
            c.residual.x,
            c.residual.y,
            c.depth_m,
            c.tilt_deg.map_or(String::new(), |t| format!("{t:.2}")),
            c.outlier
        );
    }
    write("residuals.csv", residuals)?;
    let mut parameters = String::from("parameter,sigma,unit,tolerance,relative,correlations\n");
    let advice = facts.advice.as_ref();
    for p in advice.iter().flat_map(|a| &a.parameters) {
        let _ = writeln!(
            parameters,
            "{},{:.6},{},{:.6},{:.3},{}",
            p.name,
            p.sigma * p.scale,
            p.unit,
            p.tolerance * p.scale,
            p.relative(),
            p.correlations
                .iter()
                .map(|(n, r)| format!("{n} {r:+.3}"))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    write("parameters.csv", parameters)?;
    let mut frames = String::from("frame,camera,rms_px\n");
    for (f, rms) in facts.frame_rms.iter().enumerate() {
        for (k, r) in rms.iter().enumerate() {
            if let Some(r) = r {
                let _ = writeln!(
                    frames,
                    "{},{},{r:.5}",
                    input
                        .fitted
                        .get(f)
                        .map_or("?", |(l, _)| l.as_str())
                        .replace(',', ";"),
                    rig.cameras()[k].name
                );
            }
        }
    }
    write("frames.csv", frames)?;
    let summary = json!({
        "title": input.title,
        "command": input.command,
        "verdict": input.verdict.as_ref().map(|v| json!({"grade": v.grade.name(), "why": v.why})),
        "fits": input.report.map(|r| r.fits),
        "rms_px": input.report.map(|r| r.rms_px),
        "sigma_px": input.report.and_then(|r| r.sigma_px),
        "sigma_from_scatter": input.report.and_then(|r| r.sigma_from_scatter.as_ref()).map(|(p, f)| json!({"parameter": p, "factor": f})),
        "parameters": advice.iter().flat_map(|a| &a.parameters).map(|p| json!({
            "name": p.name,
            "sigma": p.sigma * p.scale,
            "unit": p.unit,
            "tolerance": p.tolerance * p.scale,
            "correlations": p.correlations.iter().map(|(n, r)| json!({"with": n, "rho": r})).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "advice": advice.map(|a| json!({
            "text": a.text,
            "worst": a.worst.map(|w| a.parameters[w].name.clone()),
            "candidates": a.candidates,
            "view": a.best.as_ref().map(|(c, after, repeated)| json!({
                "kind": match c.kind { CandidateKind::Board => "board", CandidateKind::Texture { .. } => "texture" },
                "matches": match c.kind { CandidateKind::Texture { matches, .. } => Some(matches), CandidateKind::Board => None },
                "camera": rig.cameras()[c.camera].name,
                "distance_m": c.distance_m,
                "tilt_deg": c.tilt_deg,
                "tilt_axis": c.tilt_axis.to_string(),
                "place": c.place(),
                "pixel": [c.pixel.x, c.pixel.y],
                "sigma_after_one": after * a.worst.map_or(1.0, |w| a.parameters[w].scale),
                "sigma_after_repeats": repeated * a.worst.map_or(1.0, |w| a.parameters[w].scale),
                "repeats": super::advice::REPEATS,
                "rotation": c.master_from_target.rotation.to_rotation_matrix().matrix().row_iter().map(|r| [r[0], r[1], r[2]]).collect::<Vec<_>>(),
                "translation": c.master_from_target.translation.vector.as_slice(),
            })),
        })),
        "held_out": facts.held_out.iter().map(|f| json!({
            "frame": f.label,
            "distance_m": f.depth_m,
            "rms_px": f.rms_px,
            "squares": f.square_errors.len(),
        })).collect::<Vec<_>>(),
        "left_out": input.left_out.iter().map(|(w, y)| json!({"what": w, "why": y})).collect::<Vec<_>>(),
    });
    write(
        "report.json",
        serde_json::to_string_pretty(&summary).unwrap_or_default(),
    )?;
    Ok(())
}
