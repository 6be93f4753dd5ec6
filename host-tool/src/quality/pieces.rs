//! The screening of a long record on all cores: [`estimator_core::screening::screen`]'s result,
//! bit for bit, with its outlier test (most of its time) run on pieces of the record at once.
//!
//! A sample's outlier verdict reads only the samples and flags within
//! [`screening::outlier_reach`] of it, so a piece screened with that many samples either side
//! (as they stand after the stuck-run step) gives the verdicts the whole record gives there.

use estimator_core::screening::{self, flag, ScreenConfig, ScreenSummary};
use estimator_core::Sample;

/// Fewest samples per piece: below, the outlier test takes well under a millisecond and the
/// pieces' set-up (a copy of their flags and margins) is not worth it.
const MIN_PIECE: usize = 32_768;

/// [`screening::screen`] with the outlier test on all cores (rayon's pool), run on `series`
/// (the samples, or their residuals from a model of the slow signal: same length and times).
pub(crate) fn screen(
    samples: &[Sample],
    series: &[Sample],
    sigma: &[f64; 3],
    cfg: &ScreenConfig,
    flags: &mut [u8],
) -> ScreenSummary {
    let n = samples.len().min(flags.len());
    let piece = n.div_ceil(rayon::current_num_threads()).max(MIN_PIECE);
    screen_in_pieces(samples, series, sigma, cfg, flags, piece)
}

/// [`screen`] in pieces of `piece` samples (one piece: the one-thread screening itself).
fn screen_in_pieces(
    samples: &[Sample],
    series: &[Sample],
    sigma: &[f64; 3],
    cfg: &ScreenConfig,
    flags: &mut [u8],
    piece: usize,
) -> ScreenSummary {
    let n = samples.len().min(flags.len()).min(series.len());
    let (samples, series, flags) = (&samples[..n], &series[..n], &mut flags[..n]);
    if piece >= n {
        // `screening::screen`'s steps, the outlier test on the series.
        let mut sum = screening::screen_runs(samples, sigma, cfg, flags);
        let ordered = screening::times_ordered(series);
        for (a, s) in sigma.iter().enumerate() {
            sum.outliers[a] = screening::flag_outliers(series, flags, a, *s, cfg, ordered);
        }
        sum.rejected = flags.iter().filter(|f| **f != 0).count();
        return sum;
    }
    let mut sum = screening::screen_runs(samples, sigma, cfg, flags);
    let ordered = screening::times_ordered(samples);
    let reach = screening::outlier_reach(cfg);
    let before = flags.to_vec();
    let screen_piece = |k: usize, out: &mut [u8]| -> [usize; 3] {
        let (lo, hi) = (k * piece, k * piece + out.len());
        let (from, to) = (lo.saturating_sub(reach), (hi + reach).min(n));
        let mut window = before[from..to].to_vec();
        for (a, s) in sigma.iter().enumerate() {
            screening::flag_outliers(&series[from..to], &mut window, a, *s, cfg, ordered);
        }
        out.copy_from_slice(&window[lo - from..hi - from]);
        // An outlier is never stuck (the test skips stuck samples), so its axis bits are
        // those of its outliers.
        std::array::from_fn(|a| {
            let bits = flag::OUTLIER | screening::axis_bit(a);
            out.iter().filter(|f| **f & bits == bits).count()
        })
    };
    let mut counts = vec![[0usize; 3]; n.div_ceil(piece)];
    // The first piece on this thread, the others on the pool (see `crate::pool`).
    let pieces = flags.chunks_mut(piece).zip(counts.iter_mut()).enumerate();
    crate::pool::caller_first(pieces, |(k, (out, c))| *c = screen_piece(k, out));
    for c in counts {
        for a in 0..3 {
            sum.outliers[a] += c[a];
        }
    }
    sum.rejected = flags.iter().filter(|f| **f != 0).count();
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pieces of any size give the one-thread screening's flags and counts bit for bit, on a
    /// record with every kind of fault, some of them astride the pieces' seams.
    #[test]
    fn pieces_screen_as_the_whole_record() {
        let sigma = 1e-3;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let noise = |u: u64| ((u >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 3.5 * sigma;
        let mut s: Vec<Sample> = (0..5000)
            .map(|k| Sample {
                t_s: k as f64,
                specific_force: [
                    0.01 * (k as f64 * 1e-3).sin() + noise(next()),
                    -0.02 + noise(next()),
                    9.8 + noise(next()),
                ],
                temp_c: f64::NAN,
            })
            .collect();
        for _ in 0..400 {
            let k = (next() % 4985) as usize;
            let a = (next() % 3) as usize;
            match next() % 5 {
                0 => s[k].specific_force[a] = f64::NAN,
                1 => s[k].specific_force = [0.0; 3],
                2 => {
                    // A stuck run: 11 equal readings.
                    let v = s[k].specific_force[a];
                    for x in &mut s[k..k + 10] {
                        x.specific_force[a] = v;
                    }
                    // Glitches beside it: their sides reach past the run, up to 4h away.
                    s[k + 10].specific_force[a] += sigma * (9 + next() % 6) as f64;
                    s[k.saturating_sub(2)].specific_force[a] -= sigma * (9 + next() % 6) as f64;
                }
                3 => s[k].t_s = f64::NAN,
                _ => s[k].specific_force[a] += sigma * (5 + next() % 40) as f64,
            }
        }
        let cfg = ScreenConfig::default();
        let sig = [sigma; 3];
        let mut whole = vec![0u8; s.len()];
        let expected = screening::screen(&s, &sig, &cfg, &mut whole);
        assert!(expected.outliers.iter().sum::<usize>() > 20, "{expected:?}");
        assert!(expected.stuck.iter().sum::<usize>() > 20, "{expected:?}");
        for piece in [1, 7, 61, 333, 1000, 2499, 4999] {
            let mut flags = vec![0xffu8; s.len()];
            let got = screen_in_pieces(&s, &s, &sig, &cfg, &mut flags, piece);
            assert_eq!(got, expected, "summary, pieces of {piece}");
            assert!(flags == whole, "flags, pieces of {piece}");
        }
    }
}
