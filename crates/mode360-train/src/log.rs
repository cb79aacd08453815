//! Training logs: CSV files, the loss/delta1 plot, and peak memory.
//!
//! `train.csv`: `step,loss,lr,step_s,peak_rss_mib`; `val.csv`: `step,loss,mae_m,rmse_m,abs_rel,
//! sq_rel_m,silog,delta1_pct,delta2_pct,delta3_pct,peak_rss_mib`. Rows are appended; a resumed
//! run first drops rows past its checkpoint step, so the files never hold a step twice, and
//! writes the current header (runs before the units were unified named the same columns
//! `secs` and `peak_rss_mb`).

use image::{Rgb, RgbImage};
use mode360_core::metrics::DepthMetrics;
use std::io::Write;
use std::path::Path;

/// CSV header of `train.csv`.
pub const TRAIN_CSV_HEADER: &str = "step,loss,lr,step_s,peak_rss_mib";
/// CSV header of `val.csv`.
pub const VAL_CSV_HEADER: &str =
    "step,loss,mae_m,rmse_m,abs_rel,sq_rel_m,silog,delta1_pct,delta2_pct,delta3_pct,peak_rss_mib";
/// Plot size in pixels.
pub const PLOT_WIDTH_PX: u32 = 800;
pub const PLOT_HEIGHT_PX: u32 = 600;
/// Margin around each plot panel, pixels.
const PANEL_MARGIN_PX: i64 = 30;
/// Colours.
const BACKGROUND: Rgb<u8> = Rgb([255, 255, 255]);
const AXIS: Rgb<u8> = Rgb([60, 60, 60]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);
const TRAIN_COLOUR: Rgb<u8> = Rgb([40, 90, 200]);
const VAL_COLOUR: Rgb<u8> = Rgb([220, 60, 40]);
/// Horizontal grid lines per panel.
const GRID_LINES: usize = 4;
/// Top of the delta1 axis, percent.
const PERCENT_MAX: f64 = 100.0;

/// One row of `train.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainRecord {
    pub step: usize,
    pub loss: f64,
    pub lr: f64,
    pub step_s: f64,
    pub peak_rss_mib: f64,
}

/// One row of `val.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct ValRecord {
    pub step: usize,
    pub loss: f64,
    pub metrics: DepthMetrics,
    pub peak_rss_mib: f64,
}

/// Peak resident set size of this process (`VmHWM` in `/proc/self/status`), MiB; 0 where
/// the file is unavailable.
pub fn peak_rss_mib() -> f64 {
    mode360_core::memory::peak_resident_mib().unwrap_or(0.0)
}

fn append_line(path: &Path, header: &str, line: &str) -> std::io::Result<()> {
    let new = !path.exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)?;
    if new {
        writeln!(f, "{header}")?;
    }
    writeln!(f, "{line}")
}

/// Appends a row to `train.csv`.
pub fn append_train(path: &Path, r: &TrainRecord) -> std::io::Result<()> {
    append_line(
        path,
        TRAIN_CSV_HEADER,
        &format!(
            "{},{:.6},{:.6e},{:.3},{:.1}",
            r.step, r.loss, r.lr, r.step_s, r.peak_rss_mib
        ),
    )
}

/// Appends a row to `val.csv`.
pub fn append_val(path: &Path, r: &ValRecord) -> std::io::Result<()> {
    let m = &r.metrics;
    append_line(
        path,
        VAL_CSV_HEADER,
        &format!(
            "{},{:.6},{:.4},{:.4},{:.5},{:.5},{:.4},{:.3},{:.3},{:.3},{:.1}",
            r.step,
            r.loss,
            m.mae_m,
            m.rmse_m,
            m.abs_rel,
            m.sq_rel_m,
            m.silog,
            m.delta1_pct,
            m.delta2_pct,
            m.delta3_pct,
            r.peak_rss_mib
        ),
    )
}

/// Drops data rows whose first field (the step) exceeds `max_step` and makes `header` the
/// first line (for resume).
pub fn truncate_after_step(path: &Path, header: &str, max_step: usize) -> std::io::Result<()> {
    if !path.exists() {
        return Ok(());
    }
    let text = std::fs::read_to_string(path)?;
    let kept: Vec<&str> = text
        .lines()
        .enumerate()
        .filter(|(i, l)| {
            *i == 0
                || l.split(',')
                    .next()
                    .and_then(|s| s.parse::<usize>().ok())
                    .is_some_and(|s| s <= max_step)
        })
        .map(|(i, l)| if i == 0 { header } else { l })
        .collect();
    let mut out = kept.join("\n");
    out.push('\n');
    mode360_core::atomic_file::write_atomic(path, out)
}

/// `(x, y)` columns of a CSV, by header name; unparsable rows are skipped.
pub fn read_columns(path: &Path, x: &str, y: &str) -> std::io::Result<Vec<(f64, f64)>> {
    let text = std::fs::read_to_string(path)?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let (Some(xi), Some(yi)) = (
        header.iter().position(|h| *h == x),
        header.iter().position(|h| *h == y),
    ) else {
        return Ok(Vec::new());
    };
    Ok(lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((f.get(xi)?.parse().ok()?, f.get(yi)?.parse().ok()?))
        })
        .collect())
}

