//! Errors of reading a recording: every one names the file, and where it applies the 1-based
//! line and the column, and says what is wrong.

use std::io;

/// What went wrong while reading a recording (see the module docs for the format).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordingError {
    /// The file could not be opened.
    #[error("{file}: cannot open: {source}")]
    Open {
        file: String,
        #[source]
        source: io::Error,
    },
    /// An I/O error while reading line `line`.
    #[error("{file}:{line}: read error: {source}")]
    Read {
        file: String,
        line: u32,
        #[source]
        source: io::Error,
    },
    /// Line `line` is longer than the reader accepts ([`super::MAX_LINE_BYTES`]); reading stopped
    /// there (a file without line breaks is not read whole).
    #[error("{file}:{line}: line longer than {limit} bytes (the longest line a recording may have); not a recording, or a line break is missing")]
    LineTooLong {
        file: String,
        line: u32,
        limit: usize,
    },
    /// Line `line` is not valid UTF-8.
    #[error("{file}:{line}: not valid UTF-8 (byte 0x{byte:02x} at byte {offset} of the line); the file must be UTF-8 text")]
    InvalidUtf8 {
        file: String,
        line: u32,
        byte: u8,
        offset: usize,
    },
    /// A metadata line (`# key: value`) has a bad value.
    #[error("{file}:{line}: metadata {key}: {reason}")]
    Metadata {
        file: String,
        line: u32,
        key: String,
        reason: String,
    },
    /// The header row lacks a required column.
    #[error("{file}:{line}: missing required column {column} (header has: {header})")]
    MissingColumn {
        file: String,
        line: u32,
        column: &'static str,
        header: String,
    },
    /// The header row names a column twice.
    #[error(
        "{file}:{line}: column {column} appears twice in the header (fields {first} and {second})"
    )]
    DuplicateColumn {
        file: String,
        line: u32,
        column: String,
        first: usize,
        second: usize,
    },
    /// A data row has the wrong number of fields.
    #[error("{file}:{line}: expected {expected} fields (as in the header on line {header_line}), found {found}")]
    FieldCount {
        file: String,
        line: u32,
        expected: usize,
        found: usize,
        header_line: u32,
    },
    /// The last line has too few fields and no final newline: the file was cut off.
    #[error("{file}:{line}: truncated last line: {found} of {expected} fields and no final newline (the file appears to be cut off)")]
    Truncated {
        file: String,
        line: u32,
        expected: usize,
        found: usize,
    },
    /// A required value is empty.
    #[error("{file}:{line}: column {column}: empty value")]
    EmptyValue {
        file: String,
        line: u32,
        column: String,
    },
    /// A value does not parse as a number.
    #[error("{file}:{line}: column {column}: {text:?} is not a number")]
    NotANumber {
        file: String,
        line: u32,
        column: String,
        text: String,
    },
    /// A value is NaN or infinite.
    #[error(
        "{file}:{line}: column {column}: {text} is not finite (NaN and infinity are not allowed)"
    )]
    NotFinite {
        file: String,
        line: u32,
        column: String,
        text: String,
    },
    /// A value is outside its plausible range.
    #[error("{file}:{line}: column {column}: {value:?} {reason}")]
    OutOfRange {
        file: String,
        line: u32,
        column: String,
        value: f64,
        reason: &'static str,
    },
    /// Time does not strictly increase.
    #[error("{file}:{line}: t_s = {t:?} is not after the previous sample's {prev:?} (line {prev_line}); time must strictly increase")]
    TimeNotIncreasing {
        file: String,
        line: u32,
        t: f64,
        prev: f64,
        prev_line: u32,
    },
    /// The file holds no samples.
    #[error("{file}: no samples ({reason})")]
    NoSamples { file: String, reason: &'static str },
    /// The memory for more samples could not be had at line `line` (`samples` held so far).
    #[error("{file}:{line}: out of memory: {samples} samples read, at {per} bytes each ({mib:.0} MiB), and no room for more; give the process more memory (--max-memory-mib, ulimit -v, a larger machine) or split the recording into shorter runs", per = super::BYTES_PER_SAMPLE, mib = (*samples as f64) * super::BYTES_PER_SAMPLE as f64 / 1048576.0)]
    OutOfMemory {
        file: String,
        line: u32,
        samples: usize,
    },
    /// The file was shorter once read than when it was opened: another program truncated or
    /// rewrote it meanwhile, and what was read of it is not the recording.
    #[error("{file}: the file shrank while it was read ({opened_bytes} bytes when opened, {now_bytes} after): another program truncated or rewrote it; read it again once it is complete")]
    Shrank {
        file: String,
        opened_bytes: u64,
        now_bytes: u64,
    },
}

impl RecordingError {
    /// The file name the error refers to.
    pub fn file(&self) -> &str {
        use RecordingError::*;
        match self {
            Open { file, .. }
            | Read { file, .. }
            | LineTooLong { file, .. }
            | InvalidUtf8 { file, .. }
            | Metadata { file, .. }
            | MissingColumn { file, .. }
            | DuplicateColumn { file, .. }
            | FieldCount { file, .. }
            | Truncated { file, .. }
            | EmptyValue { file, .. }
            | NotANumber { file, .. }
            | NotFinite { file, .. }
            | OutOfRange { file, .. }
            | TimeNotIncreasing { file, .. }
            | NoSamples { file, .. }
            | OutOfMemory { file, .. }
            | Shrank { file, .. } => file,
        }
    }

    /// The 1-based line the error refers to, if any.
    pub fn line(&self) -> Option<u32> {
        use RecordingError::*;
        match self {
            Open { .. } | NoSamples { .. } | Shrank { .. } => None,
            Read { line, .. }
            | LineTooLong { line, .. }
            | InvalidUtf8 { line, .. }
            | Metadata { line, .. }
            | MissingColumn { line, .. }
            | DuplicateColumn { line, .. }
            | FieldCount { line, .. }
            | Truncated { line, .. }
            | EmptyValue { line, .. }
            | NotANumber { line, .. }
            | NotFinite { line, .. }
            | OutOfRange { line, .. }
            | TimeNotIncreasing { line, .. }
            | OutOfMemory { line, .. } => Some(*line),
        }
    }
}
