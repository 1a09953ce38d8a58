//! A Levenberg–Marquardt solver over the normal equations.
//!
//! The solver knows nothing of pipes. A problem ([`NormalEquationsProblem`]) returns, at
//! a parameter vector x, the cost F(x) = Σ rᵢ², the Gauss–Newton matrix H = JᵀJ and
//! the half-gradient g = Jᵀr, accumulated point by point (memory independent of the
//! number of residuals). Each iteration solves
//!
//! (H + λ·D) δ = −g,  D = diag(max(Hᵢᵢ, ε·maxⱼ Hⱼⱼ)),
//!
//! by Cholesky and accepts x + δ when it lowers F (Marquardt's scaled damping with
//! Nielsen's update of λ). The floor ε keeps the system definite when a column of J
//! vanishes (a parameter the data do not determine): its step is then exactly zero,
//! so the parameter stays where it started instead of drifting.
//!
//! **Stretched steps.** Under a robust loss H is the curvature of a reweighted problem,
//! and it can exceed F's true curvature along the step (Triggs' correction clipped at
//! zero for residuals past the loss's knee): every Gauss–Newton step then falls short
//! by the same factor and the solver converges linearly (a ToF frame with a systematic
//! error: 0.46 per step, seven passes over 3·10⁵ points). The gradient term is exact, so
//! an accepted step tδ measures the curvature ratio along it,
//!
//! ρ = (2t·q − ΔF)/(t²·h),  q = δᵀ(H + λD)δ,  h = δᵀHδ,
//!
//! ΔF the cost's actual decrease (the model predicts 2tq − t²h), and the next step is
//! stretched by t = 1/ρ, in [1, [`MAX_STRETCH`]]: without damping (λ → 0, q = h) that
//! is the minimum along the step of the model with the measured curvature; with
//! damping, the damping's shortening is kept and only the curvature's excess undone. A
//! ratio ρ ≥ 1 (the model's curvature is not too high) gives t = 1, the plain step; a
//! refused stretched step is retried unstretched. Asked for by
//! [`LmOptions::with_stretched_steps`], for a start near the minimum.

use nalgebra::{SMatrix, SVector};

/// What a problem hands the solver at one parameter vector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalEquations<const N: usize> {
    /// F(x) = Σ rᵢ².
    pub cost: f64,
    /// H = JᵀJ.
    pub jtj: SMatrix<f64, N, N>,
    /// g = Jᵀr (half the gradient of F).
    pub jtr: SVector<f64, N>,
    /// Number of residuals summed.
    pub n_residuals: usize,
}

impl<const N: usize> NormalEquations<N> {
    /// Equations with nothing accumulated yet.
    pub fn zero() -> Self {
        Self {
            cost: 0.0,
            jtj: SMatrix::zeros(),
            jtr: SVector::zeros(),
            n_residuals: 0,
        }
    }

    /// Add one residual r with gradient j (a row of J).
    #[inline(always)]
    pub fn push(&mut self, r: f64, j: &[f64; N]) {
        self.cost += r * r;
        for a in 0..N {
            self.jtr[a] += j[a] * r;
            for b in a..N {
                self.jtj[(a, b)] += j[a] * j[b];
            }
        }
        self.n_residuals += 1;
    }

    /// Add one residual r with gradient j under a robust loss: its cost c(r), gradient
    /// weight `wg` (Jᵀr term) and curvature weight `wh` (JᵀJ term).
    #[inline(always)]
    pub fn push_weighted(&mut self, r: f64, j: &[f64; N], cost: f64, wg: f64, wh: f64) {
        self.cost += cost;
        for a in 0..N {
            self.jtr[a] += wg * j[a] * r;
            let ha = wh * j[a];
            for b in a..N {
                self.jtj[(a, b)] += ha * j[b];
            }
        }
        self.n_residuals += 1;
    }

    /// Add equations accumulated over another set of residuals.
    pub fn merge(&mut self, other: &Self) {
        self.cost += other.cost;
        self.jtj += other.jtj;
        self.jtr += other.jtr;
        self.n_residuals += other.n_residuals;
    }

    /// Mirror the upper triangle filled by [`push`](Self::push) into the lower one.
    pub fn symmetrize(&mut self) {
        for a in 0..N {
            for b in 0..a {
                self.jtj[(a, b)] = self.jtj[(b, a)];
            }
        }
    }
}

