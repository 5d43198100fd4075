// Python entry point of the contact solver: arrays in, impulses and convergence history out.
#include <pybind11/stl.h>

#include <string>

#include "contact_problem.hpp"
#include "pgs.hpp"
#include "pgs_step.hpp"
#include "pyarrays.hpp"

namespace dc {
namespace {

BodyColumns body_columns(const py::dict& d) {
    BodyColumns c;
    size_t n = static_cast<size_t>(-1);
    c.center = column<float>(d, "center", n, 2);
    c.angle = column<float>(d, "angle", n);
    c.local_center = column<float>(d, "local_center", n, 2);
    c.velocity = column<float>(d, "velocity", n, 2);
    c.omega = column<float>(d, "omega", n);
    c.mass = column<float>(d, "mass", n);
    c.inv_mass = column<float>(d, "inv_mass", n);
    c.inv_inertia = column<float>(d, "inv_inertia", n);
    c.gravity_scale = column<float>(d, "gravity_scale", n);
    c.linear_damping = column<float>(d, "linear_damping", n);
    c.angular_damping = column<float>(d, "angular_damping", n);
    c.type = column<int8_t>(d, "type", n);
    c.n = n;
    return c;
}

ContactColumns contact_columns(const py::dict& d) {
    ContactColumns c;
    size_t n = static_cast<size_t>(-1);
    c.manifold = column<int32_t>(d, "manifold", n);
    c.row_a = column<int32_t>(d, "row_a", n);
    c.row_b = column<int32_t>(d, "row_b", n);
    c.point = column<int8_t>(d, "point", n);
    c.point_count = column<int8_t>(d, "point_count", n);
    c.manifold_type = column<int8_t>(d, "manifold_type", n);
    c.local_normal = column<float>(d, "local_normal", n, 2);
    c.local_point = column<float>(d, "local_point", n, 2);
    c.point_local = column<float>(d, "point_local", n, 2);
    c.radius_a = column<float>(d, "radius_a", n);
    c.radius_b = column<float>(d, "radius_b", n);
    c.friction = column<float>(d, "friction", n);
    c.restitution = column<float>(d, "restitution", n);
    c.restitution_threshold = column<float>(d, "restitution_threshold", n);
    c.n = n;
    return c;
}

Measure parse_measure(const std::string& s) {
    if (s == "none") return Measure::none;
    if (s == "thesis") return Measure::thesis;
    if (s == "velocity") return Measure::velocity;
    if (s == "residual") return Measure::residual;
    throw py::value_error("measure must be one of none, thesis, velocity, residual; got '" + s + "'");
}

py::dict stats_dict(const ProblemStats& s) {
    py::dict d;
    d["manifolds"] = s.manifolds;
    d["points"] = s.points;
    d["normal_rows"] = s.normal_rows;
    d["tangent_rows"] = s.tangent_rows;
    d["block_manifolds"] = s.block_manifolds;
    d["dropped_points"] = s.dropped_points;
    d["angular_manifolds"] = s.angular_manifolds;
    d["bias_rows"] = s.bias_rows;
    return d;
}

// What a solve reports besides the impulses: how it converged, what was sanitised, the problem's size.
py::dict report_dict(const SolveReport& rep, const ProblemStats& stats) {
    const py::ssize_t k = static_cast<py::ssize_t>(rep.history.size() / 3);
    py::array_t<double> history({k, py::ssize_t(3)});
    std::copy(rep.history.begin(), rep.history.end(), history.mutable_data());
    py::dict out;
    out["iterations"] = rep.iterations;
    out["history"] = history;
    out["residual"] = rep.residual;
    out["thesis"] = rep.thesis;
    out["velocity_change"] = rep.velocity;
    out["relaxation_fallback"] = rep.relaxation_fallback;
    py::dict san;
    san["nonfinite"] = rep.sanitized.nonfinite;
    san["negative"] = rep.sanitized.negative;
    san["implausible"] = rep.sanitized.implausible;
    san["cone"] = rep.sanitized.cone;
    out["sanitized"] = san;
    out["stats"] = stats_dict(stats);
    return out;
}

template <class R>
py::dict run(const BodyColumns& bc, const ContactColumns& cc, const StepSettings& st, const double* sn,
             const double* stt, const SolveOptions& opt) {
    ContactProblem<R> pb;
    SolveReport rep;
    {
        py::gil_scoped_release release;
        pb = assemble<R>(bc, cc, st);
        PGS<R> pgs(pb);
        rep = pgs.solve(sn, stt, opt);
    }
    const size_t n = cc.n;
    py::array_t<R> normal(static_cast<py::ssize_t>(n)), tangent(static_cast<py::ssize_t>(n));
    auto nm = normal.template mutable_unchecked<1>();
    auto tm = tangent.template mutable_unchecked<1>();
    for (const auto& m : pb.manifolds)
        for (int j = 0; j < m.given; ++j) {
            nm(m.first + j) = m.p[j].normal_impulse;
            tm(m.first + j) = m.p[j].tangent_impulse;
        }
    py::array_t<R> velocity({static_cast<py::ssize_t>(bc.n), py::ssize_t(2)}), omega(static_cast<py::ssize_t>(bc.n));
    auto vm = velocity.template mutable_unchecked<2>();
    auto wm = omega.template mutable_unchecked<1>();
    for (size_t i = 0; i < bc.n; ++i) {
        vm(i, 0) = pb.velocity[i].v.x;
        vm(i, 1) = pb.velocity[i].v.y;
        wm(i) = pb.velocity[i].w;
    }
    py::dict out = report_dict(rep, pb.stats);
    out["normal_impulse"] = normal;
    out["tangent_impulse"] = tangent;
    out["velocity"] = velocity;
    out["omega"] = omega;
    return out;
}

py::array_t<double> to_array(const std::vector<double>& v) {
    py::array_t<double> a(static_cast<py::ssize_t>(v.size()));
    std::copy(v.begin(), v.end(), a.mutable_data());
    return a;
}

SolveOptions solve_options(int max_iterations, double tolerance, const std::string& stop_on, double relaxation,
                           bool history, bool sanitize, double max_velocity, bool final_residual, bool guard,
                           bool conjugate) {
    if (max_iterations < 0) throw py::value_error("max_iterations must be >= 0");
    if (!(relaxation > 0.0 && relaxation < 2.0)) throw py::value_error("relaxation must be in (0, 2)");
    SolveOptions opt;
    opt.max_iterations = max_iterations;
    opt.tolerance = tolerance;
    opt.stop_on = parse_measure(stop_on);
    opt.relaxation = relaxation;
    opt.history = history;
    opt.sanitize = sanitize;
    opt.max_velocity = max_velocity;
    opt.final_residual = final_residual;
    opt.guard = guard;
    opt.conjugate = conjugate;
    return opt;
}

StepSettings step_settings(float dt, std::pair<float, float> gravity, bool block_solve, bool prune) {
    if (!(dt > 0.0f)) throw py::value_error("dt must be positive");
    StepSettings st;
    st.dt = dt;
    st.gravity[0] = gravity.first;
    st.gravity[1] = gravity.second;
    st.block_solve = block_solve;
    st.prune = prune;
    return st;
}

}  // namespace

void bind_solver(py::module_& m) {
    m.def(
        "solve_contacts",
        [](const py::dict& bodies, const py::dict& contacts,
           py::array_t<double, py::array::c_style | py::array::forcecast> start_normal,
           py::array_t<double, py::array::c_style | py::array::forcecast> start_tangent, float dt,
           std::pair<float, float> gravity, bool block_solve, bool prune, const std::string& precision,
           int max_iterations, double tolerance, const std::string& stop_on, double relaxation, bool history,
           bool sanitize, double max_velocity, bool final_residual, bool guard, bool conjugate) {
            BodyColumns bc = body_columns(bodies);
            ContactColumns cc = contact_columns(contacts);
            if (static_cast<size_t>(start_normal.size()) != cc.n || static_cast<size_t>(start_tangent.size()) != cc.n ||
                start_normal.ndim() != 1 || start_tangent.ndim() != 1)
                throw py::value_error("start impulses must have one value per contact point (" +
                                      std::to_string(cc.n) + ")");
            const StepSettings st = step_settings(dt, gravity, block_solve, prune);
            const SolveOptions opt = solve_options(max_iterations, tolerance, stop_on, relaxation, history, sanitize,
                                                   max_velocity, final_residual, guard, conjugate);
            if (precision == "float32") return run<float>(bc, cc, st, start_normal.data(), start_tangent.data(), opt);
            if (precision == "float64") return run<double>(bc, cc, st, start_normal.data(), start_tangent.data(), opt);
            throw py::value_error("precision must be float32 or float64");
        },
        py::arg("bodies"), py::arg("contacts"), py::arg("start_normal"), py::arg("start_tangent"), py::kw_only(),
        py::arg("dt"), py::arg("gravity"), py::arg("block_solve") = true, py::arg("prune") = true,
        py::arg("precision") = "float32", py::arg("max_iterations") = 8, py::arg("tolerance") = 0.0,
        py::arg("stop_on") = "none", py::arg("relaxation") = 1.0, py::arg("history") = false,
        py::arg("sanitize") = true, py::arg("max_velocity") = 0.0, py::arg("final_residual") = true,
        py::arg("guard") = true, py::arg("conjugate") = false,
        "Assemble one step's contact problem and solve it with projected Gauss-Seidel.");

    m.def(
        "contact_rows",
        [](const py::dict& bodies, const py::dict& contacts, float dt, std::pair<float, float> gravity,
           bool block_solve, bool prune) {
            const BodyColumns bc = body_columns(bodies);
            const ContactColumns cc = contact_columns(contacts);
            const StepSettings st = step_settings(dt, gravity, block_solve, prune);
            ContactProblem<double> pb;
            double scale = 1.0;
            {
                py::gil_scoped_release release;
                pb = assemble<double>(bc, cc, st);
                scale = PGS<double>(pb).free_velocity_scale();  // no impulse applied yet
            }
            const auto n = static_cast<py::ssize_t>(cc.n);
            py::array_t<int32_t> manifold(n), row_a(n), row_b(n);
            py::array_t<bool> active(n), friction_row(n);
            py::array_t<double> normal({n, py::ssize_t(2)}), r_a({n, py::ssize_t(2)}), r_b({n, py::ssize_t(2)});
            py::array_t<double> k_normal(n), k_tangent(n), bias(n), friction(n);
            auto M = manifold.mutable_unchecked<1>();
            auto A = row_a.mutable_unchecked<1>();
            auto B = row_b.mutable_unchecked<1>();
            auto act = active.mutable_unchecked<1>();
            auto fr = friction_row.mutable_unchecked<1>();
            auto N = normal.mutable_unchecked<2>();
            auto RA = r_a.mutable_unchecked<2>();
            auto RB = r_b.mutable_unchecked<2>();
            auto KN = k_normal.mutable_unchecked<1>();
            auto KT = k_tangent.mutable_unchecked<1>();
            auto BI = bias.mutable_unchecked<1>();
            auto FR = friction.mutable_unchecked<1>();
            for (size_t mi = 0; mi < pb.manifolds.size(); ++mi) {
                const auto& m = pb.manifolds[mi];
                for (int j = 0; j < m.given; ++j) {
                    const auto& p = m.p[j];
                    const py::ssize_t k = m.first + j;
                    M(k) = static_cast<int32_t>(mi);
                    A(k) = m.a;
                    B(k) = m.b;
                    act(k) = j < m.count;
                    fr(k) = m.friction_row;
                    N(k, 0) = m.normal.x;
                    N(k, 1) = m.normal.y;
                    RA(k, 0) = p.rA.x;
                    RA(k, 1) = p.rA.y;
                    RB(k, 0) = p.rB.x;
                    RB(k, 1) = p.rB.y;
                    KN(k) = p.k_normal;
                    KT(k) = p.k_tangent;
                    BI(k) = p.bias;
                    FR(k) = m.friction;
                }
            }
            const auto nb = static_cast<py::ssize_t>(bc.n);
            py::array_t<double> velocity({nb, py::ssize_t(2)}), omega(nb);
            auto V = velocity.mutable_unchecked<2>();
            auto W = omega.mutable_unchecked<1>();
            for (size_t i = 0; i < bc.n; ++i) {
                V(i, 0) = pb.velocity[i].v.x;
                V(i, 1) = pb.velocity[i].v.y;
                W(i) = pb.velocity[i].w;
            }
            py::dict out;
            out["manifold"] = manifold;
            out["row_a"] = row_a;
            out["row_b"] = row_b;
            out["active"] = active;
            out["friction_row"] = friction_row;
            out["normal"] = normal;
            out["r_a"] = r_a;
            out["r_b"] = r_b;
            out["k_normal"] = k_normal;
            out["k_tangent"] = k_tangent;
            out["bias"] = bias;
            out["friction"] = friction;
            out["velocity"] = velocity;
            out["omega"] = omega;
            out["scale"] = scale;
            return out;
        },
        py::arg("bodies"), py::arg("contacts"), py::kw_only(), py::arg("dt"), py::arg("gravity"),
        py::arg("block_solve") = true, py::arg("prune") = true,
        "The rows of one step's contact problem as the solver assembles them (float64): per contact\n"
        "point the lever arms, normal, effective inverse masses, bias; per body the velocity before\n"
        "any impulse; and the free-velocity scale the residual is divided by.");

    m.def(
        "pgs_step",
        [](World& world, float dt, std::pair<float, float> gravity, bool block_solve, bool prune,
           const std::string& precision, int max_iterations, double tolerance, const std::string& stop_on,
           double relaxation, bool conjugate, bool sanitize, double max_velocity, bool guard, const std::string& start,
           float warm_scale, float inv_dt0, int position_iterations, bool record) {
            PGSStepSettings s;
            s.step = step_settings(dt, gravity, block_solve, prune);
            s.solve = solve_options(max_iterations, tolerance, stop_on, relaxation, false, sanitize, max_velocity,
                                    true, guard, conjugate);
            if (precision != "float32" && precision != "float64")
                throw py::value_error("precision must be float32 or float64");
            s.float64 = precision == "float64";
            if (start != "zero" && start != "builtin") throw py::value_error("start must be zero or builtin");
            s.start = start == "zero" ? LoopStart::zero : LoopStart::builtin;
            if (position_iterations < 0) throw py::value_error("position_iterations must be >= 0");
            s.warm_scale = warm_scale;
            s.inv_dt0 = inv_dt0;
            s.position_iterations = position_iterations;
            s.record = record;
            PGSStepReport rep;
            {
                py::gil_scoped_release release;
                rep = pgs_step(world, s);
            }
            if (!rep.solved) return py::object(py::none());
            py::dict out = report_dict(rep.solve, rep.stats);
            out["normal_impulse"] = to_array(rep.normal_impulse);
            out["tangent_impulse"] = to_array(rep.tangent_impulse);
            out["start_normal"] = to_array(rep.start_normal);
            out["start_tangent"] = to_array(rep.start_tangent);
            out["deepest"] = rep.deepest;
            return py::object(out);
        },
        py::arg("world"), py::kw_only(), py::arg("dt"), py::arg("gravity"), py::arg("block_solve") = true,
        py::arg("prune") = true, py::arg("precision") = "float64", py::arg("max_iterations") = 8,
        py::arg("tolerance") = 0.0, py::arg("stop_on") = "none", py::arg("relaxation") = 1.0,
        py::arg("conjugate") = false, py::arg("sanitize") = true, py::arg("max_velocity") = 0.0, py::arg("guard") = true,
        py::arg("start") = "builtin", py::arg("warm_scale") = 1.0f, py::arg("inv_dt0") = 0.0f,
        py::arg("position_iterations") = 3, py::arg("record") = false,
        "One step with our PGS in place of Box2D's velocity solver (collide, solve, write, Step with 0\n"
        "velocity iterations), whole in native code. Returns the solve's report, or None without contacts.");
}

}  // namespace dc
