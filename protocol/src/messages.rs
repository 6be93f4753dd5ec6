//! The messages. Units: seconds, m/s², °C; the state as the estimator core holds it (angles in
//! rad, drift coefficients in deg/h and deg/h/(m/s²)).

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::STATE_DIM;

/// What travels in one frame: protocol version, the sender's link sequence number (one counter
/// per direction, +1 per frame, wrapping), and the message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Packet {
    /// [`crate::PROTOCOL_VERSION`] of the sender. First byte of every packet.
    pub version: u8,
    /// Link sequence number: gaps mean lost frames.
    pub seq: u32,
    /// The message.
    pub msg: Message,
}

impl Packet {
    /// A packet of the current protocol version.
    pub fn new(seq: u32, msg: Message) -> Self {
        Packet {
            version: crate::PROTOCOL_VERSION,
            seq,
            msg,
        }
    }
}

/// A packet as the firmware reads it: only a command is decoded. Any other message (which the
/// host never sends) fails to decode, as a malformed frame — so the firmware links no decoder for
/// the messages it only sends ([`crate::Decoder::push_as`]).
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct CommandPacket {
    /// [`crate::PROTOCOL_VERSION`] of the sender.
    pub version: u8,
    /// Link sequence number.
    pub seq: u32,
    /// The message, which must be a command.
    pub msg: Inbound,
}

/// [`Message`] as the firmware decodes it: the same variants in the same order (the wire
/// format), every one but [`Message::Command`] refused.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[allow(missing_docs)] // the variants of `Message`
pub enum Inbound {
    Hello(NotACommand),
    Raw(NotACommand),
    Estimate(NotACommand),
    Status(NotACommand),
    Fault(NotACommand),
    Command(Command),
}

/// The payload of a message that is not a command: never decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NotACommand {}

impl<'de> Deserialize<'de> for NotACommand {
    fn deserialize<D: serde::Deserializer<'de>>(_: D) -> Result<Self, D::Error> {
        Err(serde::de::Error::custom("not a command"))
    }
}

/// Every message of the link, both directions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub enum Message {
    /// Firmware → host, at boot and on request: who is talking.
    Hello(Hello),
    /// Firmware → host: one raw accelerometer sample (sensor mode, when enabled).
    Raw(RawSample),
    /// Firmware → host: one filter update.
    Estimate(Estimate),
    /// Firmware → host: counters and resources, periodically and on request.
    Status(Status),
    /// Firmware → host: something went wrong (also sent by the panic handler where possible).
    Fault(Fault),
    /// Host → firmware.
    Command(Command),
}

/// Which board the firmware runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum Board {
    /// The navigation computer (STM32H743-class, ADXL355 over SPI).
    Stm32h743,
    /// QEMU `mps2-an500` (Cortex-M7): samples only by replay over the link.
    QemuMps2An500,
    /// A host-side simulation of the application (tests).
    Host,
}

/// Firmware identification.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Hello {
    /// The board.
    pub board: Board,
    /// Firmware version (major, minor, patch).
    pub firmware: [u16; 3],
    /// Number of filter states.
    pub state_dim: u8,
    /// The configuration in force.
    pub config: Config,
}

/// One raw accelerometer sample.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct RawSample {
    /// Sample number since start (gaps: samples lost or rejected at the source).
    pub seq: u32,
    /// Seconds since the gyros reached stable operation.
    pub t_s: f64,
    /// Specific force along the platform axes, m/s².
    pub specific_force: [f64; 3],
    /// Platform temperature, °C (NaN when not measured).
    pub temp_c: f64,
}

/// One filter update: the state after it, its 1σ, and the update's innovation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Estimate {
    /// Update number, 0-based (the estimator's `steps()` before this update).
    pub step: u32,
    /// Time tag of the averaged measurement (mean sample time), s.
    pub t_s: f64,
    /// Raw samples averaged into this measurement.
    pub samples: u32,
    /// State after the update: 3 angles (rad), 12 drift coefficients (deg/h, deg/h/(m/s²)).
    pub state: [f64; STATE_DIM],
    /// 1σ of each state.
    pub sigma: [f64; STATE_DIM],
    /// Innovation (measured − predicted specific force), m/s².
    pub innovation: [f64; 3],
    /// Normalised innovation squared (χ²(3) when the model holds).
    pub nis: f64,
}

