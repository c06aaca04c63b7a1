//! One figure of `flatport bench`: what ran where, items per second, and the roof it is read
//! against; the printed line and the JSON row come from the same [`Figure`].

use serde::Serialize;

use flatport::gpu::roofs::{DeviceBandwidth, LinkBandwidth};

/// One figure of the JSON report.
#[derive(Debug, Serialize)]
pub(super) struct Figure {
    pub kernel: &'static str,
    pub path: &'static str,
    /// On the CPU: `scalar` (the model row by row) or `vector` (the lanes of `engine::cpu::lanes`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_path: Option<&'static str>,
    pub precision: &'static str,
    pub threads: usize,
    pub stage: &'static str,
    /// What ran it: the CPU's model name, or the GPU adapter with its driver.
    pub device: String,
    /// The clock: `host` (wall clock around the work) or `gpu_timestamp` (GPU timestamps around
    /// the compute pass, for the GPU `kernel` stage where the adapter has TIMESTAMP_QUERY).
    pub timer: &'static str,
    pub items: usize,
    pub items_per_s: f64,
    /// For one CPU thread: cycles per item at the clock the OS reports (`cpu_clock_hz`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cycles_per_item: Option<f64>,
    /// The physical limit this figure is read against: `host_link` (an end-to-end GPU call moves
    /// its rows over it) or `device_memory` (a kernel reads and writes its rows there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roof: Option<&'static str>,
    /// The share of that roof the figure uses: 1 = bound by it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roof_fraction: Option<f64>,
}

/// What a figure measured, before its rate.
pub(super) struct Measure {
    pub kernel: &'static str,
    pub path: &'static str,
    pub cpu_path: Option<&'static str>,
    pub precision: &'static str,
    pub threads: usize,
    pub stage: &'static str,
    pub timer: &'static str,
    /// Items timed where not the batch (a GPU kernel over one chunk, the sweep, a stencil).
    pub items: Option<usize>,
}

impl Measure {
    /// A CPU figure, all of the batch, host clock.
    pub fn cpu(
        kernel: &'static str,
        cpu_path: Option<&'static str>,
        threads: usize,
        stage: &'static str,
    ) -> Self {
        Self {
            kernel,
            path: "cpu",
            cpu_path,
            precision: "f64",
            threads,
            stage,
            timer: "host",
            items: None,
        }
    }

    /// A GPU figure, all of the batch, host clock.
    pub fn gpu(kernel: &'static str, precision: &'static str, stage: &'static str) -> Self {
        Self {
            kernel,
            path: "gpu",
            cpu_path: None,
            precision,
            threads: 0,
            stage,
            timer: "host",
            items: None,
        }
    }

    /// The same figure over `items` items, timed by `timer`.
    pub fn over(self, items: usize, timer: &'static str) -> Self {
        Self {
            items: Some(items),
            timer,
            ..self
        }
    }
}

/// The GPU roofs of this run.
#[derive(Debug, Clone, Copy)]
pub(super) struct Roofs {
    pub link: LinkBandwidth,
    pub device: DeviceBandwidth,
}

/// Bytes of rows per item that a relation reads and writes (inputs and outputs in the kernel's
/// precision, and a status word): over the host link end to end, in device memory in the kernel
/// (`on_device`; for the chains the pixels' statuses, and for the three-kernel chain its
/// intermediate rays too). `None` for the costs (sweeps, stencils), which read few rows per cell
/// and are compute-bound.
fn row_bytes(kernel: &str, precision: &str, on_device: bool) -> Option<(f64, f64)> {
    let real = if precision == "f64" { 8.0 } else { 4.0 };
    // Status words read beyond the reals: the two pixel rows' statuses of the chains.
    let mut statuses_in = 0.0;
    let (inputs, outputs) = match kernel {
        "backproject" | "backproject_pinhole" => (2.0, 6.0),
        "project" => (3.0, 2.0),
        "triangulate" => (4.0, 4.0),
        // Two pixel rows (and their statuses) in and a point row out, in one kernel.
        "chain_triangulate" if on_device => {
            statuses_in = 2.0;
            (4.0, 4.0)
        }
        // The same in three kernels: also two ray rows written and read again (their statuses
        // merged, not counted).
        "chain_triangulate_unfused" if on_device => {
            statuses_in = 2.0;
            (4.0 + 12.0, 12.0 + 4.0)
        }
        "chain_triangulate" | "chain_triangulate_unfused" => (4.0, 4.0),
        "vop" => (3.0, 6.0),
        _ => return None,
    };
    Some((inputs * real + 4.0 * statuses_in, outputs * real + 4.0))
}

/// Collects the figures of one run and prints each as it comes.
pub(super) struct Recorder {
    pub results: Vec<Figure>,
    /// Items in a batch (`--items`) and in the sweep figure.
    batch: usize,
    sweep_items: usize,
    clock_hz: Option<f64>,
    cpu_model: String,
    /// The GPU of the figures to come, and its roofs.
    pub gpu: Option<(String, Roofs)>,
}

