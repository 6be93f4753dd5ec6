//! The noise at the filter period and steps in the filter-period means.
//!
//! Third differences of consecutive means remove the slow gravity-cone signal (~7e-7 m/s² at
//! 60 s) and keep the means' own noise with variance 20σ_m². Compared with the raw noise over
//! √n they reveal quantised or correlated noise (the floor the filter must use), and an isolated
//! jump of size J leaves the pattern (J, −2J, J): a bias step.

use estimator_core::Measurement;

use super::{axis_name, Action, Finding};

/// A step is reported beyond this many robust 1σ of the third differences.
pub const STEP_SIGMAS: f64 = 8.0;
/// The means' scatter must differ from white raw noise by at least this factor to replace it.
pub const MEAN_NOISE_FACTOR: f64 = 1.5;

/// One third difference of four consecutive means of an axis.
#[derive(Clone, Copy, Debug)]
struct Diff {
    /// Index of the first of the four means.
    k: usize,
    /// The difference as taken (m/s²): on an even grid x₃ − 3x₂ + 3x₁ − x₀, which a jump J
    /// makes −J, 2J or −J.
    raw: f64,
    /// The same difference rescaled to the noise it would have were its four means full windows
    /// of the typical count (m/s²): `raw` · √(20 / (n · Σ cᵢ²/nᵢ)), cᵢ its coefficients, nᵢ
    /// the means' sample counts, n the median count. Every threshold and scatter is taken on
    /// this: a partial last (or first) filter period, or one with rejected samples, has a mean
    /// √(n/nᵢ) noisier. Unweighted, the last period's single sample of a 60-h run at 1 s (√60 ≈
    /// 7.7× the noise of a full mean, on an uneven grid that amplifies it 1.8× more) made 5 of
    /// 60 clean runs report a "step" at the end (issue 27).
    z: f64,
}

/// Third differences of each axis over runs of four consecutive means ([`Diff`]). On an even
/// grid of spacing h this is x₃ − 3x₂ + 3x₁ − x₀; on an uneven one (a window with rejected
/// samples, cut short by a gap or by the end of the record is tagged off the grid) it is the
/// third divided difference times 6h³, h = (t₃ − t₀)/3, which also vanishes on a line or a
/// parabola. Runs with a spacing outside [h/2, 3h/2] (a gap) are skipped. Skipping every uneven
/// run instead once hid a 2e-2 m/s² bias step: the samples at the jump are rejected as
/// glitches, which moves exactly the step's window off the grid.
fn third_differences(means: &[Measurement], axis: usize) -> Vec<Diff> {
    let typical = typical_count(means);
    let mut out = vec![];
    for k in 0..means.len().saturating_sub(3) {
        let t = |i: usize| means[k + i].t_s;
        let h = (t(3) - t(0)) / 3.0;
        let regular = h > 0.0 && (0..3).all(|i| (t(i + 1) - t(i) - h).abs() <= 0.5 * h);
        if !regular {
            continue;
        }
        let x = |i: usize| means[k + i].specific_force[axis];
        let even = (0..3).all(|i| ((t(i + 1) - t(i)) / h - 1.0).abs() < 1e-3);
        let c: [f64; 4] = if even {
            [-1.0, 3.0, -3.0, 1.0]
        } else {
            // Σ xᵢ / Πⱼ≠ᵢ (tᵢ − tⱼ), scaled to the even grid's form.
            core::array::from_fn(|i| {
                let den: f64 = (0..4).filter(|&j| j != i).map(|j| t(i) - t(j)).product();
                6.0 * h * h * h / den
            })
        };
        let raw: f64 = (0..4).map(|i| c[i] * x(i)).sum();
        // Σ cᵢ²/nᵢ against the even grid's 20/n: the variance of this difference in units of
        // a full-window one's.
        let var: f64 = (0..4)
            .map(|i| c[i] * c[i] / f64::from(means[k + i].count.max(1)))
            .sum();
        let rel = (var * typical / 20.0).sqrt();
        let z = if rel > 0.0 { raw / rel } else { raw };
        out.push(Diff { k, raw, z });
    }
    out
}

