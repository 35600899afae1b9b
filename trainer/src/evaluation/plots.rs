//! PNG figures of a run: learning curves, and predicted vs true values per parameter group (standardised units, so
//! a group's targets share axes). The font is embedded (DejaVu Sans), so plots render on any machine.

use std::path::Path;
use std::sync::Once;

use dynforge_proto::{LABELS, NUM_LABELS};
use plotters::prelude::*;

use dynforge_dataset::metrics::EpochMetrics;

fn font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType font shipped by the `dejavu` crate.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
    });
}

/// A figure that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct PlotError {
    pub file: String,
    pub problem: String,
}

fn fail(path: &Path, e: impl std::fmt::Display) -> PlotError {
    PlotError { file: path.display().to_string(), problem: e.to_string() }
}

/// Training and validation loss per epoch.
pub fn learning_curves(path: &Path, history: &[EpochMetrics]) -> Result<(), PlotError> {
    font();
    if history.is_empty() {
        return Err(fail(path, "no epochs to plot"));
    }
    let root = BitMapBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(path, e))?;
    let losses = history.iter().flat_map(|m| [m.train_loss, m.validation_loss]);
    let top = losses.fold(0.0f64, f64::max) * 1.05;
    let last = history.last().map_or(1, |m| m.epoch.max(1));
    let mut chart = ChartBuilder::on(&root)
        .caption("Learning curves (MSE, standardised labels)", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0usize..last, 0.0..top.max(1e-9))
        .map_err(|e| fail(path, e))?;
    chart.configure_mesh().x_desc("epoch").y_desc("loss").draw().map_err(|e| fail(path, e))?;
    for (name, colour, get) in [
        ("train", BLUE, (|m: &EpochMetrics| m.train_loss) as fn(&EpochMetrics) -> f64),
        ("validation", RED, |m: &EpochMetrics| m.validation_loss),
    ] {
        chart
            .draw_series(LineSeries::new(history.iter().map(|m| (m.epoch, get(m))), colour.stroke_width(2)))
            .map_err(|e| fail(path, e))?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| fail(path, e))?;
    root.present().map_err(|e| fail(path, e))
}

/// Predicted vs true (standardised by `mean`, `std`) for each parameter group, one panel per group.
pub fn predicted_vs_true(
    path: &Path,
    predicted: &[[f64; NUM_LABELS]],
    truth: &[[f64; NUM_LABELS]],
    mean: &[f64; NUM_LABELS],
    std: &[f64; NUM_LABELS],
) -> Result<(), PlotError> {
    font();
    let groups = dynforge_evaluation::tables::GROUPS;
    let root = BitMapBackend::new(path, (1500, 320)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(path, e))?;
    for ((_, name, kinds), area) in groups.iter().zip(root.split_evenly((1, groups.len()))) {
        let z = |v: f64, k: usize| (v - mean[k]) / std[k];
        let points: Vec<(f64, f64)> = LABELS
            .iter()
            .enumerate()
            .filter(|(_, l)| kinds.contains(&l.kind))
            .flat_map(|(k, _)| predicted.iter().zip(truth).map(move |(p, t)| (z(t[k], k), z(p[k], k))))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect();
        let span = points.iter().fold(1.0f64, |s, (a, b)| s.max(a.abs()).max(b.abs())) * 1.05;
        let mut chart = ChartBuilder::on(&area)
            .caption(*name, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(-span..span, -span..span)
            .map_err(|e| fail(path, e))?;
        chart.configure_mesh().x_desc("true").y_desc("predicted").draw().map_err(|e| fail(path, e))?;
        chart.draw_series(LineSeries::new([(-span, -span), (span, span)], BLACK)).map_err(|e| fail(path, e))?;
        chart
            .draw_series(points.iter().map(|&p| Circle::new(p, 2, BLUE.mix(0.35).filled())))
            .map_err(|e| fail(path, e))?;
    }
    root.present().map_err(|e| fail(path, e))
}
