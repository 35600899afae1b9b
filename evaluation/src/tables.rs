//! The paper's three result tables (friction per joint; mass and COM per link; inertia per link) and the overall
//! line, as Markdown (printed and written) from [`Scores`].

use std::fmt::Write;

use dynforge_proto::{LABELS, LabelKind};

use dynforge_dataset::metrics::{Scores, TargetScore};

fn find(kind: LabelKind, index: usize) -> Option<usize> {
    LABELS.iter().position(|l| l.kind == kind && l.index == index)
}

fn cells(s: &Scores, kind: LabelKind, index: usize) -> String {
    match find(kind, index).map(|k| s.targets[k]) {
        Some(TargetScore { r2, rmse, .. }) => format!(" {r2:.4} | {rmse:.4} |"),
        None => " - | - |".into(),
    }
}

fn table(out: &mut String, s: &Scores, title: &str, row: &str, rows: &[usize], kinds: &[(LabelKind, &str)]) {
    let _ = writeln!(out, "**{title}**\n");
    let mut head = format!("| {row} |");
    let mut rule = "|---|".to_string();
    for (_, name) in kinds {
        let _ = write!(head, " {name} R2 | {name} RMSE |");
        rule.push_str("---:|---:|");
    }
    let _ = writeln!(out, "{head}\n{rule}");
    for &i in rows {
        let label = if kinds[0].0.is_joint() { format!("J{i}") } else { format!("L{i}") };
        let mut line = format!("| {label} |");
        for (kind, _) in kinds {
            line.push_str(&cells(s, *kind, i));
        }
        let _ = writeln!(out, "{line}");
    }
    out.push('\n');
}

/// The three tables and the overall line (`overall`, e.g. "Overall"), in Markdown.
pub fn tables(s: &Scores, overall: &str) -> String {
    let mut out = String::new();
    use LabelKind::*;
    table(
        &mut out,
        s,
        "Friction per joint",
        "Joint",
        &[0, 1, 2, 3, 4, 5],
        &[(Coulomb, "Coulomb"), (Viscous, "Viscous")],
    );
    table(&mut out, s, "Mass and centre of mass per link", "Link", &[2, 3, 4, 5, 6], &[(Mass, "Mass"), (Com, "COM")]);
    table(&mut out, s, "Inertia per link", "Link", &[1, 2, 3, 4, 5, 6], &[(Ixx, "Ixx"), (Iyy, "Iyy"), (Izz, "Izz")]);
    let _ = writeln!(out, "**{overall}** ({} samples): R2 = {:.4}, RMSE = {:.4}", s.count, s.r2, s.rmse);
    out
}

/// The parameter groups of summaries and plots: short name, title, the label kinds in the group.
pub const GROUPS: [(&str, &str, &[LabelKind]); 5] = [
    ("coulomb", "Coulomb friction", &[LabelKind::Coulomb]),
    ("viscous", "viscous friction", &[LabelKind::Viscous]),
    ("mass", "mass", &[LabelKind::Mass]),
    ("com", "centre of mass", &[LabelKind::Com]),
    ("inertia", "inertia", &[LabelKind::Ixx, LabelKind::Iyy, LabelKind::Izz]),
];

/// Mean R2 of each parameter group (friction, mass, COM, inertia), for one-line summaries.
pub fn group_r2(s: &Scores) -> Vec<(&'static str, f64)> {
    GROUPS
        .iter()
        .map(|(name, _, kinds)| {
            let v: Vec<f64> =
                LABELS.iter().zip(&s.targets).filter(|(l, _)| kinds.contains(&l.kind)).map(|(_, t)| t.r2).collect();
            (*name, v.iter().sum::<f64>() / v.len() as f64)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_dataset::metrics::score;
    use dynforge_proto::NUM_LABELS;

    #[test]
    fn every_label_appears_in_exactly_one_table_cell() {
        // Give target k the R2 1 - k/1000 and find each value once in the tables.
        let truth: Vec<[f64; NUM_LABELS]> = (0..2).map(|v| [v as f64; NUM_LABELS]).collect();
        let mut s = score(&truth, &truth, &[1.0; NUM_LABELS]);
        for (k, t) in s.targets.iter_mut().enumerate() {
            t.r2 = 0.5 + k as f64 / 1000.0;
        }
        let md = tables(&s, "Overall");
        for (k, label) in LABELS.iter().enumerate() {
            let cell = format!(" {:.4} ", 0.5 + k as f64 / 1000.0);
            assert_eq!(md.matches(&cell).count(), 1, "label {} in\n{md}", label.name);
        }
        assert_eq!(group_r2(&s).len(), 5);
    }
}
