//! The Arm CMSDK APB UART (UART0 of QEMU's `mps2-an500`, the QEMU board's link): its registers,
//! bringing it up, and its receive interrupt, over [`Regs`] so that the host tests run the same
//! sequences against a model of QEMU's UART (`tests/cmsdk_uart.rs`).
//!
//! The receiver and its interrupt are enabled by **one** write of `CTRL` ([`enable_rx`]). QEMU's
//! model raises the receive interrupt only for a byte that arrives while the interrupt is
//! enabled (`hw/char/cmsdk-apb-uart.c`: `uart_receive` sets `INTSTATUS.RX` only if
//! `CTRL.RXINTEN`; a later write of `CTRL` does not raise it for a byte already held), and it
//! takes no further byte while one is held (`uart_can_receive`: `RXFULL` clear). A byte that
//! arrived between a write enabling the receiver and a second one enabling its interrupt was
//! therefore never read: no interrupt, no more input, the link dead. That happened after a
//! reset with the host's bytes already waiting (the reset test: the firmware resumed, said so,
//! and never heard the resent samples).

/// Register access to one UART (the board: volatile MMIO; the tests: a model).
pub trait Regs {
    /// Reads the register at byte offset `offset`.
    fn read(&mut self, offset: usize) -> u32;
    /// Writes `value` to the register at byte offset `offset`.
    fn write(&mut self, offset: usize, value: u32);
}

/// Data register (read: the received byte; write: the byte to send).
pub const DATA: usize = 0x00;
/// State register ([`STATE_TX_FULL`], [`STATE_RX_FULL`]).
pub const STATE: usize = 0x04;
/// Control register ([`CTRL_TX_EN`], [`CTRL_RX_EN`], [`CTRL_RX_INT_EN`]).
pub const CTRL: usize = 0x08;
/// Interrupt status (read) / clear (write 1s).
pub const INTCLEAR: usize = 0x0C;
/// Baud-rate divider.
pub const BAUDDIV: usize = 0x10;
/// `STATE`: the transmit buffer is full.
pub const STATE_TX_FULL: u32 = 1 << 0;
/// `STATE`: a received byte is waiting in `DATA`.
pub const STATE_RX_FULL: u32 = 1 << 1;
/// `CTRL`: transmitter enabled.
pub const CTRL_TX_EN: u32 = 1 << 0;
/// `CTRL`: receiver enabled.
pub const CTRL_RX_EN: u32 = 1 << 1;
/// `CTRL`: receive interrupt enabled.
pub const CTRL_RX_INT_EN: u32 = 1 << 3;
/// `INTCLEAR`: the receive interrupt.
pub const INT_RX: u32 = 1 << 1;

/// Sets the baud-rate divider and enables the transmitter only (the receiver stays off until
/// [`enable_rx`]; a fatal-error report, which only sends, calls this alone).
pub fn init_tx(r: &mut impl Regs, bauddiv: u32) {
    r.write(BAUDDIV, bauddiv);
    r.write(CTRL, CTRL_TX_EN);
}

/// Enables the receiver together with its interrupt, in one write (see the module docs: with
/// two writes, a byte arriving in between is never read, and the UART takes no other).
pub fn enable_rx(r: &mut impl Regs) {
    r.write(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
}

/// The receive interrupt: acknowledges it first (a byte arriving after this raises it again),
/// then moves every waiting byte into `ring`.
pub fn on_rx_interrupt(r: &mut impl Regs, ring: &mut crate::serial::RxProducer<'_>) {
    r.write(INTCLEAR, INT_RX);
    while r.read(STATE) & STATE_RX_FULL != 0 {
        ring.push(r.read(DATA) as u8);
    }
}
