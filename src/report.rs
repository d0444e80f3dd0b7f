//! How a command's failure is printed, and the exit code it ends with.

use std::backtrace::BacktraceStatus;
use std::process::ExitCode;

/// The exit code of a command's `result`, its error printed first (with the backtrace
/// when one was captured, `RUST_BACKTRACE=1`).
pub fn exit_code(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("{}", report(&error));
            if error.backtrace().status() == BacktraceStatus::Captured {
                eprintln!("\nStack backtrace:\n{}", error.backtrace());
            }
            ExitCode::FAILURE
        }
    }
}

/// `error` as anyhow prints it (`Error: …`, then `Caused by:` and one cause per line),
/// without the causes whose text the line before already ends with: many errors print
/// their source in their own message (`{path}: {source}`) and still give it as their
/// source, which would otherwise be said twice.
fn report(error: &anyhow::Error) -> String {
    let mut lines: Vec<String> = Vec::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if lines.last().is_none_or(|last| !last.ends_with(&text)) {
            lines.push(text);
        }
    }
    let mut report = format!("Error: {}", lines[0]);
    if lines.len() > 1 {
        report.push_str("\n\nCaused by:");
        for (k, line) in lines[1..].iter().enumerate() {
            let indented = line.replace('\n', "\n       ");
            if lines.len() == 2 {
                report.push_str(&format!("\n    {indented}"));
            } else {
                report.push_str(&format!("\n    {k}: {indented}"));
            }
        }
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_the_message_already_ends_with_is_said_once() {
        let io = std::io::Error::other("No such file or directory");
        let dataset = ciflow_envs::dataset::DatasetError::Io {
            path: "lc/data/metadata.json".into(),
            source: io,
        };
        let error = anyhow::Error::new(dataset).context("reading the dataset lc");
        assert_eq!(
            report(&error),
            "Error: reading the dataset lc\n\nCaused by:\n    \
             lc/data/metadata.json: No such file or directory"
        );
        let twice = anyhow::anyhow!("inner").context("middle").context("outer");
        assert_eq!(
            report(&twice),
            "Error: outer\n\nCaused by:\n    0: middle\n    1: inner"
        );
    }
}
