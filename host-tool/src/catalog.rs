//! The catalog of physical effects the host can add to the model by name (`--with a,b`).

use std::path::{Path, PathBuf};

use estimator_core::effects::{
    AccBias, AccMisalign, AccScale, AccTemp, DriftDaily, DriftMarkov, DriftTrend, Effect, G2Drift,
    PaperDrift, TempDrift,
};

use crate::effects_file::UserEffect;

static PAPER: PaperDrift = PaperDrift;
static ACC_BIAS: AccBias = AccBias;
static ACC_SCALE: AccScale = AccScale;
static ACC_MISALIGN: AccMisalign = AccMisalign;
static ACC_TEMP: AccTemp = AccTemp;
static G2: G2Drift = G2Drift;
static DRIFT_TREND: DriftTrend = DriftTrend::CATALOG;
static DRIFT_DAILY: DriftDaily = DriftDaily { sigma_degph: 0.01 };
static TEMP_DRIFT: TempDrift = TempDrift::CATALOG;
static DRIFT_MARKOV: DriftMarkov = DriftMarkov {
    sigma_degph: 0.01,
    tau_h: 5.0,
};

/// The effects a model can be built from in one run: the built-in ones (statics) and those
/// defined in `--effects` files, which the catalog owns. The CLI builds it once per command
/// ([`Catalog::load`]) and passes it by reference to what picks effects by name (the model's
/// `--with`, the diagnosis' candidates, the ladder, the plan); effects borrowed from it live as
/// long as it does.
#[derive(Debug, Default)]
pub struct Catalog {
    /// Effects from `--effects` files, in the order they were defined.
    user: Vec<UserEffect>,
    /// `drift-markov` with σ and τ fitted to a run ([`Catalog::tuned_markov`]), owned here like
    /// the file effects. Append-only (`boxcar`): a variant handed out stays where it is while
    /// others are added, from any thread.
    tuned: boxcar::Vec<DriftMarkov>,
    /// Effects made for a run from a profiled value ([`Catalog::made_for_run`]: a drift step at
    /// its time, a warm-up of its time constant), owned here the same way.
    made: boxcar::Vec<Made>,
}

/// What tells two effects made for a run apart: the kind's name and the profiled value's bits.
pub(crate) type MadeKey = (&'static str, u64);

/// An effect made for a run, with its key.
struct Made(MadeKey, Box<dyn Effect + Send>);

impl std::fmt::Debug for Made {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({:?})", self.1.name(), f64::from_bits(self.0 .1))
    }
}

