// The sweep kernel every method shares: Box2D's b2ContactSolver over a ContactProblem. The start
// loaded (and sanitised), the warm start applied, then sweeps over manifolds in the given (island)
// order, tangent rows before normal rows, the 2x2 block solver for two-point manifolds; with
// R = float and w = 1 a sweep is Box2D's velocity iteration bit for bit. Also what every driver
// measures: the residual and a sweep's change. The drivers are method_*.hpp; solve.cpp picks one.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "contact_problem.hpp"
#include "interrupt.hpp"
#include "solve_options.hpp"

namespace dc {

// An impulse P applied at a contact point's lever arms to its two bodies, in b2ContactSolver's
// order and arithmetic (the exact mode depends on both).
template <class R, class Point>
inline void apply_impulse(V2<R> P, const Point& p, R mA, R iA, R mB, R iB, V2<R>& vA, R& wA, V2<R>& vB, R& wB) {
    vA = vA - mA * P;
    wA -= iA * cross(p.rA, P);
    vB = vB + mB * P;
    wB += iB * cross(p.rB, P);
}

template <class R>
inline R clamp_box2d(R a, R low, R high) {  // b2Clamp: b2Max(low, b2Min(a, high))
    R m = a < high ? a : high;
    return low > m ? low : m;
}

template <class R>
class Sweeps {
public:
    explicit Sweeps(ContactProblem<R>& pb) : pb_(pb) {}

    ContactProblem<R>& problem() { return pb_; }
    // The residual's denominator: the free velocities' scale, measured before the warm start
    // (1 until load_start measures it).
    double scale() const { return scale_; }
    // The impulses save_impulses kept, 2 per contact point (normal, tangent).
    const std::vector<R>& saved() const { return saved_; }

    // The larger of two, a NaN kept (std::max drops a NaN term: a start used as given, 1e30 and
    // NaN, left the velocities NaN and the residual read 0).
    static double larger(double worst, double term) { return term > worst || term != term ? term : worst; }

    // The normalised min-map residual of the LCP at the current iterate (see docs/solver.md).
    double residual() const {
        double worst = 0;
        for (const auto& m : pb_.manifolds) {
            const V2<R> tangent = cross(m.normal, R(1));
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                const V2<R> dv = relative_velocity(m, p);
                const double vn = double(dot(dv, m.normal)) - double(p.bias);
                const double n = double(p.normal_impulse);
                worst = larger(worst, std::abs(std::min(double(p.k_normal) * n, vn)));
                if (m.friction_row) {
                    const double kt = double(p.k_tangent);
                    const double vt = double(dot(dv, tangent));
                    const double hi = double(m.friction) * n * kt;
                    const double x = kt * double(p.tangent_impulse);
                    worst = larger(worst, std::abs(x - std::clamp(x - vt, -hi, hi)));
                }
            }
        }
        return worst / scale_;
    }

    // Largest |relative normal velocity - bias| or |tangent velocity| before any impulse:
    // the scale of the problem, so the residual is 1 at a zero start on an approaching contact.
    double free_velocity_scale() const {
        double worst = 0;
        for (const auto& m : pb_.manifolds) {
            const V2<R> tangent = cross(m.normal, R(1));
            for (int j = 0; j < m.count; ++j) take_free_velocity(m, m.p[j], tangent, worst);
        }
        return worst > 1e-30 ? worst : 1e-30;
    }

    void sweep(bool relax, R w) {
        if (relax)
            sweep<true>(w);
        else
            sweep<false>(w);
    }

    // `count` sweeps (PSOR at w), each an iteration of the cap, then the residual; with history,
    // the residual after each sweep is recorded.
    template <class Record>
    void settle(int count, R w, const SolveOptions& opt, SolveReport& rep, double& residual, Record& record) {
        for (int k = 0; k < count; ++k) {
            sweep(opt.relaxation != 1.0, w);
            ++rep.iterations;
            if (opt.history) {
                residual = this->residual();
                record();
            }
        }
        residual = this->residual();
    }

