//! Work shared between the calling thread and rayon's pool.
//!
//! Why not a thread per helper, or a `par_iter` from outside the pool: on the 2-core VM a thread
//! spawned for a helper was placed by the scheduler on the caller's core and mostly started only
//! once the caller waited for it (28 of 30 spawns in a test program), and a `par_iter` called
//! from outside the pool left the caller waiting for one worker to wake and then another (the
//! screening's two pieces ran one after the other in most runs). The pool's workers are woken
//! where a core is idle, and the caller keeps working meanwhile.

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

/// Runs `f` on the spare cores: a pool of its own whose threads run at the lowest priority
/// (Linux: nice 19, a weight of 15 against a normal thread's 1024), so work that may be thrown
/// away takes only the cores the work that counts leaves idle, and all of them once it is done.
/// Elsewhere the threads run at the normal priority (the answer is the same, only slower).
/// `f` may use rayon inside: its jobs stay on this pool.
pub(crate) fn on_spare_cores<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    static SPARE: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    let pool = SPARE.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name(|k| format!("spare-{k}"))
            .start_handler(|_| lowest_priority())
            .build()
            .ok()
    });
    match pool {
        Some(pool) => pool.install(f),
        // No threads to be had: on the caller's pool.
        None => f(),
    }
}

/// This thread at the lowest scheduling priority (best effort: a thread left at the normal one
/// only competes for the cores).
fn lowest_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: gettid has no preconditions; setpriority reads its plain arguments. PRIO_PROCESS
    // with a thread id sets that thread's nice value on Linux (setpriority(2), BUGS).
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
    }
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
