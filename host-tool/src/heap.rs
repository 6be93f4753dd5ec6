//! `driftid`'s global allocator on Linux with glibc: glibc's, asking for transparent huge pages
//! for the large blocks (the samples of a recording, the smoother's nodes and covariances).
//!
//! A 60-h recording at 1 s fills ~25 MB of fresh memory, and each 4-KiB page of it costs a
//! page fault on first touch: ~7 000 faults, a fifth of reading the file (perf). In a block
//! marked `MADV_HUGEPAGE` the kernel maps 2-MiB pages instead, one fault each. Machines whose
//! transparent huge pages are set to `never` refuse the advice; the block is then served as
//! before. glibc's own switch for this (`GLIBC_TUNABLES=glibc.malloc.hugetlb=1`) is read from
//! the environment at process start, which a program cannot set for itself; allocator crates
//! that do it (jemalloc, mimalloc) would replace glibc's allocator and its tuning
//! ([`crate::cli::common::keep_freed_memory`]) for this one effect.
//!
//! It also keeps the heap within a **budget** ([`set_budget`]; `--max-memory-mib`, by default
//! [`default_budget`]: 80 % of the memory free when driftid starts). A block that would take the
//! heap past it is refused as the system's refusals are: the reader names the line it reached,
//! anywhere else the process ends with exit 2 and a message ([`refused`]). Without it a
//! recording larger than the machine's memory was not refused on Linux — memory is overcommitted
//! — but swapped, then killed by the kernel (SIGKILL, no message).

use std::alloc::{GlobalAlloc, Layout};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

/// glibc's allocator, blocks of [`LARGE_BYTES`] or more placed on whole huge pages (aligned to
/// one, their size rounded up to one: ≤ 2 MiB more per block) and advised to use them.
/// Unaligned, the part of a block before its first and after its last whole huge page still
/// faulted page by page: half the faults of the 60-h run were left. It calls glibc directly
/// (as `std::alloc::System` does) so that every block, of either kind, is freed by `free`: a
/// large block shrinks in place and a block can change kind in `realloc`.
pub struct HugePages;

/// Size of a transparent huge page on x86-64 and aarch64 (4-KiB base pages).
const HUGE_PAGE_BYTES: usize = 2 << 20;
/// Blocks from this size are placed on huge pages.
pub(crate) const LARGE_BYTES: usize = 2 * HUGE_PAGE_BYTES;
/// The alignment `malloc` guarantees (glibc: twice a pointer's size).
const MALLOC_ALIGN: usize = 2 * std::mem::size_of::<usize>();

/// `size` bytes aligned to `align` (a power of two), or null.
fn aligned(align: usize, size: usize) -> *mut u8 {
    let mut ptr = std::ptr::null_mut();
    // SAFETY: posix_memalign writes the block's address through the valid pointer; `align` is
    // a power of two and a multiple of a pointer's size.
    let rc =
        unsafe { libc::posix_memalign(&mut ptr, align.max(std::mem::size_of::<usize>()), size) };
    if rc == 0 {
        ptr.cast()
    } else {
        std::ptr::null_mut()
    }
}

/// Bytes in live blocks, each counted as [`charged`].
static LIVE: AtomicUsize = AtomicUsize::new(0);
/// The budget: a block that would take [`LIVE`] past it is refused. No limit until set.
static BUDGET: AtomicUsize = AtomicUsize::new(usize::MAX);

/// Keeps the heap's live blocks within `bytes` from now on (blocks already live count).
pub fn set_budget(bytes: usize) {
    BUDGET.store(bytes, Relaxed);
}

/// The budget in force, bytes (`usize::MAX`: none).
pub fn budget() -> usize {
    BUDGET.load(Relaxed)
}

/// Bytes in the heap's live blocks (what the budget bounds).
pub fn live_bytes() -> usize {
    LIVE.load(Relaxed)
}

