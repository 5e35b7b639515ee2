//! Progress of a long stage (capture, rectify, fit, render), shown the same
//! way by every `qhm` command.
//!
//! On a terminal, [`Bar`] draws an indicatif bar on stderr. When stderr is
//! not a terminal (a log file, a pipe, CI), an indicatif bar draws nothing,
//! so a long stage would look hung; there it prints one plain line every
//! [`LINE_INTERVAL`] instead:
//!
//! ```text
//! capture: 120/960, ETA 03:25, pass 2
//! capture: 960/960, done in 04:02
//! ```
//!
//! The ETA is the remaining count at the rate since the bar (re)started;
//! `--:--` until the first step is done. A [`Bar`] is `Sync`, so parallel
//! workers may update it.

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// How often a plain progress line is printed when stderr is not a terminal.
pub const LINE_INTERVAL: Duration = Duration::from_secs(5);

/// How a [`Bar`] shows itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Nothing at all (`--quiet`, tests).
    Hidden,
    /// An indicatif bar on stderr.
    Terminal,
    /// A plain line every interval.
    Lines,
}

impl Mode {
    /// [`Mode::Terminal`] when stderr is a terminal, else [`Mode::Lines`];
    /// [`Mode::Hidden`] when `quiet`.
    pub fn auto(quiet: bool) -> Mode {
        if quiet {
            Mode::Hidden
        } else if std::io::stderr().is_terminal() {
            Mode::Terminal
        } else {
            Mode::Lines
        }
    }
}

/// The state of a line-mode bar.
struct Lines {
    out: Box<dyn Write + Send>,
    interval: Duration,
    total: u64,
    done: u64,
    message: String,
    /// Where the rate is measured from: (time, done then).
    since: (Instant, u64),
    started: Instant,
    last_line: Option<Instant>,
    finished: bool,
}

impl Lines {
    fn line(&self, now: Instant, stage: &str) -> String {
        let mut s = format!("{stage}: {}/{}", self.done, self.total);
        if self.finished {
            s += &format!(", done in {}", mm_ss(now - self.started));
        } else {
            s += &format!(", ETA {}", self.eta(now).map_or("--:--".into(), mm_ss));
        }
        if !self.message.is_empty() {
            s += ", ";
            s += &self.message;
        }
        s
    }

    fn eta(&self, now: Instant) -> Option<Duration> {
        let (t0, d0) = self.since;
        let steps = self.done.checked_sub(d0).filter(|n| *n > 0)?;
        let left = self.total.saturating_sub(self.done);
        Some((now - t0).mul_f64(left as f64 / steps as f64))
    }

    fn print(&mut self, now: Instant, stage: &str) {
        let line = self.line(now, stage);
        // Progress is best effort: a closed stderr must not stop the work.
        let _ = writeln!(self.out, "{line}");
        let _ = self.out.flush();
        self.last_line = Some(now);
    }

    /// Prints when the interval since the last line (or the start) has passed.
    fn tick(&mut self, stage: &str) {
        let now = Instant::now();
        let from = self.last_line.unwrap_or(self.started);
        if !self.finished && now - from >= self.interval {
            self.print(now, stage);
        }
    }
}

enum Kind {
    Hidden,
    Terminal(ProgressBar),
    Lines(Mutex<Lines>),
}

/// Progress of one stage: done out of total, with an ETA.
pub struct Bar {
    stage: String,
    kind: Kind,
}

/// `mm:ss`; minutes go past 59 rather than adding an hour field.
pub fn mm_ss(d: Duration) -> String {
    let s = d.as_secs_f64().round() as u64;
    format!("{:02}:{:02}", s / 60, s % 60)
}

impl Bar {
    /// A bar for `stage` of `total` steps, shown as [`Mode::auto`] says.
    pub fn new(stage: &str, total: u64, quiet: bool) -> Bar {
        Bar::with_mode(stage, total, Mode::auto(quiet))
    }

    /// A bar that shows nothing.
    pub fn hidden() -> Bar {
        Bar::with_mode("", 0, Mode::Hidden)
    }

    pub fn with_mode(stage: &str, total: u64, mode: Mode) -> Bar {
        match mode {
            Mode::Hidden => Bar {
                stage: stage.into(),
                kind: Kind::Hidden,
            },
            Mode::Terminal => {
                let b = ProgressBar::new(total);
                b.set_style(
                    ProgressStyle::with_template(
                        "   {prefix}: [{elapsed_precise}] {bar:40} {pos}/{len} {msg} (eta {eta})",
                    )
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
                );
                b.set_prefix(stage.to_string());
                Bar {
                    stage: stage.into(),
                    kind: Kind::Terminal(b),
                }
            }
            Mode::Lines => Bar::to_writer(stage, total, Box::new(std::io::stderr()), LINE_INTERVAL),
        }
    }

    /// A line-mode bar writing to `out` every `interval` (tests, logs).
    pub fn to_writer(
        stage: &str,
        total: u64,
        out: Box<dyn Write + Send>,
        interval: Duration,
    ) -> Bar {
        let now = Instant::now();
        Bar {
            stage: stage.into(),
            kind: Kind::Lines(Mutex::new(Lines {
                out,
                interval,
                total,
                done: 0,
                message: String::new(),
                since: (now, 0),
                started: now,
                last_line: None,
                finished: false,
            })),
        }
    }

