//! Progress bars of the long-running commands (rendering, conversion, evaluation).

use indicatif::{ProgressBar, ProgressStyle};

/// Bar template: label, elapsed time, bar, frames done of all, rate and remaining time.
const FRAMES_TEMPLATE: &str =
    "{msg} [{elapsed_precise}] {bar:30} {pos}/{len} frames ({per_sec}, ETA {eta})";
/// Template when the number of frames is not known in advance.
const OPEN_ENDED_TEMPLATE: &str = "{msg} [{elapsed_precise}] {spinner} {pos} frames ({per_sec})";

/// A bar over `frames` frames labelled `label`, hidden when `show` is false (tests, child
/// processes). `frames` = 0: the count is not known, the bar counts up without an ETA.
pub fn frames_bar(label: &str, frames: usize, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(frames as u64);
    let template = if frames == 0 {
        OPEN_ENDED_TEMPLATE
    } else {
        FRAMES_TEMPLATE
    };
    pb.set_style(
        ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(label.to_string());
    pb
}

/// Prints `line` above `bar` while the bar is drawn, or on stdout when it is hidden (output to
/// a log file, a background job such as the standing training job), so that a long job's
/// result lines reach its log either way (indicatif drops them on a hidden bar).
pub fn println(bar: &ProgressBar, line: impl AsRef<str>) {
    if bar.is_hidden() {
        println!("{}", line.as_ref());
    } else {
        bar.println(line);
    }
}
