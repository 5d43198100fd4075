// deepcontact._box2d: the thin native layer. Checks array shapes and dtypes, releases the
// GIL for the work, and moves whole steps as numpy arrays (one call each way).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "interrupt.hpp"
#include "step_names.hpp"
#ifdef DC_HAVE_BOX2D3
#include "world3.hpp"
#endif
#include "pyarrays.hpp"
#include "step_read.hpp"
#include "step_strict.hpp"
#include "step_xml.hpp"
#include "world.hpp"

namespace py = pybind11;
using dc::BodyState;
using dc::ContactState;
using dc::column;

namespace {

// Hands a vector's storage to numpy without copying: the array made through numpy's own
// constructor (pybind11's array_t builds shape and stride vectors and looks its dtype up each
// call: a table of 30 columns a step took about twice as long).
template <typename T>
py::array own(std::vector<T>&& v, size_t rows, size_t cols = 1) {
    auto* heap = new std::vector<T>(std::move(v));
    heap->resize(rows * cols);  // (an empty table's vector may hold no storage: numpy then allocates its
                                // zero bytes itself, and the capsule only ends the vector)
    py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
    auto& api = py::detail::npy_api::get();
    Py_intptr_t dims[2] = {static_cast<Py_intptr_t>(rows), static_cast<Py_intptr_t>(cols)};
    PyObject* descr = api.PyArray_DescrFromType_(py::detail::npy_format_descriptor<T>::value);
    if (descr == nullptr) throw py::error_already_set();
    // (the descriptor's reference is the new array's; numpy works out alignment and contiguity)
    PyObject* made = api.PyArray_NewFromDescr_(api.PyArray_Type_, descr, cols > 1 ? 2 : 1, dims, nullptr,
                                               heap->data(), py::detail::npy_api::NPY_ARRAY_WRITEABLE_, nullptr);
    if (made == nullptr) throw py::error_already_set();
    py::array out = py::reinterpret_steal<py::array>(made);
    if (api.PyArray_SetBaseObject_(made, owner.release().ptr()) != 0) throw py::error_already_set();
    return out;
}

py::array own_bool(const std::vector<uint8_t>& v) {
    py::array_t<bool> out(static_cast<py::ssize_t>(v.size()));
    auto m = out.mutable_unchecked<1>();
    for (size_t i = 0; i < v.size(); ++i) m(i) = v[i] != 0;
    return out;
}

// The dicts handed to Python and the checked views read back, generated from records.hpp.
#define DC_OWN_FIELD(T, name, width, solver) d[#name] = own(std::move(s.name), n, width);
#define DC_COLUMN_FIELD(T, name, width, solver) v.name = column<T>(d, #name, n, width);

// with_fixed_rotation: a World's bodies; step files do not record it.
py::dict to_dict(BodyState s, bool with_fixed_rotation = true) {
    const size_t n = s.size();
    py::dict d;
    DC_BODY_FIELDS(DC_OWN_FIELD)
    if (with_fixed_rotation) d["fixed_rotation"] = own_bool(s.fixed_rotation);
    return d;
}

py::dict to_dict(ContactState s) {
    const size_t n = s.size();
    py::dict d;
    DC_CONTACT_FIELDS(DC_OWN_FIELD)
    return d;
}

// A record table given as a dict of columns, viewed without a copy (each column's shape and type
// checked by DC_COLUMN_FIELD); one function per record kind, from its field table.
#define DC_VIEW_OF_DICT(fn, View, FIELDS)    \
    View fn(const py::dict& d) {             \
        View v;                              \
        size_t n = static_cast<size_t>(-1);  \
        FIELDS(DC_COLUMN_FIELD)              \
        v.n = n;                             \
        return v;                            \
    }
DC_VIEW_OF_DICT(body_view, dc::BodyView, DC_BODY_FIELDS)
DC_VIEW_OF_DICT(contact_view, dc::ContactView, DC_CONTACT_FIELDS)
#undef DC_VIEW_OF_DICT

// A step file's header as step/reader_lxml.py gives it (numpy float32 scalars for its floats).
py::dict to_dict(const dc::StepHeader& h) {
    py::object f32 = py::module_::import("numpy").attr("float32");
    py::dict d;
    d["scene"] = h.has_scene ? py::object(py::str(h.scene)) : py::object(py::none());
    d["seed"] = h.seed;
    d["index"] = h.index;
    d["time"] = f32(h.time);
    d["dt"] = f32(h.dt);
    d["dt_ratio"] = f32(h.dt_ratio);
    std::vector<float> g(h.gravity, h.gravity + 2);
    d["gravity"] = own(std::move(g), 2);
    d["velocity_iterations"] = h.has_iterations ? py::object(py::int_(h.velocity_iterations)) : py::object(py::none());
    d["position_iterations"] = h.has_iterations ? py::object(py::int_(h.position_iterations)) : py::object(py::none());
    d["solver"] = h.solver;
    d["effects"] = h.effects;
    d["versions"] = h.versions;
    d["soft_step"] = h.soft_step.empty() ? py::object(py::none()) : py::object(py::cast(h.soft_step));
    d["solve"] = h.has_solve ? py::object(py::cast(h.solve)) : py::object(py::none());
    d["engine"] = h.engine.empty() ? py::object(py::none()) : py::object(py::cast(h.engine));
    d["engine_step"] = h.engine_step.empty() ? py::object(py::none()) : py::object(py::cast(h.engine_step));
    return d;
}

// The table from its Python form: [(name, [(attribute, kind, required, low, low exclusive, high,
// enumeration, fixed)], any attribute, [(names, declarations, min, max)])].
dc::StrictTable strict_table(const py::sequence& declarations) {
    static const std::pair<const char*, dc::ValueKind> kinds[] = {
        {"float", dc::ValueKind::Float}, {"int", dc::ValueKind::Int}, {"unsigned", dc::ValueKind::Unsigned},
        {"integer", dc::ValueKind::Integer}, {"boolean", dc::ValueKind::Boolean},
        {"token", dc::ValueKind::Token}, {"string", dc::ValueKind::String}};
    dc::StrictTable t;
    for (const auto& item : declarations) {
        const auto d = item.cast<py::tuple>();
        dc::StrictDeclaration out;
        out.name = d[0].cast<std::string>();
        for (const auto& a_item : d[1].cast<py::sequence>()) {
            const auto a = a_item.cast<py::tuple>();
            dc::StrictAttribute attribute;
            attribute.name = a[0].cast<std::string>();
            const auto kind = a[1].cast<std::string>();
            bool known = false;
            for (const auto& [k, v] : kinds)
                if (kind == k) attribute.kind = v, known = true;
            if (!known) throw std::invalid_argument("unknown attribute kind " + kind);
            attribute.required = a[2].cast<bool>();
            if (!a[3].is_none()) attribute.has_low = true, attribute.low = a[3].cast<double>();
            attribute.low_open = a[4].cast<bool>();
            if (!a[5].is_none()) attribute.has_high = true, attribute.high = a[5].cast<double>();
            attribute.enumeration = a[6].cast<std::vector<std::string>>();
            if (!a[7].is_none()) attribute.has_fixed = true, attribute.fixed = a[7].cast<std::string>();
            out.attributes.push_back(std::move(attribute));
        }
        if (out.attributes.size() > 64) throw std::invalid_argument("more than 64 attributes on " + out.name);
        out.any_attribute = d[2].cast<bool>();
        for (const auto& p_item : d[3].cast<py::sequence>()) {
            const auto p = p_item.cast<py::tuple>();
            dc::StrictParticle particle;
            particle.names = p[0].cast<std::vector<std::string>>();
            particle.declarations = p[1].cast<std::vector<int>>();
            particle.min = p[2].cast<int>();
            particle.max = p[3].cast<int>();
            out.particles.push_back(std::move(particle));
        }
        t.declarations.push_back(std::move(out));
    }
    for (const auto& d : t.declarations)   // (every reference within the table)
        for (const auto& p : d.particles)
            for (int k : p.declarations)
                if (k < 0 || static_cast<size_t>(k) >= t.declarations.size())
                    throw std::invalid_argument("a particle names no declaration");
    return t;
}

void bind_step_reader(py::module_& m) {
    static py::exception<dc::StepFileError> error(m, "StepFileError", PyExc_ValueError);
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const dc::StepFileError& e) {   // args: (message, line; 0 for the whole file)
            PyErr_SetObject(error.ptr(), py::make_tuple(e.what(), e.line).ptr());
        }
    });
    m.attr("DOCTYPE_REFUSED") = dc::kDoctypeRefused;
    py::class_<dc::StepSchema>(m, "StepSchema", "A compiled XSD, shared by every validation that uses it.")
        .def(py::init<std::string>(), py::arg("xsd_path"));
    py::class_<dc::StrictTable>(m, "StrictTable",
                                "The step schema as a table (deepcontact/step/strict.py), checked as a file is read.")
        .def(py::init(&strict_table), py::arg("declarations"));
    m.def(
        "read_step_file",
        [](const std::string& path, const dc::StepSchema* schema, const dc::StrictTable* strict) {
            dc::StepFile f;
            {
                py::gil_scoped_release release;
                f = dc::read_step_file(path, schema, strict);
            }
            return py::make_tuple(to_dict(f.header), to_dict(std::move(f.bodies), false),
                                  to_dict(std::move(f.contacts)));
        },
        py::arg("path"), py::arg("schema") = nullptr, py::arg("strict") = nullptr,
        "(header, bodies, contacts) of a step file (.xml or .xml.gz), streamed with libxml2; validated\n"
        "against schema in the same pass if given, or checked against the schema's table (strict).\n"
        "Raises StepFileError(message, line).");
    m.def(
        "check_step_table",
        [](const std::string& path, const dc::StrictTable& table) {
            dc::TableVerdict v;
            {
                py::gil_scoped_release release;
                v = dc::check_step_table(path, table);
            }
            return py::make_tuple(v.problem.empty() ? "valid" : v.deferred ? "xsd" : "invalid", v.problem);
        },
        py::arg("path"), py::arg("table"),
        "(verdict, problem): the schema's table's own verdict on a step file, no record read: \"valid\",\n"
        "\"invalid\", or \"xsd\" for a form the table leaves to the XSD; problem: its first, or \"\".\n"
        "Raises StepFileError for a file it cannot read.");
    m.def(
        "validate_step_file",
        [](const std::string& path, const dc::StepSchema& schema, size_t max_errors) {
            dc::Validation v;
            {
                py::gil_scoped_release release;
                v = dc::validate_step_file(path, schema, max_errors);
            }
            py::list errors;
            for (const auto& e : v.errors) errors.append(py::make_tuple(e.line, e.column, e.message));
            return py::make_tuple(v.root, v.has_scene ? py::object(py::str(v.scene)) : py::object(py::none()),
                                  v.seed < 0 ? py::object(py::none()) : py::object(py::int_(v.seed)), errors);
        },
        py::arg("path"), py::arg("schema"), py::arg("max_errors") = 100,
        "(root, scene, seed, [(line, column, message)]) of a file checked against the step schema in\n"
        "one streaming pass; only a <step> root is parsed (for another, root says which it is).");
}

