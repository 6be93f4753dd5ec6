//! The recording's temperature and where temperature drift stands.

use super::*;

/// The name of the temperature-drift effect.
pub(super) const TEMP_DRIFT: &str = "temp-drift";

/// Whether the report plots the temperature of diagnosis `d`: the recording has temperatures and
/// either they vary, or temperature drift is a tested candidate or in the model. (A constant
/// temperature leaves temperature drift untestable: nothing to see.)
pub(super) fn shows_temperature(d: &Diagnosis) -> bool {
    let t: Vec<f64> = d
        .series
        .temp_c
        .iter()
        .copied()
        .filter(|t| t.is_finite())
        .collect();
    let varies = t.iter().any(|v| (v - t[0]).abs() > 1e-6);
    let named = d.model.iter().any(|m| m == TEMP_DRIFT)
        || d.ranking
            .iter()
            .any(|c| c.effect == TEMP_DRIFT && c.untestable.is_none());
    !t.is_empty() && (varies || named)
}

/// Where temperature drift stands in diagnosis `d`: one sentence.
pub(super) fn temperature_status(input: &ReportInput, d: usize) -> String {
    let dg = &input.diagnoses[d];
    if dg.model.iter().any(|m| m == TEMP_DRIFT) {
        return format!("{TEMP_DRIFT} is in this model");
    }
    let Some((k, c)) = dg
        .ranking
        .iter()
        .enumerate()
        .find(|(_, c)| c.effect == TEMP_DRIFT)
    else {
        return format!("{TEMP_DRIFT} is not in the catalog of this run");
    };
    match &c.untestable {
        Some(why) => format!("{TEMP_DRIFT} could not be tested: {why}"),
        None => format!(
            "{TEMP_DRIFT}: candidate #{} of {}, p (Holm) = {}",
            k + 1,
            dg.ranking.len(),
            crate::format::p_value(c.p_adjusted, c.ln_p_adjusted)
        ),
    }
}

/// The temperature-drift estimates, value ± 1σ ([`crate::format::pm`]): the model's when it is
/// in the model, else the score test's one-step estimates.
pub(super) fn temperature_notes(input: &ReportInput, d: usize) -> Vec<String> {
    let dg = &input.diagnoses[d];
    let one = |name: &str, unit: &str, v: f64, s: f64| {
        format!("{name} = {} {unit}", crate::format::pm(v, s))
    };
    let (what, items): (&str, Vec<String>) = if dg.model.iter().any(|m| m == TEMP_DRIFT) {
        let names: Vec<&str> = crate::catalog::builtin(TEMP_DRIFT)
            .map(|e| e.params().iter().map(|p| p.name).collect())
            .unwrap_or_default();
        let params = input
            .ladder
            .get(d)
            .map(|r| &r.effect_params[..])
            .unwrap_or(&[]);
        let items = params
            .iter()
            .filter(|p| names.contains(&p.0.as_str()))
            .map(|(n, u, v, s)| one(n, u, *v, *s))
            .collect();
        ("estimated", items)
    } else {
        let items = dg
            .ranking
            .iter()
            .filter(|c| c.effect == TEMP_DRIFT && c.untestable.is_none())
            .flat_map(|c| c.params.iter())
            .map(|p| one(&p.name, &p.unit, p.value, p.sigma))
            .collect();
        ("score-test size (one step from this model)", items)
    };
    if items.is_empty() {
        return vec![];
    }
    vec![format!("{TEMP_DRIFT} {what}: {}", items.join("; "))]
}

/// The recording's temperature over time, the failure windows shaded; the caption and the notes
/// say where temperature drift stands.
pub(super) fn temperature<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    input: &ReportInput,
    d: usize,
) -> Result<()> {
    let dg = &input.diagnoses[d];
    let s = &dg.series;
    let x = x_range(&s.t_h);
    let notes = temperature_notes(input, d);
    let (chart_area, text_area) = split_notes(area, notes.len());
    let pts = decimate(&s.t_h, |k| s.temp_c[k], x, COLS);
    let lo = pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let hi = pts.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let pad = ((hi - lo) * 0.08).max(0.5);
    let y = if lo.is_finite() && hi.is_finite() {
        (lo - pad, hi + pad)
    } else {
        (0.0, 1.0)
    };
    let p = Panel {
        caption: Some(temperature_status(input, d)),
        x_desc: Some("time since start, h".into()),
        y_desc: "temperature, °C".into(),
        y,
        lines: vec![Line {
            label: Some("temp_c (recording)".into()),
            color: LINE,
            width: 2,
            dashed: false,
            pts,
        }],
        shade: shade_of(dg, None),
        legend: true,
        ..Panel::default()
    };
    time_panel(&chart_area, x, &p)?;
    draw_notes(&text_area, &notes)
}
