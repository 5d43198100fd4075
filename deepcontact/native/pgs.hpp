// Projected Gauss-Seidel over a ContactProblem, as Box2D's b2ContactSolver does it: warm start
// applied first, then sweeps over manifolds in the given (island) order, tangent rows before
// normal rows, the 2x2 block solver for two-point manifolds. With R = float, relaxation 1 and
// a fixed iteration count it is Box2D's velocity solver; otherwise it also over-relaxes (PSOR),
// stops on a tolerance, and records how it converged.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include <type_traits>

#include "contact_problem.hpp"
#include "bodyspace.hpp"
#include "interrupt.hpp"
#include "newton.hpp"

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

// What a sweep measures, to stop on (docs/solver.md, "Measuring convergence").
enum class Measure { none, thesis, velocity, residual };
// exact: float32, Box2D's arithmetic and order, starts used as given (Box2D's solver, bit for
// bit); float32: the same, bad starts sanitised first; float64: double precision.
enum class Mode { exact, float32, float64 };
// nncg: each sweep's change plus a multiple of the last direction (Silcowitz et al. 2010);
// newton: a few sweeps to settle which contacts touch and slide, then semismooth Newton steps on
// the whole step (newton.hpp), back to sweeps whenever a Newton step fails.
// subspace: the same with each Newton system solved inexactly by conjugate gradients.
// bodyspace: a few sweeps, then augmented-Lagrangian iterations on the bodies' velocities
// (bodyspace.hpp), back to sweeps whenever one fails to lower the residual.
enum class Acceleration { none, nncg, newton, subspace, bodyspace };

struct SolveOptions {
    Mode mode = Mode::float64;
    int max_iterations = 8;
    double tolerance = 0.0;        // stop once the chosen measure falls below it (0: never)
    Measure stop_on = Measure::none;
    double relaxation = 1.0;       // w of PSOR; 1 is plain PGS (Box2D)
    Acceleration accelerate = Acceleration::none;
    bool history = false;          // record all three measures after every sweep
    double max_velocity = 0.0;     // starts that alone would change a contact's velocity by more
                                   // than this are implausible (0: no such check)
    bool final_residual = true;    // report the residual at the end (one extra pass)
    bool guard = true;             // over-relaxation falls back to w = 1 if the residual climbs
    bool cone = true;              // a start's tangent beyond the friction cone is clamped onto it;
                                   // false to judge an answer as given (its excess is residual)

    bool sanitize() const { return mode != Mode::exact; }  // exact reproduces Box2D, bad starts too
    bool float64() const { return mode == Mode::float64; }
};

// The methods whose work is not only sweeps: float64 only, stopping on the residual.
inline bool is_global(Acceleration a) {
    return a == Acceleration::newton || a == Acceleration::subspace || a == Acceleration::bodyspace;
}

// The one check of a solve's options; throws std::invalid_argument (ValueError in Python).
inline void check(const SolveOptions& o) {
    if (o.max_iterations < 0) throw std::invalid_argument("max_iterations must be >= 0");
    if (!(o.tolerance >= 0.0) || !std::isfinite(o.tolerance))
        throw std::invalid_argument("tolerance must be finite and >= 0");
    if (!(o.relaxation > 0.0 && o.relaxation < 2.0)) throw std::invalid_argument("relaxation must be in (0, 2)");
    if (!(o.max_velocity >= 0.0)) throw std::invalid_argument("max_velocity must be >= 0");
    if (o.mode == Mode::exact && (o.relaxation != 1.0 || o.accelerate != Acceleration::none))
        throw std::invalid_argument("exact mode is Box2D's PGS: no over-relaxation, no acceleration");
    const bool global = is_global(o.accelerate);
    if (global && o.mode != Mode::float64) throw std::invalid_argument("newton, subspace and bodyspace are float64 only");
    if (global && !(o.stop_on == Measure::residual || o.stop_on == Measure::none))
        throw std::invalid_argument("newton, subspace and bodyspace stop on the residual (tolerance 0: exact, 1e-12)");
}

struct SanitizeReport {
    int64_t nonfinite = 0, negative = 0, implausible = 0, cone = 0;
};

struct SolveReport {
    int iterations = 0;
    std::vector<double> history;   // 3 per sweep: thesis, velocity, residual
    double residual = 0.0;         // normalised min-map residual at the end
    double thesis = std::numeric_limits<double>::quiet_NaN();  // the last sweep's measures, when
    double velocity = std::numeric_limits<double>::quiet_NaN();  // they were tracked
    int relaxation_fallback = 0;   // the sweep after which over-relaxation was dropped (0: never)
    int factorizations = 0;        // Newton steps tried (each factorizes one sparse system)
    int newton_fallbacks = 0;      // Newton steps (or outer iterations) that failed, after which sweeps went on
    int newton_iterations = 0;     // bodyspace: Newton iterations on the bodies' momentum balance
    int outer_iterations = 0;      // bodyspace: outer (multiplier and friction bound) iterations
    SanitizeReport sanitized;
};

