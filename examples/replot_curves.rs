//! Re-plots a training run's `curves.png` from its `train.csv` and `val.csv` with the current
//! plot code (a run plots its curves only at its checkpoints, so a committed run keeps the look
//! of the binary that trained it until it is resumed).
//!
//! `cargo run --example replot_curves -- RUN_DIR [RUN_DIR ...]`

use std::path::Path;

use mode360::train::log::plot_curves;

fn main() -> Result<(), String> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        return Err("usage: replot_curves RUN_DIR [RUN_DIR ...]".into());
    }
    for run in &runs {
        let dir = Path::new(run);
        let png = dir.join("curves.png");
        plot_curves(&dir.join("train.csv"), &dir.join("val.csv"), &png)?;
        println!("{}", png.display());
    }
    Ok(())
}
