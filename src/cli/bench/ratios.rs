//! The ratios between the figures of one run, printed after them (no verdicts: the goals, and
//! the outside references they were set against, are in docs/performance.md).

use super::gpu::STENCIL;
use super::record::Figure;

/// Ratios between the paths of this run, without verdicts: the speed goals, and the outside
/// reference they were set against, are in docs/performance.md, "Speed goals" (this command
/// cannot run that reference, so it does not compare against it).
pub(super) fn print_ratios(results: &[Figure], stream: f64, threads: usize) {
    // A CPU figure is the vector path's unless `scalar` is asked for.
    let rate_on = |kernel: &str,
                   path: &str,
                   cpu_path: Option<&str>,
                   precision: &str,
                   threads: Option<usize>,
                   stage: &str| {
        results
            .iter()
            .find(|f| {
                f.kernel == kernel
                    && f.path == path
                    && (path != "cpu" || f.cpu_path.is_none() || f.cpu_path == cpu_path)
                    && f.precision == precision
                    && threads.is_none_or(|t| f.threads == t)
                    && f.stage == stage
            })
            .map(|f| f.items_per_s)
    };
    let rate = |kernel: &str, path: &str, precision: &str, threads: Option<usize>, stage: &str| {
        rate_on(kernel, path, Some("vector"), precision, threads, stage)
    };
    outln!("\nratios from this run (the goals are in docs/performance.md, \"Speed goals\"):");
    let cpu_all = |k: &str| rate(k, "cpu", "f64", Some(threads), "end_to_end");
    let show = |name: &str, value: Option<f64>| match value {
        Some(v) => outln!("  {name:72} {v:8.2}"),
        None => outln!("  {name:72}      n/a"),
    };
    let ratio = |x: Option<f64>, y: Option<f64>| x.zip(y).map(|(x, y)| x / y);
    for kernel in [
        "backproject",
        "backproject_pinhole",
        "project",
        "triangulate",
        "vop",
    ] {
        for t in [1, threads] {
            let vector = rate_on(kernel, "cpu", Some("vector"), "f64", Some(t), "end_to_end");
            let scalar = rate_on(kernel, "cpu", Some("scalar"), "f64", Some(t), "end_to_end");
            show(
                &format!("{kernel} CPU vector / scalar, {t} thread(s)"),
                ratio(vector, scalar),
            );
        }
    }
    show(
        "backproject GPU f32 kernel / CPU f64 all threads",
        ratio(
            rate("backproject", "gpu", "f32", None, "kernel"),
            cpu_all("backproject"),
        ),
    );
    show(
        "backproject GPU f32 end to end / CPU f64 all threads",
        ratio(
            rate("backproject", "gpu", "f32", None, "end_to_end"),
            cpu_all("backproject"),
        ),
    );
    let best = results
        .iter()
        .filter(|f| f.kernel == "backproject")
        .map(|f| f.items_per_s)
        .fold(0.0, f64::max);
    show(
        "best backproject × 24 B / memory streaming bandwidth",
        Some(best * 24.0 / stream),
    );
    show(
        "project GPU f32 end to end / CPU f64 all threads",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 end to end, f32 host data / CPU f64 all threads",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end_f32_host"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 kernel alone / CPU f64 all threads (the end-to-end ceiling)",
        ratio(
            rate("project", "gpu", "f32", None, "kernel"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 end to end: streamed / one chunk without overlap",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end_streamed"),
            rate("project", "gpu", "f32", None, "end_to_end_one_chunk"),
        ),
    );
    show(
        "project GPU f32 end to end / GPU f32 kernel alone",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end"),
            rate("project", "gpu", "f32", None, "kernel"),
        ),
    );
    for precision in ["f32", "f64"] {
        show(
            &format!("chain_triangulate GPU {precision} kernel: fused / three kernels (unfused)"),
            ratio(
                rate("chain_triangulate", "gpu", precision, None, "kernel"),
                rate(
                    "chain_triangulate_unfused",
                    "gpu",
                    precision,
                    None,
                    "kernel",
                ),
            ),
        );
    }
    for kernel in ["stencil_reprojection", "stencil_affine_grid"] {
        let resident = rate(kernel, "gpu", "f64", None, "resident");
        let uploaded = rate(kernel, "gpu", "f64", None, "uploaded_each_call");
        let per_call = |r: Option<f64>| r.map(|r| 1e3 * STENCIL as f64 / r);
        show(
            &format!("{kernel} (GPU f64, {STENCIL} candidates): ms per call, rows resident"),
            per_call(resident),
        );
        show(
            &format!("{kernel} (GPU f64, {STENCIL} candidates): ms per call, uploaded each call"),
            per_call(uploaded),
        );
        show(
            &format!("{kernel}: speed-up from keeping the rows on the device"),
            ratio(resident, uploaded),
        );
    }
    // The sweep figure (docs/performance.md): 256 × 256 axes over 10 000 correspondences.
    let seconds = |r: Option<f64>| r.map(|r| 256.0 * 256.0 * 1e4 / r);
    show(
        "sweep GPU (f64 kernel): seconds for 256² axes × 10⁴ correspondences",
        seconds(rate("sweep", "gpu", "f64", None, "end_to_end")),
    );
    for kernel in ["sweep_reprojection", "sweep_scene"] {
        let rate = results
            .iter()
            .find(|f| f.kernel == kernel && f.path == "gpu")
            .map(|f| f.items_per_s);
        show(
            &format!("{kernel} GPU (f64 engine): seconds for 128² axes × 10⁴ correspondences"),
            rate.map(|r| 128.0 * 128.0 * 1e4 / r),
        );
    }
    show(
        "sweep CPU f64 all threads: seconds for 256² axes × 10⁴ correspondences",
        seconds(rate("sweep", "cpu", "f64", Some(threads), "end_to_end")),
    );
}
