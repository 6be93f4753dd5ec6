//! Data faults the simulator can add to a recording after the physics (`driftid simulate
//! --fault`): a sensor pinned at a rail, a short disturbance of the platform. Unlike the
//! effects they are not part of the truth model; they are what the data-quality screening must
//! find, name and exclude (docs/data-quality.md).

use std::fmt;
use std::str::FromStr;

use crate::recording::RawSample;

/// Help text describing the `--fault` syntax.
pub(crate) const FAULT_SYNTAX_HELP: &str = "\
NAME=v1,v2,... (repeatable). Faults, applied to the written samples after the physics:
  saturate=AXIS,LIMIT,T0_H,T1_H   from T0_H to T1_H hours, readings of AXIS (x, y or z) beyond
                                  +-LIMIT m/s^2 read +-LIMIT (the sensor pinned at its rails)
  burst=AXIS,SIZE,T0_H,DURATION_S from T0_H hours for DURATION_S seconds, SIZE m/s^2 added to
                                  AXIS (a disturbance of the platform: a door slammed, a bump)
  step=AXIS,SIZE,T0_H             from T0_H hours on, SIZE m/s^2 added to AXIS (a bias step)
  flip=AXIS                       AXIS written with its sign flipped (a wiring or configuration
                                  slip; the metadata and the other axes as they should be)
Example: --fault saturate=x,7,10,22 --fault burst=y,0.3,30,60 --fault step=y,1e-3,30";

/// A data fault added to simulated samples.
#[derive(Clone, Debug, PartialEq)]
pub enum Fault {
    /// Readings of `axis` clamped to ±`limit` between `t0_h` and `t1_h`.
    Saturate {
        /// 0, 1, 2 for x, y, z.
        axis: usize,
        /// The rail, m/s² (> 0).
        limit: f64,
        /// Start, h.
        t0_h: f64,
        /// End, h.
        t1_h: f64,
    },
    /// `size` added to `axis` for `duration_s` from `t0_h`.
    Burst {
        /// 0, 1, 2 for x, y, z.
        axis: usize,
        /// m/s².
        size: f64,
        /// Start, h.
        t0_h: f64,
        /// Duration, s (> 0).
        duration_s: f64,
    },
    /// Readings of `axis` written with the opposite sign, the whole run.
    Flip {
        /// 0, 1, 2 for x, y, z.
        axis: usize,
    },
}

impl Fault {
    /// Applies the fault to `samples`; returns how many samples it changed.
    pub fn apply(&self, samples: &mut [RawSample]) -> usize {
        let mut n = 0;
        match *self {
            Fault::Saturate {
                axis,
                limit,
                t0_h,
                t1_h,
            } => {
                for s in samples
                    .iter_mut()
                    .filter(|s| (t0_h * 3600.0..=t1_h * 3600.0).contains(&s.t_s))
                {
                    let v = &mut s.specific_force_mps2[axis];
                    let c = v.clamp(-limit, limit);
                    if c != *v {
                        *v = c;
                        n += 1;
                    }
                }
            }
            Fault::Burst {
                axis,
                size,
                t0_h,
                duration_s,
            } => {
                let t0 = t0_h * 3600.0;
                for s in samples
                    .iter_mut()
                    .filter(|s| s.t_s >= t0 && s.t_s < t0 + duration_s)
                {
                    s.specific_force_mps2[axis] += size;
                    n += 1;
                }
            }
            Fault::Flip { axis } => {
                for s in samples.iter_mut() {
                    s.specific_force_mps2[axis] = -s.specific_force_mps2[axis];
                }
                n = samples.len();
            }
        }
        n
    }
}

fn axis_of(s: &str) -> Result<usize, String> {
    match s.trim() {
        "x" | "X" => Ok(0),
        "y" | "Y" => Ok(1),
        "z" | "Z" => Ok(2),
        other => Err(format!("axis {other:?} is not x, y or z")),
    }
}