/// The median sample count of a filter-period mean (the full window's, whatever the partial
/// first and last ones hold).
pub fn typical_count(means: &[Measurement]) -> f64 {
    let mut counts: Vec<u32> = means.iter().map(|m| m.count).collect();
    if counts.is_empty() {
        return 1.0;
    }
    let mid = counts.len() / 2;
    f64::from(*counts.select_nth_unstable(mid).1).max(1.0)
}

/// Robust 1σ (MAD) of the rescaled differences ([`Diff::z`]).
fn robust_sigma(d: &[Diff]) -> f64 {
    let mut v: Vec<f64> = d.iter().map(|x| x.z.abs()).collect();
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    1.4826 * *m
}

/// Compares the means' scatter with raw noise/√n; returns the means' own 1σ per axis to use when
/// they disagree (other axes keep raw/√n), with a finding.
pub fn check_mean_noise(
    means: &[Measurement],
    raw_sigma: &[f64; 3],
    findings: &mut Vec<Finding>,
) -> Option<[f64; 3]> {
    if means.is_empty() {
        return None;
    }
    let n = typical_count(means);
    let mut out = [0.0; 3];
    let mut any = vec![];
    for a in 0..3 {
        let d = third_differences(means, a);
        let white = raw_sigma[a] / n.sqrt();
        out[a] = white;
        if d.len() < 30 {
            continue;
        }
        let emp = robust_sigma(&d) / 20f64.sqrt();
        // The MAD of overlapping third differences: relative 1σ ≈ 2/√N.
        let tol = MEAN_NOISE_FACTOR
            .ln()
            .max(6.0 * 2.0 / (d.len() as f64).sqrt());
        if (emp / white).ln().abs() > tol {
            out[a] = emp;
            any.push(format!("{} {:.2}×", axis_name(a), emp / white));
        }
    }
    if any.is_empty() {
        return None;
    }
    findings.push(Finding {
        kind: "mean-noise",
        message: format!(
            "the filter-period means scatter unlike white raw noise would ({}; raw 1σ [{:.2e}, {:.2e}, {:.2e}] m/s^2 over √{n:.0}): \
             quantised outputs or correlated noise; the filter uses the means' own scatter [{:.2e}, {:.2e}, {:.2e}] m/s^2",
            any.join(", "),
            raw_sigma[0],
            raw_sigma[1],
            raw_sigma[2],
            out[0],
            out[1],
            out[2]
        ),
        start_s: None,
        end_s: None,
        samples: 0,
        action: Action::Repaired,
    });
    Some(out)
}

/// Steps: third differences beyond [`STEP_SIGMAS`]; one finding per jump (not repaired).
pub fn check_steps(means: &[Measurement], skip: &[bool; 3], findings: &mut Vec<Finding>) {
    for a in (0..3).filter(|&a| !skip[a]) {
        let d = third_differences(means, a);
        if d.len() < 30 {
            continue;
        }
        let s = robust_sigma(&d);
        if s <= 0.0 {
            continue;
        }
        let mut k = 0;
        while k < d.len() {
            if d[k].z.abs() > STEP_SIGMAS * s {
                // The event spans consecutive exceedances; its peak is the middle of (J, −2J, J).
                let start = k;
                while k < d.len() && d[k].k <= d[start].k + 4 && d[k].k - d[start].k <= 4 {
                    k += 1;
                }
                let peak = (start..k)
                    .max_by(|&i, &j| d[i].z.abs().total_cmp(&d[j].z.abs()))
                    .unwrap_or(start);
                let j = -d[peak].raw / 2.0;
                let idx = (d[peak].k + 2).min(means.len() - 1);
                findings.push(Finding {
                    kind: "step",
                    message: format!(
                        "axis {}: the filter-period means jump by about {j:+.2e} m/s^2 near t = {:.0} s ({:.0}× the noise of their third differences): \
                         a bias step or a disturbance of the platform; not repaired",
                        axis_name(a),
                        means[idx].t_s,
                        d[peak].z.abs() / s
                    ),
                    start_s: Some(means[d[start].k].t_s),
                    end_s: Some(means[(d[k - 1].k + 3).min(means.len() - 1)].t_s),
                    samples: 0,
                    action: Action::NotRepaired,
                });
            } else {
                k += 1;
            }
        }
    }
}