impl Catalog {
    /// The built-in effects only.
    pub fn builtin() -> &'static Self {
        static BUILTIN: Catalog = Catalog {
            user: Vec::new(),
            tuned: boxcar::Vec::new(),
            made: boxcar::Vec::new(),
        };
        &BUILTIN
    }

    /// The built-in effects plus those of the given effects files (none: the built-in ones). A
    /// clash of names names the file and line of both definitions.
    pub fn load(paths: &[PathBuf]) -> anyhow::Result<Self> {
        let mut known = vec![paper()];
        known.extend(builtin_candidates());
        Self::with_user(crate::effects_file::load_files(paths, &known)?)
    }

    /// The built-in effects plus `user`. Refuses an effect whose name is already in the catalog
    /// (built-in or earlier in `user`), an empty parameter list, and a parameter name already
    /// used by the paper's model or another catalog effect (results are keyed by it).
    pub fn with_user(user: Vec<UserEffect>) -> anyhow::Result<Self> {
        let mut known: Vec<&dyn Effect> = vec![paper()];
        known.extend(builtin_candidates());
        let builtin = known.len();
        for e in &user {
            check_new(e, &known, builtin)?;
            known.push(e);
        }
        Ok(Self {
            user,
            tuned: boxcar::Vec::new(),
            made: boxcar::Vec::new(),
        })
    }

    /// The effects from `--effects` files.
    pub fn user(&self) -> &[UserEffect] {
        &self.user
    }

    /// Every catalog effect beyond the paper's drift model, in the order they are listed: the
    /// built-in ones, then those from `--effects` files.
    pub fn candidates(&self) -> Vec<&dyn Effect> {
        let mut v: Vec<&dyn Effect> = builtin_candidates();
        v.extend(self.user.iter().map(|e| e as &dyn Effect));
        v
    }

    /// Looks up an effect by its catalog name.
    pub fn by_name(&self, name: &str) -> Option<&dyn Effect> {
        self.candidates().into_iter().find(|e| e.name() == name)
    }

    /// The paper's model plus the named effects, in order; an unknown name is an error listing
    /// the catalog.
    pub fn model_effects(&self, with: &[String]) -> anyhow::Result<Vec<&dyn Effect>> {
        let mut effects = vec![paper()];
        for name in with {
            let e = self.by_name(name).ok_or_else(|| {
                let known: Vec<_> = self.candidates().iter().map(|e| e.name()).collect();
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

    /// `drift-markov` with σ (deg/h) and τ (h) set, owned by the catalog: one value per distinct
    /// (σ, τ) (a run tunes a handful at most), borrowed for as long as the catalog lives.
    pub(crate) fn tuned_markov(&self, sigma_degph: f64, tau_h: f64) -> &DriftMarkov {
        let same = |d: &DriftMarkov| d.sigma_degph == sigma_degph && d.tau_h == tau_h;
        if let Some((_, d)) = self.tuned.iter().find(|(_, d)| same(d)) {
            return d;
        }
        let k = self.tuned.push(DriftMarkov { sigma_degph, tau_h });
        &self.tuned[k]
    }

    /// `effects` with `drift-markov` at the σ and τ `id` was fitted with ([`Identification::markov`]):
    /// an assessment that repairs a misstated set-up tunes them again there ([`crate::assess`]).
    ///
    /// [`Identification::markov`]: crate::identify::Identification::markov
    pub(crate) fn as_tuned<'c>(
        &'c self,
        effects: &[&'c dyn Effect],
        id: &crate::identify::Identification,
    ) -> Vec<&'c dyn Effect> {
        match &id.markov {
            Some(gm) => crate::identify::markov::with_markov(
                effects,
                self.tuned_markov(gm.sigma_degph, gm.tau_h),
            ),
            None => effects.to_vec(),
        }
    }

    /// The effect `make` builds for `key`, owned by the catalog: made once per distinct key (a
    /// run adopts a handful at most: one per rung or repair), lent for as long as the catalog
    /// lives. The catalog does not know the kinds (`diagnose::select::Profiled` does).
    pub(crate) fn made_for_run(
        &self,
        key: MadeKey,
        make: impl FnOnce() -> Box<dyn Effect + Send>,
    ) -> &dyn Effect {
        if let Some((_, Made(_, e))) = self.made.iter().find(|(_, m)| m.0 == key) {
            return e.as_ref();
        }
        let k = self.made.push(Made(key, make()));
        self.made[k].1.as_ref()
    }

    /// Binds the recording columns the file effects use to the recording at `path`
    /// ([`crate::effects_file::bind_columns`]).
    pub(crate) fn bind_columns(
        &self,
        path: &Path,
        samples: &[crate::recording::RawSample],
        lines: &[u32],
    ) -> anyhow::Result<()> {
        crate::effects_file::bind_columns(&self.user, path, samples, lines)
    }

    /// The first value a file effect computed that was not a finite number, described
    /// ([`crate::effects_file::numeric_failure`]); the CLI ends with it (exit 2).
    pub(crate) fn numeric_failure(&self) -> Option<String> {
        crate::effects_file::numeric_failure(&self.user)
    }
}

/// Refuses `e` when its name or a parameter's name is taken by `known` (its first `builtin`
/// entries are the built-in effects) or it has no parameters.
fn check_new(e: &UserEffect, known: &[&dyn Effect], builtin: usize) -> anyhow::Result<()> {
    if let Some(k) = known.iter().position(|o| o.name() == e.name()) {
        let what = if k < builtin {
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
    Ok(())
}

/// The built-in effects beyond the paper's drift model, in the order they are listed.
pub fn builtin_candidates() -> Vec<&'static dyn Effect> {
    vec![
        &G2,
        &ACC_BIAS,
        &ACC_SCALE,
        &ACC_MISALIGN,
        &DRIFT_TREND,
        &DRIFT_MARKOV,
        &TEMP_DRIFT,
        &ACC_TEMP,
        &DRIFT_DAILY,
    ]
}

/// The paper's drift model.
pub fn paper() -> &'static dyn Effect {
    &PAPER
}

/// Looks up a built-in effect by its catalog name (no catalog needed: they are statics).
pub fn builtin(name: &str) -> Option<&'static dyn Effect> {
    builtin_candidates().into_iter().find(|e| e.name() == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tuned `drift-markov` is the catalog's: asked again for the same σ, τ it lends the same
    /// value (one per distinct pair), a variant lent earlier stays valid while others are added,
    /// and it carries the σ, τ asked for (compared exactly: they are stored, not computed).
    #[test]
    fn a_tuned_drift_markov_is_owned_once_per_sigma_and_tau() {
        let catalog = Catalog::with_user(vec![]).unwrap();
        let first = catalog.tuned_markov(0.02, 3.0);
        let others: Vec<&DriftMarkov> = (1..40)
            .map(|k| catalog.tuned_markov(0.001 * f64::from(k), 7.0))
            .collect();
        let again = catalog.tuned_markov(0.02, 3.0);
        assert!(std::ptr::eq(first, again));
        assert_eq!((first.sigma_degph, first.tau_h), (0.02, 3.0));
        assert_eq!(others[38].sigma_degph, 0.001 * 39.0);
        assert!(!std::ptr::eq(first, others[19]));
        assert_eq!(catalog.tuned.count(), 40);
    }

    /// An effect made for a run is the catalog's: the same key lends the same value (a ladder
    /// that adopts a drift step at one time makes it once), another key another value, and one
    /// lent earlier stays valid while others are added (compared by address, of an effect with a
    /// size: a zero-sized one would share its address with every other, and by the name the
    /// maker gave: nothing is computed).
    #[test]
    fn an_effect_made_for_a_run_is_owned_once_per_key() {
        let catalog = Catalog::with_user(vec![]).unwrap();
        let make = || -> Box<dyn Effect + Send> { Box::new(DriftDaily { sigma_degph: 0.01 }) };
        let first = catalog.made_for_run(("drift-step", 3.0f64.to_bits()), make);
        let others: Vec<&dyn Effect> = (1..30u64)
            .map(|k| catalog.made_for_run(("drift-step", k), make))
            .collect();
        let again = catalog.made_for_run(("drift-step", 3.0f64.to_bits()), || unreachable!());
        assert!(std::ptr::addr_eq(first, again));
        assert!(!std::ptr::addr_eq(first, others[10]));
        assert_eq!(first.name(), "drift-daily");
        assert_eq!(catalog.made.count(), 30);
    }
}
