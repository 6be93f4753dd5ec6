//! The CSV recording interchange format (`docs/recording-format.md`): reading and writing.
//!
//! ```text
//! # latitude_deg: 39.1
//! # gravity_mps2: 9.800898
//! # description: anything
//! t_s,ax_mps2,ay_mps2,az_mps2[,temp_c]
//! 0.0,0.0001,-0.0002,9.800898
//! ```
//!
//! Reading never panics: every defect is a [`RecordingError`] naming the file, the 1-based line
//! and, where it applies, the column. Accepted: CRLF line endings, a UTF-8 byte-order mark,
//! blank lines, `#` comment lines, unknown columns (ignored), columns in any order, fields in
//! double quotes, a last line without newline if it is complete. Rejected: missing required
//! columns, wrong field counts, a cut-off last line, values that are not numbers, NaN/Inf,
//! |a| > 1000 m/s², time not strictly increasing, bad `latitude_deg`/`gravity_mps2`,
//! invalid UTF-8, a line longer than [`MAX_LINE_BYTES`], no samples. An error quotes at most
//! [`ERROR_EXCERPT_CHARS`] characters of the file's text.

mod blocks;
mod columns;
mod error;
mod reader;
mod writer;

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

pub use columns::read_columns;
pub use error::RecordingError;
pub use reader::{
    check_gravity_mps2, check_latitude_deg, excerpt, sample_problem, RecordingReader,
    ERROR_EXCERPT_CHARS, GRAVITY_RANGE_MPS2, LATITUDE_RANGE_DEG, MAX_ABS_SPECIFIC_FORCE_MPS2,
    MAX_LINE_BYTES, REQUIRED_COLUMNS, TEMP_COLUMN, TEMP_RANGE_C,
};
pub use writer::{write_recording, Appending, RecordingWriter};

/// Memory a sample takes once read, bytes: the sample (`RawSample`, 48) and its line (4).
/// [`read_recording`] needs this much a sample (1.3 times it while the vectors, reserved from
/// the file's length at 40 bytes a row, are not yet filled), plus a round of blocks (a MiB per
/// core).
pub const BYTES_PER_SAMPLE: usize = std::mem::size_of::<RawSample>() + std::mem::size_of::<u32>();

/// The `# key: value` lines before the header.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Metadata {
    /// `latitude_deg`, in [-90, 90].
    pub latitude_deg: Option<f64>,
    /// `gravity_mps2`; `None`: normal gravity at the latitude.
    pub gravity_mps2: Option<f64>,
    /// `description`.
    pub description: Option<String>,
    /// Other keys, in file order.
    pub extra: Vec<(String, String)>,
}

/// One accelerometer sample.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RawSample {
    /// Seconds since the gyros reached stable operation (θ = 0).
    pub t_s: f64,
    /// Specific force along the platform axes x_p, y_p, z_p, m/s².
    pub specific_force_mps2: [f64; 3],
    /// Platform temperature, °C, if recorded.
    pub temp_c: Option<f64>,
}

impl From<&RawSample> for estimator_core::Sample {
    /// The one conversion from a recorded sample to the core's (temperature NaN when absent).
    fn from(s: &RawSample) -> Self {
        estimator_core::Sample {
            t_s: s.t_s,
            specific_force: s.specific_force_mps2,
            temp_c: s.temp_c.unwrap_or(f64::NAN),
        }
    }
}

/// A whole recording in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// Where it was read from.
    pub path: PathBuf,
    /// Its metadata.
    pub meta: Metadata,
    /// Its samples, time strictly increasing; never empty.
    pub samples: Vec<RawSample>,
    /// 1-based file line of each sample (for error messages further on).
    pub lines: Vec<u32>,
    /// Whether the file has a `temp_c` column.
    pub has_temp: bool,
    /// Repairs made while reading, each a message naming file and line (the only one: a
    /// truncated last line — a recorder killed mid-write — is dropped, not the whole recording).
    pub repairs: Vec<String>,
}

