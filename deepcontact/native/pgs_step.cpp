#include "pgs_step.hpp"

namespace dc {
namespace {

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

// The step's contacts posed in R, then (where there are any) solved and the solution written.
template <class R>
void solve_step(World& world, ContactProblem<R>& pb, const LoopFrame& f, const PGSStepSettings& s,
                PGSStepReport& out) {
    world.pose_loop(pb, s.step, s.start == LoopStart::builtin, s.warm_scale, out.start_normal, out.start_tangent);
    if (f.points == 0) return;
    // What a method keeps from one step to the next lives in the world (a method that keeps
    // nothing leaves it empty).
    if (!world.carried_factor) world.carried_factor = new_carried_factor();
    out.solve = solve(pb, out.start_normal.data(), out.start_tangent.data(), s.solve, world.carried_factor.get());
    out.stats = pb.stats;
    write_solution(pb, f, out);
    out.solved = true;
    out.deepest = double(f.deepest);
}

}  // namespace

PGSStepReport pgs_step(World& world, const PGSStepSettings& s) {
    PGSStepReport out;
    world.collide();
    LoopFrame& f = world.gather_loop();
    if (s.solve.float64())
        solve_step(world, f.problem64, f, s, out);
    else
        solve_step(world, f.problem32, f, s, out);
    world.set_inv_dt0(s.inv_dt0);
    world.step(s.step.dt, 0, s.position_iterations, s.record, /*collided=*/true);
    return out;
}

}  // namespace dc
