//! Streaming reader of the CSV recording format.

use std::io::BufRead;

use super::{Metadata, RawSample, RecordingError};

/// Largest plausible magnitude of a specific-force component, m/s².
pub const MAX_ABS_SPECIFIC_FORCE_MPS2: f64 = 1000.0;
/// Plausible platform temperatures, °C.
pub const TEMP_RANGE_C: (f64, f64) = (-273.15, 1000.0);
/// Plausible local gravity at the Earth's surface, m/s².
pub const GRAVITY_RANGE_MPS2: (f64, f64) = (9.0, 10.5);

/// Plausible latitudes, degrees.
pub const LATITUDE_RANGE_DEG: (f64, f64) = (-90.0, 90.0);

/// Longest line accepted, in bytes (without its line ending): 64 KiB. A data row is under 200
/// bytes and a header or `# description:` line a few hundred; the cap bounds the memory a file
/// without line breaks (binary data, a wrong file) can take, and such a file stops at once with
/// [`RecordingError::LineTooLong`] instead of being read whole.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Most characters of a file's text echoed into an error message ([`excerpt`]).
pub const ERROR_EXCERPT_CHARS: usize = 80;

/// `text` for an error message: whole if short, else its first [`ERROR_EXCERPT_CHARS`]
/// characters and how long it was.
pub fn excerpt(text: &str) -> String {
    match text.char_indices().nth(ERROR_EXCERPT_CHARS) {
        None => text.to_string(),
        Some((end, _)) => format!("{}… ({} bytes in all)", &text[..end], text.len()),
    }
}

/// The reader's rule for `latitude_deg` (metadata and `--latitude-deg`): finite, in
/// [`LATITUDE_RANGE_DEG`]. The error says why.
pub fn check_latitude_deg(v: f64) -> Result<f64, String> {
    let (lo, hi) = LATITUDE_RANGE_DEG;
    if !v.is_finite() {
        Err(format!("{v} is not finite"))
    } else if !(lo..=hi).contains(&v) {
        Err(format!("{v:?} is outside [{lo}, {hi}] degrees"))
    } else {
        Ok(v)
    }
}

/// The reader's rule for `gravity_mps2`: finite, in [`GRAVITY_RANGE_MPS2`].
pub fn check_gravity_mps2(v: f64) -> Result<f64, String> {
    let (lo, hi) = GRAVITY_RANGE_MPS2;
    if !v.is_finite() {
        Err(format!("{v} is not finite"))
    } else if !(lo..=hi).contains(&v) {
        Err(format!(
            "{v:?} is not a plausible gravity at the Earth's surface (expected {lo}..{hi} m/s^2)"
        ))
    } else {
        Ok(v)
    }
}

/// Why the reader would refuse this sample's values, if it would (non-finite time or specific
/// force, |a| > [`MAX_ABS_SPECIFIC_FORCE_MPS2`], a temperature outside [`TEMP_RANGE_C`]); the
/// order of samples is checked separately.
pub fn sample_problem(s: &RawSample) -> Option<String> {
    if !s.t_s.is_finite() {
        return Some(format!("t_s = {} is not finite", s.t_s));
    }
    for (v, c) in s.specific_force_mps2.iter().zip(&REQUIRED_COLUMNS[1..]) {
        if !v.is_finite() {
            return Some(format!("{c} = {v} is not finite"));
        }
        if v.abs() > MAX_ABS_SPECIFIC_FORCE_MPS2 {
            return Some(format!(
                "{c} = {v:?} m/s^2 is implausibly large (|a| > {MAX_ABS_SPECIFIC_FORCE_MPS2} m/s^2)"
            ));
        }
    }
    if let Some(t) = s.temp_c {
        if !(TEMP_RANGE_C.0..=TEMP_RANGE_C.1).contains(&t) {
            return Some(format!(
                "{TEMP_COLUMN} = {t} is not in the plausible range [{}, {}] deg C",
                TEMP_RANGE_C.0, TEMP_RANGE_C.1
            ));
        }
    }
    None
}

/// The header's required columns, in the order of [`RawSample::specific_force_mps2`] after `t_s`.
pub const REQUIRED_COLUMNS: [&str; 4] = ["t_s", "ax_mps2", "ay_mps2", "az_mps2"];
/// The optional temperature column.
pub const TEMP_COLUMN: &str = "temp_c";

