//! Analog Devices ADXL355: low-noise 3-axis MEMS accelerometer, 20-bit output, SPI.
//!
//! SPI mode 0, ≤ 10 MHz. Command byte = `(register << 1) | R`, with `R = 1` for a read;
//! multi-byte reads auto-increment. Data registers hold 20-bit two's-complement values
//! left-justified in 3 bytes (`XDATA3:XDATA2:XDATA1[7:4]`). Scale: 256 000 LSB/g at ±2 g,
//! 128 000 at ±4 g, 64 000 at ±8 g. Temperature: 12 bits, 1885 LSB at 25 °C, −9.05 LSB/°C.
//!
//! [`Adxl355::init`] checks the ID registers, resets the part, optionally runs the self-test,
//! then sets range and output data rate and starts measuring. Every bus error is returned, never
//! hidden; a reading with an axis at the end of the range is flagged `saturated`.

use embedded_hal::delay::DelayNs;
use embedded_hal::spi::{Operation, SpiDevice};

use crate::accel::{AccelSample, Accelerometer};

/// Standard gravity, m/s² (the datasheet's "g" for scale factors).
pub const G0: f64 = 9.806_65;

/// Register addresses.
#[allow(missing_docs)]
pub mod reg {
    pub const DEVID_AD: u8 = 0x00;
    pub const DEVID_MST: u8 = 0x01;
    pub const PARTID: u8 = 0x02;
    pub const STATUS: u8 = 0x04;
    pub const TEMP2: u8 = 0x06;
    pub const XDATA3: u8 = 0x08;
    pub const FILTER: u8 = 0x28;
    pub const RANGE: u8 = 0x2C;
    pub const POWER_CTL: u8 = 0x2D;
    pub const SELF_TEST: u8 = 0x2E;
    pub const RESET: u8 = 0x2F;
}

/// Expected ID register values.
pub const ID: [u8; 3] = [0xAD, 0x1D, 0xED];
/// Code written to RESET for a software reset.
pub const RESET_CODE: u8 = 0x52;
/// STATUS bit: new data ready.
pub const STATUS_DATA_RDY: u8 = 0x01;
/// POWER_CTL bit: standby (1) / measurement (0).
pub const POWER_STANDBY: u8 = 0x01;
/// SELF_TEST bits ST1 (self-test mode) and ST2 (apply the electrostatic force).
pub const SELF_TEST_ST1: u8 = 0x01;
/// See [`SELF_TEST_ST1`].
pub const SELF_TEST_ST2: u8 = 0x02;

/// Largest and smallest 20-bit codes: the part clips there.
const CODE_MAX: i32 = (1 << 19) - 1;
const CODE_MIN: i32 = -(1 << 19);

/// Measurement range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Range {
    /// ±2 g (finest: 3.9 µg/LSB).
    G2 = 1,
    /// ±4 g.
    G4 = 2,
    /// ±8 g.
    G8 = 3,
}

impl Range {
    /// LSB per g.
    pub fn lsb_per_g(self) -> f64 {
        match self {
            Range::G2 => 256_000.0,
            Range::G4 => 128_000.0,
            Range::G8 => 64_000.0,
        }
    }
}

/// Output data rate / low-pass corner (FILTER register ODR_LPF field): 4000 Hz >> n.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Odr(pub u8);

impl Odr {
    /// 3.906 Hz (ODR_LPF = 0xA), the slowest, lowest-noise setting: right for 1-Hz sampling.
    pub const HZ_3_906: Odr = Odr(0x0A);
    /// 125 Hz.
    pub const HZ_125: Odr = Odr(0x05);
}

/// Self-test limits: change of each axis between ST2 on and off, g. The datasheet's typical
/// responses are 0.3 g (x, y) and 1.5 g (z); the limits bracket them generously (the test is
/// about a dead or stuck axis, not calibration).
pub const SELF_TEST_LIMITS_G: [(f64, f64); 3] = [(0.1, 0.6), (0.1, 0.6), (0.5, 3.0)];