// Over-relaxed PGS is not guaranteed to converge on every LCP (it is for w in (0, 2) on a
// symmetric positive definite problem without friction, not with the friction cone's coupling):
// when the residual climbs this far above the best seen, the solve continues with w = 1.
constexpr double kRelaxationGuard = 10.0;
constexpr int kGuardEvery = 4;     // sweeps between residual checks when nothing else needs them

template <class R>
inline R clamp_box2d(R a, R low, R high) {  // b2Clamp: b2Max(low, b2Min(a, high))
    R m = a < high ? a : high;
    return low > m ? low : m;
}

template <class R>
class PGS {
public:
    explicit PGS(ContactProblem<R>& pb) : pb_(pb) {}

    // start_n/start_t: the first iterate per contact point, in the caller's row order.
    template <class S>
    SolveReport solve(const S* start_n, const S* start_t, const SolveOptions& opt) {
        SolveReport rep;
        load_start(start_n, start_t, opt, rep.sanitized);
        // The residual is normalised by the free velocities, taken before the warm start.
        if (opt.history || opt.stop_on == Measure::residual || opt.final_residual) scale_ = free_velocity_scale();
        warm_start();
        run_method(opt, rep);
        return rep;
    }

    // The one switch: each method's driver (the global ones are float64 only, by the options' check).
    void run_method(const SolveOptions& opt, SolveReport& rep) {
        if constexpr (std::is_same_v<R, double>) {
            switch (opt.accelerate) {
                case Acceleration::newton:
                case Acceleration::subspace: solve_newton(opt, rep); return;
                case Acceleration::bodyspace: solve_bodyspace(opt, rep); return;
                default: break;
            }
        }
        solve_sweeps(opt, rep);
    }
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
                worst = std::max(worst, std::abs(std::min(double(p.k_normal) * n, vn)));
                if (m.friction_row) {
                    const double kt = double(p.k_tangent);
                    const double vt = double(dot(dv, tangent));
                    const double hi = double(m.friction) * n * kt;
                    const double x = kt * double(p.tangent_impulse);
                    worst = std::max(worst, std::abs(x - std::clamp(x - vt, -hi, hi)));
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
            for (int j = 0; j < m.count; ++j) {
                const V2<R> dv = relative_velocity(m, m.p[j]);
                worst = std::max(worst, std::abs(double(dot(dv, m.normal)) - double(m.p[j].bias)));
                if (m.friction_row) worst = std::max(worst, std::abs(double(dot(dv, tangent))));
            }
        }
        return worst > 1e-30 ? worst : 1e-30;
    }

