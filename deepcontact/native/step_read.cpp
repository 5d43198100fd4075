#include "step_read.hpp"
#include "step_strict.hpp"
#include "step_names.hpp"

#include <fcntl.h>
#include <libxml/parser.h>
#include <libxml/parserInternals.h>
#include <libxml/xmlschemas.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <unordered_map>
#include <variant>

namespace dc {

const char* const kDoctypeRefused = "a DOCTYPE (DTD or entity declarations) is not allowed in deepcontact XML";

namespace {

constexpr size_t kChunk = 1 << 16;
// Far above any step we write (a 10,000-body step is 10 MB).
constexpr size_t kMaxBytes = size_t(1) << 31;
// What a compressed file may inflate to: our steps inflate about 6x, so 64x its size (and at
// least 16 MiB) refuses a small file that would fill memory long before the 2 GiB bound.
constexpr size_t kMaxRatio = 64;
constexpr size_t kMinBound = size_t(16) << 20;
constexpr int64_t kInt32Max = std::numeric_limits<int32_t>::max();

// A file read in chunks through zlib, which passes plain (uncompressed) files through as they are.
class Source {
public:
    explicit Source(const std::string& path) {
        // O_NONBLOCK: opening a FIFO must not wait for a writer; it is refused just below.
        const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
        if (fd < 0) throw StepFileError(std::string("cannot read: ") + std::strerror(errno), 0);
        struct stat st;
        if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
            ::close(fd);
            throw StepFileError("not a regular file", 0);
        }
        limit_ = kMaxBytes;
        unsigned char magic[2] = {0, 0};
        if (::pread(fd, magic, 2, 0) == 2 && magic[0] == 0x1f && magic[1] == 0x8b)
            limit_ = std::min(kMaxBytes, std::max(kMinBound, kMaxRatio * static_cast<size_t>(st.st_size)));
        gz_ = gzdopen(fd, "rb");
        if (gz_ == nullptr) {
            ::close(fd);
            throw StepFileError("cannot read: out of memory", 0);
        }
        gzbuffer(gz_, 1 << 15);   // zlib then allocates 96 kB: under malloc's mmap threshold, reused
    }
    ~Source() { gzclose_r(gz_); }
    Source(const Source&) = delete;
    Source& operator=(const Source&) = delete;

