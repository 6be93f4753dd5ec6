//! The QEMU board's UART bring-up and receive interrupt (`firmware_app::cmsdk_uart`) against a
//! model of QEMU's CMSDK APB UART (`hw/char/cmsdk-apb-uart.c`) and NVIC line, after a reset with
//! the host's bytes already waiting (the reset test's situation): whenever the model may take a
//! byte (receiver on, `DATA` empty), the first one arrives between any two register accesses,
//! and every byte must reach the receive ring.

use std::collections::VecDeque;

use firmware_app::cmsdk_uart::{self as uart, Regs};
use firmware_app::serial::RxProducer;
use heapless::spsc::Queue;

/// QEMU's CMSDK APB UART, receive side, and the NVIC line of its receive interrupt.
struct QemuUart {
    ctrl: u32,
    rx_full: bool,
    rx_buf: u8,
    int_rx: bool,
    /// The NVIC's pending bit (latched while the line is high, even with the line masked).
    nvic_pending: bool,
    /// Bytes waiting in the host's pty.
    pty: VecDeque<u8>,
    /// Register accesses (and, after the bring-up, passes of the loop) so far, and the one
    /// before which the first byte may arrive.
    accesses: usize,
    first_byte_at: usize,
}

impl QemuUart {
    fn after_reset(pty: VecDeque<u8>, first_byte_at: usize) -> Self {
        QemuUart {
            ctrl: 0,
            rx_full: false,
            rx_buf: 0,
            int_rx: false,
            nvic_pending: false,
            pty,
            accesses: 0,
            first_byte_at,
        }
    }

    /// `cmsdk_apb_uart_update`: the receive interrupt line follows INTSTATUS.RX.
    fn update(&mut self) {
        if self.int_rx {
            self.nvic_pending = true;
        }
    }

    /// QEMU's main loop between two guest accesses: `uart_can_receive`, then `uart_receive`.
    fn main_loop(&mut self) {
        if self.accesses < self.first_byte_at {
            return;
        }
        let can_receive = self.ctrl & uart::CTRL_RX_EN != 0 && !self.rx_full;
        if can_receive {
            if let Some(b) = self.pty.pop_front() {
                self.rx_buf = b;
                self.rx_full = true;
                if self.ctrl & uart::CTRL_RX_INT_EN != 0 {
                    self.int_rx = true;
                }
                self.update();
            }
        }
    }
}

impl Regs for QemuUart {
    fn read(&mut self, offset: usize) -> u32 {
        self.main_loop();
        self.accesses += 1;
        match offset {
            uart::DATA => {
                self.rx_full = false;
                u32::from(self.rx_buf)
            }
            uart::STATE => u32::from(self.rx_full) << 1,
            uart::CTRL => self.ctrl,
            _ => 0,
        }
    }
    fn write(&mut self, offset: usize, value: u32) {
        self.main_loop();
        self.accesses += 1;
        match offset {
            // A CTRL write updates the lines but raises no receive interrupt for a held byte.
            uart::CTRL => {
                self.ctrl = value & 0x7f;
                self.update();
            }
            uart::INTCLEAR => {
                if value & uart::INT_RX != 0 {
                    self.int_rx = false;
                }
                self.update();
            }
            _ => {}
        }
    }
}

/// Boots with `waiting` bytes in the pty, the first arriving before access `first_byte_at`:
/// `bring_up` enables the UART, then the interrupt runs whenever pending (the NVIC line is
/// unmasked after `bring_up`). Returns what reached the ring.
fn boot(waiting: usize, first_byte_at: usize, bring_up: impl FnOnce(&mut QemuUart)) -> Vec<u8> {
    let pty: VecDeque<u8> = (0..waiting).map(|i| (i % 251) as u8).collect();
    let mut u = QemuUart::after_reset(pty, first_byte_at);
    let mut queue: Queue<u8, 4096> = Queue::new();
    let (p, mut ring) = queue.split();
    let mut rx = RxProducer::new(p);
    bring_up(&mut u);
    let mut got = Vec::new();
    // The main loop polls the ring; the interrupt preempts it whenever pending.
    for _ in 0..10 * waiting + 100 {
        // Time goes on between the loop's passes too.
        u.accesses += 1;
        u.main_loop();
        if u.nvic_pending {
            u.nvic_pending = false;
            uart::on_rx_interrupt(&mut u, &mut rx);
            // Level-sensitive: still high after the handler, pending again.
            u.update();
        }
        while let Some(b) = ring.dequeue() {
            got.push(b);
        }
    }
    got
}

#[test]
fn bytes_waiting_at_boot_all_arrive_wherever_the_first_one_lands() {
    let want: Vec<u8> = (0..300).map(|i| (i % 251) as u8).collect();
    for at in 0..12 {
        let got = boot(300, at, |u| {
            uart::init_tx(u, 16);
            uart::enable_rx(u);
        });
        assert_eq!(got, want, "first byte before register access {at}");
    }
}

/// The former bring-up (the receiver enabled with the transmitter, its interrupt by a second
/// write) against the same model: a byte landing between the two writes is never read and the
/// UART takes no other. The test above would have caught it; this one shows the model does.
#[test]
fn the_former_two_write_bring_up_wedges_on_a_byte_between_the_writes() {
    let former = |u: &mut QemuUart| {
        u.write(uart::BAUDDIV, 16);
        u.write(uart::CTRL, uart::CTRL_TX_EN | uart::CTRL_RX_EN);
        u.write(
            uart::CTRL,
            uart::CTRL_TX_EN | uart::CTRL_RX_EN | uart::CTRL_RX_INT_EN,
        );
    };
    // The first byte lands before the third access: after RX_EN, before RX_INT_EN.
    assert!(boot(300, 2, former).is_empty());
    // Landing anywhere else, it works: the race is one access wide.
    assert_eq!(boot(300, 3, former).len(), 300);
}
