//! Writing the files `driftid` produces, safely.
//!
//! - **Atomically**: every output is written to a temporary file in the same directory as its
//!   target (so the final rename never crosses a file system), flushed and synced, then renamed
//!   over the target ([`AtomicFile`], [`TempPath`], [`write_atomic`]). An error, a panic or a
//!   dropped writer removes the temporary file; the target is then either absent or still the
//!   complete previous file — never a partial one. The temporary files are named
//!   `.driftid-PID-N.NAME` (hidden, and ending with the target's own name so that writers that
//!   choose a format by extension, like the PNG plots, still do). SIGINT, SIGTERM and SIGHUP
//!   remove every one that is not finished, then end the process by the signal
//!   ([`remove_temporaries_on_signal`]); only a SIGKILL (which nothing can catch) may leave one —
//!   never the target itself.
//! - **Never over an input**: [`ensure_not_input`] refuses an output that is the same file as
//!   one of the command's inputs (same device and inode on Unix — which also catches hard links
//!   and symbolic links — or, when the output does not exist yet, the same canonical directory
//!   and name).
//!
//! - **Never over a file the user has** ([`Outputs`], [`check_output`]): an existing target is
//!   replaced without `--force` only when it is a regular file `driftid` itself wrote there
//!   before, recognised by its content ([`Made`]): the report's HTML carries
//!   `<meta name="generator" content="driftid">`, its PNGs a `tEXt` chunk `Software: driftid`,
//!   a simulated recording the metadata line `# generator: driftid simulate`, a truth file the
//!   JSON keys `scenario` and `coefficients`, a CSV export (`diagnose --export`, `replay`'s
//!   estimates) the exact header line `driftid` writes; a raw frame log (`--raw`) is appended to
//!   only when it is empty or holds a frame `driftid` decodes. Anything else — above all a
//!   recording — is refused, naming the file and saying that `--force` replaces it.
//! - **Never renamed over a non-regular file**: a FIFO or a character device (`-o /dev/null`, a
//!   named pipe) is what a user names to receive the output: the finished temporary file is
//!   copied *into* it and removed ([`finish`]); a directory, a block device or a socket is
//!   refused, with or without `--force`.
//!
//! Renaming replaces a symbolic link at the target by a regular file (it does not write through
//! the link), and the new file has default permissions.
//!
//! Hand-written rather than `tempfile`'s `NamedTempFile::new_in` + `persist`, which cannot keep
//! two of the guarantees above: it removes its file in `Drop`, and a signal ends the process
//! without running destructors, so the SIGINT/SIGTERM/SIGHUP clean-up needs this registry of
//! temporaries anyway (created and registered under one lock); and `persist` is a bare rename,
//! which would replace a FIFO or a character device at the target (`-o /dev/null`) instead of
//! writing into it. What it would take over — a fresh name beside the target and `create_new` —
//! is a dozen lines here, against a second clean-up path beside the registry.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::Context as _;

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// The temporary files not yet renamed into place (or removed), for the signal clean-up. A
/// temporary file is created and registered under this lock, and the clean-up holds it until
/// the process is gone: no temporary file is created after the clean-up has looked.
static TEMPORARIES: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

fn temporaries() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner())
}

fn unregister(temp: &Path) {
    let mut t = temporaries();
    if let Some(i) = t.iter().position(|p| p == temp) {
        t.swap_remove(i);
    }
}

/// Installs the clean-up: on SIGINT, SIGTERM or SIGHUP every unfinished temporary file is
/// removed, then the signal's default action ends the process (status: killed by that signal,
/// 130 for SIGINT in a shell). Call once at start-up; without it a signal leaves the
/// temporaries (never a partial file under a real name).
#[cfg(unix)]
pub fn remove_temporaries_on_signal() -> anyhow::Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])
        .context("installing the signal handlers")?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                // Held until the process is gone: nothing new is created meanwhile.
                let t = temporaries();
                for p in t.iter() {
                    let _ = fs::remove_file(p);
                }
                let _ = signal_hook::low_level::emulate_default_handler(sig);
                std::process::exit(128 + sig);
            }
        })
        .context("starting the signal thread")?;
    Ok(())
}