/// A nonlinear least-squares problem seen through its normal equations.
pub trait NormalEquationsProblem<const N: usize> {
    /// The (symmetric) normal equations at `x`, or `None` when `x` lies outside the
    /// problem's domain (the solver then treats the step as failed).
    fn normal_equations(&self, x: &SVector<f64, N>) -> Option<NormalEquations<N>>;
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// A convergence test held.
    Converged(Convergence),
    /// The iteration limit was reached first.
    IterationLimit,
    /// No usable step: the problem is undefined at the start, or the damped system
    /// cannot be solved, or every step leaves the domain.
    Degenerate(DegenerateReason),
}

impl Status {
    /// A short machine-readable name: `converged`, `iteration_limit` or `degenerate`.
    pub fn name(&self) -> &'static str {
        match self {
            Status::Converged(_) => "converged",
            Status::IterationLimit => "iteration_limit",
            Status::Degenerate(_) => "degenerate",
        }
    }

    /// The reason in words, for reports.
    pub fn reason(&self) -> &'static str {
        match self {
            Status::Converged(Convergence::ZeroResidual) => "the residuals are zero",
            Status::Converged(Convergence::CostTolerance) => {
                "the fit stopped improving: a further step no longer lowers the residuals"
            }
            Status::Converged(Convergence::StepTolerance) => {
                "the fit settled: the last step changed the parameters by a negligible amount"
            }
            Status::Converged(Convergence::GradientTolerance) => {
                "the fit settled at a minimum of the residuals"
            }
            Status::Converged(Convergence::WithinUncertainty) => {
                "the fit settled: the last step was a small fraction of the parameters' 1-σ, \
                 so more iterations would not change the result measurably"
            }
            Status::IterationLimit => "the iteration limit was reached",
            Status::Degenerate(DegenerateReason::InvalidStart) => {
                "the problem is undefined at the start"
            }
            Status::Degenerate(DegenerateReason::NoDescent) => "no step lowers the cost",
        }
    }

    /// Whether a convergence test held.
    pub fn is_converged(&self) -> bool {
        matches!(self, Status::Converged(_))
    }
}

/// The convergence test that held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Convergence {
    /// The residuals are zero to rounding.
    ZeroResidual,
    /// The relative cost reduction, actual and predicted, fell below `ftol`.
    CostTolerance,
    /// The scaled step fell below `xtol` relative to the scaled parameters.
    StepTolerance,
    /// The residual vector is orthogonal to J's columns within `gtol`.
    GradientTolerance,
    /// The last step was below `stat_tol` standard deviations of the parameters: near
    /// Gauss–Newton it is taken without a further evaluation; damped and refused, x is
    /// kept (that step did not lower the cost: the minimum, or a kink of the cost, lies
    /// within it).
    WithinUncertainty,
}

/// Why no usable step could be found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DegenerateReason {
    /// The problem is undefined at the starting point.
    InvalidStart,
    /// The damping grew past its limit without a step that lowers the cost.
    NoDescent,
}

/// Options of the solver, validated when built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmOptions {
    max_iterations: usize,
    ftol: f64,
    xtol: f64,
    gtol: f64,
    initial_lambda: f64,
    stat_tol: f64,
    stretch: bool,
}

/// A solver option outside its range.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("solver option `{name}` = {value} is outside its range {range}")]
pub struct OptionError {
    /// The option's name.
    pub name: &'static str,
    /// The refused value.
    pub value: f64,
    /// The accepted range, in words.
    pub range: &'static str,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            ftol: 1e-14,
            xtol: 1e-12,
            gtol: 1e-14,
            initial_lambda: 1e-4,
            stat_tol: 0.0,
            stretch: false,
        }
    }
}

fn check(name: &'static str, value: f64, ok: bool, range: &'static str) -> Result<(), OptionError> {
    if ok {
        Ok(())
    } else {
        Err(OptionError { name, value, range })
    }
}

impl LmOptions {
    /// Maximum number of iterations (each evaluates the problem once), at least 1.
    pub fn with_max_iterations(mut self, n: usize) -> Result<Self, OptionError> {
        check("max_iterations", n as f64, n >= 1, "[1, ∞)")?;
        self.max_iterations = n;
        Ok(self)
    }

    /// Relative cost-reduction tolerance, in [0, 1).
    pub fn with_ftol(mut self, v: f64) -> Result<Self, OptionError> {
        check("ftol", v, (0.0..1.0).contains(&v), "[0, 1)")?;
        self.ftol = v;
        Ok(self)
    }

