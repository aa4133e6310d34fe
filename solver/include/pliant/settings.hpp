// SPDX-License-Identifier: Apache-2.0
// Everything a step needs to know besides the model and the state: time step, substeps,
// the sweep and accelerator choice with their parameters, stopping rules, damping, gravity.
// Names and defaults here are the ones the CLI and the API expose.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string>
#include <string_view>

namespace pliant {

enum class Sweep {
  GaussSeidel,  // coloured Gauss-Seidel: colours in parallel, tets of a colour 4 at a time
  Jacobi,       // constraint-parallel, averaged corrections
  Sequential,   // Gauss-Seidel one tet at a time in mesh order, one thread (the thesis's sweep)
};

enum class Method {
  Xpbd,                // plain projection, no acceleration
  Sor,                 // over-relaxation of positions between sweeps
  LambdaSor,           // over-relaxation of each multiplier increment (diverges for large omega)
  Chebyshev,           // Chebyshev semi-iterative on positions (Wang 2015)
  Anderson,            // Anderson on the multiplier increments, omega = 1
  AndersonSor,         // Anderson on the multiplier increments, scaled by omega (the thesis)
  Extrapolation,       // omega * last increment under the residual check (Anderson with theta = 0)
  // Solver families beyond constraint projection (same model, state, contacts and tools):
  Vbd,                 // vertex block descent: per-vertex 3x3 Newton on the incremental potential
  Newton,              // global Newton step on the incremental potential (sparse Cholesky)
  // Not a solver: the server picks one of the above per scene by measured accuracy per
  // millisecond within the scene's time budget. The stepper never sees it.
  Auto,
};

// Which family a method belongs to: the constraint-projection methods share one loop.
enum class SolverFamilyKind { ConstraintProjection, VertexBlockDescent, Newton };
SolverFamilyKind family_of(Method m);

enum class Damping { None, Simple, RigidPreserving };

// How the Newton family solves H d = -g each iteration (see docs/solver.md, "Inexact Newton").
enum class NewtonLinearSolver {
  Auto,    // direct up to kNewtonDirectMaxDofs free dofs, cg above
  Direct,  // sparse LDL^T (Eigen SimplicialLDLT): the exact Newton direction
  Cg,      // inexact Newton: conjugate gradients to a forcing term, preconditioned by a factorisation
           // of an earlier Hessian (refreshed when CG slows) up to 20,000 free dofs, else as cg-twolevel
  CgJacobi,  // the same preconditioned by the inverses of the 3x3 vertex blocks only
  CgFactor,  // cg preconditioned by the earlier factorisation whatever the size (a large body's
             // slow modes converge within the ticks; each tick pays the factor's solves)
  CgTwoLevel,  // cg preconditioned by the vertex blocks plus a coarse solve on piecewise rigid
               // motions of vertex aggregates (a large body's slow modes at a small cost per tick)
};

// Free dofs above which newton_linear_solver auto uses cg: beam3 (4,320 free dofs) stays direct,
// the thesis hippo (8,220) and armadillo (42,783) hanging from 10% of x go to cg (docs/solver.md,
// "Inexact Newton").
inline constexpr int kNewtonDirectMaxDofs = 5000;

// Which Anderson formulation the anderson / anderson-sor methods use (see docs/solver.md).
enum class AndersonForm {
  Thesis,  // the thesis's eq. 2.11-2.15: Anderson on the increments, residual e = D_k - D_{k-1}
  TypeII,  // textbook type-II Anderson on lambda -> lambda + D(lambda), mixing beta = omega
};

struct ChebyshevParams {
  double rho = 0.95;   // estimated spectral radius of the sweep
  double gamma = 0.9;  // under-relaxation
  int delay = 10;      // plain iterations before the acceleration starts
};

constexpr int kMaxSubsteps = 10000;  // the most substeps a tick may have (validate, effective_substeps)

struct SolverSettings {
  double dt = 1.0 / 60.0;   // tick length h, s
  int substeps = 64;        // h is split into this many substeps (small steps: see docs/solver.md)
  // When > 0, substeps is chosen per step from the body instead: the fewest (at most 10000)
  // that keep wave_courant_number(model, dt / substeps) at or below this (effective_substeps()
  // in stepper.hpp). 0.3 with 1 iteration resolves the material within ~2% on beam3.
  double target_wave_courant_number = 0.0;
  int iterations = 1;       // iterations per substep (upper bound when a stop rule is set)
  Sweep sweep = Sweep::GaussSeidel;
  Method method = Method::Xpbd;
  int window = 5;           // Anderson window m
  double omega = 1.0;       // SOR / lambda-SOR / Anderson-SOR factor (1 for plain methods)
  AndersonForm anderson_form = AndersonForm::Thesis;
  double condition_limit = 1e3;  // Anderson: drop oldest columns while cond(dE^T dE) exceeds it
  ChebyshevParams chebyshev;
  double jacobi_relaxation = 1.0;  // scales the averaged Jacobi corrections
  // Stop a substep's iterations early when ||r|| / ||r0|| < tolerance (0: off) ...
  double tolerance = 0.0;
  // ... or when the whole step has used this much wall time, ms (0: off). Every substep then
  // gets an equal share of the budget.
  double time_budget_ms = 0.0;
  Damping damping = Damping::Simple;
  double damping_coefficient = 0.5;  // Simple: v *= exp(-k h)  (1/s); Rigid: k in [0,1] per step
  Eigen::Vector3d gravity{0.0, -9.81, 0.0};
  // Inversion safety: tets whose volume ratio det(F) falls below this are pushed back by a
  // unilateral volume constraint (0 disables it; see docs/solver.md).
  double inversion_floor = 0.2;
  // Each tet's projection step is shortened (halved, at most 5 times) until that tet's own
  // residual ||C + alpha~ lambda|| does not grow: the Green strain's linearisation overshoots
  // on compressed tets (see docs/solver.md). false: the thesis's full step.
  bool line_search = true;
  int threads = 1;          // worker threads for the sweeps (1: all on the calling thread)
  // Method newton: the linear solver of each iteration (auto: by the body's size).
  NewtonLinearSolver newton_linear_solver = NewtonLinearSolver::Auto;
  // Method newton with CG: the loosest relative residual CG is asked for in an iteration (its
  // forcing term's cap; 0: the preconditioner's default, 0.5 or 0.01 for the two-level one).
  double newton_forcing = 0;
  bool record_residuals = true;  // compute ||r|| after every iteration (needed by Anderson)
};

std::string_view to_string(Sweep s);
std::string_view to_string(Method m);
std::string_view to_string(Damping d);
std::optional<Sweep> parse_sweep(std::string_view s);     // "gauss-seidel" | "jacobi"
std::optional<Method> parse_method(std::string_view s);   // "xpbd" | "sor" | "lambda-sor" | ...
std::string_view method_names();  // "xpbd, sor, ..., auto": the accepted names, for messages
std::string_view sweep_names();   // "gauss-seidel, jacobi, sequential"
std::optional<Damping> parse_damping(std::string_view s); // "none" | "simple" | "rigid"
std::string_view to_string(NewtonLinearSolver s);
std::optional<NewtonLinearSolver> parse_newton_linear_solver(std::string_view s);  // "auto" | "direct" | "cg" | "cg-jacobi" | "cg-factor" | "cg-twolevel"
// Whether method newton on a body with `free_dofs` free degrees of freedom solves with cg.
bool newton_uses_cg(NewtonLinearSolver s, int free_dofs);
std::string_view to_string(AndersonForm f);
std::optional<AndersonForm> parse_anderson_form(std::string_view s);  // "thesis" | "type2"

// How far a budget is from resolving the material, as a rough guide: the wave Courant number of
// its substeps (wave_courant_number in model.hpp) over sqrt(iterations per substep). On beam3 at
// rest the tip's excess over the converged solution follows it for 1 to 16 iterations: about 2%
// at 0.3, 17-30% near 1, 1.8-4.3x at 2-4 (docs/solver.md, "Accuracy of a real-time budget").
// Above 1 the body is clearly softer than its material. Calibrated at nu = 0.4 only: for a
// nearly incompressible material the pressure wave is fast and the number overstates the
// error (the haptic bridge's press at nu = 0.49, docs/haptics.md: 1.2 with the force within
// 1% of the converged one, 3.7 with it 42% low), so it is not interpreted above this nu.
double under_resolution(double wave_courant_number, int iterations);
constexpr double kUnderResolutionMaxPoisson = 0.45;

// Empty when valid, else a message naming the bad field and its value.
std::string validate(const SolverSettings& settings);

}  // namespace pliant