    // Up to n bytes; 0 at the end of the file. A damaged or cut compressed stream is an error.
    size_t read(char* out, size_t n) {
        const int got = gzread(gz_, out, static_cast<unsigned>(n));
        int code = Z_OK;
        const char* message = gzerror(gz_, &code);
        if (got < 0 || (code != Z_OK && code != Z_STREAM_END))
            throw StepFileError(std::string("cannot read: ") + (message && *message ? message : "read error") +
                                    (code == Z_BUF_ERROR ? " (a cut compressed file?)" : ""),
                                0);
        total_ += static_cast<size_t>(got);
        if (total_ > limit_)
            throw StepFileError(limit_ == kMaxBytes ? "more than 2 GiB of XML: not a step file"
                                                    : "inflates to more than 64 times its compressed size: not a "
                                                      "step file dc simulate --compress wrote", 0);
        return static_cast<size_t>(got);
    }

private:
    gzFile gz_ = nullptr;
    size_t total_ = 0;
    size_t limit_ = 0;
};

// --- values -------------------------------------------------------------------------------

struct Text {
    const char* begin;
    const char* end;
    std::string str() const { return std::string(begin, end); }
};

Text trimmed(const xmlChar* b, const xmlChar* e) {
    auto* p = reinterpret_cast<const char*>(b);
    auto* q = reinterpret_cast<const char*>(e);
    while (p < q && (*p == ' ' || *p == '\t' || *p == '\n' || *p == '\r')) ++p;
    while (q > p && (q[-1] == ' ' || q[-1] == '\t' || q[-1] == '\n' || q[-1] == '\r')) --q;
    return {p, q};
}

std::string shown(const Text& t) {
    std::string s = t.str();
    if (s.size() > 40) s = s.substr(0, 40) + "...";
    return "'" + s + "'";
}

// As numpy reads a float32 column: the decimal to the nearest double, then to float32.
bool parse_float(Text t, float& out) {
    const char* p = t.begin;
    if (p < t.end && *p == '+') ++p;
    double v = 0;
    auto r = std::from_chars(p, t.end, v);
    if (r.ec == std::errc::result_out_of_range) {   // beyond double: not finite either way
        out = std::numeric_limits<float>::infinity();
        return r.ptr == t.end;
    }
    if (r.ec != std::errc() || r.ptr != t.end || p == t.end) return false;
    out = static_cast<float>(v);
    return true;
}

// 0 ok, 1 not a whole number, 2 out of [low, high]
int parse_int(Text t, int64_t low, int64_t high, int64_t& out) {
    const char* p = t.begin;
    if (p < t.end && *p == '+') ++p;
    auto r = std::from_chars(p, t.end, out);
    if (r.ec == std::errc::result_out_of_range) return 2;
    if (r.ec != std::errc() || r.ptr != t.end || p == t.end) return 1;
    return out < low || out > high ? 2 : 0;
}

// "" when t is a finite float32 (then in out), else what is wrong with it.
std::string float_problem(Text t, float& out) {
    if (!parse_float(t, out)) return "is not a number: " + shown(t);
    if (!std::isfinite(out)) return "is not finite: " + shown(t);
    return "";
}

// "" when t is a whole number in [0, high] (then in out), else what is wrong with it.
std::string whole_problem(Text t, int64_t high, int64_t& out) {
    switch (parse_int(t, 0, high, out)) {
        case 0: return "";
        case 1: return "must be a whole number, got " + shown(t);
        default: return "is out of range: must be between 0 and " + std::to_string(high) + ", got " + shown(t);
    }
}

template <typename T>
constexpr int64_t high_of() {
    return std::is_same_v<T, uint32_t> ? int64_t(std::numeric_limits<uint32_t>::max())
                                       : std::min<int64_t>(std::numeric_limits<T>::max(), kInt32Max);
}

// --- the field tables: which attribute of which element fills which column -----------------

template <class State>
struct EnumColumn {
    std::vector<int8_t> State::*column;
    const char* const* names;
    int count;
};

template <class State>
using Column = std::variant<std::vector<float> State::*, std::vector<int8_t> State::*,
                            std::vector<int32_t> State::*, std::vector<uint32_t> State::*, EnumColumn<State>>;

template <class State>
struct Field {
    const char* element;   // "." for an attribute of the row element itself
    const char* attr;
    Column<State> column;
    int width = 1, component = 0;
    Presence presence = Presence::always;   // whether every row of a file holds it (step_names.hpp)
};

struct BodyWidths {
    DC_BODY_FIELDS(DC_WIDTH_FIELD)
};
struct ContactWidths {
    DC_CONTACT_FIELDS(DC_WIDTH_FIELD)
};

// A column of a record, or an enumerated one read by its names.
template <class State, class T>
Column<State> column_of(std::vector<T> State::*member, const char* const* names) {
    if constexpr (std::is_same_v<T, int8_t>)
        if (names != nullptr) return EnumColumn<State>{member, names, kEnumNames};
    return member;
}

// The field tables, from the step file's names (step_names.hpp).
#define DC_READ(State, Widths, element, attr, field, component, presence, names)                      \
    Field<State>{element, attr, column_of<State>(&State::field, names), Widths::field, component,     \
                 Presence::presence},
const Field<BodyState> kBodyFields[] = {DC_BODY_XML(DC_READ, BodyState, BodyWidths)};
const Field<ContactState> kContactFields[] = {DC_CONTACT_XML(DC_READ, ContactState, ContactWidths)};
#undef DC_READ
static_assert(std::size(kContactFields) <= 64 && std::size(kBodyFields) <= 64, "one bit per field");

bool named(const xmlChar* name, const char* want) {
    return std::strcmp(reinterpret_cast<const char*>(name), want) == 0;
}

// Attributes of a SAX2 start tag: (localname, prefix, URI, value, end) five at a time.
struct Attribute {
    const xmlChar* name;
    Text value;
};

template <class F>
void for_each_attribute(int count, const xmlChar** attributes, F&& f) {
    for (int i = 0; i < count; ++i) {
        const xmlChar** a = attributes + 5 * i;
        f(Attribute{a[0], trimmed(a[3], a[4])});
    }
}

// Rows of one record kind filled from its field table, checked as each row ends.
template <class State>
class Rows {
public:
    template <size_t N>
    Rows(const Field<State> (&fields)[N], const char* row_element) : fields_(fields), count_(N), row_(row_element) {
        require(Engine::box2d);
    }

    // The fields every row of a step of this engine holds (the others may be left out: 0).
    void require(Engine engine) {
        required_ = 0;
        for (size_t i = 0; i < count_; ++i)
            if (required_in(fields_[i].presence, engine)) required_ |= uint64_t(1) << i;
    }

    // A new row (the next of this file's rows).
    void begin(State& s) {
        seen_ = 0;
        row_index_ = rows_++;
        for (size_t i = 0; i < count_; ++i)
            std::visit([&](auto column) { resize(s, column, rows_ * fields_[i].width); }, fields_[i].column);
    }

    size_t rows() const { return rows_; }
    const char* row_element() const { return row_; }

    // Where the list (<bodies>, <contacts>) and the row being read start, and the list's count.
    long list_line = -1, row_line = 0;
    int64_t list_count = 0;

    // Attribute names as the parser's dictionary holds them: the parser hands every name over
    // interned, so an attribute is matched by address, not by comparing strings.
    void intern(xmlDictPtr dict) {
        attr_names_.resize(count_);
        for (size_t i = 0; i < count_; ++i)
            attr_names_[i] = xmlDictLookup(dict, reinterpret_cast<const xmlChar*>(fields_[i].attr), -1);
    }