/// Removes every unfinished temporary file now, for a process about to end without unwinding
/// (memory refused: [`crate::heap`]). Skipped if another thread holds the registry (it may be
/// the very thread that ran out, inside its lock): nothing is waited for at that point.
pub fn remove_temporaries_now() {
    if let Ok(t) = TEMPORARIES.try_lock() {
        for p in t.iter() {
            let _ = fs::remove_file(p);
        }
    }
}

/// The directory a target lives in (`.` for a bare file name).
fn dir_of(target: &Path) -> &Path {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// A fresh temporary path beside `target`: `DIR/.driftid-PID-N.NAME`.
fn temp_path_for(target: &Path) -> anyhow::Result<PathBuf> {
    let name = target
        .file_name()
        .with_context(|| format!("{}: not a file name", target.display()))?;
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut temp = std::ffi::OsString::from(format!(".driftid-{}-{n}.", std::process::id()));
    temp.push(name);
    Ok(dir_of(target).join(temp))
}

/// Renames `temp` over `target` after syncing `temp`'s contents to disk. A target that is a
/// FIFO or a character device is never renamed over: `temp` is copied into it, then removed.
fn finish(temp: &Path, target: &Path) -> anyhow::Result<()> {
    File::open(temp)
        .and_then(|f| f.sync_all())
        .with_context(|| format!("writing {}", target.display()))?;
    if let Ok(m) = fs::metadata(target) {
        let ft = m.file_type();
        if !ft.is_file() {
            let result = if is_stream(&ft) {
                File::open(temp).and_then(|mut src| {
                    let mut dst = OpenOptions::new().write(true).open(target)?;
                    io::copy(&mut src, &mut dst)?;
                    dst.flush()
                })
            } else {
                Err(io::Error::other(format!(
                    "{}, not a regular file; never replaced",
                    describe_type(&ft)
                )))
            };
            let _ = fs::remove_file(temp);
            return result.with_context(|| format!("writing {}", target.display()));
        }
    }
    fs::rename(temp, target).with_context(|| {
        format!(
            "renaming the finished {} into place as {}",
            temp.display(),
            target.display()
        )
    })
}

/// A path to write to in place of `target`, for writers that want a path (e.g. plotters'
/// bitmap backend). [`TempPath::commit`] renames it over the target; dropping it uncommitted
/// removes it.
#[derive(Debug)]
pub(crate) struct TempPath {
    target: PathBuf,
    temp: PathBuf,
    committed: bool,
}

impl TempPath {
    /// A fresh temporary path in the target's directory (nothing is created yet).
    pub(crate) fn new(target: &Path) -> anyhow::Result<Self> {
        let temp = temp_path_for(target)?;
        temporaries().push(temp.clone());
        Ok(TempPath {
            target: target.to_path_buf(),
            temp,
            committed: false,
        })
    }

    /// A fresh temporary file in the target's directory, created (empty) and registered under
    /// one lock ([`TEMPORARIES`]).
    fn create(target: &Path) -> anyhow::Result<(Self, File)> {
        let temp = temp_path_for(target)?;
        let mut t = temporaries();
        let f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp)
            .with_context(|| format!("creating a temporary file for {}", target.display()))?;
        t.push(temp.clone());
        drop(t);
        let path = TempPath {
            target: target.to_path_buf(),
            temp,
            committed: false,
        };
        Ok((path, f))
    }

    /// Where to write.
    pub(crate) fn path(&self) -> &Path {
        &self.temp
    }

    /// The final destination.
    pub(crate) fn target(&self) -> &Path {
        &self.target
    }

    /// Moves the finished file into place.
    pub(crate) fn commit(mut self) -> anyhow::Result<()> {
        finish(&self.temp, &self.target)?;
        self.committed = true;
        unregister(&self.temp);
        Ok(())
    }
}

impl Drop for TempPath {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_file(&self.temp);
            unregister(&self.temp);
        }
    }
}

