//! The navigation computer: STM32H743 (Nucleo-H743ZI pin-out), on the embassy-stm32 HAL's
//! blocking drivers (no register addresses here).
//!
//! - Clock: HSI 64 MHz for the core and all buses, no PLL (an EKF update is ~20 500 instructions,
//!   `.ci/qemu.sh`, once per 60-s period). SPI1's kernel clock: per_ck = HSI.
//! - Link: USART3 on PD8 (TX) / PD9 (RX), 115 200 Bd, 8N1 (the Nucleo's ST-LINK virtual COM
//!   port), embassy's interrupt-driven `BufferedUart`: the receive interrupt fills a
//!   [`RX_RING_BYTES`] ring (2.8 s of input), so a flash erase or a filter step loses no byte.
//! - Accelerometer: ADXL355 on SPI1, PA5 SCK / PA6 MISO / PA7 MOSI, chip select PD14, mode 0,
//!   4 MHz, through embedded-hal-bus's `ExclusiveDevice`.
//! - Sample timer: SysTick at 1 kHz; ticks for timing filter updates: DWT CYCCNT at 64 MHz.
//! - Shutdown: system reset. Fatal errors: a fault frame on the link, then halt (a watchdog,
//!   when fitted, resets; the run resumes from the checkpoint).
//! - Checkpoints: the last two 128-KiB sectors of flash bank 2 (0x081C_0000 to 0x081F_FFFF),
//!   kept out of the program's FLASH region by `memory.x`, through embassy's blocking flash
//!   driver in 32-byte flash words. Bank 2 is erased while the code runs from bank 1
//!   (read-while-write), so interrupts — the UART's — keep running during the erase.
//!
//! Not yet run on hardware: built and size-checked in CI only (see the README).

use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use embassy_stm32::flash::{Blocking, Flash as HalFlash};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::mode::Blocking as BlockingMode;
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::{bind_interrupts, peripherals};
use embedded_hal_bus::spi::ExclusiveDevice;
use embedded_storage::nor_flash::{ErrorType as FlashErrorType, NorFlash, ReadNorFlash};
use firmware_app::adxl355::{self, Adxl355};
use firmware_app::app::{App, Platform, SampleTimer, Tick};
use firmware_app::serial::RX_RING_BYTES;
use firmware_app::{AccelSample, Accelerometer};
use protocol::{Board, Detail, Fault, FaultCode};

const CORE_HZ: u32 = 64_000_000;
const BAUD: u32 = 115_200;

/// Start of RAM (memory.x: AXI SRAM): the bottom of the stack under flip-link.
pub const RAM_ORIGIN: usize = 0x2400_0000;

bind_interrupts!(struct Irqs {
    USART3 => usart::BufferedInterruptHandler<peripherals::USART3>;
});

/// The link: USART3 with interrupt-driven receive and transmit rings.
pub type Serial = BufferedUart<'static>;

/// The ADXL355's SPI device: SPI1 with the PD14 chip select.
type SpiDev =
    ExclusiveDevice<Spi<'static, BlockingMode, spi::mode::Master>, Output<'static>, Delay>;

/// Busy-wait delay on the core clock.
pub struct Delay;

impl embedded_hal::delay::DelayNs for Delay {
    fn delay_ns(&mut self, ns: u32) {
        // 64 cycles per µs, in 32-bit arithmetic (a 64-bit division costs ~1 KB of flash).
        const PER_US: u32 = CORE_HZ / 1_000_000;
        cortex_m::asm::delay(ns / 1000 * PER_US + ns % 1000 * PER_US / 1000 + 1);
    }
}

static MILLIS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

/// Fixed-rate sample timer on the 1-kHz SysTick.
pub struct MsTimer {
    start_ms: u32,
    rate_hz: f64,
    next: u32,
    running: bool,
}

impl SampleTimer for MsTimer {
    fn start(&mut self, rate_hz: f64) {
        self.start_ms = MILLIS.load(Ordering::Relaxed);
        self.rate_hz = rate_hz;
        self.next = 0;
        self.running = true;
    }
    fn stop(&mut self) {
        self.running = false;
    }
    fn poll(&mut self) -> Option<Tick> {
        if !self.running {
            return None;
        }
        let elapsed = MILLIS.load(Ordering::Relaxed).wrapping_sub(self.start_ms);
        let due = (f64::from(elapsed) * self.rate_hz / 1000.0) as u32;
        if due < self.next {
            return None;
        }
        let t = Tick {
            index: due,
            missed: due - self.next,
        };
        self.next = due + 1;
        Some(t)
    }
}

