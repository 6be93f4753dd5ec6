//! Stack painting and RAM figures from cortex-m-rt's linker symbols.
//!
//! RAM layout (cortex-m-rt): `.data`, `.bss`, `.uninit` from the start of RAM up to `__sheap`;
//! the stack grows down from `_stack_start` (end of RAM) towards `__sheap`. At boot we fill the
//! gap with a pattern; the high-water mark is the lowest word no longer holding it.

use core::ptr::{addr_of, read_volatile, write_volatile};

const PAINT: u32 = 0x5AA5_C33C;

extern "C" {
    static __sdata: u32;
    static __sheap: u32;
    static _stack_start: u32;
}

fn bounds() -> (usize, usize) {
    (addr_of!(__sheap) as usize, addr_of!(_stack_start) as usize)
}

/// Paints the free stack up to 256 bytes below the current stack pointer.
pub fn paint_stack() {
    let (lo, _) = bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = lo as *mut u32;
    let end = (sp - 256) as *mut u32;
    while p < end {
        // SAFETY: [__sheap, sp - 256) is RAM that nothing uses yet (below the live stack).
        unsafe {
            write_volatile(p, PAINT);
            p = p.add(1);
        }
    }
}

/// (stack used at the deepest so far, stack size), bytes.
pub fn stack_usage() -> (u32, u32) {
    let (lo, hi) = bounds();
    let mut p = lo as *const u32;
    // SAFETY: reads of RAM between the heap start and the stack top.
    unsafe {
        while (p as usize) < hi && read_volatile(p) == PAINT {
            p = p.add(1);
        }
    }
    ((hi - p as usize) as u32, (hi - lo) as u32)
}

/// Static RAM: .data + .bss + .uninit, bytes.
pub fn static_ram() -> u32 {
    let start = addr_of!(__sdata) as usize;
    (bounds().0 - start) as u32
}