    // The start loaded (sanitised, unless exact), then, in one more pass, judged plausible as a
    // whole (where the options ask) and, with `scale`, the residual's denominator measured (the
    // free velocities, before the warm start).
    template <class S>
    void load_start(const S* sn, const S* st, const SolveOptions& opt, SanitizeReport& rep, bool scale) {
        // Plausible as a whole, never one impulse alone: under a heavy body resting on a light
        // one, impulses that each would fling a body balance each other, and the exact answer is
        // a start like any other. A start whose impulses together change some contact's relative
        // velocity by more than max_velocity (faster than Box2D lets a body travel) is no start.
        const bool judge = opt.sanitize() && opt.cone && opt.max_velocity > 0;
        if (judge) {   // (the impulses' sum on each body, in double whatever R is, made as they load)
            dv_.assign(pb_.velocity.size(), V2<double>{0, 0});
            dw_.assign(pb_.velocity.size(), 0.0);
        }
        for (auto& m : pb_.manifolds) {
            for (int j = 0; j < m.given; ++j) load_point(m, j, sn[m.first + j], st[m.first + j], opt, rep);
            if (judge) add_start(m);
        }
        const bool plausible = check_and_scale(judge ? opt.max_velocity : 0.0, scale);
        if (judge && !plausible) {
            for (auto& m : pb_.manifolds) {
                for (int j = 0; j < m.given; ++j) {
                    m.p[j].normal_impulse = m.p[j].tangent_impulse = R(0);
                    ++rep.implausible;
                }
            }
        }
    }

    // b2ContactSolver::WarmStart
    void warm_start() {
        for (const auto& m : pb_.manifolds) {
            auto& A = pb_.velocity[m.a];
            auto& B = pb_.velocity[m.b];
            V2<R> vA = A.v, vB = B.v;
            R wA = A.w, wB = B.w;
            const V2<R> normal = m.normal;
            const V2<R> tangent = cross(normal, R(1));
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                V2<R> P = p.normal_impulse * normal + p.tangent_impulse * tangent;
                wA -= m.iA * cross(p.rA, P);
                vA = vA - m.mA * P;
                wB += m.iB * cross(p.rB, P);
                vB = vB + m.mB * P;
            }
            A = {vA, wA};
            B = {vB, wB};
        }
    }

    void restore_impulses() {
        for (auto& m : pb_.manifolds)
            for (int j = 0; j < m.count; ++j) {
                m.p[j].normal_impulse = saved_[2 * (m.first + j)];
                m.p[j].tangent_impulse = saved_[2 * (m.first + j) + 1];
            }
    }

    void save_impulses() {
        saved_.resize(2 * pb_.points);
        for (const auto& m : pb_.manifolds)
            for (int j = 0; j < m.count; ++j) {
                saved_[2 * (m.first + j)] = m.p[j].normal_impulse;
                saved_[2 * (m.first + j) + 1] = m.p[j].tangent_impulse;
            }
    }

    // thesis: max over points of |(dn, dt)|; velocity: max over rows of |d lambda| k.
    void sweep_change(double& thesis, double& velocity) const {
        for (const auto& m : pb_.manifolds)
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                const double dn = double(p.normal_impulse) - double(saved_[2 * (m.first + j)]);
                const double dt = double(p.tangent_impulse) - double(saved_[2 * (m.first + j) + 1]);
                thesis = std::max(thesis, std::sqrt(dn * dn + dt * dt));
                velocity = std::max(velocity, std::max(std::abs(dn) * double(p.k_normal),
                                                       std::abs(dt) * double(p.k_tangent)));
            }
    }

