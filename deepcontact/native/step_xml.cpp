#include "step_xml.hpp"

#include <charconv>
#include <cmath>
#include <stdexcept>
#include <utility>

namespace dc {
namespace {

const char* const kBodyType[] = {"static", "kinematic", "dynamic"};
const char* const kManifoldType[] = {"circles", "face_a", "face_b"};

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

}  // namespace

void append_float(std::string& out, float value) {
    char buf[32];
    auto r = std::to_chars(buf, buf + sizeof buf, value);
    out.append(buf, r.ptr);
}

StepWriter::StepWriter(std::string root_attributes, std::string header, std::vector<std::string> shapes,
                       bool damping)
    : root_attributes_(std::move(root_attributes)), header_(std::move(header)), shapes_(std::move(shapes)),
      damping_(damping) {}

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
        if (b.type[k] < 0 || b.type[k] > 2) throw std::out_of_range("bad body type");
        Attrs a(out, "body", idx);
        out += "    <body";
        a.i("index", idx).s("type", kBodyType[b.type[k]]);
        out += ">\n      <mass";
        a.f("value", b.mass[k]).f("inverse", b.inv_mass[k]);
        out += "/>\n      <position";
        a.f("x", b.position[2 * k]).f("y", b.position[2 * k + 1]);
        out += "/>\n      <center";
        a.f("x", b.center[2 * k]).f("y", b.center[2 * k + 1]);
        out += "/>\n";
        if (b.local_center[2 * k] != 0.0f || b.local_center[2 * k + 1] != 0.0f) {
            out += "      <local_center";
            a.f("x", b.local_center[2 * k]).f("y", b.local_center[2 * k + 1]);
            out += "/>\n";
        }
        out += "      <velocity";
        a.f("x", b.velocity[2 * k]).f("y", b.velocity[2 * k + 1]);
        out += "/>\n      <orientation";
        a.f("theta", b.angle[k]);
        out += "/>\n      <inertia";
        a.f("value", b.inertia[k]).f("inverse", b.inv_inertia[k]);
        out += "/>\n      <spin";
        a.f("omega", b.omega[k]);
        out += "/>\n";
        if (damping_) {
            out += "      <damping";
            a.f("linear", b.linear_damping[k]).f("angular", b.angular_damping[k]);
            out += "/>\n";
        }
        out += shapes_[idx];
        out += "    </body>\n";
    }
    out += "  </bodies>\n  <contacts count=\"";
    append_int(out, static_cast<int64_t>(c.n));
    out += "\">\n";
    for (size_t k = 0; k < c.n; ++k) {
        if (c.manifold_type[k] < 0 || c.manifold_type[k] > 2) throw std::out_of_range("bad manifold type");
        Attrs a(out, "contact", static_cast<int64_t>(k));
        out += "    <contact";
        a.i("index", static_cast<int64_t>(k)).i("master", c.body_a[k]).i("slave", c.body_b[k]);
        a.i("manifold", c.manifold[k]).i("point", c.point[k]).i("points", c.point_count[k]);
        a.i("island", c.island[k]).i("id", c.id_key[k]);
        out += ">\n      <fixtures";
        a.i("master", c.fixture_a[k]).i("master_child", c.child_a[k]);
        a.i("slave", c.fixture_b[k]).i("slave_child", c.child_b[k]);
        out += "/>\n      <position";
        a.f("x", c.position[2 * k]).f("y", c.position[2 * k + 1]);
        out += "/>\n      <normal";
        a.f("x", c.normal[2 * k]).f("y", c.normal[2 * k + 1]);
        out += "/>\n      <separation";
        a.f("value", c.separation[k]);
        out += "/>\n      <material";
        a.f("friction", c.friction[k]).f("restitution", c.restitution[k]);
        a.f("threshold", c.restitution_threshold[k]);
        out += "/>\n      <impulse";
        a.f("n", c.normal_impulse[k]).f("t", c.tangent_impulse[k]);
        out += "/>\n      <start";
        a.f("n", c.start_normal_impulse[k]).f("t", c.start_tangent_impulse[k]);
        out += "/>\n      <manifold";
        a.s("type", kManifoldType[c.manifold_type[k]]);
        a.f("nx", c.local_normal[2 * k]).f("ny", c.local_normal[2 * k + 1]);
        a.f("x", c.local_point[2 * k]).f("y", c.local_point[2 * k + 1]);
        a.f("px", c.point_local[2 * k]).f("py", c.point_local[2 * k + 1]);
        out += "/>\n    </contact>\n";
    }
    out += "  </contacts>\n</step>\n";
    return out;
}

}  // namespace dc
