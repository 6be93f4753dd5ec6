//! The plots' unit tests.

use super::*;
use crate::consistency::{assess, Thresholds};
use crate::diagnose::types::{Candidate, Rung, Whiteness};
use crate::report::ReportInput;

/// A 10-h run at one update a minute: a varying temperature, NIS of a consistent model but
/// for a failure window, and a ladder that added temp-drift.
fn input() -> ReportInput {
    let n = 600;
    let t_h: Vec<f64> = (0..n).map(|j| j as f64 / 60.0).collect();
    let wave = |j: usize, f: f64| (f * j as f64).sin();
    let series = Series {
        t_h: t_h.clone(),
        measured: (0..n).map(|j| [wave(j, 0.01), 0.1, 9.8]).collect(),
        predicted: (0..n).map(|j| [wave(j, 0.01), 0.1, 9.8]).collect(),
        residual: (0..n).map(|j| [1e-4 * wave(j, 1.3); 3]).collect(),
        innovation: (0..n).map(|j| [1e-4 * wave(j, 1.7); 3]).collect(),
        innovation_sigma: vec![[1e-4; 3]; n],
        whitened: (0..n).map(|j| [wave(j, 1.7); 3]).collect(),
        nis: (0..n).map(|j| 3.0 * (1.0 + 0.9 * wave(j, 2.1))).collect(),
        temp_c: t_h.iter().map(|t| 20.0 + 0.5 * t).collect(),
    };
    let candidate = Candidate {
        effect: "temp-drift".into(),
        about: String::new(),
        statistic: 50.0,
        dof: 3.0,
        p_value: 1e-10,
        p_adjusted: 3e-10,
        ln_p_value: 1e-10f64.ln(),
        ln_p_adjusted: 3e-10f64.ln(),
        params: vec![],
        refit: None,
        untestable: None,
    };
    let d = |model: Vec<String>| Diagnosis {
        model,
        floor_mps2: [1e-4; 3],
        residual_rms_mps2: [0.7e-4; 3],
        residual_rms_over_floor: [0.7; 3],
        nis_mean: 1.0,
        nis_band95: [0.95, 1.05],
        whiteness: Whiteness {
            acf: vec![[0.01; 3]; 5],
            acf_bound95: 0.08,
            ljung_box_q: 10.0,
            dof: 15.0,
            p_value: 0.8,
        },
        failures: vec![crate::diagnose::types::FailureWindow {
            start_h: 2.0,
            end_h: 3.0,
            nis_mean: 2.0,
            worst_axis: 'x',
        }],
        correlations: crate::diagnose::correlations(&series, &[0.0; 600]),
        ranking: vec![candidate.clone()],
        confounding: vec![],
        consistency: assess(1.0, n, 0.8, [0.7; 3], 0.0, &Thresholds::default()),
        choice: None,
        unconverged_rival: None,
        verdict: String::new(),
        convergence: None,
        series: series.clone(),
        profiled_refits: vec![],
    };
    let rung = |model: Vec<String>, params: Vec<(String, String, f64, f64)>| Rung {
        model,
        residual_rms_over_floor: [1.3, 1.0, 0.9],
        nis_mean: 1.0,
        whiteness_p: 0.5,
        coefficients: vec![],
        effect_params: params,
        consistent: true,
        next: None,
        next_reason: None,
    };
    let k = |n: &str, v: f64| (n.to_string(), "deg/h/degC".to_string(), v, 2.07e-7);
    ReportInput {
        title: "t".into(),
        recording: "r.csv".into(),
        description: None,
        diagnoses: vec![d(vec![]), d(vec!["temp-drift".into()])],
        ladder: vec![
            rung(vec![], vec![]),
            rung(
                vec!["temp-drift".into()],
                vec![k("KX", 5.54e-6), k("KY", -1.0e-6), k("KZ", 3.0e-7)],
            ),
        ],
        coefficients: vec![],
        findings: vec![],
        untrusted: vec![],
        provenance: Default::default(),
        markov: None,
    }
}

/// Where the SVG `<text>` element holding exactly `label` has its text (plotters writes
/// `<text …>label` and a newline).
fn find_text(svg: &str, label: &str) -> Option<usize> {
    [
        format!(">{label}\n"),
        format!(">\n{label}\n"),
        format!(">{label}<"),
    ]
    .iter()
    .find_map(|p| svg.find(p.as_str()))
}

