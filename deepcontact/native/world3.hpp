// A Box2D v3 (3.1, from the pyb2d3 wheel) world built from a scene and stepped with v3's soft
// step (substeps), its bodies handed back as the same flat arrays as a 2.4.1 world's. v3's types
// stay in world3.cpp, inside a namespace of their own: both engines live in this one module.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "state.hpp"

namespace dc {

// The soft step's settings; default_soft_step() fills them from v3's own b2DefaultWorldDef.
struct SoftStep {
    int substeps = 4;          // b2World_Step's sub-step count: v3 has no default, its samples use 4
    float contact_hertz = 0.0f;
    float damping_ratio = 0.0f;
    float push_speed = 0.0f;   // m/s: how fast v3 pushes overlapping bodies apart
    bool warm_starting = true;
};

// v3's defaults (b2DefaultWorldDef's contactHertz, contactDampingRatio, maxContactPushSpeed).
SoftStep default_soft_step();

class World3 : public SceneWorld {
public:
    // skin: the radius every polygon and edge is rounded by (2.4.1's b2_polygonRadius makes both
    // engines collide the same shapes; 0: v3's sharp polygons and segments); masses ignore it.
    World3(float gravity_x, float gravity_y, const SoftStep& soft, float restitution_threshold, bool sleeping,
           bool continuous, float skin);
    ~World3() override;
    World3(const World3&) = delete;
    World3& operator=(const World3&) = delete;

    int add_body(const BodySpec& spec) override;
    int add_circle(int body, float radius, float cx, float cy, const Material& m) override;
    int add_polygon(int body, const std::vector<float>& xy, const Material& m) override;
    int add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) override;

    void step(float dt);
    // One step, recorded as a step file holds it: the bodies before it, its contacts.
    std::pair<BodyState, ContactState> step_recorded(float dt);
    void remove_body(int body);
    BodyState bodies() const;
    // Every manifold point of every touching contact once, as a step file records it: the
    // manifold the last step solved (its points where the bodies were before the step) and
    // the impulses of its last substep, v3's total normal impulse, in island order.
    ContactState contacts() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

std::string box2d3_version();

}  // namespace dc
