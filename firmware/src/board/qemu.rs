//! QEMU `mps2-an500` board: Cortex-M7 with double-precision FPU, code at 0x0, RAM at
//! 0x2000_0000, CMSDK APB UART0 at 0x4000_4000 (QEMU's first `-serial`). Reception as on the
//! real board: UART0's receive interrupt (IRQ 0) moves each byte into the receive ring
//! ([`firmware_app::serial::RxQueue`]) the application reads. No accelerometer:
//! samples come over the link (HIL replay). SysTick runs free on the core clock as the tick
//! counter for timing filter updates; with `-icount shift=0` one instruction is one virtual
//! nanosecond, so ticks convert exactly to instructions. Semihosting ends the run with an exit
//! code (`-semihosting-config enable=on,target=native`).
//!
//! Checkpoint storage: 8 KiB of the ZBT SSRAM at 0x2010_0000, outside the linked RAM (which
//! ends at 0x2008_0000), used as a NOR flash of two 4-KiB sectors. QEMU keeps RAM contents across
//! a `system_reset` (only the ELF's load segments are reloaded, and the firmware initialises only
//! its own .data/.bss), so it plays the part of the real board's flash in the reset tests.

use core::cell::RefCell;
use core::ptr::{addr_of_mut, read_volatile, write_volatile};

// The STM32 board's HAL is a dependency of every build (Cargo has no "unless feature"), and its
// PAC turns on cortex-m-rt's device vector table: link it so that table exists. Its handlers
// all default to DefaultHandler below, which serves UART0's receive interrupt (IRQ 0). Nothing
// else of embassy runs on this board.
use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32 as _;

use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use cortex_m_semihosting::{debug, hprintln};
use firmware_app::app::{App, NoTimer, Platform};
use firmware_app::checkpoints::RamFlash;
use firmware_app::cmsdk_uart::{self, Regs, STATE, STATE_TX_FULL};
use firmware_app::serial::{RingSerial, RxProducer, RxQueue};
use firmware_app::NoSensor;
use protocol::{Board, Detail, Fault, FaultCode};

/// Start of RAM (memory-qemu.x): the bottom of the stack under flip-link.
pub const RAM_ORIGIN: usize = 0x2000_0000;

/// QEMU's mps2 system clock, which clocks SysTick (CLKSOURCE = core).
pub const SYSCLK_HZ: u32 = 25_000_000;

const UART0: usize = 0x4000_4000;
/// UART0's baud-rate divider (QEMU ignores the rate; it must be >= 16 to enable the UART).
const BAUDDIV: u32 = 16;

/// UART0's receive interrupt on mps2-an500 (QEMU `hw/arm/mps2.c`: RX IRQ 0, TX IRQ 1).
#[derive(Clone, Copy)]
struct Uart0Rx;
// SAFETY: 0 is UART0's RX interrupt line on this machine.
unsafe impl cortex_m::interrupt::InterruptNumber for Uart0Rx {
    fn number(self) -> u16 {
        0
    }
}

/// What UART0's receive interrupt fills and the application reads; split once, by [`init`].
static mut RX_QUEUE: RxQueue = RxQueue::new();

/// The ring's producer end, for UART0's receive interrupt: [`init`] puts it here before it
/// unmasks the interrupt.
static RX: Mutex<RefCell<Option<RxProducer<'static>>>> = Mutex::new(RefCell::new(None));

/// Every interrupt without its own handler lands here (cortex-m-rt, no device crate): UART0
/// receive drains the UART into [`RX`]; anything else is a fault.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    if irqn == 0 {
        cortex_m::interrupt::free(|cs| match RX.borrow(cs).borrow_mut().as_mut() {
            // UART0's registers; the main loop only transmits (TX registers).
            Some(rx) => cmsdk_uart::on_rx_interrupt(&mut Mmio(UART0), rx),
            None => fatal(
                FaultCode::HardFault,
                Detail::from("UART0 receive before init"),
            ),
        });
    } else {
        let mut m = Detail::from("unexpected interrupt ");
        m.signed(irqn.into());
        fatal(FaultCode::HardFault, m);
    }
}