using F32 = py::array_t<float, py::array::c_style>;
using I32 = py::array_t<int32_t, py::array::c_style>;

void require(const py::array& a, size_t n, size_t width, const char* name) {
    const bool ok = (width == 1 && a.ndim() == 1 && static_cast<size_t>(a.shape(0)) == n) ||
                    (width > 1 && a.ndim() == 2 && static_cast<size_t>(a.shape(0)) == n &&
                     static_cast<size_t>(a.shape(1)) == width);
    if (!ok) throw py::value_error(std::string(name) + " must have shape (" + std::to_string(n) +
                                   (width > 1 ? ", " + std::to_string(width) : std::string(",")) + ")");
}


// --- The closed loop's shared arena (contest/arena.py): its step written, read back, made tables --

constexpr size_t kArenaAlign = 64;

size_t arena_aligned(size_t n) { return (n + kArenaAlign - 1) / kArenaAlign * kArenaAlign; }

// The bytes of a buffer that is one C-contiguous block (a mapping, a bytearray); ValueError for
// any other (a reversed or strided view: bytes written from its first element on would land
// in memory it does not hold).
size_t contiguous_bytes(const py::buffer_info& b, const char* who = "arena_put") {
    py::ssize_t step = b.itemsize;
    for (py::ssize_t d = b.ndim - 1; d >= 0; --d) {
        if (b.shape[static_cast<size_t>(d)] > 1 && b.strides[static_cast<size_t>(d)] != step)
            throw py::value_error(std::string(who) + ": the arena must be one contiguous block of bytes");
        step *= b.shape[static_cast<size_t>(d)];
    }
    return static_cast<size_t>(b.size) * static_cast<size_t>(b.itemsize);
}

// A column's dtype held to numbers (bool, integers, floats, complex): their dtype number, byte
// order and item size say which they are, and their bytes mean the same in another process (an
// object column's are pointers into the judge; made an array there, they are dereferenced).
void numbers_only(const py::dtype& dtype, const char* who, size_t column) {
    const char kind = dtype.kind();
    if (kind == '\0' || std::strchr("biufc", kind) == nullptr)
        throw py::value_error(std::string(who) + ": column " + std::to_string(column) + " is of kind '" +
                              std::string(1, kind) + "'; an arena holds numbers only");
}

