//! The navigation computer: STM32H743 (Nucleo-H743ZI pin-out), register-level, no PAC.
//!
//! - Clock: the reset default, HSI 64 MHz for the core and all buses (the EKF needs ~40 k
//!   instructions per 60-s update: no PLL needed).
//! - Link: USART3 on PD8 (TX) / PD9 (RX), AF7, 115 200 Bd, 8N1 (the Nucleo's ST-LINK virtual COM port).
//! - Accelerometer: ADXL355 on SPI1, PA5 SCK / PA6 MISO / PA7 MOSI (AF5), chip select PD14,
//!   mode 0, 4 MHz (per_ck = HSI 64 MHz / 16).
//! - Sample timer: SysTick at 1 kHz; ticks for timing filter updates: DWT CYCCNT at 64 MHz.
//! - Shutdown: system reset. Fatal errors: a fault frame on the link, then halt (a watchdog,
//!   when fitted, resets; issue 5 resumes from the checkpoint).
//!
//! - Checkpoints: the last two 128-KiB sectors of flash bank 2 (sectors 6 and 7, 0x081C_0000 to
//!   0x081F_FFFF), kept out of the program's FLASH region by `memory.x`; programmed through the
//!   bank-2 registers in 256-bit flash words ([`Flash`]).
//!
//! Not yet run on hardware: built and size-checked in CI only (see the README).

use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use embedded_hal::spi::{ErrorType, Operation, SpiDevice};
use embedded_storage::nor_flash::{
    ErrorType as FlashErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use firmware_app::adxl355::{self, Adxl355};
use firmware_app::app::{App, Platform, SampleTimer, Tick};
use firmware_app::{AccelSample, Accelerometer};
use protocol::{Board, Fault, FaultCode};

const CORE_HZ: u32 = 64_000_000;

/// Start of RAM (memory.x: AXI SRAM): the bottom of the stack under flip-link.
pub const RAM_ORIGIN: usize = 0x2400_0000;

// RCC
const RCC: usize = 0x5802_4400;
const RCC_D2CCIP1R: usize = RCC + 0x050;
const RCC_AHB4ENR: usize = RCC + 0x0E0;
const RCC_APB1LENR: usize = RCC + 0x0E8;
const RCC_APB2ENR: usize = RCC + 0x0F0;
// GPIO
const GPIOA: usize = 0x5802_0000;
const GPIOD: usize = 0x5802_0C00;
const MODER: usize = 0x00;
const OSPEEDR: usize = 0x08;
const BSRR: usize = 0x18;
const AFRL: usize = 0x20;
const AFRH: usize = 0x24;
// USART3
const USART3: usize = 0x4000_4800;
const U_CR1: usize = 0x00;
const U_BRR: usize = 0x0C;
const U_ISR: usize = 0x1C;
const U_ICR: usize = 0x20;
const U_RDR: usize = 0x24;
const U_TDR: usize = 0x28;
const ISR_RXNE: u32 = 1 << 5;
const ISR_TXE: u32 = 1 << 7;
const ISR_TC: u32 = 1 << 6;
const ISR_ORE: u32 = 1 << 3;
// SPI1
const SPI1: usize = 0x4001_3000;
const S_CR1: usize = 0x00;
const S_CFG1: usize = 0x08;
const S_CFG2: usize = 0x0C;
const S_SR: usize = 0x14;
const S_IFCR: usize = 0x18;
const S_TXDR: usize = 0x20;
const S_RXDR: usize = 0x30;
const SR_RXP: u32 = 1 << 0;
const SR_TXP: u32 = 1 << 1;
const SR_SUSP: u32 = 1 << 11;
const CS_PIN: u32 = 14;

fn rd(addr: usize) -> u32 {
    // SAFETY: addresses are this board's peripheral registers.
    unsafe { read_volatile(addr as *const u32) }
}
fn wr(addr: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(addr as *mut u32, v) }
}
fn modify(addr: usize, clear: u32, set: u32) {
    wr(addr, (rd(addr) & !clear) | set);
}