/// Where the samples come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum Source {
    /// The board's accelerometer, at the configured rate.
    Sensor,
    /// Samples injected over the link ([`Command::Replay`]): hardware-in-the-loop replay.
    Replay,
}

/// Which physical effects the filter estimates. Only the paper's model for now; the firmware
/// refuses anything it was not built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum EffectSet {
    /// The paper's 12 drift coefficients (15 states).
    Paper,
}

/// Run configuration (host → firmware while stopped; echoed in [`Hello`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Config {
    /// Filter (averaging) period, s.
    pub filter_period_s: f64,
    /// Accelerometer sample rate in sensor mode, Hz.
    pub sample_rate_hz: f64,
    /// Latitude, degrees north.
    pub latitude_deg: f64,
    /// Gravity, m/s²; `None`: WGS-84 normal gravity at the latitude.
    pub gravity_mps2: Option<f64>,
    /// 1σ noise of one raw sample per axis, m/s².
    pub raw_sigma_mps2: [f64; 3],
    /// Gyro angle random walk as a variance density, deg²/h (the paper's Var(ε)).
    pub arw_deg2_per_h: f64,
    /// Effects estimated.
    pub effects: EffectSet,
    /// Samples beyond this magnitude on any axis are saturated and rejected, m/s².
    pub saturation_mps2: f64,
    /// Send every raw sample that passed the arrival checks (finite, not saturated, in time
    /// order) back as [`Message::Raw`] (sensor mode), as it arrives: the recording keeps what
    /// the firmware's screening later rejects as a glitch or a stuck run, for the host's own
    /// screening.
    pub echo_raw: bool,
    /// Send a [`Status`] every this many filter updates (0: only on request).
    pub status_every: u32,
    /// Checkpoint the filter to non-volatile storage every this many filter updates (0: never).
    /// After a reset the firmware resumes from the newest valid checkpoint.
    pub checkpoint_every: u32,
    /// χ² innovation gate: updates with NIS above this are rejected (counted, reported), and 10
    /// rejections in a row raise a fault instead of starving the filter. 0: no gate (default: the
    /// real-time single pass starts far from the truth, with NIS ≫ 1 for its first day).
    pub gate_nis: f64,
}

impl Default for Config {
    /// The paper's scenario: 60-s filter period, 1-Hz samples, 39.1° N, normal gravity,
    /// 1e-5 g per 60-s mean (7.6e-4 m/s² per 1-s sample), ARW 1e-8 deg²/h, ADXL355 ±2 g range.
    fn default() -> Self {
        Config {
            filter_period_s: 60.0,
            sample_rate_hz: 1.0,
            latitude_deg: 39.1,
            gravity_mps2: None,
            raw_sigma_mps2: [7.6e-4; 3],
            arw_deg2_per_h: 1e-8,
            effects: EffectSet::Paper,
            saturation_mps2: 2.0 * 9.806_65,
            echo_raw: true,
            status_every: 60,
            checkpoint_every: 10,
            gate_nis: 0.0,
        }
    }
}

/// Host → firmware.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub enum Command {
    /// Replace the configuration (only while stopped; otherwise refused with a fault).
    Configure(Config),
    /// Start a run from the given source: a fresh filter at t = 0.
    Start(Source),
    /// One replayed sample (replay mode).
    Replay(RawSample),
    /// End of input: average the last partial window, step the filter with it, and stop.
    Finish,
    /// Stop without flushing.
    Stop,
    /// Send [`Message::Hello`] and [`Message::Status`] now.
    Ping,
    /// End the firmware (QEMU: semihosting exit with success; real board: reset).
    Shutdown,
}

