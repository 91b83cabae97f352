//! Progress display for long work (indicatif).
//!
//! Owns: the bar style. Must not touch: what is being done.

use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar (hidden when `show` is false).
pub fn progress_bar(len: u64, msg: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}