/// A file written under a temporary name and renamed over its target by [`AtomicFile::commit`].
/// Dropped without a commit (an error on the way, a panic), the temporary file is removed and
/// the target left as it was.
#[derive(Debug)]
pub(crate) struct AtomicFile {
    w: BufWriter<File>,
    path: TempPath,
}

impl AtomicFile {
    /// Creates the temporary file beside `target`.
    pub(crate) fn create(target: &Path) -> anyhow::Result<Self> {
        let (path, f) = TempPath::create(target)?;
        Ok(AtomicFile {
            w: BufWriter::with_capacity(1 << 16, f),
            path,
        })
    }

    /// Flushes, syncs and renames the file over its target.
    pub(crate) fn commit(mut self) -> anyhow::Result<()> {
        self.w
            .flush()
            .with_context(|| format!("writing {}", self.path.target().display()))?;
        let AtomicFile { w, path } = self;
        drop(w);
        path.commit()
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.w.write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        self.w.write_all(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.w.flush()
    }
}

/// `path` resolved: canonical if it exists, else its canonical directory joined with its name.
fn resolve(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = fs::canonicalize(path) {
        return Some(p);
    }
    let dir = fs::canonicalize(dir_of(path)).ok()?;
    Some(dir.join(path.file_name()?))
}

/// Whether `a` and `b` name the same file (existing or not).
pub(crate) fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    if let (Ok(ma), Ok(mb)) = (fs::metadata(a), fs::metadata(b)) {
        use std::os::unix::fs::MetadataExt as _;
        return ma.dev() == mb.dev() && ma.ino() == mb.ino();
    }
    matches!((resolve(a), resolve(b)), (Some(x), Some(y)) if x == y)
}

/// Refuses to write `output` (given on the command line as `option`) over one of `inputs`.
pub(crate) fn ensure_not_input(
    output: &Path,
    option: &str,
    inputs: &[&Path],
) -> anyhow::Result<()> {
    for input in inputs {
        if same_file(output, input) {
            anyhow::bail!(
                "{option} {}: that is the input {}; refusing to overwrite it (choose another output file)",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// A FIFO or a character device: written into, never renamed over.
fn is_stream(ft: &fs::FileType) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        ft.is_fifo() || ft.is_char_device()
    }
    #[cfg(not(unix))]
    {
        let _ = ft;
        false
    }
}

/// What kind of file a non-regular path is, for messages.
fn describe_type(ft: &fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        if ft.is_block_device() {
            return "a block device";
        }
        if ft.is_socket() {
            return "a socket";
        }
        if ft.is_fifo() {
            return "a FIFO";
        }
        if ft.is_char_device() {
            return "a character device";
        }
    }
    if ft.is_dir() {
        "a directory"
    } else if ft.is_symlink() {
        "a symbolic link to nothing"
    } else {
        "not a regular file"
    }
}

/// The generator tag of `report`'s HTML, by which a later run recognises its own page.
pub(crate) const HTML_GENERATOR: &str = "<meta name=\"generator\" content=\"driftid\">";
/// The `tEXt` chunk's keyword and text in `report --png`'s plots.
pub(crate) const PNG_SOFTWARE: &[u8] = b"Software\0driftid";
/// The metadata key and value of a simulated recording.
pub(crate) const SIMULATED_KEY: (&str, &str) = ("generator", "driftid simulate");

/// What `driftid` writes at a target; an existing file there is recognised as one `driftid`
/// wrote by its content (module docs), and only then replaced without `--force`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Made {
    /// `report`'s HTML page.
    Html,
    /// A `report --png` plot.
    Png,
    /// `simulate`'s recording.
    SimulatedRecording,
    /// `simulate`'s truth file.
    Truth,
    /// A CSV whose first line is exactly this header (`diagnose --export`, `replay --out`).
    Csv(String),
    /// A raw frame log, appended to (`record --raw`, `replay --raw`).
    RawLog,
}

/// How much of an existing file is read to recognise it.
const SIGNATURE_BYTES: u64 = 64 << 10;

