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

/// A bar per stage of a job that reports its stages one after another: each new stage
/// clears the last one's bar and starts its own.
pub struct StageBars<S> {
    unit: &'static str,
    current: Option<(S, ProgressBar)>,
}

impl<S: PartialEq> StageBars<S> {
    pub fn new(unit: &'static str) -> Self {
        Self {
            unit,
            current: None,
        }
    }

    /// `done` of `total` in `stage`, called `name`.
    pub fn update(&mut self, stage: S, name: &str, total: usize, done: usize) {
        if self
            .current
            .as_ref()
            .is_none_or(|(shown, _)| *shown != stage)
        {
            self.finish();
            self.current = Some((stage, bar(total as u64, name, self.unit)));
        }
        if let Some((_, bar)) = &self.current {
            bar.set_position(done as u64);
        }
    }

    /// Clears the bar of the last stage.
    pub fn finish(&mut self) {
        if let Some((_, bar)) = self.current.take() {
            bar.finish_and_clear();
        }
    }
}
