//! Training throughput of the estimator (windows/s) on synthetic windows, printed as one JSON line; bench/training.sh
//! runs it beside the same model in PyTorch.

use anyhow::{Context, Result, bail};
use dynforge_trainer::model::{NetworkConfig, Preset};
use dynforge_trainer::training::{TrainConfig, synthetic_throughput};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> Result<()> {
    let (mut preset, mut inputs, mut steps, mut batch, mut seq_len) =
        ("fast".to_string(), 90usize, 20usize, 64usize, 64usize);
    let mut micro_batches = TrainConfig::default().micro_batches;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--preset" => preset = value()?,
            "--inputs" => inputs = value()?.parse()?,
            "--steps" => steps = value()?.parse()?,
            "--batch" => batch = value()?.parse()?,
            "--seq-len" => seq_len = value()?.parse()?,
            "--micro-batches" => micro_batches = value()?.parse()?,
            other => bail!(
                "unknown argument {other} (--preset paper|fast --inputs F --steps N --batch B --seq-len L --micro-batches M)"
            ),
        }
    }
    let cfg = match preset.as_str() {
        "paper" => Preset::Paper,
        "fast" => Preset::Fast,
        other => bail!("unknown preset {other}"),
    }
    .config(inputs, seq_len);
    eprintln!("burn: {} parameters", cfg.parameters());
    let rate = synthetic_throughput(&NetworkConfig::Transformer(cfg), batch, micro_batches, steps, 3, 0)?;
    let seconds = (steps * batch) as f64 / rate;
    println!(
        "{{\"framework\":\"burn\",\"preset\":\"{preset}\",\"micro_batches\":{micro_batches},\"windows_per_second\":{rate:.2},\"steps\":{steps},\"seconds\":{seconds:.3}}}"
    );
    Ok(())
}