impl Made {
    /// What is written, for messages.
    fn what(&self) -> &'static str {
        match self {
            Made::Html => "an HTML report",
            Made::Png => "a PNG plot",
            Made::SimulatedRecording => "a simulated recording",
            Made::Truth => "a truth file",
            Made::Csv(_) => "a CSV export",
            Made::RawLog => "a raw frame log",
        }
    }

    /// Whether `head` (the first [`SIGNATURE_BYTES`] of an existing regular file) is a file of
    /// this kind that `driftid` wrote.
    fn recognises(&self, head: &[u8]) -> bool {
        let contains = |needle: &[u8]| head.windows(needle.len()).any(|w| w == needle);
        match self {
            Made::Html => contains(HTML_GENERATOR.as_bytes()),
            Made::Png => head.starts_with(b"\x89PNG\r\n\x1a\n") && contains(PNG_SOFTWARE),
            Made::SimulatedRecording => {
                let line = format!("# {}: {}", SIMULATED_KEY.0, SIMULATED_KEY.1);
                String::from_utf8_lossy(head)
                    .lines()
                    .take_while(|l| l.starts_with('#'))
                    .any(|l| l.trim_end() == line)
            }
            Made::Truth => matches!(
                serde_json::from_slice::<serde_json::Value>(head),
                Ok(serde_json::Value::Object(o)) if o.contains_key("scenario") && o.contains_key("coefficients")
            ),
            Made::Csv(header) => {
                let first = head.split(|&b| b == b'\n').next().unwrap_or_default();
                first.strip_suffix(b"\r").unwrap_or(first) == header.as_bytes()
            }
            Made::RawLog => {
                // A frame the protocol decodes (the link layer is above this module).
                let mut framed = false;
                protocol::Decoder::default().feed(head, |r| framed |= r.is_ok());
                head.is_empty() || framed
            }
        }
    }
}

/// The policy for one output path (module docs): `Ok` when `target` may be written — it does
/// not exist, or it is a FIFO or a character device (written into), or a regular file `driftid`
/// wrote as `made` (or any regular file with `force`); else an error naming `option`, the file
/// and what to do. Its directory must exist.
pub(crate) fn check_output(
    target: &Path,
    option: &str,
    made: &Made,
    force: bool,
) -> anyhow::Result<()> {
    let shown = target.display();
    if target.file_name().is_none() {
        anyhow::bail!("{option} {shown}: not a file name");
    }
    let dir = dir_of(target);
    match fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => anyhow::bail!("{option} {shown}: {} is not a directory", dir.display()),
        Err(e) => anyhow::bail!("{option} {shown}: directory {}: {e}", dir.display()),
    }
    let link = match fs::symlink_metadata(target) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => anyhow::bail!("{option} {shown}: {e}"),
        Ok(m) => m,
    };
    let m = match fs::metadata(target) {
        Ok(m) => m,
        // A symbolic link to nothing: renaming would replace the link.
        Err(_) if force => return Ok(()),
        Err(_) => anyhow::bail!(
            "{option} {shown}: {} exists; refusing to replace it (give --force to replace it)",
            describe_type(&link.file_type())
        ),
    };
    let ft = m.file_type();
    if is_stream(&ft) {
        return Ok(());
    }
    if !ft.is_file() {
        anyhow::bail!(
            "{option} {shown}: {}; driftid writes only regular files, FIFOs and character devices",
            describe_type(&ft)
        );
    }
    if force {
        return Ok(());
    }
    let mut head = Vec::new();
    File::open(target)
        .and_then(|f| {
            use std::io::Read as _;
            f.take(SIGNATURE_BYTES).read_to_end(&mut head)
        })
        .with_context(|| format!("{option} {shown}: reading the existing file"))?;
    if made.recognises(&head) {
        return Ok(());
    }
    anyhow::bail!(
        "{option} {shown}: the file exists and is not {} driftid wrote{}; refusing to overwrite it (give --force to replace it, or choose another file)",
        made.what(),
        if *made == Made::RawLog { " (it would be appended to)" } else { "" }
    )
}

