#include "pgs_step.hpp"

#include <algorithm>

namespace dc {
namespace {

// Box2D's warm start: the impulses Collide carried over by feature id, times dtRatio (rounded in
// float32 first, as Box2D scales them); or zero.
void carried_start(const LoopFrame& f, const PGSStepSettings& s, std::vector<double>& start_n,
                   std::vector<double>& start_t) {
    start_n.assign(f.points, 0.0);
    start_t.assign(f.points, 0.0);
    if (s.start != LoopStart::builtin) return;
    size_t k = 0;
    for (size_t i = 0; i < f.constraints.size(); ++i)
        for (int j = 0; j < f.constraints[i].point_count; ++j, ++k) {
            start_n[k] = double(s.warm_scale * f.inputs[i].normal_impulse[j]);
            start_t[k] = double(s.warm_scale * f.inputs[i].tangent_impulse[j]);
        }
}

// The solution, per point, into the report and (rounded to float32) into the manifold points, for
// the warm start of the island solve to apply. A point Box2D drops from an ill-conditioned pair
// keeps its start, as in solve_contacts.
template <class R>
void write_solution(const ContactProblem<R>& pb, const LoopFrame& f, PGSStepReport& out) {
    out.normal_impulse.resize(f.points);
    out.tangent_impulse.resize(f.points);
    for (size_t i = 0; i < pb.manifolds.size(); ++i) {
        const ContactManifold<R>& m = pb.manifolds[i];
        b2ManifoldPoint* points = f.constraints[i].manifold->points;
        for (int j = 0; j < m.given; ++j) {
            const double normal = double(m.p[j].normal_impulse), tangent = double(m.p[j].tangent_impulse);
            out.normal_impulse[m.first + j] = normal;
            out.tangent_impulse[m.first + j] = tangent;
            points[j].normalImpulse = float(normal);
            points[j].tangentImpulse = float(tangent);
        }
    }
}

template <class R>
void solve_step(World& world, ContactProblem<R>& pb, const LoopFrame& f, const PGSStepSettings& s,
                PGSStepReport& out, LaggedFactor* carried) {
    world.pose_loop_problem(pb, s.step);
    out.solve = solve(pb, out.start_normal.data(), out.start_tangent.data(), s.solve, carried);
    out.stats = pb.stats;
    write_solution(pb, f, out);
}

}  // namespace

PGSStepReport pgs_step(World& world, const PGSStepSettings& s) {
    PGSStepReport out;
    world.collide();
    LoopFrame& f = world.gather_loop();
    if (f.points > 0) {
        carried_start(f, s, out.start_normal, out.start_tangent);
        // What a method keeps from one step to the next lives in the world (a method that keeps
        // nothing leaves it empty).
        if (!world.carried_factor) world.carried_factor = new_carried_factor();
        LaggedFactor* carried = world.carried_factor.get();
        if (s.solve.float64())
            solve_step(world, f.problem64, f, s, out, carried);
        else
            solve_step(world, f.problem32, f, s, out, carried);
        out.solved = true;
        out.deepest = double(f.deepest);
    }
    world.set_inv_dt0(s.inv_dt0);
    world.step(s.step.dt, 0, s.position_iterations, s.record, /*collided=*/true);
    return out;
}

}  // namespace dc
