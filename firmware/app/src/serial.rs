//! Serial reception that drops nothing: the UART's receive interrupt moves every byte from the
//! hardware FIFO into an [`RxRing`], and the application reads from the ring. A flash erase (up
//! to 2.2 s on the STM32H743 at x32 parallelism, datasheet maximum) or a filter step blocks the
//! loop, not the interrupt, so the 16-byte FIFO never overruns; the ring holds what arrives
//! meanwhile: [`RX_RING_BYTES`] at 115 200 Bd (11 520 bytes/s) is 2.8 s of continuous input.
//! What the ring could not take is counted ([`RxRing::dropped`]), never silent.
//!
//! `tests/uart_overrun.rs` proves it on the host: the application over a simulated UART with a
//! 16-byte FIFO at 115 200 Bd, realistic erase and step durations, polled (bytes lost) and
//! through the ring (none lost, estimates bit-identical to the host).

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

/// Receive ring size of the boards, bytes (2.8 s of continuous input at 115 200 Bd).
pub const RX_RING_BYTES: usize = 32 * 1024;

/// A single-producer (the receive interrupt), single-consumer (the main loop) byte ring.
///
/// `push` may only be called from one context at a time (the UART's interrupt handler), `pop`
/// from one other (the loop); the indices are atomics with acquire/release ordering, so the
/// two never touch the same slot: the producer writes only free slots, the consumer reads only
/// filled ones.
pub struct RxRing<const N: usize> {
    buf: UnsafeCell<[u8; N]>,
    /// Total bytes pushed (wrapping); the producer's index is `head % N`.
    head: AtomicUsize,
    /// Total bytes popped (wrapping).
    tail: AtomicUsize,
    dropped: AtomicU32,
}

// SAFETY: the producer and the consumer touch disjoint slots, ordered by the atomic indices
// (see the type's documentation); the bytes themselves are plain data.
unsafe impl<const N: usize> Sync for RxRing<N> {}

impl<const N: usize> Default for RxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RxRing<N> {
    /// An empty ring (usable in a `static`).
    pub const fn new() -> Self {
        RxRing {
            buf: UnsafeCell::new([0; N]),
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            dropped: AtomicU32::new(0),
        }
    }

    /// Bytes waiting.
    pub fn len(&self) -> usize {
        self.head
            .load(Ordering::Acquire)
            .wrapping_sub(self.tail.load(Ordering::Acquire))
    }

    /// Whether no byte is waiting.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Producer (the receive interrupt): stores `b`; when the ring is full the byte is dropped
    /// and counted, and `false` returned.
    pub fn push(&self, b: u8) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        let tail = self.tail.load(Ordering::Acquire);
        if head.wrapping_sub(tail) >= N {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        // SAFETY: slot `head % N` is free (not yet published to the consumer), and only the
        // producer writes.
        unsafe { (*self.buf.get())[head % N] = b };
        self.head.store(head.wrapping_add(1), Ordering::Release);
        true
    }

    /// Consumer (the loop): the oldest byte, if any.
    pub fn pop(&self) -> Option<u8> {
        let tail = self.tail.load(Ordering::Relaxed);
        let head = self.head.load(Ordering::Acquire);
        if head == tail {
            return None;
        }
        // SAFETY: slot `tail % N` was published by the producer (head > tail) and is not
        // reused until the tail moves past it below.
        let b = unsafe { (*self.buf.get())[tail % N] };
        self.tail.store(tail.wrapping_add(1), Ordering::Release);
        Some(b)
    }

    /// Bytes the ring had no room for.
    pub fn dropped(&self) -> u32 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// A serial port for the application: reads from an [`RxRing`] filled by the receive
/// interrupt, writes through the board's transmitter `W`.
pub struct RingSerial<'a, W, const N: usize> {
    rx: &'a RxRing<N>,
    tx: W,
}

impl<'a, W, const N: usize> RingSerial<'a, W, N> {
    /// The port over `rx` (filled by the interrupt) and `tx`.
    pub fn new(rx: &'a RxRing<N>, tx: W) -> Self {
        RingSerial { rx, tx }
    }

    /// The transmitter.
    pub fn tx_mut(&mut self) -> &mut W {
        &mut self.tx
    }

    /// The receive ring.
    pub fn rx(&self) -> &RxRing<N> {
        self.rx
    }
}

impl<W: embedded_io::ErrorType, const N: usize> embedded_io::ErrorType for RingSerial<'_, W, N> {
    type Error = W::Error;
}

impl<W: embedded_io::ErrorType, const N: usize> embedded_io::ReadReady for RingSerial<'_, W, N> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.rx.is_empty())
    }
}

impl<W: embedded_io::ErrorType, const N: usize> embedded_io::Read for RingSerial<'_, W, N> {
    /// Blocks (spins) for the first byte, as embedded-io asks; then takes what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        let mut n = 0;
        while n == 0 {
            while n < buf.len() {
                match self.rx.pop() {
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

impl<W: embedded_io::Write, const N: usize> embedded_io::Write for RingSerial<'_, W, N> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.tx.write(buf)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.tx.flush()
    }
}