private:
    static constexpr int kSweepsBeforeNewton = 4;
    static constexpr int kSweepsAfterFailure = 1024;  // at most, doubling from 4 at each failure
    static constexpr int kNewtonLimit = 200;
    static constexpr double kNewtonProgress = 0.5;
    static constexpr double kExact = 1e-12;   // what newton and bodyspace solve to without a tolerance
    static constexpr double kBodySpaceGuard = 10.0;
    static constexpr int kBodySpaceStall = 5;
    static constexpr double kPenalty = 10.0;  // bodyspace's first rho times k: a row's own mass, tenfold

    // What the sweeps driver tracks across sweeps: which accelerations still run, the best
    // residual the guard has seen, and whether the last residual measured is the iterate's.
    struct SweepState {
        bool relax, conjugate;
        double best = std::numeric_limits<double>::infinity();
        bool residual_is_current = false;  // computed after the last sweep: no extra pass needed
        double last_residual = 0.0;
    };

    // PGS, PSOR and NNCG: sweeps until the chosen measure falls below the tolerance or the cap.
    // Over-relaxation and conjugate directions drop to plain sweeps if the residual climbs (guard).
    void solve_sweeps(const SolveOptions& opt, SolveReport& rep) {
        // The change of the iterate is needed only to report it or to stop on it.
        const bool track = opt.history || opt.stop_on != Measure::none;
        const bool track_change = opt.history || opt.stop_on == Measure::thesis || opt.stop_on == Measure::velocity;
        SweepState st{opt.relaxation != 1.0, opt.accelerate == Acceleration::nncg};
        if (st.conjugate) {
            direction_.assign(2 * pb_.points, R(0));
            last_change_ = -1.0;
        }
        for (int it = 0; it < opt.max_iterations; ++it) {
            if (track_change || st.conjugate) save_impulses();
            sweep(st.relax, R(opt.relaxation));
            rep.iterations = it + 1;
            const double residual = measure_residual(opt, it, st, rep);
            // (never after the last sweep, nor once converged: a solve ends on a projected iterate)
            const bool more = it + 1 < opt.max_iterations;
            if (track && converged(opt, residual, track_change, rep)) break;
            if (st.conjugate && more) conjugate_step();
        }
        rep.residual = !opt.final_residual      ? std::numeric_limits<double>::quiet_NaN()
                       : st.residual_is_current ? st.last_residual
                                                : residual();
    }

    // The residual after sweep `it`, where history or the stopping rule needs it or the guard
    // looks (every kGuardEvery sweeps, whatever else is measured, so a solve takes the same
    // iterates with and without history); 0 where nothing needs it. The guard drops over-
    // relaxation and conjugate directions when the residual climbs tenfold above its best.
    double measure_residual(const SolveOptions& opt, int it, SweepState& st, SolveReport& rep) {
        const bool guard_now = (st.relax || st.conjugate) && opt.guard && (it + 1) % kGuardEvery == 0;
        st.residual_is_current = opt.history || opt.stop_on == Measure::residual || guard_now;
        if (!st.residual_is_current) return 0.0;
        const double residual = this->residual();
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
    bool converged(const SolveOptions& opt, double residual, bool track_change, SolveReport& rep) {
        double thesis = 0, velocity = 0;
        if (track_change) {
            sweep_change(thesis, velocity);
            rep.thesis = thesis;
            rep.velocity = velocity;
        }
        if (opt.history) rep.history.insert(rep.history.end(), {thesis, velocity, residual});
        const double value = opt.stop_on == Measure::thesis     ? thesis
                             : opt.stop_on == Measure::velocity ? velocity
                                                                : residual;
        return opt.stop_on != Measure::none && value < opt.tolerance;
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

    // Sweeps (PSOR at w) settle the active set; Newton steps finish while they lower the merit.
    // After a Newton step fails, twice as many sweeps as before run first (sweeps are cheap and
    // change which contacts touch and slide; a factorization costs a hundred sweeps).
    void solve_newton(const SolveOptions& opt, SolveReport& rep) {
        Newton newton(pb_, scale_, opt.accelerate == Acceleration::subspace);
        const R w = R(opt.relaxation);
        const double tolerance = opt.tolerance > 0 ? opt.tolerance : kExact;
        double residual = this->residual();
        auto record = [&] {
            if (opt.history) rep.history.insert(rep.history.end(), {std::nan(""), std::nan(""), residual});
        };
        int sweeps = kSweepsBeforeNewton;
        while (residual >= tolerance && rep.iterations < opt.max_iterations) {
            settle(std::min(sweeps, opt.max_iterations - rep.iterations), w, opt, rep, residual, record);
            while (residual >= tolerance && newton.factorizations() < kNewtonLimit) {
                poll_signals();
                const double before = residual;
                const bool stepped = newton.step();
                rep.factorizations = newton.factorizations();
                if (stepped) {
                    residual = this->residual();
                    record();
                }
                // a step that does not halve the residual is no better than sweeps
                if (!stepped || residual > kNewtonProgress * before) {
                    ++rep.newton_fallbacks;
                    sweeps = std::min(2 * sweeps, kSweepsAfterFailure);
                    break;
                }
            }
        }
        rep.residual = residual;
    }

    // Sweeps settle which contacts touch; outer iterations in body space finish while each lowers
    // the residual (an outer iteration counts as one iteration of the cap). One that does not is
    // undone, and twice as many sweeps as before run first.
    void solve_bodyspace(const SolveOptions& opt, SolveReport& rep) {
        BodySpace body(pb_, scale_, kPenalty);
        BodySpaceWork work;
        const R w = R(opt.relaxation);
        const double tolerance = opt.tolerance > 0 ? opt.tolerance : kExact;
        double residual = this->residual();
        auto record = [&] {
            if (opt.history) rep.history.insert(rep.history.end(), {std::nan(""), std::nan(""), residual});
        };
        std::vector<BodyVelocity<R>> kept_velocity;
        int sweeps = kSweepsBeforeNewton;
        while (residual >= tolerance && rep.iterations < opt.max_iterations) {
            settle(std::min(sweeps, opt.max_iterations - rep.iterations), w, opt, rep, residual, record);
            // The outer iteration is linear and not monotone in the largest row's residual: it goes
            // on while it stays within kBodySpaceGuard of the best residual and finds a new best
            // at least every kBodySpaceStall iterations.
            double best = residual;
            int since_best = 0;
            while (residual >= tolerance && rep.iterations < opt.max_iterations) {
                poll_signals();
                kept_velocity = pb_.velocity;
                save_impulses();
                const double before = residual;
                const bool stepped = body.outer(residual, tolerance, work);
                ++rep.iterations;
                if (stepped) {
                    residual = this->residual();
                    body.progress(before, residual);
                }
                since_best = stepped && residual < best ? 0 : since_best + 1;
                best = std::min(best, residual);
                if (!stepped || !(residual <= kBodySpaceGuard * best) || since_best >= kBodySpaceStall) {
                    if (stepped && !(residual < before)) {  // undone: sweeps go on from where they were
                        pb_.velocity = kept_velocity;
                        restore_impulses();
                        residual = before;
                    }
                    ++rep.newton_fallbacks;
                    record();
                    sweeps = std::min(2 * sweeps, kSweepsAfterFailure);
                    break;
                }
                record();
            }
        }
        rep.factorizations = rep.newton_iterations = work.newton;   // one factorization per Newton iteration
        rep.outer_iterations = work.outer;
        rep.residual = residual;
    }

    // Velocity of B relative to A at a contact point, as the solver computes it.
    V2<R> relative_velocity(const ContactManifold<R>& m, const ContactPoint<R>& p) const {
        const auto& A = pb_.velocity[m.a];
        const auto& B = pb_.velocity[m.b];
        return B.v + cross(B.w, p.rB) - A.v - cross(A.w, p.rA);
    }

    template <class S>
    void load_start(const S* sn, const S* st, const SolveOptions& opt, SanitizeReport& rep) {
        for (auto& m : pb_.manifolds) {
            for (int j = 0; j < m.given; ++j) {
                auto& p = m.p[j];
                double n = double(sn[m.first + j]), t = double(st[m.first + j]);
                if (opt.sanitize()) {
                    if (!std::isfinite(n) || !std::isfinite(t)) {
                        ++rep.nonfinite;
                        n = t = 0;
                    }
                    if (n < 0) {
                        ++rep.negative;
                        n = 0;
                    }
                    if (opt.max_velocity > 0 && (n * double(p.k_normal) > opt.max_velocity ||
                                                 std::abs(t) * double(p.k_tangent) > opt.max_velocity)) {
                        ++rep.implausible;
                        n = t = 0;
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

    // b2ContactSolver::SolveVelocityConstraints, with optional over-relaxation.
    template <bool Relax>
    void sweep(R w) {
        poll_signals();  // (every loop of every method sweeps)
        for (auto& m : pb_.manifolds) {
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

    // The 2x2 total-enumeration block solver of Box2D (cases 1-4, first valid one wins).
    template <bool Relax>
    void block_solve(ContactManifold<R>& m, V2<R>& vA, R& wA, V2<R>& vB, R& wB, R w) {
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

    // Nonsmooth nonlinear conjugate gradient (Silcowitz, Niebe, Erleben 2010): the sweep's change
    // d is the (negative) gradient; the iterate moves on by beta times the last direction, beta =
    // |d|^2 / |d_last|^2 (Fletcher-Reeves), restarting when beta > 1. The next sweep projects.
    void conjugate_step() {
        double change = 0;
        for (const auto& m : pb_.manifolds)
            for (int j = 0; j < m.count; ++j) {
                const double dn = double(m.p[j].normal_impulse) - double(saved_[2 * (m.first + j)]);
                const double dt = double(m.p[j].tangent_impulse) - double(saved_[2 * (m.first + j) + 1]);
                change += dn * dn + dt * dt;
            }
        const double beta = last_change_ > 0 ? change / last_change_ : 2.0;
        last_change_ = change;
        const bool restart = !(beta <= 1.0);
        const R b = R(restart ? 0.0 : beta);
        for (auto& m : pb_.manifolds) {
            auto& A = pb_.velocity[m.a];
            auto& B = pb_.velocity[m.b];
            const V2<R> normal = m.normal;
            const V2<R> tangent = cross(normal, R(1));
            for (int j = 0; j < m.count; ++j) {
                auto& p = m.p[j];
                R& pn = direction_[2 * (m.first + j)];
                R& pt = direction_[2 * (m.first + j) + 1];
                const R dn = p.normal_impulse - saved_[2 * (m.first + j)];
                const R dt = p.tangent_impulse - saved_[2 * (m.first + j) + 1];
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

    ContactProblem<R>& pb_;
    std::vector<R> saved_;
    std::vector<R> direction_;   // NNCG's search direction, 2 per contact point
    double last_change_ = -1.0;
    double scale_ = 1.0;
};

}  // namespace dc
