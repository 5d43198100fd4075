// What a solve is asked for and what it reports: SolveOptions (with its one check) and
// SolveReport, shared by every method's driver (sweeps.hpp, method_*.hpp) and the bindings.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

namespace dc {

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
// lagged: the same, each Newton system solved by BiCGSTAB preconditioned with a factor kept from
// an earlier system (lagged_factor.hpp), in the native loop from an earlier step.
enum class Acceleration { none, nncg, newton, subspace, bodyspace, lagged };
// The order a sweep visits the manifolds in. island: as posed (Box2D's, the islands' contacts in
// the order it found them); gravity: from the highest to the lowest along gravity (each
// manifold's higher body centre), so that one sweep carries a stack's weight down it.
enum class Order { island, gravity };

struct SolveOptions {
    Mode mode = Mode::float64;
    int max_iterations = 8;
    double tolerance = 0.0;        // stop once the chosen measure falls below it (0: never)
    Measure stop_on = Measure::none;
    double relaxation = 1.0;       // w of PSOR; 1 is plain PGS (Box2D)
    Acceleration accelerate = Acceleration::none;
    bool history = false;          // record all three measures after every sweep
    double max_velocity = 0.0;     // a start whose impulses together change some contact's velocity
                                   // by more than this is implausible (0: no such check)
    bool final_residual = true;    // report the residual at the end (one extra pass)
    bool guard = true;             // over-relaxation falls back to w = 1 if the residual climbs
    Order order = Order::island;   // the manifolds' order in a sweep
    bool cone = true;              // a start is made feasible (normal >= 0, tangent clamped onto the
                                   // cone, an implausible start dropped); false to judge an answer
                                   // as given (what is infeasible in it counts in the residual)

    bool sanitize() const { return mode != Mode::exact; }  // exact reproduces Box2D, bad starts too
    bool float64() const { return mode == Mode::float64; }
};

// The methods whose work is not only sweeps: float64 only, stopping on the residual.
inline bool is_global(Acceleration a) {
    return a == Acceleration::newton || a == Acceleration::subspace || a == Acceleration::bodyspace ||
           a == Acceleration::lagged;
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
    if (o.mode == Mode::exact && o.order != Order::island)
        throw std::invalid_argument("exact mode is Box2D's PGS: it sweeps in Box2D's island order");
    const bool global = is_global(o.accelerate);
    if (global && o.mode != Mode::float64) throw std::invalid_argument("newton, subspace, bodyspace and lagged are float64 only");
    if (global && !(o.stop_on == Measure::residual || o.stop_on == Measure::none))
        throw std::invalid_argument("newton, subspace, bodyspace and lagged stop on the residual (tolerance 0: exact, 1e-12)");
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
    int factorizations = 0;        // sparse factorizations (newton: one per Newton step tried)
    int newton_fallbacks = 0;      // Newton steps (or outer iterations) that failed, after which sweeps went on
    int newton_iterations = 0;     // bodyspace: Newton iterations on the bodies' momentum balance
    int outer_iterations = 0;      // bodyspace: outer (multiplier and friction bound) iterations
    SanitizeReport sanitized;
};

// What the global methods solve to when given no tolerance.
constexpr double kExactTolerance = 1e-12;

// The tolerance a global method stops at: the one asked, or exact.
inline double global_tolerance(const SolveOptions& o) { return o.tolerance > 0 ? o.tolerance : kExactTolerance; }

// What a global method's history records after a step of its own: the residual alone (a sweep's
// change is a sweep's measure).
inline void record_residual(const SolveOptions& o, SolveReport& rep, double residual) {
    if (o.history) rep.history.insert(rep.history.end(), {std::nan(""), std::nan(""), residual});
}

}  // namespace dc
