// The step schema as a table (compiled from schemas/step.xsd by deepcontact/step/strict.py),
// checked by the SAX reader in the pass that reads the file: elements in their order and number,
// attributes required and allowed, each attribute's type and bounds, no text where the schema
// allows none. Its acceptance is final (dc runs no XSD on a file it accepts), so it accepts only
// what every libxml2 the tests hold it to accepts (tests/test_schema_table.py: the schema's own
// edge cases); a form on which libxml2's versions differ, or that it does not read, it leaves to
// the XSD (deferred). Its first problem stops the parse; the caller then lets the XSD itself judge
// the file and say what is wrong (it is the authority).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace dc {

// Int: xs:int and its restrictions; Unsigned: xs:unsignedInt; Integer: xs:integer's (positiveInteger).
enum class ValueKind : uint8_t { Float, Int, Unsigned, Integer, Boolean, Token, String };

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

// What the table makes of a value or a file: nullptr (it fits), else why not; deferred: the
// table does not decide it, the XSD does.
struct Verdict {
    const char* why = nullptr;
    bool deferred = false;
};
inline Verdict refused(const char* why) { return {why, false}; }
inline Verdict deferred(const char* why) { return {why, true}; }

inline bool digit(char c) { return c >= '0' && c <= '9'; }

// Whether the view has white space inside (after trimming): a value XSD's collapse would change.
inline bool spaced(View v) {
    for (const char* i = v.b; i < v.e; ++i)
        if (xml_space(*i)) return true;
    return false;
}

enum class Lexical : uint8_t { Number, Bad, EmptyExponent };

// XSD's decimal-or-exponent lexical form of a float (INF and NaN are not read here). libxml2
// also takes an exponent without digits ("1e"), which the table leaves to it.
inline Lexical float_lexical(View v) {
    const char* i = v.b;
    const char* n = v.e;
    if (i < n && (*i == '+' || *i == '-')) ++i;
    size_t digits = 0;
    while (i < n && digit(*i)) ++i, ++digits;
    if (i < n && *i == '.') {
        ++i;
        while (i < n && digit(*i)) ++i, ++digits;
    }
    if (digits == 0) return Lexical::Bad;
    if (i < n && (*i == 'e' || *i == 'E')) {
        ++i;
        if (i < n && (*i == '+' || *i == '-')) ++i;
        size_t exponent = 0;
        while (i < n && digit(*i)) ++i, ++exponent;
        if (exponent == 0) return i == n ? Lexical::EmptyExponent : Lexical::Bad;
    }
    return i == n ? Lexical::Number : Lexical::Bad;
}

// The value's text NUL-terminated in `buffer` (false if it does not fit).
inline bool terminated(View v, char (&buffer)[64]) {
    if (v.size() >= sizeof buffer) return false;
    std::memcpy(buffer, v.b, v.size());
    buffer[v.size()] = '\0';
    return true;
}

inline const char* const kSlow = "(decide by parsing)";

// The bounds of a float written without an exponent, decided from its digits (no strtof: it was
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
        if (!digit(*i)) return kSlow;   // (an exponent)
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

inline Verdict float_verdict(const StrictAttribute& a, View v) {
    switch (float_lexical(v)) {
        case Lexical::EmptyExponent: return deferred("a float with an empty exponent");
        case Lexical::Bad:   // (INF and NaN fail any two bounds; without both, the XSD decides)
            return a.has_low && a.has_high ? refused("not a number") : deferred("INF or NaN, perhaps");
        case Lexical::Number: break;
    }
    if (const char* fast = fast_float_problem(a, v); fast != kSlow) return refused(fast);
    char text[64];
    if (!terminated(v, text)) return deferred("a float too long for the table");
    // (as float32, as libxml2 reads it: the value rounded once, to the nearest float32, and compared
    // with the bounds rounded likewise)
    const float x = std::strtof(text, nullptr);
    if (!std::isfinite(x) && (a.has_low || a.has_high)) return refused("not finite");
    if (a.has_low && (a.low_open ? !(x > static_cast<float>(a.low)) : !(x >= static_cast<float>(a.low))))
        return refused("below its bound");
    if (a.has_high && !(x <= static_cast<float>(a.high))) return refused("above its bound");
    return {};
}

// A whole number's digits as a value, in [-(1e18 - 1), 1e18 - 1]; false with more than 18
// significant digits (leading zeros do not count: libxml2 takes any number of them).
inline bool whole_value(const char* i, const char* e, bool negative, long long& out) {
    while (i < e && *i == '0') ++i;
    if (e - i > 18) return false;
    long long v = 0;
    for (; i < e; ++i) v = v * 10 + (*i - '0');
    out = negative ? -v : v;
    return true;
}

