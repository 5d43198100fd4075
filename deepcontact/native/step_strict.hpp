// The step schema as a table (compiled from schemas/step.xsd by deepcontact/step/strict.py),
// checked by the SAX reader in the pass that reads the file: elements in their order and number,
// attributes required and allowed, each attribute's type and bounds, no text. Its first problem
// stops the parse; the caller then lets the XSD itself say what is wrong (it is the authority),
// so this check must refuse whatever the XSD refuses, and may refuse more.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace dc {

enum class ValueKind : uint8_t { Float, Int, Boolean, Token, String };

struct StrictAttribute {
    std::string name;
    ValueKind kind = ValueKind::String;
    bool required = false;
    bool has_low = false, low_open = false, has_high = false;
    double low = 0, high = 0;
    std::vector<std::string> enumeration;
    bool has_fixed = false;
    std::string fixed;
};

struct StrictParticle {
    std::vector<std::string> names;   // the elements it accepts (one, or a choice)
    std::vector<int> declarations;    // each one's declaration
    int min = 1, max = 1;             // max -1: unbounded
};

struct StrictDeclaration {
    std::string name;
    std::vector<StrictAttribute> attributes;   // at most 64: one bit each when seen
    bool any_attribute = false;
    std::vector<StrictParticle> particles;     // a sequence
};

// The table: declarations[0] is the root's.
struct StrictTable {
    std::vector<StrictDeclaration> declarations;
};

namespace strict {

inline bool xml_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

// The value without its leading and trailing white space (attribute values are already
// normalised by the parser: no tab or newline is left inside), as a view: no copy.
struct View {
    const char* b;
    const char* e;
    size_t size() const { return static_cast<size_t>(e - b); }
    bool operator==(const std::string& s) const { return size() == s.size() && std::memcmp(b, s.data(), size()) == 0; }
};

inline View trimmed(const char* b, const char* e) {
    while (b < e && xml_space(*b)) ++b;
    while (e > b && xml_space(e[-1])) --e;
    return {b, e};
}

// XSD's decimal-or-exponent lexical form of a float (INF and NaN are refused: no type here
// allows them, and a table that allowed them would be refused by the bounds anyway).
inline bool float_lexical(View v) {
    const char* i = v.b;
    const char* n = v.e;
    if (i < n && (*i == '+' || *i == '-')) ++i;
    size_t digits = 0;
    while (i < n && *i >= '0' && *i <= '9') ++i, ++digits;
    if (i < n && *i == '.') {
        ++i;
        while (i < n && *i >= '0' && *i <= '9') ++i, ++digits;
    }
    if (digits == 0) return false;
    if (i < n && (*i == 'e' || *i == 'E')) {
        ++i;
        if (i < n && (*i == '+' || *i == '-')) ++i;
        size_t exponent = 0;
        while (i < n && *i >= '0' && *i <= '9') ++i, ++exponent;
        if (exponent == 0) return false;
    }
    return i == n;
}

// The value's text NUL-terminated in `buffer` (false if it does not fit: then it is refused,
// and the XSD decides).
inline bool terminated(View v, char (&buffer)[64]) {
    if (v.size() >= sizeof buffer) return false;
    std::memcpy(buffer, v.b, v.size());
    buffer[v.size()] = '\0';
    return true;
}

inline const char* const kSlow = "(decide by parsing)";

// The bounds of a float written without an exponent, decided from its digits (no strtod: it was
// the most of this check's time): at most 38 digits each side of the point make a value that is
// finite in float32 (below 1e38) and, unless every digit is 0, not 0 in float32 (at least 1e-38);
// so bounds of 0 or beyond 1e38 are decided exactly. kSlow where they are not.
inline const char* fast_float_problem(const StrictAttribute& a, View v) {
    const char* i = v.b;
    const bool negative = i < v.e && *i == '-';
    if (i < v.e && (*i == '+' || *i == '-')) ++i;
    size_t whole = 0, fraction = 0;
    bool nonzero = false, point = false;
    for (; i < v.e; ++i) {
        if (*i == '.') {
            point = true;
            continue;
        }
        if (*i < '0' || *i > '9') return kSlow;   // (an exponent)
        nonzero |= *i != '0';
        ++(point ? fraction : whole);
    }
    if (whole > 38 || fraction > 38) return kSlow;
    auto decided = [](double bound) { return bound == 0 || std::fabs(bound) >= 1e38; };
    if ((a.has_low && !decided(a.low)) || (a.has_high && !decided(a.high))) return kSlow;
    const int sign = !nonzero ? 0 : negative ? -1 : 1;   // (-0 is 0)
    if (a.has_low && a.low == 0 && (a.low_open ? sign <= 0 : sign < 0)) return "below its bound";
    if (a.has_high && a.high == 0 && sign > 0) return "above its bound";
    return nullptr;   // (every other bound is beyond 1e38 in size, and so is no value here)
}

// nullptr when the value fits the attribute, else what is wrong (only that it is wrong matters:
// the XSD says it in its own words).
inline const char* value_problem(const StrictAttribute& a, const char* b, const char* e) {
    if (a.kind == ValueKind::String) return nullptr;
    const View v = trimmed(b, e);
    if (!a.enumeration.empty()) {   // (a value with white space inside matches none: the XSD decides)
        for (const auto& allowed : a.enumeration)
            if (v == allowed) return nullptr;
        return "not one of its values";
    }
    char text[64];
    switch (a.kind) {
        case ValueKind::Token: return a.has_fixed && !(v == a.fixed) ? "not its fixed value" : nullptr;
        case ValueKind::Boolean: {
            const bool ok = v == std::string("true") || v == std::string("false") || (v.size() == 1 && (*v.b == '1' || *v.b == '0'));
            return ok ? nullptr : "not a boolean";
        }
        case ValueKind::Int: {
            const char* i = v.b;
            if (i < v.e && (*i == '+' || *i == '-')) ++i;
            if (i == v.e || v.e - i > 18) return "not a whole number in range";
            for (const char* k = i; k < v.e; ++k)
                if (*k < '0' || *k > '9') return "not a whole number";
            if (!terminated(v, text)) return "too long";
            const long long x = std::strtoll(text, nullptr, 10);
            if (a.has_low && (a.low_open ? x <= a.low : x < a.low)) return "below its bound";
            if (a.has_high && x > a.high) return "above its bound";
            if (a.has_fixed && x != std::strtoll(a.fixed.c_str(), nullptr, 10)) return "not its fixed value";
            return nullptr;
        }
        case ValueKind::Float: {
            if (!float_lexical(v)) return "not a number";
            if (const char* fast = fast_float_problem(a, v); fast != kSlow) return fast;
            if (!terminated(v, text)) return "not a number";
            // (compared as float32, as the XSD's validator does: the value and the bound rounded)
            const float x = static_cast<float>(std::strtod(text, nullptr));
            if (!std::isfinite(x) && (a.has_low || a.has_high)) return "not finite";
            if (a.has_low && (a.low_open ? !(x > static_cast<float>(a.low)) : !(x >= static_cast<float>(a.low))))
                return "below its bound";
            if (a.has_high && !(x <= static_cast<float>(a.high))) return "above its bound";
            return nullptr;
        }
        default: return nullptr;
    }
}

}  // namespace strict

