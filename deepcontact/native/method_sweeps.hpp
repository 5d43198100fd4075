// PGS, PSOR and NNCG: sweeps until the chosen measure falls below the tolerance or the cap.
// Over-relaxation and conjugate directions drop to plain sweeps if the residual climbs (guard).
#pragma once

#include <algorithm>
#include <limits>
#include <vector>

#include "solve_options.hpp"
#include "sweeps.hpp"

namespace dc {

// Over-relaxed PGS is not guaranteed to converge on every LCP (it is for w in (0, 2) on a
// symmetric positive definite problem without friction, not with the friction cone's coupling):
// when the residual climbs this far above the best seen, the solve continues with w = 1.
constexpr double kRelaxationGuard = 10.0;
constexpr int kGuardEvery = 4;     // sweeps between residual checks when nothing else needs them

// What the sweeps driver tracks across sweeps: which accelerations still run, the best
// residual the guard has seen, and whether the last residual measured is the iterate's.
struct SweepState {
    bool relax, conjugate;
    double best = std::numeric_limits<double>::infinity();
    bool residual_is_current = false;  // computed after the last sweep: no extra pass needed
    double last_residual = 0.0;
};

// Nonsmooth nonlinear conjugate gradient (Silcowitz, Niebe, Erleben 2010): the sweep's change
// d is the (negative) gradient; the iterate moves on by beta times the last direction, beta =
// |d|^2 / |d_last|^2 (Fletcher-Reeves), restarting when beta > 1. The next sweep projects.
template <class R>
class ConjugateDirection {
public:
    explicit ConjugateDirection(int points) : direction_(2 * points, R(0)) {}

    // After a sweep from the impulses `k` saved: the iterate moved on along the direction.
    void step(Sweeps<R>& k) {
        auto& pb = k.problem();
        const std::vector<R>& saved = k.saved();
        double change = 0;
        for (const auto& m : pb.manifolds)
            for (int j = 0; j < m.count; ++j) {
                const double dn = double(m.p[j].normal_impulse) - double(saved[2 * (m.first + j)]);
                const double dt = double(m.p[j].tangent_impulse) - double(saved[2 * (m.first + j) + 1]);
                change += dn * dn + dt * dt;
            }
        const double beta = last_change_ > 0 ? change / last_change_ : 2.0;
        last_change_ = change;
        const bool restart = !(beta <= 1.0);
        const R b = R(restart ? 0.0 : beta);
        for (auto& m : pb.manifolds) {
            auto& A = pb.velocity[m.a];
            auto& B = pb.velocity[m.b];
            const V2<R> normal = m.normal;
            const V2<R> tangent = cross(normal, R(1));
            for (int j = 0; j < m.count; ++j) {
                auto& p = m.p[j];
                R& pn = direction_[2 * (m.first + j)];
                R& pt = direction_[2 * (m.first + j) + 1];
                const R dn = p.normal_impulse - saved[2 * (m.first + j)];
                const R dt = p.tangent_impulse - saved[2 * (m.first + j) + 1];
                if (!restart) {  // x += beta p, and the bodies' velocities with it
                    const R sn = b * pn, st = b * pt;
                    p.normal_impulse += sn;
                    p.tangent_impulse += st;
                    const V2<R> P = sn * normal + st * tangent;
                    A.v = A.v - m.mA * P;
                    A.w -= m.iA * cross(p.rA, P);
                    B.v = B.v + m.mB * P;
                    B.w += m.iB * cross(p.rB, P);
                }
                pn = b * pn + dn;
                pt = b * pt + dt;
            }
        }
    }

private:
    std::vector<R> direction_;   // 2 per contact point
    double last_change_ = -1.0;
};

// The residual after sweep `it`, where history or the stopping rule needs it or the guard
// looks (every kGuardEvery sweeps, whatever else is measured, so a solve takes the same
// iterates with and without history); 0 where nothing needs it. The guard drops over-
// relaxation and conjugate directions when the residual climbs tenfold above its best.
template <class R>
double measure_residual(const Sweeps<R>& k, const SolveOptions& opt, int it, SweepState& st, SolveReport& rep) {
    const bool guard_now = (st.relax || st.conjugate) && opt.guard && (it + 1) % kGuardEvery == 0;
    st.residual_is_current = opt.history || opt.stop_on == Measure::residual || guard_now;
    if (!st.residual_is_current) return 0.0;
    const double residual = k.residual();
    st.last_residual = residual;
    if (guard_now) {
        if (!(residual <= kRelaxationGuard * st.best)) {
            st.relax = st.conjugate = false;
            rep.relaxation_fallback = it + 1;
        }
        st.best = std::min(st.best, residual);
    }
    return residual;
}

// Records the sweep's measures (history, the last change) and says whether the chosen one is
// below the tolerance.
template <class R>
bool converged(const Sweeps<R>& k, const SolveOptions& opt, double residual, bool track_change, SolveReport& rep) {
    double thesis = 0, velocity = 0;
    if (track_change) {
        k.sweep_change(thesis, velocity);
        rep.thesis = thesis;
        rep.velocity = velocity;
    }
    if (opt.history) rep.history.insert(rep.history.end(), {thesis, velocity, residual});
    const double value = opt.stop_on == Measure::thesis     ? thesis
                         : opt.stop_on == Measure::velocity ? velocity
                                                            : residual;
    return opt.stop_on != Measure::none && value < opt.tolerance;
}

// PGS, PSOR and NNCG: sweeps until the chosen measure falls below the tolerance or the cap.
template <class R>
void solve_sweeps(Sweeps<R>& k, const SolveOptions& opt, SolveReport& rep) {
    // The change of the iterate is needed only to report it or to stop on it.
    const bool track = opt.history || opt.stop_on != Measure::none;
    const bool track_change = opt.history || opt.stop_on == Measure::thesis || opt.stop_on == Measure::velocity;
    SweepState st{opt.relaxation != 1.0, opt.accelerate == Acceleration::nncg};
    ConjugateDirection<R> conjugate(st.conjugate ? k.problem().points : 0);
    for (int it = 0; it < opt.max_iterations; ++it) {
        if (track_change || st.conjugate) k.save_impulses();
        k.sweep(st.relax, R(opt.relaxation));
        rep.iterations = it + 1;
        const double residual = measure_residual(k, opt, it, st, rep);
        // (never after the last sweep, nor once converged: a solve ends on a projected iterate)
        const bool more = it + 1 < opt.max_iterations;
        if (track && converged(k, opt, residual, track_change, rep)) break;
        if (st.conjugate && more) conjugate.step(k);
    }
    rep.residual = !opt.final_residual      ? std::numeric_limits<double>::quiet_NaN()
                   : st.residual_is_current ? st.last_residual
                                            : k.residual();
}

}  // namespace dc
