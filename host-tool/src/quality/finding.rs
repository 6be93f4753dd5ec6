//! A finding of the screening or of the assessment: what kind of defect or explanation, what
//! was done about it, where in the recording.

use serde::Serialize;

/// What a finding is about: a data fault, a set-up misstatement or the recording's shape. The
/// name (kebab-case) is what the text, JSON and report print.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Too few samples to estimate anything.
    TooFewSamples,
    /// An accelerometer axis that does not respond.
    DeadAxis,
    /// So many samples rejected that what is left cannot support an estimate.
    TooManyRejected,
    /// Samples with NaN or infinite values.
    NonFinite,
    /// All-zero samples (a logger that wrote nothing).
    Dropout,
    /// Runs of identical values on an axis.
    Stuck,
    /// Single samples far outside the noise.
    Glitch,
    /// Samples pinned at a rail.
    Saturated,
    /// A window the user excluded (`--exclude`).
    Excluded,
    /// Outputs quantised coarser than the noise.
    Quantization,
    /// Filter-period means scattering more than the raw noise predicts.
    MeanNoise,
    /// A recording without measurable noise.
    NoNoise,
    /// A step in the filter-period means of one axis.
    Step,
    /// A step of one accelerometer's bias, estimated and repaired.
    AccBiasStep,
    /// A short disturbance (burst) on one axis, excluded.
    Disturbance,
    /// A step of the gyros' drift at one time, modelled (`drift-step`).
    DriftStep,
    /// A time column in other units than seconds.
    TimeUnits,
    /// A gap in the time axis.
    TimeGap,
    /// A change of the sample interval.
    SampleRateChange,
    /// Specific force written in g instead of m/s².
    UnitsG,
    /// The measured gravity magnitude disagrees with the metadata.
    GravityMismatch,
    /// The platform not level at the start.
    InitialTilt,
    /// An inverted or swapped axis at the start.
    InitialOrientation,
    /// Gravity turning as in the other hemisphere: the latitude's sign, or a left-handed frame.
    OtherHemisphere,
    /// The metadata latitude contradicted by the data.
    Latitude,
    /// A latitude misstatement that competes with another explanation.
    LatitudeConfounded,
    /// A misstated set-up (latitude, clock rate, gravity), repaired or confounded.
    SetUp,
}

impl Kind {
    /// The printed name, e.g. `time-gap`.
    pub fn name(self) -> &'static str {
        match self {
            Kind::TooFewSamples => "too-few-samples",
            Kind::DeadAxis => "dead-axis",
            Kind::TooManyRejected => "too-many-rejected",
            Kind::NonFinite => "non-finite",
            Kind::Dropout => "dropout",
            Kind::Stuck => "stuck",
            Kind::Glitch => "glitch",
            Kind::Saturated => "saturated",
            Kind::Excluded => "excluded",
            Kind::Quantization => "quantization",
            Kind::MeanNoise => "mean-noise",
            Kind::NoNoise => "no-noise",
            Kind::Step => "step",
            Kind::AccBiasStep => "acc-bias-step",
            Kind::Disturbance => "disturbance",
            Kind::DriftStep => "drift-step",
            Kind::TimeUnits => "time-units",
            Kind::TimeGap => "time-gap",
            Kind::SampleRateChange => "sample-rate-change",
            Kind::UnitsG => "units-g",
            Kind::GravityMismatch => "gravity-mismatch",
            Kind::InitialTilt => "initial-tilt",
            Kind::InitialOrientation => "initial-orientation",
            Kind::OtherHemisphere => "other-hemisphere",
            Kind::Latitude => "latitude",
            Kind::LatitudeConfounded => "latitude-confounded",
            Kind::SetUp => "set-up",
        }
    }
}

impl Serialize for Kind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What was done about a finding.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Action {
    /// The defect was corrected (e.g. a time unit, outputs in g); the estimate stands.
    Repaired,
    /// The affected samples were left out of the filter-period means.
    Rejected,
    /// Noted; nothing to do (e.g. a gap the filter bridges).
    Noted,
    /// Not repaired: the numbers are computed but not trusted (exit 3).
    NotRepaired,
    /// The recording cannot support an estimate (exit 2).
    Refused,
}

/// One data-quality finding.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Finding {
    /// What the finding is about.
    pub kind: Kind,
    /// What is wrong, in plain words with the numbers.
    pub message: String,
    /// First affected time, s (recording's time axis after any time repair).
    pub start_s: Option<f64>,
    /// Last affected time, s.
    pub end_s: Option<f64>,
    /// Samples affected.
    pub samples: usize,
    /// What was done.
    pub action: Action,
}

impl Finding {
    /// One line for the terminal.
    pub fn line(&self) -> String {
        let when = match (self.start_s, self.end_s) {
            (Some(a), Some(b)) if b > a => format!(" [t = {a:.1}–{b:.1} s]"),
            (Some(a), _) => format!(" [t = {a:.1} s]"),
            _ => String::new(),
        };
        let act = match self.action {
            Action::Repaired => "repaired",
            Action::Rejected => "samples rejected",
            Action::Noted => "noted",
            Action::NotRepaired => "estimate not trusted",
            Action::Refused => "refused",
        };
        format!("{}{when}: {} ({act})", self.kind, self.message)
    }
}

/// A recording that cannot support an estimate: the findings say why.
#[derive(Debug)]
pub struct Refusal {
    /// Every finding so far, the refused ones included.
    pub findings: Vec<Finding>,
    /// The time stamp of the sample where the recording fails, when one sample is to blame (the
    /// first irregular time), s on the samples' time axis: the CLI names its file line.
    pub at_s: Option<f64>,
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let refused: Vec<String> = self
            .findings
            .iter()
            .filter(|x| x.action == Action::Refused)
            .map(|x| x.line())
            .collect();
        write!(
            f,
            "the recording cannot support an estimate: {}",
            refused.join("; ")
        )?;
        let others: Vec<String> = self
            .findings
            .iter()
            .filter(|x| x.action != Action::Refused)
            .map(|x| x.line())
            .collect();
        if !others.is_empty() {
            write!(f, " (also found: {})", others.join("; "))?;
        }
        Ok(())
    }
}

impl std::error::Error for Refusal {}
