// Renders one step file (schemas/step.xsd). Formatting floats is nearly all the cost of
// writing XML, so it is done here with std::to_chars: the shortest text that reads back to
// the same float32, and byte-identical for identical inputs.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace dc {

// Borrowed pointers to the columns of a BodyState / ContactState (see world.hpp).
struct BodyView {
    size_t n = 0;
    const int32_t* index;
    const int8_t* type;
    const float *position, *angle, *center, *local_center, *velocity, *omega;
    const float *mass, *inv_mass, *inertia, *inv_inertia;
    const float *linear_damping, *angular_damping;
};

struct ContactView {
    size_t n = 0;
    const int32_t *manifold, *island;
    const int8_t *point, *point_count, *manifold_type;
    const int32_t *body_a, *body_b, *fixture_a, *fixture_b, *child_a, *child_b;
    const uint32_t* id_key;
    const float *local_normal, *local_point, *point_local;
    const float *position, *normal, *separation;
    const float *friction, *restitution, *restitution_threshold;
    const float *start_normal_impulse, *start_tangent_impulse;
    const float *normal_impulse, *tangent_impulse;
};

class StepWriter {
public:
    // root_attributes: the attributes of <step> common to every step of a simulation;
    // header: the <header> element's opening and common lines (render adds the per-step
    // extra_header and closes it); shapes[i]: the <shape> element of body i.
    StepWriter(std::string root_attributes, std::string header, std::vector<std::string> shapes,
               bool damping);
    // Raises std::domain_error naming the field if any value is NaN or infinite.
    std::string render(int64_t index, double time, float dt_ratio, const BodyView& bodies,
                       const ContactView& contacts, const std::string& extra_header) const;

private:
    std::string root_attributes_, header_;
    std::vector<std::string> shapes_;
    bool damping_;
};

// Appends the shortest round-trip text of a float32 value.
void append_float(std::string& out, float value);

}  // namespace dc
