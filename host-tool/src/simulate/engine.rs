//! The truth integrator: platform attitude as a DCM, C_0^p(t) = C_i^p(t)·C_0^i(t).
//!
//! * C_0^i(t) is exact: the Earth frame turns by Ω t about the polar axis ([`dcm::c_0i`]).
//! * C_i^p(t) follows dC_i^p/dt = −[w_d×] C_i^p. Each substep h (≤ `max_substep_s`) applies the
//!   exact rotation exp(−[(w_d(t+h/2)·h + δ)×]) with w_d at the midpoint taken from a predicted
//!   midpoint attitude, and δ the gyro's random angle increment, N(0, q h) per axis.

#![allow(clippy::needless_range_loop)]

use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::dcm::{self, RADPS_PER_DEG_H};
use super::{InjectedEffect, Scenario, TempProfile};

/// A solar day, s (the period of a set-up's daily drift).
const SOLAR_DAY_S: f64 = 86_400.0;

/// Random-number streams of one seed; separate streams keep each noise source's realisation
/// independent of which other effects are switched on.
pub(crate) mod stream {
    pub(crate) const GYRO: u64 = 0;
    pub(crate) const ACCEL: u64 = 1;
    pub(crate) const MARKOV: u64 = 2;
    pub(crate) const TEMP: u64 = 3;
    pub(crate) const SETUP: u64 = 4;
    pub(crate) const TIMING: u64 = 5;
}

pub(crate) fn rng(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(stream);
    r
}

fn normal(r: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(r)
}

#[derive(Clone, Debug)]
struct Markov {
    sigma: [f64; 3],
    tau_s: [f64; 3],
    /// Current value, rad/s.
    m: [f64; 3],
}

/// Steps the true platform attitude in time. [`super::simulate`] is built on it; tests use it to
/// look at the attitude between samples.
#[derive(Clone, Debug)]
pub struct Simulator {
    g: f64,
    /// Unit polar axis in frame 0 (and in inertial frame i): [0, cos L, sin L].
    n0: Vector3<f64>,
    /// Per axis [D0, Dx, Dy, Dz], rad/s and rad/s/(m/s²).
    coeff: [[f64; 4]; 3],
    /// Per axis xx, xy, xz, yy, yz, zz, rad/s/(m/s²)².
    g2: [[f64; 6]; 3],
    has_g2: bool,
    /// rad/s per s.
    trend: [f64; 3],
    /// rad/s per °C.
    temp_coef: [f64; 3],
    has_temp_drift: bool,
    temp: TempProfile,
    markov: Vec<Markov>,
    /// Periodic drifts: amplitude per axis (rad/s) and period (s).
    sines: Vec<([f64; 3], f64)>,
    /// Daily drift (a set-up error): per axis the cos and sin amplitudes at the solar day, rad/s.
    daily: [[f64; 2]; 3],
    /// Turn-on transients: amplitude per axis (rad/s) and time constant (s).
    transients: Vec<([f64; 3], f64)>,
    /// Drift steps: size per axis (rad/s) and time (s).
    drift_steps: Vec<([f64; 3], f64)>,
    /// ARW density, rad²/s.
    q: f64,
    t: f64,
    c_ip: Matrix3<f64>,
    c_0i: Matrix3<f64>,
    theta: [f64; 3],
    steps: u64,
    rng_gyro: ChaCha8Rng,
    rng_markov: ChaCha8Rng,
}

impl Simulator {
    /// A simulator at t = 0 with C_0^p = I (scenario assumed valid, see [`Scenario::validate`]).
    pub fn new(s: &Scenario) -> Self {
        let lat = s.latitude_deg.to_radians();
        let mut coeff = [[0.0; 4]; 3];
        for (i, row) in coeff.iter_mut().enumerate() {
            for (j, c) in row.iter_mut().enumerate() {
                *c = s.coefficients[4 * i + j] * RADPS_PER_DEG_H;
            }
        }
        let mut sim = Simulator {
            g: s.gravity(),
            n0: Vector3::new(0.0, lat.cos(), lat.sin()),
            coeff,
            g2: [[0.0; 6]; 3],
            has_g2: false,
            trend: s
                .setup_errors
                .drift_trend_deg_h_per_h
                .map(|k| k * RADPS_PER_DEG_H / 3600.0),
            temp_coef: [0.0; 3],
            has_temp_drift: false,
            temp: s.temp_profile.clone(),
            markov: Vec::new(),
            sines: Vec::new(),
            daily: [0, 1, 2].map(|i| {
                let d = &s.setup_errors.daily_drift_deg_h;
                [d[2 * i] * RADPS_PER_DEG_H, d[2 * i + 1] * RADPS_PER_DEG_H]
            }),
            transients: Vec::new(),
            drift_steps: Vec::new(),
            q: s.arw_deg2_per_h * (std::f64::consts::PI / 180.0).powi(2) / 3600.0,
            t: 0.0,
            // At t = 0 frame i coincides with frame 0, so C_i^p(0) = C_0^p(θ0).
            c_ip: dcm::from_euler_zyx(&s.initial_orientation_deg.map(f64::to_radians)),
            c_0i: Matrix3::identity(),
            theta: s.initial_orientation_deg.map(f64::to_radians),
            steps: 0,
            rng_gyro: rng(s.seed, stream::GYRO),
            rng_markov: rng(s.seed, stream::MARKOV),
        };
        for e in &s.effects {
            sim.inject(e);
        }
        sim
    }

