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
//! Memory stays bounded: one round of blocks at a time. A file is mapped in memory when the
//! system allows ([`read_file_parallel`]): its blocks are then slices of the map, not copies.

use std::borrow::Cow;
use std::fs::File;
use std::io::{BufRead, BufReader, Cursor, Read, Seek};

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

/// Reads the rest of `reader` into `rows`, as the one-thread reader does: the error that ends it,
/// except a truncated last line after samples, which is dropped and reported as a repair.
pub(super) fn read_rows<R: BufRead>(
    reader: &mut RecordingReader<R>,
    rows: &mut Rows,
) -> Result<(), RecordingError> {
    for item in reader {
        match item {
            Ok((line, s)) => {
                rows.lines.push(line);
                rows.samples.push(s);
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
    let rows_hint = block.len() / 40 + 1;
    let mut rows = Rows {
        samples: Vec::with_capacity(rows_hint),
        lines: Vec::with_capacity(rows_hint),
        repairs: Vec::new(),
    };
    let mut failed = false;
    for item in &mut reader {
        match item {
            Ok((line, s)) => {
                rows.lines.push(line);
                rows.samples.push(s);
            }
            Err(_) => failed = true,
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
enum Next<'m> {
    /// Whole lines (the last one without its line end only at the end of the file).
    Block(Cow<'m, [u8]>),
    /// The end of the file.
    End,
    /// More than a block without a line end: left to the one-thread reader, which stops such
    /// a line at [`super::MAX_LINE_BYTES`]. For a mapped file, the rest of it.
    NoLineEnd(Cow<'m, [u8]>),
}

/// Where the blocks come from: a stream read block by block, or a file mapped in memory.
enum Source<'m, R> {
    /// `carry`: the part line the last block left.
    Stream { inner: R, carry: Vec<u8> },
    /// `pos`: where the next block starts.
    Mapped { bytes: &'m [u8], pos: usize },
}

impl<'m, R: Read> Source<'m, R> {
    /// The next block: at least `block_bytes` more (after a stream's carry), cut after the last
    /// line end within.
    fn next_block(&mut self, block_bytes: usize) -> std::io::Result<Next<'m>> {
        match self {
            Source::Stream { inner, carry } => next_block(inner, carry, block_bytes),
            Source::Mapped { bytes, pos } => {
                let rest = &bytes[*pos..];
                if rest.is_empty() {
                    return Ok(Next::End);
                }
                if rest.len() <= block_bytes {
                    *pos = bytes.len();
                    return Ok(Next::Block(Cow::Borrowed(rest)));
                }
                match memchr::memrchr(b'\n', &rest[..block_bytes]) {
                    Some(i) => {
                        *pos += i + 1;
                        Ok(Next::Block(Cow::Borrowed(&rest[..=i])))
                    }
                    None => Ok(Next::NoLineEnd(Cow::Borrowed(rest))),
                }
            }
        }
    }
}

/// Reads the next block from `inner`: `carry` (the part line left by the last block) and then
/// at least `block_bytes` more, cut after the last line end.
fn next_block<'m>(
    inner: &mut impl Read,
    carry: &mut Vec<u8>,
    block_bytes: usize,
) -> std::io::Result<Next<'m>> {
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
            Next::Block(Cow::Owned(buf))
        });
    }
    match memchr::memrchr(b'\n', &buf) {
        Some(i) => {
            carry.extend_from_slice(&buf[i + 1..]);
            buf.truncate(i + 1);
            Ok(Next::Block(Cow::Owned(buf)))
        }
        None => Ok(Next::NoLineEnd(Cow::Owned(buf))),
    }
}

/// Reads the rows after the header (`head` stands there) into `rows` with `threads` threads,
/// in blocks of `block_bytes`; the results are the one-thread reader's ([`read_rows`]). (A
/// file's stream is read so by [`read_file_parallel`] when it cannot be mapped.)
#[cfg(test)]
pub(super) fn read_rows_parallel<R: BufRead>(
    head: RecordingReader<R>,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (proto, at, inner) = split_head(head);
    let carry = Vec::new();
    read_blocks(
        &proto,
        Source::Stream { inner, carry },
        at,
        rows,
        threads,
        block_bytes,
    )
}

/// [`read_rows_parallel`] over a file: its rows mapped in memory when the system allows, so
/// that no block is copied into a buffer first (on one thread, between the rounds: ~2 ms of a
/// 60-h recording's 13). Otherwise, and for anything but a regular file, read as a stream.
pub(super) fn read_file_parallel(
    head: RecordingReader<BufReader<File>>,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (proto, at, mut inner) = split_head(head);
    let mapped = inner.stream_position().ok().and_then(|offset| {
        let file = inner.get_ref();
        let regular = file.metadata().is_ok_and(|m| m.is_file());
        // SAFETY: the map is only read, and only while this function runs (~10 ms for 60 h).
        // A file shortened by another process in that time would fault on the lost pages
        // (SIGBUS), as for any program that maps its input (ripgrep, for one): `driftid`'s
        // outputs replace files by renaming, and its recorder appends (restarted on a file, it
        // first cuts a partial last line). A file that grows keeps the mapped length: the rows
        // written after the map are not read, as a stream stops at the end it found.
        let map = regular
            .then(|| unsafe { memmap2::Mmap::map(file) })
            .and_then(Result::ok)?;
        let offset = usize::try_from(offset).ok().filter(|&o| o <= map.len())?;
        Some((map, offset))
    });
    match &mapped {
        Some((map, offset)) => {
            let source: Source<'_, BufReader<File>> = Source::Mapped {
                bytes: &map[..],
                pos: *offset,
            };
            read_blocks(&proto, source, at, rows, threads, block_bytes)
        }
        None => {
            let source = Source::Stream {
                inner,
                carry: Vec::new(),
            };
            read_blocks(&proto, source, at, rows, threads, block_bytes)
        }
    }
}

/// [`read_rows_parallel`] over bytes in memory, as [`read_file_parallel`] reads a mapped file.
#[cfg(test)]
pub(super) fn read_slice_parallel(
    head: RecordingReader<&[u8]>,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (proto, at, bytes) = split_head(head);
    let source: Source<'_, &[u8]> = Source::Mapped { bytes, pos: 0 };
    read_blocks(&proto, source, at, rows, threads, block_bytes)
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
    mut source: Source<'_, R>,
    at: Position,
    rows: &mut Rows,
    threads: usize,
    block_bytes: usize,
) -> Result<(), RecordingError> {
    let (mut line_no, mut prev) = at;
    loop {
        let mut blocks = Vec::with_capacity(threads);
        let mut stop = None;
        while blocks.len() < threads.max(1) && stop.is_none() {
            match source.next_block(block_bytes) {
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
                return match source {
                    Source::Stream { inner, .. } => {
                        let chained = Cursor::new(b).chain(inner);
                        read_rows(&mut proto.resume_over(chained, line_no, prev), rows)
                    }
                    Source::Mapped { .. } => {
                        read_rows(&mut proto.resume_over(&b[..], line_no, prev), rows)
                    }
                };
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
    rest: &[Cow<'_, [u8]>],
    rows: &mut Rows,
    line_no: &mut u32,
    prev: &mut Option<(f64, u32)>,
) -> Result<(), RecordingError> {
    // The other blocks go to rayon's pool while this thread reads the first (why the pool, not
    // a thread per round: `crate::beside`). A block whose job panicked is read again here.
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
