// What a world is built from and what it hands back, engine-free (no Box2D header): the specs of
// a body and a shape's material, and the body and contact states as flat arrays.
#pragma once

#include <cstdint>
#include <vector>

#include "records.hpp"

namespace dc {

struct BodySpec {
    int type = 2;  // b2BodyType: 0 static, 1 kinematic, 2 dynamic
    float x = 0, y = 0, angle = 0;
    float vx = 0, vy = 0, omega = 0;
    float linear_damping = 0, angular_damping = 0;
    bool fixed_rotation = false;
    bool bullet = false;
};

struct Material {
    float density = 0;
    float friction = 0;
    float restitution = 0;
    float restitution_threshold = 1.0f;
};

// Every live body (records.hpp), in scene index order. Vectors of 2 are interleaved (x0, y0, x1, ...).
struct BodyState {
    DC_BODY_FIELDS(DC_VECTOR_FIELD)
    std::vector<uint8_t> fixed_rotation;   // read by tests and tools, never written to a step file
    size_t size() const { return index.size(); }
    void reserve(size_t rows) {
        DC_BODY_FIELDS(DC_RESERVE_FIELD)
        fixed_rotation.reserve(rows);
    }
};

// One row per manifold point of every contact the velocity solver sees (records.hpp).
struct ContactState {
    DC_CONTACT_FIELDS(DC_VECTOR_FIELD)
    size_t size() const { return manifold.size(); }
    void reserve(size_t rows) { DC_CONTACT_FIELDS(DC_RESERVE_FIELD) }
};

// What a scene is built into, whatever the engine: the calls simulate/build.py makes.
class SceneWorld {
public:
    virtual ~SceneWorld() = default;
    virtual int add_body(const BodySpec& spec) = 0;   // returns the body's index (scene order)
    // each returns the shape's index in the world (scene order)
    virtual int add_circle(int body, float radius, float cx, float cy, const Material& m) = 0;
    virtual int add_polygon(int body, const std::vector<float>& xy, const Material& m) = 0;
    virtual int add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) = 0;
};

}  // namespace dc
