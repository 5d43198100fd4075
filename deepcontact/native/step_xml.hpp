// Renders one step file (schemas/step.xsd). Formatting floats is nearly all the cost of
// writing XML, so it is done here with std::to_chars: the shortest text that reads back to
// the same float32, and byte-identical for identical inputs.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "records.hpp"
#include "step_names.hpp"

namespace dc {

// Borrowed pointers to the columns of a BodyState / ContactState (see world.hpp).
// Read-only views of a step's records (records.hpp), n rows each.
struct BodyView {
    size_t n = 0;
    DC_BODY_FIELDS(DC_POINTER_FIELD)
};

struct ContactView {
    size_t n = 0;
    DC_CONTACT_FIELDS(DC_POINTER_FIELD)
};

class StepWriter {
public:
    // root_attributes: the attributes of <step> common to every step of a simulation;
    // header: the <header> element's opening and common lines (render adds the per-step
    // extra_header and closes it); shapes[i]: the <shape> element of body i; damping: whether
    // the scene declares it; engine: which engine's rows the contacts hold (step_names.hpp).
    StepWriter(std::string root_attributes, std::string header, std::vector<std::string> shapes,
               bool damping, Engine engine = Engine::box2d);
    // Raises std::domain_error naming the field if any value is NaN or infinite.
    std::string render(int64_t index, double time, float dt_ratio, const BodyView& bodies,
                       const ContactView& contacts, const std::string& extra_header) const;

private:
    std::string root_attributes_, header_;
    std::vector<std::string> shapes_;
    bool damping_;
    Engine engine_;
};

// Appends the shortest round-trip text of a float32 value.
void append_float(std::string& out, float value);

}  // namespace dc