    /// Relative scaled-step tolerance, in [0, 1).
    pub fn with_xtol(mut self, v: f64) -> Result<Self, OptionError> {
        check("xtol", v, (0.0..1.0).contains(&v), "[0, 1)")?;
        self.xtol = v;
        Ok(self)
    }

    /// Gradient (cosine) tolerance, in [0, 1).
    pub fn with_gtol(mut self, v: f64) -> Result<Self, OptionError> {
        check("gtol", v, (0.0..1.0).contains(&v), "[0, 1)")?;
        self.gtol = v;
        Ok(self)
    }

    /// Initial damping λ relative to diag(JᵀJ), in (0, 1e10].
    pub fn with_initial_lambda(mut self, v: f64) -> Result<Self, OptionError> {
        check("initial_lambda", v, v > 0.0 && v <= 1e10, "(0, 1e10]")?;
        self.initial_lambda = v;
        Ok(self)
    }

    /// Statistical tolerance, in [0, 1): when the next step is below this many standard
    /// deviations of the parameters, take it without evaluating and stop (0 disables
    /// the test).
    pub fn with_stat_tol(mut self, v: f64) -> Result<Self, OptionError> {
        check("stat_tol", v, (0.0..1.0).contains(&v), "[0, 1)")?;
        self.stat_tol = v;
        Ok(self)
    }

    /// [`with_stat_tol`](Self::with_stat_tol) for a value known to be valid.
    pub(crate) fn with_stat(mut self, v: f64) -> Self {
        self.stat_tol = v.clamp(0.0, 0.999);
        self
    }

    /// Stretched steps (the module doc), off by default. For a start already near the
    /// minimum: far from it the curvature ratio one step measures says little about the
    /// next, and under a loss with several basins (a robust one, far outliers) a stretched
    /// step can lower the cost into another basin than the plain steps would reach
    /// (`scenarios/straight_false_alarm.toml`, 8" with 5 % far outliers: one of 40 frames
    /// fitted a 429 mm pipe for a 189 mm one with stretched steps from the cold start).
    pub fn with_stretched_steps(mut self, on: bool) -> Self {
        self.stretch = on;
        self
    }

    /// The iteration limit.
    pub fn max_iterations(&self) -> usize {
        self.max_iterations
    }
}

/// What the solver returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmReport<const N: usize> {
    /// The best parameters found.
    pub x: SVector<f64, N>,
    /// The normal equations at `x` (cost, JᵀJ, Jᵀr).
    pub equations: NormalEquations<N>,
    /// Why it stopped.
    pub status: Status,
    /// Number of iterations (problem evaluations after the first).
    pub iterations: usize,
}

/// Relative floor of the damping diagonal (see the module doc).
const DIAG_FLOOR: f64 = 1e-12;
/// Largest damping before the solver gives up.
const MAX_LAMBDA: f64 = 1e16;
/// Largest stretch of a step (see the module doc): the quadratic model with the
/// measured curvature ratio is trusted up to four of its own steps, so curvature ratios
/// down to ρ = 1/4 are corrected exactly, and smaller ones (a near-flat or non-convex
/// direction, where the quadratic model is no guide) still leave at most 1 − 4ρ of the
/// error per step instead of 1 − ρ.
pub const MAX_STRETCH: f64 = 4.0;

/// Minimise F(x) = Σ rᵢ² from `x0` by Levenberg–Marquardt.
///
/// A short loop over `Solver`'s steps: at each accepted point, the tests that need no
/// step (`Solver::stop_at_point`); then damped steps (`Solver::damped_step`) until
/// one is accepted (`Solver::try_step`) or a test ends the run.
pub fn minimize<const N: usize, P: NormalEquationsProblem<N>>(
    problem: &P,
    x0: SVector<f64, N>,
    options: &LmOptions,
) -> LmReport<N> {
    let Some(mut solver) = Solver::start(problem, x0, options) else {
        return LmReport {
            x: x0,
            equations: NormalEquations::zero(),
            status: Status::Degenerate(DegenerateReason::InvalidStart),
            iterations: 0,
        };
    };
    loop {
        // A caller's stop request (`crate::cancel`: a Python caller's Ctrl-C).
        crate::cancel::checkpoint();
        if let Some(status) = solver.stop_at_point() {
            return solver.report(status);
        }
        loop {
            crate::cancel::checkpoint();
            match solver.try_step() {
                Trial::Accepted => break,
                Trial::Rejected => continue,
                Trial::Stop(status) => return solver.report(status),
            }
        }
    }
}