/// Reads a recording as a stream: [`RecordingReader::new`] parses the metadata and the header,
/// then the reader yields `(line, sample)` for each data row, `line` being the 1-based file line.
///
/// After the first error the iterator ends. An error-free iteration that yields nothing means the
/// file has a header but no samples; [`super::read_recording`] turns that into an error.
pub struct RecordingReader<R: BufRead> {
    reader: R,
    file: String,
    meta: Metadata,
    header: Vec<String>,
    header_line: u32,
    /// Field index of t_s, ax, ay, az.
    idx: [usize; 4],
    temp_idx: Option<usize>,
    line_no: u32,
    buf: Vec<u8>,
    prev: Option<(f64, u32)>,
    done: bool,
}

/// Reads the next line into `buf` without its line ending. `Ok(None)` at end of file, otherwise
/// `Ok(Some(had_newline))`. A line longer than [`MAX_LINE_BYTES`] is an error: at most that
/// much (plus one buffer) is read of it.
fn read_line<R: BufRead>(
    reader: &mut R,
    buf: &mut Vec<u8>,
    line_no: &mut u32,
    file: &str,
) -> Result<Option<bool>, RecordingError> {
    buf.clear();
    let this_line = line_no.saturating_add(1);
    let mut had_newline = false;
    loop {
        let chunk = match reader.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(source) => {
                return Err(RecordingError::Read {
                    file: file.to_string(),
                    line: this_line,
                    source,
                })
            }
        };
        if chunk.is_empty() {
            break;
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        buf.extend_from_slice(&chunk[..take]);
        reader.consume(take);
        // The line without its ending (\n or \r\n) must fit.
        let content = buf.len()
            - usize::from(done)
            - usize::from(done && buf.len() >= 2 && buf[buf.len() - 2] == b'\r');
        if content > MAX_LINE_BYTES {
            return Err(RecordingError::LineTooLong {
                file: file.to_string(),
                line: this_line,
                limit: MAX_LINE_BYTES,
            });
        }
        if done {
            had_newline = true;
            break;
        }
    }
    if buf.is_empty() {
        return Ok(None);
    }
    *line_no = this_line;
    if had_newline {
        buf.pop();
        if buf.last() == Some(&b'\r') {
            buf.pop();
        }
    }
    Ok(Some(had_newline))
}

fn as_utf8<'a>(buf: &'a [u8], line: u32, file: &str) -> Result<&'a str, RecordingError> {
    std::str::from_utf8(buf).map_err(|e| {
        let offset = e.valid_up_to();
        RecordingError::InvalidUtf8 {
            file: file.to_string(),
            line,
            byte: buf[offset],
            offset,
        }
    })
}

/// A field without surrounding white space and without one pair of surrounding double quotes.
pub(crate) fn clean_field(f: &str) -> &str {
    let f = f.trim();
    if f.len() >= 2 && f.starts_with('"') && f.ends_with('"') {
        f[1..f.len() - 1].trim()
    } else {
        f
    }
}

pub(crate) fn parse_number(
    text: &str,
    file: &str,
    line: u32,
    column: &str,
) -> Result<f64, RecordingError> {
    if text.is_empty() {
        return Err(RecordingError::EmptyValue {
            file: file.to_string(),
            line,
            column: column.to_string(),
        });
    }
    let v: f64 = text.parse().map_err(|_| RecordingError::NotANumber {
        file: file.to_string(),
        line,
        column: column.to_string(),
        text: excerpt(text),
    })?;
    if !v.is_finite() {
        return Err(RecordingError::NotFinite {
            file: file.to_string(),
            line,
            column: column.to_string(),
            text: excerpt(text),
        });
    }
    Ok(v)
}

/// Parses one metadata value as a number; `reason` strings for the error.
fn parse_meta_number(value: &str) -> Result<f64, String> {
    match value.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("{} is not finite", excerpt(value))),
        Err(_) => Err(format!("{:?} is not a number", excerpt(value))),
    }
}

struct MetaParser {
    lat_line: Option<u32>,
    g_line: Option<u32>,
    desc_line: Option<u32>,
}

