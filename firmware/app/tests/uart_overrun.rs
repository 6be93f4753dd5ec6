//! The UART that drops nothing: the application over a simulated UART with the STM32H743's
//! 16-byte receive FIFO at 115 200 Bd, the host replaying a recording at full line rate, and
//! the firmware's blocking work taking simulated time: a flash sector erase 2.2 s (datasheet
//! maximum at x32 parallelism; typical 1.1 s), a 32-byte flash word 100 µs, an EKF step 2 ms
//! (~20 500 instructions, `.ci/qemu.sh`: 0.3 ms at 64 MHz and one per cycle; 2 ms is ample margin), and every byte the firmware sends its line
//! time (the transmitter is blocking).
//!
//! - Polled, as the old board read its UART: the FIFO overruns while the loop is blocked; bytes
//!   and frames are lost (the scenario is a real threat, the test can fail).
//! - Through the receive-interrupt ring of the boards ([`RxQueue`], [`RX_RING_BYTES`]): the
//!   interrupt empties the FIFO as bytes arrive, nothing is lost, and the firmware's estimates
//!   are bit-identical to the host's single pass.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::rc::Rc;

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use estimator_core::Sample;
use firmware_app::app::{App, NoTimer, Platform};
use firmware_app::checkpoints::{RamFlash, RamFlashError};
use firmware_app::serial::{RingSerial, RxProducer, RxQueue, RX_RING_BYTES};
use firmware_app::NoSensor;
use protocol::*;

/// 115 200 Bd, 8N1: 10 bits a byte.
const BYTE_S: f64 = 10.0 / 115_200.0;
/// The STM32H7 USART's receive FIFO.
const FIFO: usize = 16;
const ERASE_S: f64 = 2.2;
const WORD_S: f64 = 100e-6;
const STEP_S: f64 = 2e-3;
/// One pass of the idle loop.
const IDLE_S: f64 = 20e-6;
const H7_SECTOR: usize = 128 * 1024;

/// The line and the UART's receiver: host bytes arriving at line rate, the FIFO, and (when
/// interrupt-driven) the ring the receive interrupt fills.
struct Line {
    now: f64,
    /// Host bytes not yet arrived, and when the next one arrives.
    host: VecDeque<u8>,
    next_arrival: f64,
    fifo: VecDeque<u8>,
    /// Bytes lost because the FIFO was full (the USART's overrun).
    overruns: u64,
    ring: Option<RxProducer<'static>>,
    max_ring: usize,
    /// Bytes the firmware sent.
    tx: Vec<u8>,
    erases: u64,
}

type Shared = Rc<RefCell<Line>>;

impl Line {
    /// Lets `dt` seconds pass: bytes arrive; the receive interrupt (if any) moves each from the
    /// FIFO to the ring at once (its latency, ~1 µs, is far below a byte time of 87 µs).
    fn advance(&mut self, dt: f64) {
        self.now += dt;
        while !self.host.is_empty() && self.next_arrival <= self.now {
            let b = self.host.pop_front().unwrap_or(0);
            self.next_arrival += BYTE_S;
            if self.fifo.len() < FIFO {
                self.fifo.push_back(b);
            } else {
                self.overruns += 1;
            }
            if let Some(ring) = self.ring.as_mut() {
                while let Some(b) = self.fifo.pop_front() {
                    ring.push(b);
                }
                self.max_ring = self.max_ring.max(ring.len());
            }
        }
    }
}