/// A CMSDK APB UART's registers at `.0`, by volatile access.
struct Mmio(usize);

impl Regs for Mmio {
    fn read(&mut self, offset: usize) -> u32 {
        // SAFETY: a register of the UART at `self.0` (UART0: the only one this board uses).
        unsafe { read_volatile((self.0 + offset) as *const u32) }
    }
    fn write(&mut self, offset: usize, value: u32) {
        // SAFETY: as in `read`.
        unsafe { write_volatile((self.0 + offset) as *mut u32, value) }
    }
}

/// The CMSDK APB UART's transmitter as an embedded-io port.
pub struct Uart {
    regs: Mmio,
}

impl Uart {
    /// Enables the transmitter only ([`cmsdk_uart::init_tx`]); [`init`] enables reception.
    ///
    /// # Safety
    /// One instance per UART.
    unsafe fn new(base: usize) -> Self {
        let mut regs = Mmio(base);
        cmsdk_uart::init_tx(&mut regs, BAUDDIV);
        Uart { regs }
    }
    fn state(&mut self) -> u32 {
        self.regs.read(STATE)
    }
    fn put(&mut self, b: u8) {
        while self.state() & STATE_TX_FULL != 0 {}
        self.regs.write(cmsdk_uart::DATA, u32::from(b));
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            self.put(b);
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        while self.state() & STATE_TX_FULL != 0 {}
        Ok(())
    }
}

static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

fn start_systick(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    // The counter reads 0 until its first reload: wait for it, so ticks() is monotonic from here.
    while SYST::get_current() == 0 {}
}

/// Free-running 32-bit tick count (SysTick's 24 bits extended by its wrap interrupt).
pub fn ticks() -> u32 {
    loop {
        let w = WRAPS.load(Ordering::Relaxed);
        let cvr = SYST::get_current();
        if WRAPS.load(Ordering::Relaxed) == w {
            return (w << 24) | (0x00FF_FFFF - cvr);
        }
    }
}

/// Board services.
pub struct Qemu;

impl Platform for Qemu {
    const BOARD: Board = Board::QemuMps2An500;
    fn ticks(&self) -> u32 {
        ticks()
    }
    fn tick_hz(&self) -> u32 {
        SYSCLK_HZ
    }
    fn stack_usage(&self) -> (u32, u32) {
        crate::memory::stack_usage()
    }
    fn static_ram(&self) -> u32 {
        crate::memory::static_ram()
    }
}

/// Checkpoint storage: RAM that survives a QEMU reset, as NOR flash with 4-KiB sectors.
pub type Storage = RamFlash<'static, 4096>;
const STORAGE_BASE: usize = 0x2010_0000;
const STORAGE_LEN: usize = 2 * 4096;

/// The checkpoint storage (call once: the only reference to the region).
fn init_storage() -> Storage {
    // SAFETY: the region is RAM on mps2-an500, outside every linker section, and only this
    // slice refers to it (init or the self-test runs once).
    RamFlash::new(unsafe { core::slice::from_raw_parts_mut(STORAGE_BASE as *mut u8, STORAGE_LEN) })
}

/// The application on this board.
pub type BoardApp = App<Serial, NoSensor, NoTimer, Qemu, Storage>;

/// The link: the receive ring (UART0's interrupt) and UART0's transmitter.
pub type Serial = RingSerial<'static, Uart>;

/// The board's parts for the application.
pub struct Parts {
    pub serial: Serial,
    pub accel: NoSensor,
    pub timer: NoTimer,
    pub platform: Qemu,
    pub storage: Storage,
    pub boot_fault: Option<Fault>,
}