impl MetaParser {
    /// Handles a line starting with '#'. Lines that are not `# key: value` (key without white
    /// space) are plain comments.
    fn line(
        &mut self,
        meta: &mut Metadata,
        text: &str,
        line: u32,
        file: &str,
    ) -> Result<(), RecordingError> {
        let body = text.trim_start_matches('#').trim();
        let Some((key, value)) = body.split_once(':') else {
            return Ok(());
        };
        let key = key.trim();
        let value = value.trim();
        if key.is_empty() || key.contains(char::is_whitespace) {
            return Ok(());
        }
        let err = |reason: String| RecordingError::Metadata {
            file: file.to_string(),
            line,
            key: excerpt(key),
            reason,
        };
        let twice = |first: u32| err(format!("given twice (first on line {first})"));
        match key {
            "latitude_deg" => {
                if let Some(first) = self.lat_line {
                    return Err(twice(first));
                }
                let v = parse_meta_number(value)
                    .and_then(check_latitude_deg)
                    .map_err(err)?;
                self.lat_line = Some(line);
                meta.latitude_deg = Some(v);
            }
            "gravity_mps2" => {
                if let Some(first) = self.g_line {
                    return Err(twice(first));
                }
                let v = parse_meta_number(value)
                    .and_then(check_gravity_mps2)
                    .map_err(err)?;
                self.g_line = Some(line);
                meta.gravity_mps2 = Some(v);
            }
            "description" => {
                if let Some(first) = self.desc_line {
                    return Err(twice(first));
                }
                self.desc_line = Some(line);
                meta.description = Some(value.to_string());
            }
            _ => meta.extra.push((key.to_string(), value.to_string())),
        }
        Ok(())
    }
}

/// The metadata lines (`# key: value`) up to the header row, and the header row's text (trimmed,
/// a byte-order mark dropped); blank lines are skipped. `line_no` is left at the header's line.
fn read_metadata<R: BufRead>(
    reader: &mut R,
    buf: &mut Vec<u8>,
    line_no: &mut u32,
    file: &str,
) -> Result<(Metadata, String), RecordingError> {
    let mut meta = Metadata::default();
    let mut mp = MetaParser {
        lat_line: None,
        g_line: None,
        desc_line: None,
    };
    let mut saw_content = false;
    loop {
        if read_line(reader, buf, line_no, file)?.is_none() {
            let reason = if saw_content {
                "no header row, only comments"
            } else {
                "file is empty"
            };
            return Err(RecordingError::NoSamples {
                file: file.to_string(),
                reason,
            });
        }
        let mut text = as_utf8(buf, *line_no, file)?;
        if *line_no == 1 {
            text = text.strip_prefix('\u{feff}').unwrap_or(text);
        }
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        saw_content = true;
        if text.starts_with('#') {
            mp.line(&mut meta, text, *line_no, file)?;
            continue;
        }
        return Ok((meta, text.to_string()));
    }
}

/// The positions of [`REQUIRED_COLUMNS`] in the `header` (on line `header_line`); refused when
/// one is missing or a column read (required or [`TEMP_COLUMN`]) appears twice.
fn required_columns(
    header: &[String],
    header_line: u32,
    file: &str,
) -> Result<[usize; 4], RecordingError> {
    for (i, name) in header.iter().enumerate() {
        if !(REQUIRED_COLUMNS.contains(&name.as_str()) || name == TEMP_COLUMN) {
            continue;
        }
        if let Some(j) = header[i + 1..].iter().position(|n| n == name) {
            return Err(RecordingError::DuplicateColumn {
                file: file.to_string(),
                line: header_line,
                column: excerpt(name),
                first: i + 1,
                second: i + 2 + j,
            });
        }
    }
    let mut idx = [0usize; 4];
    for (k, col) in REQUIRED_COLUMNS.iter().enumerate() {
        match header.iter().position(|n| n == col) {
            Some(i) => idx[k] = i,
            None => {
                return Err(RecordingError::MissingColumn {
                    file: file.to_string(),
                    line: header_line,
                    column: col,
                    header: excerpt(&header.join(", ")),
                })
            }
        }
    }
    Ok(idx)
}

impl<R: BufRead> RecordingReader<R> {
    /// Parses the metadata lines and the header row. `display_name` is used in error messages
    /// (typically the path as the user gave it).
    pub fn new(mut reader: R, display_name: impl Into<String>) -> Result<Self, RecordingError> {
        let file: String = display_name.into();
        let mut buf = Vec::new();
        let mut line_no = 0u32;
        let (meta, header_text) = read_metadata(&mut reader, &mut buf, &mut line_no, &file)?;
        let header_line = line_no;
        let header: Vec<String> = header_text
            .split(',')
            .map(|f| clean_field(f).to_string())
            .collect();
        let idx = required_columns(&header, header_line, &file)?;
        let temp_idx = header.iter().position(|n| n == TEMP_COLUMN);
        Ok(RecordingReader {
            reader,
            file,
            meta,
            header,
            header_line,
            idx,
            temp_idx,
            line_no,
            buf,
            prev: None,
            done: false,
        })
    }

