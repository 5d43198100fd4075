#include "world3.hpp"

// v3's C headers, in a namespace of their own (the 2.4.1 headers define types of the same names);
// their system headers first, so that they are not pulled into the namespace.
#include <assert.h>
#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace v3 {
#include DC_BOX2D3_H
}

namespace dc {

struct World3::Impl {
    v3::b2WorldId world;
    std::vector<v3::b2BodyId> bodies;   // scene index order
    int shapes = 0;
    SoftStep soft;
    float restitution_threshold;
};

World3::World3(float gravity_x, float gravity_y, const SoftStep& soft, float restitution_threshold, bool sleeping,
               bool continuous)
    : impl_(std::make_unique<Impl>()) {
    if (soft.substeps < 1) throw std::invalid_argument("substeps must be >= 1");
    v3::b2WorldDef def = v3::b2DefaultWorldDef();
    def.gravity = v3::b2Vec2{gravity_x, gravity_y};
    def.contactHertz = soft.contact_hertz;
    def.contactDampingRatio = soft.damping_ratio;
    def.maxContactPushSpeed = soft.push_speed;
    def.restitutionThreshold = restitution_threshold;
    def.enableSleep = sleeping;
    def.enableContinuous = continuous;
    def.workerCount = 1;   // one thread: the engine's time is one core's, as 2.4.1's
    impl_->world = v3::b2CreateWorld(&def);
    v3::b2World_EnableWarmStarting(impl_->world, soft.warm_starting);
    impl_->soft = soft;
    impl_->restitution_threshold = restitution_threshold;
}

World3::~World3() { v3::b2DestroyWorld(impl_->world); }

int World3::add_body(const BodySpec& s) {
    v3::b2BodyDef def = v3::b2DefaultBodyDef();
    def.type = static_cast<v3::b2BodyType>(s.type);   // the same numbering: static, kinematic, dynamic
    def.position = v3::b2Vec2{s.x, s.y};
    def.rotation = v3::b2MakeRot(s.angle);
    def.linearVelocity = v3::b2Vec2{s.vx, s.vy};
    def.angularVelocity = s.omega;
    def.linearDamping = s.linear_damping;
    def.angularDamping = s.angular_damping;
    def.fixedRotation = s.fixed_rotation;
    def.isBullet = s.bullet;
    impl_->bodies.push_back(v3::b2CreateBody(impl_->world, &def));
    return static_cast<int>(impl_->bodies.size()) - 1;
}

namespace {

v3::b2ShapeDef shape_def(const Material& m) {
    v3::b2ShapeDef def = v3::b2DefaultShapeDef();
    def.density = m.density;
    def.material.friction = m.friction;
    def.material.restitution = m.restitution;
    return def;
}

}  // namespace

int World3::add_circle(int body, float radius, float cx, float cy, const Material& m) {
    if (!(radius > 0.0f)) throw std::invalid_argument("circle radius must be positive");
    const v3::b2ShapeDef def = shape_def(m);
    const v3::b2Circle circle{v3::b2Vec2{cx, cy}, radius};
    v3::b2CreateCircleShape(impl_->bodies.at(body), &def, &circle);
    return impl_->shapes++;
}

int World3::add_polygon(int body, const std::vector<float>& xy, const Material& m) {
    std::vector<v3::b2Vec2> points;
    for (std::size_t i = 0; i + 1 < xy.size(); i += 2) points.push_back(v3::b2Vec2{xy[i], xy[i + 1]});
    const v3::b2Hull hull = v3::b2ComputeHull(points.data(), static_cast<int>(points.size()));
    if (hull.count == 0) throw std::invalid_argument("a polygon Box2D v3 cannot hull (collinear or too small)");
    const v3::b2Polygon polygon = v3::b2MakePolygon(&hull, 0.0f);
    const v3::b2ShapeDef def = shape_def(m);
    v3::b2CreatePolygonShape(impl_->bodies.at(body), &def, &polygon);
    return impl_->shapes++;
}

int World3::add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) {
    const v3::b2Segment segment{v3::b2Vec2{x1, y1}, v3::b2Vec2{x2, y2}};
    const v3::b2ShapeDef def = shape_def(m);
    v3::b2CreateSegmentShape(impl_->bodies.at(body), &def, &segment);
    return impl_->shapes++;
}