/// The x coordinate of the SVG `<text>` element that holds `label`.
fn text_x(svg: &str, label: &str) -> f64 {
    let at = find_text(svg, label).expect(label);
    let start = svg[..at].rfind("<text").unwrap();
    let attr = &svg[start..at];
    let x = attr.find(" x=\"").unwrap() + 4;
    let end = attr[x..].find('"').unwrap();
    attr[x..x + end].parse().unwrap()
}

#[test]
fn a_varying_temperature_is_plotted_with_the_estimates() {
    let input = input();
    let figs = figures(&input);
    assert!(figs.iter().any(|f| f.kind == Kind::Temperature(0)));
    assert_eq!(
        temperature_status(&input, 0),
        "temp-drift: candidate #1 of 1, p (Holm) = 3.00e-10"
    );
    // The model's estimates with the digits their 1σ calls for (format::pm).
    let notes = temperature_notes(&input, 1);
    assert_eq!(
        notes,
        ["temp-drift estimated: KX = 5.54e-6 ± 2.1e-7 deg/h/degC; KY = -1.00e-6 ± 2.1e-7 deg/h/degC; KZ = 3.0e-7 ± 2.1e-7 deg/h/degC"]
    );
    assert_eq!(ladder_estimates(&input.ladder).len(), 1);
    assert!(ladder_estimates(&input.ladder)[0].contains("KX = 5.54e-6 ± 2.1e-7"));
    // A constant temperature: temp-drift untestable, no temperature plot.
    let mut flat = input.diagnoses[0].clone();
    flat.series.temp_c = vec![20.0; 600];
    flat.ranking[0].untestable = Some("no varying temp_c".into());
    assert!(!shows_temperature(&flat));
    // No temperature column at all: nothing to plot.
    flat.series.temp_c = vec![f64::NAN; 600];
    assert!(!shows_temperature(&flat));
}

#[test]
fn legends_sit_beside_the_plotting_area() {
    let input = input();
    let plot_right = (WIDTH as i32 - LEGEND_W) as f64;
    for fig in figures(&input) {
        let svg = svg(&fig, &input).unwrap();
        let labels: &[&str] = match fig.kind {
            Kind::Residual(_) => &["failure window", "±3 × noise floor", "residual"],
            Kind::Nis(_) => &["failure window", "1 (model consistent)"],
            Kind::Temperature(_) => &["failure window", "temp_c (recording)"],
            Kind::Correlations(_) => &["x axis residual"],
            Kind::Ladder => &["x axis"],
            _ => &[],
        };
        for l in labels {
            assert!(
                text_x(&svg, l) > plot_right,
                "{:?}: legend entry {l} at x = {} inside the plot",
                fig.kind,
                text_x(&svg, l)
            );
        }
    }
}

#[test]
fn nis_is_on_a_log_axis() {
    // The rolling band and the raw values span decades; a log axis shows ticks like 0.1 and
    // 10 together with 1.
    let input = input();
    let fig = figure(Kind::Nis(0), &input);
    let svg = svg(&fig, &input).unwrap();
    assert!(svg.contains("log scale"));
    let has = |t: &str| find_text(&svg, t).is_some();
    let texts: Vec<&str> = svg
        .split("<text")
        .skip(1)
        .filter_map(|t| {
            t.split_once('>')
                .map(|(_, r)| r.split('<').next().unwrap().trim())
        })
        .collect();
    assert!(
        has("1") && (has("0.1") || has("0.2") || has("10")),
        "{texts:?}"
    );
}

#[test]
fn log_ticks_are_one_two_five() {
    assert_eq!(log_ticks(0.05, 3.0), [0.05, 0.1, 0.2, 0.5, 1.0, 2.0]);
    assert!(log_ticks(0.0, 1.0).is_empty());
    assert_eq!(log_ticks(0.64, 2.1), [0.7, 0.8, 0.9, 1.0, 2.0]);
}

#[test]
fn legend_labels_wrap_at_spaces() {
    assert_eq!(
        wrap("NIS/3 of each update (χ²(3)/3) and more"),
        ["NIS/3 of each update", "(χ²(3)/3) and more"]
    );
    assert_eq!(wrap("short"), ["short"]);
}

/// The residual figure of `input`'s starting model as SVG.
fn residual_svg(input: &ReportInput) -> String {
    svg(&figure(Kind::Residual(0), input), input).unwrap()
}

