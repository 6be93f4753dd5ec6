//! The catalog of physical effects the host can add to the model by name (`--with a,b`).

use estimator_core::effects::{
    AccBias, AccMisalign, AccScale, DriftMarkov, DriftTrend, Effect, G2Drift, PaperDrift, TempDrift,
};

static PAPER: PaperDrift = PaperDrift;
static ACC_BIAS: AccBias = AccBias;
static ACC_SCALE: AccScale = AccScale;
static ACC_MISALIGN: AccMisalign = AccMisalign;
static G2: G2Drift = G2Drift;
static DRIFT_TREND: DriftTrend = DriftTrend;
static TEMP_DRIFT: TempDrift = TempDrift;
static DRIFT_MARKOV: DriftMarkov = DriftMarkov {
    sigma_degph: 0.01,
    tau_h: 5.0,
};

/// Every catalog effect beyond the paper's drift model, in the order they are listed.
pub fn candidates() -> Vec<&'static dyn Effect> {
    vec![
        &G2,
        &ACC_BIAS,
        &ACC_SCALE,
        &ACC_MISALIGN,
        &DRIFT_TREND,
        &DRIFT_MARKOV,
        &TEMP_DRIFT,
    ]
}

/// The paper's drift model.
pub fn paper() -> &'static dyn Effect {
    &PAPER
}

/// Looks up an effect by its catalog name.
pub fn by_name(name: &str) -> Option<&'static dyn Effect> {
    candidates().into_iter().find(|e| e.name() == name)
}

/// The paper's model plus the named effects, in order; an unknown name is an error listing the
/// catalog.
pub fn model_effects(with: &[String]) -> anyhow::Result<Vec<&'static dyn Effect>> {
    let mut effects = vec![paper()];
    for name in with {
        let e = by_name(name).ok_or_else(|| {
            let known: Vec<_> = candidates().iter().map(|e| e.name()).collect();
            anyhow::anyhow!(
                "unknown effect `{name}`; the catalog has: {}",
                known.join(", ")
            )
        })?;
        if effects.iter().any(|x| x.name() == e.name()) {
            anyhow::bail!("effect `{name}` given twice");
        }
        effects.push(e);
    }
    Ok(effects)
}
