// Reads step files (schemas/step.xsd) back into the records the writer renders (records.hpp),
// streaming: libxml2's SAX2 push parser fed in chunks from zlib (a `.xml.gz` file and a plain
// one read alike), no tree, no XPath. With a schema, the same pass validates against the XSD
// (xmlSchemaSAXPlug). The lxml reader in deepcontact/step/reader_lxml.py is the reference this
// is tested against, value for value.
#pragma once

#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "world.hpp"

typedef struct _xmlSchema xmlSchema;

namespace dc {

// Bad input: what is wrong and the line it is on (0: the file as a whole).
struct StepFileError : std::runtime_error {
    StepFileError(const std::string& message, long line) : std::runtime_error(message), line(line) {}
    long line;
};

extern const char* const kDoctypeRefused;

using Attributes = std::map<std::string, std::string>;

struct StepHeader {
    bool has_scene = false;
    std::string scene;
    int64_t seed = 0, index = 0;
    float time = 0, dt = 0, dt_ratio = 0;
    float gravity[2] = {0, 0};
    bool has_iterations = false;   // (a v3 step has none: its <soft_step> says how it stepped)
    int64_t velocity_iterations = 0, position_iterations = 0;
    Attributes solver, effects, versions;
    Attributes soft_step;   // <soft_step>: a Box2D v3 step's settings (empty for 2.4.1)
    Attributes engine;      // <engine>: another engine's name, version and settings (empty for Box2D's)
    Attributes engine_step; // <engine_step>: that engine's own account of the step's solve
    bool has_solve = false;
    Attributes solve;       // <solve>: how the project's solver stepped it (iterations, residual, ...)
};

struct StepFile {
    StepHeader header;
    BodyState bodies;       // fixed_rotation is not in step files and stays empty
    ContactState contacts;
};

// A compiled XSD (schemas/step.xsd), shared read-only by every validation.
class StepSchema {
public:
    explicit StepSchema(const std::string& xsd_path);
    ~StepSchema();
    StepSchema(const StepSchema&) = delete;
    StepSchema& operator=(const StepSchema&) = delete;
    xmlSchema* get() const { return schema_; }

private:
    xmlSchema* schema_ = nullptr;
};

struct SchemaIssue {
    long line, column;
    std::string message;
};

struct Validation {
    std::string root;            // the root element's name ("!DOCTYPE" if a DOCTYPE comes first)
    bool has_scene = false;
    std::string scene;           // <step scene=...>, where given
    int64_t seed = -1;           // <step seed=...>, where a whole number
    std::vector<SchemaIssue> errors;   // well-formedness, then schema errors, in file order
};

struct StrictTable;

// The whole step; throws StepFileError (file problems, bad values, a schema error when schema
// is given; with strict, the first thing the schema's table refuses: the XSD then says what,
// step_strict.hpp). Reading never blocks on a FIFO: anything but a regular file is refused.
StepFile read_step_file(const std::string& path, const StepSchema* schema, const StrictTable* strict = nullptr);

// The schema's table's own verdict on a file, no record read (what the tests hold to the XSD's).
struct TableVerdict {
    std::string problem;     // "" when the table accepts the file, else its first problem
    bool deferred = false;   // the problem is a form the table leaves to the XSD
};
TableVerdict check_step_table(const std::string& path, const StrictTable& table);

// Checks one file against the schema in one streaming pass. Only files whose root is <step>
// are parsed; for any other root, `root` says what it is and nothing else is filled in.
Validation validate_step_file(const std::string& path, const StepSchema& schema, size_t max_errors);

}  // namespace dc