/// What one damped step led to.
enum Trial {
    /// The step lowered the cost and was taken; the next point's tests follow.
    Accepted,
    /// The step was refused and the damping raised; try again.
    Rejected,
    /// A test ended the run.
    Stop(Status),
}

/// The state of one Levenberg–Marquardt run: the current point and its normal
/// equations, the damping λ and its growth factor ν, and the damping diagonal D.
struct Solver<'a, const N: usize, P: NormalEquationsProblem<N>> {
    problem: &'a P,
    options: &'a LmOptions,
    x: SVector<f64, N>,
    eq: NormalEquations<N>,
    diag: SVector<f64, N>,
    lambda: f64,
    nu: f64,
    iterations: usize,
    /// The curvature ratio ρ measured by the last accepted step (1: none measured).
    curvature_ratio: f64,
}

impl<'a, const N: usize, P: NormalEquationsProblem<N>> Solver<'a, N, P> {
    /// The state at `x0`, or `None` when the problem is undefined there.
    fn start(problem: &'a P, x0: SVector<f64, N>, options: &'a LmOptions) -> Option<Self> {
        let eq = problem.normal_equations(&x0)?;
        Some(Self {
            problem,
            options,
            x: x0,
            eq,
            diag: SVector::zeros(),
            lambda: options.initial_lambda,
            nu: 2.0,
            iterations: 0,
            curvature_ratio: 1.0,
        })
    }

    /// The report at the current point.
    fn report(&self, status: Status) -> LmReport<N> {
        LmReport {
            x: self.x,
            equations: self.eq,
            status,
            iterations: self.iterations,
        }
    }

    /// The tests at a new point, before any step: zero residuals, no curvature at all,
    /// a vanishing gradient (MINPACK's cosine max_i |gᵢ| / (√Dᵢᵢ·√F) ≤ gtol), the
    /// iteration limit. Sets the damping diagonal D = diag(max(Hᵢᵢ, ε·maxⱼ Hⱼⱼ)).
    fn stop_at_point(&mut self) -> Option<Status> {
        let eq = &self.eq;
        let tiny_cost = f64::MIN_POSITIVE * 1e10 * eq.n_residuals.max(1) as f64;
        if eq.cost <= tiny_cost {
            return Some(Status::Converged(Convergence::ZeroResidual));
        }
        let hmax = (0..N).map(|i| eq.jtj[(i, i)]).fold(0.0, f64::max);
        if !(hmax > 0.0) || !hmax.is_finite() {
            return Some(Status::Degenerate(DegenerateReason::NoDescent));
        }
        self.diag = SVector::<f64, N>::from_fn(|i, _| eq.jtj[(i, i)].max(DIAG_FLOOR * hmax));
        let gnorm = (0..N)
            .map(|i| eq.jtr[i].abs() / (self.diag[i].sqrt() * eq.cost.sqrt()))
            .fold(0.0, f64::max);
        if gnorm <= self.options.gtol {
            return Some(Status::Converged(Convergence::GradientTolerance));
        }
        if self.iterations >= self.options.max_iterations {
            return Some(Status::IterationLimit);
        }
        None
    }

    /// Raise the damping after a failed step: λ ← λν, ν ← 2ν. `Err` once λ passes
    /// its limit.
    fn raise_damping(&mut self) -> Result<(), Status> {
        self.lambda *= self.nu;
        self.nu *= 2.0;
        if self.lambda > MAX_LAMBDA {
            return Err(Status::Degenerate(DegenerateReason::NoDescent));
        }
        Ok(())
    }

    /// The step δ of (H + λD) δ = −g, raising λ until the system is solvable.
    fn damped_step(&mut self) -> Result<SVector<f64, N>, Status> {
        loop {
            let mut a = self.eq.jtj;
            for i in 0..N {
                a[(i, i)] += self.lambda * self.diag[i];
            }
            let step = a.cholesky().map(|c| -c.solve(&self.eq.jtr));
            match step.filter(|d| d.iter().all(|v| v.is_finite())) {
                Some(delta) => return Ok(delta),
                None => self.raise_damping()?,
            }
        }
    }

