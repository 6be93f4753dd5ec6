//! Fits remembered within one command. `diagnose` fits the same model to the same data more than
//! once: the starting model's rivals are the first rung's leading candidates refitted on the same
//! data, and the rung that adds an effect is that effect's refit (on a 60-h run with an
//! accelerometer bias: three refits, 0.3 s, made twice). A fit is a function of the model, the
//! prepared measurements and the settings alone; [`FitMemo`] keys it by a hash of the three
//! ([`fit_key`]) and hands back a copy.

use std::collections::VecDeque;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};

use estimator_core::effects::Effect;
use estimator_core::model::Model;

use super::{Config, Identification, Prepared};
use crate::diagnose::score::Replay;

/// Filter steps of the fits kept, at most (the least recently used forgotten first): ~250 bytes
/// a step (a fit's trajectory and innovations), 50 MB. A 60-h run at the 60-s period has 3 600
/// steps: 55 fits, enough for a rung's leaders to outlive the latitude profile's fits between
/// the starting model's rivals and the first rung.
const MAX_HELD_STEPS: usize = 200_000;
/// Runs of more filter steps are not remembered (a long `--period-s 1` run's copies would take
/// memory the fit itself needs).
const MAX_STEPS: usize = 20_000;

/// The fits of one command, shared by every copy of its [`Config`] (a new `Config` starts
/// empty), and the candidates' replays about them ([`FitMemo::replayed_or`]).
#[derive(Clone, Default)]
pub struct FitMemo(Held<Identification>, Held<Arc<Replay>>);

/// Values under their keys, shared by the copies of a memo, the most recently used last.
type Held<T> = Arc<Mutex<VecDeque<(u64, T)>>>;

/// Filter steps of the replays kept, at most (the oldest forgotten first): ~1.6 kB a step (the
/// candidates' whitened signatures, the pass's states and innovations), 13 MB. A 60-h run at
/// the 60-s period keeps two: the replay a weighing and the next rung (or the final assessment)
/// share.
const MAX_REPLAY_STEPS: usize = 8_000;

impl std::fmt::Debug for FitMemo {
    /// Nothing of the contents: a `Config`'s debug text is part of [`fit_key`].
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FitMemo")
    }
}

impl FitMemo {
    /// The fit remembered under `key`, else `fit()`'s (remembered when it succeeds and the run
    /// has at most [`MAX_STEPS`] steps; within [`MAX_HELD_STEPS`], the least recently used
    /// forgotten). Two threads asking for the same key at once may both fit.
    pub(crate) fn get_or(
        &self,
        key: u64,
        steps: usize,
        fit: impl FnOnce() -> anyhow::Result<Identification>,
    ) -> anyhow::Result<Identification> {
        let lock = || self.0.lock().unwrap_or_else(|e| e.into_inner());
        {
            let mut memo = lock();
            if let Some(i) = memo.iter().position(|(k, _)| *k == key) {
                let hit = memo.remove(i).expect("the position found");
                let id = hit.1.clone();
                memo.push_back(hit);
                return Ok(id);
            }
        }
        let id = fit()?;
        if steps <= MAX_STEPS {
            let mut memo = lock();
            let held = |m: &VecDeque<(u64, Identification)>| {
                m.iter().map(|(_, id)| id.innovations.len()).sum::<usize>()
            };
            while !memo.is_empty() && held(&memo) + steps > MAX_HELD_STEPS {
                memo.pop_front();
            }
            memo.push_back((key, id.clone()));
        }
        Ok(id)
    }
}

