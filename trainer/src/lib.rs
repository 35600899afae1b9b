//! dynforge's trainer. `data` turns shards and ROS 2 bags into model-ready windows through the paper's
//! preprocessing stages, each a named, separately tested step.

pub mod data;