impl Recorder {
    pub fn new(batch: usize, sweep_items: usize, clock_hz: Option<f64>, cpu_model: String) -> Self {
        Self {
            results: Vec::new(),
            batch,
            sweep_items,
            clock_hz,
            cpu_model,
            gpu: None,
        }
    }

    /// Records and prints `measure`, which took `seconds`.
    pub fn record(&mut self, measure: Measure, seconds: f64) {
        let items = match measure.items {
            Some(items) => items,
            None if measure.kernel == "sweep" => self.sweep_items,
            None => self.batch,
        };
        let items_per_s = items as f64 / seconds;
        let on_cpu = measure.path == "cpu";
        let cycles_per_item = self
            .clock_hz
            .filter(|_| on_cpu && measure.threads == 1)
            .map(|hz| hz / items_per_s);
        let (device, roofs) = match (&self.gpu, on_cpu) {
            (Some((adapter, roofs)), false) => (adapter.clone(), Some(*roofs)),
            _ => (self.cpu_model.clone(), None),
        };
        let (roof, roof_fraction) = roofs
            .and_then(|roofs| roof_use(&measure, roofs, items_per_s))
            .map_or((None, None), |(roof, f)| (Some(roof), Some(f)));
        let figure = Figure {
            kernel: measure.kernel,
            path: measure.path,
            cpu_path: measure.cpu_path,
            precision: measure.precision,
            threads: measure.threads,
            stage: measure.stage,
            device,
            timer: measure.timer,
            items,
            items_per_s,
            cycles_per_item,
            roof,
            roof_fraction,
        };
        outln!("{}", line(&figure));
        self.results.push(figure);
    }
}

/// The roof a GPU figure is read against, and the share of it the figure uses.
fn roof_use(measure: &Measure, roofs: Roofs, items_per_s: f64) -> Option<(&'static str, f64)> {
    let on_device = measure.stage == "kernel";
    let (inputs, outputs) = row_bytes(measure.kernel, measure.precision, on_device)?;
    if on_device {
        let bytes = inputs + outputs;
        Some((
            "device_memory",
            items_per_s * bytes / roofs.device.bytes_per_s,
        ))
    } else {
        // The least time per item the link allows: the inputs up, the outputs down.
        let seconds = inputs / roofs.link.upload + outputs / roofs.link.download;
        Some(("host_link", items_per_s * seconds))
    }
}

/// The printed line of `figure`.
fn line(figure: &Figure) -> String {
    let clock = if figure.timer == "host" {
        String::new()
    } else {
        format!("  ({})", figure.timer)
    };
    let cycles = figure
        .cycles_per_item
        .map(|c| format!("  {c:6.0} cycles/item"))
        .unwrap_or_default();
    let roof = figure
        .roof
        .zip(figure.roof_fraction)
        .map(|(roof, f)| format!("  {:5.1} % of the {}", 100.0 * f, roof.replace('_', " ")))
        .unwrap_or_default();
    format!(
        "{:25} {:3} {:6} {} {:>3} thr {:20} {}{clock}{cycles}{roof}",
        figure.kernel,
        figure.path,
        figure.cpu_path.unwrap_or(""),
        figure.precision,
        figure.threads,
        figure.stage,
        human(figure.items_per_s)
    )
}

/// A rate with its SI prefix: `  57.02 G/s`.
pub(super) fn human(rate: f64) -> String {
    if rate >= 1e9 {
        format!("{:7.2} G/s", rate / 1e9)
    } else if rate >= 1e5 {
        format!("{:7.2} M/s", rate / 1e6)
    } else {
        format!("{:7.2} k/s", rate / 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flatport::gpu::KernelTimer;

    fn roofs() -> Roofs {
        Roofs {
            link: LinkBandwidth {
                upload: 10e9,
                download: 5e9,
                bytes: 1,
            },
            device: DeviceBandwidth {
                bytes_per_s: 4e12,
                timer: KernelTimer::GpuTimestamp,
                bytes: 1,
            },
        }
    }

    /// A kernel's share of device memory: f32 back-projection moves 8 + 28 bytes an item, so
    /// 1e11 items/s use 3.6e12 of 4e12 B/s.
    #[test]
    fn kernel_figures_are_read_against_device_memory() {
        let m = Measure::gpu("backproject", "f32", "kernel");
        let (roof, f) = roof_use(&m, roofs(), 1e11).unwrap();
        assert_eq!(roof, "device_memory");
        assert!((f - 0.9).abs() < 1e-12, "{f}");
    }

    /// End to end, the inputs go up and the outputs come down: f64 projection moves 24 bytes up
    /// (2.4 ns at 10 GB/s) and 20 down (4 ns at 5 GB/s), so 1e8 items/s use 64 % of the link.
    #[test]
    fn end_to_end_figures_are_read_against_the_link_both_ways() {
        let m = Measure::gpu("project", "f64", "end_to_end");
        let (roof, f) = roof_use(&m, roofs(), 1e8).unwrap();
        assert_eq!(roof, "host_link");
        assert!((f - 0.64).abs() < 1e-12, "{f}");
        assert!(roof_use(&Measure::gpu("sweep", "f64", "end_to_end"), roofs(), 1e8).is_none());
    }
}