impl FitMemo {
    /// The candidates' replay remembered under `key`, else `replay()`'s (remembered when it
    /// succeeds, within [`MAX_REPLAY_STEPS`]). The same fit is replayed by the weighing of the
    /// catalog's alternatives and by the ladder's rung on it: `diagnose` on a misfit weighs the
    /// starting fit's alternatives (the rivals of a wrong latitude) before rung 0 scores the
    /// same candidates, and the final assessment weighs the last rung's (80 ms each on a 60-h
    /// run); `identify` weighs its final fit in the assessment and again as a misfit's rivals.
    pub(crate) fn replayed_or(
        &self,
        key: u64,
        steps: usize,
        replay: impl FnOnce() -> anyhow::Result<Replay>,
    ) -> anyhow::Result<Arc<Replay>> {
        let lock = || self.1.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, r)) = lock().iter().find(|(k, _)| *k == key) {
            return Ok(Arc::clone(r));
        }
        let r = Arc::new(replay()?);
        if steps <= MAX_REPLAY_STEPS {
            let mut memo = lock();
            let held = |m: &VecDeque<(u64, Arc<Replay>)>| {
                m.iter().map(|(_, r)| r.0.innovations.len()).sum::<usize>()
            };
            while !memo.is_empty() && held(&memo) + steps > MAX_REPLAY_STEPS {
                memo.pop_front();
            }
            memo.push_back((key, Arc::clone(&r)));
        }
        Ok(r)
    }
}

/// Feeds a fit to `h`: its parameters' names, estimate and covariance, every node of its
/// trajectory and its innovations' count (what a replay about it reads).
pub(crate) fn hash_fit(h: &mut impl Hasher, id: &Identification) {
    let mut put = |vs: &[f64]| vs.iter().for_each(|v| v.to_bits().hash(h));
    let est = id.best();
    put(&est.value);
    put(est.cov.as_slice());
    for x in &id.trajectory {
        put(x.as_slice());
    }
    for p in &id.params {
        p.name.hash(h);
    }
    id.innovations.len().hash(h);
}

/// Feeds `prep` to `h`: the site, the start and its priors, every measurement, the noise floor.
pub(crate) fn hash_prep(h: &mut impl Hasher, prep: &Prepared) {
    let mut put = |vs: &[f64]| vs.iter().for_each(|v| v.to_bits().hash(h));
    put(&[prep.site.latitude_rad, prep.site.gravity_mps2]);
    put(&prep.initial_angles);
    put(&prep.initial_angle_sigma);
    put(&prep.alignment_sigma);
    for m in &prep.measurements {
        put(&[m.t_s, m.temp_c, m.time_var_s2, f64::from(m.count)]);
        put(&m.specific_force);
        put(&m.variance);
    }
    format!("{:?} {:?}", prep.site.chart, prep.noise).hash(h);
}

/// Feeds `effects` to `h`: each one's name, priors and Gauss–Markov constants (a tuned
/// `drift-markov` differs from the catalog's only there).
pub(crate) fn hash_effects(h: &mut impl Hasher, effects: &[&dyn Effect]) {
    for e in effects {
        e.name().hash(h);
        for k in 0..e.params().len() {
            e.prior_sigma(k).to_bits().hash(h);
            format!("{:?}", e.markov(k)).hash(h);
        }
    }
}

/// A hash of everything [`super::identify`] reads: the model (site, each effect's name, priors
/// and Gauss–Markov constants, the gyro noise, the propagation), the prepared measurements and
/// the settings.
pub(crate) fn fit_key(model: &Model<'_>, prep: &Prepared, cfg: &Config) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    hash_prep(&mut h, prep);
    let site = model.site();
    for v in [site.latitude_rad, site.gravity_mps2, model.arw_rad2ps()] {
        v.to_bits().hash(&mut h);
    }
    hash_effects(&mut h, model.effects());
    format!("{:?} {:?} {cfg:?}", site.chart, model.propagation()).hash(&mut h);
    h.finish()
}