// Whether an array is of its arena form (a row of arena_put's forms, `width` long: dtype number,
// byte order, item size, trailing dimensions, each trailing extent) with rows a uint32 holds.
bool of_form(const py::array& a, const int64_t* form, size_t width) {
    const py::dtype dtype = a.dtype();
    const int64_t trailing = form[3];
    if (trailing < 0 || static_cast<size_t>(4 + trailing) > width || a.ndim() != trailing + 1 ||
        dtype.num() != form[0] || dtype.byteorder() != static_cast<char>(form[1]) || dtype.itemsize() != form[2])
        return false;
    for (int64_t d = 0; d < trailing; ++d)
        if (a.shape(static_cast<py::ssize_t>(d + 1)) != form[4 + d]) return false;
    return static_cast<uint64_t>(a.shape(0)) <= 0xFFFFFFFFu;
}

// The column arena_put writes of `item`, C-contiguous (copied where it is not, after its form is
// checked: a broadcast view's copy can be larger than memory, and raises MemoryError, which
// py::array::ensure would clear and leave a null array); None where it is not an array of its form.
py::object formed_column(const py::handle& item, const int64_t* form, size_t width, size_t column) {
    if (!py::isinstance<py::array>(item)) return py::none();
    py::array a = py::reinterpret_borrow<py::array>(item);
    numbers_only(a.dtype(), "arena_put", column);
    if (!of_form(a, form, width)) return py::none();
    if (a.flags() & py::array::c_style) return std::move(a);
    auto& api = py::detail::npy_api::get();
    PyObject* copied = api.PyArray_FromAny_(a.ptr(), nullptr, 0, 0,
                                            py::detail::npy_api::NPY_ARRAY_ENSUREARRAY_ | py::array::c_style, nullptr);
    if (copied == nullptr) throw py::error_already_set();
    return py::reinterpret_steal<py::object>(copied);
}

// One column's bytes as an arena holds them: where they are, its rows, their bytes.
struct ArenaColumn {
    const void* data;
    uint32_t rows;
    size_t bytes;
};

// The columns after a header of `head` bytes: each one's row count ("<I"), then each at a
// multiple of kArenaAlign, zero-padded (the arena holds their bytes: the caller counted them).
void write_columns(unsigned char* base, size_t head, const std::vector<ArenaColumn>& columns) {
    size_t at = arena_aligned(head + 4 * columns.size());
    for (size_t i = 0; i < columns.size(); ++i) {
        const uint32_t rows = columns[i].rows;
        for (int k = 0; k < 4; ++k) base[head + 4 * i + k] = static_cast<unsigned char>(rows >> (8 * k));
        const size_t bytes = columns[i].bytes, padded = arena_aligned(bytes);
        if (bytes) std::memcpy(base + at, columns[i].data, bytes);
        std::memset(base + at + bytes, 0, padded - bytes);
        at += padded;
    }
}

// (the closed loop's step into its shared arena, laid out as contest/arena.py reads it back:
// the row counts after the header, each column at a multiple of 64 bytes, zero padding between)
py::ssize_t arena_put(const py::buffer& arena, size_t head, const py::list& arrays,
                      const py::array_t<int64_t, py::array::c_style>& forms) {
    const py::buffer_info out = arena.request(true);
    const size_t size = contiguous_bytes(out), n = arrays.size();
    if (forms.ndim() != 2 || static_cast<size_t>(forms.shape(0)) != n || forms.shape(1) < 4)
        throw py::value_error("arena_put: one form a column (dtype number, byte order, item size, trailing shape)");
    if (head > size) throw py::value_error("arena_put: a header longer than the arena");
    const size_t width = static_cast<size_t>(forms.shape(1));
    std::vector<py::array> columns;
    columns.reserve(n);
    size_t used = arena_aligned(head + 4 * n);
    for (size_t i = 0; i < n; ++i) {
        // (a column not of its form: 0, nothing written, and the caller makes a new schema)
        py::object a = formed_column(arrays[i], forms.data() + i * width, width, i);
        if (a.is_none()) return 0;
        columns.push_back(py::reinterpret_steal<py::array>(a.release()));
        used += arena_aligned(static_cast<size_t>(columns.back().nbytes()));
    }
    if (used > size) return -static_cast<py::ssize_t>(used);
    std::vector<ArenaColumn> spans;
    spans.reserve(n);
    for (const py::array& a : columns)
        spans.push_back({a.data(), static_cast<uint32_t>(a.shape(0)), static_cast<size_t>(a.nbytes())});
    write_columns(static_cast<unsigned char*>(out.ptr), head, spans);
    return static_cast<py::ssize_t>(used);
}

// What is wrong with a contestant's answer (normal and tangent impulses, one a contact point), in
// the judge's order: 0 nothing, 1 a normal impulse not finite, 2 a tangent impulse not finite,
// 3 a normal impulse that pulls (below 0). One pass; contest/wire.py checked_answer names it.
// (float64 arrays, or ones numpy casts to float64 safely, keeping every value: no forcecast)
int answer_fault(const py::array_t<double, py::array::c_style>& normal,
                 const py::array_t<double, py::array::c_style>& tangent) {
    if (normal.ndim() != 1 || tangent.ndim() != 1 || normal.shape(0) != tangent.shape(0))
        throw py::value_error("answer_fault: one normal and one tangent impulse a contact point");
    const double* n = normal.data();
    const double* t = tangent.data();
    bool normal_finite = true, tangent_finite = true, pulls = false;
    for (py::ssize_t i = 0; i < normal.shape(0); ++i) {
        normal_finite &= std::isfinite(n[i]);
        tangent_finite &= std::isfinite(t[i]);
        pulls |= n[i] < 0.0;
    }
    return !normal_finite ? 1 : !tangent_finite ? 2 : pulls ? 3 : 0;
}

// --- The loop's step written from the world itself (contest/arena.py, StepChannel.write_world) --
// What the judge's ctx of an ordinary start holds, each column taken where World.bodies() and
// World.contacts() take it, or made from them as the judge makes it in Python (StepProblem's
// rows and keys, Box2D's carried start, the points that persisted, the step before's solution):
// the same bytes arena_put writes of that ctx, without a numpy array or a dict a column.

enum WorldColumn : int64_t {
    kBodyColumn = 0,          // + the field's place in DC_BODY_FIELDS
    kContactColumn = 100,     // + the field's place in DC_CONTACT_FIELDS
    kFixedRotation = 200,
    kRowA, kRowB, kStartNormal, kStartTangent, kKeys, kPersisted, kPreviousKeys, kPreviousNormal, kPreviousTangent
};
#define DC_ONE_FIELD(T, name, width, solver) +1
static_assert(0 DC_BODY_FIELDS(DC_ONE_FIELD) <= kContactColumn - kBodyColumn &&
                  0 DC_CONTACT_FIELDS(DC_ONE_FIELD) <= kFixedRotation - kContactColumn,
              "each table's fields have codes of their own");