    /// Adds injected effect `e` to the truth model's gyro drift (the accelerometer effects act
    /// on the written samples instead; a drift-markov state starts at a draw from its
    /// stationary distribution).
    fn inject(&mut self, e: &InjectedEffect) {
        match e {
            InjectedEffect::G2 {
                d_deg_h_per_mps2_sq,
            } => {
                self.has_g2 = true;
                for i in 0..3 {
                    for k in 0..6 {
                        self.g2[i][k] += d_deg_h_per_mps2_sq[i][k] * RADPS_PER_DEG_H;
                    }
                }
            }
            InjectedEffect::DriftTrend { k_deg_h_per_h } => {
                for i in 0..3 {
                    self.trend[i] += k_deg_h_per_h[i] * RADPS_PER_DEG_H / 3600.0;
                }
            }
            InjectedEffect::TempDrift { c_deg_h_per_c } => {
                self.has_temp_drift = true;
                for i in 0..3 {
                    self.temp_coef[i] += c_deg_h_per_c[i] * RADPS_PER_DEG_H;
                }
            }
            InjectedEffect::DriftMarkov { sigma_deg_h, tau_h } => {
                let sigma = sigma_deg_h.map(|x| x * RADPS_PER_DEG_H);
                let mut m = [0.0; 3];
                for i in 0..3 {
                    m[i] = sigma[i] * normal(&mut self.rng_markov);
                }
                self.markov.push(Markov {
                    sigma,
                    tau_s: tau_h.map(|x| x * 3600.0),
                    m,
                });
            }
            InjectedEffect::DriftSine { a_deg_h, period_h } => {
                self.sines
                    .push((a_deg_h.map(|a| a * RADPS_PER_DEG_H), period_h * 3600.0));
            }
            InjectedEffect::DriftTransient { a_deg_h, tau_h } => {
                self.transients
                    .push((a_deg_h.map(|a| a * RADPS_PER_DEG_H), tau_h * 3600.0));
            }
            InjectedEffect::DriftStep { a_deg_h, t0_h } => {
                self.drift_steps
                    .push((a_deg_h.map(|a| a * RADPS_PER_DEG_H), t0_h * 3600.0));
            }
            InjectedEffect::AccBias { .. }
            | InjectedEffect::AccTemp { .. }
            | InjectedEffect::AccNorth { .. }
            | InjectedEffect::AccScale { .. }
            | InjectedEffect::AccMisalign { .. } => {}
        }
    }

    /// Current time, s.
    pub(crate) fn time_s(&self) -> f64 {
        self.t
    }

    /// C_i^p: inertial → platform.
    pub fn c_ip(&self) -> Matrix3<f64> {
        self.c_ip
    }

    /// C_0^p = C_i^p·C_0^i: Earth frame 0 → platform.
    pub fn c_0p(&self) -> Matrix3<f64> {
        self.c_ip * self.c_0i
    }

    /// Local north in platform axes, C_0^p [0, 1, 0] (frame 0 is ENU).
    pub(crate) fn north(&self) -> Vector3<f64> {
        self.c_0p().column(1).into_owned()
    }

    /// True specific force in platform axes, A = C_0^p [0, 0, g], m/s².
    pub fn specific_force(&self) -> Vector3<f64> {
        self.c_0p() * Vector3::new(0.0, 0.0, self.g)
    }

    /// Euler angles θ = (tx, ty, tz) of C_0^p = Rz·Ry·Rx, rad, unwrapped along the trajectory
    /// (continuous from θ(0) = 0, as a filter integrating θ̇ would have them).
    pub(crate) fn theta_rad(&self) -> [f64; 3] {
        self.theta
    }

    /// Sum of the Gauss–Markov drift states, rad/s.
    pub fn markov_rad_s(&self) -> [f64; 3] {
        let mut out = [0.0; 3];
        for m in &self.markov {
            for i in 0..3 {
                out[i] += m.m[i];
            }
        }
        out
    }

