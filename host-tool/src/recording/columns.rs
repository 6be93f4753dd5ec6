//! Extra columns of a recording, read by header name for the effects that use them
//! (`columns = ["I_spin"]` in an effects file). The main reader ignores columns it does not
//! know; this second pass reads only the named ones, and only when an effect asks for them.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::reader::{clean_field, parse_number};
use super::{RecordingReader, REQUIRED_COLUMNS, TEMP_COLUMN};

/// The values of columns `names` at the samples on file lines `lines` (ascending, as
/// [`super::Recording::lines`]), one vector per name. A missing column, an empty or
/// non-numeric value is an error naming the file, the line and the column.
pub fn read_columns(path: &Path, names: &[String], lines: &[u32]) -> anyhow::Result<Vec<Vec<f64>>> {
    let file = path.display().to_string();
    let open = || File::open(path).map_err(|e| anyhow::anyhow!("{file}: cannot open: {e}"));
    let reader = RecordingReader::new(BufReader::new(open()?), file.clone())?;
    let (header, header_line) = (reader.header().to_vec(), reader.header_line());
    let mut idx = Vec::with_capacity(names.len());
    for n in names {
        if REQUIRED_COLUMNS.contains(&n.as_str()) || n == TEMP_COLUMN {
            anyhow::bail!("{file}:{header_line}: column {n} is the recording's own, not an extra column an effect may use");
        }
        let Some(i) = header.iter().position(|h| h == n) else {
            anyhow::bail!(
                "{file}:{header_line}: no column {n} (header has: {}); an effect of the effects file uses it",
                header.join(", ")
            );
        };
        idx.push(i);
    }
    let mut out = vec![Vec::with_capacity(lines.len()); names.len()];
    let mut wanted = lines.iter().copied().peekable();
    let mut buf = Vec::new();
    let mut text = BufReader::with_capacity(1 << 16, open()?);
    let mut line = 0u32;
    while let Some(&next) = wanted.peek() {
        buf.clear();
        let n = text
            .read_until(b'\n', &mut buf)
            .map_err(|e| anyhow::anyhow!("{file}:{}: read error: {e}", line + 1))?;
        if n == 0 {
            anyhow::bail!(
                "{file}:{next}: the file ended before this line (changed while it was read?)"
            );
        }
        line += 1;
        if line != next {
            continue;
        }
        wanted.next();
        let row = std::str::from_utf8(&buf)
            .map_err(|_| anyhow::anyhow!("{file}:{line}: not valid UTF-8"))?
            .trim_end_matches(['\n', '\r']);
        let fields: Vec<&str> = row.split(',').collect();
        for (k, &i) in idx.iter().enumerate() {
            let text = fields.get(i).map_or("", |f| clean_field(f));
            out[k].push(parse_number(text, &file, line, &names[k])?);
        }
    }
    Ok(out)
}
