//! The ADXL355 driver against `embedded-hal-mock`: exact register traffic, scaling, ID and
//! self-test checks, and the error paths.

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use embedded_hal_mock::eh1::delay::NoopDelay;
use embedded_hal_mock::eh1::spi::{Mock, Transaction as T};
use firmware_app::adxl355::{self, reg, Adxl355, Config, Error, Range, G0};
use firmware_app::Accelerometer;

fn encode20(v: i32) -> [u8; 3] {
    let u = (v as u32) & 0xFFFFF;
    [(u >> 12) as u8, (u >> 4) as u8, ((u & 0xF) << 4) as u8]
}

fn read(addr: u8, data: Vec<u8>) -> Vec<T<u8>> {
    vec![
        T::transaction_start(),
        T::write_vec(vec![(addr << 1) | 1]),
        T::read_vec(data),
        T::transaction_end(),
    ]
}

fn write(addr: u8, v: u8) -> Vec<T<u8>> {
    vec![
        T::transaction_start(),
        T::write_vec(vec![addr << 1, v]),
        T::transaction_end(),
    ]
}

fn burst(axes: [i32; 3], temp: u16) -> Vec<T<u8>> {
    let mut d = vec![(temp >> 8) as u8 & 0x0F, temp as u8];
    for a in axes {
        d.extend_from_slice(&encode20(a));
    }
    read(reg::TEMP2, d)
}

fn id() -> Vec<T<u8>> {
    read(reg::DEVID_AD, adxl355::ID.to_vec())
}

#[test]
fn decode20_sign_extends() {
    for v in [
        0,
        1,
        -1,
        256_000,
        -256_000,
        (1 << 19) - 1,
        -(1 << 19),
        12345,
        -54321,
    ] {
        let [a, b, c] = encode20(v);
        assert_eq!(adxl355::decode20(a, b, c), v);
    }
    // The low nibble of XDATA1 is reserved: ignored.
    let [a, b, c] = encode20(-2);
    assert_eq!(adxl355::decode20(a, b, c | 0x0F), -2);
}

#[test]
fn init_with_self_test_then_samples_scale_to_mps2() {
    // Self-test at ±8 g (64 000 LSB/g): ST2 adds 0.3 g, 0.3 g, 1.5 g.
    let rest = [100, -200, 64_000];
    let st = [100 + 19_200, -200 + 19_200, 64_000 + 96_000];
    let mut ex = Vec::new();
    ex.extend(id());
    ex.extend(write(reg::RESET, adxl355::RESET_CODE));
    ex.extend(id());
    ex.extend(write(reg::FILTER, 0x0A));
    ex.extend(write(reg::RANGE, Range::G8 as u8));
    ex.extend(write(reg::POWER_CTL, 0));
    ex.extend(write(reg::SELF_TEST, adxl355::SELF_TEST_ST1));
    for _ in 0..4 {
        ex.extend(burst(rest, 1885));
    }
    ex.extend(write(
        reg::SELF_TEST,
        adxl355::SELF_TEST_ST1 | adxl355::SELF_TEST_ST2,
    ));
    for _ in 0..4 {
        ex.extend(burst(st, 1885));
    }
    ex.extend(write(reg::SELF_TEST, 0));
    ex.extend(write(reg::POWER_CTL, adxl355::POWER_STANDBY));
    ex.extend(write(reg::RANGE, Range::G2 as u8));
    ex.extend(write(reg::POWER_CTL, 0));
    // Then one sample: ready, 1 g on z, -0.5 g on x, at 25 °C - 10 °C.
    ex.extend(read(reg::STATUS, vec![adxl355::STATUS_DATA_RDY]));
    ex.extend(burst([-128_000, 0, 256_000], (1885.0 + 90.5) as u16));
    // A sample clipped at the end of the range.
    ex.extend(read(reg::STATUS, vec![adxl355::STATUS_DATA_RDY]));
    ex.extend(burst([0, (1 << 19) - 1, 256_000], 1885));
    let mut spi = Mock::new(&ex);
    let mut dev = Adxl355::new(spi.clone());
    dev.init(&Config::default(), &mut NoopDelay::new()).unwrap();
    assert_eq!(dev.range(), Range::G2);
    let s = dev.sample(12.5).unwrap();
    assert_eq!(s.t_s, 12.5);
    assert!((s.specific_force[0] + 0.5 * G0).abs() < 1e-12);
    assert_eq!(s.specific_force[1], 0.0);
    assert!((s.specific_force[2] - G0).abs() < 1e-12);
    assert!((s.temp_c - 15.0).abs() < 0.1, "{}", s.temp_c);
    assert!(!s.saturated);
    assert!(dev.sample(13.5).unwrap().saturated);
    spi.done();
}

#[test]
fn wrong_id_is_refused() {
    let mut spi = Mock::new(&read(reg::DEVID_AD, vec![0xFF, 0xFF, 0xFF]));
    let mut dev = Adxl355::new(spi.clone());
    assert_eq!(
        dev.init(&Config::default(), &mut NoopDelay::new()),
        Err(Error::BadId([0xFF; 3]))
    );
    spi.done();
}

#[test]
fn dead_axis_fails_self_test() {
    let rest = [0, 0, 64_000];
    let st = [0, 19_200, 64_000 + 96_000]; // x does not move
    let mut ex = Vec::new();
    ex.extend(write(reg::RANGE, Range::G8 as u8));
    ex.extend(write(reg::POWER_CTL, 0));
    ex.extend(write(reg::SELF_TEST, adxl355::SELF_TEST_ST1));
    for _ in 0..4 {
        ex.extend(burst(rest, 1885));
    }
    ex.extend(write(
        reg::SELF_TEST,
        adxl355::SELF_TEST_ST1 | adxl355::SELF_TEST_ST2,
    ));
    for _ in 0..4 {
        ex.extend(burst(st, 1885));
    }
    ex.extend(write(reg::SELF_TEST, 0));
    ex.extend(write(reg::POWER_CTL, adxl355::POWER_STANDBY));
    let mut spi = Mock::new(&ex);
    let mut dev = Adxl355::new(spi.clone());
    match dev.self_test(&mut NoopDelay::new()) {
        Err(Error::SelfTest {
            axis: 0,
            response_g,
        }) => assert_eq!(response_g, 0.0),
        other => panic!("{other:?}"),
    }
    spi.done();
}

#[test]
fn no_new_data_is_an_error() {
    let mut spi = Mock::new(&read(reg::STATUS, vec![0]));
    let mut dev = Adxl355::new(spi.clone());
    assert_eq!(dev.sample(0.0), Err(Error::NotReady));
    spi.done();
}

/// A bus that fails every transaction.
struct BrokenBus;
impl ErrorType for BrokenBus {
    type Error = ErrorKind;
}
impl SpiDevice for BrokenBus {
    fn transaction(&mut self, _: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        Err(ErrorKind::Other)
    }
}

#[test]
fn bus_errors_are_returned() {
    let mut dev = Adxl355::new(BrokenBus);
    assert_eq!(dev.check_id(), Err(Error::Spi(ErrorKind::Other)));
    assert_eq!(dev.sample(0.0), Err(Error::Spi(ErrorKind::Other)));
    assert_eq!(
        dev.init(&Config::default(), &mut NoopDelay::new()),
        Err(Error::Spi(ErrorKind::Other))
    );
}
