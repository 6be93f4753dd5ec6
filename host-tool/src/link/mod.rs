//! The host end of the telemetry link (the `protocol` crate): serial ports and pseudo-terminals,
//! the frame receiver with loss accounting, HIL replay and recording.
//!
//! - [`port`]: opening a serial port (`serialport`, no libudev) and creating a pty pair for QEMU.
//! - [`Receiver`]: bytes → messages, counting damaged frames and sequence gaps.
//! - [`replay`]: stream a recording into the firmware and collect what comes back.
//! - [`record`]: record the firmware's stream to a recording CSV and a raw frame log.
//! - [`timeline`]: which received samples continue a recording (resends, bad time stamps, a new run).

pub mod port;
pub mod record;
pub mod replay;
pub(crate) mod timeline;

use protocol::{DecodeError, Decoder, DecoderStats, Message, Packet, SeqEvent, SeqTracker};

/// What the host saw of one direction of the link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Decoder counts (frames good and dropped, by reason; bytes).
    pub decoder: DecoderStats,
    /// Frames whose sequence numbers never arrived.
    pub missing: u64,
    /// Times the sender's sequence went back (firmware reset).
    pub restarts: u64,
}

impl LinkStats {
    /// Frames lost: dropped by the decoder, or missing entirely (the larger of the two views,
    /// since a frame can be both damaged and counted as a gap).
    pub fn lost(&self) -> u64 {
        self.decoder.bad().max(self.missing)
    }
}

impl std::fmt::Display for LinkStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let d = &self.decoder;
        write!(
            f,
            "{} frames ok, {} dropped (crc {}, cobs {}, overflow {}, version {}, malformed {}), {} missing by sequence, {} restarts, {} bytes",
            d.ok,
            d.bad(),
            d.crc,
            d.cobs,
            d.overflow,
            d.version,
            d.malformed,
            self.missing,
            self.restarts,
            d.bytes
        )
    }
}

/// Decodes a byte stream into packets, tracking losses.
#[derive(Clone, Debug, Default)]
pub struct Receiver {
    decoder: Decoder,
    seq: SeqTracker,
}

impl Receiver {
    /// A receiver that has seen nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds bytes; returns the packets completed, in order. Damaged frames are counted only.
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<Packet> {
        let mut out = Vec::new();
        self.feed_with(bytes, |r| {
            if let Ok(p) = r {
                out.push(p);
            }
        });
        out
    }

    /// Feeds bytes; calls `f` with every frame result (packets and drop reasons).
    pub(crate) fn feed_with(
        &mut self,
        bytes: &[u8],
        mut f: impl FnMut(Result<Packet, DecodeError>),
    ) {
        let seq = &mut self.seq;
        self.decoder.feed(bytes, |r| {
            if let Ok(p) = &r {
                if let SeqEvent::Restart = seq.observe(p.seq) {
                    // counted in `restarts`
                }
            }
            f(r)
        });
    }

    /// Counts so far.
    pub(crate) fn stats(&self) -> LinkStats {
        LinkStats {
            decoder: *self.decoder.stats(),
            missing: self.seq.missing,
            restarts: self.seq.restarts,
        }
    }
}

/// One-line summary of a message for progress displays.
pub(crate) fn describe(msg: &Message) -> String {
    match msg {
        Message::Hello(h) => format!(
            "firmware {}.{}.{} on {:?}, {} states, filter period {} s, latitude {} deg",
            h.firmware[0],
            h.firmware[1],
            h.firmware[2],
            h.board,
            h.state_dim,
            h.config.filter_period_s,
            h.config.latitude_deg
        ),
        Message::Raw(r) => format!("sample {} t={} s", r.seq, r.t_s),
        Message::Estimate(e) => {
            let h = e.t_s / 3600.0;
            format!(
                "step {:>5} t={:>8.3} h NIS {:>7.3}  D(X)_0 {:+.5}±{:.5}  D(Y)_0 {:+.5}±{:.5}  D(Z)_0 {:+.5}±{:.5} deg/h",
                e.step, h, e.nis, e.state[3], e.sigma[3], e.state[7], e.sigma[7], e.state[11], e.sigma[11]
            )
        }
        Message::Status(s) => {
            let c = &s.counters;
            format!(
                "status{} t={} s running={}{} samples ok {} nan {} sat {} stuck {} glitch {} dropout {} read-err {} dup {} order {} resync {}; steps {} (errors {}, gated {}); checkpoints {} (errors {}); rx {} bad {} missing {}; refused {}; stack {}/{} B, static {} B",
                if s.boot { " (boot)" } else { "" },
                s.t_s,
                s.running,
                match s.resumed {
                    Some(r) => format!(" resumed at update {} (sample {}, checkpoint {})", r.step, r.next_seq, r.generation),
                    None => String::new(),
                },
                c.samples_ok,
                c.samples_nan,
                c.samples_saturated,
                c.samples_stuck,
                c.samples_glitch,
                c.samples_dropout,
                c.read_errors,
                c.samples_duplicate,
                c.samples_out_of_order,
                c.samples_resync,
                c.filter_steps,
                c.filter_errors,
                c.updates_rejected,
                c.checkpoints_written,
                c.checkpoint_errors,
                c.frames_rx,
                c.frames_rx_bad,
                c.frames_rx_missing,
                c.commands_refused,
                s.stack_used_bytes,
                s.stack_size_bytes,
                s.static_ram_bytes
            )
        }
        Message::Fault(f) => format!("FAULT {:?} at step {}: {}", f.code, f.step, f.detail),
        Message::Command(c) => format!("command {c:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Command, Encoder};

    #[test]
    fn receiver_counts_damage_and_gaps() {
        let mut enc = Encoder::new();
        let mut bytes = Vec::new();
        for i in 0..5 {
            let mut f = enc.frame(Message::Command(Command::Ping)).unwrap().to_vec();
            if i == 2 {
                f[4] ^= 0x01;
            }
            bytes.extend(f);
        }
        let mut r = Receiver::new();
        let got = r.feed(&bytes);
        assert_eq!(
            got.iter().map(|p| p.seq).collect::<Vec<_>>(),
            vec![0, 1, 3, 4]
        );
        let s = r.stats();
        assert_eq!((s.decoder.bad(), s.missing, s.lost()), (1, 1, 1));
    }
}
