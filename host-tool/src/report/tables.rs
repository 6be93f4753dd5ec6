//! The report's tables: fit per rung, candidates, ladder, coefficient movement, coefficients.

use super::*;

/// A candidate's physics, folded under its name: the table stays narrow enough for 800 px.
fn physics(about: &str) -> String {
    if about.is_empty() {
        return String::new();
    }
    format!(
        "<details class=\"small\"><summary>physics</summary>{}</details>",
        text(about)
    )
}

/// Parameter sizes a candidate's row shows before the rest folds away.
const SIZES_SHOWN: usize = 6;

pub(super) fn fit_table(h: &mut String, ds: &[Diagnosis]) {
    let rows: Vec<(String, &Diagnosis)> = ds.iter().map(|d| (model_name(&d.model), d)).collect();
    fit_rows(h, "model", &rows);
    if let Some(d) = ds.first() {
        floor_line(h, d);
    }
}

/// One row per fit, labelled in the first column (`what`: model, run): RMS/floor, mean NIS/3
/// and its band, Ljung–Box p, failure windows and whether it is consistent.
pub(super) fn fit_rows(h: &mut String, what: &str, rows: &[(String, &Diagnosis)]) {
    let _ = writeln!(
        h,
        "<table><tr><th class=\"l\">{what}</th><th>RMS/floor x</th><th>y</th><th>z</th><th>mean NIS/3</th><th>{:.1} % band</th><th>Ljung–Box p</th><th>failure windows</th><th>consistent</th></tr>",
        100.0 * Thresholds::default().nis_band_prob
    );
    for (label, d) in rows {
        // Coloured by the one definition of consistent (crate::consistency).
        let band = d.consistency.nis_band;
        let in_band = d.nis_mean >= band[0] && d.nis_mean <= band[1];
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td class=\"{}\">{:.3}</td><td>[{:.3}, {:.3}]</td><td class=\"{}\">{}</td><td>{}</td><td class=\"{}\">{}</td></tr>",
            esc(label),
            d.residual_rms_over_floor[0],
            d.residual_rms_over_floor[1],
            d.residual_rms_over_floor[2],
            if in_band { "ok" } else { "bad" },
            d.nis_mean,
            band[0],
            band[1],
            if white(d.whiteness.p_value) { "ok" } else { "bad" },
            fmt_p(d.whiteness.p_value),
            d.failures.len(),
            if d.consistency.is_consistent() { "ok" } else { "bad" },
            if d.consistency.is_consistent() { "yes" } else { "no" }
        );
    }
    let _ = writeln!(h, "</table>");
}

/// The noise floor of one filter-period mean of `d`'s recording.
pub(super) fn floor_line(h: &mut String, d: &Diagnosis) {
    let _ = writeln!(
        h,
        "<p class=\"small\">Noise floor of one filter-period mean (from raw-sample differences): x {:.3e}, y {:.3e}, z {:.3e} m/s².</p>",
        d.floor_mps2[0], d.floor_mps2[1], d.floor_mps2[2]
    );
}

