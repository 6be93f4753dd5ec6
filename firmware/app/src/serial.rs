//! Serial reception that drops nothing: the UART's receive interrupt moves every byte from the
//! hardware FIFO into a ring ([`RxQueue`], heapless's SPSC queue), and the application reads
//! from the ring. A flash erase (up to 2.2 s on the STM32H743 at x32 parallelism, datasheet maximum) or a filter step blocks the
//! loop, not the interrupt, so the 16-byte FIFO never overruns; the ring holds what arrives
//! meanwhile: [`RX_RING_BYTES`] at 115 200 Bd (11 520 bytes/s) is 2.8 s of continuous input.
//! What the ring could not take is counted ([`RxProducer::dropped`]), never silent.
//!
//! `tests/uart_overrun.rs` proves it on the host: the application over a simulated UART with a
//! 16-byte FIFO at 115 200 Bd, realistic erase and step durations, polled (bytes lost) and
//! through the ring (none lost, estimates bit-identical to the host).

use heapless::spsc::{Consumer, Producer, Queue};

/// Receive ring size of the boards, bytes (2.8 s of continuous input at 115 200 Bd).
pub const RX_RING_BYTES: usize = 32 * 1024;

/// The receive ring a board keeps in a `static`: heapless's lock-free single-producer,
/// single-consumer queue of [`RX_RING_BYTES`] slots (it holds one byte less; a power of two
/// keeps its index arithmetic a mask). [`Queue::split`] it once, at start-up: the
/// [`RxProducer`] goes to the receive interrupt, the [`Consumer`] into a [`RingSerial`] for the
/// loop. The split ends are the only way in, so no caller discipline is left to trust.
pub type RxQueue = Queue<u8, RX_RING_BYTES>;

/// The receive interrupt's end of the ring: stores bytes, counts those it had no room for.
pub struct RxProducer<'a> {
    q: Producer<'a, u8>,
    dropped: u32,
}

impl<'a> RxProducer<'a> {
    /// The interrupt's end over `q` (the producer of a split [`Queue`]).
    pub fn new(q: Producer<'a, u8>) -> Self {
        RxProducer { q, dropped: 0 }
    }

    /// Stores `b`; when the ring is full the byte is dropped and counted, and `false` returned.
    pub fn push(&mut self, b: u8) -> bool {
        let stored = self.q.enqueue(b).is_ok();
        if !stored {
            self.dropped = self.dropped.wrapping_add(1);
        }
        stored
    }

    /// Bytes waiting in the ring.
    pub fn len(&self) -> usize {
        self.q.len()
    }

    /// Whether no byte is waiting.
    pub fn is_empty(&self) -> bool {
        self.q.is_empty()
    }

    /// Bytes the ring had no room for.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}

/// A serial port for the application: reads from the consumer end of a ring the receive
/// interrupt fills ([`RxProducer`]), writes through the board's transmitter `W`.
pub struct RingSerial<'a, W> {
    rx: Consumer<'a, u8>,
    tx: W,
}

impl<'a, W> RingSerial<'a, W> {
    /// The port over `rx` (the consumer of a split [`Queue`]) and `tx`.
    pub fn new(rx: Consumer<'a, u8>, tx: W) -> Self {
        RingSerial { rx, tx }
    }

    /// The transmitter.
    pub fn tx_mut(&mut self) -> &mut W {
        &mut self.tx
    }
}

impl<W: embedded_io::ErrorType> embedded_io::ErrorType for RingSerial<'_, W> {
    type Error = W::Error;
}

impl<W: embedded_io::ErrorType> embedded_io::ReadReady for RingSerial<'_, W> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.rx.is_empty())
    }
}

impl<W: embedded_io::ErrorType> embedded_io::Read for RingSerial<'_, W> {
    /// Blocks (spins) for the first byte, as embedded-io asks; then takes what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        let mut n = 0;
        while n == 0 {
            while n < buf.len() {
                match self.rx.dequeue() {
                    Some(b) => {
                        buf[n] = b;
                        n += 1;
                    }
                    None => break,
                }
            }
            if n == 0 {
                core::hint::spin_loop();
            }
        }
        Ok(n)
    }
}

impl<W: embedded_io::Write> embedded_io::Write for RingSerial<'_, W> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.tx.write(buf)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.tx.flush()
    }
}
