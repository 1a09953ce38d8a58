//! What an estimate is asked for: the method (C-EPD, RU-EPD, ML-EPD) and the options of
//! [`estimate`](crate::estimate::estimate) — the solver's, the subsample stage, the robust
//! loss and its scale, the range gate, held diameters and a start — each validated when
//! set.

use std::fmt;
use std::str::FromStr;

use crate::error::EpdError;
use crate::lm::LmOptions;
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::residual::{Geometry, Residual};

/// An estimator of the paper (C-EPD, RU-EPD) or ours (ML-EPD).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Method {
    /// Canonical-ellipse residual, eq. (6): biased under depth noise (Theorem 1).
    CEpd,
    /// Error-based residual, eqs. (20)–(23): unbiased (Theorem 2).
    RuEpd,
    /// Range residual along the sensing line (maximum likelihood for range noise).
    MlEpd,
}

impl Method {
    /// All methods, in the order of the paper then ours.
    pub const ALL: [Method; 3] = [Method::CEpd, Method::RuEpd, Method::MlEpd];

    /// The residual the method minimises.
    pub fn residual(self) -> Residual {
        match self {
            Method::CEpd => Residual::Canonical,
            Method::RuEpd => Residual::ErrorBased,
            Method::MlEpd => Residual::Range,
        }
    }

    /// The name used on command lines, in CSV and JSON: `c-epd`, `ru-epd`, `ml-epd`.
    pub fn name(self) -> &'static str {
        match self {
            Method::CEpd => "c-epd",
            Method::RuEpd => "ru-epd",
            Method::MlEpd => "ml-epd",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = EpdError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "c-epd" | "cepd" => Ok(Method::CEpd),
            "ru-epd" | "ruepd" => Ok(Method::RuEpd),
            "ml-epd" | "mlepd" => Ok(Method::MlEpd),
            _ => Err(EpdError::InvalidOption(format!(
                "unknown method `{s}`: expected one of c-epd, ru-epd, ml-epd"
            ))),
        }
    }
}

/// Options of [`estimate`](crate::estimate::estimate), validated when built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimateOptions {
    pub(crate) lm: LmOptions,
    pub(crate) stage_points: usize,
    pub(crate) loss: Loss,
    pub(crate) loss_scale: LossScale,
    pub(crate) range_gate: Option<(f64, f64)>,
    pub(crate) fixed_diameters: Option<(f64, f64)>,
    pub(crate) start: Option<Params>,
    pub(crate) start_points: Option<usize>,
}

/// How the scale of a robust loss is set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LossScale {
    /// As given, in metres of range error (for C-EPD converted to the canonical residual
    /// through r_c ≈ 2δ/R with the initial guess's mean radius R).
    #[default]
    Fixed,
    /// From the data: the loss's 95 %-efficiency constant ([`Loss::k95`]: Huber 1.345,
    /// Cauchy 2.3849) times the robust scale [`crate::loss::mad_sigma`] of the method's
    /// own residuals (1.4826·median|r|), measured
    /// after a first robust pass and again before the final one. The given scale only
    /// seeds the first pass.
    Auto,
}

/// The solver stops once its step is below this many standard deviations of each
/// parameter (taken from the normal equations, without a further pass over the data):
/// point clouds are large samples, and a step of 0.1σ changes an estimate by 0.5 % of its
/// own variance (0.1²), far below anything its 1-σ can show.
pub const STAT_TOL: f64 = 0.1;

/// The evenly strided subsample on which the fit first converges before its final
/// iterations on every point: 8192 points put the parameters within a few of their
/// 1-σ at that size, √(N/8192) of the full frame's (6σ at 3·10⁵ points), from where the
/// iterations on every point, each costing O(N), take few steps (two on a clean full
/// frame, docs/benchmarks.md).
pub const STAGE_POINTS: usize = 8192;

impl Default for EstimateOptions {
    fn default() -> Self {
        Self {
            lm: LmOptions::default().with_stat(STAT_TOL),
            stage_points: STAGE_POINTS,
            loss: Loss::Squared,
            loss_scale: LossScale::Fixed,
            range_gate: None,
            fixed_diameters: None,
            start: None,
            start_points: None,
        }
    }
}

impl EstimateOptions {
    /// The solver options.
    pub fn with_lm(mut self, lm: LmOptions) -> Self {
        self.lm = lm;
        self
    }

    /// A robust loss against outliers; its scale is in metres of range error (for C-EPD
    /// it is converted to the canonical residual through r_c ≈ 2δ/R with the initial
    /// guess's mean radius R), or see [`with_loss_scale`](Self::with_loss_scale).
    pub fn with_loss(mut self, loss: Loss) -> Result<Self, EpdError> {
        loss.validate()?;
        self.loss = loss;
        Ok(self)
    }

    /// How the loss's scale is set: as given, or from the data.
    pub fn with_loss_scale(mut self, scale: LossScale) -> Self {
        self.loss_scale = scale;
        self
    }

    /// The robust loss.
    pub fn loss(&self) -> Loss {
        self.loss
    }

    /// The range gate [min, max] (m), if any.
    pub fn range_gate(&self) -> Option<(f64, f64)> {
        self.range_gate
    }

    /// Keep only the points whose range along their sensing line, *as the model puts
    /// the wall* (not as measured), lies in [min, max] (m). A gate on the measured range
    /// truncates each point's own noise (keeps the points whose error shortened them
    /// near `max`) and biases the diameters; the model range of a ray does not depend
    /// on its point's noise. The model is a first fit on the points whose measured
    /// range lies in the gate; the final fit starts from it.
    pub fn with_range_gate(mut self, min: f64, max: f64) -> Result<Self, EpdError> {
        if !(min >= 0.0 && max > min && !max.is_nan()) {
            return Err(EpdError::InvalidOption(format!(
                "range gate [{min}, {max}] m: need 0 ≤ min < max"
            )));
        }
        self.range_gate = Some((min, max));
        Ok(self)
    }

