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
