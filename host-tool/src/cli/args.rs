//! Validated parsers of the numeric command-line options, one definition each, used by every
//! subcommand through clap's `value_parser`. A bad value is a usage error (exit code 2) that clap
//! reports naming the option, e.g.
//! `error: invalid value 'nan' for '--period-s <PERIOD_S>': must be a finite number > 0`.
//! NaN, infinities and values out of range never reach the code behind the options.

use crate::recording::check_latitude_deg;

/// Longest duration accepted by `--duration-s`/`--timeout-s`, s (about 31.7 years): far beyond
/// any run, and well inside what `std::time::Duration` holds.
pub(crate) const MAX_DURATION_S: f64 = 1e9;

/// Most seeds a benchmark accepts.
pub(crate) const MAX_SEEDS: u64 = 1_000_000;

fn number(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!(
            "{s} is not finite (NaN and infinity are not allowed)"
        ))
    }
}

/// Any finite number.
pub(crate) fn finite_f64(s: &str) -> Result<f64, String> {
    number(s)
}

/// A finite number > 0.
pub(crate) fn positive_f64(s: &str) -> Result<f64, String> {
    match number(s)? {
        v if v > 0.0 => Ok(v),
        v => Err(format!("{v} is not > 0 (must be a finite number > 0)")),
    }
}

/// A finite number ≥ 0.
pub(crate) fn nonneg_f64(s: &str) -> Result<f64, String> {
    match number(s)? {
        v if v >= 0.0 => Ok(v),
        v => Err(format!("{v} is negative (must be a finite number >= 0)")),
    }
}

/// A window of hours `T0..T1` (`--exclude`): finite, T0 ≤ T1.
pub(crate) fn hours_window(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("{s:?} is not a window T0..T1 in hours (e.g. 12.5..13)"))?;
    let (a, b) = (number(a.trim())?, number(b.trim())?);
    if a > b {
        return Err(format!("the window {a}..{b} ends before it starts"));
    }
    Ok((a, b))
}

/// A latitude in degrees, in the range the recording format accepts (the reader's own check).
pub(crate) fn latitude_deg(s: &str) -> Result<f64, String> {
    check_latitude_deg(number(s)?)
}

/// A duration in seconds: finite, > 0 and at most [`MAX_DURATION_S`] (so converting it to a
/// `Duration` cannot fail).
pub(crate) fn duration_s(s: &str) -> Result<f64, String> {
    match positive_f64(s)? {
        v if v <= MAX_DURATION_S => Ok(v),
        v => Err(format!(
            "{v} s is more than the {MAX_DURATION_S:e} s accepted"
        )),
    }
}

/// Most MiB `--max-memory-mib` takes (1 PiB).
pub const MAX_MEMORY_MIB: u64 = 1 << 30;

/// `--max-memory-mib`: an integer number of MiB in [1, [`MAX_MEMORY_MIB`]], as bytes.
pub fn memory_mib(s: &str) -> Result<usize, String> {
    let v: u64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a whole number of MiB"))?;
    if (1..=MAX_MEMORY_MIB).contains(&v) {
        usize::try_from(v << 20).map_err(|_| format!("{v} MiB is more than this machine addresses"))
    } else {
        Err(format!(
            "{v} is outside [1, {MAX_MEMORY_MIB}] MiB (the option's range)"
        ))
    }
}

/// An integer ≥ 1 that fits a u32 (e.g. a baud rate).
pub(crate) fn positive_u32(s: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(0) => Err("0 is not allowed (must be an integer >= 1)".into()),
        Ok(v) => Ok(v),
        Err(_) => Err(format!(
            "{s:?} is not an integer in 1..={} (must be an integer >= 1)",
            u32::MAX
        )),
    }
}

/// A number of seeds: an integer in 1..=[`MAX_SEEDS`].
pub(crate) fn seed_count(s: &str) -> Result<u64, String> {
    match s.trim().parse::<u64>() {
        Ok(v) if (1..=MAX_SEEDS).contains(&v) => Ok(v),
        _ => Err(format!(
            "{s:?} is not an integer in 1..={MAX_SEEDS} (the number of seeds)"
        )),
    }
}

/// Longest run `--hours` accepts (simulate, plan, bench), h: about 14 months — far beyond a
/// drift identification run (hours to weeks); `plan --hours 1e9` aborted on a 14-TB allocation.
pub(crate) const MAX_HOURS: f64 = 1e4;
/// Sample interval `--rate-s` accepts, s: 0.1 ms to one day.
pub(crate) const RATE_S: (f64, f64) = (1e-4, 86_400.0);
/// Filter period `--period-s` accepts, s: 1 ms to one day.
pub(crate) const PERIOD_S: (f64, f64) = (1e-3, 86_400.0);
/// `--arw` (gyro angle random walk variance density), deg²/h: 1 deg²/h is a random walk of
/// 1 deg/√h, some 10⁴× an INS gyro's.
pub(crate) const MAX_ARW: f64 = 1.0;
/// `--raw-sigma` (1σ of one accelerometer sample), m/s²: 1 ng to 0.1 g.
pub(crate) const RAW_SIGMA_MPS2: (f64, f64) = (1e-8, 1.0);
/// `--gate-nis` (χ² gate on the NIS; 0: off).
pub(crate) const MAX_GATE_NIS: f64 = 1e6;
/// `--alternatives` (plan).
pub(crate) const MAX_ALTERNATIVES: usize = 100;