/// Pins `pins` of `port` to alternate function `af`, high speed.
fn alternate(port: usize, pins: &[u32], af: u32) {
    for &p in pins {
        modify(port + MODER, 0b11 << (2 * p), 0b10 << (2 * p));
        modify(port + OSPEEDR, 0b11 << (2 * p), 0b10 << (2 * p));
        let (reg, sh) = if p < 8 {
            (AFRL, 4 * p)
        } else {
            (AFRH, 4 * (p - 8))
        };
        modify(port + reg, 0xF << sh, af << sh);
    }
}

/// USART3 as an embedded-io port.
pub struct Usart3;

impl Usart3 {
    fn init() -> Self {
        modify(RCC_AHB4ENR, 0, 1 << 3); // GPIOD
        modify(RCC_APB1LENR, 0, 1 << 18); // USART3
        let _ = rd(RCC_APB1LENR);
        alternate(GPIOD, &[8, 9], 7);
        wr(USART3 + U_CR1, 0);
        wr(USART3 + U_BRR, CORE_HZ / 115_200);
        wr(USART3 + U_CR1, (1 << 29) | (1 << 3) | (1 << 2) | 1); // FIFOEN, TE, RE, UE
        Usart3
    }
    fn put(b: u8) {
        while rd(USART3 + U_ISR) & ISR_TXE == 0 {}
        wr(USART3 + U_TDR, u32::from(b));
    }
}

impl embedded_io::ErrorType for Usart3 {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Usart3 {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            Self::put(b);
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        while rd(USART3 + U_ISR) & ISR_TC == 0 {}
        Ok(())
    }
}
impl embedded_io::ReadReady for Usart3 {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        let isr = rd(USART3 + U_ISR);
        if isr & ISR_ORE != 0 {
            // Overrun: bytes were lost; the frame decoder will drop and count the damaged frame.
            wr(USART3 + U_ICR, ISR_ORE);
        }
        Ok(isr & ISR_RXNE != 0)
    }
}
impl embedded_io::Read for Usart3 {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        while rd(USART3 + U_ISR) & ISR_RXNE == 0 {}
        let mut n = 0;
        while n < buf.len() && rd(USART3 + U_ISR) & ISR_RXNE != 0 {
            buf[n] = rd(USART3 + U_RDR) as u8;
            n += 1;
        }
        Ok(n)
    }
}

/// SPI1 with a GPIO chip select, as an embedded-hal `SpiDevice` (polled, byte-wide).
pub struct Spi1;

/// SPI errors (none are detected beyond the bus hanging, which the polling loops do not time out).
#[derive(Clone, Copy, Debug)]
pub struct SpiError;

impl embedded_hal::spi::Error for SpiError {
    fn kind(&self) -> embedded_hal::spi::ErrorKind {
        embedded_hal::spi::ErrorKind::Other
    }
}

impl Spi1 {
    fn init() -> Self {
        modify(RCC_AHB4ENR, 0, (1 << 0) | (1 << 3)); // GPIOA, GPIOD
        modify(RCC_D2CCIP1R, 0b111 << 12, 0b100 << 12); // SPI123 kernel clock = per_ck (HSI)
        modify(RCC_APB2ENR, 0, 1 << 12); // SPI1
        let _ = rd(RCC_APB2ENR);
        alternate(GPIOA, &[5, 6, 7], 5);
        wr(GPIOD + BSRR, 1 << CS_PIN); // CS high
        modify(GPIOD + MODER, 0b11 << (2 * CS_PIN), 0b01 << (2 * CS_PIN));
        wr(SPI1 + S_CFG1, (0b011 << 28) | 7); // /16, 8-bit frames
        wr(SPI1 + S_CFG2, (1 << 31) | (1 << 26) | (1 << 22)); // AFCNTR, SSM, MASTER; mode 0
        wr(SPI1 + S_CR1, 1 << 12); // SSI
        Spi1
    }
    fn byte(out: u8) -> u8 {
        while rd(SPI1 + S_SR) & SR_TXP == 0 {}
        // SAFETY: byte access to the data register sends one 8-bit frame.
        unsafe { write_volatile((SPI1 + S_TXDR) as *mut u8, out) };
        while rd(SPI1 + S_SR) & SR_RXP == 0 {}
        // SAFETY: as above.
        unsafe { read_volatile((SPI1 + S_RXDR) as *const u8) }
    }
}

