//! What dynforge's long commands show while they run: progress bars on a terminal and log lines when standard error
//! is not one (a Slurm log, a pipe), so that each command only says which display it gets.

mod bars;
mod generation;
mod interrupt;

pub use bars::{Bars, bar};
pub use generation::GenerationDisplay;
pub use interrupt::{STOP, catch_interrupts};