/// `v` as a person writes it: 0, 60, 86400, 1e-8, 1e9.
fn short(v: f64) -> String {
    if v == 0.0 || (1e-3..1e5).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// A parser of a finite number in `lo..=hi` (`lo` itself excluded when `open_low`), `unit` for
/// the message: `invalid value '1e9' for '--hours <HOURS>': 1e9 is outside (0, 10000] h (the
/// option's range)`.
pub(crate) fn range_f64(
    lo: f64,
    hi: f64,
    open_low: bool,
    unit: &'static str,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v = number(s)?;
        let above_lo = if open_low { v > lo } else { v >= lo };
        if above_lo && v <= hi {
            Ok(v)
        } else {
            Err(format!(
                "{} is outside {}{}, {}]{}{unit} (the option's range)",
                short(v),
                if open_low { "(" } else { "[" },
                short(lo),
                short(hi),
                if unit.is_empty() { "" } else { " " }
            ))
        }
    }
}

/// `--hours` of a run to be made (plan, bench): (0, [`MAX_HOURS`]].
pub(crate) fn hours(s: &str) -> Result<f64, String> {
    range_f64(0.0, MAX_HOURS, true, "h")(s)
}

/// `--hours` of `simulate` (0 allowed: one sample): [0, [`MAX_HOURS`]].
pub(crate) fn hours_or_zero(s: &str) -> Result<f64, String> {
    range_f64(0.0, MAX_HOURS, false, "h")(s)
}

/// `--rate-s`: [`RATE_S`].
pub(crate) fn rate_s(s: &str) -> Result<f64, String> {
    range_f64(RATE_S.0, RATE_S.1, false, "s")(s)
}

/// `--period-s`: [`PERIOD_S`].
pub(crate) fn period_s(s: &str) -> Result<f64, String> {
    range_f64(PERIOD_S.0, PERIOD_S.1, false, "s")(s)
}

/// `--arw`: [0, [`MAX_ARW`]].
pub(crate) fn arw(s: &str) -> Result<f64, String> {
    range_f64(0.0, MAX_ARW, false, "deg^2/h")(s)
}

/// `--raw-sigma`: [`RAW_SIGMA_MPS2`].
pub(crate) fn raw_sigma(s: &str) -> Result<f64, String> {
    range_f64(RAW_SIGMA_MPS2.0, RAW_SIGMA_MPS2.1, false, "m/s^2")(s)
}

/// `--gate-nis`: [0, [`MAX_GATE_NIS`]].
pub(crate) fn gate_nis(s: &str) -> Result<f64, String> {
    range_f64(0.0, MAX_GATE_NIS, false, "")(s)
}

/// `--alternatives`: an integer in 0..=[`MAX_ALTERNATIVES`].
pub(crate) fn alternatives(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(v) if v <= MAX_ALTERNATIVES => Ok(v),
        _ => Err(format!(
            "{s:?} is not an integer in [0, {MAX_ALTERNATIVES}] (the option's range)"
        )),
    }
}

/// `secs` (already checked by [`duration_s`]) as a `Duration`, without a panic path.
pub(crate) fn to_duration(secs: f64, option: &str) -> anyhow::Result<std::time::Duration> {
    std::time::Duration::try_from_secs_f64(secs)
        .map_err(|e| anyhow::anyhow!("{option} {secs}: not a valid duration ({e})"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_parser_refuses_what_it_should() {
        for bad in ["nan", "NaN", "inf", "-inf", "abc", "", "1e400"] {
            assert!(finite_f64(bad).is_err(), "{bad}");
            assert!(positive_f64(bad).is_err(), "{bad}");
            assert!(nonneg_f64(bad).is_err(), "{bad}");
            assert!(duration_s(bad).is_err(), "{bad}");
            assert!(latitude_deg(bad).is_err(), "{bad}");
        }
        assert_eq!(finite_f64("-2.5"), Ok(-2.5));
        assert!(positive_f64("0").is_err() && positive_f64("-1").is_err());
        assert_eq!(positive_f64("1e-9"), Ok(1e-9));
        assert_eq!(nonneg_f64("0"), Ok(0.0));
        assert!(nonneg_f64("-0.1").is_err());
        assert!(duration_s("0").is_err() && duration_s("-1").is_err());
        assert!(duration_s("1e300").is_err(), "would overflow Duration");
        assert_eq!(duration_s("0.5"), Ok(0.5));
        assert!(to_duration(MAX_DURATION_S, "--timeout-s").is_ok());
        assert!(latitude_deg("90.5").is_err() && latitude_deg("-91").is_err());
        assert_eq!(latitude_deg("-39.1"), Ok(-39.1));
        assert!(positive_u32("0").is_err() && positive_u32("-1").is_err());
        assert!(positive_u32("4294967296").is_err());
        assert_eq!(positive_u32("115200"), Ok(115_200));
        assert!(seed_count("0").is_err() && seed_count("1000001").is_err());
        assert_eq!(seed_count("24"), Ok(24));
        assert!(hours("0").is_err() && hours("1e9").is_err() && hours("nan").is_err());
        assert_eq!(hours("60"), Ok(60.0));
        assert_eq!(hours_or_zero("0"), Ok(0.0));
        assert!(rate_s("1e9").is_err() && period_s("0").is_err());
        assert!(raw_sigma("1e-300").is_err() && arw("1e9").is_err() && gate_nis("1e300").is_err());
        assert!(alternatives("1000000000").is_err());
        let e = hours("1e9").unwrap_err();
        assert!(e.contains("1e9 is outside (0, 10000] h"), "{e}");
    }
}
