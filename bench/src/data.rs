//! Data pipeline throughput: windows per second from the shards (cold: read, decode, resample, Jacobian features,
//! window) and from the cache, for a `generate` directory.
//!
//! Usage: dynforge-bench-data DIR [LEN:STRIDE:SSR[:HOP]=64:64:16]. Compare with the windows/s the model consumes in
//! training (bench/training.sh; figures in `docs/measurements.md`).

use std::time::Instant;

use anyhow::{Context, Result};
use dynforge_dataset::cache::windows::{CachedWindows, cache_path};
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::window::WindowSpec;
use dynforge_robot::urdf;

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let dir = std::path::PathBuf::from(args.next().context("usage: dynforge-bench-data DIR [LEN:STRIDE:SSR[:HOP]]")?);
    let spec: WindowSpec = match args.next() {
        Some(s) => s.parse()?,
        None => WindowSpec::default(),
    };
    let first = std::fs::read_dir(dir.join("shards"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|x| x == "mcap"))
        .context("no shard")?;
    let bag = dynforge_shard::read(&first)?;
    let model = urdf::parse(bag.robot_description.as_deref().context("no URDF")?, "shard")?;
    let features = JacobianFeatures::new(&model);
    let _ = std::fs::remove_file(cache_path(&dir, &spec, &features)?);
    let start = Instant::now();
    let (cold, skipped) = CachedWindows::load_or_build(&dir, &spec, &features, |_, _| true)?;
    let cold_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let (warm, _) = CachedWindows::load_or_build(&dir, &spec, &features, |_, _| true)?;
    let warm_s = start.elapsed().as_secs_f64();
    assert!(warm.hit && !cold.hit);
    println!(
        "{} windows of {} x {} ({} shards skipped): cold {:.0} windows/s ({:.2} s), from cache {:.0} windows/s ({:.3} s)",
        cold.count(),
        spec.len,
        cold.width,
        skipped.len(),
        cold.count() as f64 / cold_s,
        cold_s,
        warm.count() as f64 / warm_s,
        warm_s
    );
    println!("model consumption on this machine: 44-56 windows/s (paper preset) to 270-440 windows/s (fast preset)");
    Ok(())
}
