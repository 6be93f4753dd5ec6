//! Effects the simulator can inject on top of the paper's drift model, and their command-line
//! syntax `NAME=v1,v2,…[:w1,w2,…]`.

use std::fmt;
use std::str::FromStr;

/// Names of the injectable effects, as on the command line and in the truth file.
pub(crate) const EFFECT_NAMES: [&str; 12] = [
    "g2",
    "acc-bias",
    "acc-scale",
    "acc-misalign",
    "drift-trend",
    "drift-markov",
    "temp-drift",
    "drift-sine",
    "drift-transient",
    "acc-temp",
    "drift-step",
    "acc-north",
];

/// Help text describing the `--effect` syntax.
pub(crate) const EFFECT_SYNTAX_HELP: &str = "\
NAME=v1,v2,... (repeatable; the same effect twice adds up). Effects:
  g2=18 values          drift += sum_{j<=k} D(i)_jk A_j A_k, deg/h/(m/s^2)^2; 6 per axis X,Y,Z in order xx,xy,xz,yy,yz,zz.
                        A static run sees 15 combinations (A_x^2+A_y^2+A_z^2 = g^2): the truth file and the
                        estimates give D(i)0 += g^2 D(i)zz, G(i)xx-zz = D(i)xx - D(i)zz, G(i)yy-zz = D(i)yy - D(i)zz,
                        G(i)xy, G(i)xz, G(i)yz (estimator-core/src/effects/g2.rs)
  acc-bias=bx,by,bz     accelerometer bias, m/s^2
  acc-scale=sx,sy,sz    accelerometer scale-factor error, ppm (z_i += s_i*1e-6*A_i)
  acc-misalign=xy,xz,yx,yz,zx,zy   z_i += sum_{j!=i} m_ij A_j, rad
  drift-trend=kx,ky,kz  drift += k*t/3600, deg/h per hour
  drift-markov=sx,sy,sz:tx,ty,tz   first-order Gauss-Markov drift, std deg/h : time constant h
  temp-drift=cx,cy,cz   drift += c*(T(t)-T(0)), deg/h per deg C; adds a temp_c column
  drift-sine=ax,ay,az:P drift += a*sin(2*pi*t/P), deg/h, period P in h (not in the catalog)
  drift-transient=ax,ay,az:tau   turn-on transient: drift += a*exp(-t/tau), deg/h, tau in h (not in the catalog)
  acc-temp=kx,ky,kz     accelerometer bias += k*(T(t)-T(0)), m/s^2 per deg C; adds a temp_c column
  drift-step=ax,ay,az:T0 drift step: drift += a from T0 hours on, deg/h (not in the catalog)
  acc-north=kx,ky,kz    z_i += k_i*north_i, m/s^2 per unit, north the local north in platform axes: an
                        Earth-fixed horizontal disturbance, e.g. the field's pull on the accelerometers
                        (not in the catalog; an effects file names it: docs/effect-files.md)
Example: --effect acc-bias=1e-4,0,0 --effect drift-markov=0.01,0.01,0.01:5,5,5";

/// An effect the truth simulator can inject. Serialised as `{"name": "acc-bias", "params": {…}}`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "name", content = "params", rename_all = "kebab-case")]
pub enum InjectedEffect {
    /// Gyro drift ∝ products of specific force: w_d,i += Σ_{j≤k} D(i)_jk A_j A_k,
    /// deg/h/(m/s²)², per axis in order xx, xy, xz, yy, yz, zz.
    G2 { d_deg_h_per_mps2_sq: [[f64; 6]; 3] },
    /// Accelerometer bias: z += b, m/s².
    AccBias { b_mps2: [f64; 3] },
    /// Accelerometer scale factor: z_i += s_i·1e-6·A_i, ppm.
    AccScale { s_ppm: [f64; 3] },
    /// Accelerometer misalignment: z_i += Σ_{j≠i} m_ij A_j, rad, order xy, xz, yx, yz, zx, zy.
    AccMisalign { m_rad: [f64; 6] },
    /// Drift trend: w_d,i += k_i·t/3600, deg/h per hour.
    DriftTrend { k_deg_h_per_h: [f64; 3] },
    /// First-order Gauss–Markov drift with std σ (deg/h) and time constant τ (h), started in its
    /// stationary distribution.
    DriftMarkov {
        sigma_deg_h: [f64; 3],
        tau_h: [f64; 3],
    },
    /// Temperature-driven drift: w_d,i += c_i (T(t) − T(0)), deg/h per °C.
    TempDrift { c_deg_h_per_c: [f64; 3] },
    /// Periodic drift (not in the catalog): w_d,i += a_i sin(2π t / P), deg/h, P in h.
    DriftSine { a_deg_h: [f64; 3], period_h: f64 },
    /// Turn-on transient (not in the catalog): w_d,i += a_i exp(−t/τ), deg/h, τ in h.
    DriftTransient { a_deg_h: [f64; 3], tau_h: f64 },
    /// Temperature-driven accelerometer bias: z_i += k_i (T(t) − T(0)),
    /// m/s² per °C.
    AccTemp { k_mps2_per_c: [f64; 3] },
    /// Drift step (not in the catalog): w_d,i += a_i for t ≥ T0, deg/h, T0 in h (a sudden change
    /// of a gyro's constant drift: a kink, not a jump, in the accelerometers).
    DriftStep { a_deg_h: [f64; 3], t0_h: f64 },
    /// Accelerometer error along local north (not in the catalog): z_i += k_i·north_i, m/s²
    /// per unit, north = C_0^p·[0, 1, 0] the local north in platform axes.
    AccNorth { k_mps2: [f64; 3] },
}

