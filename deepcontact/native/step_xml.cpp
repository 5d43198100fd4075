#include "step_xml.hpp"
#include "step_names.hpp"

#include <charconv>
#include <cstring>
#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

namespace dc {
namespace {

void append_int(std::string& out, int64_t value) {
    char buf[24];
    auto r = std::to_chars(buf, buf + sizeof buf, value);
    out.append(buf, r.ptr);
}

// Writes ` name="value"` checking that value is finite.
class Attrs {
public:
    Attrs(std::string& out, const char* what, int64_t index) : out_(out), what_(what), index_(index) {}
    Attrs& f(const char* name, float v) {
        if (!std::isfinite(v))
            throw std::domain_error(std::string("non-finite ") + name + " in " + what_ + " " +
                                    std::to_string(index_));
        append_float(open(name), v);
        return close();
    }
    Attrs& i(const char* name, int64_t v) {
        append_int(open(name), v);
        return close();
    }
    Attrs& s(const char* name, const char* v) {
        open(name) += v;
        return close();
    }

private:
    std::string& open(const char* name) {   // ` name="`: the value follows
        out_ += ' ';
        out_ += name;
        out_ += "=\"";
        return out_;
    }
    Attrs& close() {
        out_ += '"';
        return *this;
    }

    std::string& out_;
    const char* what_;
    int64_t index_;
};

// One attribute of a row, from a column of a view: a float (finite), an integer, or a name.
void put(Attrs& a, const char* attr, const float* column, size_t i, const char* const*) { a.f(attr, column[i]); }
template <class T>
void put(Attrs& a, const char* attr, const T* column, size_t i, const char* const* names) {
    if (names != nullptr) {
        if (column[i] < 0 || column[i] >= kEnumNames) throw std::out_of_range(std::string("bad ") + attr);
        a.s(attr, names[column[i]]);
    } else {
        a.i(attr, static_cast<int64_t>(column[i]));
    }
}

// The attributes of a record's row, from the step file's names (step_names.hpp): its own
// attributes on the row element, then one empty element per group of attributes.
template <class View>
struct Emit {
    const char* element;
    const char* attr;
    Presence presence;
    void (*put)(Attrs&, const char*, const View&, size_t);
    bool (*nonzero)(const View&, size_t);
};

struct BodyWidths {
    DC_BODY_FIELDS(DC_WIDTH_FIELD)
};
struct ContactWidths {
    DC_CONTACT_FIELDS(DC_WIDTH_FIELD)
};

#define DC_EMIT(View, Widths, element, attr, field, component, presence, names)                       \
    Emit<View>{element, attr, Presence::presence,                                                     \
               [](Attrs& a, const char* at, const View& v, size_t k) {                               \
                   put(a, at, v.field, Widths::field * k + component, names);                        \
               },                                                                                     \
               [](const View& v, size_t k) { return v.field[Widths::field * k + component] != 0; }},
const Emit<BodyView> kBodyEmit[] = {DC_BODY_XML(DC_EMIT, BodyView, BodyWidths)};
const Emit<ContactView> kContactEmit[] = {DC_CONTACT_XML(DC_EMIT, ContactView, ContactWidths)};
#undef DC_EMIT

// A table's rows grouped by element, found once per table (not once per row written): the row
// element's own attributes [0, own), then one [begin, end) per child element.
struct Groups {
    size_t own = 0;
    std::vector<std::pair<size_t, size_t>> children;
};

template <class View, size_t N>
const Groups& groups(const Emit<View> (&table)[N]) {
    static const Groups g = [&] {
        Groups out;
        while (out.own < N && std::strcmp(table[out.own].element, ".") == 0) ++out.own;
        for (size_t i = out.own; i < N;) {
            size_t end = i;
            while (end < N && std::strcmp(table[end].element, table[i].element) == 0) ++end;
            out.children.emplace_back(i, end);
            i = end;
        }
        return out;
    }();
    return g;
}

// Writes row k's own attributes, closes its start tag, and writes its child elements; declared:
// whether the scene declares the effects of Presence::declared rows; engine: whose rows to write.
template <class View, size_t N>
void write_row(std::string& out, Attrs& a, const Emit<View> (&table)[N], const View& v, size_t k, bool declared,
               Engine engine) {
    const Groups& g = groups(table);
    for (size_t i = 0; i < g.own; ++i) table[i].put(a, table[i].attr, v, k);
    out += ">\n";
    for (const auto& [begin, end] : g.children) {
        const Presence p = table[begin].presence;
        bool shown = required_in(p, engine) || (p == Presence::declared && declared);
        for (size_t i = begin; p == Presence::nonzero && !shown && i < end; ++i) shown = table[i].nonzero(v, k);
        if (!shown) continue;
        out += "      <";
        out += table[begin].element;
        for (size_t i = begin; i < end; ++i) table[i].put(a, table[i].attr, v, k);
        out += "/>\n";
    }
}

}  // namespace

void append_float(std::string& out, float value) {
    char buf[32];
    auto r = std::to_chars(buf, buf + sizeof buf, value);
    out.append(buf, r.ptr);
}

StepWriter::StepWriter(std::string root_attributes, std::string header, std::vector<std::string> shapes,
                       bool damping, Engine engine)
    : root_attributes_(std::move(root_attributes)), header_(std::move(header)), shapes_(std::move(shapes)),
      damping_(damping), engine_(engine) {}

std::string StepWriter::render(int64_t index, double time, float dt_ratio, const BodyView& b,
                               const ContactView& c, const std::string& extra_header) const {
    std::string out;
    out.reserve(512 + b.n * 480 + c.n * 640);
    out += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<step";
    out += root_attributes_;
    {
        Attrs a(out, "step", index);
        a.i("index", index).f("time", static_cast<float>(time)).f("dt_ratio", dt_ratio);
    }
    out += ">\n";
    out += header_;
    out += extra_header;
    out += "  </header>\n";

    out += "  <bodies count=\"";
    append_int(out, static_cast<int64_t>(b.n));
    out += "\">\n";
    for (size_t k = 0; k < b.n; ++k) {
        const int32_t idx = b.index[k];
        if (idx < 0 || static_cast<size_t>(idx) >= shapes_.size())
            throw std::out_of_range("body index " + std::to_string(idx) + " has no shape");
        Attrs a(out, "body", idx);
        out += "    <body";
        write_row(out, a, kBodyEmit, b, k, damping_, engine_);
        out += shapes_[idx];
        out += "    </body>\n";
    }
    out += "  </bodies>\n  <contacts count=\"";
    append_int(out, static_cast<int64_t>(c.n));
    out += "\">\n";
    for (size_t k = 0; k < c.n; ++k) {
        Attrs a(out, "contact", static_cast<int64_t>(k));
        out += "    <contact";
        a.i("index", static_cast<int64_t>(k));   // (its row in the file, not a recorded field)
        write_row(out, a, kContactEmit, c, k, true, engine_);
        out += "    </contact>\n";
    }
    out += "  </contacts>\n</step>\n";
    return out;
}

}  // namespace dc