/// `--png DIR`-like options: a folder that exists, or can be made (its nearest existing
/// ancestor is a folder).
pub(crate) fn check_output_dir(dir: &Path, option: &str) -> anyhow::Result<()> {
    let mut p = dir;
    loop {
        match fs::metadata(p) {
            Ok(m) if m.is_dir() => return Ok(()),
            Ok(_) => anyhow::bail!(
                "{option} {}: {} exists and is not a directory",
                dir.display(),
                p.display()
            ),
            Err(e) if e.kind() == io::ErrorKind::NotFound => match p.parent() {
                Some(q) if !q.as_os_str().is_empty() => p = q,
                _ => return Ok(()),
            },
            Err(e) => anyhow::bail!("{option} {}: {}: {e}", dir.display(), p.display()),
        }
    }
}

/// The outputs of one command, checked before anything is written: each against every input
/// ([`ensure_not_input`]), against the outputs claimed before it, and by [`check_output`].
#[derive(Debug)]
pub(crate) struct Outputs {
    inputs: Vec<PathBuf>,
    force: bool,
    claimed: Vec<(PathBuf, String)>,
}

impl Outputs {
    /// The command's input files and its `--force`.
    pub(crate) fn new(inputs: &[&Path], force: bool) -> Self {
        Outputs {
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            force,
            claimed: Vec::new(),
        }
    }

    /// Checks one output (given as `option`) and claims it.
    pub(crate) fn check(&mut self, target: &Path, option: &str, made: Made) -> anyhow::Result<()> {
        let inputs: Vec<&Path> = self.inputs.iter().map(|p| p.as_path()).collect();
        ensure_not_input(target, option, &inputs)?;
        if let Some((p, o)) = self.claimed.iter().find(|(p, _)| same_file(p, target)) {
            anyhow::bail!(
                "{option} {}: that is also the output {o} {}; choose another file",
                target.display(),
                p.display()
            );
        }
        check_output(target, option, &made, self.force)?;
        self.claimed
            .push((target.to_path_buf(), option.to_string()));
        Ok(())
    }
}

/// Opens a log `driftid` appends to (`--raw`), after [`check_output`] with [`Made::RawLog`]:
/// a raw frame log driftid wrote (or an empty file) is appended to; any other existing regular
/// file is refused, or with `force` replaced (truncated) — never appended to; a FIFO or a
/// character device is written into.
pub(crate) fn open_log(target: &Path, option: &str, force: bool) -> anyhow::Result<File> {
    check_output(target, option, &Made::RawLog, force)?;
    let foreign = force && check_output(target, option, &Made::RawLog, false).is_err();
    let mut o = OpenOptions::new();
    if foreign {
        o.write(true).truncate(true);
    } else {
        o.append(true).create(true);
    }
    o.open(target)
        .with_context(|| format!("{option} {}: opening", target.display()))
}

