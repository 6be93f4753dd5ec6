//! The story at the top of the page: the verdict as its own block (trusted or not, and whether
//! the final model fits), and what changed between the starting and the final model — what the
//! ladder added and which drift coefficients moved, in units of their 1σ.

use super::*;

/// Coefficients listed as having moved most.
const MOVED_SHOWN: usize = 5;

/// Whether the final model fits, in capitals: the one definition of consistent decides.
fn fit_word(d: &Diagnosis) -> &'static str {
    if d.consistency.is_consistent() {
        "THE FINAL MODEL FITS"
    } else if d.choice.is_none() {
        "OUTSIDE THE CATALOG"
    } else {
        "THE FINAL MODEL DOES NOT FIT YET"
    }
}

/// One model's fit in words: mean NIS/3 against its 99.9 % band, Ljung–Box p against the
/// whiteness level.
pub(super) fn fit_words(d: &Diagnosis) -> String {
    let band = d.consistency.nis_band;
    let inside = d.nis_mean >= band[0] && d.nis_mean <= band[1];
    format!(
        "mean NIS/3 {:.3} {} its {:.1} % band {:.3}–{:.3}, Ljung–Box p {} ({})",
        d.nis_mean,
        if inside { "inside" } else { "<b>outside</b>" },
        100.0 * Thresholds::default().nis_band_prob,
        band[0],
        band[1],
        fmt_p(d.whiteness.p_value),
        if white(d.whiteness.p_value) {
            "white"
        } else {
            "<b>not white</b>"
        }
    )
}

/// The verdict block: TRUSTED or NOT TRUSTED, whether the final model fits, the story in one
/// sentence, and the reasons not to trust.
pub(super) fn verdict_block(h: &mut String, input: &ReportInput) {
    let first = &input.diagnoses[0];
    let last = &input.diagnoses[input.diagnoses.len() - 1];
    let trusted = input.untrusted.is_empty();
    let _ = writeln!(
        h,
        "<section id=\"verdict\" class=\"headline {}\"><p class=\"state\">{}</p><p class=\"fit\">{}</p>",
        if trusted { "trusted" } else { "untrusted" },
        if trusted { "TRUSTED" } else { "NOT TRUSTED" },
        fit_word(last)
    );
    if input.diagnoses.len() > 1 {
        let added: Vec<String> = last
            .model
            .iter()
            .filter(|m| !first.model.contains(m))
            .map(|m| format!("<code>{}</code>", esc(m)))
            .collect();
        let _ = writeln!(
            h,
            "<p>The starting model ({}) did not explain the measurements: {}. The ladder added {}; the final model ({}): {}.</p>",
            esc(&model_name(&first.model)),
            fit_words(first),
            added.join(", "),
            esc(&model_name(&last.model)),
            fit_words(last)
        );
    } else {
        let _ = writeln!(
            h,
            "<p>The model ({}): {}.</p>",
            esc(&model_name(&last.model)),
            fit_words(last)
        );
    }
    untrusted_list(h, &input.untrusted);
    if trusted {
        held_on(h, &input.coefficients);
    }
    let _ = writeln!(h, "</section>");
}

/// What a trusted result holds on: the alternatives its drift coefficients hold only on the
/// absence of (as `identify` and `diagnose` end; the table of section 5 per coefficient).
fn held_on(h: &mut String, coefficients: &[super::CoefRow]) {
    let on = crate::diagnose::alternatives::held_on(
        coefficients
            .iter()
            .map(|r| (r.name.as_str(), r.conditional_on.as_slice())),
    );
    let said = match crate::diagnose::alternatives::held_on_words(&on) {
        Some(words) => format!(
            "Trusted on the absence of what this run cannot rule out: {}; a second run from another orientation (<code>driftid plan</code>) or a bench value settles it (per coefficient: <a href=\"#coefficients\">section 5</a>, “holds only without”).",
            esc(&words)
        ),
        None => "No alternative this run cannot rule out moves a drift coefficient beyond its total 1σ.".into(),
    };
    let _ = writeln!(h, "<p>{said}</p>");
}

