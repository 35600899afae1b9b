//! dynforge's worker: turns one job (dataset seed, robot, trajectory, configuration) into a recording of 1 kHz joint
//! data, or a discard with a reason ([`job`] and the modules it chains), and serves a coordinator's jobs as the
//! worker process ([`serve`]).

// Index loops over the joints mirror the equations they implement.
#![allow(clippy::needless_range_loop)]

pub mod collision;
pub mod control;
pub mod engine;
pub mod family;
pub mod job;
pub mod output;
pub mod serve;
pub mod simulate;
pub mod trajectory;