#undef DC_ONE_FIELD

// The contacts' fields Box2D's answer lives in (the impulses each point carries): an oracle's alone
// to see, so no code gives them.
constexpr bool answer_field(std::string_view name) { return name == "normal_impulse" || name == "tangent_impulse"; }

// [(slot, name, code, dtype, row width)] of every column arena_put_world writes.
py::list world_columns() {
    py::list out;
    int64_t k = 0;
    auto add = [&out](const char* slot, const char* name, int64_t code, py::dtype dtype, int width) {
        out.append(py::make_tuple(slot, name, code, dtype, width));
    };
#define DC_WORLD_COLUMN(T, name, width, solver)                                 \
    if (!answer_field(#name)) add(table, #name, base + k, py::dtype::of<T>(), width); \
    ++k;
    {
        const char* table = "bodies";
        int64_t base = kBodyColumn;
        DC_BODY_FIELDS(DC_WORLD_COLUMN)
    }
    k = 0;
    {
        const char* table = "contacts";
        int64_t base = kContactColumn;
        DC_CONTACT_FIELDS(DC_WORLD_COLUMN)
    }
#undef DC_WORLD_COLUMN
    add("bodies", "fixed_rotation", kFixedRotation, py::dtype::of<bool>(), 1);
    add("problem.contacts", "row_a", kRowA, py::dtype::of<int32_t>(), 1);
    add("problem.contacts", "row_b", kRowB, py::dtype::of<int32_t>(), 1);
    add("problem", "start_normal", kStartNormal, py::dtype::of<float>(), 1);
    add("problem", "start_tangent", kStartTangent, py::dtype::of<float>(), 1);
    add("problem", "keys", kKeys, py::dtype::of<int64_t>(), 5);
    add("ctx", "persisted", kPersisted, py::dtype::of<bool>(), 1);
    add("previous", "keys", kPreviousKeys, py::dtype::of<int64_t>(), 5);
    add("previous", "normal", kPreviousNormal, py::dtype::of<double>(), 1);
    add("previous", "tangent", kPreviousTangent, py::dtype::of<double>(), 1);
    return out;
}

// Each row of `keys` (rows of 5) found among the rows of `known`, matched whole: an
// open-addressed table of known's rows, the first row of each key kept (a hash only finds where
// to compare). found[j] and row[j] (0 where none).
void match_keys(const int64_t* k, size_t n, const int64_t* q, size_t m, bool* found, py::ssize_t* row) {
    auto hash = [](const int64_t* v) {
        uint64_t h = 0x9E3779B97F4A7C15ull;
        for (int c = 0; c < 5; ++c) {
            h ^= static_cast<uint64_t>(v[c]) + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
            h *= 0xFF51AFD7ED558CCDull;
            h ^= h >> 33;
        }
        return h;
    };
    size_t size = 16;
    while (size < 2 * n) size <<= 1;
    std::vector<int64_t> table(size, -1);
    for (size_t i = 0; i < n; ++i) {
        for (size_t at = hash(k + 5 * i) & (size - 1);; at = (at + 1) & (size - 1)) {
            if (table[at] < 0) {
                table[at] = static_cast<int64_t>(i);
                break;
            }
            if (std::equal(k + 5 * i, k + 5 * i + 5, k + 5 * table[at])) break;   // (kept: the first)
        }
    }
    for (size_t j = 0; j < m; ++j) {
        found[j] = false;
        row[j] = 0;
        if (n == 0) continue;
        for (size_t at = hash(q + 5 * j) & (size - 1); table[at] >= 0; at = (at + 1) & (size - 1)) {
            if (std::equal(q + 5 * j, q + 5 * j + 5, k + 5 * table[at])) {
                found[j] = true;
                row[j] = static_cast<py::ssize_t>(table[at]);
                break;
            }
        }
    }
}

bool all_finite(const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return std::isfinite(x); });
}

using Int64Rows = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;
using Doubles = py::array_t<double, py::array::c_style | py::array::forcecast>;