// Where a file stands against the table, element by element.
class StrictCheck {
public:
    explicit StrictCheck(const StrictTable& table) : table_(table) {}

    // An element starts (SAX2: its local name, its namespace URI, its attributes five pointers
    // each: localname, prefix, URI, value, end). False on the first problem (then `problem`).
    bool start(const char* name, const char* uri, int n_attributes, const char** attributes) {
        if (uri != nullptr) return fail("an element in a namespace");
        int declaration = -1;
        if (frames_.empty()) {
            if (done_root_ || table_.declarations.empty() || table_.declarations[0].name != name)
                return fail("not the schema's root element");
            declaration = 0;
            done_root_ = true;
        } else {
            Frame& f = frames_.back();
            const auto& particles = table_.declarations[f.declaration].particles;
            while (declaration < 0) {
                if (f.particle >= particles.size()) return fail("an element the schema does not expect here");
                const StrictParticle& p = particles[f.particle];
                int match = -1;
                for (size_t k = 0; k < p.names.size(); ++k)
                    if (p.names[k] == name) match = static_cast<int>(k);
                if (match >= 0 && (p.max < 0 || f.count < p.max)) {
                    ++f.count;
                    declaration = p.declarations[static_cast<size_t>(match)];
                } else if (f.count >= p.min) {
                    ++f.particle;
                    f.count = 0;
                } else {
                    return fail("an element the schema does not expect here (one it needs is missing)");
                }
            }
        }
        const StrictDeclaration& d = table_.declarations[static_cast<size_t>(declaration)];
        uint64_t seen = 0;
        size_t hint = 0;
        for (int k = 0; k < n_attributes; ++k) {
            const char* const* a = attributes + 5 * k;
            const char* attribute = a[0];
            if (a[2] != nullptr) {   // (namespaced: the XML Schema instance's are always allowed)
                if (std::strcmp(a[2], "http://www.w3.org/2001/XMLSchema-instance") == 0 || d.any_attribute) continue;
                return fail("an attribute the schema does not allow");
            }
            // (searched from after the last one found: files list attributes in the schema's order)
            const size_t n = d.attributes.size();
            size_t found = n;
            for (size_t step = 0; step < n; ++step) {
                const size_t j = (hint + step) % n;
                if (std::strcmp(d.attributes[j].name.c_str(), attribute) == 0) {
                    found = j;
                    break;
                }
            }
            hint = found + 1;
            if (found == d.attributes.size()) {
                if (d.any_attribute) continue;
                return fail("an attribute the schema does not allow");
            }
            if (strict::value_problem(d.attributes[found], a[3], a[4]) != nullptr)
                return fail("an attribute's value the schema does not allow");
            seen |= uint64_t(1) << found;
        }
        for (size_t j = 0; j < d.attributes.size(); ++j)
            if (d.attributes[j].required && !(seen >> j & 1)) return fail("a required attribute missing");
        frames_.push_back({declaration, 0, 0});
        return true;
    }

    bool end() {
        if (frames_.empty()) return true;
        const Frame f = frames_.back();
        frames_.pop_back();
        const auto& particles = table_.declarations[static_cast<size_t>(f.declaration)].particles;
        for (size_t k = f.particle; k < particles.size(); ++k)
            if ((k == f.particle ? f.count : 0) < particles[k].min) return fail("an element the schema needs is missing");
        return true;
    }

    // Character data: only white space, everywhere (no element of the schema holds text).
    bool text(const char* b, int n) {
        for (int k = 0; k < n; ++k)
            if (!strict::xml_space(b[k])) return fail("text where the schema allows none");
        return true;
    }

    bool finished() const { return ok() && frames_.empty() && done_root_; }
    bool ok() const { return problem.empty(); }

    std::string problem;

private:
    struct Frame {
        int declaration;
        size_t particle;
        int count;
    };
    bool fail(const char* why) {
        if (problem.empty()) problem = why;
        return false;
    }
    const StrictTable& table_;
    std::vector<Frame> frames_;
    bool done_root_ = false;
};

}  // namespace dc
