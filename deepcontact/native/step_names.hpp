// The step file's names: which attribute of which element holds which field of a record
// (records.hpp), one table per record, in the order the file writes them. The writer
// (step_xml.cpp), the native reader (step_read.cpp) and, through the module, the lxml reference
// reader (step/reader_lxml.py) all take their names from here: a new recorded field is a row
// here and one in records.hpp.
//
// X(..., element, attribute, field, component, presence, names): a table is expanded as
// DC_BODY_XML(X, ...), each row handing X the arguments after X first
//   element    "." for an attribute of the row element (<body>, <contact>) itself
//   component  which value of a 2-wide field (0: x, 1: y)
//   presence   always; nonzero: the element is written only where one of its values is not 0;
//              declared: only when the scene declares the effect (damping); box2d, box2d3: only
//              in the steps of that engine (2.4.1's warm start and local manifold; v3's total
//              impulse and anchors)
//   names      for an enumerated field, its names in order (else nullptr)
#pragma once

#include <cstdint>
#include <string>

namespace dc {

enum class Presence : int8_t { always, nonzero, declared, box2d, box2d3 };

// Whose own rows a step file holds, by its <solver name> (step/engines.py: rows_of): Box2D
// 2.4.1's, v3's, or another engine's (own: the rows every engine records, and no more).
enum class Engine : int8_t { box2d, box2d3, own };

// The rows of the engine a <solver name> names.
inline Engine engine_rows(const std::string& solver_name) {
    if (solver_name == "box2d" || solver_name == "pgs") return Engine::box2d;
    return solver_name == "box2d3" ? Engine::box2d3 : Engine::own;
}

// Whether a row of the given presence is in every file of an engine (nonzero and declared rows
// are decided per row or per scene).
constexpr bool required_in(Presence p, Engine e) {
    return p == Presence::always || (p == Presence::box2d && e == Engine::box2d) ||
           (p == Presence::box2d3 && e == Engine::box2d3);
}

inline const char* const kBodyTypeNames[] = {"static", "kinematic", "dynamic"};
inline const char* const kManifoldTypeNames[] = {"circles", "face_a", "face_b"};
inline constexpr int kEnumNames = 3;   // names in each of the tables above

}  // namespace dc

#define DC_BODY_XML(X, ...)                                                      \
    X(__VA_ARGS__, ".", "index", index, 0, always, nullptr)                      \
    X(__VA_ARGS__, ".", "type", type, 0, always, dc::kBodyTypeNames)             \
    X(__VA_ARGS__, "mass", "value", mass, 0, always, nullptr)                    \
    X(__VA_ARGS__, "mass", "inverse", inv_mass, 0, always, nullptr)              \
    X(__VA_ARGS__, "position", "x", position, 0, always, nullptr)                \
    X(__VA_ARGS__, "position", "y", position, 1, always, nullptr)                \
    X(__VA_ARGS__, "center", "x", center, 0, always, nullptr)                    \
    X(__VA_ARGS__, "center", "y", center, 1, always, nullptr)                    \
    X(__VA_ARGS__, "local_center", "x", local_center, 0, nonzero, nullptr)       \
    X(__VA_ARGS__, "local_center", "y", local_center, 1, nonzero, nullptr)       \
    X(__VA_ARGS__, "velocity", "x", velocity, 0, always, nullptr)                \
    X(__VA_ARGS__, "velocity", "y", velocity, 1, always, nullptr)                \
    X(__VA_ARGS__, "orientation", "theta", angle, 0, always, nullptr)            \
    X(__VA_ARGS__, "inertia", "value", inertia, 0, always, nullptr)              \
    X(__VA_ARGS__, "inertia", "inverse", inv_inertia, 0, always, nullptr)        \
    X(__VA_ARGS__, "spin", "omega", omega, 0, always, nullptr)                   \
    X(__VA_ARGS__, "damping", "linear", linear_damping, 0, declared, nullptr)    \
    X(__VA_ARGS__, "damping", "angular", angular_damping, 0, declared, nullptr)

// (A contact's own `index` attribute is its row in the file, not a recorded field.)
#define DC_CONTACT_XML(X, ...)                                                           \
    X(__VA_ARGS__, ".", "master", body_a, 0, always, nullptr)                            \
    X(__VA_ARGS__, ".", "slave", body_b, 0, always, nullptr)                             \
    X(__VA_ARGS__, ".", "manifold", manifold, 0, always, nullptr)                        \
    X(__VA_ARGS__, ".", "point", point, 0, always, nullptr)                              \
    X(__VA_ARGS__, ".", "points", point_count, 0, always, nullptr)                       \
    X(__VA_ARGS__, ".", "island", island, 0, always, nullptr)                            \
    X(__VA_ARGS__, ".", "id", id_key, 0, always, nullptr)                                \
    X(__VA_ARGS__, "fixtures", "master", fixture_a, 0, always, nullptr)                  \
    X(__VA_ARGS__, "fixtures", "master_child", child_a, 0, always, nullptr)              \
    X(__VA_ARGS__, "fixtures", "slave", fixture_b, 0, always, nullptr)                   \
    X(__VA_ARGS__, "fixtures", "slave_child", child_b, 0, always, nullptr)               \
    X(__VA_ARGS__, "position", "x", position, 0, always, nullptr)                        \
    X(__VA_ARGS__, "position", "y", position, 1, always, nullptr)                        \
    X(__VA_ARGS__, "normal", "x", normal, 0, always, nullptr)                            \
    X(__VA_ARGS__, "normal", "y", normal, 1, always, nullptr)                            \
    X(__VA_ARGS__, "separation", "value", separation, 0, always, nullptr)                \
    X(__VA_ARGS__, "material", "friction", friction, 0, always, nullptr)                 \
    X(__VA_ARGS__, "material", "restitution", restitution, 0, always, nullptr)           \
    X(__VA_ARGS__, "material", "threshold", restitution_threshold, 0, always, nullptr)   \
    X(__VA_ARGS__, "impulse", "n", normal_impulse, 0, always, nullptr)                   \
    X(__VA_ARGS__, "impulse", "t", tangent_impulse, 0, always, nullptr)                  \
    X(__VA_ARGS__, "start", "n", start_normal_impulse, 0, box2d, nullptr)                \
    X(__VA_ARGS__, "start", "t", start_tangent_impulse, 0, box2d, nullptr)               \
    X(__VA_ARGS__, "total", "n", total_normal_impulse, 0, box2d3, nullptr)               \
    X(__VA_ARGS__, "manifold", "type", manifold_type, 0, box2d, dc::kManifoldTypeNames)  \
    X(__VA_ARGS__, "manifold", "nx", local_normal, 0, box2d, nullptr)                    \
    X(__VA_ARGS__, "manifold", "ny", local_normal, 1, box2d, nullptr)                    \
    X(__VA_ARGS__, "manifold", "x", local_point, 0, box2d, nullptr)                      \
    X(__VA_ARGS__, "manifold", "y", local_point, 1, box2d, nullptr)                      \
    X(__VA_ARGS__, "manifold", "px", point_local, 0, box2d, nullptr)                     \
    X(__VA_ARGS__, "manifold", "py", point_local, 1, box2d, nullptr)                     \
    X(__VA_ARGS__, "anchors", "ax", anchor_a, 0, box2d3, nullptr)                        \
    X(__VA_ARGS__, "anchors", "ay", anchor_a, 1, box2d3, nullptr)                        \
    X(__VA_ARGS__, "anchors", "bx", anchor_b, 0, box2d3, nullptr)                        \
    X(__VA_ARGS__, "anchors", "by", anchor_b, 1, box2d3, nullptr)