/// Driver configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Range.
    pub range: Range,
    /// Output data rate.
    pub odr: Odr,
    /// Run the self-test during `init`.
    pub self_test: bool,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            range: Range::G2,
            odr: Odr::HZ_3_906,
            self_test: true,
        }
    }
}

/// Driver errors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Error<E> {
    /// The SPI bus failed.
    Spi(E),
    /// The ID registers do not read `AD 1D ED` (wrong part, no part, or a broken bus).
    BadId([u8; 3]),
    /// The self-test response of an axis is outside [`SELF_TEST_LIMITS_G`] (measured, g).
    #[allow(missing_docs)]
    SelfTest { axis: u8, response_g: f64 },
    /// No new data since the last read (the sample timer outran the output data rate).
    NotReady,
}

/// Raw register values of one reading.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawReading {
    /// 20-bit codes, sign-extended.
    pub axes: [i32; 3],
    /// 12-bit temperature code.
    pub temp: u16,
}

/// ADXL355 over an SPI device (chip select handled by the [`SpiDevice`]).
#[derive(Debug)]
pub struct Adxl355<SPI> {
    spi: SPI,
    range: Range,
    require_ready: bool,
}

impl<SPI: SpiDevice> Adxl355<SPI> {
    /// A driver over `spi`; call [`Adxl355::init`] before reading.
    pub fn new(spi: SPI) -> Self {
        Adxl355 {
            spi,
            range: Range::G2,
            require_ready: true,
        }
    }

    /// Gives the bus back.
    pub fn release(self) -> SPI {
        self.spi
    }

    /// The range in use.
    pub fn range(&self) -> Range {
        self.range
    }

    /// Reads `buf.len()` registers from `addr` on.
    pub fn read_regs(&mut self, addr: u8, buf: &mut [u8]) -> Result<(), Error<SPI::Error>> {
        self.spi
            .transaction(&mut [Operation::Write(&[(addr << 1) | 1]), Operation::Read(buf)])
            .map_err(Error::Spi)?;
        Ok(())
    }

    /// Writes one register.
    pub fn write_reg(&mut self, addr: u8, value: u8) -> Result<(), Error<SPI::Error>> {
        self.spi.write(&[addr << 1, value]).map_err(Error::Spi)?;
        Ok(())
    }

    /// Reads and checks the ID registers.
    pub fn check_id(&mut self) -> Result<(), Error<SPI::Error>> {
        let mut id = [0u8; 3];
        self.read_regs(reg::DEVID_AD, &mut id)?;
        if id != ID {
            return Err(Error::BadId(id));
        }
        Ok(())
    }

    /// ID check, reset, optional self-test, range, data rate, measurement mode.
    pub fn init(
        &mut self,
        cfg: &Config,
        delay: &mut impl DelayNs,
    ) -> Result<(), Error<SPI::Error>> {
        self.check_id()?;
        self.write_reg(reg::RESET, RESET_CODE)?;
        delay.delay_ms(10);
        self.check_id()?;
        self.write_reg(reg::FILTER, cfg.odr.0 & 0x0F)?;
        if cfg.self_test {
            self.self_test(delay)?;
        }
        self.set_range(cfg.range)?;
        self.write_reg(reg::POWER_CTL, 0)?; // measurement mode
        delay.delay_ms(20);
        Ok(())
    }

    /// Sets the range (the part must be in standby; `init` does this in order).
    pub fn set_range(&mut self, range: Range) -> Result<(), Error<SPI::Error>> {
        self.write_reg(reg::RANGE, range as u8)?;
        self.range = range;
        Ok(())
    }

