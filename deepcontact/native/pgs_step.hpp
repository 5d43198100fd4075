// One step with the project's PGS in place of Box2D's velocity solver, whole in native code
// (docs/solver.md, "The loop"): Collide, gather the contacts in island order, assemble, solve from Box2D's warm
// start or from zero, write the impulses into the manifold points, then Box2D's Step with no
// velocity iterations. The Python loop (simulate/pgs_loop.py) does the same in pieces, for
// starts made in Python; this saves the per-step round trip of every array through numpy.
#pragma once

#include <cmath>
#include <stdexcept>
#include <vector>

#include "contact_problem.hpp"
#include "solve.hpp"
#include "world.hpp"

namespace dc {

// Where a step of the loop starts PGS: from zero, or from the impulses Box2D carried over.
enum class LoopStart { zero, builtin };

struct PGSStepSettings {
    StepSettings step;             // dt, gravity, block solver, prune
    SolveOptions solve;            // precision (mode), stopping, relaxation, acceleration
    LoopStart start = LoopStart::builtin;
    float warm_scale = 1.0f;       // dtRatio applied to the carried impulses (0 on the first step)
    float inv_dt0 = 0.0f;          // set before Step so that dt * inv_dt0 == 1: our impulses stand as written
    int position_iterations = 3;
    bool record = false;           // keep the step for World::recorded_bodies() / recorded_contacts()
};

// Throws std::invalid_argument (ValueError in Python) naming what is wrong.
inline void check(const PGSStepSettings& s) {
    check(s.step);
    check(s.solve);
    if (s.position_iterations < 0) throw std::invalid_argument("position_iterations must be >= 0");
    if (!std::isfinite(s.warm_scale) || !std::isfinite(s.inv_dt0))
        throw std::invalid_argument("warm_scale and inv_dt0 must be finite");
}

struct PGSStepReport {
    bool solved = false;           // false when the step had no contact points
    SolveReport solve;
    ProblemStats stats;
    std::vector<double> start_normal, start_tangent;      // the first iterate, per contact point
    std::vector<double> normal_impulse, tangent_impulse;  // the solution, per contact point
    double deepest = 0.0;          // deepest penetration among the step's contact points (m), >= 0
};

PGSStepReport pgs_step(World& world, const PGSStepSettings& settings);

// The same step in two halves, for a start made between them (the closed loop's, in Python):
// pgs_pose collides and poses the step (its builtin or zero start into report.start_normal and
// start_tangent) and returns its contact points, in the order World::contacts() reads them;
// pgs_finish solves that posed step from the start given (one impulse a point, each), writes the
// answer and steps Box2D. The two give the bits pgs_step gives from the same start. pgs_finish
// throws std::invalid_argument where the world changed since pgs_pose (or it posed nothing), or
// the start or the precision is not the pose's.
size_t pgs_pose(World& world, const PGSStepSettings& settings, PGSStepReport& report);
void pgs_finish(World& world, const PGSStepSettings& settings, const double* start_normal,
                const double* start_tangent, size_t points, PGSStepReport& report);

}  // namespace dc