/// The transmitter: blocking, each byte takes its line time.
struct Tx(Shared);
impl embedded_io::ErrorType for Tx {
    type Error = Infallible;
}
impl embedded_io::Write for Tx {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut l = self.0.borrow_mut();
        l.tx.extend_from_slice(buf);
        l.advance(buf.len() as f64 * BYTE_S);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// The old board's polled receiver: reads the FIFO only when the loop asks.
struct Polled(Shared, Tx);
impl embedded_io::ErrorType for Polled {
    type Error = Infallible;
}
impl embedded_io::ReadReady for Polled {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(!self.0.borrow().fifo.is_empty())
    }
}
impl embedded_io::Read for Polled {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let mut l = self.0.borrow_mut();
        let n = buf.len().min(l.fifo.len());
        for b in buf.iter_mut().take(n) {
            *b = l.fifo.pop_front().unwrap_or(0);
        }
        Ok(n)
    }
}
impl embedded_io::Write for Polled {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.1.write(buf)
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// The board: the filter step's duration passes between the loop's two tick reads around it.
struct Board(Shared);
impl Platform for Board {
    const BOARD: protocol::Board = protocol::Board::Host;
    fn ticks(&self) -> u32 {
        self.0.borrow_mut().advance(STEP_S / 2.0);
        0
    }
}

/// The STM32H743's checkpoint flash (two 128-KiB sectors, 32-byte words) with its timing.
struct Flash(Shared, RamFlash<'static, H7_SECTOR, 32>);
impl ErrorType for Flash {
    type Error = RamFlashError;
}
impl ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamFlashError> {
        self.1.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.1.capacity()
    }
}
impl NorFlash for Flash {
    const WRITE_SIZE: usize = 32;
    const ERASE_SIZE: usize = H7_SECTOR;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        let sectors = (to - from) as usize / H7_SECTOR;
        {
            let mut l = self.0.borrow_mut();
            l.erases += sectors as u64;
            l.advance(ERASE_S * sectors as f64);
        }
        self.1.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RamFlashError> {
        self.0
            .borrow_mut()
            .advance(WORD_S * (bytes.len() / 32) as f64);
        self.1.write(offset, bytes)
    }
}

fn config() -> Config {
    // The default 60-s windows of 1-Hz samples, but a checkpoint after every update: the 241
    // records of a 4-h replay (start marker + 240 updates) overflow two 102-record sectors, so
    // the log erases twice in the middle of the stream.
    Config {
        checkpoint_every: 1,
        ..Config::default()
    }
}

fn recording(n: usize) -> Vec<RawSample> {
    let g = 9.800898;
    let mut state = 7u64;
    (0..n)
        .map(|k| {
            let t = k as f64;
            let a = 7.29e-5 * t * 0.6;
            let mut noise = [0.0; 3];
            for v in &mut noise {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                *v = ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e-3;
            }
            RawSample {
                seq: k as u32,
                t_s: t,
                specific_force: [
                    g * 0.05 * a.sin() + noise[0],
                    g * 0.05 * (1.0 - a.cos()) + noise[1],
                    g + noise[2],
                ],
                temp_c: f64::NAN,
            }
        })
        .collect()
}

/// The host's whole replay as one byte stream, sent at full line rate from t = 0.
fn host_stream(samples: &[RawSample]) -> VecDeque<u8> {
    let mut enc = Encoder::new();
    let mut out = VecDeque::new();
    let mut send = |c: Command| out.extend(enc.frame(Message::Command(c)).unwrap().iter());
    send(Command::Configure(config()));
    send(Command::Start(Source::Replay));
    for s in samples {
        send(Command::Replay(*s));
    }
    send(Command::Finish);
    out
}

struct Outcome {
    estimates: Vec<Estimate>,
    counters: Counters,
    overruns: u64,
    ring_dropped: u32,
    max_ring: usize,
    erases: u64,
    line_s: f64,
}

/// Runs the replay through `App` with a polled or an interrupt-driven receiver.
fn run(samples: &[RawSample], interrupt: bool) -> Outcome {
    let queue: &'static mut RxQueue = Box::leak(Box::new(RxQueue::new()));
    let (producer, consumer) = queue.split();
    let host = host_stream(samples);
    let line_s = host.len() as f64 * BYTE_S;
    let line = Rc::new(RefCell::new(Line {
        now: 0.0,
        host,
        // The host starts once the firmware has announced itself (boot frames sent).
        next_arrival: 0.1,
        fifo: VecDeque::new(),
        overruns: 0,
        ring: interrupt.then(|| RxProducer::new(producer)),
        max_ring: 0,
        tx: Vec::new(),
        erases: 0,
    }));
    let mem: &'static mut [u8] = Box::leak(vec![0xFFu8; 2 * H7_SECTOR].into_boxed_slice());
    let flash = Flash(line.clone(), RamFlash::new(mem));
    let board = Board(line.clone());
    let counters = if interrupt {
        let serial = RingSerial::new(consumer, Tx(line.clone()));
        drive(
            App::with_storage(serial, NoSensor, NoTimer, board, flash),
            &line,
        )
    } else {
        let serial = Polled(line.clone(), Tx(line.clone()));
        drive(
            App::with_storage(serial, NoSensor, NoTimer, board, flash),
            &line,
        )
    };
    let l = line.borrow();
    let mut dec = Decoder::new();
    let mut estimates = Vec::new();
    dec.feed(&l.tx, |r| {
        if let Ok(Packet {
            msg: Message::Estimate(e),
            ..
        }) = r
        {
            estimates.push(e);
        }
    });
    Outcome {
        estimates,
        counters,
        overruns: l.overruns,
        ring_dropped: l.ring.as_ref().map_or(0, RxProducer::dropped),
        max_ring: l.max_ring,
        erases: l.erases,
        line_s,
    }
}

fn drive<S, F>(mut app: App<S, NoSensor, NoTimer, Board, F>, line: &Shared) -> Counters
where
    S: embedded_io::Read + embedded_io::ReadReady + embedded_io::Write,
    F: NorFlash,
{
    app.boot();
    // Until the host has sent everything and the firmware has read it all (ring and FIFO
    // empty), plus a second for the last frames.
    let mut quiet_since = None;
    loop {
        line.borrow_mut().advance(IDLE_S);
        app.poll();
        let l = line.borrow();
        let idle =
            l.host.is_empty() && l.fifo.is_empty() && l.ring.as_ref().is_none_or(|r| r.is_empty());
        if !idle {
            quiet_since = None;
        } else if quiet_since.is_none() {
            quiet_since = Some(l.now);
        } else if quiet_since.is_some_and(|t| l.now - t > 1.0) {
            break;
        }
    }
    *app.counters()
}

fn host_single_pass(samples: &[RawSample]) -> Vec<Estimate> {
    let mut out = Vec::new();
    let samples = samples.iter().map(|s| Sample {
        t_s: s.t_s,
        specific_force: s.specific_force,
        temp_c: s.temp_c,
    });
    firmware_app::app::single_pass(&config(), samples, |e| out.push(e)).unwrap();
    out
}

#[test]
fn the_receive_ring_loses_nothing_through_erases_and_steps() {
    let samples = recording(4 * 3600 + 1);
    let want = host_single_pass(&samples);
    assert_eq!(want.len(), 241); // 240 full windows + the flushed last sample
    let o = run(&samples, true);
    println!(
        "interrupt ring: {:.1} s of input, {} erases, ring high-water {} of {} bytes, FIFO overruns {}, ring drops {}",
        o.line_s, o.erases, o.max_ring, RX_RING_BYTES, o.overruns, o.ring_dropped
    );
    // 240 checkpoints of 1 920-byte records (the start marker, then one after each update but the
    // last, see below), 68 per sector: the log moves to the next sector three times, each an
    // erase of 2.2 s of blocked loop.
    assert_eq!(o.erases, 3);
    // Nothing lost at any stage: not in the FIFO, not in the ring, no frame damaged or missing.
    assert_eq!((o.overruns, o.ring_dropped), (0, 0));
    assert_eq!(
        (o.counters.frames_rx_bad, o.counters.frames_rx_missing),
        (0, 0)
    );
    // Configure, Start, 14 401 samples, Finish.
    assert_eq!(o.counters.frames_rx, 14_404);
    // An erase blocks the loop for 2.2 s: ~25 300 bytes arrive meanwhile, and the ring holds
    // them (it is sized for 2.8 s). The bound checks the erase really stalled the reader.
    assert!(
        o.max_ring > 20_000 && o.max_ring < RX_RING_BYTES,
        "{}",
        o.max_ring
    );
    // The start marker, a checkpoint after each of the 240 full windows' updates but the last
    // (that update comes when the last sample, which opens window 240, leaves the screening: at
    // the Finish, where no checkpoint is taken), and the end-of-run marker.
    assert_eq!(o.counters.checkpoints_written, 1 + 239 + 1);
    assert_eq!(o.estimates, want, "bit-identical to the host's single pass");
}

#[test]
fn a_polled_uart_overruns_in_the_same_scenario() {
    let samples = recording(4 * 3600 + 1);
    let o = run(&samples, false);
    println!(
        "polled: {:.1} s of input, {} erases, FIFO overruns {} bytes, frames bad {}, estimates {} of 241",
        o.line_s,
        o.erases,
        o.overruns,
        o.counters.frames_rx_bad,
        o.estimates.len()
    );
    // Whenever the loop blocks for more than 16 byte times (1.4 ms) the FIFO overruns: an erase
    // (2.2 s: ~25 000 bytes), a checkpoint write (41 words x 100 us = 4 ms), any frame the
    // firmware sends (a 100-byte fault or status frame: 9 ms). Every overrun damages the frame
    // it hits, and a lost command cascades (samples refused, each refusal answered by a fault
    // frame that blocks again). The bounds are far below what the run shows: the loss is
    // massive, not marginal.
    assert!(o.overruns > 10_000, "{}", o.overruns);
    assert!(
        o.counters.frames_rx_bad > 100,
        "{}",
        o.counters.frames_rx_bad
    );
    assert!(o.estimates.len() < 241, "{}", o.estimates.len());
}