/// Red triangles at a frame's edge (the clip markers: red polygons).
fn red_triangles(svg: &str) -> usize {
    svg.split("<polygon")
        .skip(1)
        .filter(|p| p.split('>').next().unwrap_or("").contains("#C81E1E"))
        .count()
}

#[test]
fn a_worst_misfit_within_three_robust_ranges_is_in_the_frame() {
    // The case: a maximum of 5.2e-4 against a robust limit of ~3.5e-4 (3.5 floors):
    // the plot scales to the data, nothing is clipped.
    let mut input = input();
    input.diagnoses[0].series.residual[300] = [5.2e-4, 0.0, 0.0];
    let s = residual_svg(&input);
    assert!(
        !s.contains("the frame (clipped"),
        "nothing should be clipped"
    );
    assert_eq!(red_triangles(&s), 0);
}

#[test]
fn a_glitch_beyond_the_frame_is_marked_at_the_edge_and_counted() {
    // Two residuals of 40 floors on x, one of −40 on z: far beyond 3 robust ranges, so the frame
    // keeps the bulk and marks them.
    let mut input = input();
    let r = &mut input.diagnoses[0].series.residual;
    r[100][0] = 4e-3;
    r[400][0] = 4.2e-3;
    r[250][2] = -4e-3;
    let s = residual_svg(&input);
    assert!(s.contains("▲ 2 above the frame"), "x axis: two above");
    assert!(s.contains("▼ 1 below the frame"), "z axis: one below");
    assert_eq!(red_triangles(&s), 3, "one marker per clipped point");
}

#[test]
fn a_failure_window_is_shaded_on_its_own_axis_only() {
    // The window of `input` belongs to axis x: shaded in the x panel, not in y or z.
    let input = input();
    let s = residual_svg(&input);
    let shade = "#FFAAAA";
    let x_panel = s.find("x axis").unwrap();
    let y_panel = s.find("y axis").unwrap();
    assert!(s[x_panel..y_panel].contains(shade), "x panel shaded");
    assert!(!s[y_panel..].contains(shade), "y and z panels not shaded");
}

#[test]
fn acf_stems_are_red_only_beyond_their_bound() {
    let mut input = input();
    let last = input.diagnoses.len() - 1;
    // All lags inside ±0.08 but one at 0.2 on axis y.
    input.diagnoses[last].whiteness.acf[2][1] = 0.2;
    let s = svg(&figure(Kind::Acf(last), &input), &input).unwrap();
    // One stem and its dot in red, nothing else (the caption's text is black).
    let red = s.matches("#C81E1E").count();
    assert_eq!(red, 2, "one red stem and its dot");
    // In-band stems are not in the axes' colours (y's orange reads as red).
    for c in AXIS_COLORS {
        let hex = format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2);
        assert!(!s.contains(&hex), "a stem in {hex}");
    }
}

#[test]
fn what_changed_shows_nis_whiteness_and_the_shifts_per_rung() {
    let mut input = input();
    // The starting model misfits: NIS/3 above its band, p far below the whiteness level.
    input.diagnoses[0].nis_mean = 1.11;
    input.diagnoses[0].whiteness.p_value = 0.0;
    input.ladder[0].coefficients = vec![("DX0".into(), 0.48, 5e-4), ("DY0".into(), -0.5, 5e-4)];
    input.ladder[1].coefficients = vec![("DX0".into(), 0.4988, 9e-4), ("DY0".into(), -0.5, 6e-4)];
    let s = svg(&figure(Kind::Story, &input), &input).unwrap();
    for label in [
        "mean NIS/3, 99.9 % band",
        "Ljung–Box p (whiteness)",
        "0: paper",
        "1: + temp-drift",
        "DX0",
    ] {
        assert!(find_text(&s, label).is_some(), "{label} missing");
    }
    // DX0 moved by (0.4988 − 0.48)/9e-4 = 20.9 σ: drawn; p = 0 drawn at the edge as "< 1e-308".
    assert!(
        s.contains("p = &lt; 1e-308") || s.contains("p = < 1e-308"),
        "p of 0 labelled"
    );
    let moved = crate::report::story::moved(&input.ladder);
    assert_eq!(moved[0].name, "DX0");
    // Exact arithmetic on two decimals: the tolerance only absorbs rounding.
    assert!(
        (moved[0].sigmas - 20.888).abs() < 1e-2,
        "{}",
        moved[0].sigmas
    );
}

