//! Work shared between the calling thread and rayon's pool.
//!
//! Why not a thread per helper, or a `par_iter` from outside the pool: on the 2-core VM a thread
//! spawned for a helper was placed by the scheduler on the caller's core and mostly started only
//! once the caller waited for it (28 of 30 spawns in a test program), and a `par_iter` called
//! from outside the pool left the caller waiting for one worker to wake and then another (the
//! screening's two pieces ran one after the other in most runs). The pool's workers are woken
//! where a core is idle, and the caller keeps working meanwhile.

/// Starts rayon's global pool (its threads as `RAYON_NUM_THREADS` or the cores say), each
/// worker, and this thread, first registering the thread-local state a fit would register
/// later ([`register_thread_locals`]). A pool started already is left as it is.
pub fn start() {
    register_thread_locals();
    let _ = rayon::ThreadPoolBuilder::new()
        .start_handler(|_| register_thread_locals())
        .build_global();
}

/// How long [`register_thread_locals`]' receive waits: past the channel's spinning, so that it
/// blocks.
const REGISTER_WAIT: std::time::Duration = std::time::Duration::from_micros(200);

/// A receive that blocks on one of std's channels registers the thread's waiting context, a
/// thread-local whose destructor glibc records in a block it allocates itself. The smoother's
/// pipeline ([`crate::identify::smoother`]) first blocks in the fit, and there, with the memory
/// spent under `ulimit -v`, glibc could not allocate that block and aborted ("failed to
/// register TLS destructor: out of memory", exit 134, 1 run in 5 of a 24-h run under 90 MB,
/// `memory_refused_during_the_fit_is_exit_2_with_a_message`) where every refusal of the heap's
/// ends with exit 2 and a message ([`crate::heap`]). Blocked once at the thread's start, it is
/// registered while there is memory. (Which thread-locals a thread registers, and when: gdb on
/// `__cxa_thread_atexit_impl`, docs/bad-input.md.)
fn register_thread_locals() {
    let (_keep_open, rx) = std::sync::mpsc::sync_channel::<()>(1);
    let _ = rx.recv_timeout(REGISTER_WAIT);
}

/// Runs `f` on every item: the first on this thread, the others as jobs on rayon's pool
/// (`rayon::in_place_scope`); returns when all are done.
pub(crate) fn caller_first<I>(items: I, f: impl Fn(I::Item) + Sync)
where
    I: IntoIterator,
    I::Item: Send,
{
    let f = &f;
    rayon::in_place_scope(|scope| {
        let mut items = items.into_iter();
        let first = items.next();
        for item in items {
            scope.spawn(move |_| f(item));
        }
        if let Some(item) = first {
            f(item);
        }
    });
}

#[cfg(test)]
mod tests {
    /// Every item is run once, whatever the count (none, one, several).
    #[test]
    fn every_item_runs_once() {
        for n in [0usize, 1, 2, 7] {
            let mut seen = vec![0u32; n];
            super::caller_first(seen.iter_mut(), |s| *s += 1);
            assert_eq!(seen, vec![1; n], "{n} items");
        }
    }
}
