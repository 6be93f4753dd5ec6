//! Reading a recording's rows on several cores, with the one-thread reader's results.
//!
//! After the header, the file is read in blocks cut at line ends. In each round, the first block
//! is read on this thread by the reader standing where the last block ended
//! ([`RecordingReader::resume_over`]), the others each on rayon's pool by a reader that
//! does not yet know where it stands: its lines are numbered from the block's start and its
//! first time is not compared with the time before it. Joining them in file order shifts the
//! line numbers and makes that comparison at the seam. A block that fails either way (an error
//! in it, a time out of order at the seam) is read again on this thread from where it starts,
//! so every error and repair is the one the one-thread reader gives, on the same line.
//! Memory stays bounded: one round of blocks at a time, each read into a buffer of its own (not
//! mapped: a mapped file that another program shortens while it is read kills the reader with
//! SIGBUS). The rows grow by fallible reservation ([`Rows::push`]): memory that cannot be had is
//! [`RecordingError::OutOfMemory`], not an abort.

use std::collections::TryReserveError;
use std::io::{BufRead, Cursor, Read};

use super::{RawSample, RecordingError, RecordingReader};

/// Bytes per block (cut at the last line end within): a round of blocks on two cores takes
/// about a millisecond, against ~40 µs to start a thread.
pub(super) const BLOCK_BYTES: usize = 1 << 20;

/// Blocks read at once (this thread's and the pool's): the cores there are, at most 8; one
/// inside a rayon pool (recordings read in parallel already use every core).
pub(super) fn read_threads() -> usize {
    if rayon::current_thread_index().is_some() {
        return 1;
    }
    std::thread::available_parallelism().map_or(1, |n| n.get().min(8))
}

/// The rows read so far, their 1-based file lines, and the repairs made.
#[derive(Default)]
pub(super) struct Rows {
    pub samples: Vec<RawSample>,
    pub lines: Vec<u32>,
    pub repairs: Vec<String>,
}

/// The allocator's refusals returned to `try_reserve` (the allocator ends the process on others).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
use crate::heap::fallibly;
/// Elsewhere the system allocator returns every refusal.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn fallibly<T>(f: impl FnOnce() -> T) -> T {
    f()
}

impl Rows {
    /// Room for `n` more rows, or the allocator's refusal (no abort).
    pub fn try_reserve(&mut self, n: usize) -> Result<(), TryReserveError> {
        fallibly(|| {
            self.samples.try_reserve(n)?;
            self.lines.try_reserve(n)
        })
    }

    /// Adds a row, growing the vectors (by doubling) only if the memory can be had.
    #[inline]
    pub fn push(&mut self, line: u32, s: RawSample) -> Result<(), TryReserveError> {
        if self.samples.len() == self.samples.capacity()
            || self.lines.len() == self.lines.capacity()
        {
            self.try_reserve(1)?;
        }
        self.lines.push(line);
        self.samples.push(s);
        Ok(())
    }
}

/// The error for rows that found no memory, at `line` of `file`.
pub(super) fn out_of_memory(file: &str, line: u32, rows: &Rows) -> RecordingError {
    RecordingError::OutOfMemory {
        file: file.to_string(),
        line,
        samples: rows.samples.len(),
    }
}

