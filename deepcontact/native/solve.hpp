// The solve of one step's contact problem: the start loaded, the warm start applied, then one
// switch to the method's driver, one file each (solver2d's shape):
//   method_sweeps.hpp     PGS (Box2D's velocity solver), PSOR and NNCG
//   method_newton.hpp     newton, subspace: proximal semismooth Newton on the whole step
//   method_bodyspace.hpp  bodyspace: augmented-Lagrangian iterations on the bodies' velocities
//   method_lagged.hpp     lagged: the same, each Newton system preconditioned by a kept factor
// all over the one sweep kernel (sweeps.hpp). Adding a method: a driver file and a case here.
#pragma once

#include <type_traits>

#include "contact_problem.hpp"
#include "method_bodyspace.hpp"
#include "method_lagged.hpp"
#include "method_newton.hpp"
#include "method_sweeps.hpp"
#include "solve_options.hpp"
#include "sweeps.hpp"

namespace dc {

// The one switch (the global methods are float64 only, by the options' check). carried: what a
// method keeps from one step to the next in the native loop (nullptr: nothing).
template <class R>
void run_method(Sweeps<R>& k, const SolveOptions& opt, SolveReport& rep, LaggedFactor* carried) {
    if constexpr (std::is_same_v<R, double>) {
        switch (opt.accelerate) {
            case Acceleration::newton:
            case Acceleration::subspace: solve_newton(k, opt, rep); return;
            case Acceleration::bodyspace: solve_bodyspace(k, opt, rep); return;
            case Acceleration::lagged: solve_lagged(k, opt, rep, carried); return;
            default: break;
        }
    }
    solve_sweeps(k, opt, rep);
}

// start_n/start_t: the first iterate per contact point, in the caller's row order; carried: what
// the native loop keeps for a method across steps (a lagged factor), or nullptr.
template <class R, class S>
SolveReport solve(ContactProblem<R>& pb, const S* start_n, const S* start_t, const SolveOptions& opt,
                  LaggedFactor* carried = nullptr) {
    SolveReport rep;
    Sweeps<R> k(pb);
    k.load_start(start_n, start_t, opt, rep.sanitized);
    // The residual is normalised by the free velocities, taken before the warm start.
    if (opt.history || opt.stop_on == Measure::residual || opt.final_residual) k.measure_scale();
    k.warm_start();
    run_method(k, opt, rep, carried);
    return rep;
}

}  // namespace dc