/// The accelerometer, if it passed its checks at boot.
pub struct Sensor(Option<Adxl355<SpiDev>>);

type SpiError = <SpiDev as embedded_hal::spi::ErrorType>::Error;

impl Accelerometer for Sensor {
    type Error = adxl355::Error<SpiError>;
    fn sample(&mut self, t_s: f64) -> Result<AccelSample, Self::Error> {
        match &mut self.0 {
            Some(d) => d.sample(t_s),
            None => Err(adxl355::Error::NotReady),
        }
    }
    fn present(&self) -> bool {
        self.0.is_some()
    }
}

/// Board services.
pub struct Stm32h743;

impl Platform for Stm32h743 {
    const BOARD: Board = Board::Stm32h743;
    fn ticks(&self) -> u32 {
        cortex_m::peripheral::DWT::cycle_count()
    }
    fn tick_hz(&self) -> u32 {
        CORE_HZ
    }
    fn stack_usage(&self) -> (u32, u32) {
        crate::memory::stack_usage()
    }
    fn static_ram(&self) -> u32 {
        crate::memory::static_ram()
    }
}

/// The application on this board.
pub type BoardApp = App<Serial, Sensor, MsTimer, Stm32h743, Flash>;

/// The board's parts for the application.
pub struct Parts {
    pub serial: Serial,
    pub accel: Sensor,
    pub timer: MsTimer,
    pub platform: Stm32h743,
    pub storage: Flash,
    pub boot_fault: Option<Fault>,
}

fn uart_config() -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = BAUD;
    c
}

