//! Stack painting and RAM figures from cortex-m-rt's linker symbols.
//!
//! RAM layout as flip-link (the linker) makes it: the stack grows down from `_stack_start` to the
//! start of RAM ([`crate::board::RAM_ORIGIN`]), and `.data`, `.bss`, `.uninit` sit above it, up
//! to `__sheap`; an overflow runs off the start of RAM and faults. (Linked without flip-link,
//! cortex-m-rt's layout: statics first, the stack from the end of RAM down to `__sheap`; both
//! are handled.) At boot we fill the free stack with a pattern; the high-water mark is the
//! lowest word no longer holding it.

use core::ptr::{addr_of, read_volatile, write_volatile};

const PAINT: u32 = 0x5AA5_C33C;

extern "C" {
    static __sdata: u32;
    static __sheap: u32;
    static _stack_start: u32;
}

/// (lowest, highest) address of the stack.
fn bounds() -> (usize, usize) {
    let top = addr_of!(_stack_start) as usize;
    if top <= addr_of!(__sdata) as usize {
        (crate::board::RAM_ORIGIN, top) // flip-link: the stack below the statics
    } else {
        (addr_of!(__sheap) as usize, top)
    }
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
    (addr_of!(__sheap) as usize - addr_of!(__sdata) as usize) as u32
}
