//! Progress bars (indicatif) with one style for the whole tool.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over `len` steps with a message.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>10} [{elapsed_precise}] {bar:32.cyan/blue} {pos}/{len} {msg}")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}
