//! Training logs: CSV files, the loss/delta1 plot, and peak memory.
//!
//! `train.csv`: `step,loss,lr,step_s,peak_rss_mib`; `val.csv`: `step,loss,mae_m,rmse_m,abs_rel,
//! sq_rel_m,silog,delta1_pct,delta2_pct,delta3_pct,peak_rss_mib`. Rows are appended; a resumed
//! run first drops rows past its checkpoint step, so the files never hold a step twice, and
//! writes the current header (runs before the units were unified named the same columns
//! `secs` and `peak_rss_mb`).

use image::{Rgb, RgbImage};
use mode360_core::glyphs::TextStyle;
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
/// Each step's training loss, under its running mean ([`TRAIN_COLOUR`]).
const TRAIN_RAW_COLOUR: Rgb<u8> = Rgb([185, 200, 235]);
/// Steps in the running mean of the training loss (in log10).
const TRAIN_SMOOTH_STEPS: usize = 50;
/// Left margin, wide enough for the value labels, pixels.
const LEFT_MARGIN_PX: i64 = 64;
/// Gap between an axis and its labels, pixels.
const LABEL_GAP_PX: u32 = 5;
/// The axes' labels: the 3x5 font at twice its size.
const LABEL_TEXT: TextStyle = TextStyle {
    scale: 2,
    gap_px: 2,
    ink: AXIS,
};
const VAL_COLOUR: Rgb<u8> = Rgb([220, 60, 40]);
/// The step axis' title.
const STEP_AXIS_TITLE: &str = "STEP";
/// Horizontal grid lines per panel.
const GRID_LINES: usize = 4;
/// Top of the delta1 axis, percent.
const PERCENT_MAX: f64 = 100.0;
/// Grid steps the delta1 axis may take, percent: the smallest whose [`GRID_LINES`] intervals
/// hold the validation points is used, so a change of a tenth of a point shows.
const PERCENT_STEPS: [f64; 8] = [0.25, 0.5, 1.0, 2.0, 2.5, 5.0, 10.0, 25.0];

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
    marks: bool,
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
    for &(x, y) in pts.iter().filter(|_| marks) {
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

/// Running mean of `series`' y over the last `window` points (fewer at the start).
fn running_mean(series: &[(f64, f64)], window: usize) -> Vec<(f64, f64)> {
    let window = window.max(1);
    let mut sum = 0.0;
    series
        .iter()
        .enumerate()
        .map(|(i, &(x, y))| {
            sum += y;
            if i >= window {
                sum -= series[i - window].1;
            }
            (x, sum / (i + 1).min(window) as f64)
        })
        .collect()
}

/// A tick's value with two or three significant digits: `0.52`, `1.3`, `12`, `1250`.
fn tick_label(v: f64) -> String {
    match v.abs() {
        a if a >= 10.0 => format!("{v:.0}"),
        a if a >= 1.0 => format!("{v:.1}"),
        _ => format!("{v:.2}"),
    }
}

/// Labels the grid lines of `panel` (top to bottom) with `labels`, right-aligned left of it.
fn label_rows(img: &mut RgbImage, p: Panel, labels: &[String]) {
    let rows = labels.len().saturating_sub(1).max(1) as i64;
    for (k, text) in (0i64..).zip(labels) {
        let y = p.y0 + (p.y1 - p.y0) * k / rows - i64::from(LABEL_TEXT.height_px() / 2);
        let x = p.x0 - i64::from(LABEL_GAP_PX + LABEL_TEXT.width_px(text));
        LABEL_TEXT.draw(img, x.max(0) as u32, y.max(0) as u32, text);
    }
}

/// The delta1 axis `(bottom, top, grid step)` for validation values in `[min, max]`, percent:
/// the first step `s` of [`PERCENT_STEPS`] for which
///
/// ```text
/// bottom = s floor(min / s)  (one step lower where that is min itself, never below 0)
/// top    = bottom + GRID_LINES s  (moved down to 100 % with bottom where it is above)
/// ```
///
/// holds `max` below `top` (or at 100 %), so no point sits on the panel's edge but at 0 or 100.
fn percent_axis(min: f64, max: f64) -> (f64, f64, f64) {
    let intervals = GRID_LINES as f64;
    for s in PERCENT_STEPS {
        let mut bottom = (min / s).floor() * s;
        if bottom == min {
            bottom -= s;
        }
        bottom = bottom.clamp(0.0, PERCENT_MAX - intervals * s);
        let top = bottom + intervals * s;
        if max < top || top == PERCENT_MAX {
            return (bottom, top, s);
        }
    }
    (0.0, PERCENT_MAX, PERCENT_MAX / intervals)
}

/// Draws `segments` left to right from `(x, y)`, each in its own colour (a title that is its
/// own legend).
fn draw_segments(img: &mut RgbImage, x: i64, y: i64, segments: &[(&str, Rgb<u8>)]) {
    let mut x = x;
    for &(text, ink) in segments {
        let style = TextStyle { ink, ..LABEL_TEXT };
        style.draw(img, x.max(0) as u32, y.max(0) as u32, text);
        x += i64::from(style.width_px(text) + style.gap_px);
    }
}

/// Re-plots `curves.png`: top panel the training loss (each step light blue, its running mean
/// over [`TRAIN_SMOOTH_STEPS`] blue) and the validation loss (red) vs step on one shared log10
/// scale spanning the data; bottom panel validation delta1 (red) vs step on a scale fitted to
/// the points ([`percent_axis`]; 0..100 % without any). Both panels share the step axis; each
/// carries a title in the colours of its lines, the grid lines their values and the step axis
/// its first and last step (the CSV files hold the numbers).
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
        x0: LEFT_MARGIN_PX,
        y0: PANEL_MARGIN_PX,
        x1: w - PANEL_MARGIN_PX,
        y1: h / 2 - PANEL_MARGIN_PX / 2,
    };
    let bottom = Panel {
        x0: LEFT_MARGIN_PX,
        y0: h / 2 + PANEL_MARGIN_PX / 2,
        x1: w - PANEL_MARGIN_PX,
        y1: h - PANEL_MARGIN_PX,
    };
    draw_frame(&mut img, top);
    draw_frame(&mut img, bottom);
    let title_y = |panel: Panel| panel.y0 - i64::from(LABEL_GAP_PX + LABEL_TEXT.height_px());
    let mean = format!("MEAN OF {TRAIN_SMOOTH_STEPS}");
    draw_segments(
        &mut img,
        top.x0,
        title_y(top),
        &[
            ("LOSS, LOG SCALE: ", AXIS),
            ("EACH STEP", TRAIN_RAW_COLOUR),
            (", ", AXIS),
            (&mean, TRAIN_COLOUR),
            (", ", AXIS),
            ("VALIDATION", VAL_COLOUR),
        ],
    );
    draw_segments(
        &mut img,
        bottom.x0,
        title_y(bottom),
        &[("VALIDATION DELTA1 (%)", VAL_COLOUR)],
    );
    let (train_log, val_log) = (log10_series(&train), log10_series(&val_loss));
    if let Some(b) = bounds_of(&[&train_log, &val_log]) {
        draw_series(&mut img, top, b, &train_log, TRAIN_RAW_COLOUR, false);
        let smooth = running_mean(&train_log, TRAIN_SMOOTH_STEPS);
        draw_series(&mut img, top, b, &smooth, TRAIN_COLOUR, false);
        draw_series(&mut img, top, b, &val_log, VAL_COLOUR, true);
        let labels: Vec<String> = (0..=GRID_LINES)
            .map(|k| {
                let log_v = b.y_max - (b.y_max - b.y_min) * k as f64 / GRID_LINES as f64;
                tick_label(10f64.powf(log_v))
            })
            .collect();
        label_rows(&mut img, top, &labels);
    }
    if let Some(b) = bounds_of(&[&train, &val_d1]) {
        let (y_min, y_max, grid_step) = match bounds_of(&[&val_d1]) {
            Some(v) => percent_axis(v.y_min, v.y_max),
            None => (0.0, PERCENT_MAX, PERCENT_MAX / GRID_LINES as f64),
        };
        let pct = Bounds { y_min, y_max, ..b };
        draw_series(&mut img, bottom, pct, &val_d1, VAL_COLOUR, true);
        // as many decimals as the grid step has
        let decimals = if grid_step.fract() == 0.0 {
            0
        } else if (grid_step * 2.0).fract() == 0.0 {
            1
        } else {
            2
        };
        let labels: Vec<String> = (0..=GRID_LINES)
            .map(|k| format!("{:.*}%", decimals, y_max - grid_step * k as f64))
            .collect();
        label_rows(&mut img, bottom, &labels);
        let y = (bottom.y1 + i64::from(LABEL_GAP_PX)) as u32;
        let (first, last) = (format!("{:.0}", b.x_min), format!("{:.0}", b.x_max));
        LABEL_TEXT.draw(&mut img, bottom.x0 as u32, y, &first);
        let x = bottom.x1 - i64::from(LABEL_TEXT.width_px(&last));
        LABEL_TEXT.draw(&mut img, x.max(0) as u32, y, &last);
        let x = (bottom.x0 + bottom.x1 - i64::from(LABEL_TEXT.width_px(STEP_AXIS_TITLE))) / 2;
        LABEL_TEXT.draw(&mut img, x.max(0) as u32, y, STEP_AXIS_TITLE);
    }
    let tmp = out_png.with_extension("png.tmp");
    img.save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, out_png).map_err(|e| format!("{}: {e}", out_png.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_running_mean_averages_the_last_points() {
        let s: Vec<(f64, f64)> = [1.0, 3.0, 5.0, 7.0]
            .iter()
            .enumerate()
            .map(|(i, &y)| (i as f64, y))
            .collect();
        let m = running_mean(&s, 2);
        assert_eq!(m, vec![(0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (3.0, 6.0)]);
        assert_eq!(tick_label(0.523), "0.52");
        assert_eq!(tick_label(1.26), "1.3");
        assert_eq!(tick_label(2300.0), "2300");
    }

    #[test]
    fn curves_carry_their_labels_and_the_running_mean() {
        let dir = std::env::temp_dir().join(format!("mode360-curves-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (train, val, png) = (
            dir.join("train.csv"),
            dir.join("val.csv"),
            dir.join("c.png"),
        );
        let mut t = format!("{TRAIN_CSV_HEADER}\n");
        for step in 1..=200 {
            // alternating 1 and 100: the running mean sits at 10 in the middle of the panel
            let loss = if step % 2 == 0 { 100.0 } else { 1.0 };
            t += &format!("{step},{loss},1e-4,1.0,100\n");
        }
        std::fs::write(&train, t).unwrap();
        std::fs::write(&val, "step,loss,delta1_pct\n100,10,50\n200,10,60\n").unwrap();
        plot_curves(&train, &val, &png).unwrap();
        let img = image::open(&png).unwrap().to_rgb8();
        std::fs::remove_dir_all(&dir).ok();
        // the value labels: ink left of both panels
        let label_ink = |y0: u32, y1: u32| {
            (y0..y1)
                .flat_map(|y| (0..LEFT_MARGIN_PX as u32).map(move |x| (x, y)))
                .filter(|&(x, y)| *img.get_pixel(x, y) == AXIS)
                .count()
        };
        let h = PLOT_HEIGHT_PX;
        assert!(label_ink(0, h / 2) > 50, "top panel labels");
        assert!(label_ink(h / 2, h) > 50, "bottom panel labels");
        // the running mean (blue) passes the top panel's middle row band, where no raw point lies
        let mid = ((PANEL_MARGIN_PX + h as i64 / 2 - PANEL_MARGIN_PX / 2) / 2) as u32;
        let blue = (mid - 3..=mid + 3)
            .flat_map(|y| (LEFT_MARGIN_PX as u32..PLOT_WIDTH_PX).map(move |x| (x, y)))
            .filter(|&(x, y)| *img.get_pixel(x, y) == TRAIN_COLOUR)
            .count();
        assert!(blue > 200, "running mean pixels near the middle: {blue}");
        // the titles, in the lines' colours, above the top panel
        let title_ink = |c: Rgb<u8>| {
            (0..PANEL_MARGIN_PX as u32)
                .flat_map(|y| (0..PLOT_WIDTH_PX).map(move |x| (x, y)))
                .filter(|&(x, y)| *img.get_pixel(x, y) == c)
                .count()
        };
        assert!(title_ink(TRAIN_COLOUR) > 50 && title_ink(VAL_COLOUR) > 50);
        // delta1 50 and 60 % on a 45..65 % axis: the validation line spans half the bottom
        // panel (a tenth on a fixed 0..100 % axis)
        let red_rows: Vec<u32> = (h / 2 + PANEL_MARGIN_PX as u32 / 2..h - PANEL_MARGIN_PX as u32)
            .filter(|&y| {
                (LEFT_MARGIN_PX as u32..PLOT_WIDTH_PX).any(|x| *img.get_pixel(x, y) == VAL_COLOUR)
            })
            .collect();
        let panel_h = f64::from(h / 2 - PANEL_MARGIN_PX as u32 * 3 / 2);
        let span = f64::from(red_rows.last().unwrap() - red_rows.first().unwrap());
        assert!(
            (span / panel_h - 0.5).abs() < 0.05,
            "validation line spans {span} of {panel_h} rows"
        );
    }

    #[test]
    fn the_delta1_axis_fits_its_points() {
        // a tenth of a point apart: quarter-point grid steps
        assert_eq!(percent_axis(92.8, 92.93), (92.75, 93.75, 0.25));
        // a point on a grid line gets one step below it
        assert_eq!(percent_axis(50.0, 60.0), (45.0, 65.0, 5.0));
        // never below 0 or above 100
        assert_eq!(percent_axis(0.0, 3.0), (0.0, 4.0, 1.0));
        assert_eq!(percent_axis(99.0, 100.0), (98.0, 100.0, 0.5));
        assert_eq!(percent_axis(3.0, 97.0), (0.0, 100.0, 25.0));
    }
}
