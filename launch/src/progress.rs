//! The progress bars of a single-process run (`trainer::Progress`), drawn on stderr; plain
//! lines every 10 s when stderr is not a terminal (CI logs).

use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar of `len` steps on stderr (hidden when stderr is not a terminal): `what`, right-aligned
/// in `width` columns, the elapsed time, the bar, the count, the rate and the ETA, then the
/// bar's message when `with_message`.
pub fn bar(len: u64, what: &str, width: usize, with_message: bool) -> ProgressBar {
    let msg = if with_message { " {msg}" } else { "" };
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr_with_hz(4));
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what:>width$} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} ({{per_sec}}, ETA {{eta}}){msg}"
        ))
        .expect("valid template"),
    );
    bar
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    bar(len, what, 10, true)
}

/// Prints a plain progress line when stderr is not a terminal (CI logs), at most every 10 s.
struct PlainProgress {
    last: Instant,
}

impl PlainProgress {
    fn tick(&mut self, bar: &ProgressBar, force: bool) {
        if bar.is_hidden() && (force || self.last.elapsed() >= Duration::from_secs(10)) {
            self.last = Instant::now();
            let elapsed = bar.elapsed().as_secs_f64();
            let rate = bar.position() as f64 / elapsed.max(1e-9);
            let left =
                bar.length().unwrap_or(0).saturating_sub(bar.position()) as f64 / rate.max(1e-9);
            eprintln!(
                "{}/{} ({rate:.2}/s, ETA {left:.0} s) {}",
                bar.position(),
                bar.length().unwrap_or(0),
                bar.message()
            );
        }
    }
}

/// Progress bars of a single-process run (plain lines every 10 s when stderr is not a terminal).
#[derive(Default)]
pub struct Bars {
    bar: Option<ProgressBar>,
    plain: Option<PlainProgress>,
}

impl Bars {
    fn show(&mut self, len: u64, what: &str) -> &ProgressBar {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        self.plain.get_or_insert(PlainProgress {
            last: Instant::now(),
        });
        self.bar.insert(progress_bar(len, what))
    }
    fn tick(&mut self) {
        if let (Some(bar), Some(plain)) = (&self.bar, &mut self.plain) {
            plain.tick(bar, false);
        }
    }
}

impl trainer::Progress for Bars {
    fn demos(&mut self, done: u64, total: u64) {
        if done == 1 {
            self.show(total, "demos");
        }
        if let Some(b) = &self.bar {
            b.set_position(done);
        }
        self.tick();
    }
    fn imitation_epoch(&mut self, epoch: u32, total: u32, loss: f32) {
        if epoch == 1 {
            self.show(total as u64, "imitation");
        }
        if let Some(b) = &self.bar {
            b.set_position(epoch as u64);
            b.set_message(format!("loss {loss:.5}"));
        }
        self.tick();
    }
    fn imitation_done(&mut self, loss: f32, transitions: usize) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        eprintln!("imitation done: loss {loss:.5}, {transitions} transitions");
    }
    fn rl_start(&mut self, first: u64, total: u64) {
        let bar = self.show(total, "rl");
        bar.set_position(first);
        bar.reset_eta();
    }
    fn rl_episode(&mut self, line: &trainer::RlLine<'_>, episodes_per_s: f64) {
        if let Some(b) = &self.bar {
            b.inc(1);
            b.set_message(format!(
                "ε {:.3} success {:.2} loss {:.5} {episodes_per_s:.2} ep/s",
                line.epsilon, line.success_rate_window, line.loss
            ));
        }
        self.tick();
    }
    fn validated(&mut self, _line: &serde_json::Value) {
        if let Some(b) = &self.bar {
            b.reset_eta();
        }
    }
    fn rl_end(&mut self) {
        if let (Some(bar), Some(plain)) = (&self.bar, &mut self.plain) {
            plain.tick(bar, true);
        }
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}