impl ErrorType for Spi1 {
    type Error = SpiError;
}

impl SpiDevice for Spi1 {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), SpiError> {
        wr(GPIOD + BSRR, 1 << (CS_PIN + 16)); // CS low
        modify(SPI1 + S_CR1, 0, 1); // SPE
        modify(SPI1 + S_CR1, 0, 1 << 9); // CSTART
        for op in ops.iter_mut() {
            match op {
                Operation::Read(b) => b.iter_mut().for_each(|x| *x = Self::byte(0)),
                Operation::Write(b) => b.iter().for_each(|&x| {
                    Self::byte(x);
                }),
                Operation::Transfer(r, w) => {
                    for i in 0..r.len().max(w.len()) {
                        let v = Self::byte(w.get(i).copied().unwrap_or(0));
                        if let Some(x) = r.get_mut(i) {
                            *x = v;
                        }
                    }
                }
                Operation::TransferInPlace(b) => b.iter_mut().for_each(|x| *x = Self::byte(*x)),
                Operation::DelayNs(ns) => {
                    cortex_m::asm::delay(ns.saturating_mul(CORE_HZ / 1_000_000) / 1000 + 1)
                }
            }
        }
        modify(SPI1 + S_CR1, 0, 1 << 10); // CSUSP
        while rd(SPI1 + S_SR) & SR_SUSP == 0 {}
        wr(SPI1 + S_IFCR, 0xFF8); // clear flags
        modify(SPI1 + S_CR1, 1, 0); // SPE off
        wr(GPIOD + BSRR, 1 << CS_PIN); // CS high
        Ok(())
    }
}

/// Busy-wait delay on the core clock.
pub struct Delay;

impl embedded_hal::delay::DelayNs for Delay {
    fn delay_ns(&mut self, ns: u32) {
        cortex_m::asm::delay((u64::from(ns) * u64::from(CORE_HZ) / 1_000_000_000) as u32 + 1);
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
pub struct Sensor(Option<Adxl355<Spi1>>);

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
pub type BoardApp = App<Usart3, Sensor, MsTimer, Stm32h743, Flash>;

/// The board's parts for the application.
pub struct Parts {
    pub serial: Usart3,
    pub accel: Sensor,
    pub timer: MsTimer,
    pub platform: Stm32h743,
    pub storage: Flash,
    pub boot_fault: Option<Fault>,
}

/// Brings up clocks, link, sensor and timers.
pub fn init() -> Parts {
    let mut cp = cortex_m::Peripherals::take().expect("peripherals taken once");
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(CORE_HZ / 1000 - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    let serial = Usart3::init();
    let mut dev = Adxl355::new(Spi1::init());
    let (accel, boot_fault) = match dev.init(&adxl355::Config::default(), &mut Delay) {
        Ok(()) => (Sensor(Some(dev)), None),
        Err(e) => {
            let code = match e {
                adxl355::Error::BadId(_) => FaultCode::SensorId,
                adxl355::Error::SelfTest { .. } => FaultCode::SensorSelfTest,
                _ => FaultCode::SensorRead,
            };
            (
                Sensor(None),
                Some(Fault::new(
                    code,
                    0,
                    format_args!("ADXL355: {}", SensorFault(&e)),
                )),
            )
        }
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
        storage: Flash::take(),
        boot_fault,
    }
}

/// A sensor error for the boot fault, without floating-point formatting (~15 KB of
/// `core::fmt::float` otherwise): the self-test response in milli-g.
struct SensorFault<'a>(&'a adxl355::Error<SpiError>);

impl core::fmt::Display for SensorFault<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            adxl355::Error::Spi(_) => write!(f, "SPI error"),
            adxl355::Error::BadId(id) => {
                write!(f, "bad id {:02x} {:02x} {:02x}", id[0], id[1], id[2])
            }
            adxl355::Error::SelfTest { axis, response_g } => write!(
                f,
                "self-test axis {axis}: response {} mg out of limits",
                (response_g * 1e3) as i64
            ),
            adxl355::Error::NotReady => write!(f, "no new data"),
        }
    }
}

