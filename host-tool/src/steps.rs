//! Which step a long computation is on, for whoever shows it. The library names its steps through
//! a [`Progress`] its caller gives ("rung 2: refitting acc-bias (3/7)"); it writes nothing
//! itself: the CLI turns the notes into a spinner's message on a terminal
//! ([`crate::progress::follow`]), and a caller that gives none pays nothing.

use std::sync::Arc;

/// What receives the notes.
type Sink = Arc<dyn Fn(&str) + Send + Sync>;

/// Where the notes of a computation go (nowhere by default), with the prefix of the part of the
/// work it is in (`rung 2`).
#[derive(Clone, Default)]
pub struct Progress {
    sink: Option<Sink>,
    prefix: String,
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Progress")
            .field("listened", &self.sink.is_some())
            .field("prefix", &self.prefix)
            .finish()
    }
}

impl Progress {
    /// Notes go to `sink`.
    pub fn new(sink: impl Fn(&str) + Send + Sync + 'static) -> Self {
        Progress {
            sink: Some(Arc::new(sink)),
            prefix: String::new(),
        }
    }

    /// Says which step the work is on; `step` is formatted only when someone listens.
    pub(crate) fn note(&self, step: impl FnOnce() -> String) {
        if let Some(sink) = &self.sink {
            let step = step();
            if self.prefix.is_empty() {
                sink(&step);
            } else {
                sink(&format!("{}: {step}", self.prefix));
            }
        }
    }

    /// The same sink, its notes prefixed by `part` (`rung 2: …`).
    pub(crate) fn within(&self, part: impl Into<String>) -> Progress {
        let part = part.into();
        Progress {
            sink: self.sink.clone(),
            prefix: if self.prefix.is_empty() {
                part
            } else {
                format!("{}: {part}", self.prefix)
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Progress;
    use std::sync::{Arc, Mutex};

    #[test]
    fn notes_carry_the_part_of_the_work_they_come_from() {
        let seen = Arc::new(Mutex::new(vec![]));
        let s = seen.clone();
        let p = Progress::new(move |m| s.lock().unwrap().push(m.to_string()));
        p.note(|| "fitting".into());
        p.within("rung 2")
            .note(|| "refitting acc-bias (3/7)".into());
        p.within("rung 2").within("x").note(|| "y".into());
        assert_eq!(
            *seen.lock().unwrap(),
            [
                "fitting",
                "rung 2: refitting acc-bias (3/7)",
                "rung 2: x: y"
            ]
        );
        // Nobody listening: the step is not even formatted.
        Progress::default().note(|| unreachable!("formatted without a listener"));
    }
}
