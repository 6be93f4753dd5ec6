//! The catalog of physical effects the host can add to the model by name (`--with a,b`).

use estimator_core::effects::{
    AccBias, AccMisalign, AccScale, DriftDaily, DriftMarkov, DriftTrend, Effect, G2Drift,
    PaperDrift, TempDrift,
};

static PAPER: PaperDrift = PaperDrift;
static ACC_BIAS: AccBias = AccBias;
static ACC_SCALE: AccScale = AccScale;
static ACC_MISALIGN: AccMisalign = AccMisalign;
static G2: G2Drift = G2Drift;
static DRIFT_TREND: DriftTrend = DriftTrend;
static DRIFT_DAILY: DriftDaily = DriftDaily { sigma_degph: 0.01 };
static TEMP_DRIFT: TempDrift = TempDrift;
static DRIFT_MARKOV: DriftMarkov = DriftMarkov {
    sigma_degph: 0.01,
    tau_h: 5.0,
};

/// Every catalog effect beyond the paper's drift model, in the order they are listed: the
/// built-in ones, then those registered for this run ([`register`], `--effects FILE`).
pub fn candidates() -> Vec<&'static dyn Effect> {
    let mut v = builtin_candidates();
    v.extend(user_effects());
    v
}

fn builtin_candidates() -> Vec<&'static dyn Effect> {
    vec![
        &G2,
        &ACC_BIAS,
        &ACC_SCALE,
        &ACC_MISALIGN,
        &DRIFT_TREND,
        &DRIFT_MARKOV,
        &TEMP_DRIFT,
        &DRIFT_DAILY,
    ]
}

// ---- user effects (`--effects FILE`, see crate::effects_file) -------------------------------

/// Effects added to the catalog for this run (process-wide).
static USER: std::sync::RwLock<Vec<&'static dyn Effect>> = std::sync::RwLock::new(Vec::new());

fn user_effects() -> Vec<&'static dyn Effect> {
    USER.read().unwrap_or_else(|e| e.into_inner()).clone()
}

/// Adds effects to the catalog for the rest of the process: from then on [`candidates`],
/// [`by_name`] and [`model_effects`] offer them like built-in ones. Refuses an effect whose name
/// is already in the catalog (built-in or registered), an empty parameter list, and a parameter
/// name already used by the paper's model or another catalog effect (results are keyed by it).
pub fn register(effects: Vec<&'static dyn Effect>) -> anyhow::Result<()> {
    let mut user = USER.write().unwrap_or_else(|e| e.into_inner());
    let mut known: Vec<&'static dyn Effect> = vec![paper()];
    known.extend(builtin_candidates());
    known.extend(user.iter().copied());
    let mut added: Vec<&'static dyn Effect> = Vec::new();
    for e in effects {
        if let Some(o) = known.iter().chain(&added).find(|o| o.name() == e.name()) {
            let what = if builtin_candidates().iter().any(|b| b.name() == o.name())
                || o.name() == paper().name()
            {
                "a built-in effect"
            } else {
                "an effect already added"
            };
            anyhow::bail!("effect `{}`: the name is taken by {what}", e.name());
        }
        if e.params().is_empty() {
            anyhow::bail!("effect `{}` has no parameters", e.name());
        }
        for (k, p) in e.params().iter().enumerate() {
            if e.params()[..k].iter().any(|q| q.name == p.name) {
                anyhow::bail!("effect `{}`: parameter `{}` given twice", e.name(), p.name);
            }
            if let Some(o) = known
                .iter()
                .chain(&added)
                .find(|o| o.params().iter().any(|q| q.name == p.name))
            {
                anyhow::bail!(
                    "effect `{}`: parameter name `{}` is already used by effect `{}`; rename it",
                    e.name(),
                    p.name,
                    o.name()
                );
            }
        }
        added.push(e);
    }
    user.extend(added);
    Ok(())
}

// ---- end of user effects --------------------------------------------------------------------

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
                "unknown effect `{name}`; the catalog has: {} (effects defined in a file need --effects FILE)",
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
