//! Progress bars of the per-frame commands on stderr, drawn only where stderr is a
//! terminal: a log file or a pipe gets the commands' summary lines alone.

use std::io::IsTerminal;

/// A bar of `len` items named `unit`, prefixed by the command's name.
pub fn bar(command: &str, len: usize, unit: &str) -> indicatif::ProgressBar {
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{command} [{{bar:30}}] {{pos}}/{{len}} {unit} {{elapsed}}<{{eta}}"
        ))
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.tick();
    bar
}