pub(super) fn ranking_table(h: &mut String, d: &Diagnosis) {
    if d.ranking.is_empty() {
        let _ = writeln!(h, "<p>No candidate left to test.</p>");
        return;
    }
    let _ = writeln!(
        h,
        "<table><tr><th>#</th><th class=\"l\">effect</th><th>statistic</th><th>dof</th><th>p</th><th>p (Holm)</th><th class=\"l\">estimated size ± 1σ (detectable ≥)</th><th>evidence gain (refit)</th><th>RMS/floor after refit (x, y, z)</th></tr>"
    );
    for (i, c) in d.ranking.iter().enumerate() {
        if let Some(why) = &c.untestable {
            let _ = writeln!(h, "<tr><td>{}</td><td class=\"l\">{}{}</td><td colspan=\"7\" class=\"l\">not testable: {}</td></tr>", i + 1, esc(&c.effect), physics(&c.about), text(why));
            continue;
        }
        let size = |p: &crate::diagnose::types::ParamEstimate| {
            format!(
                "<span class=\"n\">{} = {} {} (≥ {})</span><br>",
                esc(&p.name),
                esc(&crate::format::pm(p.value, p.sigma)),
                esc(&p.unit),
                crate::format::sci(p.min_detectable)
            )
        };
        let mut sizes: String = c.params.iter().take(SIZES_SHOWN).map(size).collect();
        if c.params.len() > SIZES_SHOWN {
            // The rest opens in place ("… 9 more").
            let rest: String = c.params.iter().skip(SIZES_SHOWN).map(size).collect();
            let _ = write!(
                sizes,
                "<details><summary>… {} more</summary>{rest}</details>",
                c.params.len() - SIZES_SHOWN
            );
        }
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"l\"><b>{}</b>{}</td><td>{:.1}</td><td>{:.0}</td><td>{}</td><td class=\"{}\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td></tr>",
            i + 1,
            esc(&c.effect),
            physics(&c.about),
            c.statistic,
            c.dof,
            esc(&crate::format::p_value(c.p_value, c.ln_p_value)),
            if c.p_adjusted < 0.01 { "bad" } else { "ok" },
            esc(&crate::format::p_value(c.p_adjusted, c.ln_p_adjusted)),
            sizes,
            c.refit.as_ref().map(|r| format!("{}{:+.1}", if r.converged() { "" } else { "≈" }, r.evidence_gain)).unwrap_or_else(|| "—".into()),
            c.refit
                .as_ref()
                .map(|r| format!("{:.3}, {:.3}, {:.3}", r.rms_over_floor[0], r.rms_over_floor[1], r.rms_over_floor[2]))
                .unwrap_or_else(|| "not refitted".into()),
        );
    }
    let _ = writeln!(h, "</table>");
    if d.ranking
        .iter()
        .any(|c| c.refit.as_ref().is_some_and(|r| !r.converged()))
    {
        let _ = writeln!(
            h,
            "<p>≈: the refit did not converge; its evidence gain is that of a trajectory still moving, approximate, and not ranked.</p>"
        );
    }
}

pub(super) fn ladder_table(h: &mut String, rungs: &[Rung]) {
    let _ = writeln!(
        h,
        "<table><tr><th>rung</th><th class=\"l\">model</th><th>RMS/floor x</th><th>y</th><th>z</th><th>mean NIS/3</th><th>Ljung–Box p</th><th class=\"l\">next: added effect (p)</th></tr>"
    );
    for (i, r) in rungs.iter().enumerate() {
        let next = match &r.next {
            Some((e, p)) => format!("{} (p = {})", esc(e), fmt_p(*p)),
            None => "— (stop: no candidate significant)".into(),
        };
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"l\">{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{}</td><td class=\"l\">{}</td></tr>",
            i,
            esc(&model_name(&r.model)),
            r.residual_rms_over_floor[0],
            r.residual_rms_over_floor[1],
            r.residual_rms_over_floor[2],
            r.nis_mean,
            fmt_p(r.whiteness_p),
            next
        );
    }
    let _ = writeln!(h, "</table>");
}

/// How the 12 drift coefficients moved from rung to rung.
pub(super) fn movement_table(h: &mut String, rungs: &[Rung]) {
    if rungs.len() < 2 {
        return;
    }
    let _ = writeln!(
        h,
        "<h3>How the drift coefficients moved along the ladder (value ± 1σ)</h3>"
    );
    let _ = write!(h, "<table><tr><th class=\"l\">coefficient</th>");
    for (i, r) in rungs.iter().enumerate() {
        let _ = write!(h, "<th>rung {i}: {}</th>", esc(&model_name(&r.model)));
    }
    let _ = writeln!(h, "<th>change / 1σ</th></tr>");
    let n = rungs[0].coefficients.len();
    for k in 0..n {
        let (name, v0, _) = &rungs[0].coefficients[k];
        let _ = write!(h, "<tr><td class=\"l\">{}</td>", esc(name));
        for r in rungs {
            match r.coefficients.get(k) {
                Some((_, v, s)) => {
                    let _ = write!(h, "<td>{}</td>", esc(&pm(*v, *s)));
                }
                None => {
                    let _ = write!(h, "<td>n/a</td>");
                }
            }
        }
        let (_, vl, sl) = rungs[rungs.len() - 1]
            .coefficients
            .get(k)
            .cloned()
            .unwrap_or_default();
        let _ = writeln!(h, "<td>{:+.1}</td></tr>", (vl - v0) / sl);
    }
    let _ = writeln!(
        h,
        "</table><p class=\"small\">Units: D·0 deg/h, D·x/y/z deg/h/(m/s²).</p>"
    );
}