    /// The metadata found before the header.
    pub fn metadata(&self) -> &Metadata {
        &self.meta
    }

    /// Whether the header has a `temp_c` column.
    pub fn has_temp(&self) -> bool {
        self.temp_idx.is_some()
    }

    /// The header's column names.
    pub fn header(&self) -> &[String] {
        &self.header
    }

    /// The 1-based line of the header row.
    pub fn header_line(&self) -> u32 {
        self.header_line
    }

    /// The display name used in error messages.
    pub fn display_name(&self) -> &str {
        &self.file
    }

    /// Where the reader stands: the last line it read, and the last finite time with its line
    /// (the next row's time must exceed it).
    pub(crate) fn position(&self) -> (u32, Option<(f64, u32)>) {
        (self.line_no, self.prev)
    }

    /// This reader (file name, metadata, header) going on over `bytes`, standing at line
    /// `line_no` after the finite time `prev`: the rows of `bytes` are read exactly as this
    /// reader would read them there ([`super::read_recording`] reads blocks of a file so).
    pub(crate) fn resume_over<S: BufRead>(
        &self,
        bytes: S,
        line_no: u32,
        prev: Option<(f64, u32)>,
    ) -> RecordingReader<S> {
        RecordingReader {
            reader: bytes,
            file: self.file.clone(),
            meta: self.meta.clone(),
            header: self.header.clone(),
            header_line: self.header_line,
            idx: self.idx,
            temp_idx: self.temp_idx,
            line_no,
            buf: Vec::new(),
            prev,
            done: false,
        }
    }

    /// The underlying reader, standing after the last line read.
    pub(crate) fn into_inner(self) -> R {
        self.reader
    }

    /// The fast path for the common row: a whole line in the read buffer, ASCII, plain numbers
    /// (no quotes, blanks, NaN/∞), the right field count, plausible values, time increasing.
    /// It consumes the line and returns its sample; on anything else it consumes nothing and
    /// returns `None`, and [`Self::next_sample`]'s general path reads the same line again and
    /// accepts it or reports exactly what is wrong. Both paths give the same f64 (fast-float2
    /// and `str::parse` both round correctly; a test checks that they accept the same text).
    fn fast_sample(&mut self) -> Option<(u32, RawSample)> {
        let chunk = self.reader.fill_buf().ok()?;
        let end = memchr::memchr(b'\n', chunk)?;
        let mut line = &chunk[..end];
        if let [rest @ .., b'\r'] = line {
            line = rest;
        }
        if line.len() > MAX_LINE_BYTES || !line.is_ascii() {
            return None;
        }
        let fields = self.header.len();
        let mut vals = [0.0f64; 4];
        let mut temp = None;
        let mut pos = 0;
        for i in 0..fields {
            let rest = &line[pos..];
            let wanted = self.idx.iter().position(|&j| j == i);
            let len = if wanted.is_some() || Some(i) == self.temp_idx {
                if wanted.is_none() && rest.first().is_none_or(|&b| b == b',') {
                    0 // an empty temperature: none recorded
                } else {
                    // Only text that starts like a number: blanks, quotes, "inf"/"nan" go the
                    // general way.
                    if !matches!(rest.first(), Some(b'0'..=b'9' | b'-' | b'+' | b'.')) {
                        return None;
                    }
                    let (v, used) = fast_float2::parse_partial::<f64, _>(rest).ok()?;
                    if !v.is_finite() {
                        return None;
                    }
                    match wanted {
                        Some(0) => vals[0] = v,
                        Some(k) if v.abs() <= MAX_ABS_SPECIFIC_FORCE_MPS2 => vals[k] = v,
                        Some(_) => return None,
                        None if (TEMP_RANGE_C.0..=TEMP_RANGE_C.1).contains(&v) => temp = Some(v),
                        None => return None,
                    }
                    used
                }
            } else {
                memchr::memchr(b',', rest).unwrap_or(rest.len())
            };
            pos += len;
            // The field must end here: at a comma, or at the end of the line for the last one.
            if i + 1 < fields {
                if line.get(pos) != Some(&b',') {
                    return None;
                }
                pos += 1;
            } else if pos != line.len() {
                return None;
            }
        }
        let t = vals[0];
        if let Some((prev, _)) = self.prev {
            if t <= prev {
                return None; // both finite here
            }
        }
        let line_no = self.line_no.checked_add(1)?;
        self.reader.consume(end + 1);
        self.line_no = line_no;
        self.prev = Some((t, line_no));
        Some((
            line_no,
            RawSample {
                t_s: t,
                specific_force_mps2: [vals[1], vals[2], vals[3]],
                temp_c: temp,
            },
        ))
    }

