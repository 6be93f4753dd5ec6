//! One parameter of a candidate made for the run — a warm-up's time constant, a cycle's period —
//! profiled by evidence: the candidate's amplitudes enter linearly, so each value costs one
//! forward pass linearised about the current fit ([`super::drift_step::with_extra`]). The values
//! run over a coarse geometric grid, then every ×`ratio` within the best coarse cell; every value
//! tried is kept (a [`Member`]: where the run does not settle the value and the coefficients
//! follow it, another value is a rival of its own, [`super::select`]).

use estimator_core::effects::Effect;
use rayon::prelude::*;

use super::select::{Member, Profiled};
use crate::identify::{Config, Identification, Prepared};

/// The grid of one profiled parameter.
pub(crate) struct Grid<'a> {
    /// The coarse values, s.
    pub coarse_s: &'a [f64],
    /// The fine grid's ratio within the best coarse cell…
    pub ratio: f64,
    /// …and its steps each way.
    pub steps: i32,
    /// The candidate at a value.
    pub made: fn(f64) -> Profiled,
    /// The look-elsewhere penalty charged to every value's gain, −2 ln units.
    pub penalty: f64,
}

/// The best value found, its gain and every value tried.
pub struct Fit {
    /// The best value, s.
    pub value_s: f64,
    /// Its evidence gain over the fit profiled, net of the look-elsewhere penalty.
    pub evidence_gain: f64,
    /// Every value tried, with its gain (net of the same penalty) and coefficients.
    pub members: Vec<Member>,
}

/// Profiles `grid` on `id`'s fit of `effects`; `keep` drops fine values the run cannot show.
/// `None` when every pass failed.
pub(crate) fn over(
    prep: &Prepared,
    effects: &[&dyn Effect],
    cfg: &Config,
    id: &Identification,
    grid: &Grid<'_>,
    keep: impl Fn(f64) -> bool,
) -> Option<Fit> {
    let base = crate::identify::neg2_log_evidence(&id.innovations);
    let eval = |values_s: Vec<f64>| -> Vec<(f64, Member)> {
        values_s
            .par_iter()
            .filter_map(|&v| {
                let profiled = (grid.made)(v);
                let effect = profiled.make();
                let e = super::drift_step::with_extra(prep, effects, cfg, id, effect.as_ref())?;
                Some((
                    v,
                    Member {
                        profiled,
                        evidence_gain: base - e.neg2_log_evidence - grid.penalty,
                        drift: e.drift,
                    },
                ))
            })
            .collect()
    };
    let best = |v: &[(f64, Member)]| {
        v.iter()
            .max_by(|a, b| a.1.evidence_gain.total_cmp(&b.1.evidence_gain))
            .map(|(value, m)| (*value, m.evidence_gain))
    };
    let mut tried = eval(grid.coarse_s.to_vec());
    let (coarse, _) = best(&tried)?;
    let values: Vec<f64> = (-grid.steps..=grid.steps)
        .map(|k| coarse * grid.ratio.powi(k))
        .filter(|v| keep(*v))
        .collect();
    // The fine grid's middle is the coarse best: its member again, not a pass of its own.
    let mut fine = eval(values.iter().copied().filter(|v| *v != coarse).collect());
    if values.contains(&coarse) {
        if let Some(middle) = tried.iter().find(|(v, _)| *v == coarse).cloned() {
            let at = fine.partition_point(|(v, _)| *v < coarse);
            fine.insert(at, middle);
        }
    }
    let (value_s, evidence_gain) = best(&fine)?;
    tried.extend(fine);
    Some(Fit {
        value_s,
        evidence_gain,
        members: tried.into_iter().map(|(_, m)| m).collect(),
    })
}