    void reserve(State& s, size_t rows) {
        for (size_t i = 0; i < count_; ++i)
            std::visit([&](auto column) { reserve(s, column, rows * fields_[i].width); }, fields_[i].column);
    }

    // The fields of one element: [first, last) of the table (grouped by element). Element names
    // come interned from the parser's dictionary, so they are remembered by address.
    std::pair<size_t, size_t> group(const char* element) {
        for (const auto& [name, range] : groups_)
            if (name == element) return range;
        size_t first = 0;
        while (first < count_ && std::strcmp(fields_[first].element, element) != 0) ++first;
        size_t last = first;
        while (last < count_ && std::strcmp(fields_[last].element, element) == 0) ++last;
        if (groups_.size() < 64) groups_.emplace_back(element, std::pair{first, last});
        return {first, last};
    }

    // Fills the column an attribute of an element of `group` names; returns an error message or "".
    std::string set(State& s, std::pair<size_t, size_t> group, const Attribute& a) {
        for (size_t i = group.first; i < group.second; ++i) {
            const Field<State>& f = fields_[i];
            if (a.name != attr_names_[i]) continue;
            const uint64_t bit = uint64_t(1) << i;
            if (seen_ & bit) return describe(f) + "> is given twice in " + row_ + " " + std::to_string(row_index_);
            seen_ |= bit;
            const size_t at = row_index_ * f.width + f.component;
            return std::visit([&](auto column) { return store(s, column, at, f, a.value); }, f.column);
        }
        return "";
    }

    // "" if every required field was given in this row.
    std::string missing() const {
        if ((seen_ & required_) == required_) return "";
        for (size_t i = 0; i < count_; ++i)
            if ((required_ >> i & 1) && !(seen_ >> i & 1))
                return std::string(row_) + " " + std::to_string(row_index_) + " has no " + describe(fields_[i]) + "=...>";
        return "";
    }

private:
    template <typename T>
    static void resize(State& s, std::vector<T> State::*column, size_t n) {
        (s.*column).resize(n, T(0));
    }
    static void resize(State& s, EnumColumn<State> e, size_t n) { (s.*e.column).resize(n, int8_t(0)); }
    template <typename T>
    static void reserve(State& s, std::vector<T> State::*column, size_t n) {
        (s.*column).reserve(n);
    }
    static void reserve(State& s, EnumColumn<State> e, size_t n) { (s.*e.column).reserve(n); }

    std::string describe(const Field<State>& f) const {
        return std::string("<") + (std::strcmp(f.element, ".") == 0 ? row_ : f.element) + " " + f.attr;
    }

    // "<impulse n> of contact 3 " and what is wrong, or "" when nothing is
    std::string in_row(const Field<State>& f, const std::string& problem) const {
        if (problem.empty()) return "";
        return describe(f) + "> of " + row_ + " " + std::to_string(row_index_) + " " + problem;
    }

    std::string store(State& s, std::vector<float> State::*column, size_t at, const Field<State>& f, Text t) const {
        float v;
        std::string problem = float_problem(t, v);
        if (problem.empty()) (s.*column)[at] = v;
        return in_row(f, problem);
    }

    template <typename T>
    std::string store(State& s, std::vector<T> State::*column, size_t at, const Field<State>& f, Text t) const {
        int64_t v = 0;
        std::string problem = whole_problem(t, high_of<T>(), v);
        if (problem.empty()) (s.*column)[at] = static_cast<T>(v);
        return in_row(f, problem);
    }

    std::string store(State& s, EnumColumn<State> e, size_t at, const Field<State>& f, Text t) const {
        for (int k = 0; k < e.count; ++k)
            if (t.str() == e.names[k]) {
                (s.*e.column)[at] = static_cast<int8_t>(k);
                return "";
            }
        return in_row(f, "has an unknown value " + shown(t));
    }