    /// Hold the diameters at (Dmax, Dmin) (m) and fit only the pose (θx, θy, θz, δy, δz)
    /// of eq. (2): for a pipe of known diameter (depth calibration). The initial guess's
    /// diameters are replaced by these (after putting the guess in canonical form, so
    /// that its roll names the major axis), the solver's step in them is exactly zero,
    /// and the estimate reports them bit for bit with no standard deviation. Both must be
    /// finite and > 0, with Dmax ≥ Dmin.
    pub fn with_fixed_diameters(mut self, d_max: f64, d_min: f64) -> Result<Self, EpdError> {
        if !(d_max.is_finite() && d_min.is_finite() && d_min > 0.0 && d_max >= d_min) {
            return Err(EpdError::InvalidOption(format!(
                "fixed diameters Dmax = {d_max} m, Dmin = {d_min} m: need finite \
                 Dmax ≥ Dmin > 0"
            )));
        }
        self.fixed_diameters = Some((d_max, d_min));
        Ok(self)
    }

    /// The held diameters (Dmax, Dmin) (m), if any.
    pub fn fixed_diameters(&self) -> Option<(f64, f64)> {
        self.fixed_diameters
    }

    /// Start the solver at `beta`, a fit of the same points or of a sample of them (the
    /// pilot fit of `--max-points`' informed choice), instead of the data-only start: the
    /// subsample stage and the robust loss's refit there are skipped, the loss's data scale
    /// is taken at `beta`, and the solver iterates on all points from it. The estimate is
    /// the same minimum of the same cost wherever the start lies in its basin; the loss's
    /// data scale is then measured at another point near it (1.4826·median|rᵢ| moves by
    /// the start's error, a few of its standard deviations). With held diameters the held
    /// values replace `beta`'s. `beta` must be finite and describe a pipe (positive
    /// diameters).
    pub fn with_start(mut self, beta: Params) -> Result<Self, EpdError> {
        let finite = beta.to_array().iter().all(|v| v.is_finite());
        if !finite || Geometry::new(&beta).is_none() {
            return Err(EpdError::InvalidOption(format!(
                "start β {:?}: need finite parameters with Dmax, Dmin > 0",
                beta.to_array()
            )));
        }
        self.start = Some(beta);
        self.start_points = None;
        Ok(self)
    }

    /// [`with_start`](Self::with_start) from a fit of `n` points of a sample of the
    /// frame (the informed choice's pilot): a fit of N > 2m points, m = 2n, then first
    /// converges on an evenly strided subsample of about m of them
    /// (`warm_stage_points`), then iterates on all points. A
    /// fit of n points lies about √(N/n) of the final fit's standard deviations from the
    /// final minimum (its first step measured 24 of them, in 7 dimensions, from the pilot
    /// of 1024 points to the fit of 20 000: `epd estimate --max-points 20000` on a frame of
    /// `epd simulate --seed 3`, solver traced), and from there the solver evaluated the
    /// cost over all points 8 times, each step short of the minimum where the robust
    /// loss's weights move with the step; with a stage on 2n points (half the start's
    /// variance, at 2n/N of a pass per evaluation), 7 evaluations over its 2 223 points
    /// and 3 over all.
    pub fn with_start_fitted_on(self, beta: Params, n: usize) -> Result<Self, EpdError> {
        let mut o = self.with_start(beta)?;
        o.start_points = Some(n);
        Ok(o)
    }

    /// The points of the first stage of a fit of `n` points warm-started by
    /// [`with_start_fitted_on`](Self::with_start_fitted_on): twice the start's, when
    /// `n` is more than twice that (else `None`: no stage).
    pub(crate) fn warm_stage_points(&self, n: usize) -> Option<usize> {
        let m = 2 * self.start_points?;
        (m > 0 && n > 2 * m).then_some(m)
    }

    /// The solver's start ([`with_start`](Self::with_start)), if any.
    pub fn start(&self) -> Option<Params> {
        self.start
    }

    /// These options with the data-only start: for a fit of other points than those the
    /// start was fitted to (a section of the frame, after a survey's first fit).
    pub fn without_start(mut self) -> Self {
        self.start = None;
        self.start_points = None;
        self
    }

    /// The start of a fit of `self`: [`with_start`](Self::with_start)'s β with the held
    /// diameters, if any.
    pub(crate) fn held_start(&self) -> Option<Params> {
        let mut beta = self.start?;
        if let Some((d_max, d_min)) = self.fixed_diameters {
            (beta.d_max, beta.d_min) = (d_max, d_min);
        }
        Some(beta)
    }

    /// Which parameters of eq. (2) the solver holds.
    pub(crate) fn fixed_mask(&self) -> [bool; N_PARAMS] {
        let held = self.fixed_diameters.is_some();
        [held, held, false, false, false, false, false]
    }

    /// Size of the evenly strided subsample on which the fit first converges before the
    /// final iterations on all points; 0 fits all points from the start. At least 64
    /// otherwise.
    pub fn with_stage_points(mut self, n: usize) -> Result<Self, EpdError> {
        if n != 0 && n < 64 {
            return Err(EpdError::InvalidOption(format!(
                "stage_points = {n}: use 0 (no subsample stage) or at least 64"
            )));
        }
        self.stage_points = n;
        Ok(self)
    }
}
