//! What a diagnosis produces: the comparison of model and measurements, the ranked candidates and
//! the model ladder. Plain data (serde) so the report, the JSON output and the tests share it.

use serde::Serialize;

/// Time series of one model against the measurements, one entry per filter update.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Series {
    /// Time, h.
    pub t_h: Vec<f64>,
    /// Measured specific force (window means), m/s², per axis.
    pub measured: Vec<[f64; 3]>,
    /// Model prediction along the converged (smoothed) trajectory, m/s².
    pub predicted: Vec<[f64; 3]>,
    /// Measured − predicted along the smoothed trajectory, m/s².
    pub residual: Vec<[f64; 3]>,
    /// Filter innovations of the final forward pass, m/s².
    pub innovation: Vec<[f64; 3]>,
    /// 1σ of each innovation (sqrt of the diagonal of S), m/s².
    pub innovation_sigma: Vec<[f64; 3]>,
    /// Whitened innovations (unit variance when the model holds).
    pub whitened: Vec<[f64; 3]>,
    /// NIS of each update (χ²(3) when the model holds).
    pub nis: Vec<f64>,
    /// Measured temperature, °C (NaN where the recording has none).
    pub temp_c: Vec<f64>,
}

pub use crate::consistency::Whiteness;

/// A model's display name from the effects added to the paper's (`paper`, `paper + acc-bias +
/// drift-trend`): the one spelling the commands, the progress notes and the report print.
pub(crate) fn model_name<S: AsRef<str>>(added: &[S]) -> String {
    joined_name(added, " + ")
}

/// [`model_name`] without spaces (`paper+acc-bias`): a cell of the exported plots' CSV index.
pub(crate) fn model_name_compact<S: AsRef<str>>(added: &[S]) -> String {
    joined_name(added, "+")
}

fn joined_name<S: AsRef<str>>(added: &[S], sep: &str) -> String {
    std::iter::once("paper")
        .chain(added.iter().map(AsRef::as_ref))
        .collect::<Vec<_>>()
        .join(sep)
}

/// A rung of a ladder by what it added to the rung `before` it (`+ temp-drift`), the first
/// rung (no `before`) by its [`model_name`].
pub(crate) fn rung_name(model: &[String], before: Option<&[String]>) -> String {
    let Some(prev) = before else {
        return model_name(model);
    };
    let added: Vec<&str> = model
        .iter()
        .filter(|m| !prev.contains(m))
        .map(String::as_str)
        .collect();
    format!("+ {}", added.join(" + "))
}

/// A time interval where the model leaves its band.
#[derive(Clone, Debug, Serialize)]
pub struct FailureWindow {
    /// Start and end, h.
    pub start_h: f64,
    /// End, h.
    pub end_h: f64,
    /// Mean NIS/3 over the interval (1 when the model holds).
    pub nis_mean: f64,
    /// Axis with the largest mean squared whitened innovation there (`x`, `y`, `z`).
    pub worst_axis: char,
}

/// Correlation of the residuals with a candidate regressor.
#[derive(Clone, Debug, Serialize)]
pub struct RegressorCorrelation {
    /// Regressor name: `A_x`, `A_x*A_y`, `t`, `temp`, …
    pub regressor: String,
    /// Correlation coefficient with the residual of each axis.
    pub corr: [f64; 3],
    /// 99 % bound for no correlation (±2.58/√N).
    pub bound99: f64,
}

/// One estimated parameter of a candidate effect.
#[derive(Clone, Debug, Serialize)]
pub struct ParamEstimate {
    /// Parameter name.
    pub name: String,
    /// Unit.
    pub unit: String,
    /// Estimated size (one Gauss–Newton step from the current model).
    pub value: f64,
    /// Its 1σ.
    pub sigma: f64,
    /// Smallest size this run would detect with 90 % power at the 1 % level, same unit.
    pub min_detectable: f64,
}

/// A catalog effect scored against the current model's innovations.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    /// Catalog name.
    pub effect: String,
    /// Physical explanation.
    pub about: String,
    /// Score (Lagrange-multiplier) statistic.
    pub statistic: f64,
    /// Degrees of freedom (identifiable parameters tested).
    pub dof: f64,
    /// p-value of the statistic under χ²(dof).
    pub p_value: f64,
    /// p-value adjusted for the number of candidates tested (Holm).
    pub p_adjusted: f64,
    /// Natural log of the p-value (does not underflow: ranks candidates whose p is 0 in f64).
    pub ln_p_value: f64,
    /// Natural log of the Holm-adjusted p-value.
    pub ln_p_adjusted: f64,
    /// Estimated parameters with 1σ and the detection limit.
    pub params: Vec<ParamEstimate>,
    /// The leading candidates refitted: evidence, residual and consistency after adding it.
    pub refit: Option<super::select::Refit>,
    /// Why it could not be tested (e.g. no temperature column); `None` when tested.
    pub untestable: Option<String>,
}