impl InjectedEffect {
    /// The effect's name (`acc-bias`, …).
    pub fn name(&self) -> &'static str {
        match self {
            InjectedEffect::G2 { .. } => "g2",
            InjectedEffect::AccBias { .. } => "acc-bias",
            InjectedEffect::AccScale { .. } => "acc-scale",
            InjectedEffect::AccMisalign { .. } => "acc-misalign",
            InjectedEffect::DriftTrend { .. } => "drift-trend",
            InjectedEffect::DriftMarkov { .. } => "drift-markov",
            InjectedEffect::TempDrift { .. } => "temp-drift",
            InjectedEffect::DriftSine { .. } => "drift-sine",
            InjectedEffect::DriftTransient { .. } => "drift-transient",
            InjectedEffect::AccTemp { .. } => "acc-temp",
            InjectedEffect::DriftStep { .. } => "drift-step",
            InjectedEffect::AccNorth { .. } => "acc-north",
        }
    }

    /// All parameters are finite; Markov σ ≥ 0 and τ > 0.
    pub(crate) fn validate(&self) -> Result<(), String> {
        let vals = self.values();
        if vals.iter().flatten().any(|v| !v.is_finite()) {
            return Err(format!("{}: parameters must be finite", self.name()));
        }
        if let InjectedEffect::DriftSine { period_h: t, .. }
        | InjectedEffect::DriftTransient { tau_h: t, .. } = self
        {
            if *t <= 0.0 {
                return Err(format!(
                    "{}: the period or time constant must be > 0",
                    self.name()
                ));
            }
        }
        if let InjectedEffect::DriftStep { t0_h, .. } = self {
            if *t0_h < 0.0 {
                return Err("drift-step: the step time must be >= 0 h".into());
            }
        }
        if let InjectedEffect::DriftMarkov { sigma_deg_h, tau_h } = self {
            if sigma_deg_h.iter().any(|s| *s < 0.0) {
                return Err("drift-markov: sigma must be >= 0".into());
            }
            if tau_h.iter().any(|t| *t <= 0.0) {
                return Err("drift-markov: tau must be > 0".into());
            }
        }
        Ok(())
    }

    /// Parameter groups as on the command line (groups separated by ':').
    fn values(&self) -> Vec<Vec<f64>> {
        match self {
            InjectedEffect::G2 {
                d_deg_h_per_mps2_sq,
            } => {
                vec![d_deg_h_per_mps2_sq.iter().flatten().copied().collect()]
            }
            InjectedEffect::AccBias { b_mps2 } => vec![b_mps2.to_vec()],
            InjectedEffect::AccScale { s_ppm } => vec![s_ppm.to_vec()],
            InjectedEffect::AccMisalign { m_rad } => vec![m_rad.to_vec()],
            InjectedEffect::DriftTrend { k_deg_h_per_h } => vec![k_deg_h_per_h.to_vec()],
            InjectedEffect::DriftMarkov { sigma_deg_h, tau_h } => {
                vec![sigma_deg_h.to_vec(), tau_h.to_vec()]
            }
            InjectedEffect::TempDrift { c_deg_h_per_c } => vec![c_deg_h_per_c.to_vec()],
            InjectedEffect::AccTemp { k_mps2_per_c } => vec![k_mps2_per_c.to_vec()],
            InjectedEffect::AccNorth { k_mps2 } => vec![k_mps2.to_vec()],
            InjectedEffect::DriftSine {
                a_deg_h,
                period_h: t,
            }
            | InjectedEffect::DriftTransient { a_deg_h, tau_h: t }
            | InjectedEffect::DriftStep { a_deg_h, t0_h: t } => {
                vec![a_deg_h.to_vec(), vec![*t]]
            }
        }
    }
}

impl fmt::Display for InjectedEffect {
    /// The command-line syntax, e.g. `acc-bias=0.0001,0.0,0.0`; parses back to the same value.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}=", self.name())?;
        for (g, group) in self.values().iter().enumerate() {
            if g > 0 {
                write!(f, ":")?;
            }
            for (i, v) in group.iter().enumerate() {
                if i > 0 {
                    write!(f, ",")?;
                }
                write!(f, "{v:?}")?;
            }
        }
        Ok(())
    }
}

