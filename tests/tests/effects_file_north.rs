//! Effect files that use the Earth-fixed directions (issue 27 item 5): local north and east in
//! platform axes beside up. A simulated paper run whose accelerometers pick up a term along
//! local north (`simulate --effect acc-north=…`, the truth simulator's own attitude) is
//! identified with the shipped file `host-tool/examples/effects/acc-north.toml`; a misspelt
//! direction is refused by name.

use std::path::PathBuf;

use estimator_core::Effect;
use host_tool::catalog;
use host_tool::cli::common::load;
use host_tool::effects_file::{load_file, parse_effects};
use host_tool::identify::{build_model, identify, prepare, Config};
use host_tool::recording::write_recording;
use host_tool::simulate::{simulate, InjectedEffect, Scenario};

fn example_file() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../host-tool/examples/effects/acc-north.toml")
}

/// The north term and the drift coefficients are recovered within 3σ of the truth.
///
/// Why 3σ: with the right model the estimate is Gaussian about the truth with the 1σ the
/// identification reports, so |error| < 3σ holds with 99.7 % (measured at this seed: within
/// 0.2σ for KN, 1.3σ for the drift coefficients). The run resolves KN only to ~1.9e-4 m/s² (1σ
/// total, all three axes; the noise alone, 2e-5): north's constant part acts like an
/// accelerometer bias, which the start attitude's prior tilt (5″ ≈ 2.4e-4 m/s² of g) mimics —
/// hence a large truth, 2e-3 and -1.5e-3 m/s² on x and y: a north of the wrong sign or the
/// wrong column of C moves them by ≥ 10σ (east in place of north: DX0 off by 6σ). The 1σ bound
/// (< 3e-4 m/s², x and y) keeps the first check from passing by width.
#[test]
fn a_north_term_is_identified_with_the_shipped_file() {
    let dir = std::env::temp_dir().join(format!("driftid-north-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let k = [2e-3, -1.5e-3, 1e-3];
    let mut sc = Scenario::paper();
    sc.seed = 7;
    sc.rate_s = 10.0;
    sc.effects = vec![InjectedEffect::AccNorth { k_mps2: k }];
    let sim = simulate(&sc);
    let run = dir.join("north.csv");
    write_recording(&run, &sim.meta, &sim.samples).unwrap();

    let file = load_file(&example_file()).unwrap();
    assert_eq!(file[0].name(), "acc-north");
    assert!(file[0].uses_north());
    let loaded = load(catalog::Catalog::builtin(), &run, None).unwrap();
    let cfg = Config::default();
    let prep = prepare(loaded.site, &loaded.samples, &cfg).unwrap();
    let effects: Vec<&dyn Effect> = vec![catalog::paper(), &file[0]];
    let model = build_model(prep.site, &effects, &cfg).unwrap();
    let id = identify(&model, &prep, &cfg).unwrap();
    let best = id.best();
    let truth: Vec<(String, f64)> = sim
        .truth
        .coefficients
        .iter()
        .map(|(n, v)| (n.clone(), *v))
        .chain(["KNx", "KNy", "KNz"].iter().map(|n| n.to_string()).zip(k))
        .collect();
    let mut z = Vec::new();
    for (name, t) in &truth {
        let i = id.params.iter().position(|p| p.name == name).unwrap();
        let (v, s) = (best.value[i], best.sigma(i));
        z.push(format!("{name} {:+.2}σ (1σ {s:.2e})", (v - t) / s));
        assert!(
            (v - t).abs() < 3.0 * s,
            "{name} = {v:e} ± {s:e}, truth {t:e}"
        );
        if name != "KNz" && name.starts_with("KN") {
            assert!(s < 3e-4, "{name}: 1σ {s:e} m/s^2");
        }
    }
    println!("errors in σ: {}", z.join(", "));
    std::fs::remove_dir_all(&dir).ok();
}

/// A direction that does not exist (`north_w`, `west_x`) is refused at load time naming the
/// file, line:column, the effect, the unknown variable and the variables that exist.
#[test]
fn an_unknown_direction_is_refused_by_name() {
    for (expr, bad) in [("K * north_w", "north_w"), ("K * west_x", "west_x")] {
        let src = format!(
            "[[effect]]\nname = \"e1\"\napplies_to = \"drift\"\n\
             params = [ {{ name = \"K\", unit = \"deg/h\", prior_sigma = 0.1 }} ]\n\
             x = \"{expr}\"\ny = \"0\"\nz = \"0\"\n"
        );
        let e = format!(
            "{:#}",
            parse_effects(std::path::Path::new("bad.toml"), &src).unwrap_err()
        );
        let head = format!("bad.toml:5:5: effect `e1`: x = \"{expr}\": unknown variable `{bad}`");
        assert!(e.starts_with(&head), "{e}");
        assert!(
            e.contains("up_x, up_y, up_z, north_x, north_y, north_z, east_x, east_y, east_z, t_h"),
            "{e}"
        );
    }
}

/// `east_*` is north × up (ENU is right-handed: east × north = up), and the partial derivatives
/// a file effect reports by A (through up and east) and by north match central differences of
/// its own value, A and north varied as independent variables.
///
/// Tolerances: the value against north × A/|A| computed here, 1e-15 (a few roundings of unit
/// vectors' products); the derivatives, 1e-7 of the largest: central differences with steps of
/// 1e-6 (north, unit) and 1e-5 m/s² (A, |A| ≈ 10) have truncation ~h²·f''' < 1e-11 and rounding
/// ~ε·f/h < 1e-9 relative, while a wrong or missing term changes a derivative by O(1).
#[test]
fn east_is_north_cross_up_and_its_derivatives_match_finite_differences() {
    use estimator_core::effects::{Context, Partials};
    use nalgebra::{Matrix3, Vector3};
    let src = "[[effect]]\nname = \"e1\"\napplies_to = \"drift\"\n\
        params = [ { name = \"KE\", unit = \"deg/h\", prior_sigma = 0.1 },\n\
                   { name = \"KN\", unit = \"deg/h\", prior_sigma = 0.1 } ]\n\
        x = \"KE*east_x + KN*north_y*east_z\"\ny = \"KE*east_y\"\nz = \"KE*east_z*up_x + KN*north_z\"\n";
    let e = parse_effects(std::path::Path::new("e.toml"), src).unwrap();
    let e = &e[0];
    assert!(e.uses_north());
    let p = [0.7, -1.3];
    let eval = |a: Vector3<f64>, n: Vector3<f64>| {
        let ctx = Context {
            t_s: 3600.0,
            specific_force: a,
            temp_dev_c: 0.0,
            north: n,
        };
        let (mut value, mut d_force, mut d_north) =
            (Vector3::zeros(), Matrix3::zeros(), Matrix3::zeros());
        let mut cols = [Vector3::zeros(); 2];
        e.drift(
            &p,
            &ctx,
            Partials {
                value: &mut value,
                d_params: &mut cols,
                d_force: &mut d_force,
            },
        );
        e.d_north(&p, &ctx, true, &mut d_north);
        (value, d_force, d_north)
    };
    for (a, n) in [
        (
            Vector3::<f64>::new(3.1, -5.2, 7.3),
            Vector3::<f64>::new(0.8, 0.6, 0.0),
        ),
        (
            Vector3::new(-0.4, 7.6, 6.2),
            Vector3::new(0.0, -0.6329, 0.7742),
        ),
    ] {
        let n = (n - a * (n.dot(&a) / a.norm_squared())).normalize(); // ⟂ A, as north to up
        let east = n.cross(&(a / a.norm()));
        let (v, df, dn) = eval(a, n);
        assert!(
            (v.y - p[0] * east.y).abs() < 1e-15,
            "{v:?} vs east {east:?}"
        );
        // East completes a right-handed frame: east × north = up.
        assert!((east.cross(&n) - a / a.norm()).amax() < 1e-15);
        let scale = df.amax().max(dn.amax());
        for j in 0..3 {
            let (mut ap, mut am, mut np, mut nm) = (a, a, n, n);
            ap[j] += 1e-5;
            am[j] -= 1e-5;
            np[j] += 1e-6;
            nm[j] -= 1e-6;
            let num_a = (eval(ap, n).0 - eval(am, n).0) / 2e-5;
            let num_n = (eval(a, np).0 - eval(a, nm).0) / 2e-6;
            assert!((df.column(j) - num_a).amax() < 1e-7 * scale, "∂/∂A_{j}");
            assert!((dn.column(j) - num_n).amax() < 1e-7 * scale, "∂/∂north_{j}");
        }
    }
}
