//! The obstacle section of `mode360 eval`'s table: recall per band and for thin instances,
//! near δ1 and phantom free space per condition, each measure's per-frame mean and worst
//! frame, and the worst misses. Rows without ground-truth labels read n/a.

use super::EvalReport;
use mode360_core::obstacles::{ObstacleMeasure, ObstacleReport};

/// A percentage, or n/a when nothing was counted.
fn pct(value: Option<f64>) -> String {
    value.map_or_else(|| "n/a".to_string(), |v| format!("{v:.1}"))
}

/// `recovered/instances (pct)`.
fn recall_cell(recovered: u64, instances: u64, recall_pct: Option<f64>) -> String {
    match recall_pct {
        Some(p) => format!("{p:.1} ({recovered}/{instances})"),
        None => "n/a (0)".to_string(),
    }
}

fn row_cells(o: &ObstacleReport) -> Vec<String> {
    let mut cells: Vec<String> = o
        .bands
        .iter()
        .map(|b| recall_cell(b.recovered, b.instances, b.recall_pct))
        .collect();
    cells.push(recall_cell(
        o.thin.recovered,
        o.thin.instances,
        o.thin.recall_pct,
    ));
    for m in [
        ObstacleMeasure::NearObjectDelta1,
        ObstacleMeasure::NearAllDelta1,
        ObstacleMeasure::Phantom,
        ObstacleMeasure::PhantomOutOfRange,
    ] {
        cells.push(pct(o.measure(m).and_then(|s| s.pooled_pct)));
    }
    cells
}

impl EvalReport {
    /// The obstacle section (empty when the report has no rows).
    pub fn obstacle_table(&self) -> String {
        if self.rows.is_empty() {
            return String::new();
        }
        let mut s = String::from(
            "obstacles (instances within 10 m, >= 20 px at 512; recovered: median range within 25 %)\n\
             | condition | recall 0-2 m | recall 2-5 m | recall 5-10 m | thin < 3° | δ1 objects ≤ 5 m | δ1 all ≤ 5 m | phantom ≤ 50 m % | out of range % |\n\
             |---|---|---|---|---|---|---|---|---|\n",
        );
        for r in &self.rows {
            let cells = match &r.obstacles {
                Some(o) => row_cells(o),
                None => vec!["n/a".to_string(); 8],
            };
            s.push_str(&format!("| {} | {} |\n", r.condition, cells.join(" | ")));
        }
        for r in &self.rows {
            let Some(o) = &r.obstacles else {
                continue;
            };
            s.push_str(&format!(
                "per frame, {} ({} frames with labels): mean / worst\n",
                r.condition, o.frames
            ));
            for m in &o.measures {
                let worst = m.worst.as_ref().map_or_else(
                    || "n/a".to_string(),
                    |w| format!("{:.1} (stamp {} ns)", w.value_pct, w.stamp_ns),
                );
                s.push_str(&format!(
                    "  {}: {} / {}\n",
                    m.measure.label(),
                    pct(m.frame_mean_pct),
                    worst
                ));
            }
            if !o.worst_misses.is_empty() {
                s.push_str("  worst misses (true -> predicted median range):\n");
                for miss in &o.worst_misses {
                    let pred = miss
                        .score
                        .pred_range_m
                        .map_or_else(|| "no estimate".to_string(), |p| format!("{p:.2} m"));
                    s.push_str(&format!(
                        "    instance {} at stamp {} ns: {:.2} m -> {} ({} px, {:.1}° wide, {:.0} % out of range, elevation {:.0}°)\n",
                        miss.score.instance,
                        miss.stamp_ns,
                        miss.score.true_range_m,
                        pred,
                        miss.score.pixels,
                        miss.score.width_deg,
                        miss.score.out_of_range_pct,
                        miss.score.elevation_deg
                    ));
                }
            }
        }
        s
    }
}