    const Field<State>* fields_;
    size_t count_;
    const char* row_;
    uint64_t required_ = 0, seen_ = 0;
    size_t row_index_ = 0, rows_ = 0;
    std::vector<std::pair<const char*, std::pair<size_t, size_t>>> groups_;
    std::vector<const xmlChar*> attr_names_;
};

// --- the SAX2 reader ------------------------------------------------------------------------

enum class At : uint8_t { Outside, Step, Header, Bodies, Body, Shape, Contacts, Contact, Other };

// What a <header> must hold (a <solve> line may follow them): 2.4.1's <iterations> or v3's
// <soft_step>, as <solver name> says.
const char* const kHeaderParts[] = {"gravity", "iterations", "solver", "soft_step", "effects", "versions", "engine"};
constexpr uint32_t kIterationsPart = 1u << 1, kSoftStepPart = 1u << 3, kEnginePart = 1u << 6;

struct Problem {
    std::string message;
    long line = 0, column = 0;
};

// Where the parser is; thread_local because libxml2 hands the error callback the plugged
// validator's data, not ours.
thread_local struct Reader* t_reader = nullptr;

struct Reader {
    enum Mode { Read, RootOnly };
    Mode mode;
    xmlParserCtxtPtr ctxt = nullptr;
    StepFile out;
    std::vector<At> stack{At::Outside};
    Rows<BodyState> bodies{kBodyFields, "body"};
    Rows<ContactState> contacts{kContactFields, "contact"};
    std::unordered_map<int64_t, float> radius;   // fixture -> collision radius
    long header_line = 0;
    uint32_t header_seen = 0;
    bool root_seen = false;
    // root element attributes, for validation
    std::string root;
    Problem problem;              // the reader's own first error (stops the parse)
    Problem syntax;               // the parser's first fatal error
    std::vector<SchemaIssue> schema_errors;
    size_t max_errors = 1;
    StrictCheck* strict = nullptr;   // the schema's table, checked as the file is read (or none)

    explicit Reader(Mode m) : mode(m) {}

    long line() const { return ctxt ? xmlSAX2GetLineNumber(ctxt) : 0; }

    Engine engine() const {
        const auto name = out.header.solver.find("name");
        return engine_rows(name != out.header.solver.end() ? name->second : std::string("box2d"));
    }

    void fail(std::string message, long at = -1) {
        if (problem.message.empty()) problem = {std::move(message), at < 0 ? line() : at, 0};
        xmlStopParser(ctxt);
    }

    void start(const xmlChar* name, int n_attributes, const xmlChar** attributes) {
        const At parent = problem.message.empty() ? stack.back() : At::Other;   // after a problem: nothing more
        At here = At::Other;
        switch (parent) {
            case At::Outside: here = step(name, n_attributes, attributes); break;
            case At::Step:
                if (mode == RootOnly) break;
                if (named(name, "header")) {
                    here = At::Header;
                    header_line = line();
                } else if (named(name, "bodies")) {
                    here = At::Bodies;
                    open_list(bodies, out.bodies, name, n_attributes, attributes);
                    out.bodies.gravity_scale.reserve(out.bodies.index.capacity());   // (not a field of the file)
                } else if (named(name, "contacts")) {
                    here = At::Contacts;
                    open_list(contacts, out.contacts, name, n_attributes, attributes);
                }
                break;
            case At::Header: header(name, n_attributes, attributes); break;
            case At::Bodies:
                if (named(name, "body")) {
                    here = At::Body;
                    out.bodies.gravity_scale.push_back(1.0f);   // scenes have no per-body gravity scale
                    open_row(bodies, out.bodies, n_attributes, attributes);
                }
                break;
            case At::Body:
                if (named(name, "shape"))
                    here = At::Shape;
                else
                    row(bodies, out.bodies, reinterpret_cast<const char*>(name), n_attributes, attributes);
                break;
            case At::Shape: shape(name, n_attributes, attributes); break;
            case At::Contacts:
                if (named(name, "contact")) {
                    here = At::Contact;
                    open_row(contacts, out.contacts, n_attributes, attributes);
                }
                break;
            case At::Contact:
                row(contacts, out.contacts, reinterpret_cast<const char*>(name), n_attributes, attributes);
                break;
            case At::Other: break;
        }
        stack.push_back(here);
    }

    void end() {
        if (stack.size() < 2) return;   // (never: every start pushed one)
        const At here = stack.back();
        stack.pop_back();
        if (!problem.message.empty()) return;
        if (here == At::Body) close_row(bodies);
        if (here == At::Contact) close_row(contacts);
        if (here == At::Bodies) close_list(bodies);
        if (here == At::Contacts) close_list(contacts);
    }

    // A list's start: its count (checked at its end) and the rows it is to hold reserved ahead,
    // which saves regrowing every column.
    template <class State>
    void open_list(Rows<State>& rows, State& s, const xmlChar* name, int n, const xmlChar** attributes) {
        rows.list_line = line();
        rows.list_count = count_of(name, n, attributes);
        rows.require(engine());
        if (rows.list_count > 0) rows.reserve(s, static_cast<size_t>(std::min<int64_t>(rows.list_count, 1 << 20)));
    }

    template <class State>
    void open_row(Rows<State>& rows, State& s, int n, const xmlChar** attributes) {
        rows.row_line = line();
        rows.begin(s);
        row(rows, s, ".", n, attributes);
    }

    template <class State>
    void close_row(const Rows<State>& rows) {
        std::string m = rows.missing();
        if (!m.empty()) fail(m, rows.row_line);
    }

    template <class State>
    void close_list(const Rows<State>& rows) {
        if (static_cast<size_t>(rows.list_count) == rows.rows()) return;
        const std::string row = rows.row_element();
        fail("<" + row + "s count=\"" + std::to_string(rows.list_count) + "\"> but it holds " +
                 std::to_string(rows.rows()) + " <" + row + "> elements",
             rows.list_line);
    }