/// The reasons not to trust the numbers, as a list (nothing when there are none).
pub(super) fn untrusted_list(h: &mut String, untrusted: &[String]) {
    if untrusted.is_empty() {
        return;
    }
    let _ = writeln!(
        h,
        "<p>The numbers below are computed, but the tool does not trust them:</p><ul>"
    );
    for r in untrusted {
        let _ = writeln!(h, "<li>{}</li>", text(r));
    }
    let _ = writeln!(h, "</ul>");
}

/// What the ladder added (each parameter ± 1σ and its size in σ) and the drift coefficients
/// that moved most between the first and the final rung.
pub(super) fn what_changed(h: &mut String, input: &ReportInput) {
    added_table(h, &input.ladder);
    moved_table(h, &input.ladder);
}

/// Each rung's added parameters with their estimates.
fn added_table(h: &mut String, rungs: &[Rung]) {
    let _ = writeln!(
        h,
        "<table><tr><th>rung</th><th class=\"l\">added</th><th class=\"l\">parameter</th><th>estimate ± 1σ</th><th class=\"l\">unit</th><th>|estimate| / 1σ</th></tr>"
    );
    for (k, r) in rungs.iter().enumerate().skip(1) {
        let prev = &rungs[k - 1];
        let added: Vec<&str> = r
            .model
            .iter()
            .filter(|m| !prev.model.contains(m))
            .map(String::as_str)
            .collect();
        for (name, unit, v, s) in r.effect_params.iter().skip(prev.effect_params.len()) {
            let _ = writeln!(
                h,
                "<tr><td>{k}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td class=\"l\">{}</td><td>{:.1}</td></tr>",
                esc(&added.join(" + ")),
                esc(name),
                esc(&pm(*v, *s)),
                esc(unit),
                v.abs() / s
            );
        }
    }
    let _ = writeln!(h, "</table>");
}

/// How one drift coefficient moved along the ladder.
pub(crate) struct Moved {
    /// Its name (`DX0`, …).
    pub(crate) name: String,
    /// Value and 1σ in the starting model.
    pub(crate) start: (f64, f64),
    /// Value and 1σ in the final model.
    pub(crate) end: (f64, f64),
    /// (final − start) / final 1σ.
    pub(crate) sigmas: f64,
}

/// The drift coefficients ordered by how far they moved from the first to the final rung, in
/// units of the final 1σ (the CLI's "moved … σ").
pub(crate) fn moved(rungs: &[Rung]) -> Vec<Moved> {
    let (Some(a), Some(b)) = (rungs.first(), rungs.last()) else {
        return vec![];
    };
    let mut m: Vec<_> = a
        .coefficients
        .iter()
        .zip(&b.coefficients)
        .map(|((n, v0, s0), (_, v1, s1))| Moved {
            name: n.clone(),
            start: (*v0, *s0),
            end: (*v1, *s1),
            sigmas: (v1 - v0) / s1,
        })
        .filter(|c| c.sigmas.is_finite())
        .collect();
    m.sort_by(|x, y| y.sigmas.abs().total_cmp(&x.sigmas.abs()));
    m
}

fn moved_table(h: &mut String, rungs: &[Rung]) {
    let m = moved(rungs);
    if m.is_empty() {
        return;
    }
    let _ = writeln!(
        h,
        "<table><tr><th class=\"l\">drift coefficient</th><th>starting model ± 1σ</th><th>final model ± 1σ</th><th>moved, final 1σ</th></tr>"
    );
    for c in m.iter().take(MOVED_SHOWN) {
        let z = c.sigmas;
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td class=\"{}\">{:+.1}</td></tr>",
            esc(&c.name),
            esc(&pm(c.start.0, c.start.1)),
            esc(&pm(c.end.0, c.end.1)),
            if z.abs() > 3.0 { "bad" } else { "ok" },
            z
        );
    }
    let _ = writeln!(h, "</table>");
    if let Some(rest) = m.get(MOVED_SHOWN) {
        let _ = writeln!(
            h,
            "<p class=\"small\">The other {} drift coefficients moved by at most {:.1} σ (all in section 4). Units: D·0 deg/h, D·x/y/z deg/h/(m/s²).</p>",
            m.len() - MOVED_SHOWN,
            rest.sigmas.abs()
        );
    }
}