/// A rectangle of the plot, pixels.
#[derive(Clone, Copy, Debug)]
struct Panel {
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// Bresenham line.
fn line(img: &mut RgbImage, a: (i64, i64), b: (i64, i64), c: Rgb<u8>) {
    let (mut x, mut y) = a;
    let (dx, dy) = ((b.0 - a.0).abs(), -(b.1 - a.1).abs());
    let (sx, sy) = (
        if a.0 < b.0 { 1 } else { -1 },
        if a.1 < b.1 { 1 } else { -1 },
    );
    let mut err = dx + dy;
    loop {
        put(img, x, y, c);
        if (x, y) == b {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}

/// Data bounds of a plot panel.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    x_min: f64,
    x_max: f64,
    y_min: f64,
    y_max: f64,
}

/// Bounds of the finite points of `series`, `None` if there are none.
fn bounds_of(series: &[&[(f64, f64)]]) -> Option<Bounds> {
    let mut b = Bounds {
        x_min: f64::INFINITY,
        x_max: f64::NEG_INFINITY,
        y_min: f64::INFINITY,
        y_max: f64::NEG_INFINITY,
    };
    for &(x, y) in series.iter().flat_map(|s| s.iter()) {
        if x.is_finite() && y.is_finite() {
            b.x_min = b.x_min.min(x);
            b.x_max = b.x_max.max(x);
            b.y_min = b.y_min.min(y);
            b.y_max = b.y_max.max(y);
        }
    }
    b.x_min.is_finite().then_some(b)
}

/// Draws `series` (x ascending) into `panel` mapped through `bounds`.
fn draw_series(
    img: &mut RgbImage,
    panel: Panel,
    bounds: Bounds,
    series: &[(f64, f64)],
    c: Rgb<u8>,
) {
    let xspan = (bounds.x_max - bounds.x_min).max(f64::EPSILON);
    let yspan = (bounds.y_max - bounds.y_min).max(f64::EPSILON);
    let to_px = |(x, y): (f64, f64)| {
        (
            panel.x0 + ((x - bounds.x_min) / xspan * (panel.x1 - panel.x0) as f64).round() as i64,
            panel.y1 - ((y - bounds.y_min) / yspan * (panel.y1 - panel.y0) as f64).round() as i64,
        )
    };
    let pts: Vec<(i64, i64)> = series
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(to_px)
        .collect();
    for w in pts.windows(2) {
        line(img, w[0], w[1], c);
    }
    for &(x, y) in &pts {
        for d in -1..=1 {
            put(img, x + d, y, c);
            put(img, x, y + d, c);
        }
    }
}

/// `(x, log10 y)` of the positive points.
fn log10_series(series: &[(f64, f64)]) -> Vec<(f64, f64)> {
    series
        .iter()
        .filter(|(_, y)| *y > 0.0)
        .map(|&(x, y)| (x, y.log10()))
        .collect()
}

fn draw_frame(img: &mut RgbImage, p: Panel) {
    for k in 1..GRID_LINES {
        let y = p.y0 + (p.y1 - p.y0) * k as i64 / GRID_LINES as i64;
        line(img, (p.x0, y), (p.x1, y), GRID);
    }
    line(img, (p.x0, p.y1), (p.x1, p.y1), AXIS);
    line(img, (p.x0, p.y0), (p.x0, p.y1), AXIS);
}

/// Re-plots `curves.png` (no text; the CSV files hold the numbers): top panel training loss
/// (blue) and validation loss (red) vs step on one shared log10 scale spanning the data;
/// bottom panel validation delta1 (red) vs step on a fixed 0..100 % scale, grid lines every
/// 25 %. Both panels share the step axis.
pub fn plot_curves(train_csv: &Path, val_csv: &Path, out_png: &Path) -> Result<(), String> {
    let train = if train_csv.exists() {
        read_columns(train_csv, "step", "loss")
            .map_err(|e| format!("{}: {e}", train_csv.display()))?
    } else {
        Vec::new()
    };
    let (val_loss, val_d1) = if val_csv.exists() {
        (
            read_columns(val_csv, "step", "loss")
                .map_err(|e| format!("{}: {e}", val_csv.display()))?,
            read_columns(val_csv, "step", "delta1_pct")
                .map_err(|e| format!("{}: {e}", val_csv.display()))?,
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let mut img = RgbImage::from_pixel(PLOT_WIDTH_PX, PLOT_HEIGHT_PX, BACKGROUND);
    let (w, h) = (i64::from(PLOT_WIDTH_PX), i64::from(PLOT_HEIGHT_PX));
    let top = Panel {
        x0: PANEL_MARGIN_PX,
        y0: PANEL_MARGIN_PX,
        x1: w - PANEL_MARGIN_PX,
        y1: h / 2 - PANEL_MARGIN_PX / 2,
    };
    let bottom = Panel {
        x0: PANEL_MARGIN_PX,
        y0: h / 2 + PANEL_MARGIN_PX / 2,
        x1: w - PANEL_MARGIN_PX,
        y1: h - PANEL_MARGIN_PX,
    };
    draw_frame(&mut img, top);
    draw_frame(&mut img, bottom);
    let (train_log, val_log) = (log10_series(&train), log10_series(&val_loss));
    if let Some(b) = bounds_of(&[&train_log, &val_log]) {
        draw_series(&mut img, top, b, &train_log, TRAIN_COLOUR);
        draw_series(&mut img, top, b, &val_log, VAL_COLOUR);
    }
    if let Some(b) = bounds_of(&[&train, &val_d1]) {
        let pct = Bounds {
            y_min: 0.0,
            y_max: PERCENT_MAX,
            ..b
        };
        draw_series(&mut img, bottom, pct, &val_d1, VAL_COLOUR);
    }
    let tmp = out_png.with_extension("png.tmp");
    img.save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, out_png).map_err(|e| format!("{}: {e}", out_png.display()))
}
