// The solve of one step's contact problem (solve.cpp): the start loaded, the warm start applied,
// then one switch to the method's driver, one file each (solver2d's shape):
//   method_sweeps.hpp     PGS (Box2D's velocity solver), PSOR and NNCG
//   method_newton.hpp     newton, subspace: proximal semismooth Newton on the whole step
//   method_bodyspace.hpp  bodyspace: augmented-Lagrangian iterations on the bodies' velocities
//   method_lagged.hpp     lagged: the same, each Newton system preconditioned by a kept factor
// all over the one sweep kernel (sweeps.hpp). Adding a method: a driver file and a case in
// solve.cpp. Only declarations here: the drivers (and Eigen's sparse solvers under them) compile
// once, in solve.cpp, not in every file that calls a solve.
#pragma once

#include <memory>

#include "contact_problem.hpp"
#include "solve_options.hpp"

namespace dc {

class LaggedFactor;   // (lagged_factor.hpp)

// start_n/start_t: the first iterate per contact point, in the caller's row order; carried: what
// the native loop keeps for a method across steps (a lagged factor), or nullptr. Instantiated in
// solve.cpp for R = float and double, S = double.
template <class R, class S>
SolveReport solve(ContactProblem<R>& pb, const S* start_n, const S* start_t, const SolveOptions& opt,
                  LaggedFactor* carried = nullptr);

// An empty factor for a world to carry from step to step (made where its type is whole).
std::shared_ptr<LaggedFactor> new_carried_factor();

}  // namespace dc
