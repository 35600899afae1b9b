//! The paper's two ablations as data and tables: the dataset grid (sequence length x stride x SSR, fixed
//! architecture) and the architecture grid (layers x heads x embedding of the transformer), with the paper's values
//! beside each row of ours. `dynforge_trainer::sweep` trains and scores the rows.

use std::fmt::Write as _;

use serde::Serialize;

/// The paper's dataset grid: (sequence length, stride, SSR, its validation R2).
pub const DATASET_GRID: [(usize, usize, usize, f64); 16] = [
    (16, 32, 8, 0.7880),
    (16, 64, 16, 0.8090),
    (16, 128, 32, 0.8333),
    (16, 256, 32, 0.8446),
    (32, 32, 8, 0.8134),
    (32, 64, 16, 0.8428),
    (32, 128, 128, 0.8383),
    (64, 32, 8, 0.8328),
    (64, 32, 16, 0.8331),
    (64, 64, 16, 0.8633),
    (64, 64, 32, 0.8592),
    (64, 64, 64, 0.8571),
    (128, 16, 8, 0.8181),
    (128, 32, 8, 0.8451),
    (128, 32, 16, 0.8459),
    (128, 64, 16, 0.8479),
];

/// The paper's architecture grid: (layers, heads, embedding, its validation R2 and RMSE).
pub const ARCHITECTURE_GRID: [(usize, usize, usize, f64, f64); 4] = [
    (2, 16, 256, 0.8460, 0.1185),
    (4, 16, 128, 0.8555, 0.1148),
    (4, 32, 128, 0.8633, 0.1116),
    (8, 32, 128, 0.8410, 0.1200),
];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grid {
    Dataset,
    Architecture,
    Both,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub name: String,
    pub len: usize,
    pub stride: usize,
    pub ssr: usize,
    pub layers: usize,
    pub heads: usize,
    pub dim: usize,
    pub r2: f64,
    pub rmse: f64,
    pub train_seconds: f64,
    /// CPU seconds of the training steps (all threads): the cost side of accuracy per CPU-hour.
    pub cpu_seconds: f64,
    pub windows: usize,
    pub paper_r2: f64,
    pub paper_rmse: Option<f64>,
    /// Why the configuration was not trained (e.g. windows longer than the recordings); its scores are NaN.
    pub skipped: Option<String>,
}

/// R2 and RMSE cells, or the reason the configuration was not run.
fn scores(r: &Row) -> String {
    match &r.skipped {
        Some(reason) => format!("not run: {} | -", reason.replace('|', "/")),
        None => format!("{:.4} | {:.4}", r.r2, r.rmse),
    }
}

/// Both tables, markdown.
pub fn tables(dataset: &[Row], arch: &[Row]) -> String {
    let mut md = String::new();
    if !dataset.is_empty() {
        let _ = writeln!(md, "**Dataset configurations** (fixed architecture)\n");
        let _ = writeln!(
            md,
            "| Seq Len | Stride | SSR | Effective time (s) | Windows | Val R2 | Val RMSE | Paper Val R2 |"
        );
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in dataset {
            let span = (r.len * r.stride) as f64 / 1000.0;
            let _ = writeln!(
                md,
                "| {} | {} | {} | {span:.3} | {} | {} | {:.4} |",
                r.len,
                r.stride,
                r.ssr,
                r.windows,
                scores(r),
                r.paper_r2
            );
        }
        md.push('\n');
    }
    if !arch.is_empty() {
        let _ = writeln!(md, "**Architectures** (fixed dataset configuration)\n");
        let _ = writeln!(
            md,
            "| Layers | Heads | Embedding | Val R2 | Val RMSE | Train time (s) | CPU hours | Paper Val R2 | Paper Val RMSE |"
        );
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in arch {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.0} | {:.3} | {:.4} | {:.4} |",
                r.layers,
                r.heads,
                r.dim,
                scores(r),
                r.train_seconds,
                r.cpu_seconds / 3600.0,
                r.paper_r2,
                r.paper_rmse.unwrap_or(f64::NAN)
            );
        }
    }
    md
}