    /// The next data row's sample and line (blank and `#` lines skipped), or `None` at the end.
    fn next_sample(&mut self) -> Result<Option<(u32, RawSample)>, RecordingError> {
        if let Some(s) = self.fast_sample() {
            return Ok(Some(s));
        }
        loop {
            let Some(had_newline) = read_line(
                &mut self.reader,
                &mut self.buf,
                &mut self.line_no,
                &self.file,
            )?
            else {
                return Ok(None);
            };
            let line = self.line_no;
            let text = as_utf8(&self.buf, line, &self.file)?;
            let trimmed = text.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            self.check_field_count(text, line, had_newline)?;
            let sample = self.parse_row(text, line)?;
            self.check_order(sample.t_s, line)?;
            return Ok(Some((line, sample)));
        }
    }

    /// The header's field count, or why not: a short last line without its newline is a file
    /// cut off ([`RecordingError::Truncated`]), anything else a wrong count.
    fn check_field_count(
        &self,
        text: &str,
        line: u32,
        had_newline: bool,
    ) -> Result<(), RecordingError> {
        let expected = self.header.len();
        let found = text.split(',').count();
        if found == expected {
            return Ok(());
        }
        let file = self.file.clone();
        if !had_newline && found < expected {
            return Err(RecordingError::Truncated {
                file,
                line,
                expected,
                found,
            });
        }
        Err(RecordingError::FieldCount {
            file,
            line,
            expected,
            found,
            header_line: self.header_line,
        })
    }

    /// The sample of a row of the right field count: numbers in range, or the first that is
    /// not (a non-finite time or force is kept, NaN, for the screening to count).
    fn parse_row(&self, text: &str, line: u32) -> Result<RawSample, RecordingError> {
        let file = self.file.as_str();
        let mut vals = [0.0f64; 4];
        let mut temp = None;
        for (i, field) in text.split(',').enumerate() {
            if let Some(k) = self.idx.iter().position(|&j| j == i) {
                let column = REQUIRED_COLUMNS[k];
                // A non-finite value (a sensor's NaN) is kept: the data-quality screening
                // rejects and counts that sample instead of refusing the whole file.
                let v = match parse_number(clean_field(field), file, line, column) {
                    Err(RecordingError::NotFinite { .. }) => f64::NAN,
                    other => other?,
                };
                if k > 0 && v.abs() > MAX_ABS_SPECIFIC_FORCE_MPS2 {
                    return Err(RecordingError::OutOfRange {
                        file: file.to_string(),
                        line,
                        column: column.to_string(),
                        value: v,
                        reason: "m/s^2 is implausibly large (|a| > 1000 m/s^2)",
                    });
                }
                vals[k] = v;
            } else if Some(i) == self.temp_idx {
                let f = clean_field(field);
                if !f.is_empty() {
                    let v = parse_number(f, file, line, TEMP_COLUMN)?;
                    if !(TEMP_RANGE_C.0..=TEMP_RANGE_C.1).contains(&v) {
                        return Err(RecordingError::OutOfRange {
                            file: file.to_string(),
                            line,
                            column: TEMP_COLUMN.to_string(),
                            value: v,
                            reason: "deg C is outside the plausible range [-273.15, 1000]",
                        });
                    }
                    temp = Some(v);
                }
            }
        }
        Ok(RawSample {
            t_s: vals[0],
            specific_force_mps2: [vals[1], vals[2], vals[3]],
            temp_c: temp,
        })
    }

    /// Checks that the finite time `t` of `line` comes after the last finite one, and makes it
    /// the last. A non-finite time is kept for the screening to count, outside the order.
    fn check_order(&mut self, t: f64, line: u32) -> Result<(), RecordingError> {
        if !t.is_finite() {
            return Ok(());
        }
        if let Some((prev, prev_line)) = self.prev {
            // `!(t > prev)` also catches what the finiteness check already excludes.
            if t.partial_cmp(&prev) != Some(std::cmp::Ordering::Greater) {
                return Err(RecordingError::TimeNotIncreasing {
                    file: self.file.clone(),
                    line,
                    t,
                    prev,
                    prev_line,
                });
            }
        }
        self.prev = Some((t, line));
        Ok(())
    }
}

impl<R: BufRead> Iterator for RecordingReader<R> {
    type Item = Result<(u32, RawSample), RecordingError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        match self.next_sample() {
            Ok(Some(s)) => Some(Ok(s)),
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}