    template <class State>
    void row(Rows<State>& rows, State& s, const char* element, int n, const xmlChar** attributes) {
        const auto group = rows.group(element);
        if (group.first == group.second) return;   // not a field of ours (the schema's business)
        for_each_attribute(n, attributes, [&](const Attribute& a) {
            if (!problem.message.empty()) return;
            std::string m = rows.set(s, group, a);
            if (!m.empty()) fail(m);
        });
    }

    At step(const xmlChar* name, int n, const xmlChar** attributes) {
        root = reinterpret_cast<const char*>(name);
        root_seen = true;
        if (!named(name, "step")) {
            if (mode == Read) fail("root element is <" + root + ">, not <step>");
            return At::Other;
        }
        StepHeader& h = out.header;
        bool seed = false, index = false, time = false, dt = false, ratio = false;
        for_each_attribute(n, attributes, [&](const Attribute& a) {
            if (named(a.name, "scene")) {
                h.has_scene = true;
                h.scene = a.value.str();   // as given: the schema's token type is checked by validation
            } else if (named(a.name, "seed") && mode == RootOnly) {   // a bad one is the schema's to report
                seed = whole_problem(a.value, kInt32Max, h.seed).empty();
            } else if (named(a.name, "seed")) {
                seed = whole(h.seed, "step", "seed", a.value);
            } else if (mode == RootOnly) {
                return;
            } else if (named(a.name, "index")) {
                index = whole(h.index, "step", "index", a.value);
            } else if (named(a.name, "time")) {
                time = finite(h.time, "step", "time", a.value);
            } else if (named(a.name, "dt")) {
                dt = finite(h.dt, "step", "dt", a.value);
            } else if (named(a.name, "dt_ratio")) {
                ratio = finite(h.dt_ratio, "step", "dt_ratio", a.value);
            }
        });
        if (mode == RootOnly) {
            if (!seed) h.seed = -1;
            return At::Step;
        }
        const char* lacking = !seed ? "seed" : !index ? "index" : !time ? "time" : !dt ? "dt" : !ratio ? "dt_ratio" : nullptr;
        if (lacking && problem.message.empty()) fail(std::string("<step> has no ") + lacking + "=...");
        return At::Step;
    }

    int64_t count_of(const xmlChar* name, int n, const xmlChar** attributes) {
        int64_t v = -1;
        for_each_attribute(n, attributes, [&](const Attribute& a) {
            if (named(a.name, "count")) whole(v, reinterpret_cast<const char*>(name), "count", a.value);
        });
        if (v < 0 && problem.message.empty())
            fail(std::string("<") + reinterpret_cast<const char*>(name) + "> has no count=...");
        return v;
    }

    void header(const xmlChar* name, int n, const xmlChar** attributes) {
        StepHeader& h = out.header;
        auto copy = [&](Attributes& into) {
            for_each_attribute(n, attributes, [&](const Attribute& a) {
                into[reinterpret_cast<const char*>(a.name)] = a.value.str();
            });
        };
        if (named(name, "solve")) {   // written only where the project's solver stepped the world
            h.has_solve = true;
            return copy(h.solve);
        }
        for (size_t k = 0; k < std::size(kHeaderParts); ++k)
            if (named(name, kHeaderParts[k])) header_seen |= 1u << k;
        bool x = false, y = false;
        if (named(name, "gravity")) {
            for_each_attribute(n, attributes, [&](const Attribute& a) {
                if (named(a.name, "x")) x = finite(h.gravity[0], "gravity", "x", a.value);
                if (named(a.name, "y")) y = finite(h.gravity[1], "gravity", "y", a.value);
            });
            if (!(x && y) && problem.message.empty()) fail("<gravity> lacks x or y");
        } else if (named(name, "iterations")) {
            h.has_iterations = true;
            for_each_attribute(n, attributes, [&](const Attribute& a) {
                if (named(a.name, "velocity")) x = whole(h.velocity_iterations, "iterations", "velocity", a.value);
                if (named(a.name, "position")) y = whole(h.position_iterations, "iterations", "position", a.value);
            });
            if (!(x && y) && problem.message.empty()) fail("<iterations> lacks velocity or position");
        } else {
            for (const auto& [element, part] : kAttributeParts)
                if (named(name, element)) return copy(h.*part);
        }
    }

    // The header's elements kept whole, as their attributes' names and values.
    static constexpr std::pair<const char*, Attributes StepHeader::*> kAttributeParts[] = {
        {"solver", &StepHeader::solver},     {"soft_step", &StepHeader::soft_step},
        {"effects", &StepHeader::effects},   {"versions", &StepHeader::versions},
        {"engine", &StepHeader::engine},     {"engine_step", &StepHeader::engine_step}};

