// newton and subspace: sweeps (PSOR at w) settle the active set; proximal semismooth Newton
// steps on the whole step (newton.hpp) finish while each at least halves the residual.
#pragma once

#include <algorithm>
#include <cmath>

#include "newton.hpp"
#include "solve_options.hpp"
#include "sweeps.hpp"

namespace dc {

constexpr int kNewtonLimit = 200;          // factorizations in one solve
constexpr double kNewtonProgress = 0.5;    // a step must at least halve the residual

// Sweeps (PSOR at w) settle the active set; Newton steps finish while they lower the merit.
// After a Newton step fails, twice as many sweeps as before run first (kSettleFirst, kSettleMost).
inline void solve_newton(Sweeps<double>& k, const SolveOptions& opt, SolveReport& rep) {
    Newton newton(k.problem(), k.scale(), opt.accelerate == Acceleration::subspace);
    const double w = opt.relaxation;
    const double tolerance = global_tolerance(opt);
    double residual = k.residual();
    auto record = [&] { record_residual(opt, rep, residual); };
    int sweeps = kSettleFirst;
    while (residual >= tolerance && rep.iterations < opt.max_iterations) {
        k.settle(std::min(sweeps, opt.max_iterations - rep.iterations), w, opt, rep, residual, record);
        while (residual >= tolerance && newton.factorizations() < kNewtonLimit) {
            poll_signals();
            const double before = residual;
            const bool stepped = newton.step();
            rep.factorizations = newton.factorizations();
            if (stepped) {
                residual = k.residual();
                record();
            }
            // a step that does not halve the residual is no better than sweeps
            if (!stepped || residual > kNewtonProgress * before) {
                ++rep.newton_fallbacks;
                sweeps = std::min(2 * sweeps, kSettleMost);
                break;
            }
        }
    }
    rep.residual = residual;
}

}  // namespace dc
