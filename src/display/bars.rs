//! The trainer's commands in a terminal: a bar for preprocessing and for the batches of an epoch, a line per epoch.

use std::io::IsTerminal;
use std::time::Instant;

use dynforge_dataset::metrics::EpochMetrics;
use dynforge_trainer::training::TrainObserver;
use dynforge_trainer::training::session::SessionObserver;
use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar on standard error, hidden when it is not a terminal.
pub fn bar(template: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(0);
    b.set_style(ProgressStyle::with_template(template).expect("valid template"));
    b
}

/// A session's progress: a bar for preprocessing and for the batches of an epoch, a line per epoch.
pub struct Bars {
    bar: ProgressBar,
    started: Instant,
    batch: usize,
    steps: usize,
    /// Without a terminal: the last tenth of a preprocessing stage logged.
    logged: usize,
}

impl Bars {
    pub fn new(batch: usize) -> Self {
        Bars { bar: bar("{msg} {bar:40} {pos}/{len}"), started: Instant::now(), batch, steps: 0, logged: 0 }
    }

    fn line(&self, text: &str) {
        if self.bar.is_hidden() { eprintln!("{text}") } else { self.bar.println(text) }
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

impl TrainObserver for Bars {
    fn message(&mut self, text: &str) {
        self.line(text);
    }

    fn step(&mut self, epoch: usize, batch: usize, batches: usize, loss: f64) {
        if batch == 1 || self.bar.length() != Some(batches as u64) {
            self.bar.set_length(batches as u64);
            self.started = Instant::now();
            self.steps = 0;
        }
        self.steps += 1;
        self.bar.set_position(batch as u64);
        let rate = (self.steps * self.batch) as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        self.bar.set_message(format!("epoch {epoch}: loss {loss:.4}, {rate:.0} examples/s"));
    }

    fn epoch(&mut self, m: &EpochMetrics, best: bool) {
        self.line(&format!("{m}{}", if best { " (best)" } else { "" }));
    }
}

impl SessionObserver for Bars {
    fn preprocessing(&mut self, what: &str, done: usize, total: usize) {
        // Logs (no terminal) get a line per tenth of the stage instead of a bar.
        let tenth = (10 * done).checked_div(total).unwrap_or(0);
        if self.bar.is_hidden() && tenth > self.logged {
            eprintln!("{what}: {done}/{total} ({:.0} s)", self.started.elapsed().as_secs_f64());
        }
        self.logged = if done == 0 { 0 } else { tenth };
        self.bar.set_message(what.to_string());
        self.bar.set_length(total as u64);
        self.bar.set_position(done as u64);
    }
}