    void shape(const xmlChar* name, int n, const xmlChar** attributes) {
        if (!(named(name, "circle") || named(name, "polygon") || named(name, "edge"))) return;
        int64_t fixture = -1;
        float r = 0;
        bool has_radius = false;
        const char* what = reinterpret_cast<const char*>(name);
        for_each_attribute(n, attributes, [&](const Attribute& a) {
            if (named(a.name, "fixture")) whole(fixture, what, "fixture", a.value);
            if (named(a.name, "radius")) has_radius = finite(r, what, "radius", a.value);
        });
        if ((fixture < 0 || !has_radius) && problem.message.empty())
            fail(std::string("<") + what + "> needs both fixture=... and radius=... in a step file");
        radius[fixture] = r;
    }

    // A value outside the record tables: fails naming <element attr> unless the check passes.
    bool checked(const std::string& problem, const char* element, const char* attr) {
        if (!problem.empty()) fail(std::string("<") + element + " " + attr + "> " + problem);
        return problem.empty();
    }

    bool whole(int64_t& out_value, const char* element, const char* attr, Text t) {
        return checked(whole_problem(t, kInt32Max, out_value), element, attr);
    }

    bool finite(float& out_value, const char* element, const char* attr, Text t) {
        return checked(float_problem(t, out_value), element, attr);
    }

    // After the parse: what a step must have, and each contact's shape radii.
    void finish() {
        if (!problem.message.empty()) return;
        if (header_line == 0) return fail("<step> has no <header>", 1);
        // (each engine's own part: 2.4.1's <iterations>, v3's <soft_step>, another engine's <engine>)
        const uint32_t other_engine = engine() == Engine::box2d3 ? kIterationsPart | kEnginePart
                                      : engine() == Engine::box2d ? kSoftStepPart | kEnginePart
                                                                  : kIterationsPart | kSoftStepPart;
        for (size_t k = 0; k < std::size(kHeaderParts); ++k)
            if (!(header_seen >> k & 1) && !(other_engine >> k & 1))
                return fail(std::string("<header> has no <") + kHeaderParts[k] + ">", header_line);
        if (bodies.list_line < 0) return fail("no <bodies> element", 1);
        if (contacts.list_line < 0) return fail("no <contacts> element", 1);
        ContactState& c = out.contacts;
        const size_t n = c.manifold.size();
        c.radius_a.resize(n);
        c.radius_b.resize(n);
        for (size_t k = 0; k < n; ++k) {
            for (auto [fixture, r] : {std::pair{c.fixture_a[k], &c.radius_a[k]}, std::pair{c.fixture_b[k], &c.radius_b[k]}}) {
                auto found = radius.find(fixture);
                if (found == radius.end())
                    return fail("a contact names fixture " + std::to_string(fixture) + ", which no body has", 0);
                *r = found->second;
            }
        }
    }
};

Reader* reader_of(void* data) { return static_cast<Reader*>(data); }

void on_start(void* data, const xmlChar* name, const xmlChar*, const xmlChar* uri, int, const xmlChar**,
              int n_attributes, int, const xmlChar** attributes) {
    Reader* r = reader_of(data);
    if (r->strict != nullptr && r->problem.message.empty() &&
        !r->strict->start(reinterpret_cast<const char*>(name), reinterpret_cast<const char*>(uri), n_attributes,
                          reinterpret_cast<const char**>(attributes)))
        r->fail(r->strict->verdict_line());
    r->start(name, n_attributes, attributes);
}

void on_end(void* data, const xmlChar*, const xmlChar*, const xmlChar*) {
    Reader* r = reader_of(data);
    if (r->strict != nullptr && r->problem.message.empty() && !r->strict->end())
        r->fail(r->strict->verdict_line());
    r->end();
}

void on_text(void* data, const xmlChar* text, int n, bool cdata) {
    Reader* r = reader_of(data);
    if (r->strict != nullptr && r->problem.message.empty() &&
        !r->strict->text(reinterpret_cast<const char*>(text), n, cdata))
        r->fail(r->strict->verdict_line());
}

void on_characters(void* data, const xmlChar* text, int n) { on_text(data, text, n, false); }
void on_cdata(void* data, const xmlChar* text, int n) { on_text(data, text, n, true); }

void on_doctype(void*, const xmlChar*, const xmlChar*, const xmlChar*) {
    // Entities would hide values from the schema (or read other files): refused outright.
    if (t_reader) t_reader->fail(kDoctypeRefused);
}

std::string message_of(const xmlError* e) {
    std::string m = e->message ? e->message : "malformed XML";
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    return m;
}

void on_syntax_error(void*, xmlErrorPtr e) {
    Reader* r = t_reader;
    if (r == nullptr || e == nullptr || e->level < XML_ERR_ERROR) return;
    if (e->domain == XML_FROM_SCHEMASV) {   // the plugged validator reports through here too
        if (r->schema_errors.size() < r->max_errors)
            r->schema_errors.push_back({static_cast<long>(e->line), static_cast<long>(e->int2), message_of(e)});
        return;
    }
    if (r->syntax.message.empty()) r->syntax = {message_of(e), static_cast<long>(e->line), static_cast<long>(e->int2)};
}

void on_schema_error(void* data, xmlErrorPtr e) {
    Reader* r = reader_of(data);
    if (e == nullptr || e->level < XML_ERR_ERROR || r->schema_errors.size() >= r->max_errors) return;
    long line = e->line;
    if (line == 0 && r->ctxt) line = xmlSAX2GetLineNumber(r->ctxt);
    r->schema_errors.push_back({line, static_cast<long>(e->int2), message_of(e)});
}

// The parser's input: bytes already read (for sniffing) first, then the rest of the file.
// libxml2 calls read() from C, so an error is kept here and reported after the parse.
struct Input {
    Source& source;
    std::string head;
    size_t served = 0;
    std::string error;

