#include "solve.hpp"

#include <type_traits>

#include "lagged_factor.hpp"
#include "method_bodyspace.hpp"
#include "method_lagged.hpp"
#include "method_newton.hpp"
#include "method_sweeps.hpp"
#include "sweeps.hpp"

namespace dc {
namespace {

// The one switch (the global methods are float64 only, by the options' check).
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

}  // namespace

template <class R, class S>
SolveReport solve(ContactProblem<R>& pb, const S* start_n, const S* start_t, const SolveOptions& opt,
                  LaggedFactor* carried) {
    SolveReport rep;
    Sweeps<R> k(pb);
    // The residual is normalised by the free velocities, taken before the warm start: measured
    // wherever a residual may be read (reported, stopped on, looked at by the sweeps' guard or by
    // a global method), so that skipping it changes no iterate.
    const bool sweeps = opt.accelerate == Acceleration::none || opt.accelerate == Acceleration::nncg;
    const bool guarded = opt.guard && (opt.relaxation != 1.0 || opt.accelerate == Acceleration::nncg);
    k.load_start(start_n, start_t, opt, rep.sanitized,
                 opt.history || opt.stop_on == Measure::residual || opt.final_residual || guarded || !sweeps);
    k.warm_start();
    run_method(k, opt, rep, carried);
    return rep;
}

template SolveReport solve<float, double>(ContactProblem<float>&, const double*, const double*,
                                          const SolveOptions&, LaggedFactor*);
template SolveReport solve<double, double>(ContactProblem<double>&, const double*, const double*,
                                           const SolveOptions&, LaggedFactor*);

std::shared_ptr<LaggedFactor> new_carried_factor() { return std::make_shared<LaggedFactor>(); }

}  // namespace dc