// A whole number of xs:int, xs:unsignedInt or xs:integer. Where libxml2's versions differ, on a
// value otherwise valid, the XSD decides: white space around an xs:int or xs:unsignedInt (2.9
// refuses it, later ones take it), a sign on an xs:unsignedInt (2.9 refuses any, later ones take
// "+1" and "-0").
inline Verdict whole_verdict(const StrictAttribute& a, View raw) {
    const View v = trimmed(raw.b, raw.e);
    const char* i = v.b;
    const bool negative = i < v.e && *i == '-', sign = i < v.e && (*i == '+' || *i == '-');
    i += sign;
    if (i == v.e) return refused("not a whole number");
    for (const char* k = i; k < v.e; ++k)
        if (!digit(*k)) return refused("not a whole number");
    long long x = 0;
    if (!whole_value(i, v.e, negative, x)) {   // (beyond any bound of 32 bits, and any fixed value)
        if (negative && a.has_low) return refused("below its bound");
        if (!negative && a.has_high) return refused("above its bound");
        return a.has_fixed ? refused("not its fixed value") : deferred("a whole number of more than 18 digits");
    }
    if (a.has_low && (a.low_open ? x <= a.low : x < a.low)) return refused("below its bound");
    if (a.has_high && x > a.high) return refused("above its bound");
    if (a.has_fixed && x != std::strtoll(a.fixed.c_str(), nullptr, 10)) return refused("not its fixed value");
    if (a.kind != ValueKind::Integer && v.size() != raw.size()) return deferred("white space around a whole number");
    if (a.kind == ValueKind::Unsigned && sign) return deferred("a sign on an unsigned number");
    return {};
}

// A token (after XSD's white space collapse) among `allowed` or equal to a fixed value: the
// table compares the trimmed text, and leaves a value with white space inside to the XSD.
inline Verdict token_verdict(View v, bool matched, const char* why) {
    if (matched) return {};
    return spaced(v) ? deferred("a token with white space inside") : refused(why);
}

// nullptr when the value fits the attribute, else what is wrong (only that it is wrong matters:
// the XSD says it in its own words), or that the XSD is to decide.
inline Verdict value_verdict(const StrictAttribute& a, const char* b, const char* e) {
    if (a.kind == ValueKind::String) return {};
    const View v = trimmed(b, e);
    if (!a.enumeration.empty()) {
        bool found = false;
        for (const auto& allowed : a.enumeration) found |= v == allowed;
        return token_verdict(v, found, "not one of its values");
    }
    switch (a.kind) {
        case ValueKind::Token: return token_verdict(v, !a.has_fixed || v == a.fixed, "not its fixed value");
        case ValueKind::Boolean: {
            const bool ok = v == std::string("true") || v == std::string("false") || (v.size() == 1 && (*v.b == '1' || *v.b == '0'));
            return ok ? Verdict{} : refused("not a boolean");
        }
        case ValueKind::Int:
        case ValueKind::Unsigned:
        case ValueKind::Integer: return whole_verdict(a, {b, e});
        case ValueKind::Float: return float_verdict(a, v);
        default: return {};
    }
}

}  // namespace strict

inline const char* const kSchemaInstance = "http://www.w3.org/2001/XMLSchema-instance";

// Where a file stands against the table, element by element.
class StrictCheck {
public:
    explicit StrictCheck(const StrictTable& table) : table_(table) {}