/// Counters of everything that was rejected or lost, since boot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct Counters {
    /// Samples accepted into the averaging.
    pub samples_ok: u32,
    /// Samples with a NaN/∞ component or time.
    pub samples_nan: u32,
    /// Samples beyond the saturation limit.
    pub samples_saturated: u32,
    /// Sensor read errors (SPI, data not ready).
    pub read_errors: u32,
    /// Samples before the previous one in time (out of order).
    pub samples_out_of_order: u32,
    /// Samples with the same time as the previous one (duplicates).
    pub samples_duplicate: u32,
    /// Samples rejected because an axis repeated the same reading longer than its noise allows
    /// (a stuck sensor; estimator-core's screening).
    pub samples_stuck: u32,
    /// Samples rejected as glitches: outliers against their neighbours (estimator-core's
    /// screening).
    pub samples_glitch: u32,
    /// Samples rejected because every axis read exactly zero (a dropout; estimator-core's
    /// screening).
    pub samples_dropout: u32,
    /// Filter updates done.
    pub filter_steps: u32,
    /// Filter updates refused by the estimator.
    pub filter_errors: u32,
    /// Measurements rejected by the innovation gate (the filter predicted across them).
    pub updates_rejected: u32,
    /// Frames received and decoded.
    pub frames_rx: u32,
    /// Received frames lost (COBS/CRC/version/overflow/malformed).
    pub frames_rx_bad: u32,
    /// Gaps in the host's sequence numbers (frames missing entirely).
    pub frames_rx_missing: u32,
    /// Commands refused (wrong state, bad configuration).
    pub commands_refused: u32,
    /// Frames sent.
    pub frames_tx: u32,
    /// Checkpoints written to non-volatile storage.
    pub checkpoints_written: u32,
    /// Checkpoint writes that failed (storage error).
    pub checkpoint_errors: u32,
    /// Samples (and a `Finish`) discarded after a resume while waiting for the sample the
    /// checkpoint ends at ([`Resume::next_seq`]): frames the host sent before it saw the reset.
    pub samples_resync: u32,
}

/// A run resumed from a checkpoint after a reset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Resume {
    /// Filter updates already done in the checkpoint (the next estimate has this step number).
    pub step: u32,
    /// Filter time in the checkpoint, s.
    pub t_s: f64,
    /// Sequence number of the first sample the checkpoint does not contain: the host resends
    /// from here (replay), or the sensor counts on from here.
    pub next_seq: u32,
    /// Checkpoint generation (increases with every checkpoint written).
    pub generation: u32,
}

/// Firmware state and resources.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Status {
    /// Filter time, s.
    pub t_s: f64,
    /// A run is in progress.
    pub running: bool,
    /// Source of the current or last run.
    pub source: Source,
    /// Counters since boot.
    pub counters: Counters,
    /// Stack used so far (high-water mark of the painted stack), bytes; 0 if not measured.
    pub stack_used_bytes: u32,
    /// Stack size, bytes.
    pub stack_size_bytes: u32,
    /// Static RAM (.data + .bss + .uninit), bytes.
    pub static_ram_bytes: u32,
    /// Cost of the last filter update in timer ticks (board-specific clock; 0 if not measured).
    pub last_step_ticks: u32,
    /// Frequency of those ticks, Hz (0 if not measured).
    pub tick_hz: u32,
    /// This status is the one sent at boot (a reset happened if the host saw a run before).
    pub boot: bool,
    /// The checkpoint the run was resumed from at boot, if any.
    pub resumed: Option<Resume>,
}

/// Kinds of fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum FaultCode {
    /// The firmware panicked (detail: location and message).
    Panic,
    /// A HardFault (detail: program counter).
    HardFault,
    /// The accelerometer's ID registers do not match.
    SensorId,
    /// The accelerometer's self-test failed.
    SensorSelfTest,
    /// The accelerometer could not be read.
    SensorRead,
    /// The estimator refused an update (detail: the error).
    Filter,
    /// A configuration was refused (detail: why).
    BadConfig,
    /// A command came in a state where it cannot be done.
    BadCommand,
    /// A checkpoint was found but refused (other format version or model configuration,
    /// damaged); the firmware starts without it. Detail: why.
    CheckpointRefused,
    /// Non-volatile storage failed (detail: the operation).
    Storage,
}

/// A fault report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fault {
    /// What.
    pub code: FaultCode,
    /// Filter update count when it happened.
    pub step: u32,
    /// Human-readable detail (truncated to 80 bytes).
    pub detail: heapless::String<80>,
}

