#include "pgs_step.hpp"

#include <algorithm>

namespace dc {
namespace {

// The solver's columns of a world's records (records.hpp), borrowed.
#define DC_SOLVER_TAKE(T, name, width, solver) DC_IF_##solver(c.name = s.name.data();)

BodyColumns columns(const BodyState& s) {
    BodyColumns c;
    c.n = s.size();
    DC_BODY_FIELDS(DC_SOLVER_TAKE)
    return c;
}

ContactColumns columns(const ContactState& s, const int32_t* row_a, const int32_t* row_b) {
    ContactColumns c;
    c.n = s.size();
    DC_CONTACT_FIELDS(DC_SOLVER_TAKE)
    c.row_a = row_a;
    c.row_b = row_b;
    return c;
}

template <class R>
void solve_step(const BodyColumns& bc, const ContactColumns& cc, const PGSStepSettings& s,
                const std::vector<double>& start_n, const std::vector<double>& start_t, PGSStepReport& out,
                LaggedFactor* carried) {
    ContactProblem<R> pb = assemble<R>(bc, cc, s.step);
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
    const BodyState bodies = world.bodies();  // before Collide, as the Python loop takes them
    world.collide();
    const ContactState contacts = world.contacts();
    const size_t n = contacts.size();
    if (n > 0) {
        // Contacts name bodies by scene index; the solver wants their rows.
        const int32_t last = bodies.size() ? *std::max_element(bodies.index.begin(), bodies.index.end()) : -1;
        std::vector<int32_t> row_of(static_cast<size_t>(last + 1), -1);
        for (size_t i = 0; i < bodies.size(); ++i) row_of[bodies.index[i]] = static_cast<int32_t>(i);
        std::vector<int32_t> row_a(n), row_b(n);
        for (size_t k = 0; k < n; ++k) {
            row_a[k] = row_of[contacts.body_a[k]];
            row_b[k] = row_of[contacts.body_b[k]];
        }
        const BodyColumns bc = columns(bodies);
        const ContactColumns cc = columns(contacts, row_a.data(), row_b.data());

        // Box2D's warm start: the impulses Collide carried over by feature id, times dtRatio
        // (rounded in float32 first, as Box2D scales them).
        std::vector<double> start_n(n, 0.0), start_t(n, 0.0);
        if (s.start == LoopStart::builtin)
            for (size_t k = 0; k < n; ++k) {
                start_n[k] = double(s.warm_scale * contacts.normal_impulse[k]);
                start_t[k] = double(s.warm_scale * contacts.tangent_impulse[k]);
            }
        // What a method keeps from one step to the next lives in the world (a method that keeps
        // nothing leaves it empty).
        if (!world.carried_factor) world.carried_factor = new_carried_factor();
        LaggedFactor* carried = world.carried_factor.get();
        if (s.solve.float64())
            solve_step<double>(bc, cc, s, start_n, start_t, out, carried);
        else
            solve_step<float>(bc, cc, s, start_n, start_t, out, carried);
        out.start_normal = std::move(start_n);
        out.start_tangent = std::move(start_t);
        out.solved = true;

        std::vector<float> normal(n), tangent(n);
        for (size_t k = 0; k < n; ++k) {
            normal[k] = float(out.normal_impulse[k]);
            tangent[k] = float(out.tangent_impulse[k]);
        }
        world.set_manifold_impulses(normal.data(), tangent.data(), n);
        for (float d : contacts.separation) out.deepest = std::max(out.deepest, -double(d));
    }
    world.set_inv_dt0(s.inv_dt0);
    world.step(s.step.dt, 0, s.position_iterations, s.record, /*collided=*/true);
    return out;
}

}  // namespace dc