impl FromStr for Fault {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (name, rest) = s
            .split_once('=')
            .ok_or_else(|| format!("{s:?}: expected NAME=AXIS,v1,v2,v3 (saturate or burst)"))?;
        let mut parts: Vec<&str> = rest.split(',').map(str::trim).collect();
        if name.trim() == "flip" {
            return match parts[..] {
                [a] => Ok(Fault::Flip {
                    axis: axis_of(a).map_err(|e| format!("flip: {e}"))?,
                }),
                _ => Err(format!("flip: expected one AXIS (x, y or z), got {rest:?}")),
            };
        }
        if name.trim() == "step" && parts.len() == 3 {
            // A step is a burst that lasts: to the end of any recording.
            parts.push("inf-step");
        }
        if parts.len() != 4 {
            return Err(format!(
                "{name}: expected AXIS and 3 numbers, comma-separated, got {rest:?}"
            ));
        }
        let axis = axis_of(parts[0]).map_err(|e| format!("{name}: {e}"))?;
        let mut v = [0.0; 3];
        for (o, p) in v.iter_mut().zip(&parts[1..]) {
            if *p == "inf-step" {
                *o = f64::INFINITY;
                continue;
            }
            *o = p
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{name}: {p:?} is not a finite number"))?;
        }
        match name.trim() {
            "saturate" => {
                if v[0] <= 0.0 || v[2] < v[1] {
                    return Err(format!(
                        "saturate: LIMIT must be > 0 and T1_H >= T0_H, got {rest:?}"
                    ));
                }
                Ok(Fault::Saturate {
                    axis,
                    limit: v[0],
                    t0_h: v[1],
                    t1_h: v[2],
                })
            }
            "step" => Ok(Fault::Burst {
                axis,
                size: v[0],
                t0_h: v[1],
                duration_s: f64::INFINITY,
            }),
            "burst" => {
                if v[2] <= 0.0 {
                    return Err(format!("burst: DURATION_S must be > 0, got {rest:?}"));
                }
                Ok(Fault::Burst {
                    axis,
                    size: v[0],
                    t0_h: v[1],
                    duration_s: v[2],
                })
            }
            other => Err(format!(
                "unknown fault {other:?} (saturate, burst, step or flip)"
            )),
        }
    }
}

impl fmt::Display for Fault {
    /// The command-line syntax; parses back to the same value.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ax = |a: usize| ['x', 'y', 'z'][a];
        match *self {
            Fault::Saturate {
                axis,
                limit,
                t0_h,
                t1_h,
            } => write!(f, "saturate={},{limit:?},{t0_h:?},{t1_h:?}", ax(axis)),
            Fault::Burst {
                axis,
                size,
                t0_h,
                duration_s,
            } if duration_s == f64::INFINITY => write!(f, "step={},{size:?},{t0_h:?}", ax(axis)),
            Fault::Burst {
                axis,
                size,
                t0_h,
                duration_s,
            } => write!(f, "burst={},{size:?},{t0_h:?},{duration_s:?}", ax(axis)),
            Fault::Flip { axis } => write!(f, "flip={}", ax(axis)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_apply_and_print_back() {
        let f: Fault = "saturate=x,1.5,0,1".parse().unwrap();
        assert_eq!(f.to_string().parse::<Fault>().unwrap(), f);
        let flip: Fault = "flip=y".parse().unwrap();
        assert_eq!(flip, Fault::Flip { axis: 1 });
        assert_eq!(flip.to_string().parse::<Fault>().unwrap(), flip);
        assert!("flip=y,1".parse::<Fault>().is_err());
        let mut s: Vec<RawSample> = (0..4)
            .map(|k| RawSample {
                t_s: k as f64 * 1800.0,
                specific_force_mps2: [[-2.0, 1.0, 2.0, 3.0][k], 0.0, 9.8],
                temp_c: None,
            })
            .collect();
        // t = 0, 1800, 3600 s are within [0, 1] h; 3.0 at 5400 s is not.
        assert_eq!(f.apply(&mut s), 2);
        let x: Vec<f64> = s.iter().map(|s| s.specific_force_mps2[0]).collect();
        assert_eq!(x, [-1.5, 1.0, 1.5, 3.0]);
        let b: Fault = "burst=z,0.3,0.5,1800".parse().unwrap();
        assert_eq!(b.apply(&mut s), 1);
        assert_eq!(s[1].specific_force_mps2[2], 9.8 + 0.3);
        assert!("saturate=w,1,0,1".parse::<Fault>().is_err());
        assert!("burst=x,1,0,0".parse::<Fault>().is_err());
        assert!("saturate=x,1,2".parse::<Fault>().is_err());
    }
}