fn parse_list<const N: usize>(name: &str, what: &str, s: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "{name}: expected {N} comma-separated {what}, got {} ({s:?})",
            parts.len()
        ));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p
            .parse::<f64>()
            .map_err(|_| format!("{name}: {p:?} is not a number"))?;
        if !o.is_finite() {
            return Err(format!("{name}: {p:?} is not finite"));
        }
    }
    Ok(out)
}

/// Whether an effect's values `rest` come in the groups its name takes (`groups` of them,
/// split at `:`): one list, or values and time constants or times for the drift processes.
fn check_groups(name: &str, rest: &str, groups: usize) -> Result<(), String> {
    let want_groups = match name {
        "drift-markov" | "drift-sine" | "drift-transient" | "drift-step" => 2,
        _ => 1,
    };
    if EFFECT_NAMES.contains(&name) && groups != want_groups {
        return Err(
            if ["drift-sine", "drift-transient", "drift-step"].contains(&name) {
                format!("{name}: expected a_x,a_y,a_z:time (h), got {rest:?}")
            } else if want_groups == 2 {
                format!("{name}: expected sigma_x,sigma_y,sigma_z:tau_x,tau_y,tau_z, got {rest:?}")
            } else {
                format!("{name}: expected one comma-separated list, got {rest:?}")
            },
        );
    }
    Ok(())
}

impl FromStr for InjectedEffect {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (name, rest) = s.split_once('=').ok_or_else(|| {
            format!(
                "expected NAME=v1,v2,..., got {s:?}; names: {}",
                EFFECT_NAMES.join(", ")
            )
        })?;
        let name = name.trim();
        let groups: Vec<&str> = rest.split(':').collect();
        check_groups(name, rest, groups.len())?;
        let e = match name {
            "g2" => {
                let v: [f64; 18] = parse_list(
                    name,
                    "values (6 per axis X,Y,Z: xx,xy,xz,yy,yz,zz)",
                    groups[0],
                )?;
                let mut d = [[0.0; 6]; 3];
                for (i, row) in d.iter_mut().enumerate() {
                    row.copy_from_slice(&v[6 * i..6 * i + 6]);
                }
                InjectedEffect::G2 {
                    d_deg_h_per_mps2_sq: d,
                }
            }
            "acc-bias" => InjectedEffect::AccBias {
                b_mps2: parse_list(name, "values (m/s^2)", groups[0])?,
            },
            "acc-scale" => InjectedEffect::AccScale {
                s_ppm: parse_list(name, "values (ppm)", groups[0])?,
            },
            "acc-misalign" => InjectedEffect::AccMisalign {
                m_rad: parse_list(name, "values (xy,xz,yx,yz,zx,zy, rad)", groups[0])?,
            },
            "drift-trend" => InjectedEffect::DriftTrend {
                k_deg_h_per_h: parse_list(name, "values (deg/h per h)", groups[0])?,
            },
            "drift-markov" => InjectedEffect::DriftMarkov {
                sigma_deg_h: parse_list(name, "sigmas (deg/h)", groups[0])?,
                tau_h: parse_list(name, "time constants (h)", groups[1])?,
            },
            "temp-drift" => InjectedEffect::TempDrift {
                c_deg_h_per_c: parse_list(name, "values (deg/h per deg C)", groups[0])?,
            },
            "drift-sine" => InjectedEffect::DriftSine {
                a_deg_h: parse_list(name, "amplitudes (deg/h)", groups[0])?,
                period_h: parse_list::<1>(name, "period (h)", groups[1])?[0],
            },
            "acc-temp" => InjectedEffect::AccTemp {
                k_mps2_per_c: parse_list(name, "values (m/s^2 per deg C)", groups[0])?,
            },
            "drift-transient" => InjectedEffect::DriftTransient {
                a_deg_h: parse_list(name, "amplitudes (deg/h)", groups[0])?,
                tau_h: parse_list::<1>(name, "time constant (h)", groups[1])?[0],
            },
            "acc-north" => InjectedEffect::AccNorth {
                k_mps2: parse_list(name, "values (m/s^2 per unit of north)", groups[0])?,
            },
            "drift-step" => InjectedEffect::DriftStep {
                a_deg_h: parse_list(name, "step sizes (deg/h)", groups[0])?,
                t0_h: parse_list::<1>(name, "step time (h)", groups[1])?[0],
            },
            _ => {
                return Err(format!(
                    "unknown effect {name:?}; known: {}",
                    EFFECT_NAMES.join(", ")
                ))
            }
        };
        e.validate()?;
        Ok(e)
    }
}
