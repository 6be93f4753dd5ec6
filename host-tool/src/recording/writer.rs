//! Writing the CSV recording format, streaming or in one go.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use super::reader::{
    check_gravity_mps2, check_latitude_deg, sample_problem, MAX_LINE_BYTES, REQUIRED_COLUMNS,
    TEMP_COLUMN,
};
use super::{Metadata, RawSample};

/// Metadata values are single-line: line breaks become spaces.
fn one_line(s: &str) -> String {
    s.replace(['\r', '\n'], " ")
}

/// Writes a recording row by row (for the recorder and the simulator). Numbers are written in
/// Rust's shortest round-trip representation, so reading gives back the same `f64`s.
pub struct RecordingWriter<W: Write> {
    w: W,
    has_temp: bool,
    prev_t: Option<f64>,
    rows: u64,
}

impl RecordingWriter<BufWriter<File>> {
    /// Creates (truncates) `path` and writes the metadata and the header.
    /// Metadata [`RecordingWriter::new`] refuses is refused before the file is touched.
    pub fn create(path: &Path, meta: &Metadata, has_temp: bool) -> io::Result<Self> {
        RecordingWriter::new(io::sink(), meta, has_temp)?;
        let f = File::create(path)?;
        RecordingWriter::new(BufWriter::with_capacity(1 << 16, f), meta, has_temp)
    }
}

/// An existing recording opened for appending (see [`RecordingWriter::append`]).
pub struct Appending {
    /// The writer, positioned at the end of the file.
    pub writer: RecordingWriter<BufWriter<File>>,
    /// The file's metadata.
    pub meta: Metadata,
    /// Samples already in the file.
    pub samples: u64,
    /// Time of the last sample in the file, s (`None`: header only).
    pub last_t_s: Option<f64>,
    /// What was repaired (a partial last line cut off), naming the file and line.
    pub repair: Option<String>,
}

impl RecordingWriter<BufWriter<File>> {
    /// Opens an existing recording to append to it (a recorder restarted on the same file): the
    /// file is read and checked first; a partial last line (a recorder killed mid-write) is cut
    /// off the file and reported; new rows then go after the last complete one, and must come
    /// after its time. A file that breaks the format is an error naming file and line: nothing
    /// is appended to it.
    pub fn append(path: &Path) -> Result<Appending, super::RecordingError> {
        use super::RecordingError;
        let name = path.display().to_string();
        let open_err = |source| RecordingError::Open {
            file: name.clone(),
            source,
        };
        let bytes = std::fs::read(path).map_err(open_err)?;
        let complete = match bytes.iter().rposition(|&b| b == b'\n') {
            Some(i) => i + 1,
            None => 0,
        };
        // Read and checked first: a file that is not a recording is not touched at all (its
        // last line is not cut off either).
        let mut reader =
            super::RecordingReader::new(io::Cursor::new(&bytes[..complete]), name.clone())?;
        let meta = reader.metadata().clone();
        let has_temp = reader.has_temp();
        let mut samples = 0u64;
        let mut last_t_s = None;
        for item in &mut reader {
            let (_, s) = item?;
            samples += 1;
            last_t_s = Some(s.t_s);
        }
        let mut repair = None;
        if complete < bytes.len() {
            let line = bytes[..complete].iter().filter(|&&b| b == b'\n').count() + 1;
            repair = Some(format!(
                "{name}:{line}: partial last line ({} bytes, no newline: the recorder was stopped mid-write) cut off before appending",
                bytes.len() - complete
            ));
            let f = std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map_err(open_err)?;
            f.set_len(complete as u64).map_err(open_err)?;
            f.sync_all().map_err(open_err)?;
        }
        let f = std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .map_err(open_err)?;
        let writer = RecordingWriter {
            w: BufWriter::with_capacity(1 << 16, f),
            has_temp,
            prev_t: last_t_s,
            rows: 0,
        };
        Ok(Appending {
            writer,
            meta,
            samples,
            last_t_s,
            repair,
        })
    }
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

impl<W: Write> RecordingWriter<W> {
    /// Writes the metadata lines and the header row to `w`. With `has_temp` the rows carry a
    /// `temp_c` column (empty where a sample has no temperature).
    ///
    /// Metadata the reader would refuse is refused here (`InvalidInput`, nothing written): a
    /// latitude or gravity outside the reader's ranges ([`check_latitude_deg`],
    /// [`check_gravity_mps2`]), a line longer than [`MAX_LINE_BYTES`]; extra keys that would
    /// repeat `latitude_deg`, `gravity_mps2` or `description` are left out.
    pub fn new(mut w: W, meta: &Metadata, has_temp: bool) -> io::Result<Self> {
        let mut lines = Vec::new();
        if let Some(l) = meta.latitude_deg {
            check_latitude_deg(l).map_err(|e| invalid(format!("metadata latitude_deg: {e}")))?;
            lines.push(format!("# latitude_deg: {l:?}"));
        }
        if let Some(g) = meta.gravity_mps2 {
            check_gravity_mps2(g).map_err(|e| invalid(format!("metadata gravity_mps2: {e}")))?;
            lines.push(format!("# gravity_mps2: {g:?}"));
        }
        if let Some(d) = &meta.description {
            lines.push(format!("# description: {}", one_line(d)));
        }
        for (k, v) in &meta.extra {
            let k: String = one_line(k)
                .replace(':', "_")
                .split_whitespace()
                .collect::<Vec<_>>()
                .join("_");
            if k.is_empty() || ["latitude_deg", "gravity_mps2", "description"].contains(&k.as_str())
            {
                continue;
            }
            lines.push(format!("# {k}: {}", one_line(v)));
        }
        if let Some(l) = lines.iter().find(|l| l.len() > MAX_LINE_BYTES) {
            return Err(invalid(format!(
                "metadata line of {} bytes is longer than the {MAX_LINE_BYTES} a recording line may have",
                l.len()
            )));
        }
        for l in &lines {
            writeln!(w, "{l}")?;
        }
        write!(w, "{}", REQUIRED_COLUMNS.join(","))?;
        if has_temp {
            write!(w, ",{TEMP_COLUMN}")?;
        }
        writeln!(w)?;
        Ok(RecordingWriter {
            w,
            has_temp,
            prev_t: None,
            rows: 0,
        })
    }