    fn lines(&self, f: impl FnOnce(&mut Lines)) {
        if let Kind::Lines(m) = &self.kind {
            let mut l = m.lock().unwrap_or_else(|e| e.into_inner());
            f(&mut l);
        }
    }

    /// Sets the total and the steps already done, and restarts the ETA (a
    /// resumed capture starts part way).
    pub fn start(&self, total: u64, done: u64) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => {
                b.set_length(total);
                b.set_position(done);
                b.reset_eta();
            }
            Kind::Lines(_) => self.lines(|l| {
                l.total = total;
                l.done = done;
                l.since = (Instant::now(), done);
            }),
        }
    }

    /// Sets the total once it is known, keeping the rate measured so far.
    pub fn set_total(&self, total: u64) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.set_length(total),
            Kind::Lines(_) => self.lines(|l| l.total = total),
        }
    }

    /// Steps done so far.
    pub fn set_position(&self, done: u64) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.set_position(done),
            Kind::Lines(_) => self.lines(|l| {
                l.done = done;
                l.tick(&self.stage);
            }),
        }
    }

    /// One more step done.
    pub fn inc(&self, n: u64) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.inc(n),
            Kind::Lines(_) => self.lines(|l| {
                l.done += n;
                l.tick(&self.stage);
            }),
        }
    }

    /// A short note shown after the count (e.g. `pass 2`).
    pub fn set_message(&self, msg: &str) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.set_message(msg.to_string()),
            Kind::Lines(_) => self.lines(|l| l.message = msg.to_string()),
        }
    }

    /// Prints a line of text without breaking the bar.
    pub fn println(&self, text: &str) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.println(text),
            Kind::Lines(_) => self.lines(|l| {
                let _ = writeln!(l.out, "{text}");
            }),
        }
    }

    /// Ends the stage: clears the terminal bar, or prints the closing line.
    pub fn finish(&self) {
        match &self.kind {
            Kind::Hidden => {}
            Kind::Terminal(b) => b.finish_and_clear(),
            Kind::Lines(_) => self.lines(|l| {
                if !l.finished {
                    l.finished = true;
                    l.print(Instant::now(), &self.stage);
                }
            }),
        }
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        if let Kind::Terminal(b) = &self.kind {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A writer the test can read back.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    impl Shared {
        fn text(&self) -> String {
            String::from_utf8(self.0.lock().unwrap().clone()).unwrap()
        }
    }

    #[test]
    fn lines_every_interval_with_eta_and_a_closing_line() {
        let out = Shared::default();
        let bar = Bar::to_writer(
            "capture",
            10,
            Box::new(out.clone()),
            Duration::from_millis(40),
        );
        bar.set_message("pass 2");
        // Faster than the interval: no line yet.
        bar.inc(1);
        assert_eq!(out.text(), "");
        std::thread::sleep(Duration::from_millis(60));
        bar.inc(1);
        let text = out.text();
        assert_eq!(text.lines().count(), 1, "{text}");
        let line = text.lines().next().unwrap();
        assert!(line.starts_with("capture: 2/10, ETA 00:0"), "{line}");
        assert!(line.ends_with(", pass 2"), "{line}");
        // Within the interval of the last line: still one.
        bar.inc(1);
        assert_eq!(out.text().lines().count(), 1);
        bar.set_position(10);
        bar.finish();
        bar.finish();
        let text = out.text();
        let last = text.lines().last().unwrap();
        assert!(last.starts_with("capture: 10/10, done in 00:00"), "{text}");
        assert_eq!(text.lines().count(), 2, "{text}");
    }

    #[test]
    fn eta_is_unknown_before_the_first_step_and_restarts_on_resume() {
        let out = Shared::default();
        let bar = Bar::to_writer("rectify", 100, Box::new(out.clone()), Duration::ZERO);
        bar.start(100, 40);
        bar.set_position(40);
        assert!(
            out.text().contains("rectify: 40/100, ETA --:--"),
            "{}",
            out.text()
        );
        bar.set_position(70);
        let last = out.text().lines().last().unwrap().to_string();
        // 30 steps took ~no time: 30 more take about as long.
        assert_eq!(last, "rectify: 70/100, ETA 00:00");
        bar.set_total(200);
        bar.inc(1);
        let last = out.text().lines().last().unwrap().to_string();
        assert_eq!(last, "rectify: 71/200, ETA 00:00");
    }

    #[test]
    fn formats_minutes_past_the_hour() {
        assert_eq!(mm_ss(Duration::from_secs(0)), "00:00");
        assert_eq!(mm_ss(Duration::from_secs(205)), "03:25");
        assert_eq!(mm_ss(Duration::from_secs(3725)), "62:05");
    }

    #[test]
    fn hidden_bar_accepts_everything() {
        let b = Bar::hidden();
        b.start(5, 1);
        b.inc(1);
        b.set_position(3);
        b.set_message("x");
        b.println("y");
        b.finish();
    }
}
