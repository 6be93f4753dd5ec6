//! The application loop, generic over the board: serial link (embedded-io), accelerometer
//! ([`Accelerometer`]), sample timer ([`SampleTimer`]) and board services ([`Platform`]).
//!
//! Per call of [`App::poll`]: drain the received bytes (commands, replayed samples), then, in
//! sensor mode, take a sample if the timer says one is due. Every sample goes through
//! [`App::accept`]: NaN/∞, saturation and time order are checked on arrival, then the core's
//! screening ([`crate::screen`]) judges dropouts, stuck axes and glitches; every rejection is
//! counted. Good samples are averaged to the filter period with the core's [`Averager`], each
//! full window steps the real-time EKF, and each update is sent as an [`Estimate`]. No heap;
//! every buffer is fixed.

use embedded_io::{Read, ReadReady, Write};
use embedded_storage::nor_flash::NorFlash;
use estimator_core::{
    units, Averager, Ekf, Measurement, Model, Propagation, Sample, Site, PAPER_EFFECTS,
};
use protocol::{
    Board, Command, CommandPacket, Config, Counters, Decoder, EffectSet, Encoder, Estimate, Fault,
    FaultCode, Hello, Inbound, Message, RawSample, Resume, SeqEvent, SeqTracker, Source, Status,
    STATE_DIM,
};

use crate::accel::Accelerometer;
use crate::checkpoints::{CheckpointStore, NoStorage, StoreError, MAX_PAYLOAD};
use crate::counters::{self, Count};
use crate::resume::{self, msg, Msg, ResumePoint};
use crate::screen::{Screen, Screened};

/// Firmware version sent in [`Hello`].
pub const FIRMWARE_VERSION: [u16; 3] = [0, 1, 0];

/// One due sample of the sample timer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Tick number since `start` (sample time = index / rate).
    pub index: u32,
    /// Ticks skipped before this one because the loop was late (samples lost, counted).
    pub missed: u32,
}

/// The fixed-rate sample clock.
pub trait SampleTimer {
    /// Starts ticking at `rate_hz`, tick 0 now.
    fn start(&mut self, rate_hz: f64);
    /// Stops ticking.
    fn stop(&mut self);
    /// Non-blocking: the tick that is due, if any.
    fn poll(&mut self) -> Option<Tick>;
}

/// A timer that never ticks (boards without a sensor).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTimer;

impl SampleTimer for NoTimer {
    fn start(&mut self, _rate_hz: f64) {}
    fn stop(&mut self) {}
    fn poll(&mut self) -> Option<Tick> {
        None
    }
}

/// Board services the application reports on.
pub trait Platform {
    /// The board.
    const BOARD: Board;
    /// A free-running counter for timing filter updates (0 if none).
    fn ticks(&self) -> u32 {
        0
    }
    /// Its frequency, Hz (0 if none).
    fn tick_hz(&self) -> u32 {
        0
    }
    /// (stack used so far, stack size), bytes.
    fn stack_usage(&self) -> (u32, u32) {
        (0, 0)
    }
    /// Static RAM (.data + .bss + .uninit), bytes.
    fn static_ram(&self) -> u32 {
        0
    }
}

/// What the board should do after a poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// Keep polling.
    Continue,
    /// The host asked to end the firmware ([`Command::Shutdown`]); the link is flushed.
    Shutdown,
}

/// The filter of the paper's model, sized exactly.
pub type Filter = Ekf<'static, STATE_DIM>;

/// One EKF update of the firmware's filter: the core's [`estimator_core::step_paper`], which
/// is compiled (and optimised for speed) in estimator-core, while the firmware's own crates are
/// optimised for size (Cargo.toml).
pub fn filter_step(
    ekf: &mut Filter,
    m: &Measurement,
) -> Result<estimator_core::Residual, estimator_core::FilterError> {
    estimator_core::step_paper(ekf, m)
}

struct Run {
    source: Source,
    averager: Averager,
    ekf: Filter,
    /// Sample screening (the firmware's arrival checks, then the core's screener).
    screen: Screen,
    sample_seq: u32,
    /// After a resume (replay): discard samples until the one with this sequence number.
    resync: Option<u32>,
    /// Sensor mode after a resume: added to the timer's sample times, s.
    time_offset_s: f64,
}

/// Consecutive gate rejections that raise a fault (`Config::gate_nis`).
pub const GATE_MAX_RUN: u32 = 10;