// (bytes used, or minus those needed where the arena is too small, or 0 where a contact names a
// body the world does not hold; the step's contact keys, int64 rows of 5; whether the bodies'
// angle, centre, velocity and spin are finite). columns: world_columns' codes, one an arena
// column; carried: Box2D's warm-start scale (dtRatio, 0 where warm starting is off); known: the
// step before's keys (which of this step's points persisted); previous: its solution by key.
py::tuple arena_put_world(dc::World& w, const py::buffer& arena, size_t head,
                          const py::array_t<int64_t, py::array::c_style>& columns, float carried,
                          const Int64Rows& known, const Int64Rows& previous_keys, const Doubles& previous_normal,
                          const Doubles& previous_tangent) {
    const py::buffer_info out = arena.request(true);
    const size_t size = contiguous_bytes(out, "arena_put_world"), n = static_cast<size_t>(columns.size());
    if (head > size) throw py::value_error("arena_put_world: a header longer than the arena");
    if (columns.ndim() != 1) throw py::value_error("arena_put_world: one code a column");
    for (const py::array* a : {static_cast<const py::array*>(&known), static_cast<const py::array*>(&previous_keys)})
        if (a->ndim() != 2 || a->shape(1) != 5) throw py::value_error("arena_put_world: keys must be rows of 5");
    const size_t previous = static_cast<size_t>(previous_keys.shape(0));
    if (previous_normal.ndim() != 1 || previous_tangent.ndim() != 1 ||
        static_cast<size_t>(previous_normal.shape(0)) != previous ||
        static_cast<size_t>(previous_tangent.shape(0)) != previous)
        throw py::value_error("arena_put_world: the step before's impulses must be one a key");
    const BodyState b = w.bodies();
    ContactState c = w.contacts();
    const size_t bodies = b.size(), points = c.size();
    const bool finite = all_finite(b.angle) && all_finite(b.center) && all_finite(b.velocity) && all_finite(b.omega);
    // the bodies' rows of each point's bodies (StepProblem._from_world: a body's index is its row
    // where the indices run from 0 to n - 1, else it is looked up among them, which are ascending)
    std::vector<int32_t> row_a(points), row_b(points);
    const bool dense = bodies > 0 && b.index.front() == 0 && b.index.back() == static_cast<int32_t>(bodies - 1);
    for (size_t i = 0; i < points; ++i) {
        for (auto [body, row] : {std::pair{c.body_a[i], &row_a[i]}, std::pair{c.body_b[i], &row_b[i]}}) {
            if (dense) {
                *row = body;
                continue;
            }
            const auto at = std::lower_bound(b.index.begin(), b.index.end(), body);
            if (at == b.index.end() || *at != body) return py::make_tuple(0, py::none(), finite);
            *row = static_cast<int32_t>(at - b.index.begin());
        }
    }
    std::vector<float> start_normal(points), start_tangent(points);
    std::vector<int64_t> keys(5 * points);
    for (size_t i = 0; i < points; ++i) {
        start_normal[i] = carried * c.normal_impulse[i];   // (numpy's float32 product: one rounding)
        start_tangent[i] = carried * c.tangent_impulse[i];
        const int64_t key[5] = {c.fixture_a[i], c.child_a[i], c.fixture_b[i], c.child_b[i], c.id_key[i]};
        std::copy(key, key + 5, &keys[5 * i]);
    }
    std::unique_ptr<bool[]> persisted(new bool[points ? points : 1]);
    std::vector<py::ssize_t> unused(points);
    match_keys(known.data(), static_cast<size_t>(known.shape(0)), keys.data(), points, persisted.get(), unused.data());
    std::vector<uint8_t> fixed_rotation(bodies);
    for (size_t i = 0; i < bodies; ++i) fixed_rotation[i] = b.fixed_rotation[i] != 0;

    // every column the world gives, by its code (world_columns)
    const auto rows = static_cast<uint32_t>(points), before = static_cast<uint32_t>(previous);
    std::vector<std::optional<ArenaColumn>> given(kPreviousTangent + 1);
    int64_t k = 0;
#define DC_BODY_GIVEN(T, name, width, solver) \
    given[kBodyColumn + k++] = ArenaColumn{b.name.data(), static_cast<uint32_t>(bodies), b.name.size() * sizeof(T)};
#define DC_CONTACT_GIVEN(T, name, width, solver) \
    if (!answer_field(#name)) given[kContactColumn + k] = ArenaColumn{c.name.data(), rows, c.name.size() * sizeof(T)}; \
    ++k;
    DC_BODY_FIELDS(DC_BODY_GIVEN)
    k = 0;
    DC_CONTACT_FIELDS(DC_CONTACT_GIVEN)
#undef DC_BODY_GIVEN
#undef DC_CONTACT_GIVEN
    given[kFixedRotation] = ArenaColumn{fixed_rotation.data(), static_cast<uint32_t>(bodies), bodies};
    given[kRowA] = ArenaColumn{row_a.data(), rows, 4 * points};
    given[kRowB] = ArenaColumn{row_b.data(), rows, 4 * points};
    given[kStartNormal] = ArenaColumn{start_normal.data(), rows, 4 * points};
    given[kStartTangent] = ArenaColumn{start_tangent.data(), rows, 4 * points};
    given[kKeys] = ArenaColumn{keys.data(), rows, 40 * points};
    given[kPersisted] = ArenaColumn{persisted.get(), rows, points};
    given[kPreviousKeys] = ArenaColumn{previous_keys.data(), before, 40 * previous};
    given[kPreviousNormal] = ArenaColumn{previous_normal.data(), before, 8 * previous};
    given[kPreviousTangent] = ArenaColumn{previous_tangent.data(), before, 8 * previous};

    std::vector<ArenaColumn> spans;
    spans.reserve(n);
    size_t used = arena_aligned(head + 4 * n);
    for (size_t i = 0; i < n; ++i) {
        const int64_t code = columns.data()[i];
        if (code < 0 || static_cast<size_t>(code) >= given.size() || !given[static_cast<size_t>(code)])
            throw py::value_error("arena_put_world: no column has the code " + std::to_string(code));
        spans.push_back(*given[static_cast<size_t>(code)]);
        used += arena_aligned(spans.back().bytes);
    }
    if (used <= size) write_columns(static_cast<unsigned char*>(out.ptr), head, spans);
    const auto put = used <= size ? static_cast<py::ssize_t>(used) : -static_cast<py::ssize_t>(used);
    return py::make_tuple(put, own(std::move(keys), points, 5), finite);
}

// The bytes of one column of `rows` rows of `dtype` and trailing `extents` (appended to `shape`);
// ValueError where an extent is negative or the count does not fit a size_t.
size_t column_bytes(const py::dtype& dtype, uint32_t rows, const py::tuple& extents, std::vector<py::ssize_t>& shape) {
    size_t row = static_cast<size_t>(dtype.itemsize()), bytes = 0;
    for (const auto e : extents) {
        const py::ssize_t extent = e.cast<py::ssize_t>();
        if (extent < 0 || __builtin_mul_overflow(row, static_cast<size_t>(extent), &row))
            throw py::value_error("arena_views: a column's trailing shape holds no bytes an arena could");
        shape.push_back(extent);
    }
    if (__builtin_mul_overflow(row, static_cast<size_t>(rows), &bytes))
        throw py::value_error("arena_views: a column larger than any arena");
    return bytes;
}

// (a contestant's copy of a step's arena, read as arena_put laid it out: one view a column,
// each sharing the copy's memory)
py::list arena_views(const py::array_t<uint8_t, py::array::c_style>& copy, size_t head, const py::list& dtypes,
                     const py::list& shapes) {
    const size_t n = dtypes.size(), size = static_cast<size_t>(copy.size());
    if (shapes.size() != n) throw py::value_error("arena_views: one shape a column");
    if (head > size || 4 * n > size - head) throw py::value_error("arena_views: the copy ends in its row counts");
    const unsigned char* base = copy.data();
    size_t at = arena_aligned(head + 4 * n);
    py::list out(n);
    for (size_t i = 0; i < n; ++i) {
        uint32_t rows = 0;
        for (int k = 0; k < 4; ++k) rows |= static_cast<uint32_t>(base[head + 4 * i + k]) << (8 * k);
        const py::dtype dtype = dtypes[i].cast<py::dtype>();
        numbers_only(dtype, "arena_views", i);
        std::vector<py::ssize_t> shape{static_cast<py::ssize_t>(rows)};
        const size_t bytes = column_bytes(dtype, rows, shapes[i].cast<py::tuple>(), shape);
        if (at > size || bytes > size - at) throw py::value_error("arena_views: a column runs past the copy's end");
        out[i] = py::array(dtype, shape, {}, base + at, copy);
        at += arena_aligned(bytes);
    }
    return out;
}

// One table of arena_tables: `table` (names, positions), a dict of each name's column. Names are
// exact str, so that no Python code (a __hash__, an __eq__) runs while `columns` is read here.
py::dict arena_table(const py::list& columns, const py::handle& table) {
    PyObject* pair = table.ptr();
    if (!PyTuple_Check(pair) || PyTuple_GET_SIZE(pair) != 2) throw py::type_error("arena_tables: a plan of pairs");
    PyObject* names = PyTuple_GET_ITEM(pair, 0);
    PyObject* at = PyTuple_GET_ITEM(pair, 1);
    if (!PyTuple_Check(names) || !PyTuple_Check(at) || PyTuple_GET_SIZE(names) != PyTuple_GET_SIZE(at))
        throw py::value_error("arena_tables: a position a name");
    py::dict d;
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(names); ++i) {
        PyObject* name = PyTuple_GET_ITEM(names, i);
        if (!PyUnicode_CheckExact(name)) throw py::type_error("arena_tables: a name is a str");
        const Py_ssize_t k = PyLong_AsSsize_t(PyTuple_GET_ITEM(at, i));
        if (k == -1 && PyErr_Occurred()) throw py::error_already_set();
        if (k < 0 || k >= PyList_GET_SIZE(columns.ptr())) throw py::value_error("arena_tables: no such column");
        if (PyDict_SetItem(d.ptr(), name, PyList_GET_ITEM(columns.ptr(), k)) != 0) throw py::error_already_set();
    }
    return d;
}

// (a contestant's ctx tables from its copy's views: each (names, positions) of the plan a dict,
// its names in order, each name's column the one at its position; 77 entries a step)
py::list arena_tables(const py::list& columns, const py::list& plan) {
    py::list out(plan.size());
    for (size_t t = 0; t < plan.size(); ++t) out[t] = arena_table(columns, plan[t]);
    return out;
}

}  // namespace