    // An element starts (SAX2: its local name, its namespace URI, its attributes five pointers
    // each: localname, prefix, URI, value, end). False on the first problem (then `problem`).
    bool start(const char* name, const char* uri, int n_attributes, const char** attributes) {
        if (uri != nullptr) return fail("an element in a namespace");
        const int declaration = enter(name);
        if (declaration < 0) return false;
        const StrictDeclaration& d = table_.declarations[static_cast<size_t>(declaration)];
        if (!attributes_fit(d, n_attributes, attributes)) return false;
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

    // Character data, a CDATA section's too: none at all in an element of empty content (not
    // even white space, nor an empty section), white space only in one of element content.
    // libxml2 2.9 refuses a CDATA section of white space in element content, later ones take it.
    bool text(const char* b, int n, bool cdata) {
        if (frames_.empty()) return true;
        if (table_.declarations[static_cast<size_t>(frames_.back().declaration)].particles.empty())
            return fail("text in an element of empty content");
        for (int k = 0; k < n; ++k)
            if (!strict::xml_space(b[k])) return fail("text where the schema allows none");
        return !cdata || fail(strict::deferred("a CDATA section in element content"));
    }

    bool finished() const { return ok() && frames_.empty() && done_root_; }
    bool ok() const { return problem.empty(); }

    // The problem as the reader reports it: a refusal, or a form the table leaves to the XSD.
    std::string verdict_line() const {
        return (deferred ? "left to the XSD by the schema's table: " : "not valid against the schema: ") + problem;
    }

    std::string problem;
    bool deferred = false;   // the problem is a form the table does not decide

private:
    struct Frame {
        int declaration;
        size_t particle;
        int count;
    };

    // The declaration of an element starting here (the next particle of its parent's sequence
    // that takes it), or -1 (then `problem`).
    int enter(const char* name) {
        if (frames_.empty()) {
            if (done_root_ || table_.declarations.empty() || table_.declarations[0].name != name) {
                fail("not the schema's root element");
                return -1;
            }
            done_root_ = true;
            return 0;
        }
        Frame& f = frames_.back();
        const auto& particles = table_.declarations[static_cast<size_t>(f.declaration)].particles;
        while (f.particle < particles.size()) {
            const StrictParticle& p = particles[f.particle];
            for (size_t k = 0; k < p.names.size(); ++k)
                if (p.names[k] == name && (p.max < 0 || f.count < p.max)) {
                    ++f.count;
                    return p.declarations[k];
                }
            if (f.count < p.min) {
                fail("an element the schema does not expect here (one it needs is missing)");
                return -1;
            }
            ++f.particle;
            f.count = 0;
        }
        fail("an element the schema does not expect here");
        return -1;
    }

    bool attributes_fit(const StrictDeclaration& d, int n_attributes, const char** attributes) {
        uint64_t seen = 0;
        size_t hint = 0;
        for (int k = 0; k < n_attributes; ++k) {
            const char* const* a = attributes + 5 * k;
            if (a[2] != nullptr) {
                if (const strict::Verdict v = namespaced(d, a[0], a[2]); v.why != nullptr) return fail(v);
                continue;
            }
            const size_t found = attribute_of(d, a[0], hint);
            hint = found + 1;
            if (found == d.attributes.size()) {
                if (d.any_attribute) continue;
                return fail("an attribute the schema does not allow");
            }
            if (const strict::Verdict v = strict::value_verdict(d.attributes[found], a[3], a[4]); v.why != nullptr)
                return fail(v.deferred ? v : strict::refused("an attribute's value the schema does not allow"));
            seen |= uint64_t(1) << found;
        }
        for (size_t j = 0; j < d.attributes.size(); ++j)
            if (d.attributes[j].required && !(seen >> j & 1)) return fail("a required attribute missing");
        return true;
    }

    // The index of the attribute named so in d (its size if none), searched from `hint`, after
    // the last one found: files list attributes in the schema's order.
    static size_t attribute_of(const StrictDeclaration& d, const char* name, size_t hint) {
        const size_t n = d.attributes.size();
        for (size_t step = 0; step < n; ++step) {
            const size_t j = (hint + step) % n;
            if (std::strcmp(d.attributes[j].name.c_str(), name) == 0) return j;
        }
        return n;
    }

    // An attribute in a namespace. The XML Schema instance's: its schema location hints the XSD
    // ignores, its type it decides (one derived from the element's own type is allowed), nil it
    // refuses (no element here is nillable). Any other only where the element takes any attribute.
    static strict::Verdict namespaced(const StrictDeclaration& d, const char* name, const char* uri) {
        const bool instance = std::strcmp(uri, kSchemaInstance) == 0;
        if (instance &&
            (std::strcmp(name, "schemaLocation") == 0 || std::strcmp(name, "noNamespaceSchemaLocation") == 0))
            return {};
        if (instance && std::strcmp(name, "type") == 0) return strict::deferred("an xsi:type");
        if (instance && std::strcmp(name, "nil") == 0)
            return strict::refused("xsi:nil on an element that is not nillable");
        return d.any_attribute ? strict::Verdict{} : strict::refused("an attribute the schema does not allow");
    }

    bool fail(const char* why) { return fail(strict::refused(why)); }
    bool fail(strict::Verdict v) {
        if (problem.empty()) problem = v.why, deferred = v.deferred;
        return false;
    }

    const StrictTable& table_;
    std::vector<Frame> frames_;
    bool done_root_ = false;
};

}  // namespace dc
