//! Adding your own physical effect: implement one trait, `estimator_core::Effect`.
//!
//! Here: a second-order accelerometer nonlinearity, `z_i += k_i·1e-6·A_i²` (k in 1e-6 per m/s²).
//! We inject it into a simulated paper run, then
//! identify with and without it and watch the residual fall to the noise floor.
//!
//! Run: `cargo run --release -p host-tool --example custom_effect`

use estimator_core::effects::{Context, Effect, Param, Partials};
use estimator_core::Sample;
use host_tool::catalog;
use host_tool::cli::common::build_model;
use host_tool::identify::{identify, prepare, Config};
use host_tool::simulate::{simulate, Scenario};
use nalgebra::Vector3;

/// Accelerometer quadratic nonlinearity, three states in 1e-6/(m/s²).
struct AccQuadratic;

const PARAMS: [Param; 3] = [
    Param {
        name: "QAx",
        unit: "1e-6/(m/s^2)",
        prior_sigma: 100.0,
    },
    Param {
        name: "QAy",
        unit: "1e-6/(m/s^2)",
        prior_sigma: 100.0,
    },
    Param {
        name: "QAz",
        unit: "1e-6/(m/s^2)",
        prior_sigma: 100.0,
    },
];

impl Effect for AccQuadratic {
    fn name(&self) -> &str {
        "acc-quadratic"
    }
    fn about(&self) -> &str {
        "Second-order accelerometer nonlinearity: output grows with the square of the input."
    }
    fn params(&self) -> &[Param] {
        &PARAMS
    }
    /// Value, ∂/∂parameters and ∂/∂specific force: the model chains these into H.
    fn accel_error(&self, p: &[f64], ctx: &Context, out: Partials<'_>) {
        let a = &ctx.specific_force;
        for i in 0..3 {
            out.value[i] += p[i] * 1e-6 * a[i] * a[i];
            out.d_params[i] = Vector3::ith(i, 1e-6 * a[i] * a[i]);
            out.d_force[(i, i)] += 2.0 * p[i] * 1e-6 * a[i];
        }
    }
    fn touches_drift(&self) -> bool {
        false
    }
    fn touches_accel(&self) -> bool {
        true
    }
}

static ACC_QUADRATIC: AccQuadratic = AccQuadratic;

fn main() -> anyhow::Result<()> {
    let k_true = [3.0, -2.0, 1.5]; // 1e-6/(m/s²)
    let mut sc = Scenario::paper();
    sc.rate_s = 10.0;
    let sim = simulate(&sc);
    // Inject the effect into the recorded samples (the simulator does not know it).
    let samples: Vec<Sample> = sim
        .samples
        .iter()
        .map(|s| {
            let a = s.specific_force_mps2;
            let z = [0, 1, 2].map(|i| a[i] + k_true[i] * 1e-6 * a[i] * a[i]);
            Sample {
                t_s: s.t_s,
                specific_force: z,
                temp_c: f64::NAN,
            }
        })
        .collect();
    let site = estimator_core::Site::new(sc.latitude_deg, sc.gravity_mps2);
    let cfg = Config::default();
    let prep = prepare(site, &samples, &cfg)?;
    for effects in [
        vec![catalog::paper()],
        vec![catalog::paper(), &ACC_QUADRATIC as &dyn Effect],
    ] {
        let model = build_model(site, &effects, &cfg)?;
        let id = identify(&model, &prep, &cfg)?;
        let rms = id.residual_rms_mps2(&prep);
        let floor = prep.floor_mps2();
        println!(
            "model {:<28} residual RMS / floor = [{:.3}, {:.3}, {:.3}], mean NIS/3 = {:.3}",
            effects
                .iter()
                .map(|e| e.name())
                .collect::<Vec<_>>()
                .join(" + "),
            rms[0] / floor[0],
            rms[1] / floor[1],
            rms[2] / floor[2],
            id.nis_mean()
        );
        let best = id.best();
        for (k, p) in id.params.iter().enumerate().skip(12) {
            println!(
                "    {} = {:.3} ± {:.3} {} (injected {})",
                p.name,
                best.value[k],
                best.sigma(k),
                p.unit,
                k_true[k - 12]
            );
        }
    }
    Ok(())
}