    /// Self-test at ±8 g (so the z response on top of 1 g does not clip): the mean change of
    /// each axis when the electrostatic force is applied must be within [`SELF_TEST_LIMITS_G`].
    /// Leaves the part in standby with self-test off. Returns the responses, g.
    pub fn self_test(&mut self, delay: &mut impl DelayNs) -> Result<[f64; 3], Error<SPI::Error>> {
        self.set_range(Range::G8)?;
        self.write_reg(reg::POWER_CTL, 0)?;
        delay.delay_ms(20);
        self.write_reg(reg::SELF_TEST, SELF_TEST_ST1)?;
        let off = self.mean_g(delay)?;
        self.write_reg(reg::SELF_TEST, SELF_TEST_ST1 | SELF_TEST_ST2)?;
        delay.delay_ms(20);
        let on = self.mean_g(delay)?;
        self.write_reg(reg::SELF_TEST, 0)?;
        self.write_reg(reg::POWER_CTL, POWER_STANDBY)?;
        let mut resp = [0.0; 3];
        for (i, r) in resp.iter_mut().enumerate() {
            *r = on[i] - off[i];
            let (lo, hi) = SELF_TEST_LIMITS_G[i];
            if !(*r >= lo && *r <= hi) {
                return Err(Error::SelfTest {
                    axis: i as u8,
                    response_g: *r,
                });
            }
        }
        Ok(resp)
    }

    /// Mean of 4 readings, g.
    fn mean_g(&mut self, delay: &mut impl DelayNs) -> Result<[f64; 3], Error<SPI::Error>> {
        let mut sum = [0.0; 3];
        for _ in 0..4 {
            delay.delay_ms(10);
            let r = self.read_raw()?;
            for (s, &a) in sum.iter_mut().zip(&r.axes) {
                *s += f64::from(a) / self.range.lsb_per_g();
            }
        }
        Ok(sum.map(|s| s / 4.0))
    }

    /// Whether to refuse a reading when STATUS says no new data (default true).
    pub fn require_data_ready(&mut self, on: bool) {
        self.require_ready = on;
    }

    /// Reads temperature and the three axes in one burst (TEMP2 … ZDATA1, 11 registers).
    pub fn read_raw(&mut self) -> Result<RawReading, Error<SPI::Error>> {
        let mut b = [0u8; 11];
        self.read_regs(reg::TEMP2, &mut b)?;
        let temp = (u16::from(b[0] & 0x0F) << 8) | u16::from(b[1]);
        let axes = core::array::from_fn(|i| decode20(b[2 + 3 * i], b[3 + 3 * i], b[4 + 3 * i]));
        Ok(RawReading { axes, temp })
    }

    /// Reads STATUS.
    pub fn status(&mut self) -> Result<u8, Error<SPI::Error>> {
        let mut s = [0u8];
        self.read_regs(reg::STATUS, &mut s)?;
        Ok(s[0])
    }
}

/// Sign-extends a left-justified 20-bit value from its three registers.
pub fn decode20(d3: u8, d2: u8, d1: u8) -> i32 {
    let u = (u32::from(d3) << 12) | (u32::from(d2) << 4) | (u32::from(d1) >> 4);
    ((u << 12) as i32) >> 12
}

/// Temperature code → °C.
pub fn temp_c(code: u16) -> f64 {
    25.0 + (f64::from(code) - 1885.0) / -9.05
}

impl<SPI: SpiDevice> Accelerometer for Adxl355<SPI> {
    type Error = Error<SPI::Error>;

    fn sample(&mut self, t_s: f64) -> Result<AccelSample, Self::Error> {
        if self.require_ready && self.status()? & STATUS_DATA_RDY == 0 {
            return Err(Error::NotReady);
        }
        let r = self.read_raw()?;
        let scale = G0 / self.range.lsb_per_g();
        Ok(AccelSample {
            t_s,
            specific_force: r.axes.map(|a| f64::from(a) * scale),
            temp_c: temp_c(r.temp),
            saturated: r.axes.iter().any(|&a| a >= CODE_MAX || a <= CODE_MIN),
        })
    }
}