/// The default budget: 80 % of the memory this process can have when it starts — the least of
/// the machine's available memory (`MemAvailable`: free memory and caches the kernel can drop)
/// and its cgroup's room (`memory.max − memory.current`, cgroup v2: a container's limit). `None`
/// where neither can be read (no limit is then set). The 20 % left covers what the heap's live
/// blocks do not count: the program, the threads' stacks, the allocator's free lists (measured:
/// 10–30 MB; a 60-h run at 1 s needs a budget of 40 MiB and peaks at 68 MB resident).
pub fn default_budget() -> Option<usize> {
    let available = meminfo_available();
    let cgroup = cgroup_room();
    let least = match (available, cgroup) {
        (Some(a), Some(c)) => a.min(c),
        (a, c) => a.or(c)?,
    };
    Some((least / 5 * 4) as usize)
}

/// `MemAvailable` of `/proc/meminfo`, bytes.
fn meminfo_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb.saturating_mul(1024))
}

/// Room left under this process's cgroup-v2 memory limit, bytes (`None`: no limit, or no
/// cgroup v2).
fn cgroup_room() -> Option<u64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let rel = own.lines().find_map(|l| l.strip_prefix("0::"))?;
    let dir = std::path::Path::new("/sys/fs/cgroup").join(rel.trim_start_matches('/'));
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).ok();
    let max: u64 = read("memory.max")?.trim().parse().ok()?; // "max": no limit
    let current: u64 = read("memory.current")?.trim().parse().ok()?;
    Some(max.saturating_sub(current))
}

/// What a block of `size` bytes counts against the budget: a large block its whole huge pages.
fn charged(size: usize) -> usize {
    if size >= LARGE_BYTES {
        size.next_multiple_of(HUGE_PAGE_BYTES)
    } else {
        size
    }
}

/// Counts `bytes` more as live if the budget allows them.
fn take(bytes: usize) -> bool {
    let before = LIVE.fetch_add(bytes, Relaxed);
    if before.saturating_add(bytes) > BUDGET.load(Relaxed) {
        LIVE.fetch_sub(bytes, Relaxed);
        false
    } else {
        true
    }
}

/// Counts `bytes` fewer as live.
fn give(bytes: usize) {
    LIVE.fetch_sub(bytes, Relaxed);
}

/// Allocations in progress whose caller handles a refusal itself (the reader's `try_reserve`,
/// [`fallibly`]): a null is returned to them. Any other refusal ends the process with exit 2
/// and a message ([`refused`]) instead of Rust's abort (exit 134, "memory allocation of …
/// failed", once garbled by a second failing allocation while printing).
static FALLIBLE: AtomicUsize = AtomicUsize::new(0);

/// Runs `f` with the allocator's refusals returned as null (for `try_reserve`).
pub(crate) fn fallibly<T>(f: impl FnOnce() -> T) -> T {
    use std::sync::atomic::Ordering::SeqCst;
    FALLIBLE.fetch_add(1, SeqCst);
    let r = f();
    FALLIBLE.fetch_sub(1, SeqCst);
    r
}

/// A refused block of `size` bytes (`by_budget`: refused by the budget, not the system): null
/// inside [`fallibly`]; otherwise the message and exit 2 at once. Written with `write(2)` from a
/// stack buffer (no allocation: there may be no memory) and ended with `_exit` (no destructor
/// may allocate), after the unfinished outputs' temporary files are removed
/// ([`crate::output::remove_temporaries_now`]; the budget lifted for it, so that only the system
/// can refuse its few small blocks).
fn refused(size: usize, by_budget: bool) -> *mut u8 {
    if FALLIBLE.load(std::sync::atomic::Ordering::SeqCst) > 0 {
        return std::ptr::null_mut();
    }
    let mut buf = [0u8; 640];
    let mut n = 0;
    let mut put = |b: &[u8]| {
        let k = b.len().min(buf.len() - n);
        buf[n..n + k].copy_from_slice(&b[..k]);
        n += k;
    };
    let mut digits = [0u8; 20];
    put(b"driftid: error: out of memory: a block of ");
    put(decimal(size, &mut digits));
    if by_budget {
        put(b" bytes would take the heap past its budget of ");
        put(decimal(budget() >> 20, &mut digits));
        put(
            b" MiB (--max-memory-mib; by default 80 % of the memory free when driftid starts); \
              give it more (--max-memory-mib, a larger machine), a longer --period-s, or split \
              the recording into shorter runs (README, \"Bad input\")\n",
        );
    } else {
        put(
            b" bytes was refused; give the process more memory (ulimit -v, a larger machine), \
              a longer --period-s, or split the recording into shorter runs (README, \"Bad input\")\n",
        );
    }
    static ENDING: AtomicUsize = AtomicUsize::new(0);
    if ENDING.fetch_add(1, Relaxed) == 0 {
        set_budget(usize::MAX);
        crate::output::remove_temporaries_now();
    }
    // SAFETY: write(2) of an initialised stack buffer, then _exit: async-signal-safe calls that
    // neither allocate nor run destructors.
    unsafe {
        libc::write(2, buf.as_ptr().cast(), n);
        libc::_exit(2)
    }
}