/// Two candidates whose innovation signatures are nearly the same on this run.
#[derive(Clone, Debug, Serialize)]
pub struct Confounding {
    /// First effect (the higher ranked).
    pub a: String,
    /// Second effect.
    pub b: String,
    /// Largest canonical correlation of their whitened innovation signatures.
    pub canonical_correlation: f64,
    /// Difference of −2 ln p of their score tests (b − a, ≥ 0: `a` ranks first), a scale fair
    /// between effects with different degrees of freedom.
    pub statistic_gap: f64,
    /// Whether the data still prefer one clearly (gap ≥ [`crate::diagnose::SEPARATION_GAP`]).
    pub separated: bool,
    /// What experiment would separate them.
    pub separate_by: String,
}

/// The comparison of one model with the measurements, and what is missing.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    /// Effects in the model (beyond the paper's drift).
    pub model: Vec<String>,
    /// Noise floor of one filter-period mean, m/s², per axis (from raw-sample differences).
    pub floor_mps2: [f64; 3],
    /// RMS of the residual along the converged trajectory, m/s².
    pub residual_rms_mps2: [f64; 3],
    /// RMS over floor, per axis (≈ 1 when the model holds).
    pub residual_rms_over_floor: [f64; 3],
    /// Mean NIS/3 (1 when consistent).
    pub nis_mean: f64,
    /// 95 % band of the mean NIS/3 for this many updates.
    pub nis_band95: [f64; 2],
    /// Whiteness of the whitened innovations.
    pub whiteness: Whiteness,
    /// Where the model fails.
    pub failures: Vec<FailureWindow>,
    /// Residual correlation with candidate regressors.
    pub correlations: Vec<RegressorCorrelation>,
    /// Candidates, most significant first (untestable ones last).
    pub ranking: Vec<Candidate>,
    /// Confounded pairs among the leading candidates.
    pub confounding: Vec<Confounding>,
    /// The consistency of this model (one definition, [`crate::consistency`]).
    pub consistency: crate::consistency::Consistency,
    /// The effect the evidence adds next, and why (`None`: nothing earns its place).
    pub choice: Option<super::select::Choice>,
    /// A candidate whose refit did not converge and which the evidence cannot rule out
    /// ([`super::select::unconverged_rival`]), in words.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unconverged_rival: Option<String>,
    /// One-paragraph verdict in plain words.
    pub verdict: String,
    /// How the model's smoother iterations ended (`None` where no fit ran, e.g. in tests).
    pub convergence: Option<crate::identify::Convergence>,
    /// The time series (for plots).
    #[serde(skip)]
    pub series: Series,
    /// The refits of the candidates made for this run (drift step, warm-up, periodic drift),
    /// which have no place in the catalog's ranking: the choice may be one of them.
    #[serde(skip)]
    pub profiled_refits: Vec<super::select::Refit>,
}

impl Diagnosis {
    /// The refit of `effect` at this rung: a ranked candidate's or a profiled one's.
    pub(crate) fn refit_of(&self, effect: &str) -> Option<&super::select::Refit> {
        self.refits().find(|r| r.effect == effect)
    }

    /// Every refit of this rung: the ranked candidates' and the profiled ones'.
    pub(crate) fn refits(&self) -> impl Iterator<Item = &super::select::Refit> {
        self.ranking
            .iter()
            .filter_map(|c| c.refit.as_ref())
            .chain(&self.profiled_refits)
    }
}

/// One model of the ladder and how it fits.
#[derive(Clone, Debug, Serialize)]
pub struct Rung {
    /// Effects in the model (beyond the paper's drift).
    pub model: Vec<String>,
    /// Residual RMS over floor per axis.
    pub residual_rms_over_floor: [f64; 3],
    /// Mean NIS/3.
    pub nis_mean: f64,
    /// Ljung–Box p-value.
    pub whiteness_p: f64,
    /// The 12 drift coefficients (name, value, 1σ) in this model.
    pub coefficients: Vec<(String, f64, f64)>,
    /// Every parameter of the added effects: (name, unit, value, 1σ).
    pub effect_params: Vec<(String, String, f64, f64)>,
    /// Whether this model is consistent with the measurements.
    pub consistent: bool,
    /// The effect added at the next rung, with its p-value, if any.
    pub next: Option<(String, f64)>,
    /// Why that effect was added (the evidence).
    pub next_reason: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one spelling of a model's name, compact form and rung labels (strings: compared
    /// exactly).
    #[test]
    fn a_model_is_named_by_the_effects_added_to_the_papers() {
        let none: [&str; 0] = [];
        assert_eq!(model_name(&none), "paper");
        let m = ["acc-bias".to_string(), "drift-trend".to_string()];
        assert_eq!(model_name(&m), "paper + acc-bias + drift-trend");
        assert_eq!(model_name_compact(&m), "paper+acc-bias+drift-trend");
        assert_eq!(rung_name(&m, None), "paper + acc-bias + drift-trend");
        assert_eq!(rung_name(&m, Some(&m[..1])), "+ drift-trend");
    }
}
