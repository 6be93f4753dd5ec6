//! Serial ports and pseudo-terminals.

use std::io;
use std::time::Duration;

use anyhow::Context as _;
use serialport::{SerialPort, TTYPort};

/// Default baud rate of the navigation computer's link (ignored by ptys).
pub(crate) const DEFAULT_BAUD: u32 = 115_200;

/// Read timeout used by the link loops: short, so they can watch deadlines and child processes.
pub const POLL: Duration = Duration::from_millis(100);

/// Write timeout of the link's sending side: long, because the receiver legitimately stops
/// reading for a while (an EKF update, QEMU busy) and a write that times out half-way through a
/// frame would lose the rest of the stream. Only a receiver gone for this long is an error. (A
/// replay does not wait for it: it ends at its own time-out, `replay::replay`.)
pub(crate) const WRITE_TIMEOUT: Duration = Duration::from_secs(60);

/// A second handle on `port` for the sending side, with [`WRITE_TIMEOUT`] (reads keep [`POLL`]).
pub fn writer_of(port: &TTYPort) -> anyhow::Result<TTYPort> {
    let mut w = port
        .try_clone_native()
        .context("cloning the serial port for writing")?;
    w.set_timeout(WRITE_TIMEOUT)?;
    Ok(w)
}

/// Opens a serial port (a tty device or a pty's slave side) in raw mode.
pub(crate) fn open(path: &str, baud: u32) -> anyhow::Result<TTYPort> {
    serialport::new(path, baud)
        .timeout(POLL)
        .open_native()
        .with_context(|| format!("opening serial port {path}"))
}

/// A pseudo-terminal pair for talking to QEMU: the host keeps the master; QEMU opens the slave by
/// its path (`-serial /dev/pts/N`). The slave handle is returned too: keep it open until QEMU has
/// opened the slave, or reads on the master fail (EIO) while no one holds it.
pub struct Pty {
    /// The host's end.
    pub master: TTYPort,
    /// The other end (kept open by the host while it lives).
    pub slave: TTYPort,
    /// Path of the slave device, for QEMU.
    pub slave_path: String,
}

/// Creates a pty pair in raw mode.
pub fn pty_pair() -> anyhow::Result<Pty> {
    let (mut master, slave) = TTYPort::pair().context("creating a pseudo-terminal pair")?;
    master.set_timeout(POLL)?;
    let slave_path = slave.name().context("the pty slave has no name")?;
    Ok(Pty {
        master,
        slave,
        slave_path,
    })
}

/// Whether an I/O error means "no data yet" rather than a broken link.
pub(crate) fn is_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
    )
}

/// Whether an I/O error means the other end went away (port unplugged, QEMU exited).
pub(crate) fn is_gone(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::BrokenPipe
            | io::ErrorKind::NotConnected
            | io::ErrorKind::UnexpectedEof
            | io::ErrorKind::NotFound
            | io::ErrorKind::ConnectionReset
    ) || e.raw_os_error() == Some(5) // EIO: pty with no other end / device removed
}