/// The key of [`crate::identify::identify_widened`]'s fit: [`fit_key`]'s and the nested fit it
/// starts from, told by its estimate, covariance, end nodes and evidence (hashing every node, as
/// [`hash_fit`] does, would cost a tenth of the fit).
pub(crate) fn widened_key(
    model: &Model<'_>,
    prep: &Prepared,
    cfg: &Config,
    nested: &Identification,
) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    fit_key(model, prep, cfg).hash(&mut h);
    "widened from".hash(&mut h);
    let mut put = |vs: &[f64]| vs.iter().for_each(|v| v.to_bits().hash(&mut h));
    let est = nested.best();
    put(&est.value);
    put(est.cov.as_slice());
    for x in nested
        .trajectory
        .first()
        .into_iter()
        .chain(nested.trajectory.last())
    {
        put(x.as_slice());
    }
    put(&[crate::identify::neg2_log_evidence(&nested.innovations)]);
    for p in &nested.params {
        p.name.hash(&mut h);
    }
    (nested.trajectory.len(), nested.innovations.len()).hash(&mut h);
    h.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{build_model, identify};

    /// The memo hands back the fit made for the same model, data and settings — and only for
    /// them: another effect, another latitude or another setting is fitted anew.
    #[test]
    fn a_fit_is_reused_only_for_the_same_model_data_and_settings() {
        use crate::simulate::Scenario;
        let mut sc = Scenario::paper();
        sc.hours = 6.0;
        sc.rate_s = 60.0;
        let cfg = Config::default();
        let prep = crate::simulate::prepared(&sc, &cfg);
        let paper = [crate::catalog::paper()];
        let with_bias = [
            crate::catalog::paper(),
            crate::catalog::builtin("acc-bias").unwrap(),
        ];
        let model = build_model(prep.site, &paper, &cfg).unwrap();
        let key = fit_key(&model, &prep, &cfg);
        let first = identify(&model, &prep, &cfg).unwrap();
        let again = identify(&model, &prep, &cfg).unwrap();
        assert_eq!(first.best().value, again.best().value);
        assert_eq!(cfg.memo.0.lock().unwrap().len(), 1, "remembered once");
        let other = build_model(prep.site, &with_bias, &cfg).unwrap();
        assert_ne!(fit_key(&other, &prep, &cfg), key, "another effect");
        let moved = crate::identify::setup::at_latitude(&prep, 30.0);
        assert_ne!(fit_key(&model, &moved, &cfg), key, "another latitude");
        let slower = Config {
            period_s: 120.0,
            ..cfg.clone()
        };
        assert_ne!(fit_key(&model, &prep, &slower), key, "another setting");
        // A fresh Config starts with an empty memo: nothing is shared between commands.
        assert_eq!(Config::default().memo.0.lock().unwrap().len(), 0);
    }

    /// A fit's replay is handed back when the same fit is weighed again, wherever its progress
    /// is noted (`identify` weighs the alternatives in the assessment and again as a misfit's
    /// rivals) and when the ladder scores the same candidates on it; another fit is replayed
    /// anew.
    #[test]
    fn a_fit_is_replayed_once() {
        use crate::diagnose::alternatives::{self, Alternative};
        use crate::diagnose::DiagnoseConfig;
        use crate::simulate::Scenario;
        let mut sc = Scenario::paper();
        sc.hours = 6.0;
        sc.rate_s = 60.0;
        let cfg = DiagnoseConfig::default();
        let prep = crate::simulate::prepared(&sc, &cfg.identify);
        let catalog = crate::catalog::Catalog::builtin();
        let paper = [crate::catalog::paper()];
        let model = build_model(prep.site, &paper, &cfg.identify).unwrap();
        let id = identify(&model, &prep, &cfg.identify).unwrap();
        let first = alternatives::weigh(&prep, catalog, &paper, &cfg, &id).unwrap();
        let noted = DiagnoseConfig {
            progress: cfg.progress.within("the model does not fit"),
            ..cfg.clone()
        };
        let again = alternatives::weigh(&prep, catalog, &paper, &noted, &id).unwrap();
        let gains = |a: &[Alternative]| a.iter().map(|x| x.evidence_gain).collect::<Vec<_>>();
        assert_eq!(gains(&first), gains(&again));
        assert_eq!(
            cfg.identify.memo.1.lock().unwrap().len(),
            1,
            "replayed once"
        );
        let (d, _) = crate::diagnose::diagnose(&prep, catalog, &paper, &cfg).unwrap();
        assert_eq!(
            cfg.identify.memo.1.lock().unwrap().len(),
            1,
            "and scored from it"
        );
        assert!(!d.ranking.is_empty());
        let mut other = id.clone();
        if let Some(est) = other.refined.as_mut() {
            est.value[0] += 1e-6;
        }
        alternatives::weigh(&prep, catalog, &paper, &cfg, &other).unwrap();
        assert_eq!(cfg.identify.memo.1.lock().unwrap().len(), 2, "another fit");
    }
}
