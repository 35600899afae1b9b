//! A generation in a terminal: a bar plus a line per worker on a TTY, a log line every few seconds otherwise.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use dynforge_coordinator::run::{Observer, Progress};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

/// Progress in the terminal: a bar plus a line per worker on a TTY, periodic log lines otherwise.
pub struct GenerationDisplay {
    bars: Option<(MultiProgress, ProgressBar, Vec<ProgressBar>)>,
    last_log: Instant,
}

impl Default for GenerationDisplay {
    fn default() -> Self {
        GenerationDisplay { bars: None, last_log: Instant::now() }
    }
}

impl Observer for GenerationDisplay {
    fn update(&mut self, p: &Progress) {
        if !std::io::stderr().is_terminal() {
            if self.last_log.elapsed() >= Duration::from_secs(5) || p.finished() == p.total {
                self.last_log = Instant::now();
                eprintln!("[{}/{}] {}", p.finished(), p.total, p);
            }
            return;
        }
        let (multi, main, workers) = self.bars.get_or_insert_with(|| {
            let multi = MultiProgress::new();
            let main = multi.add(ProgressBar::new(p.total));
            // wide_msg: cut to the terminal's width instead of wrapping.
            main.set_style(
                ProgressStyle::with_template("{bar:40} {pos}/{len} jobs, ETA {eta} | {wide_msg}")
                    .expect("valid template"),
            );
            // Jobs an earlier run finished are not progress of this one: the ETA starts from them.
            main.set_position(p.resumed);
            main.reset_eta();
            (multi, main, Vec::new())
        });
        main.set_length(p.total);
        main.set_position(p.finished());
        main.set_message(p.to_string());
        while workers.len() < p.slots.len() {
            let spinner = multi.add(ProgressBar::new_spinner());
            spinner.enable_steady_tick(Duration::from_millis(200));
            workers.push(spinner);
        }
        for (k, (bar, job)) in workers.iter().zip(&p.slots).enumerate() {
            bar.set_message(match job {
                Some(j) => format!("worker {k}: robot {} trajectory {}", j.robot, j.trajectory),
                None => format!("worker {k}: idle"),
            });
        }
    }

    fn message(&mut self, text: &str) {
        match &self.bars {
            Some((multi, ..)) => {
                let _ = multi.println(text);
            }
            None => eprintln!("{text}"),
        }
    }
}

impl Drop for GenerationDisplay {
    fn drop(&mut self) {
        if let Some((_, main, workers)) = &self.bars {
            for w in workers {
                w.finish_and_clear();
            }
            // Where the run stopped (an interrupted run is not N/N), on a line of its own.
            main.abandon();
            eprintln!();
        }
    }
}