/// The application. `N` is the non-volatile storage for checkpoints ([`NoStorage`]: none).
pub struct App<S, A, T, P, N = NoStorage> {
    serial: S,
    accel: A,
    timer: T,
    platform: P,
    config: Config,
    run: Option<Run>,
    last_source: Source,
    counters: Counters,
    decoder: Decoder,
    encoder: Encoder,
    rx_seq: SeqTracker,
    last_step_ticks: u32,
    last_t_s: f64,
    store: Option<CheckpointStore<N>>,
    resumed: Option<Resume>,
    boot_status: bool,
    /// The checkpoint payload being written or read (in the application's state, which the
    /// boards keep in a static: not on the stack).
    ckpt_buf: [u8; MAX_PAYLOAD],
}

/// Checks a configuration; `Err` says why it is refused.
pub fn validate(c: &Config) -> Result<(), &'static str> {
    let pos = |v: f64| v.is_finite() && v > 0.0;
    if !pos(c.filter_period_s) {
        return Err("filter period must be finite and > 0");
    }
    if !pos(c.sample_rate_hz) {
        return Err("sample rate must be finite and > 0");
    }
    if !(c.latitude_deg.is_finite() && c.latitude_deg.abs() < 89.0) {
        return Err("latitude must be within +-89 deg");
    }
    if let Some(g) = c.gravity_mps2 {
        if !(g.is_finite() && (9.7..9.9).contains(&g)) {
            return Err("gravity must be within 9.7..9.9 m/s^2");
        }
    }
    if !c.raw_sigma_mps2.iter().all(|&s| pos(s)) {
        return Err("raw noise sigma must be finite and > 0");
    }
    if !(c.gate_nis.is_finite() && c.gate_nis >= 0.0) {
        return Err("gate NIS must be finite and >= 0 (0: no gate)");
    }
    if !(c.arw_deg2_per_h.is_finite() && c.arw_deg2_per_h >= 0.0) {
        return Err("ARW must be finite and >= 0");
    }
    if !pos(c.saturation_mps2) {
        return Err("saturation limit must be finite and > 0");
    }
    match c.effects {
        EffectSet::Paper => Ok(()),
    }
}

/// The filter a configuration asks for (the firmware's and the host's single pass alike).
pub fn filter_for(c: &Config) -> Result<Filter, &'static str> {
    let site = Site::new(c.latitude_deg, c.gravity_mps2);
    let arw = units::arw_deg2ph_to_rad2ps(c.arw_deg2_per_h);
    let model = Model::new(site, &PAPER_EFFECTS, arw, Propagation::default())
        .map_err(|_| "model refused")?;
    let mut ekf = Ekf::with_default_prior(model).map_err(|_| "filter refused")?;
    if c.gate_nis > 0.0 {
        ekf.set_gate(Some(estimator_core::filter::Gate {
            nis_max: c.gate_nis,
            max_run: GATE_MAX_RUN,
        }));
    }
    Ok(ekf)
}

/// Why [`single_pass`] stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SinglePassError {
    /// The configuration was refused (why).
    Config(&'static str),
    /// The estimator refused an update.
    Filter(estimator_core::FilterError),
}

/// The host's reference for the firmware: the same screening ([`Screen`]), averaging and
/// real-time EKF over `samples` (a replay: none flagged saturated by a sensor), each update handed
/// to `out` as the estimate message the firmware would send (no heap). Returns the sample and
/// filter counters the firmware would report for the same samples.
pub fn single_pass(
    config: &Config,
    samples: impl IntoIterator<Item = Sample>,
    mut out: impl FnMut(Estimate),
) -> Result<Counters, SinglePassError> {
    let mut ekf = filter_for(config).map_err(SinglePassError::Config)?;
    let mut avg = Averager::new(config.filter_period_s, config.raw_sigma_mps2);
    let mut screen = Screen::new(config, None);
    let mut counters = Counters::default();
    let mut update = |ekf: &mut Filter, m: &Measurement, c: &mut Counters| {
        let step = ekf.steps();
        let r = filter_step(ekf, m).map_err(SinglePassError::Filter)?;
        counters::bump(c, Count::FilterSteps);
        out(estimate_of(ekf, step, m, r.innovation, r.nis));
        Ok(())
    };
    let mut take = |(s, verdict): Screened, ekf: &mut Filter, c: &mut Counters| {
        if let Err(why) = verdict {
            counters::bump(c, Count::Rejected(why));
            return Ok(());
        }
        counters::bump(c, Count::SamplesOk);
        match avg.push(&s) {
            Some(m) => update(ekf, &m, c),
            None => Ok(()),
        }
    };
    for s in samples {
        match screen.push(&s, false, config.saturation_mps2) {
            Err(why) => counters::bump(&mut counters, Count::Rejected(why)),
            Ok(Some(o)) => take(o, &mut ekf, &mut counters)?,
            Ok(None) => {}
        }
    }
    while let Some(o) = screen.drain() {
        take(o, &mut ekf, &mut counters)?;
    }
    if let Some(m) = avg.flush() {
        update(&mut ekf, &m, &mut counters)?;
    }
    Ok(counters)
}

