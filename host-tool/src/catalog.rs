//! The catalog of physical effects the host can add to the model by name (`--with a,b`).

use estimator_core::effects::{AccBias, DriftMarkov, Effect, PaperDrift};

static PAPER: PaperDrift = PaperDrift;
static ACC_BIAS: AccBias = AccBias;
static DRIFT_MARKOV: DriftMarkov = DriftMarkov { sigma_degph: 0.01, tau_h: 5.0 };

/// Every catalog effect beyond the paper's drift model, in the order they are tried.
pub fn candidates() -> Vec<&'static dyn Effect> {
    vec![&ACC_BIAS, &DRIFT_MARKOV]
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
            anyhow::anyhow!("unknown effect `{name}`; the catalog has: {}", known.join(", "))
        })?;
        if effects.iter().any(|x| x.name() == e.name()) {
            anyhow::bail!("effect `{name}` given twice");
        }
        effects.push(e);
    }
    Ok(effects)
}