/// Brings up the board.
pub fn init() -> Parts {
    let cp = cortex_m::Peripherals::take().expect("peripherals taken once");
    start_systick(cp.SYST);
    // SAFETY: the only UART0 instance.
    let uart = unsafe { Uart::new(UART0) };
    // SAFETY: init runs once (the peripherals are taken above, or it panics), so this is the
    // only reference to RX_QUEUE there will be; its two ends are all that is used from here on.
    let (rx, rx_loop) = unsafe { (*addr_of_mut!(RX_QUEUE)).split() };
    cortex_m::interrupt::free(|cs| RX.borrow(cs).replace(Some(RxProducer::new(rx))));
    // Reception by interrupt from here on: the receiver and its interrupt in one write (a byte
    // arriving between two writes would wedge QEMU's UART: firmware_app::cmsdk_uart), then the
    // NVIC line (a byte already received has latched it pending).
    cmsdk_uart::enable_rx(&mut Mmio(UART0));
    // SAFETY: UART0's receive interrupt; its handler is DefaultHandler above.
    unsafe { cortex_m::peripheral::NVIC::unmask(Uart0Rx) };
    Parts {
        serial: RingSerial::new(rx_loop, uart),
        accel: NoSensor,
        timer: NoTimer,
        platform: Qemu,
        storage: init_storage(),
        boot_fault: None,
    }
}

/// Ends the run with success (the host asked).
pub fn shutdown() -> ! {
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}

