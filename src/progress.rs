//! The command line's progress bars: one look for every long job.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over `len` `unit`s, prefixed with `what`, showing its message, the elapsed time
/// and an estimate of what is left.
pub fn bar(len: u64, what: &str, unit: &str) -> ProgressBar {
    let template = format!(
        "{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {unit} {{msg}} ({{elapsed}}, eta {{eta}})"
    );
    let bar = ProgressBar::new(len).with_style(
        ProgressStyle::with_template(&template)
            .expect("a valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_owned());
    bar
}
