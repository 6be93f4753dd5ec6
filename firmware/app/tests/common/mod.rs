//! The in-memory link and host board the application tests run on.

use std::collections::VecDeque;
use std::convert::Infallible;

use firmware_app::app::Platform;
use protocol::Board;

/// Both directions of the serial link: bytes to the firmware (`rx`) and from it (`tx`).
#[derive(Default)]
pub struct Link {
    pub rx: VecDeque<u8>,
    pub tx: Vec<u8>,
}
impl embedded_io::ErrorType for Link {
    type Error = Infallible;
}
impl embedded_io::Read for Link {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let n = buf.len().min(self.rx.len());
        for b in buf.iter_mut().take(n) {
            *b = self.rx.pop_front().unwrap();
        }
        Ok(n)
    }
}
impl embedded_io::ReadReady for Link {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(!self.rx.is_empty())
    }
}
impl embedded_io::Write for Link {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.tx.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// The host as a board (no timer ticks, no stack figures).
pub struct HostBoard;
impl Platform for HostBoard {
    const BOARD: Board = Board::Host;
}