/// Reads a whole recording. Fails if it holds no samples. A file of more than two blocks is
/// read on all cores ([`blocks`]), with the same samples, lines, errors and repairs. A regular
/// file is read up to the length it had when opened (rows appended meanwhile are not read); one
/// that is shorter once read — truncated or rewritten by another program meanwhile — is
/// [`RecordingError::Shrank`], whatever its rows said. Memory: [`BYTES_PER_SAMPLE`] a sample;
/// memory refused is [`RecordingError::OutOfMemory`].
pub fn read_recording(path: &Path) -> Result<Recording, RecordingError> {
    let name = path.display().to_string();
    let f = File::open(path).map_err(|source| RecordingError::Open {
        file: name.clone(),
        source,
    })?;
    let regular = f.metadata().ok().filter(|m| m.is_file());
    let bytes = regular.as_ref().map_or(0, |m| m.len());
    // A second handle on the same open file, to see its length once read.
    let watch = regular.and_then(|_| f.try_clone().ok());
    let limit = if watch.is_some() { bytes } else { u64::MAX };
    // Room for every row up front (rows of a plain recording are 40–70 bytes): growing the
    // vectors by doubling moved and page-faulted them again, 10 % of reading a 60-h recording.
    let rows_hint = (bytes / 40).min(1 << 26) as usize;
    let read = || {
        let input = BufReader::with_capacity(1 << 16, f.take(limit));
        let reader = RecordingReader::new(input, name.clone())?;
        #[cfg(test)]
        tests::AFTER_HEADER.with(|hook| {
            if let Some(h) = hook.borrow().as_ref() {
                h(path);
            }
        });
        let (threads, block_bytes) = (blocks::read_threads(), blocks::BLOCK_BYTES);
        let parallel = threads > 1 && bytes > 2 * block_bytes as u64;
        collect(reader, path, rows_hint, |mut reader, rows| {
            if parallel {
                blocks::read_rows_parallel(reader, rows, threads, block_bytes)
            } else {
                blocks::read_rows(&mut reader, rows)
            }
        })
    };
    let result = read();
    match watch.and_then(|w| w.metadata().ok()).map(|m| m.len()) {
        Some(now) if now < bytes => Err(RecordingError::Shrank {
            file: name,
            opened_bytes: bytes,
            now_bytes: now,
        }),
        _ => result,
    }
}

/// Reads a whole recording from any buffered reader; `display_name` is used in errors.
pub fn read_recording_from<R: std::io::BufRead>(
    reader: R,
    display_name: &str,
) -> Result<Recording, RecordingError> {
    let reader = RecordingReader::new(reader, display_name)?;
    collect(reader, Path::new(display_name), 0, |mut reader, rows| {
        blocks::read_rows(&mut reader, rows)
    })
}

/// Reads the rows after the header with `read` (on one thread or in blocks).
fn collect<R: std::io::BufRead>(
    reader: RecordingReader<R>,
    path: &Path,
    rows_hint: usize,
    read: impl FnOnce(RecordingReader<R>, &mut blocks::Rows) -> Result<(), RecordingError>,
) -> Result<Recording, RecordingError> {
    let meta = reader.metadata().clone();
    let has_temp = reader.has_temp();
    let file = reader.display_name().to_string();
    let mut rows = blocks::Rows::default();
    // A hint the allocator refuses is dropped: the rows then grow as they come, and it is their
    // growth that fails, if anything does, naming the line it reached.
    if rows.try_reserve(rows_hint).is_err() {
        rows = blocks::Rows::default();
    }
    read(reader, &mut rows)?;
    if rows.samples.is_empty() {
        return Err(RecordingError::NoSamples {
            file,
            reason: "header only",
        });
    }
    Ok(Recording {
        path: path.to_path_buf(),
        meta,
        samples: rows.samples,
        lines: rows.lines,
        has_temp,
        repairs: rows.repairs,
    })
}

#[cfg(test)]
mod tests;