// An enumerated field's names as a list (None for a field that is not enumerated).
py::object enum_names(const char* const* names) {
    if (names == nullptr) return py::none();
    py::list out;
    for (int i = 0; i < dc::kEnumNames; ++i) out.append(names[i]);
    return out;
}

void dc::check_signals() {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw Interrupted{};  // (the handler's exception stays set)
}

PYBIND11_MODULE(_box2d, m) {
    // A native loop stopped by a signal (interrupt.hpp): the exception Python's handler raised is
    // already set; it is what the call raises.
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const dc::Interrupted&) {
            if (!PyErr_Occurred()) PyErr_SetNone(PyExc_KeyboardInterrupt);
        }
    });
    dc::bind_solver(m);
    dc::bind_grid(m);
    bind_step_reader(m);
    m.doc() = "Box2D 2.4.1 (Debian's libbox2d) for deepcontact: worlds stepped whole, state as numpy arrays.";
    // The step file's names (step_names.hpp), for the lxml reference reader: (element, attribute,
    // field, component, presence, an enumerated field's names or None, the field's dtype and width)
    // per row, in the file's order.
    py::dict body_types, contact_types;
#define DC_TYPE_OF(types, T, name, width, solver) types[#name] = py::make_tuple(py::dtype::of<T>(), width);
#define DC_BODY_TYPE(...) DC_TYPE_OF(body_types, __VA_ARGS__)
#define DC_CONTACT_TYPE(...) DC_TYPE_OF(contact_types, __VA_ARGS__)
    DC_BODY_FIELDS(DC_BODY_TYPE)
    DC_CONTACT_FIELDS(DC_CONTACT_TYPE)
    py::list body_xml, contact_xml;
