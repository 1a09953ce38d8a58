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
            Status::Converged(Convergence::CostTolerance) => "the cost stopped decreasing (ftol)",
            Status::Converged(Convergence::StepTolerance) => "the step became negligible (xtol)",
            Status::Converged(Convergence::GradientTolerance) => "the gradient vanished (gtol)",
            Status::Converged(Convergence::WithinUncertainty) => {
                "the last step was below stat_tol of the parameters' standard deviations"
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
    /// The last step was below `stat_tol` standard deviations of the parameters (taken
    /// without a further evaluation).
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

/// Minimise F(x) = Σ rᵢ² from `x0` by Levenberg–Marquardt.
pub fn minimize<const N: usize, P: NormalEquationsProblem<N>>(
    problem: &P,
    x0: SVector<f64, N>,
    options: &LmOptions,
) -> LmReport<N> {
    let Some(mut eq) = problem.normal_equations(&x0) else {
        return LmReport {
            x: x0,
            equations: NormalEquations::zero(),
            status: Status::Degenerate(DegenerateReason::InvalidStart),
            iterations: 0,
        };
    };
    let mut x = x0;
    let mut lambda = options.initial_lambda;
    let mut nu = 2.0;
    let mut iterations = 0;
    let done = |x: SVector<f64, N>, eq, status, iterations| LmReport {
        x,
        equations: eq,
        status,
        iterations,
    };
    loop {
        let tiny_cost = f64::MIN_POSITIVE * 1e10 * eq.n_residuals.max(1) as f64;
        if eq.cost <= tiny_cost {
            return done(
                x,
                eq,
                Status::Converged(Convergence::ZeroResidual),
                iterations,
            );
        }
        // Damping diagonal with a relative floor.
        let hmax = (0..N).map(|i| eq.jtj[(i, i)]).fold(0.0, f64::max);
        if !(hmax > 0.0) || !hmax.is_finite() {
            return done(
                x,
                eq,
                Status::Degenerate(DegenerateReason::NoDescent),
                iterations,
            );
        }
        let diag = SVector::<f64, N>::from_fn(|i, _| eq.jtj[(i, i)].max(DIAG_FLOOR * hmax));
        // Gradient test: max_i |gᵢ| / (√Hᵢᵢ·√F) ≤ gtol (MINPACK's cosine).
        let gnorm = (0..N)
            .map(|i| eq.jtr[i].abs() / (diag[i].sqrt() * eq.cost.sqrt()))
            .fold(0.0, f64::max);
        if gnorm <= options.gtol {
            return done(
                x,
                eq,
                Status::Converged(Convergence::GradientTolerance),
                iterations,
            );
        }
        if iterations >= options.max_iterations {
            return done(x, eq, Status::IterationLimit, iterations);
        }
        // Find an acceptable step.
        loop {
            let mut a = eq.jtj;
            for i in 0..N {
                a[(i, i)] += lambda * diag[i];
            }
            let step = a.cholesky().map(|c| -c.solve(&eq.jtr));
            let Some(delta) = step.filter(|d| d.iter().all(|v| v.is_finite())) else {
                lambda *= nu;
                nu *= 2.0;
                if lambda > MAX_LAMBDA {
                    return done(
                        x,
                        eq,
                        Status::Degenerate(DegenerateReason::NoDescent),
                        iterations,
                    );
                }
                continue;
            };
            // Scaled step and parameter norms.
            let dnorm = (0..N)
                .map(|i| (diag[i].sqrt() * delta[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            let xnorm = (0..N)
                .map(|i| (diag[i].sqrt() * x[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            // Predicted reduction of the Gauss–Newton model: δᵀHδ + 2λ δᵀDδ.
            let hd = eq.jtj * delta;
            let predicted = delta.dot(&hd)
                + 2.0 * lambda * (0..N).map(|i| diag[i] * delta[i] * delta[i]).sum::<f64>();
            // Near Gauss–Newton (λ ≤ 1), a step the model says cannot lower the cost by
            // more than ftol is not worth an evaluation: x is the minimum.
            if lambda <= 1.0 && predicted <= options.ftol * eq.cost {
                return done(
                    x,
                    eq,
                    Status::Converged(Convergence::CostTolerance),
                    iterations,
                );
            }
            // Statistical test: the step, measured in the parameters' standard deviations
            // (√(δᵀHδ/σ̂²), σ̂² = F/(m − N)), is below `stat_tol`. The model is then
            // trusted for this last small step: it is taken without a further
            // evaluation (the equations reported are those at the previous point, which
            // differ by a negligible amount).
            let dof = eq.n_residuals.saturating_sub(N).max(1) as f64;
            if lambda <= 1.0
                && options.stat_tol > 0.0
                && delta.dot(&hd) <= options.stat_tol * options.stat_tol * eq.cost / dof
            {
                return done(
                    x + delta,
                    eq,
                    Status::Converged(Convergence::WithinUncertainty),
                    iterations + 1,
                );
            }
            iterations += 1;
            let x_new = x + delta;
            let trial = problem
                .normal_equations(&x_new)
                .filter(|e| e.cost.is_finite());
            match trial {
                Some(new_eq) if new_eq.cost < eq.cost => {
                    let actual = eq.cost - new_eq.cost;
                    let gain = actual / predicted.max(f64::MIN_POSITIVE);
                    lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
                    lambda = lambda.max(1e-15);
                    nu = 2.0;
                    let rel_actual = actual / eq.cost;
                    let rel_pred = predicted / eq.cost;
                    x = x_new;
                    eq = new_eq;
                    if rel_actual <= options.ftol && rel_pred <= options.ftol {
                        return done(
                            x,
                            eq,
                            Status::Converged(Convergence::CostTolerance),
                            iterations,
                        );
                    }
                    if dnorm <= options.xtol * xnorm {
                        return done(
                            x,
                            eq,
                            Status::Converged(Convergence::StepTolerance),
                            iterations,
                        );
                    }
                    break;
                }
                _ => {
                    // Rejected: the step left the domain or did not lower the cost.
                    // The model, trusted near Gauss–Newton (λ ≤ 1), cannot improve the
                    // cost beyond rounding, or the step is negligible: x is the minimum.
                    // (With large λ a tiny prediction only means heavy damping.)
                    let negligible_model =
                        lambda <= 1.0 && predicted <= options.ftol * eq.cost * 1e-2;
                    if dnorm <= options.xtol * xnorm || negligible_model {
                        return done(
                            x,
                            eq,
                            Status::Converged(Convergence::StepTolerance),
                            iterations,
                        );
                    }
                    lambda *= nu;
                    nu *= 2.0;
                    if lambda > MAX_LAMBDA {
                        return done(
                            x,
                            eq,
                            Status::Degenerate(DegenerateReason::NoDescent),
                            iterations,
                        );
                    }
                    if iterations >= options.max_iterations {
                        return done(x, eq, Status::IterationLimit, iterations);
                    }
                }
            }
        }
    }
}