/// The host asked to end: reset.
pub fn shutdown() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

/// Reports a fatal error on the link (a fault frame) and halts.
pub fn fatal(code: FaultCode, detail: core::fmt::Arguments<'_>) -> ! {
    let fault = Fault::new(code, 0, detail);
    let mut buf = [0u8; protocol::MAX_FRAME];
    if let Ok(f) = protocol::encode(
        &protocol::Packet::new(u32::MAX, protocol::Message::Fault(fault)),
        &mut buf,
    ) {
        for &b in f {
            Usart3::put(b);
        }
    }
    loop {
        cortex_m::asm::wfi();
    }
}

// ---------------------------------------------------------------------------------------------
// Checkpoint flash: bank 2, sectors 6 and 7 (RM0433 §4: embedded flash memory).

const FLASH_REGS: usize = 0x5200_2000;
const FLASH_KEYR2: usize = FLASH_REGS + 0x104;
const FLASH_CR2: usize = FLASH_REGS + 0x10C;
const FLASH_SR2: usize = FLASH_REGS + 0x110;
const FLASH_CCR2: usize = FLASH_REGS + 0x114;
const FLASH_KEY1: u32 = 0x4567_0123;
const FLASH_KEY2: u32 = 0xCDEF_89AB;
const CR_LOCK: u32 = 1 << 0;
const CR_PG: u32 = 1 << 1;
const CR_SER: u32 = 1 << 2;
const CR_PSIZE_X64: u32 = 0b11 << 4;
const CR_START: u32 = 1 << 7;
const SR_BSY: u32 = 1 << 0;
const SR_WBNE: u32 = 1 << 1;
const SR_QW: u32 = 1 << 2;
/// WRPERR, PGSERR, STRBERR, INCERR, OPERR, RDPERR, RDSERR, SNECCERR, DBECCERR.
const SR_ERRORS: u32 = (1 << 17)
    | (1 << 18)
    | (1 << 19)
    | (1 << 21)
    | (1 << 22)
    | (1 << 23)
    | (1 << 24)
    | (1 << 25)
    | (1 << 26);
/// Base address of the checkpoint region (bank 2, sector 6).
const CKPT_BASE: usize = 0x081C_0000;
const CKPT_SECTOR0: u32 = 6;
const SECTOR_SIZE: usize = 128 * 1024;

/// The checkpoint region of the internal flash as a NOR flash (offsets from 0x081C_0000).
pub struct Flash {
    _private: (),
}

/// Flash errors: the SR2 error bits of the failed operation, or an access outside the region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// Outside the checkpoint region or not aligned to the flash word / sector.
    OutOfBounds,
    /// The controller reported these SR2 error flags.
    Controller(u32),
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::Controller(_) => NorFlashErrorKind::Other,
        }
    }
}

impl Flash {
    /// The checkpoint region (init runs once).
    fn take() -> Self {
        Flash { _private: () }
    }

    fn wait_idle() -> Result<(), FlashError> {
        // SAFETY: FLASH_SR2 is a read-only status register of this MCU.
        while unsafe { read_volatile(FLASH_SR2 as *const u32) } & (SR_BSY | SR_QW | SR_WBNE) != 0 {}
        let sr = unsafe { read_volatile(FLASH_SR2 as *const u32) };
        let errors = sr & SR_ERRORS;
        if errors != 0 {
            // SAFETY: writing ones to CCR2 clears those flags.
            unsafe { write_volatile(FLASH_CCR2 as *mut u32, errors) };
            return Err(FlashError::Controller(errors));
        }
        Ok(())
    }