private:
    template <class S>
    void load_point(ContactManifold<R>& m, int j, S sn, S st, const SolveOptions& opt, SanitizeReport& rep) {
        auto& p = m.p[j];
        double n = double(sn), t = double(st);
        if (opt.sanitize()) {
            if (!std::isfinite(n) || !std::isfinite(t)) {
                ++rep.nonfinite;
                n = t = 0;
            }
            if (n < 0 && opt.cone) {   // (cone false: an answer judged as given, its sign too)
                ++rep.negative;
                n = 0;
            }
            const double bound = double(m.friction) * n;
            if (opt.cone && std::abs(t) > bound) {
                ++rep.cone;
                t = std::clamp(t, -bound, bound);
            }
        }
        p.normal_impulse = R(n);
        p.tangent_impulse = m.friction_row ? R(t) : R(0);
    }

    // A manifold's loaded impulses added to its bodies' sums (dv_, dw_).
    void add_start(const ContactManifold<R>& m) {
        auto d = [](V2<R> v) { return V2<double>{double(v.x), double(v.y)}; };
        const V2<double> normal = d(m.normal), tangent = cross(normal, 1.0);
        for (int j = 0; j < m.count; ++j) {
            const auto& p = m.p[j];
            const V2<double> P = double(p.normal_impulse) * normal + double(p.tangent_impulse) * tangent;
            dv_[m.a] = dv_[m.a] - double(m.mA) * P;
            dw_[m.a] -= double(m.iA) * cross(d(p.rA), P);
            dv_[m.b] = dv_[m.b] + double(m.mB) * P;
            dw_[m.b] += double(m.iB) * cross(d(p.rB), P);
        }
    }

    // One pass over the points: whether the sums dv_, dw_ change every contact's relative velocity
    // by at most max_velocity (0: not judged, true), and with `scale` the free velocities' scale
    // (free_velocity_scale) kept as the residual's denominator.
    bool check_and_scale(double max_velocity, bool scale) {
        auto d = [](V2<R> v) { return V2<double>{double(v.x), double(v.y)}; };
        bool plausible = true;
        double worst = 0;
        if (!(max_velocity > 0) && !scale) return true;
        for (const auto& m : pb_.manifolds) {
            const V2<double> normal = d(m.normal), tangent = cross(normal, 1.0);
            const V2<R> tangent_r = cross(m.normal, R(1));
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                if (max_velocity > 0 && plausible) {
                    const V2<double> rel = dv_[m.b] + cross(dw_[m.b], d(p.rB)) - dv_[m.a] - cross(dw_[m.a], d(p.rA));
                    const double vn = std::abs(dot(rel, normal)), vt = std::abs(dot(rel, tangent));
                    plausible = vn <= max_velocity && vt <= max_velocity;   // (NaN: not plausible)
                }
                if (scale) take_free_velocity(m, p, tangent_r, worst);
            }
            if (!plausible && !scale) break;
        }
        if (scale) scale_ = worst > 1e-30 ? worst : 1e-30;
        return plausible;
    }

    // A point's |relative normal velocity - bias| and (with friction) |tangent velocity| at the
    // current velocities, each taken into worst where larger. (Friction, not a friction row: a
    // frictionless row posed all the same, unpruned, leaves the problem and its residual as they
    // were, and so must its scale.)
    void take_free_velocity(const ContactManifold<R>& m, const ContactPoint<R>& p, V2<R> tangent, double& worst) const {
        const V2<R> dv = relative_velocity(m, p);
        worst = std::max(worst, std::abs(double(dot(dv, m.normal)) - double(p.bias)));
        if (m.friction_row && m.friction > R(0)) worst = std::max(worst, std::abs(double(dot(dv, tangent))));
    }

    // Velocity of B relative to A at a contact point, as the solver computes it.
    V2<R> relative_velocity(const ContactManifold<R>& m, const ContactPoint<R>& p) const {
        const auto& A = pb_.velocity[m.a];
        const auto& B = pb_.velocity[m.b];
        return B.v + cross(B.w, p.rB) - A.v - cross(A.w, p.rA);
    }

    // b2ContactSolver::SolveVelocityConstraints, with optional over-relaxation.
    template <bool Relax>
    void sweep(R w) {
        poll_signals();  // (every loop of every method sweeps)
        // (two loops: island order's the one it always was, no index read a manifold)
        if (pb_.order.empty())
            sweep_in<Relax, false>(w);
        else
            sweep_in<Relax, true>(w);
    }

    template <bool Relax, bool Ordered>
    void sweep_in(R w) {
        const int32_t* order = pb_.order.data();
        const size_t count = pb_.manifolds.size();
        for (size_t i = 0; i < count; ++i) {
            auto& m = pb_.manifolds[Ordered ? size_t(order[i]) : i];
            auto& A = pb_.velocity[m.a];
            auto& B = pb_.velocity[m.b];
            V2<R> vA = A.v, vB = B.v;
            R wA = A.w, wB = B.w;
            const R mA = m.mA, mB = m.mB, iA = m.iA, iB = m.iB;
            const V2<R> normal = m.normal;
            const V2<R> tangent = cross(normal, R(1));

            if (m.friction_row) {
                for (int j = 0; j < m.count; ++j) {
                    auto& p = m.p[j];
                    V2<R> dv = vB + cross(wB, p.rB) - vA - cross(wA, p.rA);
                    R vt = dot(dv, tangent) - R(0);
                    R lambda = p.tangent_mass * (-vt);
                    if (Relax) lambda = w * lambda;
                    R max_friction = m.friction * p.normal_impulse;
                    R new_impulse = clamp_box2d(p.tangent_impulse + lambda, -max_friction, max_friction);
                    lambda = new_impulse - p.tangent_impulse;
                    p.tangent_impulse = new_impulse;
                    apply_impulse(lambda * tangent, p, mA, iA, mB, iB, vA, wA, vB, wB);
                }
            }

            if (m.count == 1 || !m.block) {
                for (int j = 0; j < m.count; ++j) {
                    auto& p = m.p[j];
                    V2<R> dv = vB + cross(wB, p.rB) - vA - cross(wA, p.rA);
                    R vn = dot(dv, normal);
                    R lambda = -p.normal_mass * (vn - p.bias);
                    if (Relax) lambda = w * lambda;
                    R sum = p.normal_impulse + lambda;
                    R new_impulse = sum > R(0) ? sum : R(0);
                    lambda = new_impulse - p.normal_impulse;
                    p.normal_impulse = new_impulse;
                    apply_impulse(lambda * normal, p, mA, iA, mB, iB, vA, wA, vB, wB);
                }
            } else {
                block_solve<Relax>(m, vA, wA, vB, wB, w);
            }
            A = {vA, wA};
            B = {vB, wB};
        }
    }

    // The 2x2 total-enumeration block solver of Box2D (cases 1-4, first valid one wins). Inlined
    // into the sweep, as in Box2D's own loop: called, the bodies' velocities went through memory.
    template <bool Relax>
    __attribute__((always_inline)) inline void block_solve(ContactManifold<R>& m, V2<R>& vA, R& wA, V2<R>& vB, R& wB,
                                                           R w) {
        auto& cp1 = m.p[0];
        auto& cp2 = m.p[1];
        const R mA = m.mA, mB = m.mB, iA = m.iA, iB = m.iB;
        const V2<R> normal = m.normal;
        const V2<R> a{cp1.normal_impulse, cp2.normal_impulse};
        V2<R> dv1 = vB + cross(wB, cp1.rB) - vA - cross(wA, cp1.rA);
        V2<R> dv2 = vB + cross(wB, cp2.rB) - vA - cross(wA, cp2.rA);
        R vn1 = dot(dv1, normal);
        R vn2 = dot(dv2, normal);
        V2<R> b{vn1 - cp1.bias, vn2 - cp2.bias};
        b = b - mul(m.K, a);

        auto apply = [&](V2<R> x) {
            if (Relax) {  // over-relax the exact 2x2 answer, then keep it feasible
                x = a + w * (x - a);
                x.x = x.x > R(0) ? x.x : R(0);
                x.y = x.y > R(0) ? x.y : R(0);
            }
            V2<R> d = x - a;
            V2<R> P1 = d.x * normal;
            V2<R> P2 = d.y * normal;
            vA = vA - mA * (P1 + P2);
            wA -= iA * (cross(cp1.rA, P1) + cross(cp2.rA, P2));
            vB = vB + mB * (P1 + P2);
            wB += iB * (cross(cp1.rB, P1) + cross(cp2.rB, P2));
            cp1.normal_impulse = x.x;
            cp2.normal_impulse = x.y;
        };

        // Case 1: vn = 0
        V2<R> x = -mul(m.normal_mass, b);
        if (x.x >= R(0) && x.y >= R(0)) return apply(x);
        // Case 2: vn1 = 0, x2 = 0
        x.x = -cp1.normal_mass * b.x;
        x.y = R(0);
        vn2 = m.K.ex.y * x.x + b.y;
        if (x.x >= R(0) && vn2 >= R(0)) return apply(x);
        // Case 3: vn2 = 0, x1 = 0
        x.x = R(0);
        x.y = -cp2.normal_mass * b.y;
        vn1 = m.K.ey.x * x.y + b.x;
        if (x.y >= R(0) && vn1 >= R(0)) return apply(x);
        // Case 4: x = 0
        x.x = R(0);
        x.y = R(0);
        vn1 = b.x;
        vn2 = b.y;
        if (vn1 >= R(0) && vn2 >= R(0)) return apply(x);
        // No solution: Box2D leaves the impulses as they are.
    }

    ContactProblem<R>& pb_;
    std::vector<R> saved_;
    std::vector<V2<double>> dv_;   // the start's impulses summed on each body (plausibility)
    std::vector<double> dw_;
    double scale_ = 1.0;
};

// How the global methods interleave sweeps: this many before the first global step, twice as many
// after each failure, up to kSettleMost (sweeps are cheap and change which contacts touch and
// slide; a factorization costs a hundred sweeps).
constexpr int kSettleFirst = 4;
constexpr int kSettleMost = 1024;

}  // namespace dc