    /// One damped step: the tests on the model's prediction, then the evaluation at
    /// x + δ, accepted when it lowers the cost (Nielsen's update of λ), refused
    /// otherwise.
    fn try_step(&mut self) -> Trial {
        let step = match self.damped_step() {
            Ok(d) => d,
            Err(status) => return Trial::Stop(status),
        };
        let (lambda, diag, cost) = (self.lambda, self.diag, self.eq.cost);
        // The stretch t of the damped step δ (module doc): q = δᵀ(H + λD)δ, h = δᵀHδ.
        let h = step.dot(&(self.eq.jtj * step));
        let q = h + lambda * (0..N).map(|i| diag[i] * step[i] * step[i]).sum::<f64>();
        let stretch = if self.options.stretch {
            stretch(self.curvature_ratio)
        } else {
            1.0
        };
        let delta = step * stretch;
        // Scaled step and parameter norms.
        let dnorm = (0..N)
            .map(|i| (diag[i].sqrt() * delta[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let xnorm = (0..N)
            .map(|i| (diag[i].sqrt() * self.x[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        // Predicted reduction of the Gauss–Newton model for the plain step: 2q − h =
        // δᵀHδ + 2λ δᵀDδ; along the stretched step tδ, of the model whose curvature
        // along δ is h/t (the measured one, t = 1/ρ): t(2q − h).
        let hd = self.eq.jtj * delta;
        let plain = 2.0 * q - h;
        let predicted = stretch * plain;
        // Near Gauss–Newton (λ ≤ 1), a step the model says cannot lower the cost by
        // more than ftol is not worth an evaluation: x is the minimum.
        if lambda <= 1.0 && plain <= self.options.ftol * cost {
            return Trial::Stop(Status::Converged(Convergence::CostTolerance));
        }
        // Statistical test: the step, measured in the parameters' standard deviations
        // (√(δᵀHδ/σ̂²), σ̂² = F/(m − N)), is below `stat_tol`. The model is then trusted
        // for this last small step: it is taken without a further evaluation (the
        // equations reported are those at the previous point, which differ by a
        // negligible amount).
        let dof = self.eq.n_residuals.saturating_sub(N).max(1) as f64;
        let stat = self.options.stat_tol;
        if lambda <= 1.0 && stat > 0.0 && delta.dot(&hd) <= stat * stat * cost / dof {
            self.x += delta;
            self.iterations += 1;
            return Trial::Stop(Status::Converged(Convergence::WithinUncertainty));
        }
        self.iterations += 1;
        let x_new = self.x + delta;
        let trial = self
            .problem
            .normal_equations(&x_new)
            .filter(|e| e.cost.is_finite() && e.cost < cost);
        let Some(new_eq) = trial else {
            if stretch > 1.0 {
                // A stretched step refused: the next one is the plain step.
                self.curvature_ratio = 1.0;
                if self.iterations >= self.options.max_iterations {
                    return Trial::Stop(Status::IterationLimit);
                }
                return Trial::Rejected;
            }
            // Refused: the step left the domain or did not lower the cost. (A refused
            // step near Gauss–Newton whose predicted gain is below ftol cannot occur:
            // the test above stopped before evaluating it.)
            // A damped step below `stat_tol` standard deviations refused: on a smooth
            // cost a short enough step along a descent direction lowers it, so the
            // minimum lies within the step, or the cost has a kink there (a bend's exact
            // range error, where rays change wall). The damped steps that follow are
            // shorter still and at most move x by hundredths of its σ: they crept on for
            // tens of evaluations (the bend's exact stage on a tof-sim 20" elbow: 35
            // more, moving no parameter by 0.01σ).
            if stat > 0.0 && delta.dot(&hd) <= stat * stat * cost / dof {
                return Trial::Stop(Status::Converged(Convergence::WithinUncertainty));
            }
            if dnorm <= self.options.xtol * xnorm {
                return Trial::Stop(Status::Converged(Convergence::StepTolerance));
            }
            if let Err(status) = self.raise_damping() {
                return Trial::Stop(status);
            }
            if self.iterations >= self.options.max_iterations {
                return Trial::Stop(Status::IterationLimit);
            }
            return Trial::Rejected;
        };
        let actual = cost - new_eq.cost;
        let gain = actual / predicted.max(f64::MIN_POSITIVE);
        let measured = (2.0 * stretch * q - actual) / (stretch * stretch * h);
        self.curvature_ratio = if measured.is_finite() { measured } else { 1.0 };
        self.lambda = (lambda * (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0)).max(1e-15);
        self.nu = 2.0;
        self.x = x_new;
        self.eq = new_eq;
        if actual / cost <= self.options.ftol && predicted / cost <= self.options.ftol {
            return Trial::Stop(Status::Converged(Convergence::CostTolerance));
        }
        if dnorm <= self.options.xtol * xnorm {
            return Trial::Stop(Status::Converged(Convergence::StepTolerance));
        }
        Trial::Accepted
    }
}

/// The stretch t = 1/ρ of a damped step (module doc), in [1, [`MAX_STRETCH`]]: 1 when
/// ρ ≥ 1, when ρ ≤ 0 (F not convex along the step: no curvature to extrapolate with) or
/// when ρ is not a number.
fn stretch(curvature_ratio: f64) -> f64 {
    let t = 1.0 / curvature_ratio;
    if t.is_finite() && t > 1.0 {
        t.min(MAX_STRETCH)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    //! Every exit of the solver, each reached by a problem built for it.
    use super::*;

    /// A one-parameter problem from residuals r(x) with gradients, or `None` outside
    /// its domain.
    struct One<F: Fn(f64) -> Option<Vec<(f64, f64)>>>(F);

    impl<F: Fn(f64) -> Option<Vec<(f64, f64)>>> NormalEquationsProblem<1> for One<F> {
        fn normal_equations(&self, x: &SVector<f64, 1>) -> Option<NormalEquations<1>> {
            let mut eq = NormalEquations::zero();
            for (r, j) in (self.0)(x[0])? {
                eq.push(r, &[j]);
            }
            Some(eq)
        }
    }

    /// A problem handing the solver raw equations.
    struct Raw(NormalEquations<1>);

    impl NormalEquationsProblem<1> for Raw {
        fn normal_equations(&self, _: &SVector<f64, 1>) -> Option<NormalEquations<1>> {
            Some(self.0)
        }
    }

    /// A problem given by its exact cost F(x) and half-gradient g(x), and a curvature
    /// H(x) that may differ from F's (as a robust loss's reweighted curvature does).
    struct Curved<F: Fn(f64) -> Option<(f64, f64, f64)>>(F);

    impl<F: Fn(f64) -> Option<(f64, f64, f64)>> NormalEquationsProblem<1> for Curved<F> {
        fn normal_equations(&self, x: &SVector<f64, 1>) -> Option<NormalEquations<1>> {
            let (cost, g, h) = (self.0)(x[0])?;
            let mut eq = NormalEquations::zero();
            eq.cost = cost;
            eq.jtr[0] = g;
            eq.jtj[(0, 0)] = h;
            eq.n_residuals = 100;
            Some(eq)
        }
    }

    /// F = 1 + (x − m)², its half-gradient x − m, and a curvature `over` times F's.
    fn over_curved(m: f64, over: f64) -> impl Fn(f64) -> Option<(f64, f64, f64)> {
        move |x| Some((1.0 + (x - m).powi(2), x - m, over))
    }

    #[test]
    fn an_overestimated_curvature_is_measured_and_undone() {
        // H twice F's curvature: each plain step halves the error (5 → 0.625 after
        // three); the first step measures ρ = 1/2 and the second, stretched by 2, lands
        // on the minimum.
        let o = LmOptions::default()
            .with_initial_lambda(1e-12)
            .unwrap()
            .with_stretched_steps(true);
        let r = run(&Curved(over_curved(5.0, 2.0)), 0.0, o);
        // Plain steps (the default) leave 5·2⁻³ after three.
        let plain = run(
            &Curved(over_curved(5.0, 2.0)),
            0.0,
            o.with_stretched_steps(false)
                .with_max_iterations(3)
                .unwrap(),
        );
        assert!(
            (plain.x[0] - (5.0 - 5.0 / 8.0)).abs() < 1e-6,
            "x = {}",
            plain.x[0]
        );
        assert!(r.status.is_converged(), "{:?}", r.status);
        assert!((r.x[0] - 5.0).abs() < 1e-9, "x = {}", r.x[0]);
        assert!(r.iterations <= 3, "{} iterations", r.iterations);
    }

    #[test]
    fn the_stretch_is_capped() {
        // H ten times F's curvature (ρ = 0.1): the stretch stops at MAX_STRETCH, so after
        // the first step (error 5 → 4.5) each leaves 1 − 0.1·MAX_STRETCH = 0.6 of the
        // error: 4.5·0.6⁴ = 0.583 after five steps. Uncapped it would be exact after two;
        // unstretched 5·0.9⁵ = 2.95.
        let o = LmOptions::default()
            .with_max_iterations(5)
            .and_then(|o| o.with_initial_lambda(1e-12))
            .unwrap()
            .with_stretched_steps(true);
        let r = run(&Curved(over_curved(5.0, 10.0)), 0.0, o);
        let expected = 4.5 * (1.0 - 0.1 * MAX_STRETCH).powi(4);
        assert!((r.x[0] - (5.0 - expected)).abs() < 1e-9, "x = {}", r.x[0]);
    }

    #[test]
    fn a_refused_stretched_step_is_retried_plain() {
        // F = 1 + (x − 4)² left of the minimum and 1 + 100 (x − 4)² right of it; H is
        // twice F's curvature below x = 1 and exact above. From 0: the plain step reaches
        // 2 and measures ρ = 1/2; the stretched step from 2 would reach 6 (F = 401) and
        // is refused; the plain step then lands on 4 — without raising the damping,
        // which would have shortened it.
        let f = |x: f64| {
            let (c, g) = if x <= 4.0 {
                ((x - 4.0).powi(2), x - 4.0)
            } else {
                (100.0 * (x - 4.0).powi(2), 100.0 * (x - 4.0))
            };
            Some((1.0 + c, g, if x < 1.0 { 2.0 } else { 1.0 }))
        };
        let o = LmOptions::default()
            .with_initial_lambda(1e-12)
            .unwrap()
            .with_stretched_steps(true);
        let r = run(&Curved(f), 0.0, o);
        assert!(r.status.is_converged(), "{:?}", r.status);
        assert!((r.x[0] - 4.0).abs() < 1e-9, "x = {}", r.x[0]);
    }

    /// A cost with a kink at its minimum, F = 1 + |x|/2 (half-gradient sign(x)/4, model
    /// curvature 1, 100 residuals: σ̂² = F/99, σ_x = σ̂): every Gauss–Newton step jumps
    /// past the kink and is refused, and the damping shortens the steps. With the
    /// statistical stop (`stat_tol` 0.1) the solver ends `WithinUncertainty` at the first
    /// refused step below 0.1σ: a step toward 0 of length δ lowers F unless δ > 2|x|, so
    /// |x| < 0.05σ there; without it the damping creeps on to `StepTolerance`, with more
    /// evaluations.
    #[test]
    fn a_refused_step_within_the_uncertainty_ends_the_run() {
        let kink = |x: f64| Some((1.0 + 0.5 * x.abs(), 0.25 * x.signum(), 1.0));
        let evaluations = |o: LmOptions| {
            let count = std::cell::Cell::new(0usize);
            let r = run(
                &Curved(|x| {
                    count.set(count.get() + 1);
                    kink(x)
                }),
                0.3,
                o,
            );
            (r, count.get())
        };
        let o = LmOptions::default().with_initial_lambda(1e-12).unwrap();
        let (stat, n_stat) = evaluations(o.with_stat(0.1));
        let (plain, n_plain) = evaluations(o);
        assert_eq!(
            stat.status,
            Status::Converged(Convergence::WithinUncertainty)
        );
        let sigma = ((1.0 + 0.5 * stat.x[0].abs()) / 99.0).sqrt();
        assert!(
            stat.x[0].abs() < 0.05 * sigma,
            "x = {}, σ = {sigma}",
            stat.x[0]
        );
        assert_ne!(
            plain.status,
            Status::Converged(Convergence::WithinUncertainty)
        );
        assert!(n_stat < n_plain, "{n_stat} vs {n_plain} evaluations");
    }

    fn run<P: NormalEquationsProblem<1>>(p: &P, x0: f64, o: LmOptions) -> LmReport<1> {
        minimize(p, SVector::from([x0]), &o)
    }

    /// r = (x − 1, x + 1): minimum at 0 with F = 2.
    fn pair(x: f64) -> Option<Vec<(f64, f64)>> {
        Some(vec![(x - 1.0, 1.0), (x + 1.0, 1.0)])
    }

    /// r = x − 90 on the domain x ≥ `lo`.
    fn walled(lo: f64) -> impl Fn(f64) -> Option<Vec<(f64, f64)>> {
        move |x| (x >= lo).then(|| vec![(x - 90.0, 1.0)])
    }

    #[test]
    fn undefined_start() {
        let r = run(&One(|_| None), 0.0, LmOptions::default());
        assert_eq!(r.status, Status::Degenerate(DegenerateReason::InvalidStart));
    }

    #[test]
    fn zero_residual() {
        let r = run(
            &One(|x| Some(vec![(x - 3.0, 1.0)])),
            3.0,
            LmOptions::default(),
        );
        assert_eq!(r.status, Status::Converged(Convergence::ZeroResidual));
    }

    #[test]
    fn no_curvature_at_all() {
        let r = run(&One(|_| Some(vec![(1.0, 0.0)])), 0.0, LmOptions::default());
        assert_eq!(r.status, Status::Degenerate(DegenerateReason::NoDescent));
    }

    #[test]
    fn vanishing_gradient() {
        let r = run(&One(pair), 0.0, LmOptions::default());
        assert_eq!(r.status, Status::Converged(Convergence::GradientTolerance));
        assert_eq!(r.iterations, 0);
    }

    #[test]
    fn iteration_limit_at_a_point() {
        let o = LmOptions::default().with_max_iterations(1).unwrap();
        let rosen = |x: f64| Some(vec![(10.0 * (x * x - 1.0), 20.0 * x), (1.0 - x, -1.0)]);
        let r = run(&One(rosen), -1.2, o);
        assert_eq!(r.status, Status::IterationLimit);
        assert_eq!(r.iterations, 1);
    }

    #[test]
    fn unsolvable_damped_system() {
        let mut eq = NormalEquations::zero();
        eq.push(1.0, &[1.0]);
        eq.jtr[0] = f64::INFINITY;
        let r = run(&Raw(eq), 0.0, LmOptions::default());
        assert_eq!(r.status, Status::Degenerate(DegenerateReason::NoDescent));
    }

    #[test]
    fn model_predicts_no_gain() {
        // The gain 2x² is 5e-15 of F = 2: below ftol, yet representable.
        let r = run(&One(pair), 7e-8, LmOptions::default());
        assert_eq!(r.status, Status::Converged(Convergence::CostTolerance));
        assert_eq!(r.iterations, 0, "stopped before evaluating");
    }

    #[test]
    fn step_within_the_uncertainty() {
        // 100 residuals x − yᵢ: the step to their mean is ≪ 0.5 σ of the mean.
        let ys: Vec<f64> = (0..100)
            .map(|i| ((i * 37) % 100) as f64 / 50.0 - 1.0)
            .collect();
        let mean = ys.iter().sum::<f64>() / 100.0;
        let problem = One(move |x| Some(ys.iter().map(|y| (x - y, 1.0)).collect()));
        let o = LmOptions::default().with_stat_tol(0.5).unwrap();
        let r = run(&problem, mean + 1e-3, o);
        assert_eq!(r.status, Status::Converged(Convergence::WithinUncertainty));
        assert!((r.x[0] - mean).abs() < 1e-6);
    }

    #[test]
    fn accepted_step_with_no_gain() {
        // Damping λ > 1 skips the model test: the step is evaluated, accepted and its
        // gain is below ftol.
        let o = LmOptions::default().with_initial_lambda(2.0).unwrap();
        let r = run(&One(pair), 7e-8, o);
        assert_eq!(r.status, Status::Converged(Convergence::CostTolerance));
        assert_eq!(r.iterations, 1);
    }

    #[test]
    fn accepted_small_step() {
        let o = LmOptions::default()
            .with_ftol(0.0)
            .unwrap()
            .with_xtol(0.5)
            .unwrap();
        let r = run(&One(walled(f64::NEG_INFINITY)), 100.0, o);
        assert_eq!(r.status, Status::Converged(Convergence::StepTolerance));
        assert_eq!(r.iterations, 1);
    }

    #[test]
    fn refused_small_step() {
        let o = LmOptions::default().with_xtol(0.9).unwrap();
        let r = run(&One(walled(100.0)), 100.0, o);
        assert_eq!(r.status, Status::Converged(Convergence::StepTolerance));
        assert_eq!(r.x[0], 100.0);
    }

    #[test]
    fn every_step_refused() {
        let o = LmOptions::default().with_xtol(0.0).unwrap();
        let r = run(&One(walled(100.0)), 100.0, o);
        assert_eq!(r.status, Status::Degenerate(DegenerateReason::NoDescent));
        assert_eq!(r.x[0], 100.0);
    }

    #[test]
    fn iteration_limit_while_refusing() {
        let o = LmOptions::default().with_max_iterations(3).unwrap();
        let r = run(&One(walled(100.0)), 100.0, o);
        assert_eq!(r.status, Status::IterationLimit);
        assert_eq!(r.iterations, 3);
    }
}