/// Reports a fatal error on the semihosting console and the link, then exits with failure.
pub fn fatal(code: FaultCode, detail: Detail) -> ! {
    hprintln!("firmware fatal {:?}: {}", code, detail.as_str());
    // SAFETY: we are going down; the main loop no longer runs.
    let mut uart = unsafe { Uart::new(UART0) };
    let fault = Fault::with_detail(code, 0, detail);
    let mut buf = [0u8; protocol::MAX_FRAME];
    if let Ok(f) = protocol::encode(
        &protocol::Packet::new(u32::MAX, protocol::Message::Fault(fault)),
        &mut buf,
    ) {
        let _ = embedded_io::Write::write_all(&mut uart, f);
    }
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// Self-test (`--features selftest`): calibrates ticks against a loop of known instruction
/// count, times EKF updates of the paper's model on synthetic 1-Hz samples, prints the figures
/// and exits. Run under `-icount shift=0` for exact instruction counts.
#[cfg(feature = "selftest")]
pub fn selftest() -> ! {
    use estimator_core::{Averager, Sample};
    let cp = cortex_m::Peripherals::take().expect("peripherals taken once");
    start_systick(cp.SYST);
    // 2 instructions per iteration: subs + bne.
    const ITER: u32 = 1_000_000;
    let t0 = ticks();
    // SAFETY: a pure register loop.
    unsafe {
        core::arch::asm!("1:", "subs {0}, {0}, #1", "bne 1b", inout(reg) ITER => _, options(nomem, nostack));
    }
    let cal = ticks().wrapping_sub(t0);
    let instr_per_tick = f64::from(2 * ITER) / f64::from(cal.max(1));
    let cfg = protocol::Config::default();
    let ekf = static_filter(&cfg, false);
    let mut avg = Averager::new(cfg.filter_period_s, cfg.raw_sigma_mps2);
    let g = 9.800_898;
    let (mut n, mut sum, mut min, mut max) = (0u32, 0u64, u32::MAX, 0u32);
    for k in 0..(60 * 40 + 1) {
        let t = f64::from(k);
        let a = 7.29e-5 * 0.6 * t;
        let s = Sample {
            t_s: t,
            specific_force: [g * 0.05 * libm_sin(a), 1e-4 * t * 1e-3, g],
            temp_c: f64::NAN,
        };
        if let Some(m) = avg.push(&s) {
            let t0 = ticks();
            firmware_app::app::filter_step(ekf, &m).expect("filter step");
            let dt = ticks().wrapping_sub(t0);
            if n > 0 {
                // the first update has no prediction
                sum += u64::from(dt);
                min = min.min(dt);
                max = max.max(dt);
            }
            n += 1;
        }
    }
    // The checkpoint path the link loop runs (its deepest stack): encode the resume block and
    // the filter image, append it to the log in the board's storage, load it back, restore.
    let storage = init_storage();
    let ckpt = checkpoint_round_trip(ekf, storage);
    hprintln!("checkpoint round trip: {}", ckpt);
    let steps = n - 1;
    let mean = sum as f64 / f64::from(steps);
    let (used, size) = crate::memory::stack_usage();
    hprintln!("selftest: {} EKF updates of the 15-state model", steps);
    hprintln!(
        "calibration: {} ticks for {} instructions = {:.3} instructions/tick",
        cal,
        2 * ITER,
        instr_per_tick
    );
    hprintln!(
        "ticks per update: mean {:.0}, min {}, max {}; instructions per update: mean {:.0} (min {:.0}, max {:.0})",
        mean,
        min,
        max,
        mean * instr_per_tick,
        f64::from(min) * instr_per_tick,
        f64::from(max) * instr_per_tick
    );
    hprintln!(
        "stack high-water {} of {} bytes; static RAM {} bytes",
        used,
        size,
        crate::memory::static_ram()
    );
    hprintln!(
        "final state D(X)_0 = {} deg/h (1 sigma {})",
        ekf.state()[3],
        ekf.sigma(3)
    );
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}

/// Saves `ekf` as a checkpoint into `storage` and restores it: "ok" or what failed.
#[cfg(feature = "selftest")]
#[inline(never)]
fn checkpoint_round_trip(ekf: &firmware_app::app::Filter, storage: Storage) -> &'static str {
    use firmware_app::checkpoints::{CheckpointStore, MAX_PAYLOAD};
    use firmware_app::resume;
    use firmware_app::screen::Screen;
    let Ok(mut store) = CheckpointStore::new(storage) else {
        return "storage geometry refused";
    };
    // The application keeps its checkpoint buffer and screening in its state (a static), not on
    // the stack: so does the self-test.
    let Some(buf) = cortex_m::singleton!(: [u8; MAX_PAYLOAD] = [0; MAX_PAYLOAD]) else {
        return "buffer taken";
    };
    let cfg = protocol::Config::default();
    let Some(screen) = cortex_m::singleton!(: Screen = Screen::new(&cfg, None)) else {
        return "screening taken";
    };
    let point = resume::ResumePoint {
        next_seq: 0,
        last_t_s: None,
    };
    let Ok(n) = resume::encode_run(buf, protocol::Source::Replay, point, &cfg, screen, ekf) else {
        return "encode failed";
    };
    if store.save(&buf[..n]).is_err() {
        return "save failed";
    }
    match store.load(buf) {
        // As the application restores: decode, a fresh filter, its image loaded in place.
        Ok(Some(f)) => match resume::decode(&buf[..f.len]) {
            Ok(Some(b)) if screen.load(b.screen_state).is_none() => "screening state refused",
            Ok(Some(b)) => {
                let restored = static_filter(&b.config, true);
                match resume::load_filter(restored, b.image) {
                    Ok(()) if restored.state() == ekf.state() => "ok",
                    _ => "restore failed",
                }
            }
            _ => "decode failed",
        },
        _ => "load failed",
    }
}

/// A filter of `cfg` in a static, as the application keeps its filter (in its state, a
/// static): the self-test's stack high-water is then the EKF's and the checkpoint path's, not
/// copies of the filter. Its own frame holds the new filter until it is moved in.
#[cfg(feature = "selftest")]
#[inline(never)]
fn static_filter(cfg: &protocol::Config, second: bool) -> &'static mut firmware_app::app::Filter {
    use firmware_app::app::Filter;
    let f = firmware_app::app::filter_for(cfg).expect("default config");
    let cell = if second {
        cortex_m::singleton!(: Filter = f)
    } else {
        cortex_m::singleton!(: Filter = f)
    };
    cell.expect("each filter made once")
}

#[cfg(feature = "selftest")]
fn libm_sin(x: f64) -> f64 {
    // Small-angle series is plenty for a synthetic input.
    x - x * x * x / 6.0 + x * x * x * x * x / 120.0
}