#define DC_XML_ROW(list, types, element, attr, field, component, presence, names)                  \
    list.append(py::make_tuple(element, attr, #field, component, #presence, enum_names(names),        \
                               types[#field].cast<py::tuple>()[0], types[#field].cast<py::tuple>()[1]));
    DC_BODY_XML(DC_XML_ROW, body_xml, body_types)
    DC_CONTACT_XML(DC_XML_ROW, contact_xml, contact_types)
#undef DC_XML_ROW
#undef DC_BODY_TYPE
#undef DC_CONTACT_TYPE
#undef DC_TYPE_OF
    m.attr("STEP_BODY_XML") = body_xml;
    m.attr("STEP_CONTACT_XML") = contact_xml;
    m.attr("box2d_version") = DC_BOX2D_VERSION;  // from pkg-config at build time
    m.attr("box2d_runtime_version") = std::to_string(b2_version.major) + "." + std::to_string(b2_version.minor) +
                                       "." + std::to_string(b2_version.revision);
    m.attr("linear_slop") = b2_linearSlop;
    m.attr("polygon_radius") = b2_polygonRadius;
    m.attr("max_polygon_vertices") = b2_maxPolygonVertices;

    // The calls a scene is built with, one binding for both engines (state.hpp: SceneWorld).
    py::class_<dc::SceneWorld>(m, "SceneWorld")
        .def(
            "add_body",
            [](dc::SceneWorld& w, int type, float x, float y, float angle, float vx, float vy, float omega,
               float linear_damping, float angular_damping, bool fixed_rotation, bool bullet) {
                dc::BodySpec s{type, x, y, angle, vx, vy, omega, linear_damping, angular_damping, fixed_rotation, bullet};
                return w.add_body(s);
            },
            py::arg("type"), py::arg("x"), py::arg("y"), py::arg("angle") = 0.0f, py::arg("vx") = 0.0f,
            py::arg("vy") = 0.0f, py::arg("omega") = 0.0f, py::arg("linear_damping") = 0.0f,
            py::arg("angular_damping") = 0.0f, py::arg("fixed_rotation") = false, py::arg("bullet") = false)
        .def(
            "add_circle",
            [](dc::SceneWorld& w, int body, float radius, float cx, float cy, float density, float friction,
               float restitution, float threshold) {
                return w.add_circle(body, radius, cx, cy, {density, friction, restitution, threshold});
            },
            py::arg("body"), py::arg("radius"), py::arg("x") = 0.0f, py::arg("y") = 0.0f, py::arg("density") = 0.0f,
            py::arg("friction") = 0.0f, py::arg("restitution") = 0.0f, py::arg("restitution_threshold") = 1.0f)
        .def(
            "add_polygon",
            [](dc::SceneWorld& w, int body, F32 vertices, float density, float friction, float restitution,
               float threshold) {
                if (vertices.ndim() != 2 || vertices.shape(1) != 2)
                    throw py::value_error("vertices must have shape (n, 2)");
                std::vector<float> xy(vertices.data(), vertices.data() + vertices.size());
                return w.add_polygon(body, xy, {density, friction, restitution, threshold});
            },
            py::arg("body"), py::arg("vertices"), py::arg("density") = 0.0f, py::arg("friction") = 0.0f,
            py::arg("restitution") = 0.0f, py::arg("restitution_threshold") = 1.0f)
        .def(
            "add_edge",
            [](dc::SceneWorld& w, int body, float x1, float y1, float x2, float y2, float friction, float restitution,
               float threshold) {
                return w.add_edge(body, x1, y1, x2, y2, {0.0f, friction, restitution, threshold});
            },
            py::arg("body"), py::arg("x1"), py::arg("y1"), py::arg("x2"), py::arg("y2"), py::arg("friction") = 0.0f,
            py::arg("restitution") = 0.0f, py::arg("restitution_threshold") = 1.0f);

#ifdef DC_HAVE_BOX2D3
    // Box2D v3 (3.1, the pyb2d3 wheel's library): the soft step, beside 2.4.1 (world3.hpp).
    m.attr("box2d3_version") = dc::box2d3_version();
    const dc::SoftStep v3_defaults = dc::default_soft_step();
    m.def(
        "soft_step_defaults",
        [] {
            const dc::SoftStep s = dc::default_soft_step();
            py::dict d;
            d["substeps"] = s.substeps;
            d["contact_hertz"] = s.contact_hertz;
            d["damping_ratio"] = s.damping_ratio;
            d["push_speed"] = s.push_speed;
            return d;
        },
        "Box2D v3's soft step defaults (b2DefaultWorldDef's; substeps: its samples' 4).");
    py::class_<dc::World3, dc::SceneWorld>(m, "World3")
        .def(py::init([](float gx, float gy, int substeps, float hertz, float damping_ratio, float push_speed,
                         bool warm_starting, float restitution_threshold, bool sleeping, bool continuous, float skin) {
                 return std::make_unique<dc::World3>(
                     gx, gy, dc::SoftStep{substeps, hertz, damping_ratio, push_speed, warm_starting},
                     restitution_threshold, sleeping, continuous, skin);
             }),
             py::arg("gravity_x") = 0.0f, py::arg("gravity_y") = 0.0f, py::arg("substeps") = v3_defaults.substeps,
             py::arg("contact_hertz") = v3_defaults.contact_hertz,
             py::arg("damping_ratio") = v3_defaults.damping_ratio, py::arg("push_speed") = v3_defaults.push_speed,
             py::arg("warm_starting") = true, py::arg("restitution_threshold") = 1.0f, py::arg("sleeping") = false,
             py::arg("continuous") = false, py::arg("skin") = b2_polygonRadius,
             "A Box2D v3 world. skin: the radius polygons and edges are rounded by (default 2.4.1's\n"
             "polygon radius: both engines collide the same shapes; 0 for v3's sharp ones).")
        .def(
            "step",
            [](dc::World3& w, float dt, bool record) -> py::object {
                if (!(dt > 0.0f)) throw py::value_error("dt must be positive");
                if (!record) {
                    py::gil_scoped_release release;
                    w.step(dt);
                    return py::none();
                }
                std::pair<BodyState, ContactState> done;
                {
                    py::gil_scoped_release release;
                    done = w.step_recorded(dt);
                }
                return py::make_tuple(to_dict(std::move(done.first)), to_dict(std::move(done.second)));
            },
            py::arg("dt"), py::arg("record") = false,
            "One soft step. With record=True returns (bodies before the step, contacts solved in it).")
        .def("bodies", [](const dc::World3& w) { return to_dict(w.bodies()); })
        .def("remove_body", &dc::World3::remove_body, py::arg("index"))
        .def("contacts", [](const dc::World3& w) { return to_dict(w.contacts()); },
             "The touching contacts' points as a step file records them (the last step's manifolds).");
#endif

    py::class_<dc::World, dc::SceneWorld>(m, "World")
        .def(py::init<float, float>(), py::arg("gravity_x") = 0.0f, py::arg("gravity_y") = 0.0f)
        .def("remove_body", &dc::World::remove_body, py::arg("index"))
        .def(
            "step",
            [](dc::World& w, float dt, int vel, int pos, bool record, bool collided) -> py::object {
                if (!(dt > 0.0f)) throw py::value_error("dt must be positive");
                if (vel < 0 || pos < 0) throw py::value_error("iteration counts must be >= 0");
                {
                    py::gil_scoped_release release;
                    w.step(dt, vel, pos, record, collided);
                }
                if (!record) return py::none();
                return py::make_tuple(to_dict(w.recorded_bodies()), to_dict(w.recorded_contacts()));
            },
            py::arg("dt"), py::arg("velocity_iterations"), py::arg("position_iterations"), py::arg("record") = false,
            py::arg("collided") = false,
            "One Box2D step. With record=True returns (bodies before the step, contacts solved in it).\n"
            "collided=True: collide() ran on these positions and nothing changed since; Box2D's Step\n"
            "skips its own Collide (the same manifolds a second time).")
        .def("recorded", [](const dc::World& w) {
                 return py::make_tuple(to_dict(w.recorded_bodies()), to_dict(w.recorded_contacts()));
             },
             "(bodies before, contacts solved) of the last step recorded; see step(record=True).")
        .def("collide", &dc::World::collide, py::call_guard<py::gil_scoped_release>(),
             "b2ContactManager::Collide(): rebuild manifolds, carrying impulses over by feature id.")
        .def("find_new_contacts", &dc::World::find_new_contacts, py::call_guard<py::gil_scoped_release>())
        .def("bodies", [](const dc::World& w) { return to_dict(w.bodies()); })
        .def("contacts", [](dc::World& w) { return to_dict(w.contacts()); },
             "Touching contacts in island order (the order Box2D's solver visits them).")
        .def(
            "set_manifold_impulses",
            [](dc::World& w, F32 normal, F32 tangent) {
                const size_t n = static_cast<size_t>(normal.size());
                require(normal, n, 1, "normal");
                require(tangent, n, 1, "tangent");
                w.set_manifold_impulses(normal.data(), tangent.data(), n);
            },
            py::arg("normal"), py::arg("tangent"),
            "Write impulses into the manifold points of the contacts last returned by contacts().")
        .def(
            "set_body_state",
            [](dc::World& w, I32 index, F32 position, F32 angle, F32 velocity, F32 omega) {
                const size_t n = static_cast<size_t>(index.size());
                require(index, n, 1, "index");
                require(position, n, 2, "position");
                require(angle, n, 1, "angle");
                require(velocity, n, 2, "velocity");
                require(omega, n, 1, "omega");
                w.set_body_state(index.data(), position.data(), angle.data(), velocity.data(), omega.data(), n);
            },
            py::arg("index"), py::arg("position"), py::arg("angle"), py::arg("velocity"), py::arg("omega"))
        .def_property("continuous", &dc::World::continuous, &dc::World::set_continuous)
        .def_property("sleeping", &dc::World::sleeping, &dc::World::set_sleeping)
        .def_property("warm_starting", &dc::World::warm_starting, &dc::World::set_warm_starting)
        .def_property("block_solve", &dc::World::block_solve, &dc::World::set_block_solve,
                      "g_blockSolve while this world steps (the 2x2 block solver for two-point manifolds).")
        .def_property("inv_dt0", &dc::World::inv_dt0, &dc::World::set_inv_dt0,
                      "1/dt of the previous step; the next warm start is scaled by dt * inv_dt0.")
        .def_property_readonly("last_dt_ratio", &dc::World::last_dt_ratio)
        .def_property_readonly("body_count", &dc::World::body_count)
        .def_property_readonly("fixture_count", &dc::World::fixture_count);

    py::class_<dc::StepWriter>(m, "StepWriter")
        .def(py::init([](std::string root, std::string header, std::vector<std::string> shapes, bool damping,
                         const std::string& engine) {
                 if (engine != "box2d" && engine != "box2d3" && engine != "own")
                     throw py::value_error("engine (whose rows) must be box2d, box2d3 or own");
                 const dc::Engine rows = engine == "box2d" ? dc::Engine::box2d
                                         : engine == "box2d3" ? dc::Engine::box2d3 : dc::Engine::own;
                 return std::make_unique<dc::StepWriter>(std::move(root), std::move(header), std::move(shapes), damping,
                                                         rows);
             }),
             py::arg("root_attributes"), py::arg("header"), py::arg("shapes"), py::arg("damping"),
             py::arg("engine") = "box2d")
        .def(
            "render",
            [](const dc::StepWriter& w, int64_t index, double time, float dt_ratio, const py::dict& bodies,
               const py::dict& contacts, const std::string& extra_header) {
                dc::BodyView b = body_view(bodies);
                dc::ContactView c = contact_view(contacts);
                std::string out;
                {
                    py::gil_scoped_release release;
                    out = w.render(index, time, dt_ratio, b, c, extra_header);
                }
                return py::bytes(out);
            },
            py::arg("index"), py::arg("time"), py::arg("dt_ratio"), py::arg("bodies"), py::arg("contacts"),
            py::arg("extra_header") = std::string());

    m.def(
        "format_floats",
        [](py::array_t<float, py::array::c_style | py::array::forcecast> values) {
            std::vector<std::string> out;
            out.reserve(values.size());
            for (py::ssize_t i = 0; i < values.size(); ++i) {
                std::string s;
                dc::append_float(s, values.data()[i]);
                out.push_back(std::move(s));
            }
            return out;
        },
        "Shortest text that reads back to the same float32, for each value.");

    m.def("arena_put", &arena_put, py::arg("arena"), py::arg("head"), py::arg("arrays"), py::arg("forms"),
          "Writes the columns `arrays` into `arena` (a writable buffer, one contiguous block) after a header\n"
          "of `head` bytes: each one's row count (uint32), then each at a multiple of 64 bytes, zero-padded;\n"
          "returns the bytes used, 0 where a column is not of its form and nothing was written, or minus\n"
          "the bytes needed where the arena is too small. forms: int64 rows, one a column: its dtype's\n"
          "number, byte order (the character's code), item size, the count of its trailing dimensions and\n"
          "each of them (padded). A column not contiguous is copied first; ValueError for a column that is\n"
          "not numbers (objects, records, text, times) or an arena that is not contiguous.");

    m.def("arena_views", &arena_views, py::arg("copy"), py::arg("head"), py::arg("dtypes"), py::arg("shapes"),
          "The columns of a copy of an arena (a contiguous uint8 array) that arena_put wrote: one array a\n"
          "column of `dtypes` (numbers) and trailing `shapes`, its rows as written, each a view of the\n"
          "copy. ValueError where a column would run past the copy's end or is not of numbers.");

    m.def("answer_fault", &answer_fault, py::arg("normal"), py::arg("tangent"),
          "What is wrong with an answer's impulses (float64, one a contact point), in the judge's order:\n"
          "0 nothing, 1 a normal impulse not finite, 2 a tangent impulse not finite, 3 a normal impulse\n"
          "below 0.");

    m.def("world_columns", &world_columns,
          "[(slot, name, code, dtype, row width)] of each column of the closed loop's ctx that\n"
          "arena_put_world writes straight from a world (a field of its bodies or contacts, or one the\n"
          "judge's ctx makes of them).");

    m.def("arena_put_world", &arena_put_world, py::arg("world"), py::arg("arena"), py::arg("head"),
          py::arg("columns"), py::arg("carried"), py::arg("known"), py::arg("previous_keys"),
          py::arg("previous_normal"), py::arg("previous_tangent"),
          "Writes the step `world` holds into `arena` as arena_put writes the closed loop's ctx of it,\n"
          "the columns named by their world_columns codes, each taken from the world (World.bodies(),\n"
          "World.contacts()) or made of it: (bytes used, minus those needed where the arena is too small,\n"
          "or 0 where a contact names a body the world does not hold; the step's contact keys, int64 rows\n"
          "of 5; whether the bodies' angle, centre, velocity and spin are finite). carried: Box2D's\n"
          "warm-start scale; known: the step before's keys; previous_*: its solution by key.");

    m.def(
        "key_rows",
        [](py::array_t<int64_t, py::array::c_style | py::array::forcecast> known,
           py::array_t<int64_t, py::array::c_style | py::array::forcecast> keys) {
            // (contact keys, rows of 5, matched whole: match_keys)
            auto rows_of = [](const py::array& a, const char* what) {
                if (a.ndim() != 2 || a.shape(1) != 5)
                    throw py::value_error(std::string("key_rows: ") + what + " must be rows of 5");
                return static_cast<size_t>(a.shape(0));
            };
            const size_t n = rows_of(known, "known"), m = rows_of(keys, "keys");
            py::array_t<bool> found(static_cast<py::ssize_t>(m));
            py::array_t<py::ssize_t> row(static_cast<py::ssize_t>(m));
            const int64_t* k = known.data();
            const int64_t* q = keys.data();
            bool* f = found.mutable_data();
            py::ssize_t* r = row.mutable_data();
            {
                py::gil_scoped_release release;
                match_keys(k, n, q, m, f, r);
            }
            return py::make_tuple(found, row);
        },
        py::arg("known"), py::arg("keys"),
        "(found, row) of each row of `keys` (int64 rows of 5: contact keys) among the rows of `known`:\n"
        "whether it is one of them, matched whole, and the first row holding it (0 where none does).");

    m.def("arena_tables", &arena_tables, py::arg("columns"), py::arg("plan"),
          "One dict a table of `plan` ((names, positions) each; names str): each name's value the column\n"
          "of `columns` at its position, in the names' order.");

    py::register_exception<std::domain_error>(m, "NonFiniteError", PyExc_ValueError);
}