/// `v` in decimal, written into `digits` (no allocation).
fn decimal(mut v: usize, digits: &mut [u8; 20]) -> &[u8] {
    let mut d = digits.len();
    loop {
        d -= 1;
        digits[d] = b'0' + (v % 10) as u8;
        v /= 10;
        if v == 0 {
            break;
        }
    }
    &digits[d..]
}

/// A large block: on whole huge pages, advised to use them.
fn large(layout: Layout) -> *mut u8 {
    let size = layout.size().next_multiple_of(HUGE_PAGE_BYTES);
    let ptr = aligned(layout.align().max(HUGE_PAGE_BYTES), size);
    if !ptr.is_null() {
        // SAFETY: the range is the block just allocated; MADV_HUGEPAGE changes only how the
        // kernel backs it, never its contents. A refusal (huge pages off) changes nothing.
        unsafe {
            libc::madvise(ptr.cast(), size, libc::MADV_HUGEPAGE);
        }
    }
    ptr
}

/// A block from glibc with the caller's layout (huge pages when large), or null; not counted.
fn system_alloc(layout: Layout) -> *mut u8 {
    if layout.size() >= LARGE_BYTES {
        large(layout)
    } else if layout.align() <= MALLOC_ALIGN && layout.align() <= layout.size() {
        // SAFETY: malloc of a non-zero size (GlobalAlloc's contract).
        unsafe { libc::malloc(layout.size()).cast() }
    } else {
        aligned(layout.align(), layout.size())
    }
}