void World3::step(float dt) { v3::b2World_Step(impl_->world, dt, impl_->soft.substeps); }

void World3::remove_body(int body) {
    v3::b2BodyId& b = impl_->bodies.at(body);
    if (!v3::b2Body_IsValid(b)) throw std::invalid_argument("body " + std::to_string(body) + " was removed already");
    v3::b2DestroyBody(b);
}

std::vector<std::vector<float>> World3::contact_columns() const {
    std::vector<std::vector<float>> out(4);
    std::vector<v3::b2ContactData> data;
    for (std::size_t i = 0; i < impl_->bodies.size(); ++i) {
        const v3::b2BodyId b = impl_->bodies[i];
        if (!v3::b2Body_IsValid(b)) continue;
        data.resize(static_cast<std::size_t>(v3::b2Body_GetContactCapacity(b)));
        const int n = v3::b2Body_GetContactData(b, data.data(), static_cast<int>(data.size()));
        for (int k = 0; k < n; ++k) {
            // each contact once: from the body of shape A
            if (v3::b2Shape_GetBody(data[k].shapeIdA).index1 != b.index1) continue;
            const v3::b2Manifold& m = data[k].manifold;
            for (int j = 0; j < m.pointCount; ++j) {
                out[0].push_back(m.points[j].separation);
                out[1].push_back(m.points[j].normalImpulse);
                out[2].push_back(m.points[j].tangentImpulse);
                out[3].push_back(m.points[j].totalNormalImpulse);
            }
        }
    }
    return out;
}

BodyState World3::bodies() const {
    BodyState s;
    for (std::size_t i = 0; i < impl_->bodies.size(); ++i) {
        const v3::b2BodyId b = impl_->bodies[i];
        if (!v3::b2Body_IsValid(b)) continue;   // (removed)
        const v3::b2Vec2 p = v3::b2Body_GetPosition(b), c = v3::b2Body_GetWorldCenterOfMass(b);
        const v3::b2Vec2 lc = v3::b2Body_GetLocalCenterOfMass(b), v = v3::b2Body_GetLinearVelocity(b);
        const float mass = v3::b2Body_GetMass(b), inertia = v3::b2Body_GetRotationalInertia(b);
        s.index.push_back(static_cast<int32_t>(i));
        s.type.push_back(static_cast<int8_t>(v3::b2Body_GetType(b)));
        s.position.insert(s.position.end(), {p.x, p.y});
        s.angle.push_back(v3::b2Rot_GetAngle(v3::b2Body_GetRotation(b)));
        s.center.insert(s.center.end(), {c.x, c.y});
        s.local_center.insert(s.local_center.end(), {lc.x, lc.y});
        s.velocity.insert(s.velocity.end(), {v.x, v.y});
        s.omega.push_back(v3::b2Body_GetAngularVelocity(b));
        s.mass.push_back(mass);
        s.inv_mass.push_back(mass > 0 ? 1.0f / mass : 0.0f);
        s.inertia.push_back(inertia);
        s.inv_inertia.push_back(inertia > 0 ? 1.0f / inertia : 0.0f);
        s.linear_damping.push_back(v3::b2Body_GetLinearDamping(b));
        s.angular_damping.push_back(v3::b2Body_GetAngularDamping(b));
        s.gravity_scale.push_back(v3::b2Body_GetGravityScale(b));
        s.fixed_rotation.push_back(v3::b2Body_IsFixedRotation(b) ? 1 : 0);
    }
    return s;
}

std::string box2d3_version() {
    const v3::b2Version v = v3::b2GetVersion();
    return std::to_string(v.major) + "." + std::to_string(v.minor) + "." + std::to_string(v.revision);
}

}  // namespace dc
