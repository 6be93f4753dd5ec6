//! Averaging raw accelerometer samples to the filter period, shared by firmware and host.
//!
//! Windows are `[k·T, (k+1)·T)` from t = 0. Each window's mean is tagged at the *mean sample
//! time*, not at the window end: the platform turns ~0.25°/min, so tagging at the end would cost up
//! to ~1.6e-2 m/s² (model.md). The measurement variance is the raw-sample variance over the count.

use nalgebra::Vector3;

/// One raw accelerometer sample.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Sample {
    /// Seconds since the gyros reached stable operation.
    pub t_s: f64,
    /// Specific force along the platform axes, m/s².
    pub specific_force: [f64; 3],
    /// Platform temperature, °C (NaN when not measured).
    pub temp_c: f64,
}

/// One filter-period measurement: the mean of a window of samples.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Measurement {
    /// Mean sample time, s.
    pub t_s: f64,
    /// Mean specific force, m/s².
    pub specific_force: [f64; 3],
    /// Mean temperature, °C (NaN when not measured).
    pub temp_c: f64,
    /// Number of samples averaged.
    pub count: u32,
    /// Variance of the mean per axis, (m/s²)².
    pub variance: [f64; 3],
    /// Spread of the sample times about `t_s`, s² (0 for a single sample). The mean of a
    /// curving signal differs from its value at the mean time by ½·A''·this; the model adds it.
    pub time_var_s2: f64,
}

/// Accumulates samples into filter-period means.
#[derive(Clone, Debug)]
pub struct Averager {
    period_s: f64,
    raw_variance: [f64; 3],
    window: i64,
    count: u32,
    t0: f64,
    a0: [f64; 3],
    sum_dt: f64,
    sum_dt2: f64,
    sum_da: [f64; 3],
    sum_temp: f64,
    temp_count: u32,
}

impl Averager {
    /// Windows of `period_s` seconds; `raw_sigma_mps2` is the 1σ noise of one raw sample per axis.
    pub fn new(period_s: f64, raw_sigma_mps2: [f64; 3]) -> Self {
        Averager {
            period_s,
            raw_variance: raw_sigma_mps2.map(|s| s * s),
            window: i64::MIN,
            count: 0,
            t0: 0.0,
            a0: [0.0; 3],
            sum_dt: 0.0,
            sum_dt2: 0.0,
            sum_da: [0.0; 3],
            sum_temp: 0.0,
            temp_count: 0,
        }
    }

    /// The filter period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Adds a sample; returns the previous window's mean when the sample opens a new window.
    /// Samples must come in time order (the caller checks; see the recording reader).
    pub fn push(&mut self, s: &Sample) -> Option<Measurement> {
        let w = libm::floor(s.t_s / self.period_s) as i64;
        let done = if w != self.window { self.flush() } else { None };
        if self.count == 0 {
            self.window = w;
            self.t0 = s.t_s;
            self.a0 = s.specific_force;
        }
        self.count += 1;
        self.sum_dt += s.t_s - self.t0;
        self.sum_dt2 += (s.t_s - self.t0) * (s.t_s - self.t0);
        for i in 0..3 {
            self.sum_da[i] += s.specific_force[i] - self.a0[i];
        }
        if s.temp_c.is_finite() {
            self.sum_temp += s.temp_c;
            self.temp_count += 1;
        }
        done
    }

    /// Ends the current window and returns its mean, if it holds any sample.
    pub fn flush(&mut self) -> Option<Measurement> {
        if self.count == 0 {
            return None;
        }
        let n = f64::from(self.count);
        let mean = Vector3::from(self.sum_da) / n + Vector3::from(self.a0);
        let m = Measurement {
            t_s: self.t0 + self.sum_dt / n,
            specific_force: mean.into(),
            temp_c: if self.temp_count > 0 {
                self.sum_temp / f64::from(self.temp_count)
            } else {
                f64::NAN
            },
            count: self.count,
            variance: self.raw_variance.map(|v| v / n),
            time_var_s2: (self.sum_dt2 / n - (self.sum_dt / n) * (self.sum_dt / n)).max(0.0),
        };
        self.count = 0;
        self.sum_dt = 0.0;
        self.sum_dt2 = 0.0;
        self.sum_da = [0.0; 3];
        self.sum_temp = 0.0;
        self.temp_count = 0;
        Some(m)
    }
}
