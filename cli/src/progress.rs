//! Progress of long commands: a bar on a terminal; elsewhere (a log file, CI, a pipe) a plain line
//! on stderr every [`PLAIN_EVERY_PERCENT`] % or [`PLAIN_EVERY_SECONDS`] s, so a redirected run is
//! never silent for minutes.

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal as _;
use std::time::{Duration, Instant};

/// A plain progress line at least this often, in percent of the work…
pub const PLAIN_EVERY_PERCENT: u64 = 10;
/// …or in seconds, whichever comes first.
pub const PLAIN_EVERY_SECONDS: u64 = 30;

pub struct Progress {
    label: String,
    unit: &'static str,
    total: u64,
    done: u64,
    start: Instant,
    /// The bar on a terminal; `None` writes plain lines.
    bar: Option<ProgressBar>,
    last_line: (u64, Instant),
}

impl Progress {
    /// Progress over `total` units (`unit`: "steps", "texels") labelled `label`. `terminal`
    /// chooses the bar; [`Progress::new`] passes whether stderr is one.
    pub fn with_output(label: &str, total: u64, unit: &'static str, terminal: bool) -> Progress {
        let bar = terminal.then(|| {
            let bar = ProgressBar::new(total);
            let template = "{prefix:>9} [{bar:32}] {pos}/{len} {msg}, ETA {eta}";
            if let Ok(style) = ProgressStyle::with_template(template) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(label.to_string());
            bar
        });
        let start = Instant::now();
        Progress { label: label.into(), unit, total, done: 0, start, bar, last_line: (0, start) }
    }

    pub fn new(label: &str, total: u64, unit: &'static str) -> Progress {
        Progress::with_output(label, total, unit, std::io::stderr().is_terminal())
    }

    /// Moves to `done` units; `note` (e.g. the training PSNR) is shown with it.
    pub fn set(&mut self, done: u64, note: &dyn Fn() -> String) {
        self.done = done.min(self.total);
        if let Some(bar) = &self.bar {
            bar.set_position(self.done);
            bar.set_message(format!("{} {}", self.unit, note()));
        } else if let Some(line) = self.plain_line(Instant::now(), note) {
            eprintln!("{line}");
        }
    }

    /// Changes the total (more work found on the way).
    pub fn set_total(&mut self, total: u64) {
        if total != self.total {
            self.total = total;
            if let Some(bar) = &self.bar {
                bar.set_length(total);
            }
        }
    }

    pub fn inc(&mut self, units: u64) {
        self.set(self.done + units, &String::new);
    }

    /// The plain line due at `now`, if one is: every [`PLAIN_EVERY_PERCENT`] % or
    /// [`PLAIN_EVERY_SECONDS`] s since the last, and at the end.
    fn plain_line(&mut self, now: Instant, note: &dyn Fn() -> String) -> Option<String> {
        let (last_done, last_time) = self.last_line;
        let step = (self.total * PLAIN_EVERY_PERCENT / 100).max(1);
        let due = self.done >= last_done + step
            || self.done == self.total && last_done < self.total
            || now.duration_since(last_time) >= Duration::from_secs(PLAIN_EVERY_SECONDS);
        if !due || self.done == last_done {
            return None;
        }
        self.last_line = (self.done, now);
        let elapsed = now.duration_since(self.start).as_secs_f64();
        let percent = 100.0 * self.done as f64 / self.total.max(1) as f64;
        let eta = elapsed * (self.total - self.done) as f64 / self.done.max(1) as f64;
        let note = note();
        let note = if note.is_empty() { String::new() } else { format!(", {note}") };
        Some(format!(
            "{}: {}/{} {} ({percent:.0} %), {elapsed:.0} s, ETA {eta:.0} s{note}",
            self.label, self.done, self.total, self.unit
        ))
    }

    /// Clears the bar; returns the time since the start.
    pub fn finish(self) -> Duration {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
        self.start.elapsed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_lines_come_every_ten_percent_or_thirty_seconds_and_at_the_end() {
        let mut p = Progress::with_output("ntc-0.2", 1000, "steps", false);
        let t0 = p.start;
        let mut lines = Vec::new();
        for done in (0..=1000).step_by(25) {
            p.done = done;
            // 1 s per 25 steps: the 10 % rule fires first.
            let now = t0 + Duration::from_secs(done / 25);
            lines.extend(p.plain_line(now, &|| "train PSNR 30.00 dB".into()));
        }
        assert_eq!(lines.len(), 10, "{lines:#?}");
        assert_eq!(lines[0], "ntc-0.2: 100/1000 steps (10 %), 4 s, ETA 36 s, train PSNR 30.00 dB");
        assert!(lines[9].starts_with("ntc-0.2: 1000/1000 steps (100 %), 40 s, ETA 0 s"));
        // Slow work: a line after 30 s even without 10 % more.
        let mut p = Progress::with_output("decode", 1000, "texels", false);
        let t0 = p.start;
        p.done = 5;
        assert_eq!(p.plain_line(t0 + Duration::from_secs(10), &String::new), None);
        let line = p.plain_line(t0 + Duration::from_secs(31), &String::new);
        assert_eq!(line.as_deref(), Some("decode: 5/1000 texels (0 %), 31 s, ETA 6169 s"));
    }
}
