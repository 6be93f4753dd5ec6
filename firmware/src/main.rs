//! Navigation-computer firmware: a thin board layer under [`firmware_app::App`].
//!
//! Boards (one per build, chosen by feature):
//! - default: the STM32H743 navigation computer (`board/stm32h743.rs`, on embassy-stm32): USART3
//!   link (interrupt-driven receive ring), ADXL355 on SPI1, SysTick sample timer, DWT cycle
//!   counter; memory map `firmware/memory.x`.
//! - `board-qemu`: QEMU `mps2-an500` (`board/qemu.rs`): CMSDK UART0 link (receive interrupt into
//!   a ring), no sensor (samples come by replay), SysTick tick counter, semihosting exit codes;
//!   memory map `firmware/memory-qemu.x`.
//!
//! Linked by flip-link: the stack lies below the statics, so an overflow faults.
//!
//! Both paint the stack at boot and report its high-water mark and the static RAM in every
//! status frame. A panic or HardFault is reported (fault frame / semihosting / defmt) and, under
//! QEMU, ends the run with a failure exit code.
#![no_std]
#![no_main]

#[cfg(feature = "defmt")]
use defmt_rtt as _;

#[cfg_attr(feature = "board-qemu", path = "board/qemu.rs")]
#[cfg_attr(not(feature = "board-qemu"), path = "board/stm32h743.rs")]
mod board;
mod memory;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use firmware_app::app::{App, Event};

macro_rules! log {
    ($($t:tt)*) => {
        #[cfg(feature = "defmt")]
        defmt::info!($($t)*);
    };
}

#[entry]
fn main() -> ! {
    memory::paint_stack();
    log!("driftid firmware boot");
    #[cfg(feature = "selftest")]
    #[allow(unreachable_code)]
    board::selftest();
    #[allow(unreachable_code)]
    let mut parts = board::init();
    crash_test();
    let boot_fault = parts.boot_fault.take();
    let app = app_of(parts);
    app.boot();
    if let Some(fault) = boot_fault {
        app.send(protocol::Message::Fault(fault));
    }
    loop {
        if app.poll() == Event::Shutdown {
            log!("shutdown requested");
            board::shutdown();
        }
    }
}

/// The application in a static. Not inlined: `App::with_storage` builds the application (~5 KB
/// with its buffers) in this frame before it moves into the static, and `main`'s frame stays on
/// the stack for the whole run.
#[inline(never)]
fn app_of(parts: board::Parts) -> &'static mut board::BoardApp {
    cortex_m::singleton!(: board::BoardApp = App::with_storage(parts.serial, parts.accel, parts.timer, parts.platform, parts.storage))
        .unwrap_or_else(|| panic!("main runs once")) // not `expect`: see board::init
}

/// Crash tests (`--features crash-panic` / `crash-hardfault`, for `.ci/qemu.sh`): prove that a
/// panic or a HardFault ends a QEMU run with a failure code instead of hanging CI.
#[inline(always)]
fn crash_test() {
    #[cfg(feature = "crash-panic")]
    panic!("crash test: deliberate panic");
    #[cfg(feature = "crash-stackoverflow")]
    {
        // Unbounded recursion with a live frame per call: runs the stack off the start of RAM.
        #[inline(never)]
        #[allow(unconditional_recursion)] // the point: it never returns
        fn deeper(n: u32) -> u32 {
            let frame = core::hint::black_box([n; 64]);
            deeper(n + 1).wrapping_add(frame[(n % 64) as usize])
        }
        let _ = deeper(0);
    }
    #[cfg(feature = "crash-hardfault")]
    // SAFETY: deliberately not safe: an undefined instruction raises a fault (escalated to
    // HardFault, the only fault handler enabled).
    unsafe {
        core::arch::asm!("udf #0");
    }
}

/// Reports where the panic happened, not its message: formatting the message would link the
/// `Debug`/`Display` code of every value any `unwrap`/`expect`/`panic!` in the image could print
/// (several KB of `.text`; the budget in `.ci/qemu.sh`). The file and line find the call; the
/// defmt build logs the full message.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    #[cfg(feature = "defmt")]
    defmt::error!("panic: {}", defmt::Display2Format(info));
    let mut m = protocol::Detail::from("panic");
    if let Some(at) = info.location() {
        m.text(" at ").text(at.file()).text(":").dec(at.line());
    }
    board::fatal(protocol::FaultCode::Panic, m)
}

#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    #[cfg(feature = "defmt")]
    defmt::error!("HardFault at pc {=u32:#x}", ef.pc());
    let mut m = protocol::Detail::from("HardFault pc=0x");
    m.hex(ef.pc(), 8).text(" lr=0x").hex(ef.lr(), 8);
    board::fatal(protocol::FaultCode::HardFault, m)
}
