//! Progress of psgrasp's long batch commands (`psgrasp datagen`, `psgrasp eval`):
//! [`BatchProgress`] draws an [`indicatif`] bar when stderr is a terminal, writes one plain line
//! every [`LOG_LINE_EVERY`] items (and at the last) when it is a file or a pipe — a background
//! run's log stays readable — and nothing when the command is `--quiet`.
use indicatif::{HumanDuration, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// Items between two lines of a log (stderr not a terminal).
pub const LOG_LINE_EVERY: u64 = 10;

/// Where progress goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressOutput {
    /// An indicatif bar on the terminal.
    Bar,
    /// A line every `every` items and at the last (a log file or pipe).
    Lines {
        /// Items between two lines.
        every: u64,
    },
    /// Nothing (`--quiet`).
    Quiet,
}

impl ProgressOutput {
    /// The output for this process: `Quiet` when `quiet`, a bar when stderr is a terminal,
    /// lines every [`LOG_LINE_EVERY`] items otherwise.
    pub fn for_stderr(quiet: bool) -> Self {
        if quiet {
            Self::Quiet
        } else if std::io::stderr().is_terminal() {
            Self::Bar
        } else {
            Self::Lines {
                every: LOG_LINE_EVERY,
            }
        }
    }
}

/// Progress over `to_run` items of one unit (scenes, rounds) that this run executes; the caller
/// describes the whole job's state (items done before, rates) in a status text each time.
#[derive(Debug)]
pub struct BatchProgress {
    output: ProgressOutput,
    bar: ProgressBar,
    to_run: u64,
    ran: u64,
    unit: &'static str,
    start: Instant,
}

impl BatchProgress {
    /// Progress over `to_run` items called `unit` (singular, e.g. "scene"), shown on `output`.
    pub fn new(to_run: u64, unit: &'static str, output: ProgressOutput) -> Self {
        let bar = match output {
            ProgressOutput::Bar => {
                let style = ProgressStyle::with_template("[{bar:30}] {msg}  ETA {eta}")
                    .map(|s| s.progress_chars("#> "))
                    .unwrap_or_else(|_| ProgressStyle::default_bar());
                ProgressBar::with_draw_target(Some(to_run), ProgressDrawTarget::stderr())
                    .with_style(style)
            }
            ProgressOutput::Lines { .. } | ProgressOutput::Quiet => ProgressBar::hidden(),
        };
        Self {
            output,
            bar,
            to_run,
            ran: 0,
            unit,
            start: Instant::now(),
        }
    }

    /// Items run so far.
    pub fn ran(&self) -> u64 {
        self.ran
    }

    /// Mean wall time per item run so far (zero before the first).
    pub fn per_item(&self) -> Duration {
        if self.ran == 0 {
            Duration::ZERO
        } else {
            self.start.elapsed().div_f64(self.ran as f64)
        }
    }

    /// Shows the state before the first item (`status`: the job as a whole).
    pub fn start(&self, status: &str) {
        match self.output {
            ProgressOutput::Bar => self.bar.set_message(status.to_owned()),
            ProgressOutput::Lines { .. } => {
                eprintln!("{status}; {} {}s to run", self.to_run, self.unit)
            }
            ProgressOutput::Quiet => {}
        }
    }

    /// Records `n` more items run and shows `status`; returns the log line written, if any.
    pub fn advance(&mut self, n: u64, status: &str) -> Option<String> {
        let before = self.ran;
        self.ran += n;
        let per = self.per_item();
        let text = format!("{status}  {:.1} s/{}", per.as_secs_f64(), self.unit);
        match self.output {
            ProgressOutput::Bar => {
                self.bar.set_message(text);
                self.bar.set_position(self.ran);
                None
            }
            ProgressOutput::Lines { every } => {
                let crossed = every > 0 && self.ran / every > before / every;
                if !(crossed || (self.ran >= self.to_run && before < self.to_run)) {
                    return None;
                }
                let left = per.mul_f64(self.to_run.saturating_sub(self.ran) as f64);
                let line = format!("{text}  ETA {}", HumanDuration(left));
                eprintln!("{line}");
                Some(line)
            }
            ProgressOutput::Quiet => None,
        }
    }

    /// Leaves the bar as it is; the terminal's next line starts below it.
    pub fn finish(&self) {
        if self.output == ProgressOutput::Bar && !self.bar.is_hidden() {
            self.bar.abandon();
            eprintln!();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_gets_a_line_every_few_items_and_at_the_last() {
        let mut p = BatchProgress::new(25, "scene", ProgressOutput::Lines { every: 10 });
        p.start("0/30 scenes");
        let mut lines = Vec::new();
        for i in 1..=25 {
            if let Some(l) = p.advance(1, &format!("{}/30 scenes", 5 + i)) {
                lines.push(l);
            }
        }
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[0].starts_with("15/30 scenes  "), "{}", lines[0]);
        assert!(lines[1].starts_with("25/30 scenes  "), "{}", lines[1]);
        assert!(lines[2].starts_with("30/30 scenes  "), "{}", lines[2]);
        assert!(lines.iter().all(|l| l.contains(" s/scene  ETA ")));
        // Past the last item (more than announced): no more lines.
        assert_eq!(p.advance(1, "31/30 scenes"), None);
        assert_eq!(p.ran(), 26);
    }

    #[test]
    fn steps_of_several_items_cross_a_line_once() {
        let mut p = BatchProgress::new(100, "scene", ProgressOutput::Lines { every: 10 });
        // 0 → 7 → 14 → 21 → 35: lines at 14 (crossed 10), 21 (20), 35 (30).
        let shown: Vec<bool> = [7, 7, 7, 14]
            .iter()
            .map(|&n| p.advance(n, "x").is_some())
            .collect();
        assert_eq!(shown, [false, true, true, true]);
    }

    #[test]
    fn quiet_and_bar_outputs_write_no_lines() {
        for output in [ProgressOutput::Quiet, ProgressOutput::Bar] {
            let mut p = BatchProgress::new(3, "scene", output);
            p.start("0/3");
            assert!((1..=3).all(|i| p.advance(1, &format!("{i}/3")).is_none()));
            p.finish();
        }
        assert_eq!(ProgressOutput::for_stderr(true), ProgressOutput::Quiet);
    }
}