/// The estimate message of one filter update.
pub fn estimate_of(
    ekf: &Filter,
    step: u32,
    m: &Measurement,
    innovation: [f64; 3],
    nis: f64,
) -> Estimate {
    let mut state = [0.0; STATE_DIM];
    state.copy_from_slice(ekf.state());
    Estimate {
        step,
        t_s: m.t_s,
        samples: m.count,
        state,
        sigma: core::array::from_fn(|i| ekf.sigma(i)),
        innovation,
        nis,
    }
}

impl<S, A, T, P> App<S, A, T, P, NoStorage>
where
    S: Read + ReadReady + Write,
    A: Accelerometer,
    T: SampleTimer,
    P: Platform,
{
    /// The application over a board's peripherals, with the default configuration and no
    /// checkpoint storage.
    pub fn new(serial: S, accel: A, timer: T, platform: P) -> Self {
        Self::with_storage(serial, accel, timer, platform, NoStorage)
    }
}

impl<S, A, T, P, N> App<S, A, T, P, N>
where
    S: Read + ReadReady + Write,
    A: Accelerometer,
    T: SampleTimer,
    P: Platform,
    N: NorFlash,
{
    /// The application with checkpoint storage on `flash` (an append-only record log across its
    /// erase sectors; see [`crate::checkpoints`]). Flash of fewer than two sectors means no
    /// checkpoints.
    pub fn with_storage(serial: S, accel: A, timer: T, platform: P, flash: N) -> Self {
        App {
            serial,
            accel,
            timer,
            platform,
            config: Config::default(),
            run: None,
            last_source: Source::Replay,
            counters: Counters::default(),
            decoder: Decoder::new(),
            encoder: Encoder::new(),
            rx_seq: SeqTracker::new(),
            last_step_ticks: 0,
            last_t_s: 0.0,
            store: CheckpointStore::new(flash).ok(),
            resumed: None,
            boot_status: false,
            ckpt_buf: [0; MAX_PAYLOAD],
        }
    }

    /// Call once after boot: resumes the run of the newest valid checkpoint, if any, and
    /// announces the firmware (`Hello`, then a `Status` with `boot` set and what was resumed).
    /// A checkpoint that cannot be used (other format or model configuration, damaged contents)
    /// is refused with a [`FaultCode::CheckpointRefused`] fault and the firmware starts idle.
    #[inline(never)]
    pub fn boot(&mut self) {
        let mut refused: Option<(FaultCode, Msg)> = None;
        if let Some(store) = self.store.as_mut() {
            match store.load(&mut self.ckpt_buf) {
                Ok(Some(found)) => {
                    if let Err(why) = self.restore(found.len, found.generation) {
                        refused = Some((FaultCode::CheckpointRefused, why));
                    }
                }
                Ok(None) => {}
                Err(e @ StoreError::Format { .. }) => {
                    let mut m = Msg::new();
                    e.describe(&mut m);
                    refused = Some((FaultCode::CheckpointRefused, m))
                }
                Err(e) => {
                    let mut m = Msg::from("loading checkpoint: ");
                    e.describe(&mut m);
                    refused = Some((FaultCode::Storage, m))
                }
            }
        }
        self.send_hello();
        self.boot_status = true;
        self.send_status();
        self.boot_status = false;
        if let Some((code, why)) = refused {
            let step = self.counters.filter_steps;
            self.send(Message::Fault(Fault::with_detail(code, step, why)));
        }
    }

    /// The checkpoint the current run was resumed from at boot.
    pub fn resumed(&self) -> Option<Resume> {
        self.resumed
    }

    /// Restores a run from the checkpoint payload in the first `len` bytes of the checkpoint
    /// buffer ([`crate::resume`]).
    #[inline(never)]
    fn restore(&mut self, len: usize, generation: u32) -> Result<(), Msg> {
        let Some(b) = resume::decode(&self.ckpt_buf[..len])? else {
            return Ok(()); // "no run"
        };
        let (config, source, point) = (b.config, b.source, b.point);
        let ekf = filter_for(&config).map_err(|why| msg("checkpoint: ", why))?;
        let time_offset_s = match (source, point.last_t_s) {
            // The sensor's clock restarts at 0 after a reset; without a real-time clock the
            // outage is unknown, so time continues from the last sample (documented limitation).
            (Source::Sensor, Some(t)) => t + 1.0 / config.sample_rate_hz,
            _ => 0.0,
        };
        // The run is built first and its filter and screening loaded in place (one filter on
        // the stack, not several); if the image is refused, no run is left behind.
        self.run = Some(Run {
            source,
            averager: Averager::new(config.filter_period_s, config.raw_sigma_mps2),
            ekf,
            screen: Screen::new(&config, point.last_t_s),
            sample_seq: point.next_seq,
            resync: (source == Source::Replay).then_some(point.next_seq),
            time_offset_s,
        });
        let Some(run) = self.run.as_mut() else {
            return Ok(());
        };
        if run.screen.load(b.screen_state).is_none() {
            self.run = None;
            return Err(Msg::from("checkpoint: screening state unreadable"));
        }
        if let Err(why) = resume::load_filter(&mut run.ekf, b.image) {
            self.run = None;
            return Err(why);
        }
        // The checkpoint was taken right after the screening's last sample out opened the
        // current window: it is the averager's only sample.
        if let Some(s) = run.screen.last_accepted() {
            let _ = run.averager.push(&s);
        }
        let (step, t_s) = (run.ekf.steps(), run.ekf.time_s());
        self.config = config;
        self.last_source = source;
        if source == Source::Sensor {
            self.timer.start(config.sample_rate_hz);
        }
        self.resumed = Some(Resume {
            step,
            t_s,
            next_seq: point.next_seq,
            generation,
        });
        self.last_t_s = t_s;
        Ok(())
    }

    /// Writes a checkpoint of the running filter (or, with `point = None`, the "no run" marker).
    fn save_checkpoint(&mut self, point: Option<ResumePoint>) {
        let Some(store) = self.store.as_mut() else {
            return;
        };
        let buf = &mut self.ckpt_buf;
        let len = match (point, self.run.as_ref()) {
            (Some(p), Some(run)) => {
                resume::encode_run(buf, run.source, p, &self.config, &run.screen, &run.ekf)
            }
            _ => resume::encode_no_run(buf),
        };
        let Ok(len) = len else {
            counters::bump(&mut self.counters, Count::CheckpointErrors);
            return;
        };
        match store.save(&self.ckpt_buf[..len]) {
            Ok(_) => counters::bump(&mut self.counters, Count::CheckpointsWritten),
            Err(e) => {
                counters::bump(&mut self.counters, Count::CheckpointErrors);
                let step = self.counters.filter_steps;
                let mut m = Msg::from("saving checkpoint: ");
                e.describe(&mut m);
                self.send(Message::Fault(Fault::with_detail(
                    FaultCode::Storage,
                    step,
                    m,
                )));
            }
        }
    }

    /// Counters so far.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The running filter, if any.
    pub fn filter(&self) -> Option<&Filter> {
        self.run.as_ref().map(|r| &r.ekf)
    }

    /// The board services.
    pub fn platform(&self) -> &P {
        &self.platform
    }

    /// The serial port (tests).
    pub fn serial_mut(&mut self) -> &mut S {
        &mut self.serial
    }

    /// One pass of the loop; never blocks except on serial output.
    // clippy's collapsible_match would move the packet into a guard, which cannot be done.
    #[allow(clippy::collapsible_match)]
    #[inline(never)]
    pub fn poll(&mut self) -> Event {
        let mut buf = [0u8; 64];
        while let Ok(true) = self.serial.read_ready() {
            let n = match self.serial.read(&mut buf) {
                Ok(n) if n > 0 => n,
                _ => break,
            };
            for &b in &buf[..n] {
                // Commands only: a message the firmware only sends is a malformed frame here
                // (and no decoder for it is linked).
                match self.decoder.push_as::<CommandPacket>(b) {
                    None => {}
                    Some(Ok(p)) => {
                        if self.handle(p) == Event::Shutdown {
                            let _ = self.serial.flush();
                            return Event::Shutdown;
                        }
                    }
                    Some(Err(_)) => counters::bump(&mut self.counters, Count::FramesRxBad),
                }
            }
        }
        let sensor_run = matches!(
            self.run,
            Some(Run {
                source: Source::Sensor,
                ..
            })
        );
        if sensor_run {
            if let Some(tick) = self.timer.poll() {
                counters::add(&mut self.counters, Count::ReadErrors, tick.missed);
                let offset = self.run.as_ref().map_or(0.0, |r| r.time_offset_s);
                let t_s = offset + f64::from(tick.index) / self.config.sample_rate_hz;
                match self.accel.sample(t_s) {
                    Ok(s) => {
                        let sample = Sample {
                            t_s: s.t_s,
                            specific_force: s.specific_force,
                            temp_c: s.temp_c,
                        };
                        self.accept(&sample, s.saturated);
                    }
                    Err(_) => counters::bump(&mut self.counters, Count::ReadErrors),
                }
            }
        }
        Event::Continue
    }

    #[inline(never)]
    fn handle(&mut self, p: CommandPacket) -> Event {
        counters::bump(&mut self.counters, Count::FramesRx);
        if let SeqEvent::Gap { missing } = self.rx_seq.observe(p.seq) {
            counters::add(&mut self.counters, Count::FramesRxMissing, missing);
        }
        let Inbound::Command(cmd) = p.msg;
        match cmd {
            Command::Configure(c) => {
                if self.run.is_some() {
                    return self.refuse(FaultCode::BadCommand, "configure while running");
                }
                if let Err(why) = validate(&c) {
                    return self.refuse(FaultCode::BadConfig, why);
                }
                self.config = c;
                self.send_hello();
            }
            Command::Start(source) => return self.start(source),
            Command::Replay(s) => match self.run.as_mut() {
                Some(run) if run.source == Source::Replay => {
                    if let Some(want) = run.resync {
                        if s.seq != want {
                            // Sent before the host saw the reset: the host resends from `want`.
                            counters::bump(&mut self.counters, Count::SamplesResync);
                            return Event::Continue;
                        }
                        run.resync = None;
                    }
                    let sample = Sample {
                        t_s: s.t_s,
                        specific_force: s.specific_force,
                        temp_c: s.temp_c,
                    };
                    self.accept_numbered(&sample, false, Some(s.seq));
                }
                _ => {
                    return self.refuse(FaultCode::BadCommand, "replay sample while not replaying")
                }
            },
            Command::Finish => {
                if self.run.as_ref().is_some_and(|r| r.resync.is_some()) {
                    // A Finish sent before the reset: the resent samples come first.
                    counters::bump(&mut self.counters, Count::SamplesResync);
                    return Event::Continue;
                }
                // The samples the screening still holds, judged with the neighbours there are,
                // then the last (partial) window.
                while let Some(o) = self.run.as_mut().and_then(|r| r.screen.drain()) {
                    self.take(o, None);
                }
                if let Some(m) = self.run.as_mut().and_then(|r| r.averager.flush()) {
                    self.step(&m, None);
                }
                self.end_run();
            }
            Command::Stop => self.end_run(),
            Command::Ping => {
                self.send_hello();
                self.send_status();
            }
            Command::Shutdown => {
                self.end_run();
                return Event::Shutdown;
            }
        }
        Event::Continue
    }

    /// Starts a run. Not inlined: the new run (filter and screening, ~4 KB) is built in this
    /// frame before it moves into the application's state, and that frame must not stay on the
    /// stack under every other command (the replayed samples' path to the EKF).
    #[inline(never)]
    fn start(&mut self, source: Source) -> Event {
        if self.run.is_some() {
            return self.refuse(FaultCode::BadCommand, "start while running");
        }
        if source == Source::Sensor && !self.accel.present() {
            return self.refuse(FaultCode::BadCommand, "no accelerometer on this board");
        }
        let ekf = match filter_for(&self.config) {
            Ok(f) => f,
            Err(why) => return self.refuse(FaultCode::BadConfig, why),
        };
        let averager = Averager::new(self.config.filter_period_s, self.config.raw_sigma_mps2);
        // A fresh run: no older checkpoint may be resumed from now on.
        self.save_checkpoint(None);
        self.resumed = None;
        self.run = Some(Run {
            source,
            averager,
            ekf,
            screen: Screen::new(&self.config, None),
            sample_seq: 0,
            resync: None,
            time_offset_s: 0.0,
        });
        self.last_source = source;
        if source == Source::Sensor {
            self.timer.start(self.config.sample_rate_hz);
        }
        self.send_status();
        Event::Continue
    }

    fn end_run(&mut self) {
        if self.run.take().is_some() {
            self.timer.stop();
            // The run is over: a reset must not resume it.
            self.save_checkpoint(None);
        }
        self.send_status();
    }

    fn refuse(&mut self, code: FaultCode, why: &str) -> Event {
        counters::bump(&mut self.counters, Count::CommandsRefused);
        let step = self.counters.filter_steps;
        self.send(Message::Fault(Fault::with_detail(
            code,
            step,
            Msg::from(why),
        )));
        Event::Continue
    }

    /// Screens one sample; the sample the screening hands back (judged, `half_window` samples
    /// later) is averaged, and the filter steps when a window is complete. Returns whether the
    /// sample passed the arrival checks (its verdict from the core's screening comes later).
    pub fn accept(&mut self, s: &Sample, saturated: bool) -> bool {
        self.accept_numbered(s, saturated, None)
    }

    /// [`App::accept`] with the sample's sequence number from its source (replay: the host's);
    /// `None`: the firmware's own count.
    fn accept_numbered(&mut self, s: &Sample, saturated: bool, source_seq: Option<u32>) -> bool {
        let Some(run) = self.run.as_mut() else {
            return false;
        };
        let out = match run.screen.push(s, saturated, self.config.saturation_mps2) {
            Ok(out) => out,
            Err(why) => {
                counters::bump(&mut self.counters, Count::Rejected(why));
                return false;
            }
        };
        let seq = source_seq.unwrap_or(run.sample_seq);
        run.sample_seq = seq.wrapping_add(1);
        if run.source == Source::Sensor && self.config.echo_raw {
            let raw = RawSample {
                seq,
                t_s: s.t_s,
                specific_force: s.specific_force,
                temp_c: s.temp_c,
            };
            self.send(Message::Raw(raw));
        }
        if let Some(o) = out {
            // A checkpoint after the update this may complete resumes with the next sample.
            let point = ResumePoint {
                next_seq: seq.wrapping_add(1),
                last_t_s: Some(s.t_s),
            };
            self.take(o, Some(point));
        }
        true
    }

    /// A sample out of the screening: counted, and averaged if accepted; steps the filter when
    /// it opens the next window.
    fn take(&mut self, (s, verdict): Screened, point: Option<ResumePoint>) {
        if let Err(why) = verdict {
            counters::bump(&mut self.counters, Count::Rejected(why));
            return;
        }
        counters::bump(&mut self.counters, Count::SamplesOk);
        if let Some(m) = self.run.as_mut().and_then(|r| r.averager.push(&s)) {
            self.step(&m, point);
        }
    }

    fn step(&mut self, m: &Measurement, point: Option<ResumePoint>) {
        let Some(run) = self.run.as_mut() else { return };
        let step = run.ekf.steps();
        let t0 = self.platform.ticks();
        let r = filter_step(&mut run.ekf, m);
        self.last_step_ticks = self.platform.ticks().wrapping_sub(t0);
        match r {
            Ok(res) => {
                if res.rejected {
                    counters::bump(&mut self.counters, Count::UpdatesRejected);
                }
                let e = estimate_of(&run.ekf, step, m, res.innovation, res.nis);
                self.last_t_s = run.ekf.time_s();
                counters::bump(&mut self.counters, Count::FilterSteps);
                self.send(Message::Estimate(e));
                let every = self.config.status_every;
                if every > 0 && self.counters.filter_steps.is_multiple_of(every) {
                    self.send_status();
                }
                let every = self.config.checkpoint_every;
                let done = run_steps(&self.run);
                if let (true, Some(p)) = (every > 0 && done.is_multiple_of(every), point) {
                    self.save_checkpoint(Some(p));
                }
            }
            Err(e) => {
                counters::bump(&mut self.counters, Count::FilterErrors);
                let mut m = Msg::new();
                describe_filter_error(&e, &mut m);
                self.send(Message::Fault(Fault::with_detail(
                    FaultCode::Filter,
                    step,
                    m,
                )));
            }
        }
    }

    /// The current status.
    pub fn status(&self) -> Status {
        let (stack_used_bytes, stack_size_bytes) = self.platform.stack_usage();
        Status {
            t_s: self.run.as_ref().map_or(self.last_t_s, |r| r.ekf.time_s()),
            running: self.run.is_some(),
            source: self.last_source,
            counters: self.counters,
            stack_used_bytes,
            stack_size_bytes,
            static_ram_bytes: self.platform.static_ram(),
            last_step_ticks: self.last_step_ticks,
            tick_hz: self.platform.tick_hz(),
            boot: self.boot_status,
            resumed: self.resumed,
        }
    }

    #[inline(never)]
    fn send_status(&mut self) {
        // Count this frame in the status it carries.
        self.counters.frames_tx = self.counters.frames_tx.wrapping_add(1);
        let st = self.status();
        self.counters.frames_tx = self.counters.frames_tx.wrapping_sub(1);
        self.send(Message::Status(st));
    }

    #[inline(never)]
    fn send_hello(&mut self) {
        let h = Hello {
            board: P::BOARD,
            firmware: FIRMWARE_VERSION,
            state_dim: STATE_DIM as u8,
            config: self.config,
        };
        self.send(Message::Hello(h));
    }

    /// Frames and sends one message (blocking on the serial port).
    pub fn send(&mut self, msg: Message) {
        if let Ok(frame) = self.encoder.frame(msg) {
            let _ = self.serial.write_all(frame);
            counters::bump(&mut self.counters, Count::FramesTx);
        }
    }
}

