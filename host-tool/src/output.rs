//! Writing the files `driftid` produces, safely.
//!
//! - **Atomically**: every output is written to a temporary file in the same directory as its
//!   target (so the final rename never crosses a file system), flushed and synced, then renamed
//!   over the target ([`AtomicFile`], [`TempPath`], [`write_atomic`]). An error, a panic or a
//!   dropped writer removes the temporary file; the target is then either absent or still the
//!   complete previous file — never a partial one. A process killed outright (SIGKILL, or a
//!   Ctrl-C, which kills without running destructors) may leave the temporary file, named
//!   `.driftid-PID-N.NAME` (hidden, and ending with the target's own name so that writers that
//!   choose a format by extension, like the PNG plots, still do): never the target itself.
//! - **Never over an input**: [`ensure_not_input`] refuses an output that is the same file as
//!   one of the command's inputs (same device and inode on Unix — which also catches hard links
//!   and symbolic links — or, when the output does not exist yet, the same canonical directory
//!   and name).
//!
//! Renaming replaces a symbolic link at the target by a regular file (it does not write through
//! the link), and the new file has default permissions.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::Context as _;

static COUNTER: AtomicU64 = AtomicU64::new(0);

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

/// Renames `temp` over `target` after syncing `temp`'s contents to disk.
fn finish(temp: &Path, target: &Path) -> anyhow::Result<()> {
    File::open(temp)
        .and_then(|f| f.sync_all())
        .with_context(|| format!("writing {}", target.display()))?;
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
pub struct TempPath {
    target: PathBuf,
    temp: PathBuf,
    committed: bool,
}

impl TempPath {
    /// A fresh temporary path in the target's directory (nothing is created yet).
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        Ok(TempPath {
            target: target.to_path_buf(),
            temp: temp_path_for(target)?,
            committed: false,
        })
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        &self.temp
    }

    /// The final destination.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Moves the finished file into place.
    pub fn commit(mut self) -> anyhow::Result<()> {
        finish(&self.temp, &self.target)?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for TempPath {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_file(&self.temp);
        }
    }
}

/// A file written under a temporary name and renamed over its target by [`AtomicFile::commit`].
/// Dropped without a commit (an error on the way, a panic), the temporary file is removed and
/// the target left as it was.
#[derive(Debug)]
pub struct AtomicFile {
    w: BufWriter<File>,
    path: TempPath,
}

impl AtomicFile {
    /// Creates the temporary file beside `target`.
    pub fn create(target: &Path) -> anyhow::Result<Self> {
        let path = TempPath::new(target)?;
        let f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path.path())
            .with_context(|| format!("creating a temporary file for {}", target.display()))?;
        Ok(AtomicFile {
            w: BufWriter::with_capacity(1 << 16, f),
            path,
        })
    }

    /// The final destination.
    pub fn target(&self) -> &Path {
        self.path.target()
    }

    /// Flushes, syncs and renames the file over its target.
    pub fn commit(mut self) -> anyhow::Result<()> {
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

/// Writes `bytes` to `target` atomically.
pub fn write_atomic(target: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let mut f = AtomicFile::create(target)?;
    f.write_all(bytes)
        .with_context(|| format!("writing {}", target.display()))?;
    f.commit()
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
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    if let (Ok(ma), Ok(mb)) = (fs::metadata(a), fs::metadata(b)) {
        use std::os::unix::fs::MetadataExt as _;
        return ma.dev() == mb.dev() && ma.ino() == mb.ino();
    }
    matches!((resolve(a), resolve(b)), (Some(x), Some(y)) if x == y)
}

/// Refuses to write `output` (given on the command line as `option`) over one of `inputs`.
pub fn ensure_not_input(output: &Path, option: &str, inputs: &[&Path]) -> anyhow::Result<()> {
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