/// Reads the rest of `reader` into `rows`, as the one-thread reader does: the error that ends it,
/// except a truncated last line after samples, which is dropped and reported as a repair.
pub(super) fn read_rows<R: BufRead>(
    reader: &mut RecordingReader<R>,
    rows: &mut Rows,
) -> Result<(), RecordingError> {
    while let Some(item) = reader.next() {
        match item {
            Ok((line, s)) => {
                if rows.push(line, s).is_err() {
                    return Err(out_of_memory(reader.display_name(), line, rows));
                }
            }
            // Only ever the last line (no newline follows it): keep everything before it.
            Err(e @ RecordingError::Truncated { .. }) if !rows.samples.is_empty() => {
                rows.repairs.push(format!(
                    "{e}; ignored that line, kept the {} samples before it",
                    rows.samples.len()
                ));
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// One block read on the pool: lines numbered from the block's start.
struct Detached {
    rows: Rows,
    /// Lines in the block.
    lines: u32,
    /// The last finite time and its line (block-relative).
    last: Option<(f64, u32)>,
    /// Whether the reader stopped at an error (the block is then read again in place).
    failed: bool,
}

fn read_detached(proto: &RecordingReader<&[u8]>, block: &[u8]) -> Detached {
    let mut reader = proto.resume_over(block, 0, None);
    // Room for the block's rows (40 bytes or more each): no regrowth.
    // Memory refused here fails the block: it is read again in place, where it is an error.
    let rows_hint = block.len() / 40 + 1;
    let mut rows = Rows::default();
    let mut failed = rows.try_reserve(rows_hint).is_err();
    while !failed {
        match reader.next() {
            Some(Ok((line, s))) => failed = rows.push(line, s).is_err(),
            Some(Err(_)) => failed = true,
            None => break,
        }
    }
    let (lines, last) = reader.position();
    Detached {
        rows,
        lines,
        last,
        failed,
    }
}

/// What reading the next block found.
enum Next {
    /// Whole lines (the last one without its line end only at the end of the input).
    Block(Vec<u8>),
    /// The end of the input.
    End,
    /// More than a block without a line end: left to the one-thread reader, which stops such
    /// a line at [`super::MAX_LINE_BYTES`].
    NoLineEnd(Vec<u8>),
}

/// Reads the next block from `inner`: `carry` (the part line left by the last block) and then
/// at least `block_bytes` more, cut after the last line end.
fn next_block(
    inner: &mut impl Read,
    carry: &mut Vec<u8>,
    block_bytes: usize,
) -> std::io::Result<Next> {
    let mut buf = std::mem::take(carry);
    let want = buf.len() + block_bytes;
    // The whole block at once: grown by doubling, a block moved and faulted in ~10 times.
    buf.reserve_exact(block_bytes);
    let mut at_end = false;
    while buf.len() < want {
        let got = inner
            .by_ref()
            .take((want - buf.len()) as u64)
            .read_to_end(&mut buf)?;
        if got == 0 {
            at_end = true;
            break;
        }
    }
    if at_end {
        return Ok(if buf.is_empty() {
            Next::End
        } else {
            Next::Block(buf)
        });
    }
    match memchr::memrchr(b'\n', &buf) {
        Some(i) => {
            carry.extend_from_slice(&buf[i + 1..]);
            buf.truncate(i + 1);
            Ok(Next::Block(buf))
        }
        None => Ok(Next::NoLineEnd(buf)),
    }
}

/// Reads the rows after the header (`head` stands there) into `rows` with `threads` threads,
/// in blocks of `block_bytes`; the results are the one-thread reader's ([`read_rows`]). Each
/// block is read into a buffer of its own, on one thread between the rounds: measured, 15.3 →
/// 16.0 ms of CPU for a 60-h recording at 1 s against mapping the file, which cost SIGBUS when
/// another program shortened the file while it was read.
pub(super) fn read_rows_parallel<R: BufRead>(
    head: RecordingReader<R>,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (proto, at, inner) = split_head(head);
    read_blocks(&proto, inner, at, rows, threads, block_bytes)
}

/// Where a reader stands: its last line, and the last finite time with its line.
type Position = (u32, Option<(f64, u32)>);

/// What the block readers start from: a reader like `head` over no bytes yet (to be resumed
/// over each block), where `head` stands (its line, its last time), and the rest of its input.
fn split_head<R: BufRead>(
    head: RecordingReader<R>,
) -> (RecordingReader<&'static [u8]>, Position, R) {
    let proto = head.resume_over(&b""[..], 0, None);
    (proto, head.position(), head.into_inner())
}

/// The rounds of blocks from `source`, the reader standing at `at` (its line, its last time).
fn read_blocks<R: BufRead>(
    proto: &RecordingReader<&[u8]>,
    mut inner: R,
    at: Position,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (mut line_no, mut prev) = at;
    let mut carry = Vec::new();
    loop {
        let mut blocks = Vec::with_capacity(threads);
        let mut stop = None;
        while blocks.len() < threads.max(1) && stop.is_none() {
            match next_block(&mut inner, &mut carry, block_bytes) {
                Ok(Next::Block(b)) => blocks.push(b),
                Ok(next) => stop = Some(Ok(next)),
                Err(e) => stop = Some(Err(e)),
            }
        }
        if let Some((first, rest)) = blocks.split_first() {
            read_round(proto, first, rest, rows, &mut line_no, &mut prev)?;
        }
        match stop {
            None => {}
            Some(Ok(Next::NoLineEnd(b))) => {
                let chained = Cursor::new(b).chain(inner);
                return read_rows(&mut proto.resume_over(chained, line_no, prev), rows);
            }
            Some(Ok(_)) => break,
            Some(Err(source)) => {
                return Err(RecordingError::Read {
                    file: proto.display_name().to_string(),
                    line: line_no.saturating_add(1),
                    source,
                })
            }
        }
    }
    Ok(())
}

/// Reads one round of blocks: `first` here from where the file stands (`line_no`, `prev`), the
/// `rest` each on rayon's pool, joined in order (and read again here when they fail).
fn read_round(
    proto: &RecordingReader<&[u8]>,
    first: &[u8],
    rest: &[Vec<u8>],
    rows: &mut Rows,
    line_no: &mut u32,
    prev: &mut Option<(f64, u32)>,
) -> Result<(), RecordingError> {
    // The other blocks go to rayon's pool while this thread reads the first (why the pool, not
    // a thread per round: `crate::pool`). A block whose job panicked is read again here.
    let mut detached: Vec<Option<Detached>> = Vec::with_capacity(rest.len());
    detached.resize_with(rest.len(), || None);
    let mut first_result = Ok(());
    rayon::in_place_scope(|scope| {
        for (b, out) in rest.iter().zip(detached.iter_mut()) {
            scope.spawn(move |_| {
                *out = std::panic::catch_unwind(|| read_detached(proto, b)).ok();
            });
        }
        let mut reader = proto.resume_over(first, *line_no, *prev);
        first_result = read_rows(&mut reader, rows);
        (*line_no, *prev) = reader.position();
    });
    first_result?;
    for (block, d) in rest.iter().zip(detached) {
        match d.filter(|d| !d.failed && fits(d, *line_no, *prev)) {
            Some(d) => {
                if rows.try_reserve(d.rows.samples.len()).is_err() {
                    let line = d.rows.lines.first().map_or(*line_no, |l| l + *line_no);
                    return Err(out_of_memory(proto.display_name(), line, rows));
                }
                rows.samples.extend_from_slice(&d.rows.samples);
                rows.lines.extend(d.rows.lines.iter().map(|l| l + *line_no));
                *prev = d.last.map(|(t, l)| (t, l + *line_no)).or(*prev);
                *line_no += d.lines;
            }
            None => {
                let mut reader = proto.resume_over(&block[..], *line_no, *prev);
                read_rows(&mut reader, rows)?;
                (*line_no, *prev) = reader.position();
            }
        }
    }
    Ok(())
}

/// Whether a detached block continues the file at `line_no` after the finite time `prev`: its
/// first finite time is later, and its line numbers stay within u32.
fn fits(d: &Detached, line_no: u32, prev: Option<(f64, u32)>) -> bool {
    let first = d.rows.samples.iter().map(|s| s.t_s).find(|t| t.is_finite());
    let in_order = match (first, prev) {
        (Some(t), Some((p, _))) => t > p,
        _ => true,
    };
    in_order && line_no.checked_add(d.lines).is_some()
}
