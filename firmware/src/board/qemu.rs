//! QEMU `mps2-an500` board: Cortex-M7 with double-precision FPU, code at 0x0, RAM at
//! 0x2000_0000, CMSDK APB UART0 at 0x4000_4000 (QEMU's first `-serial`). No accelerometer:
//! samples come over the link (HIL replay). SysTick runs free on the core clock as the tick
//! counter for timing filter updates; with `-icount shift=0` one instruction is one virtual
//! nanosecond, so ticks convert exactly to instructions. Semihosting ends the run with an exit
//! code (`-semihosting-config enable=on,target=native`).
//!
//! Checkpoint storage: 8 KiB of the ZBT SSRAM at 0x2010_0000, outside the linked RAM (which
//! ends at 0x2008_0000), used as a NOR flash of two 4-KiB sectors. QEMU keeps RAM contents across
//! a `system_reset` (only the ELF's load segments are reloaded, and the firmware initialises only
//! its own .data/.bss), so it plays the part of the real board's flash in the reset tests.

use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use cortex_m_semihosting::{debug, hprintln};
use firmware_app::app::{App, NoTimer, Platform};
use firmware_app::checkpoints::RamFlash;
use firmware_app::NoSensor;
use protocol::{Board, Fault, FaultCode};

/// QEMU's mps2 system clock, which clocks SysTick (CLKSOURCE = core).
pub const SYSCLK_HZ: u32 = 25_000_000;

const UART0: usize = 0x4000_4000;
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;

/// The CMSDK APB UART as an embedded-io port.
pub struct Uart {
    base: usize,
}

impl Uart {
    /// # Safety
    /// One instance per UART.
    unsafe fn new(base: usize) -> Self {
        write_volatile((base + BAUDDIV) as *mut u32, 16);
        write_volatile((base + CTRL) as *mut u32, 0b11); // TX and RX enable
        Uart { base }
    }
    fn state(&self) -> u32 {
        // SAFETY: MMIO register of our UART.
        unsafe { read_volatile((self.base + STATE) as *const u32) }
    }
    fn put(&mut self, b: u8) {
        while self.state() & STATE_TX_FULL != 0 {}
        // SAFETY: MMIO register of our UART.
        unsafe { write_volatile((self.base + DATA) as *mut u32, u32::from(b)) }
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

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.state() & STATE_RX_FULL != 0)
    }
}

impl embedded_io::Read for Uart {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let mut n = 0;
        if buf.is_empty() {
            return Ok(0);
        }
        // Blocking for the first byte, as embedded-io asks; then whatever is there.
        while self.state() & STATE_RX_FULL == 0 {}
        while n < buf.len() && self.state() & STATE_RX_FULL != 0 {
            // SAFETY: MMIO register of our UART.
            buf[n] = unsafe { read_volatile((self.base + DATA) as *const u32) } as u8;
            n += 1;
        }
        Ok(n)
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

/// The application on this board.
pub type BoardApp = App<Uart, NoSensor, NoTimer, Qemu, Storage>;

/// The board's parts for the application.
pub struct Parts {
    pub serial: Uart,
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
    let serial = unsafe { Uart::new(UART0) };
    Parts {
        serial,
        accel: NoSensor,
        timer: NoTimer,
        platform: Qemu,
        // SAFETY: the region is RAM on mps2-an500, outside every linker section, and only this
        // slice refers to it (init runs once).
        storage: RamFlash::new(unsafe {
            core::slice::from_raw_parts_mut(STORAGE_BASE as *mut u8, STORAGE_LEN)
        }),
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
pub fn fatal(code: FaultCode, detail: core::fmt::Arguments<'_>) -> ! {
    hprintln!("firmware fatal {:?}: {}", code, detail);
    // SAFETY: we are going down; the main loop no longer runs.
    let mut uart = unsafe { Uart::new(UART0) };
    let fault = Fault::new(code, 0, detail);
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
    use firmware_app::app::filter_for;
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
    let mut ekf = filter_for(&cfg).expect("default config");
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
            ekf.step(&m).expect("filter step");
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

#[cfg(feature = "selftest")]
fn libm_sin(x: f64) -> f64 {
    // Small-angle series is plenty for a synthetic input.
    x - x * x * x / 6.0 + x * x * x * x * x / 120.0
}
