//! The verdict: one paragraph in plain words. Whether the model is consistent is decided in one
//! place only, [`crate::consistency`] (its thresholds are named there, once); this module words
//! that decision and the evidence's choice.

use super::types::Diagnosis;

/// Failure windows named in an "outside the catalog" verdict (the longest list stays readable).
pub(crate) const NAMED_WINDOWS: usize = 5;

/// Whether the model explains the data: the one definition ([`crate::consistency`]).
pub fn is_consistent(d: &Diagnosis) -> bool {
    d.consistency.is_consistent()
}

/// The verdict of diagnosis `d` whose candidates were tested at level `alpha`.
pub(crate) fn verdict(d: &Diagnosis, alpha: f64) -> String {
    let said = chosen_or_not(d, alpha);
    match &d.unconverged_rival {
        Some(rival) => format!("{said} Not settled: {rival}."),
        None => said,
    }
}

/// The verdict without the rival a refit that did not converge leaves open.
fn chosen_or_not(d: &Diagnosis, alpha: f64) -> String {
    let state = state(d);
    if d.choice.is_some() {
        return missing_effect(d, &state);
    }
    if is_consistent(d) {
        return format!(
            "{state} The model explains the measurements: the residual is at the noise floor, white and consistent with its covariance; no catalog effect earns its place (score tests at {:.0} %, refits by evidence).",
            alpha * 100.0
        );
    }
    outside_catalog(d, &state)
}

/// The fit in one sentence: RMS/floor, NIS/3 in its consistency band, Ljung–Box p.
fn state(d: &Diagnosis) -> String {
    let rms: Vec<String> = d
        .residual_rms_over_floor
        .iter()
        .map(|r| format!("{r:.2}"))
        .collect();
    format!(
        "Residual RMS / noise floor = [{}] (x, y, z), mean NIS/3 = {:.3} (99.9 % band {:.3}–{:.3}), Ljung–Box p = {}.",
        rms.join(", "),
        d.nis_mean,
        d.consistency.nis_band[0],
        d.consistency.nis_band[1],
        // One p-value style (`format::p_value`): its log where p underflows.
        crate::format::p_value(
            d.whiteness.p_value,
            crate::stats::chi2_ln_sf(d.whiteness.ljung_box_q, d.whiteness.dof)
        )
    )
}

/// The evidence chose an effect: why, how the model fits with it, and its confounded rivals.
fn missing_effect(d: &Diagnosis, state: &str) -> String {
    let Some(choice) = &d.choice else {
        return state.to_string();
    };
    let c = d.ranking.iter().find(|c| c.effect == choice.effect);
    let mut s = format!(
        "{state} The model misses a physical effect: {}.",
        choice.reason
    );
    if let Some(r) = c.and_then(|c| c.refit.as_ref()) {
        s += &format!(
            " With it the residual RMS / floor is [{:.2}, {:.2}, {:.2}], NIS/3 {:.3}, Ljung–Box p {:.1e} ({}).",
            r.rms_over_floor[0],
            r.rms_over_floor[1],
            r.rms_over_floor[2],
            r.nis_mean,
            r.whiteness_p,
            if r.consistent { "consistent" } else { "still not consistent" }
        );
    }
    if let Some(c) = c {
        s += &format!(" {}", c.about);
        for cf in d
            .confounding
            .iter()
            .filter(|cf| !cf.separated && (cf.a == c.effect || cf.b == c.effect))
        {
            let rival = if cf.a == c.effect { &cf.b } else { &cf.a };
            s += &format!(
                " Caution: `{rival}` leaves almost the same signature on this run (canonical correlation {:.3}); the data barely separate them. What would: {}.",
                cf.canonical_correlation, cf.separate_by
            );
        }
    }
    s
}

/// Not consistent and nothing earns its place: what fails, what the residual still correlates
/// with, where, and how to define the missing effect.
fn outside_catalog(d: &Diagnosis, state: &str) -> String {
    let why = d.consistency.failures.join("; ");
    let corr: Vec<String> = d
        .correlations
        .iter()
        .filter_map(|c| {
            let m = c.corr.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            (m > c.bound99).then(|| format!("{} ({:+.2})", c.regressor, m))
        })
        .collect();
    let windows: Vec<String> = d
        .failures
        .iter()
        .take(NAMED_WINDOWS)
        .map(|f| format!("{:.1}–{:.1} h (axis {})", f.start_h, f.end_h, f.worst_axis))
        .collect();
    format!(
        "{state} OUTSIDE THE CATALOG: the model does not explain the measurements ({why}), and no catalog effect improves it enough to earn its place. \
         The residual still correlates with: {}; it fails most in: {}. Define the missing effect in a file \
         (`--effects FILE.toml`, README \"Effects defined in a file\") as an expression of A_x, A_y, A_z, t_h, temp_c and its parameters, and diagnose again.",
        if corr.is_empty() { "none of the regressors beyond chance".to_string() } else { corr.join(", ") },
        if windows.is_empty() { "no particular window".to_string() } else { windows.join(", ") }
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::consistency::{assess, Thresholds};
    use crate::diagnose::types::{FailureWindow, Series, Whiteness};

    /// A diagnosis of NIS/3 `nis`, Ljung–Box p `p` and RMS/floor `rms`, nothing chosen.
    pub(crate) fn diagnosis(nis: f64, p: f64, rms: f64) -> Diagnosis {
        Diagnosis {
            model: vec![],
            floor_mps2: [1e-4; 3],
            residual_rms_mps2: [rms * 1e-4; 3],
            residual_rms_over_floor: [rms; 3],
            nis_mean: nis,
            nis_band95: [0.95, 1.05],
            whiteness: Whiteness {
                p_value: p,
                ..Whiteness::default()
            },
            failures: vec![FailureWindow {
                start_h: 1.0,
                end_h: 2.0,
                nis_mean: 3.0,
                worst_axis: 'y',
            }],
            correlations: vec![],
            ranking: vec![],
            confounding: vec![],
            consistency: assess(nis, 3600, p, [rms; 3], 0.0, &Thresholds::default()),
            choice: None,
            unconverged_rival: None,
            verdict: String::new(),
            convergence: None,
            series: Series::default(),
            profiled_refits: vec![],
        }
    }

    #[test]
    fn the_words_follow_the_one_definition() {
        let ok = diagnosis(1.0, 0.5, 1.0);
        assert!(is_consistent(&ok));
        assert!(verdict(&ok, 0.01).contains("The model explains the measurements"));
        // Each failing check alone makes it "outside the catalog", naming the check.
        for (d, says) in [
            (diagnosis(1.2, 0.5, 1.0), "mean NIS/3"),
            (diagnosis(1.0, 1e-5, 1.0), "not white"),
            (diagnosis(1.0, 0.5, 1.2), "residual RMS"),
        ] {
            assert!(!is_consistent(&d));
            let v = verdict(&d, 0.01);
            assert!(v.contains("OUTSIDE THE CATALOG"), "{v}");
            assert!(v.contains(says), "{v}");
            assert!(v.contains("1.0–2.0 h (axis y)"), "{v}");
        }
    }
}
