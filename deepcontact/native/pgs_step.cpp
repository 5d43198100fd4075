#include "pgs_step.hpp"

#include <algorithm>

namespace dc {
namespace {

template <class R>
void solve_step(ContactProblem<R>& pb, const BodyColumns& bc, const ContactColumns& cc, const PGSStepSettings& s,
                const std::vector<double>& start_n, const std::vector<double>& start_t, PGSStepReport& out,
                LaggedFactor* carried) {
    assemble_into(pb, bc, cc, s.step);
    out.solve = solve(pb, start_n.data(), start_t.data(), s.solve, carried);
    out.stats = pb.stats;
    // A point Box2D drops from an ill-conditioned pair keeps its start, as in solve_contacts.
    out.normal_impulse = start_n;
    out.tangent_impulse = start_t;
    for (const auto& m : pb.manifolds)
        for (int j = 0; j < m.given; ++j) {
            out.normal_impulse[m.first + j] = double(m.p[j].normal_impulse);
            out.tangent_impulse[m.first + j] = double(m.p[j].tangent_impulse);
        }
}

}  // namespace

PGSStepReport pgs_step(World& world, const PGSStepSettings& s) {
    PGSStepReport out;
    world.collide();
    LoopFrame& f = world.gather_loop();
    const size_t n = f.points;
    if (n > 0) {
        const BodyColumns bc = f.body_columns();
        const ContactColumns cc = f.contact_columns();
        // Box2D's warm start: the impulses Collide carried over by feature id, times dtRatio
        // (rounded in float32 first, as Box2D scales them).
        std::vector<double> start_n(n, 0.0), start_t(n, 0.0);
        if (s.start == LoopStart::builtin)
            for (size_t k = 0; k < n; ++k) {
                start_n[k] = double(s.warm_scale * f.contacts.normal_impulse[k]);
                start_t[k] = double(s.warm_scale * f.contacts.tangent_impulse[k]);
            }
        // What a method keeps from one step to the next lives in the world (a method that keeps
        // nothing leaves it empty).
        if (!world.carried_factor) world.carried_factor = new_carried_factor();
        LaggedFactor* carried = world.carried_factor.get();
        if (s.solve.float64())
            solve_step(f.problem64, bc, cc, s, start_n, start_t, out, carried);
        else
            solve_step(f.problem32, bc, cc, s, start_n, start_t, out, carried);
        out.start_normal = std::move(start_n);
        out.start_tangent = std::move(start_t);
        out.solved = true;

        std::vector<float> normal(n), tangent(n);
        for (size_t k = 0; k < n; ++k) {
            normal[k] = float(out.normal_impulse[k]);
            tangent[k] = float(out.tangent_impulse[k]);
        }
        world.set_manifold_impulses(normal.data(), tangent.data(), n);
        out.deepest = double(f.deepest);
    }
    world.set_inv_dt0(s.inv_dt0);
    world.step(s.step.dt, 0, s.position_iterations, s.record, /*collided=*/true);
    return out;
}

}  // namespace dc