    /// Unlocks CR2 (no-op when unlocked).
    fn unlock() {
        // SAFETY: the documented key sequence on FLASH_KEYR2.
        unsafe {
            if read_volatile(FLASH_CR2 as *const u32) & CR_LOCK != 0 {
                write_volatile(FLASH_KEYR2 as *mut u32, FLASH_KEY1);
                write_volatile(FLASH_KEYR2 as *mut u32, FLASH_KEY2);
            }
        }
    }

    fn lock() {
        // SAFETY: setting LOCK re-locks the bank-2 control register.
        unsafe {
            write_volatile(
                FLASH_CR2 as *mut u32,
                read_volatile(FLASH_CR2 as *const u32) | CR_LOCK,
            )
        };
    }
}

impl FlashErrorType for Flash {
    type Error = FlashError;
}

impl ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let o = offset as usize;
        if o + bytes.len() > 2 * SECTOR_SIZE {
            return Err(FlashError::OutOfBounds);
        }
        for (i, b) in bytes.iter_mut().enumerate() {
            // SAFETY: inside the memory-mapped checkpoint region.
            *b = unsafe { read_volatile((CKPT_BASE + o + i) as *const u8) };
        }
        Ok(())
    }
    fn capacity(&self) -> usize {
        2 * SECTOR_SIZE
    }
}

impl NorFlash for Flash {
    const WRITE_SIZE: usize = 32;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let (a, b) = (from as usize, to as usize);
        if !a.is_multiple_of(SECTOR_SIZE)
            || !b.is_multiple_of(SECTOR_SIZE)
            || a > b
            || b > 2 * SECTOR_SIZE
        {
            return Err(FlashError::OutOfBounds);
        }
        Self::wait_idle()?;
        Self::unlock();
        let mut r = Ok(());
        for sector in (a / SECTOR_SIZE)..(b / SECTOR_SIZE) {
            let snb = CKPT_SECTOR0 + sector as u32;
            // SAFETY: sector erase of a checkpoint sector (never program code: memory.x).
            unsafe {
                write_volatile(FLASH_CR2 as *mut u32, CR_SER | CR_PSIZE_X64 | (snb << 8));
                write_volatile(
                    FLASH_CR2 as *mut u32,
                    CR_SER | CR_PSIZE_X64 | (snb << 8) | CR_START,
                );
            }
            r = Self::wait_idle();
            if r.is_err() {
                break;
            }
        }
        // SAFETY: clears SER/SNB.
        unsafe { write_volatile(FLASH_CR2 as *mut u32, 0) };
        Self::lock();
        r
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let o = offset as usize;
        if !o.is_multiple_of(32)
            || !bytes.len().is_multiple_of(32)
            || o + bytes.len() > 2 * SECTOR_SIZE
        {
            return Err(FlashError::OutOfBounds);
        }
        Self::wait_idle()?;
        Self::unlock();
        // SAFETY: PG with 64-bit parallelism for the bank-2 checkpoint region.
        unsafe { write_volatile(FLASH_CR2 as *mut u32, CR_PG | CR_PSIZE_X64) };
        let mut r = Ok(());
        for (k, word) in bytes.chunks_exact(32).enumerate() {
            let addr = CKPT_BASE + o + 32 * k;
            for (j, w) in word.chunks_exact(4).enumerate() {
                let v = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
                // SAFETY: one 256-bit flash word written as eight aligned 32-bit writes; the
                // controller programs it when the write buffer is full.
                unsafe { write_volatile((addr + 4 * j) as *mut u32, v) };
            }
            cortex_m::asm::dsb();
            r = Self::wait_idle();
            if r.is_err() {
                break;
            }
        }
        // SAFETY: ends programming.
        unsafe { write_volatile(FLASH_CR2 as *mut u32, 0) };
        Self::lock();
        r
    }
}