// SAFETY: every block comes from malloc, calloc, realloc or posix_memalign with at least the
// size and alignment asked for, and is freed by `free`, which takes any of them. Every live
// block is counted in LIVE as `charged(its layout's size)`: taken before it is made, given back
// when it is freed or fails, adjusted when it changes size.
unsafe impl GlobalAlloc for HugePages {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let bytes = charged(layout.size());
        if !take(bytes) {
            return refused(layout.size(), true);
        }
        let ptr = system_alloc(layout);
        if ptr.is_null() {
            give(bytes);
            refused(layout.size(), false)
        } else {
            ptr
        }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() < LARGE_BYTES
            && layout.align() <= MALLOC_ALIGN
            && layout.align() <= layout.size()
        {
            if !take(layout.size()) {
                return refused(layout.size(), true);
            }
            // SAFETY: calloc of a non-zero size; it skips clearing memory fresh from the kernel.
            let ptr: *mut u8 = unsafe { libc::calloc(layout.size(), 1).cast() };
            return if ptr.is_null() {
                give(layout.size());
                refused(layout.size(), false)
            } else {
                ptr
            };
        }
        // SAFETY: `alloc` with the caller's layout; the block it returns holds `size` bytes.
        unsafe {
            let ptr = self.alloc(layout);
            if !ptr.is_null() {
                std::ptr::write_bytes(ptr, 0, layout.size());
            }
            ptr
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        give(charged(layout.size()));
        // SAFETY: `ptr` came from this allocator, so from glibc (see the impl's SAFETY).
        unsafe { libc::free(ptr.cast()) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let small = |size: usize| size < LARGE_BYTES;
        let (old_bytes, new_bytes) = (charged(layout.size()), charged(new_size));
        if small(layout.size()) && small(new_size) && layout.align() <= MALLOC_ALIGN {
            if layout.align() <= new_size {
                if new_bytes > old_bytes && !take(new_bytes - old_bytes) {
                    return refused(new_size, true);
                }
                // SAFETY: `ptr` is a malloc'd block (the caller's contract), `new_size` > 0.
                let new: *mut u8 = unsafe { libc::realloc(ptr.cast(), new_size).cast() };
                if new.is_null() {
                    give(new_bytes.saturating_sub(old_bytes));
                    return refused(new_size, false);
                }
                give(old_bytes.saturating_sub(new_bytes));
                return new;
            }
        } else if !small(layout.size()) && new_size <= layout.size() {
            // A large block shrinks in place (`free` does not ask its size); it counts as its
            // new layout from now on, as `dealloc` will.
            give(old_bytes - new_bytes);
            return ptr;
        }
        // SAFETY: the caller's contract for `realloc` makes the new layout valid; the old block
        // holds `layout.size()` bytes and the new one `new_size`.
        unsafe {
            let new = self.alloc(Layout::from_size_align_unchecked(new_size, layout.align()));
            if !new.is_null() {
                std::ptr::copy_nonoverlapping(ptr, new, layout.size().min(new_size));
                self.dealloc(ptr, layout);
            }
            new
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(size: usize, align: usize) -> Layout {
        Layout::from_size_align(size, align).unwrap()
    }

    /// A large block starts on a huge page; what is written survives growth, a shrink in place
    /// (the same address), and a change of kind either way; zeroed blocks read zero.
    #[test]
    fn blocks_keep_their_contents_across_kinds() {
        let a = HugePages;
        // SAFETY: each block is used within its size and freed once, with its layout.
        unsafe {
            let big = layout(LARGE_BYTES + 123, 8);
            let p = a.alloc(big);
            assert!(!p.is_null());
            assert_eq!(
                p as usize % HUGE_PAGE_BYTES,
                0,
                "large block on a huge page"
            );
            for k in 0..big.size() {
                *p.add(k) = (k % 251) as u8;
            }
            // Shrink within the large kind: in place.
            let q = a.realloc(p, big, LARGE_BYTES);
            assert_eq!(q, p, "a large block shrinks in place");
            // Grow: moved, contents kept.
            let grown = a.realloc(q, layout(LARGE_BYTES, 8), 3 * LARGE_BYTES);
            for k in 0..LARGE_BYTES {
                assert_eq!(*grown.add(k), (k % 251) as u8, "byte {k} after growth");
            }
            // Large to small: in place; small to large: moved; contents kept.
            let small = a.realloc(grown, layout(3 * LARGE_BYTES, 8), 1000);
            let again = a.realloc(small, layout(1000, 8), LARGE_BYTES + 1);
            for k in 0..1000 {
                assert_eq!(
                    *again.add(k),
                    (k % 251) as u8,
                    "byte {k} after the kind changed"
                );
            }
            a.dealloc(again, layout(LARGE_BYTES + 1, 8));
            // The budget (here, in the same test: a concurrent test's blocks would be refused by
            // it, ending the process): a block past it is refused — null inside `fallibly` —, one
            // within it is not, and freeing gives the room back.
            let before = live_bytes();
            set_budget(before + 4096);
            let l = layout(3000, 8);
            assert!(
                fallibly(|| a.alloc(layout(5000, 8))).is_null(),
                "past the budget"
            );
            let p = a.alloc(l);
            assert!(!p.is_null() && live_bytes() == before + 3000);
            assert!(
                fallibly(|| a.realloc(p, l, 5000)).is_null(),
                "grown past the budget"
            );
            a.dealloc(p, l);
            assert_eq!(live_bytes(), before);
            set_budget(usize::MAX);
            // Zeroed, both kinds, and an alignment above malloc's.
            for (size, align) in [(100, 8), (LARGE_BYTES, 8), (4096, 4096)] {
                let l = layout(size, align);
                let z = a.alloc_zeroed(l);
                assert_eq!(z as usize % align, 0);
                assert!((0..size).all(|k| *z.add(k) == 0), "{size} bytes zeroed");
                a.dealloc(z, l);
            }
            assert_eq!(live_bytes(), 0, "every block counted and given back");
        }
    }
}