    static int read(void* context, char* out, int n) {
        auto* in = static_cast<Input*>(context);
        if (in->served < in->head.size()) {
            const size_t k = std::min(in->head.size() - in->served, static_cast<size_t>(n));
            std::memcpy(out, in->head.data() + in->served, k);
            in->served += k;
            return static_cast<int>(k);
        }
        try {
            return static_cast<int>(in->source.read(out, static_cast<size_t>(n)));
        } catch (const std::exception& e) {
            in->error = e.what();
            return -1;
        }
    }
};

// Parses the file (`head`: bytes already read from it), with the schema's validator plugged in
// if given: libxml2's pull parser reading through zlib, which streams without the push
// parser's look-ahead. Stops at the reader's first problem or the first well-formedness error.
void parse(Reader& reader, const StepSchema* schema, Source& source, std::string head) {
    xmlSAXHandler handler;
    std::memset(&handler, 0, sizeof handler);
    handler.initialized = XML_SAX2_MAGIC;
    handler.startElementNs = on_start;
    handler.endElementNs = on_end;
    handler.internalSubset = on_doctype;
    handler.serror = on_syntax_error;
    if (reader.strict != nullptr) {   // (text matters only to the table: without it, never read)
        handler.characters = on_characters;
        handler.cdataBlock = on_cdata;
    }
    xmlSAXHandlerPtr sax = &handler;
    void* data = &reader;

    std::unique_ptr<xmlSchemaValidCtxt, void (*)(xmlSchemaValidCtxtPtr)> valid(nullptr, xmlSchemaFreeValidCtxt);
    std::unique_ptr<xmlSchemaSAXPlugStruct, int (*)(xmlSchemaSAXPlugPtr)> plug(nullptr, xmlSchemaSAXUnplug);
    if (schema != nullptr) {
        valid.reset(xmlSchemaNewValidCtxt(schema->get()));
        if (!valid) throw std::bad_alloc();
        xmlSchemaSetValidStructuredErrors(valid.get(), on_schema_error, &reader);
        plug.reset(xmlSchemaSAXPlug(valid.get(), &sax, &data));
        if (!plug) throw std::runtime_error("cannot plug the schema validator into the parser");
    }
    Input input{source, std::move(head)};
    // Declared after the plug: freed before it is unplugged.
    std::unique_ptr<xmlParserCtxt, void (*)(xmlParserCtxtPtr)> ctxt(
        xmlCreateIOParserCtxt(sax, data, Input::read, nullptr, &input, XML_CHAR_ENCODING_NONE), xmlFreeParserCtxt);
    if (!ctxt) throw std::bad_alloc();
    // No network and no DTD loading. NOENT: the predefined entities and character references
    // in attribute values are decoded (without it SAX2 hands "&amp;" over as "&#38;", so a scene
    // named "a&b" read back as another name); no other entity can be declared (a DOCTYPE is refused).
    xmlCtxtUseOptions(ctxt.get(), XML_PARSE_NONET | XML_PARSE_NOENT);
    // The plugged validator's handler has no error callback of its own: ours, on the copy the
    // parser uses, so that nothing is printed and every well-formedness error is kept.
    ctxt->sax->serror = on_syntax_error;
    reader.ctxt = ctxt.get();
    reader.bodies.intern(ctxt->dict);
    reader.contacts.intern(ctxt->dict);
    t_reader = &reader;
    struct Reset {
        Reader& r;
        ~Reset() {
            t_reader = nullptr;
            r.ctxt = nullptr;
        }
    } reset{reader};
    xmlParseDocument(ctxt.get());
    if (!input.error.empty()) throw StepFileError(input.error, 0);
    if (!ctxt->wellFormed && reader.syntax.message.empty()) {
        const xmlError* e = xmlCtxtGetLastError(ctxt.get());
        reader.syntax = {e ? message_of(e) : "malformed XML", e ? static_cast<long>(e->line) : 0,
                         e ? static_cast<long>(e->int2) : 0};
    }
}

// The first bytes of a file, and the name of its root element as far as they tell
// ("" where they do not): what a validator needs to pick the schema before parsing.
std::string root_name(const std::string& head) {
    size_t i = 0;
    if (head.compare(0, 3, "\xEF\xBB\xBF") == 0) i = 3;
    while (i < head.size()) {
        while (i < head.size() && std::strchr(" \t\r\n", head[i]) && head[i]) ++i;
        if (i >= head.size() || head[i] != '<') return "";
        if (head.compare(i, 4, "<!--") == 0) {
            const size_t e = head.find("-->", i + 4);
            if (e == std::string::npos) return "";
            i = e + 3;
        } else if (head.compare(i, 2, "<?") == 0) {
            const size_t e = head.find("?>", i + 2);
            if (e == std::string::npos) return "";
            i = e + 2;
        } else if (head.compare(i, 2, "<!") == 0) {
            return "!DOCTYPE";
        } else {
            size_t e = i + 1;
            while (e < head.size() && !std::strchr(" \t\r\n/>", head[e])) ++e;
            return head.substr(i + 1, e - i - 1);
        }
    }
    return "";
}

std::string read_head(Source& source) {
    std::string head(kChunk, '\0');
    head.resize(source.read(head.data(), head.size()));
    return head;
}

}  // namespace