/// Brings up clocks, link, sensor and timers.
#[inline(never)]
pub fn init() -> Parts {
    let mut config = embassy_stm32::Config::default();
    // HSI 64 MHz everywhere (the reset clock), and SPI1's kernel clock from per_ck = HSI.
    config.rcc.mux.persel = embassy_stm32::rcc::mux::Persel::HSI;
    config.rcc.mux.spi123sel = embassy_stm32::rcc::mux::Saisel::PER;
    let p = embassy_stm32::init(config);

    // Not `expect`: its message is formatted through `Display` (the panic handler prints the
    // location only); `panic!` with a literal links no formatting code.
    let mut cp =
        cortex_m::Peripherals::take().unwrap_or_else(|| panic!("core peripherals taken once"));
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(CORE_HZ / 1000 - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();

    static mut TX_BUF: [u8; 1024] = [0; 1024];
    static mut RX_BUF: [u8; RX_RING_BYTES] = [0; RX_RING_BYTES];
    // SAFETY: init runs once; these are the only references to the two buffers.
    let (tx_buf, rx_buf) = unsafe { (&mut *addr_of_mut!(TX_BUF), &mut *addr_of_mut!(RX_BUF)) };
    // Not `expect`: that would link the error's `Debug` (the panic handler prints no message).
    let serial = BufferedUart::new(p.USART3, p.PD9, p.PD8, tx_buf, rx_buf, Irqs, uart_config())
        .unwrap_or_else(|_| panic!("USART3 configuration"));

    let mut spi_config = spi::Config::default();
    spi_config.frequency = Hertz(4_000_000);
    let spi = Spi::new_blocking(p.SPI1, p.PA5, p.PA7, p.PA6, spi_config);
    let cs = Output::new(p.PD14, Level::High, Speed::VeryHigh);
    let (accel, boot_fault) = match ExclusiveDevice::new(spi, cs, Delay) {
        Ok(dev) => {
            let mut dev = Adxl355::new(dev);
            match dev.init(&adxl355::Config::default(), &mut Delay) {
                Ok(()) => (Sensor(Some(dev)), None),
                Err(e) => {
                    let code = match e {
                        adxl355::Error::BadId(_) => FaultCode::SensorId,
                        adxl355::Error::SelfTest { .. } => FaultCode::SensorSelfTest,
                        _ => FaultCode::SensorRead,
                    };
                    let mut m = Detail::from("ADXL355: ");
                    describe_sensor_error(&e, &mut m);
                    let fault = Fault::with_detail(code, 0, m);
                    (Sensor(None), Some(fault))
                }
            }
        }
        Err(_) => (
            Sensor(None),
            Some(Fault::with_detail(
                FaultCode::SensorRead,
                0,
                Detail::from("ADXL355: chip select"),
            )),
        ),
    };
    let timer = MsTimer {
        start_ms: 0,
        rate_hz: 1.0,
        next: 0,
        running: false,
    };
    Parts {
        serial,
        accel,
        timer,
        platform: Stm32h743,
        storage: Flash(HalFlash::new_blocking(p.FLASH)),
        boot_fault,
    }
}

/// A sensor error's text for the boot fault, without `core::fmt` (its float formatting alone
/// is ~15 KB): the self-test response in milli-g.
fn describe_sensor_error(e: &adxl355::Error<SpiError>, m: &mut Detail) {
    match e {
        adxl355::Error::Spi(_) => m.text("SPI error"),
        adxl355::Error::BadId(id) => m
            .text("bad id ")
            .hex(id[0].into(), 2)
            .text(" ")
            .hex(id[1].into(), 2)
            .text(" ")
            .hex(id[2].into(), 2),
        adxl355::Error::SelfTest { axis, response_g } => m
            .text("self-test axis ")
            .dec(u32::from(*axis))
            .text(": response ")
            .signed((response_g * 1e3) as i32)
            .text(" mg out of limits"),
        adxl355::Error::NotReady => m.text("no new data"),
    };
}

/// The host asked to end: reset.
pub fn shutdown() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

/// Reports a fatal error on the link (a fault frame, through a blocking transmitter taken over
/// from the application) and halts.
pub fn fatal(code: FaultCode, detail: Detail) -> ! {
    let fault = Fault::with_detail(code, 0, detail);
    let mut buf = [0u8; protocol::MAX_FRAME];
    if let Ok(f) = protocol::encode(
        &protocol::Packet::new(u32::MAX, protocol::Message::Fault(fault)),
        &mut buf,
    ) {
        // SAFETY: we are going down with interrupts off; the application no longer runs, so
        // nothing else uses USART3 or its TX pin.
        let (usart, tx) = unsafe { (peripherals::USART3::steal(), peripherals::PD8::steal()) };
        if let Ok(mut tx) = usart::UartTx::new_blocking(usart, tx, uart_config()) {
            let _ = tx.blocking_write(f);
            let _ = tx.blocking_flush();
        }
    }
    loop {
        cortex_m::asm::wfi();
    }
}

// ---------------------------------------------------------------------------------------------
// Checkpoint flash: bank 2, sectors 6 and 7.

/// Offset of the checkpoint region from the start of flash (bank 2, sector 6).
const CKPT_OFFSET: u32 = 0x1C_0000;
const SECTOR_SIZE: usize = 128 * 1024;

/// The checkpoint region of the internal flash as a NOR flash (offsets from 0x081C_0000), over
/// embassy's blocking driver (its unlocked erase and write: interrupts stay enabled).
pub struct Flash(HalFlash<'static, Blocking>);

/// Flash errors: embassy's, or an access outside the checkpoint region.
pub type FlashError = embassy_stm32::flash::Error;

impl Flash {
    fn check(from: u32, len: usize) -> Result<u32, FlashError> {
        if from as usize + len > 2 * SECTOR_SIZE {
            return Err(FlashError::Size);
        }
        Ok(CKPT_OFFSET + from)
    }
}

impl FlashErrorType for Flash {
    type Error = FlashError;
}

impl ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let at = Self::check(offset, bytes.len())?;
        self.0.blocking_read(at, bytes)
    }
    fn capacity(&self) -> usize {
        2 * SECTOR_SIZE
    }
}

impl NorFlash for Flash {
    const WRITE_SIZE: usize = 32;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if to < from {
            return Err(FlashError::Size);
        }
        let a = Self::check(from, (to - from) as usize)?;
        self.0.blocking_erase(a, a + (to - from))
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let at = Self::check(offset, bytes.len())?;
        self.0.blocking_write(at, bytes)
    }
}
