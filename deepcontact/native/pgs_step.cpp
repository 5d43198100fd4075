#include "pgs_step.hpp"

#include <cmath>
#include <string>
#include <utility>

namespace dc {
namespace {

// The solution, per point, into the report and (rounded to float32) into the manifold points, for
// the warm start of the island solve to apply. A point Box2D drops from an ill-conditioned pair
// keeps its start, as in solve_contacts.
template <class R>
void write_solution(const ContactProblem<R>& pb, LoopFrame& f, PGSStepReport& out) {
    out.normal_impulse.resize(f.points);
    out.tangent_impulse.resize(f.points);
    bool finite = true;
    for (size_t i = 0; i < pb.manifolds.size(); ++i) {
        const ContactManifold<R>& m = pb.manifolds[i];
        b2ManifoldPoint* points = f.constraints[i].manifold->points;
        for (int j = 0; j < m.given; ++j) {
            const double normal = double(m.p[j].normal_impulse), tangent = double(m.p[j].tangent_impulse);
            out.normal_impulse[m.first + j] = normal;
            out.tangent_impulse[m.first + j] = tangent;
            points[j].normalImpulse = float(normal);
            points[j].tangentImpulse = float(tangent);
            finite = finite && std::isfinite(points[j].normalImpulse) && std::isfinite(points[j].tangentImpulse);
        }
    }
    f.finite_answer = finite;
}

// The step's contacts posed in R with their start (Box2D's carried impulses or zero).
template <class R>
void pose_step(World& world, ContactProblem<R>& pb, const PGSStepSettings& s, PGSStepReport& out) {
    world.pose_loop(pb, s.step, s.start == LoopStart::builtin, s.warm_scale, out.start_normal, out.start_tangent);
}

// The order its sweeps visit the posed manifolds in (SolveOptions::order): gravity's by each
// contact's bodies' centres as the step was posed (the buffer is kept: cleared otherwise).
template <class R>
void set_order(ContactProblem<R>& pb, const LoopFrame& f, const PGSStepSettings& s) {
    if (s.solve.order != Order::gravity) {
        pb.order.clear();
        return;
    }
    gravity_order(pb, s.step.gravity, [&](size_t i) {
        const b2Vec2 a = f.contact_bodies[i].first->GetWorldCenter(), b = f.contact_bodies[i].second->GetWorldCenter();
        return std::pair{V2<float>{a.x, a.y}, V2<float>{b.x, b.y}};
    });
}

// The posed step (where it has contact points) solved from the start given and the solution written.
template <class R>
void solve_step(World& world, ContactProblem<R>& pb, LoopFrame& f, const PGSStepSettings& s, const double* sn,
                const double* st, PGSStepReport& out) {
    if (f.points == 0) return;
    // What a method keeps from one step to the next lives in the world (a method that keeps
    // nothing leaves it empty).
    if (!world.carried_factor) world.carried_factor = new_carried_factor();
    set_order(pb, f, s);
    out.solve = solve(pb, sn, st, s.solve, world.carried_factor.get());
    out.stats = pb.stats;
    write_solution(pb, f, out);
    out.solved = true;
    out.deepest = double(f.deepest);
}

// The posed step solved from the start given, the answer written, then Box2D stepped with it as
// its warm start and no velocity iterations.
void finish_step(World& world, LoopFrame& f, const PGSStepSettings& s, const double* sn, const double* st,
                 PGSStepReport& out) {
    if (s.solve.float64())
        solve_step(world, f.problem64, f, s, sn, st, out);
    else
        solve_step(world, f.problem32, f, s, sn, st, out);
    world.set_inv_dt0(s.inv_dt0);
    world.step(s.step.dt, 0, s.position_iterations, s.record, /*collided=*/true);
}

}  // namespace

size_t pgs_pose(World& world, const PGSStepSettings& s, PGSStepReport& out) {
    world.collide();
    LoopFrame& f = world.gather_loop();
    if (s.solve.float64())
        pose_step(world, f.problem64, s, out);
    else
        pose_step(world, f.problem32, s, out);
    f.posed_float64 = s.solve.float64();
    return f.points;
}

void pgs_finish(World& world, const PGSStepSettings& s, const double* sn, const double* st, size_t points,
                PGSStepReport& out) {
    LoopFrame& f = world.loop_frame();
    if (!world.posed_now())
        throw std::invalid_argument("pgs_finish: the world changed since pgs_pose posed its step (or none was posed)");
    if (f.posed_float64 != s.solve.float64())
        throw std::invalid_argument("pgs_finish: the step was posed in another precision");
    if (points != f.points)
        throw std::invalid_argument("pgs_finish: the start has " + std::to_string(points) +
                                    " impulses a row; the posed step has " + std::to_string(f.points) + " points");
    finish_step(world, f, s, sn, st, out);
}

PGSStepReport pgs_step(World& world, const PGSStepSettings& s) {
    PGSStepReport out;
    pgs_pose(world, s, out);
    finish_step(world, world.loop_frame(), s, out.start_normal.data(), out.start_tangent.data(), out);
    return out;
}

}  // namespace dc