pub(super) fn coefficient_table(h: &mut String, rows: &[CoefRow]) {
    let truth = rows.iter().any(|r| r.truth.is_some());
    let _ = write!(h, "<table><tr><th class=\"l\">parameter</th><th class=\"l\">unit</th><th>estimate ± 1σ total</th><th>noise 1σ</th><th>bound (CRB 1σ)</th><th>noise 1σ / bound</th><th>total / noise</th><th class=\"l\">most from</th><th class=\"l\">holds only without (reach, total 1σ)</th>");
    if truth {
        let _ = write!(h, "<th>truth</th><th>error</th><th>error / 1σ total</th>");
    }
    let _ = writeln!(h, "</tr>");
    for r in rows {
        let _ = write!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.2e}</td><td>{:.2e}</td><td>{:.2}</td><td>{:.2}</td><td class=\"l\">{}</td><td class=\"l\">{}</td>",
            esc(&r.name),
            esc(&r.unit),
            esc(&pm(r.value, r.sigma_total)),
            r.sigma,
            r.bound,
            r.sigma / r.bound,
            r.sigma_total / r.sigma,
            esc(&r.dominant),
            esc(&conditional_cell(&r.conditional_on))
        );
        if truth {
            truth_cells(h, r.value, r.sigma_total, r.truth);
        }
        let _ = writeln!(h, "</tr>");
    }
    let _ = writeln!(h, "</table>");
}

/// The alternatives a coefficient holds only on the absence of, the three farthest-reaching
/// (`—` for none).
fn conditional_cell(on: &[(String, f64)]) -> String {
    if on.is_empty() {
        return "—".into();
    }
    let mut cell = on
        .iter()
        .take(3)
        .map(|(e, z)| format!("{e} ({z:.1})"))
        .collect::<Vec<_>>()
        .join(", ");
    if on.len() > 3 {
        cell += &format!(", +{}", on.len() - 3);
    }
    cell
}

/// `drift-markov`'s σ and τ, each ± its 1σ (the curvature's) with its 1σ interval from the
/// profile likelihood (the honest one where the likelihood's ridge bends), as `identify` prints
/// them ([`crate::identify::markov::MarkovFit::line`]).
pub(super) fn markov_table(h: &mut String, gm: &crate::identify::markov::MarkovFit) {
    let _ = writeln!(
        h,
        "<h3>The Gauss–Markov drift (drift-markov): σ and τ from the data</h3><p>Fitted by marginal likelihood, shared by the three axes; −2 ln L {:.1} below the catalog's σ 0.01 deg/h, τ 5 h.{}</p>",
        gm.evidence_gain,
        if gm.at_bound {
            " <span class=\"bad\">At the edge of the range: no Gauss–Markov wander this run can measure (no 1σ).</span>"
        } else {
            ""
        }
    );
    let _ = writeln!(
        h,
        "<table><tr><th class=\"l\">parameter</th><th class=\"l\">unit</th><th>estimate ± 1σ</th><th>1σ interval (profile likelihood)</th></tr>"
    );
    let rows = [
        (
            "σ (stationary 1σ of each axis' drift)",
            "deg/h",
            gm.sigma_degph,
            gm.sigma_sd_degph,
            gm.sigma_interval_degph,
        ),
        (
            "τ (correlation time)",
            "h",
            gm.tau_h,
            gm.tau_sd_h,
            gm.tau_interval_h,
        ),
    ];
    for (name, unit, v, sd, [lo, hi]) in rows {
        let (est, interval) = if gm.at_bound {
            (crate::format::sig(v, 2), "—".to_string())
        } else {
            (
                pm(v, sd),
                format!(
                    "{}–{}",
                    crate::format::sig(lo, 2),
                    crate::format::sig(hi, 2)
                ),
            )
        };
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\">{unit}</td><td>{}</td><td>{}</td></tr>",
            esc(name),
            esc(&est),
            esc(&interval)
        );
    }
    let _ = writeln!(
        h,
        "</table><p class=\"small\">Correlation of the estimates of ln σ and ln τ: {:.2}.</p>",
        gm.correlation
    );
}

/// The truth, error and error / 1σ cells of an estimate `value` ± `sigma` (dashes without truth).
pub(super) fn truth_cells(h: &mut String, value: f64, sigma: f64, truth: Option<f64>) {
    match truth {
        Some(t) => {
            let e = value - t;
            let z = e / sigma;
            let _ = write!(
                h,
                "<td>{}</td><td>{}</td><td class=\"{}\">{:+.2}</td>",
                num(t),
                with_sigma(e, sigma),
                if z.abs() > 3.0 { "bad" } else { "ok" },
                z
            );
        }
        None => {
            let _ = write!(h, "<td>—</td><td>—</td><td>—</td>");
        }
    }
}