    /// Appends one row. Refuses (`InvalidInput`) what the reader would reject: non-finite
    /// values, |a| or a temperature out of the reader's range ([`sample_problem`]), times that
    /// do not strictly increase.
    pub fn write_sample(&mut self, s: &RawSample) -> io::Result<()> {
        let a = s.specific_force_mps2;
        if let Some(p) = sample_problem(s) {
            return Err(invalid(format!("sample at t_s = {:?}: {p}", s.t_s)));
        }
        if let Some(p) = self.prev_t {
            if s.t_s <= p {
                return Err(invalid(format!(
                    "t_s = {:?} is not after the previous sample's {p:?}",
                    s.t_s
                )));
            }
        }
        write!(self.w, "{:?},{:?},{:?},{:?}", s.t_s, a[0], a[1], a[2])?;
        if self.has_temp {
            match s.temp_c {
                Some(t) if t.is_finite() => write!(self.w, ",{t:?}")?,
                Some(_) => {
                    return Err(invalid(format!(
                        "non-finite temperature at t_s = {:?}",
                        s.t_s
                    )))
                }
                None => write!(self.w, ",")?,
            }
        }
        writeln!(self.w)?;
        self.prev_t = Some(s.t_s);
        self.rows += 1;
        Ok(())
    }

    /// Flushes buffered rows to the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.w.flush()
    }

    /// Whether the rows carry a `temp_c` column.
    pub fn has_temp(&self) -> bool {
        self.has_temp
    }

    /// Number of rows written so far.
    pub fn rows_written(&self) -> u64 {
        self.rows
    }

    /// Flushes and returns the underlying writer.
    pub fn into_inner(mut self) -> io::Result<W> {
        self.w.flush()?;
        Ok(self.w)
    }
}

/// Writes a whole recording to `path`, atomically (a temporary file renamed into place, see
/// [`crate::output`]): on an error the previous file, if any, is left as it was. A `temp_c`
/// column is written if any sample has a temperature.
pub fn write_recording(path: &Path, meta: &Metadata, samples: &[RawSample]) -> io::Result<()> {
    let has_temp = samples.iter().any(|s| s.temp_c.is_some());
    let file = crate::output::AtomicFile::create(path).map_err(io::Error::other)?;
    let mut w = RecordingWriter::new(file, meta, has_temp)?;
    for s in samples {
        w.write_sample(s)?;
    }
    w.into_inner()?.commit().map_err(io::Error::other)
}