StepSchema::StepSchema(const std::string& xsd_path) {
    xmlSchemaParserCtxtPtr p = xmlSchemaNewParserCtxt(xsd_path.c_str());
    if (p == nullptr) throw std::runtime_error("cannot read the schema " + xsd_path);
    schema_ = xmlSchemaParse(p);
    xmlSchemaFreeParserCtxt(p);
    if (schema_ == nullptr) throw std::runtime_error("cannot compile the schema " + xsd_path);
}

StepSchema::~StepSchema() { xmlSchemaFree(schema_); }

StepFile read_step_file(const std::string& path, const StepSchema* schema, const StrictTable* strict) {
    Source source(path);
    Reader reader(Reader::Read);
    std::unique_ptr<StrictCheck> check;
    if (strict != nullptr && schema == nullptr) {
        check = std::make_unique<StrictCheck>(*strict);
        reader.strict = check.get();
    }
    parse(reader, schema, source, std::string());
    if (check && reader.problem.message.empty() && reader.syntax.message.empty() && !check->finished())
        throw StepFileError(
            check->ok() ? std::string("not valid against the schema: it ends early") : check->verdict_line(), 0);
    if (!reader.schema_errors.empty()) {   // the schema's first complaint, where it came first
        const SchemaIssue& e = reader.schema_errors.front();
        if (reader.problem.message.empty() || e.line <= reader.problem.line) throw StepFileError(e.message, e.line);
    }
    if (!reader.syntax.message.empty())
        throw StepFileError("not a well-formed step file: " + reader.syntax.message, reader.syntax.line);
    if (!reader.root_seen && reader.problem.message.empty()) throw StepFileError("not a step file: no root element", 1);
    reader.finish();
    if (!reader.problem.message.empty()) throw StepFileError(reader.problem.message, reader.problem.line);
    return std::move(reader.out);
}

TableVerdict check_step_table(const std::string& path, const StrictTable& table) {
    Source source(path);
    Reader reader(Reader::RootOnly);   // (the root's attributes only: no record's own checks)
    StrictCheck check(table);
    reader.strict = &check;
    parse(reader, nullptr, source, std::string());
    if (!reader.problem.message.empty()) return {reader.problem.message, !check.ok() && check.deferred};
    if (!reader.syntax.message.empty()) return {"not a well-formed step file: " + reader.syntax.message, false};
    if (!check.finished()) return {"not valid against the schema: it ends early", false};
    return {};
}

Validation validate_step_file(const std::string& path, const StepSchema& schema, size_t max_errors) {
    Validation v;
    Source source(path);
    std::string head = read_head(source);
    v.root = root_name(head);
    if (!v.root.empty() && v.root != "step") return v;
    Reader reader(Reader::RootOnly);
    reader.max_errors = max_errors;
    parse(reader, &schema, source, std::move(head));
    if (!reader.root.empty()) v.root = reader.root;
    v.has_scene = reader.out.header.has_scene;
    v.scene = reader.out.header.scene;
    v.seed = reader.out.header.seed;
    if (!reader.problem.message.empty())
        v.errors.push_back({reader.problem.line, reader.problem.column, reader.problem.message});
    if (!reader.syntax.message.empty()) {
        v.errors.push_back({reader.syntax.line, reader.syntax.column, reader.syntax.message});
        v.seed = -1;
    }
    for (auto& e : reader.schema_errors) v.errors.push_back(std::move(e));
    if (v.errors.empty() && !reader.root_seen) v.errors.push_back({1, 0, "Document is empty"});
    return v;
}

}  // namespace dc
