//! What dynforge's long commands show while they run: progress bars on a terminal and log lines when standard error
//! is not one (a Slurm log, a pipe), so that the binary only says which display a command gets.

mod bars;
mod generation;
mod interrupt;

pub use bars::{Bars, bar};
pub use generation::GenerationDisplay;
pub use interrupt::{STOP, catch_interrupts};