/// A filter error's text for the fault frame, without `core::fmt` (its float formatting alone
/// would link ~15 KB into the firmware): times to the millisecond ([`secs`]). The core's texts,
/// repeated: calling its `Display` would link its float formatting.
pub fn describe_filter_error(e: &estimator_core::FilterError, m: &mut Msg) {
    use estimator_core::FilterError as E;
    let n = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
    match *e {
        E::TimeNotIncreasing {
            step,
            t_s,
            filter_t_s,
        } => {
            m.text("step ").dec(step).text(": measurement at t = ");
            secs(m, t_s);
            m.text(" s is not after the filter time ");
            secs(m, filter_t_s);
            m.text(" s")
        }
        E::Capacity { needed, capacity } => m
            .text("model needs ")
            .dec(n(needed))
            .text(" states, filter capacity is ")
            .dec(n(capacity)),
        E::Dimension { expected, got } => m
            .text("expected ")
            .dec(n(expected))
            .text(" values, got ")
            .dec(n(got)),
        E::BadMeasurement { step } => m
            .text("step ")
            .dec(step)
            .text(": measurement or its variance is not finite and positive"),
        E::SingularInnovation { step } => m
            .text("step ")
            .dec(step)
            .text(": innovation covariance is not positive definite"),
        E::Unhealthy { step, index } => m
            .text("step ")
            .dec(step)
            .text(": covariance or state unhealthy at state ")
            .dec(n(index)),
        E::RejectionRun { step, count } => m
            .text("step ")
            .dec(step)
            .text(": ")
            .dec(count)
            .text(" consecutive measurements failed the innovation gate"),
    };
}

/// Appends a time in seconds to the millisecond, with 32-bit integers only (no float
/// formatting, and no 64-bit division: both cost flash). Saturates beyond 136 years; NaN
/// prints as 0.000.
fn secs(m: &mut Msg, t: f64) {
    let a = if t < 0.0 { -t } else { t };
    let whole = a as u32; // saturating; NaN -> 0
    let ms = (((a - f64::from(whole)) * 1e3) as u32).min(999);
    if t < 0.0 {
        m.text("-");
    }
    m.dec(whole).text(".");
    if ms < 100 {
        m.text(if ms < 10 { "00" } else { "0" });
    }
    m.dec(ms);
}

fn run_steps(run: &Option<Run>) -> u32 {
    run.as_ref().map_or(0, |r| r.ekf.steps())
}