// By hand: postcard's `MaxSize` covers heapless 0.7's `String`, not the 0.9 one used here.
impl MaxSize for Fault {
    /// The code, the step, and the detail: its length (a varint, one byte below 128) and bytes.
    const POSTCARD_MAX_SIZE: usize =
        FaultCode::POSTCARD_MAX_SIZE + u32::POSTCARD_MAX_SIZE + 1 + <[u8; 80]>::POSTCARD_MAX_SIZE;
}

impl Fault {
    /// A fault with `detail` formatted and truncated to fit (the host's way; the firmware
    /// writes its details with [`Detail`]'s methods, without `core::fmt`).
    pub fn new(code: FaultCode, step: u32, detail: core::fmt::Arguments<'_>) -> Self {
        let mut d = Detail::new();
        let _ = core::fmt::write(&mut d, detail);
        Fault::with_detail(code, step, d)
    }

    /// A fault with a detail written with [`Detail`].
    pub fn with_detail(code: FaultCode, step: u32, detail: Detail) -> Self {
        Fault {
            code,
            step,
            detail: detail.0,
        }
    }
}

/// A fault's detail being written: text, decimal and hexadecimal numbers appended in turn,
/// truncated to [`Fault::detail`]'s 80 bytes (at a character boundary). The firmware writes
/// its details with these methods instead of `core::fmt` (`format_args!` and `Display`), whose
/// machinery costs ~3.5 KB of its flash (issue 10); `core::fmt::Write` is implemented for the
/// host's [`Fault::new`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Detail(heapless::String<80>);

impl Detail {
    /// An empty detail.
    pub const fn new() -> Self {
        Detail(heapless::String::new())
    }

    /// Appends `s`, or as much of it as fits.
    pub fn text(&mut self, s: &str) -> &mut Self {
        let mut n = s.len().min(self.0.capacity() - self.0.len());
        while !s.is_char_boundary(n) {
            n -= 1;
        }
        // `get`, not `&s[..n]`: a slice's panic path links ~2.5 KB of `core` (Unicode tables).
        if let Some(head) = s.get(..n) {
            let _ = self.0.push_str(head);
        }
        self
    }

    /// Appends `v` in decimal.
    pub fn dec(&mut self, v: u32) -> &mut Self {
        let mut buf = [0u8; 10];
        let mut i = buf.len();
        let mut v = v;
        loop {
            i -= 1;
            buf[i] = (v % 10) as u8;
            v /= 10;
            if v == 0 {
                break;
            }
        }
        self.digits(&buf[i..])
    }

    /// Appends `v` in decimal with its sign.
    pub fn signed(&mut self, v: i32) -> &mut Self {
        if v < 0 {
            self.text("-");
        }
        self.dec(v.unsigned_abs())
    }

    /// Appends the `digits` lowest hexadecimal digits of `v` (lower case, zero-padded, at most 8).
    pub fn hex(&mut self, v: u32, digits: u32) -> &mut Self {
        let mut buf = [0u8; 8];
        let n = digits.min(8) as usize;
        for (k, b) in buf[..n].iter_mut().enumerate() {
            *b = ((v >> (4 * (n - 1 - k))) & 0xf) as u8;
        }
        self.digits(&buf[..n])
    }

    /// Appends digits given by value (0..16). Through a table of one-digit strings: no
    /// `str::from_utf8` (~550 B of flash) and no `unsafe`.
    fn digits(&mut self, d: &[u8]) -> &mut Self {
        const DIGITS: [&str; 16] = [
            "0", "1", "2", "3", "4", "5", "6", "7", "8", "9", "a", "b", "c", "d", "e", "f",
        ];
        for &x in d {
            self.text(DIGITS[usize::from(x & 0xf)]);
        }
        self
    }

    /// The text so far.
    pub fn as_str(&self) -> &str {
        self.0.as_str()
    }
}

impl From<&str> for Detail {
    fn from(s: &str) -> Self {
        let mut d = Detail::new();
        d.text(s);
        d
    }
}

impl core::fmt::Write for Detail {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        self.text(s);
        Ok(())
    }
}