/// Adds the `tEXt` chunk `Software: driftid` after a PNG's header chunk, by which
/// [`Made::Png`] recognises the plot later. Bytes that are not a PNG are returned unchanged.
pub(crate) fn tag_png(png: &[u8]) -> Vec<u8> {
    // Signature (8) + IHDR chunk (4 length + 4 type + 13 data + 4 CRC).
    const AFTER_IHDR: usize = 33;
    if png.len() < AFTER_IHDR || !png.starts_with(b"\x89PNG\r\n\x1a\n") || &png[12..16] != b"IHDR" {
        return png.to_vec();
    }
    let mut chunk = Vec::with_capacity(12 + PNG_SOFTWARE.len());
    chunk.extend_from_slice(&(PNG_SOFTWARE.len() as u32).to_be_bytes());
    chunk.extend_from_slice(b"tEXt");
    chunk.extend_from_slice(PNG_SOFTWARE);
    let crc = crc32fast::hash(&chunk[4..]);
    chunk.extend_from_slice(&crc.to_be_bytes());
    let mut out = Vec::with_capacity(png.len() + chunk.len());
    out.extend_from_slice(&png[..AFTER_IHDR]);
    out.extend_from_slice(&chunk);
    out.extend_from_slice(&png[AFTER_IHDR..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("driftid-output-{}-{name}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// A writer dropped mid-way (an error or an interruption before commit) leaves the previous
    /// file byte-identical and no temporary file; a commit replaces it whole.
    #[test]
    fn uncommitted_writes_leave_the_previous_file_and_no_temporary() {
        let dir = temp_dir("atomic");
        let target = dir.join("run.csv");
        fs::write(&target, b"previous complete file\n").unwrap();
        {
            let mut f = AtomicFile::create(&target).unwrap();
            f.write_all(&[b'x'; 200_000]).unwrap();
            // Dropped here without commit.
        }
        assert_eq!(fs::read(&target).unwrap(), b"previous complete file\n");
        assert_eq!(entries(&dir), ["run.csv"], "no temporary file left");
        let mut f = AtomicFile::create(&target).unwrap();
        f.write_all(b"new\n").unwrap();
        // Until the commit the target is untouched.
        assert_eq!(fs::read(&target).unwrap(), b"previous complete file\n");
        f.commit().unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"new\n");
        assert_eq!(entries(&dir), ["run.csv"]);
        // A new target that is never committed does not appear at all.
        drop(AtomicFile::create(&dir.join("other.csv")).unwrap());
        assert_eq!(entries(&dir), ["run.csv"]);
        // TempPath keeps the target's extension (plotters picks the format by it).
        let t = TempPath::new(&dir.join("fig.png")).unwrap();
        assert_eq!(t.path().extension().unwrap(), "png");
        fs::write(t.path(), b"png").unwrap();
        drop(t);
        assert_eq!(entries(&dir), ["run.csv"]);
        let _ = fs::remove_dir_all(&dir);
    }

    /// Files driftid writes are recognised as its own by their content; others are not.
    #[test]
    fn driftid_recognises_the_files_it_wrote() {
        // The smallest PNG header: signature + IHDR (13 bytes of data) + CRC.
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend_from_slice(&[0; 17]);
        png.extend_from_slice(b"\0\0\0\0IEND\xaeB`\x82");
        assert!(!Made::Png.recognises(&png));
        assert!(Made::Png.recognises(&tag_png(&png)));
        assert!(Made::Html.recognises(format!("<html><head>{HTML_GENERATOR}").as_bytes()));
        assert!(!Made::Html.recognises(b"t_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n"));
        let sim =
            "# latitude_deg: 39.1\n# generator: driftid simulate\nt_s,ax_mps2,ay_mps2,az_mps2\n";
        assert!(Made::SimulatedRecording.recognises(sim.as_bytes()));
        assert!(!Made::SimulatedRecording
            .recognises(b"# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n"));
        assert!(Made::Truth.recognises(br#"{"scenario": {}, "coefficients": {}}"#));
        assert!(!Made::Truth.recognises(b"notes"));
        assert!(Made::Csv("a,b".into()).recognises(b"a,b\r\n1,2\n"));
        assert!(!Made::Csv("a,b".into()).recognises(b"a,b,c\n"));
        assert!(Made::RawLog.recognises(b""));
        assert!(!Made::RawLog.recognises(b"t_s,ax_mps2\n"));
    }

    #[test]
    fn the_same_file_is_recognised_by_any_name() {
        let dir = temp_dir("same");
        let a = dir.join("a.csv");
        fs::write(&a, b"a").unwrap();
        assert!(same_file(&a, &dir.join(".").join("a.csv")));
        assert!(!same_file(&a, &dir.join("b.csv")));
        // Not existing yet: same directory and name.
        assert!(same_file(&dir.join("new.csv"), &dir.join("./new.csv")));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(&a, dir.join("link.csv")).unwrap();
            assert!(same_file(&a, &dir.join("link.csv")));
            fs::hard_link(&a, dir.join("hard.csv")).unwrap();
            assert!(same_file(&a, &dir.join("hard.csv")));
        }
        let e = ensure_not_input(&a, "--out", &[&dir.join("b.csv"), &a]).unwrap_err();
        assert!(format!("{e}").contains("--out") && format!("{e}").contains("a.csv"));
        let _ = fs::remove_dir_all(&dir);
    }
}