    /// The deterministic part of the drift rate now (all terms but the white noise), rad/s.
    #[cfg(test)]
    pub(crate) fn drift_rate_rad_s(&self) -> Vector3<f64> {
        let a = self.c_0p() * Vector3::new(0.0, 0.0, self.g);
        self.drift(self.t, &a, &self.markov_rad_s())
    }

    fn drift(&self, t: f64, a: &Vector3<f64>, markov: &[f64; 3]) -> Vector3<f64> {
        let mut w = Vector3::zeros();
        let prod = [
            a.x * a.x,
            a.x * a.y,
            a.x * a.z,
            a.y * a.y,
            a.y * a.z,
            a.z * a.z,
        ];
        let dt_temp = if self.has_temp_drift {
            self.temp.at(t) - self.temp.at(0.0)
        } else {
            0.0
        };
        for i in 0..3 {
            let c = &self.coeff[i];
            let mut wi = c[0] + c[1] * a.x + c[2] * a.y + c[3] * a.z;
            if self.has_g2 {
                wi += self.g2[i]
                    .iter()
                    .zip(&prod)
                    .map(|(d, p)| d * p)
                    .sum::<f64>();
            }
            wi += self.trend[i] * t + self.temp_coef[i] * dt_temp + markov[i];
            for (a, p) in &self.sines {
                wi += a[i] * (2.0 * std::f64::consts::PI * t / p).sin();
            }
            if self.daily[i] != [0.0; 2] {
                let (sn, cs) = (std::f64::consts::TAU * t / SOLAR_DAY_S).sin_cos();
                wi += self.daily[i][0] * cs + self.daily[i][1] * sn;
            }
            for (a, tau) in &self.transients {
                wi += a[i] * (-t / tau).exp();
            }
            for (a, t0) in &self.drift_steps {
                if t >= *t0 {
                    wi += a[i];
                }
            }
            w[i] = wi;
        }
        w
    }

    /// One substep of length h.
    fn step(&mut self, h: f64) {
        let t0 = self.t;
        let tm = t0 + 0.5 * h;
        let t1 = t0 + h;
        let g0 = Vector3::new(0.0, 0.0, self.g);
        // Gauss–Markov states: exact discretisation; the rate over the step uses the mean.
        let m0 = self.markov_rad_s();
        for mk in &mut self.markov {
            for i in 0..3 {
                let phi = (-h / mk.tau_s[i]).exp();
                let s = mk.sigma[i] * (1.0 - phi * phi).max(0.0).sqrt();
                mk.m[i] = mk.m[i] * phi + s * normal(&mut self.rng_markov);
            }
        }
        let m1 = self.markov_rad_s();
        let m_mid = [
            0.5 * (m0[0] + m1[0]),
            0.5 * (m0[1] + m1[1]),
            0.5 * (m0[2] + m1[2]),
        ];
        // Predictor: drift at the start, half a step to the midpoint.
        let a0 = self.c_ip * self.c_0i * g0;
        let w0 = self.drift(t0, &a0, &m0);
        let c_0i_m = dcm::c_0i(&self.n0, tm);
        let c_ip_m = dcm::passive(&(w0 * (0.5 * h))) * self.c_ip;
        let am = c_ip_m * c_0i_m * g0;
        let wm = self.drift(tm, &am, &m_mid);
        // Corrector: full step with the midpoint rate plus the random angle increment.
        let mut phi = wm * h;
        if self.q > 0.0 {
            let s = (self.q * h).sqrt();
            for i in 0..3 {
                phi[i] += s * normal(&mut self.rng_gyro);
            }
        }
        self.c_ip = dcm::passive(&phi) * self.c_ip;
        self.steps += 1;
        if self.steps.is_multiple_of(1024) {
            self.c_ip = dcm::reorthonormalize(&self.c_ip);
        }
        self.t = t1;
        self.c_0i = dcm::c_0i(&self.n0, t1);
        self.update_theta();
    }

    fn update_theta(&mut self) {
        let e = dcm::euler_zyx(&self.c_0p());
        for i in 0..3 {
            self.theta[i] += dcm::wrap_pi(e[i] - self.theta[i]);
        }
    }

    /// Advances to `t_s` in equal substeps no longer than `max_substep_s`. Does nothing if
    /// `t_s` is not after the current time.
    pub fn advance_to(&mut self, t_s: f64, max_substep_s: f64) {
        let span = t_s - self.t;
        if span.is_nan() || span <= 0.0 {
            return;
        }
        let n = (span / max_substep_s).ceil().max(1.0) as u64;
        let h = span / n as f64;
        for _ in 0..n {
            self.step(h);
        }
        // Land on the requested time exactly (no accumulation of rounding in t).
        if self.t != t_s {
            self.t = t_s;
            self.c_0i = dcm::c_0i(&self.n0, t_s);
            self.update_theta();
        }
    }
}
