// Python entry points of the contact solver (deepcontact/solver, simulate/pgs_loop.py): the
// options as bound structs, arrays in, impulses and convergence history out.
#include <pybind11/stl.h>

#include <initializer_list>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "body_rows.hpp"
#include "contact_problem.hpp"
#include "lemke.hpp"
#include "solve.hpp"
#include "sweeps.hpp"
#include "pgs_step.hpp"
#include "pyarrays.hpp"

namespace dc {
namespace {

// The solver's columns of dicts of arrays, checked (records.hpp's solver rows).
#define DC_SOLVER_COLUMN(T, name, width, solver) DC_IF_##solver(c.name = column<T>(d, #name, n, width);)

BodyColumns body_columns(const py::dict& d) {
    BodyColumns c;
    size_t n = static_cast<size_t>(-1);
    DC_BODY_FIELDS(DC_SOLVER_COLUMN)
    c.n = n;
    return c;
}

ContactColumns contact_columns(const py::dict& d) {
    ContactColumns c;
    size_t n = static_cast<size_t>(-1);
    DC_CONTACT_FIELDS(DC_SOLVER_COLUMN)
    c.row_a = column<int32_t>(d, "row_a", n);
    c.row_b = column<int32_t>(d, "row_b", n);
    c.n = n;
    return c;
}

py::tuple names(const char* const* first, const char* const* last) {
    py::list out;
    for (; first != last; ++first) out.append(*first);
    return py::tuple(out);
}

// Enums whose values may also be given by name ("float64"); a bad name is a ValueError listing
// the choices, so the Python layer need not check the strings again.
template <class E>
struct EnumNames {
    static inline std::string type;  // the Python name
    static inline std::vector<std::pair<std::string, E>> values;
};

template <class E>
void bind_enum(py::module_& m, const char* name, std::initializer_list<std::pair<const char*, E>> values,
               const char* doc) {
    py::enum_<E> e(m, name, doc);
    EnumNames<E>::type = name;
    for (const auto& [key, value] : values) {
        e.value(key, value);
        EnumNames<E>::values.emplace_back(key, value);
    }
}

template <class E>
E enum_value(const py::handle& h, const std::string& field) {
    if (py::isinstance<E>(h)) return h.cast<E>();
    if (!py::isinstance<py::str>(h)) throw py::type_error(field + " must be a " + EnumNames<E>::type + " or its name");
    const std::string s = h.cast<std::string>();
    std::string choices;
    for (const auto& [key, value] : EnumNames<E>::values) {
        if (key == s) return value;
        choices += (choices.empty() ? "" : ", ") + key;
    }
    throw py::value_error(field + " must be one of " + choices + ", not '" + s + "'");
}

// An enum field of a bound struct, settable by value or by name.
template <class T, class E>
void enum_field(py::class_<T>& cls, const char* name, E T::*member) {
    cls.def_property(
        name, [member](const T& t) { return t.*member; },
        [member, field = std::string(name)](T& t, const py::object& v) { t.*member = enum_value<E>(v, field); });
}

// A keyword constructor for an options struct: each keyword sets the field of that name (through
// its bound property, so names convert to enums), then the struct is checked once.
template <class T>
std::unique_ptr<T> from_keywords(const char* what, const py::kwargs& kw) {
    auto out = std::make_unique<T>();
    py::object self = py::cast(out.get(), py::return_value_policy::reference);
    for (const auto& [key, value] : kw) {
        const std::string k = py::str(key);
        if (k.rfind("_", 0) == 0 || !py::hasattr(py::type::of(self), k.c_str()))
            throw py::type_error(std::string(what) + " has no field '" + k + "'");
        self.attr(key) = value;
    }
    check(*out);
    return out;
}

py::dict stats_dict(const ProblemStats& s) {
    py::dict d;
#define DC_STAT_ITEM(name) d[#name] = s.name;
    DC_PROBLEM_STATS(DC_STAT_ITEM)
#undef DC_STAT_ITEM
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
    out["factorizations"] = rep.factorizations;
    out["newton_fallbacks"] = rep.newton_fallbacks;
    out["newton_iterations"] = rep.newton_iterations;
    out["outer_iterations"] = rep.outer_iterations;
    py::dict san;
    san["nonfinite"] = rep.sanitized.nonfinite;
    san["negative"] = rep.sanitized.negative;
    san["implausible"] = rep.sanitized.implausible;
    san["cone"] = rep.sanitized.cone;
    out["sanitized"] = san;
    out["stats"] = stats_dict(stats);
    return out;
}

// A new array of n rows of `width` values, stored in out[name]; returns where to write it.
template <class T>
T* new_column(py::dict& out, const char* name, size_t n, size_t width = 1) {
    const auto rows = static_cast<py::ssize_t>(n);
    py::array_t<T> a = width == 1 ? py::array_t<T>(rows) : py::array_t<T>({rows, static_cast<py::ssize_t>(width)});
    out[name] = a;
    return a.mutable_data();
}

template <class R>
void body_velocities(const ContactProblem<R>& pb, py::dict& out) {
    const size_t n = pb.velocity.size();
    R* velocity = new_column<R>(out, "velocity", n, 2);
    R* omega = new_column<R>(out, "omega", n);
    for (size_t i = 0; i < n; ++i) {
        velocity[2 * i] = pb.velocity[i].v.x;
        velocity[2 * i + 1] = pb.velocity[i].v.y;
        omega[i] = pb.velocity[i].w;
    }
}

template <class R>
py::dict solve(const BodyColumns& bc, const ContactColumns& cc, const StepSettings& st, const double* sn,
               const double* stt, const SolveOptions& opt, LaggedFactor* carried) {
    ContactProblem<R> pb;
    SolveReport rep;
    {
        py::gil_scoped_release release;
        pb = assemble<R>(bc, cc, st);
        if (opt.order == Order::gravity)
            gravity_order(pb, st.gravity, [&](size_t i) {
                const auto& m = pb.manifolds[i];
                return std::pair{V2<float>{bc.center[2 * m.a], bc.center[2 * m.a + 1]},
                                 V2<float>{bc.center[2 * m.b], bc.center[2 * m.b + 1]}};
            });
        rep = solve(pb, sn, stt, opt, carried);
    }
    py::dict out = report_dict(rep, pb.stats);
    R* normal = new_column<R>(out, "normal_impulse", cc.n);
    R* tangent = new_column<R>(out, "tangent_impulse", cc.n);
    for (const auto& m : pb.manifolds)
        for (int j = 0; j < m.given; ++j) {
            normal[m.first + j] = m.p[j].normal_impulse;
            tangent[m.first + j] = m.p[j].tangent_impulse;
        }
    body_velocities(pb, out);
    return out;
}

py::dict solve_contacts(const py::dict& bodies, const py::dict& contacts,
                        py::array_t<double, py::array::c_style | py::array::forcecast> start_normal,
                        py::array_t<double, py::array::c_style | py::array::forcecast> start_tangent,
                        const StepSettings& step, const SolveOptions& options, py::object carry) {
    const BodyColumns bc = body_columns(bodies);
    const ContactColumns cc = contact_columns(contacts);
    if (start_normal.ndim() != 1 || start_tangent.ndim() != 1 || static_cast<size_t>(start_normal.size()) != cc.n ||
        static_cast<size_t>(start_tangent.size()) != cc.n)
        throw py::value_error("start impulses must have one value per contact point (" + std::to_string(cc.n) + ")");
    check(step);
    check(bc, cc);
    check(options);
    // carry: the world whose carried state (the lagged method's factor and penalty) this solve
    // uses and leaves for the next, as a step of the native loop does (pgs_step)
    LaggedFactor* carried = nullptr;
    if (!carry.is_none()) {
        World& world = carry.cast<World&>();
        if (!world.carried_factor) world.carried_factor = new_carried_factor();
        carried = world.carried_factor.get();
    }
    if (options.float64())
        return solve<double>(bc, cc, step, start_normal.data(), start_tangent.data(), options, carried);
    return solve<float>(bc, cc, step, start_normal.data(), start_tangent.data(), options, carried);
}

// Per contact point the rows as assembled; per body the velocity before any impulse.
py::dict rows_dict(const ContactProblem<double>& pb, size_t points) {
    py::dict out;
    int32_t* manifold = new_column<int32_t>(out, "manifold", points);
    int32_t* row_a = new_column<int32_t>(out, "row_a", points);
    int32_t* row_b = new_column<int32_t>(out, "row_b", points);
    bool* active = new_column<bool>(out, "active", points);
    bool* friction_row = new_column<bool>(out, "friction_row", points);
    double* normal = new_column<double>(out, "normal", points, 2);
    double* r_a = new_column<double>(out, "r_a", points, 2);
    double* r_b = new_column<double>(out, "r_b", points, 2);
    double* k_normal = new_column<double>(out, "k_normal", points);
    double* k_tangent = new_column<double>(out, "k_tangent", points);
    double* bias = new_column<double>(out, "bias", points);
    double* friction = new_column<double>(out, "friction", points);
    for (size_t mi = 0; mi < pb.manifolds.size(); ++mi) {
        const auto& m = pb.manifolds[mi];
        for (int j = 0; j < m.given; ++j) {
            const auto& p = m.p[j];
            const size_t k = m.first + j;
            manifold[k] = static_cast<int32_t>(mi);
            row_a[k] = m.a;
            row_b[k] = m.b;
            active[k] = j < m.count;
            friction_row[k] = m.friction_row;
            normal[2 * k] = m.normal.x;
            normal[2 * k + 1] = m.normal.y;
            r_a[2 * k] = p.rA.x;
            r_a[2 * k + 1] = p.rA.y;
            r_b[2 * k] = p.rB.x;
            r_b[2 * k + 1] = p.rB.y;
            k_normal[k] = p.k_normal;
            k_tangent[k] = p.k_tangent;
            bias[k] = p.bias;
            friction[k] = m.friction;
        }
    }
    // the rows' Jacobians in body space (body_rows.hpp): per point its normal row, then its tangent row
    double* jacobian = new_column<double>(out, "jacobian", points, 12);
    const std::vector<BodyRow> rows = body_rows(pb);
    for (size_t k = 0; k < rows.size(); ++k) {
        std::copy(rows[k].normal, rows[k].normal + 6, jacobian + 12 * k);
        std::copy(rows[k].tangent, rows[k].tangent + 6, jacobian + 12 * k + 6);
    }
    body_velocities(pb, out);
    return out;
}

py::dict contact_rows(const py::dict& bodies, const py::dict& contacts, const StepSettings& step) {
    const BodyColumns bc = body_columns(bodies);
    const ContactColumns cc = contact_columns(contacts);
    check(step);
    check(bc, cc);
    ContactProblem<double> pb;
    double scale = 1.0;
    {
        py::gil_scoped_release release;
        pb = assemble<double>(bc, cc, step);
        scale = Sweeps<double>(pb).free_velocity_scale();  // no impulse applied yet
    }
    py::dict out = rows_dict(pb, cc.n);
    out["scale"] = scale;
    return out;
}

py::array_t<double> to_array(const std::vector<double>& v) {
    py::array_t<double> a(static_cast<py::ssize_t>(v.size()));
    std::copy(v.begin(), v.end(), a.mutable_data());
    return a;
}

// A step's report as pgs_step returns it: None without contact points.
py::object step_report(const PGSStepReport& rep, const PGSStepSettings& settings) {
    if (!rep.solved) return py::none();
    py::dict out = report_dict(rep.solve, rep.stats);
    out["normal_impulse"] = to_array(rep.normal_impulse);
    out["tangent_impulse"] = to_array(rep.tangent_impulse);
    if (settings.record) {   // (the first iterate is the step file's; an unrecorded step reads none)
        out["start_normal"] = to_array(rep.start_normal);
        out["start_tangent"] = to_array(rep.start_tangent);
    }
    out["deepest"] = rep.deepest;
    return out;
}

py::object step_world(World& world, const PGSStepSettings& settings) {
    check(settings);
    PGSStepReport rep;
    {
        py::gil_scoped_release release;
        rep = pgs_step(world, settings);
    }
    return step_report(rep, settings);
}

size_t pose_world(World& world, const PGSStepSettings& settings) {
    check(settings);
    PGSStepReport rep;
    py::gil_scoped_release release;
    return pgs_pose(world, settings, rep);
}

py::object finish_world(World& world, const PGSStepSettings& settings,
                        py::array_t<double, py::array::c_style | py::array::forcecast> start_normal,
                        py::array_t<double, py::array::c_style | py::array::forcecast> start_tangent) {
    check(settings);
    if (start_normal.ndim() != 1 || start_tangent.ndim() != 1 || start_normal.size() != start_tangent.size())
        throw py::value_error("start_normal and start_tangent must each have one impulse a contact point");
    PGSStepReport rep;
    {
        py::gil_scoped_release release;
        pgs_finish(world, settings, start_normal.data(), start_tangent.data(),
                   static_cast<size_t>(start_normal.size()), rep);
    }
    return step_report(rep, settings);
}

void bind_options(py::module_& m) {
    bind_enum<Mode>(m, "Mode", {{"exact", Mode::exact}, {"float32", Mode::float32}, {"float64", Mode::float64}},
                    "Arithmetic of a solve: exact is Box2D's float32 PGS bit for bit, starts used as given;\n"
                    "float32 the same with bad starts sanitised; float64 double precision.");
    bind_enum<Measure>(
        m, "Measure",
        {{"none", Measure::none}, {"thesis", Measure::thesis}, {"velocity", Measure::velocity},
         {"residual", Measure::residual}},
        "What a sweep measures to stop on (docs/solver.md, \"Measuring convergence\").");
    bind_enum<Acceleration>(
        m, "Acceleration",
        {{"none", Acceleration::none}, {"nncg", Acceleration::nncg}, {"newton", Acceleration::newton},
         {"subspace", Acceleration::subspace}, {"bodyspace", Acceleration::bodyspace},
         {"lagged", Acceleration::lagged}},
        "none: plain (P)SOR sweeps; nncg: nonsmooth nonlinear conjugate gradient; newton: sweeps,\n"
        "then semismooth Newton steps on the whole step (float64, stops on the residual); subspace:\n"
        "the same with each system solved inexactly by conjugate gradients; bodyspace: sweeps, then\n"
        "augmented-Lagrangian iterations on the bodies' velocities (float64, stops on the residual);\n"
        "lagged: the same, each Newton system preconditioned by a factor kept from an earlier one (in\n"
        "the native loop, from an earlier step).");
    bind_enum<Order>(m, "Order", {{"island", Order::island}, {"gravity", Order::gravity}},
                     "The order a sweep visits the manifolds in: island (Box2D's, as posed) or gravity (from\n"
                     "the highest to the lowest along gravity; a scene without gravity keeps island order).");
    m.def("is_global", &is_global, py::arg("accelerate"),
          "Whether a method's work is more than sweeps (a global step over the whole problem): such a\n"
          "method is float64 only and stops on the residual (the traits the Python layer reads).");
    bind_enum<LoopStart>(m, "LoopStart", {{"zero", LoopStart::zero}, {"builtin", LoopStart::builtin}},
                         "Where a step of the native loop starts PGS: zero or Box2D's carried impulses.");

    py::class_<StepSettings>(m, "StepSettings", "The step a contact problem belongs to (checked on construction).")
        .def(py::init([](const py::kwargs& kw) { return from_keywords<StepSettings>("StepSettings", kw); }))
        .def_readwrite("dt", &StepSettings::dt, "time step (s)")
        .def_property(
            "gravity", [](const StepSettings& s) { return std::make_pair(s.gravity[0], s.gravity[1]); },
            [](StepSettings& s, std::pair<float, float> g) {
                s.gravity[0] = g.first;
                s.gravity[1] = g.second;
            },
            "(x, y) in m/s^2")
        .def_readwrite("block_solve", &StepSettings::block_solve, "Box2D's 2x2 block solver for two-point manifolds")
        .def_readwrite("prune", &StepSettings::prune, "leave out rows the scene does not need");

    py::class_<SolveOptions> options(m, "SolveOptions", "How PGS solves (checked on construction and on use).");
    enum_field(options, "mode", &SolveOptions::mode);
    enum_field(options, "stop_on", &SolveOptions::stop_on);
    enum_field(options, "accelerate", &SolveOptions::accelerate);
    enum_field(options, "order", &SolveOptions::order);
    options.def(py::init([](const py::kwargs& kw) { return from_keywords<SolveOptions>("SolveOptions", kw); }))
        .def_readwrite("max_iterations", &SolveOptions::max_iterations)
        .def_readwrite("tolerance", &SolveOptions::tolerance, "stop once stop_on falls below it (0: never)")
        .def_readwrite("relaxation", &SolveOptions::relaxation, "w of PSOR in (0, 2); 1 is plain PGS")
        .def_readwrite("history", &SolveOptions::history, "record thesis, velocity, residual after every sweep")
        .def_readwrite("max_velocity", &SolveOptions::max_velocity,
                       "a start whose impulses together change some contact velocity by more is implausible (0: no check)")
        .def_readwrite("final_residual", &SolveOptions::final_residual, "report the residual at the end")
        .def_readwrite("guard", &SolveOptions::guard, "fall back to w = 1 if the residual climbs tenfold")
        .def_readwrite("cone", &SolveOptions::cone, "clamp a start's tangents onto the friction cone (false: judge as given)");

    py::class_<PGSStepSettings> loop(m, "PGSStepSettings", "One step of the native loop (checked on construction and use).");
    enum_field(loop, "start", &PGSStepSettings::start);
    loop.def(py::init([](const py::kwargs& kw) { return from_keywords<PGSStepSettings>("PGSStepSettings", kw); }))
        .def_readwrite("step", &PGSStepSettings::step)
        .def_readwrite("solve", &PGSStepSettings::solve)
        .def_readwrite("warm_scale", &PGSStepSettings::warm_scale, "dtRatio applied to the carried impulses")
        .def_readwrite("inv_dt0", &PGSStepSettings::inv_dt0, "1/dt Box2D scales the written impulses by")
        .def_readwrite("position_iterations", &PGSStepSettings::position_iterations)
        .def_readwrite("record", &PGSStepSettings::record, "keep the step for World.recorded()");
}

// Lemke on (M, q): (z, pivots), z None where it ends on a ray or runs out of pivots.
py::tuple lemke_lcp(py::array_t<double, py::array::c_style | py::array::forcecast> M,
                    py::array_t<double, py::array::c_style | py::array::forcecast> q, int max_pivots) {
    if (q.ndim() != 1) throw py::value_error("q must be one-dimensional");
    const py::ssize_t n = q.shape(0);
    if (M.ndim() != 2 || M.shape(0) != n || M.shape(1) != n)
        throw py::value_error("M must be " + std::to_string(n) + " x " + std::to_string(n) + ", like q");
    if (max_pivots < 0) throw py::value_error("max_pivots must be at least 0");
    LemkeResult r;
    {
        py::gil_scoped_release release;
        r = lemke(M.data(), q.data(), static_cast<int>(n), max_pivots);
    }
    py::object z = py::none();
    if (r.solved) z = py::array_t<double>(n, r.z.data());
    return py::make_tuple(z, r.pivots);
}

}  // namespace

void bind_solver(py::module_& m) {
    bind_options(m);
    m.attr("SOLVER_BODY_FIELDS") = names(std::begin(kSolverBodyFields), std::end(kSolverBodyFields));
    m.attr("SOLVER_CONTACT_FIELDS") = names(std::begin(kSolverContactFields), std::end(kSolverContactFields));
    m.def("solve_contacts", &solve_contacts, py::arg("bodies"), py::arg("contacts"), py::arg("start_normal"),
          py::arg("start_tangent"), py::arg("step"), py::arg("options"), py::arg("carry") = py::none(),
          "Assemble one step's contact problem and solve it with projected Gauss-Seidel; carry: a World\n"
          "whose carried state (the lagged method's factor and penalty) the solve uses and updates, as a\n"
          "step of the native loop does.");
    m.def("contact_rows", &contact_rows, py::arg("bodies"), py::arg("contacts"), py::arg("step"),
          "The rows of one step's contact problem as the solver assembles them (float64): per contact\n"
          "point the lever arms, normal, effective inverse masses, bias and its two rows' Jacobians in body\n"
          "space (jacobian: normal then tangent, on a's vx, vy, w then b's); per body the velocity before\n"
          "any impulse; and the free-velocity scale the residual is divided by.");
    m.def("lemke", &lemke_lcp, py::arg("M"), py::arg("q"), py::arg("max_pivots"),
          "Lemke's complementary pivoting on w = M z + q (dense M, float64): (z, pivots), z None on a\n"
          "ray or when max_pivots run out (native/lemke.hpp; solver/pivoting.py has the tableau form).");
    m.def("pgs_step", &step_world, py::arg("world"), py::arg("settings"),
          "One step with our PGS in place of Box2D's velocity solver (collide, solve, write, Step with 0\n"
          "velocity iterations), whole in native code. Returns the solve's report (with the first iterate,\n"
          "start_normal and start_tangent, where settings.record), or None without contacts.");
    m.def("pgs_pose", &pose_world, py::arg("world"), py::arg("settings"),
          "The first half of pgs_step, for a start made in between: collide and pose the step; returns its\n"
          "contact points (in the order World.contacts() reads them). pgs_finish takes the start.");
    m.def("pgs_finish", &finish_world, py::arg("world"), py::arg("settings"), py::arg("start_normal"),
          py::arg("start_tangent"),
          "The second half: the step pgs_pose posed solved from this start (float64, one impulse a\n"
          "point), the answer written and Box2D stepped, as pgs_step from the same start; its report, or\n"
          "None without contacts. ValueError where the world changed since the pose.");
}

}  // namespace dc