#[test]
fn window_means_average_whole_windows() {
    // Updates valued 1..=9 in windows of 4: means of 1–4 and 5–8; the last one alone (less than
    // half a window) is left out. Exact arithmetic: the tolerance absorbs rounding only.
    let t: Vec<f64> = (0..10).map(|k| k as f64).collect();
    let m = window_means(&t[..9], |k| (k + 1) as f64, 4);
    assert_eq!(m.len(), 2);
    assert!((m[0].0 - 1.5).abs() < 1e-12 && (m[0].1 - 2.5).abs() < 1e-12);
    assert!((m[1].0 - 5.5).abs() < 1e-12 && (m[1].1 - 6.5).abs() < 1e-12);
    // Half a window (2 of 4) is kept: 9 and 10 average to 9.5.
    let m = window_means(&t, |k| (k + 1) as f64, 4);
    assert_eq!(m.len(), 3);
    assert!((m[2].1 - 9.5).abs() < 1e-12);
}

#[test]
fn a_final_model_that_does_not_fit_is_outside_the_catalog_in_the_verdict_block() {
    let mut input = input();
    let last = input.diagnoses.len() - 1;
    // The final model fails its whiteness check and nothing earns its place.
    input.diagnoses[last].whiteness.p_value = 1e-6;
    input.diagnoses[last].consistency =
        assess(1.0, 600, 1e-6, [0.7; 3], 0.0, &Thresholds::default());
    input.untrusted = vec!["define it in `--effects FILE.toml` <here>".into()];
    let page = crate::report::render_html(&input).unwrap();
    let block = &page[page.find("<section id=\"verdict\"").unwrap()..];
    let block = &block[..block.find("</section>").unwrap()];
    assert!(block.contains("class=\"headline untrusted\"><p class=\"state\">NOT TRUSTED</p>"));
    assert!(block.contains("<p class=\"fit\">OUTSIDE THE CATALOG</p>"));
    // The reason with its backticks as <code>, its markup escaped.
    assert!(block.contains("<li>define it in <code>--effects FILE.toml</code> &lt;here&gt;</li>"));
    assert!(block.contains("The ladder added <code>temp-drift</code>"));
}

/// A fitted `drift-markov` (issue 29): its σ and τ in the coefficients section, each ± its 1σ
/// with the digits the 1σ gives ([`crate::format::pm`]: 2 significant digits of the 1σ) and its
/// profile-likelihood interval; without it the section has no such table.
#[test]
fn the_gauss_markov_sigma_and_tau_are_shown_with_their_one_sigma() {
    let mut input = input();
    let plain = crate::report::render_html(&input).unwrap();
    assert!(!plain.contains("drift-markov"));
    input.markov = Some(markov_fit(false));
    let page = crate::report::render_html(&input).unwrap();
    let section = &page[page.find("<h2 id=\"coefficients\"").unwrap()..];
    assert!(
        section.contains("σ and τ from the data"),
        "no drift-markov table"
    );
    assert!(
        section.contains("<td class=\"l\">deg/h</td><td>0.0123 ± 0.0021</td><td>0.0095–0.016</td>")
    );
    assert!(section.contains("<td class=\"l\">h</td><td>4.9 ± 1.3</td><td>3.6–7.1</td>"));
    // At a bound of its range there is no 1σ to show, and the page says why.
    input.markov = Some(markov_fit(true));
    let page = crate::report::render_html(&input).unwrap();
    assert!(page.contains("At the edge of the range"));
    assert!(page.contains("<td class=\"l\">deg/h</td><td>0.012</td><td>—</td>"));
}

fn markov_fit(at_bound: bool) -> crate::identify::markov::MarkovFit {
    crate::identify::markov::MarkovFit {
        sigma_degph: 0.0123,
        sigma_sd_degph: 0.0021,
        sigma_interval_degph: [0.0095, 0.0161],
        tau_h: 4.87,
        tau_sd_h: 1.3,
        tau_interval_h: [3.6, 7.1],
        correlation: 0.42,
        at_bound,
        evidence_gain: 3.2,
        passes: 40,
        lattice: [0.0; crate::identify::markov::LATTICE_POINTS],
    }
}
