//! A progress bar on stderr with rate and ETA; silent when stderr is not a terminal or when asked.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// Progress of a long job counted in `unit`s.
pub struct Progress {
    label: String,
    unit: &'static str,
    enabled: bool,
    started: Instant,
    last: Option<Instant>,
}

impl Progress {
    /// A bar for `label`; drawn only when stderr is a terminal and `quiet` is false.
    pub fn new(label: &str, unit: &'static str, quiet: bool) -> Self {
        Self {
            label: label.into(),
            unit,
            enabled: !quiet && std::io::stderr().is_terminal(),
            started: Instant::now(),
            last: None,
        }
    }

    /// Redraws (at most 10 times a second, and always at the end).
    pub fn update(&mut self, done: usize, total: usize) {
        if !self.enabled {
            return;
        }
        let now = Instant::now();
        if done < total
            && self
                .last
                .is_some_and(|l| now - l < Duration::from_millis(100))
        {
            return;
        }
        self.last = Some(now);
        let elapsed = self.started.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        let fraction = done as f64 / total.max(1) as f64;
        let width = 30;
        let filled = (fraction * width as f64).round() as usize;
        let eta = if done > 0 && done < total {
            format!(", ETA {}", human_seconds((total - done) as f64 / rate))
        } else {
            String::new()
        };
        let _ = write!(
            std::io::stderr(),
            "\r{} [{}{}] {:5.1}% {done}/{total} {}, {}/s{eta}   ",
            self.label,
            "#".repeat(filled),
            "-".repeat(width - filled),
            100.0 * fraction,
            self.unit,
            human_count(rate)
        );
        if done >= total {
            let _ = writeln!(std::io::stderr(), "in {}", human_seconds(elapsed));
        }
    }
}

fn human_count(x: f64) -> String {
    match x {
        x if x >= 1e9 => format!("{:.2} G", x / 1e9),
        x if x >= 1e6 => format!("{:.2} M", x / 1e6),
        x if x >= 1e3 => format!("{:.1} k", x / 1e3),
        x => format!("{x:.0} "),
    }
}

fn human_seconds(s: f64) -> String {
    if s >= 90.0 {
        format!("{}m{:02}s", (s / 60.0) as u64, (s % 60.0) as u64)
    } else {
        format!("{s:.1}s")
    }
}
