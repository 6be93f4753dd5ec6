//! Progress for long runs: drawn on a terminal (stderr), silent when piped or redirected.

use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar of `len` steps with a message; hidden unless stderr is a terminal.
pub(crate) fn bar(len: u64, msg: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})")
            .unwrap()
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// Notes of the library's steps ([`crate::steps::Progress`]) as `pb`'s message; nothing when
/// `pb` is hidden (stderr not a terminal), so a redirected run formats no message at all.
pub(crate) fn follow(pb: &ProgressBar) -> crate::steps::Progress {
    if pb.is_hidden() {
        return crate::steps::Progress::default();
    }
    let pb = pb.clone();
    crate::steps::Progress::new(move |m| pb.set_message(m.to_string()))
}

/// A spinner with a message that the caller updates; hidden unless stderr is a terminal.
pub(crate) fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    pb.set_style(ProgressStyle::with_template("{spinner} {msg} ({elapsed})").unwrap());
    pb.set_message(msg.to_string());
    // indicatif's steady tick is a thread of its own, started (and joined when the spinner
    // finishes) even for a hidden spinner: only on a terminal.
    if !pb.is_hidden() {
        pb.enable_steady_tick(Duration::from_millis(120));
    }
    pb
}
