// bodyspace: sweeps settle which contacts touch; augmented-Lagrangian iterations on the bodies'
// velocities (bodyspace.hpp) finish while each lowers the residual.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "bodyspace.hpp"
#include "solve_options.hpp"
#include "sweeps.hpp"

namespace dc {

constexpr double kPenalty = 10.0;        // the first rho times k: a row's own mass, tenfold
constexpr double kBodySpaceGuard = 10.0;  // outer iterations go on within this of the best residual
constexpr int kBodySpaceStall = 5;        // ... and while one of every this many finds a new best

// Outer iterations from `residual` until the tolerance, the cap, or one that fails: the outer
// iteration is linear and not monotone in the largest row's residual, so it goes on while it stays
// within kBodySpaceGuard of the best residual and finds a new best at least every kBodySpaceStall
// iterations. One that did not lower the residual is undone. false once one failed.
template <class Record>
bool outer_iterations(Sweeps<double>& k, BodySpace& body, BodySpaceWork& work, const SolveOptions& opt,
                      double tolerance, SolveReport& rep, double& residual, Record& record) {
    auto& pb = k.problem();
    std::vector<BodyVelocity<double>> kept_velocity;
    double best = residual;
    int since_best = 0;
    while (residual >= tolerance && rep.iterations < opt.max_iterations) {
        poll_signals();
        kept_velocity = pb.velocity;
        k.save_impulses();
        const double before = residual;
        const bool stepped = body.outer(residual, tolerance, work);
        ++rep.iterations;
        if (stepped) {
            residual = k.residual();
            body.progress(before, residual);
        }
        since_best = stepped && residual < best ? 0 : since_best + 1;
        best = std::min(best, residual);
        if (!stepped || !(residual <= kBodySpaceGuard * best) || since_best >= kBodySpaceStall) {
            if (stepped && !(residual < before)) {  // undone: sweeps go on from where they were
                pb.velocity = kept_velocity;
                k.restore_impulses();
                residual = before;
            }
            ++rep.newton_fallbacks;
            record();
            return false;
        }
        record();
    }
    return true;
}

// Sweeps settle which contacts touch; outer iterations in body space finish while each lowers
// the residual (an outer iteration counts as one iteration of the cap). After one fails, twice
// as many sweeps as before run first (kSettleFirst, kSettleMost). lagged: the factor that
// preconditions the Newton systems (method_lagged.hpp); nullptr factorizes each.
inline void solve_bodyspace(Sweeps<double>& k, const SolveOptions& opt, SolveReport& rep,
                            LaggedFactor* lagged = nullptr) {
    // The lagged method starts from the penalty its factor's last solve ended with (the native
    // loop carries both from step to step); the first solve, and bodyspace, from kPenalty.
    const double penalty = lagged && lagged->penalty() > 0 ? lagged->penalty() : kPenalty;
    BodySpace body(k.problem(), k.scale(), penalty, lagged);
    BodySpaceWork work;
    const double tolerance = global_tolerance(opt);
    double residual = k.residual();
    auto record = [&] { record_residual(opt, rep, residual); };
    int sweeps = kSettleFirst;
    while (residual >= tolerance && rep.iterations < opt.max_iterations) {
        k.settle(std::min(sweeps, opt.max_iterations - rep.iterations), opt.relaxation, opt, rep, residual, record);
        if (!outer_iterations(k, body, work, opt, tolerance, rep, residual, record))
            sweeps = std::min(2 * sweeps, kSettleMost);
    }
    rep.factorizations = work.factorizations;
    rep.newton_iterations = work.newton;
    rep.outer_iterations = work.outer;
    if (lagged) lagged->set_penalty(body.penalty());
    rep.residual = residual;
}

}  // namespace dc
