#include "world3.hpp"

// v3's C headers, in a namespace of their own (the 2.4.1 headers define types of the same names);
// their system headers first, so that they are not pulled into the namespace.
#include <assert.h>
#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace v3 {
#include DC_BOX2D3_H
}

namespace dc {

struct World3::Impl {
    struct ShapeInfo {
        int32_t body = -1, number = -1;   // scene indices of its body and of the shape
        float friction = 0, restitution = 0, radius = 0;
    };
    v3::b2WorldId world;
    std::vector<v3::b2BodyId> bodies;   // scene index order
    std::vector<bool> fixed_rotation;   // by body
    std::vector<std::vector<v3::b2MassData>> masses;   // by body: its shapes' (sharp) mass data
    std::vector<ShapeInfo> shapes;      // by v3's shape id (index1)
    int shape_count = 0;
    float skin = 0.0f;

    // A dynamic body's mass from its shapes as 2.4.1 computes it (a polygon's skin carries no
    // mass there): v3 would weigh the rounded polygon.
    void set_mass(int body) {
        const v3::b2BodyId id = bodies.at(body);
        if (v3::b2Body_GetType(id) != v3::b2_dynamicBody) return;
        float mass = 0.0f, inertia = 0.0f;
        v3::b2Vec2 center{0.0f, 0.0f};
        for (const v3::b2MassData& m : masses[body]) {
            mass += m.mass;
            center.x += m.mass * m.center.x;
            center.y += m.mass * m.center.y;
            inertia += m.rotationalInertia;   // about the body origin
        }
        if (mass > 0.0f) center = v3::b2Vec2{center.x / mass, center.y / mass};
        inertia -= mass * (center.x * center.x + center.y * center.y);   // about the centre of mass
        if (fixed_rotation[body] || !(inertia > 0.0f)) inertia = 0.0f;
        v3::b2Body_SetMassData(id, v3::b2MassData{mass, center, inertia});
    }

    int add(int body, v3::b2ShapeId id, const Material& m, float radius) {
        if (shapes.size() <= static_cast<std::size_t>(id.index1)) shapes.resize(id.index1 + 1);
        shapes[id.index1] = ShapeInfo{body, shape_count, m.friction, m.restitution, radius};
        return shape_count++;
    }
    SoftStep soft;
    float restitution_threshold;
};

SoftStep default_soft_step() {
    const v3::b2WorldDef def = v3::b2DefaultWorldDef();
    SoftStep soft;
    soft.contact_hertz = def.contactHertz;
    soft.damping_ratio = def.contactDampingRatio;
    soft.push_speed = def.maxContactPushSpeed;
    return soft;
}

World3::World3(float gravity_x, float gravity_y, const SoftStep& soft, float restitution_threshold, bool sleeping,
               bool continuous, float skin)
    : impl_(std::make_unique<Impl>()) {
    if (!(skin >= 0.0f)) throw std::invalid_argument("the polygon skin must be >= 0");
    impl_->skin = skin;
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
    impl_->fixed_rotation.push_back(s.fixed_rotation);
    impl_->masses.emplace_back();
    return static_cast<int>(impl_->bodies.size()) - 1;
}

namespace {

v3::b2ShapeDef shape_def(const Material& m) {
    v3::b2ShapeDef def = v3::b2DefaultShapeDef();
    def.density = m.density;
    def.updateBodyMass = false;   // (World3::Impl::set_mass)
    def.material.friction = m.friction;
    def.material.restitution = m.restitution;
    return def;
}

}  // namespace

int World3::add_circle(int body, float radius, float cx, float cy, const Material& m) {
    if (!(radius > 0.0f)) throw std::invalid_argument("circle radius must be positive");
    const v3::b2ShapeDef def = shape_def(m);
    const v3::b2Circle circle{v3::b2Vec2{cx, cy}, radius};
    const int number = impl_->add(body, v3::b2CreateCircleShape(impl_->bodies.at(body), &def, &circle), m, radius);
    impl_->masses.at(body).push_back(v3::b2ComputeCircleMass(&circle, m.density));
    impl_->set_mass(body);
    return number;
}

namespace {

// v3's hull welds vertices closer than its linear slop (5 mm), so a thin card cannot be hulled;
// a rectangle is made as a box instead (b2MakeOffsetBox takes no hull). False if not a rectangle.
bool rectangle(const std::vector<v3::b2Vec2>& p, v3::b2Polygon& out) {
    if (p.size() != 4) return false;
    const v3::b2Vec2 u{p[1].x - p[0].x, p[1].y - p[0].y}, w{p[3].x - p[0].x, p[3].y - p[0].y};
    const float lu = std::hypot(u.x, u.y), lw = std::hypot(w.x, w.y);
    if (!(lu > 0.0f && lw > 0.0f)) return false;
    const float scale = std::max(lu, lw), tolerance = 1e-5f * scale;
    // the fourth corner closes the parallelogram and the corner is square
    if (std::abs(p[0].x + u.x + w.x - p[2].x) > tolerance || std::abs(p[0].y + u.y + w.y - p[2].y) > tolerance ||
        std::abs(u.x * w.x + u.y * w.y) > tolerance * scale)
        return false;
    const v3::b2Vec2 center{0.5f * (p[0].x + p[2].x), 0.5f * (p[0].y + p[2].y)};
    out = v3::b2MakeOffsetBox(0.5f * lu, 0.5f * lw, center, v3::b2MakeRot(std::atan2(u.y, u.x)));
    return true;
}

}  // namespace

int World3::add_polygon(int body, const std::vector<float>& xy, const Material& m) {
    std::vector<v3::b2Vec2> points;
    for (std::size_t i = 0; i + 1 < xy.size(); i += 2) points.push_back(v3::b2Vec2{xy[i], xy[i + 1]});
    const v3::b2Hull hull = v3::b2ComputeHull(points.data(), static_cast<int>(points.size()));
    v3::b2Polygon sharp;
    if (hull.count > 0) {
        sharp = v3::b2MakePolygon(&hull, 0.0f);
    } else if (!rectangle(points, sharp)) {
        throw std::invalid_argument("a polygon Box2D v3 cannot hull (collinear, or vertices closer than its "
                                    "linear slop, 5 mm)");
    }
    // 2.4.1's skin as a rounded polygon: both engines collide the same shape
    v3::b2Polygon polygon = sharp;
    polygon.radius = impl_->skin;
    const v3::b2ShapeDef def = shape_def(m);
    const int number =
        impl_->add(body, v3::b2CreatePolygonShape(impl_->bodies.at(body), &def, &polygon), m, impl_->skin);
    impl_->masses.at(body).push_back(v3::b2ComputePolygonMass(&sharp, m.density));
    impl_->set_mass(body);
    return number;
}

int World3::add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) {
    const v3::b2ShapeDef def = shape_def(m);   // (an edge has no mass in either engine)
    if (impl_->skin == 0.0f) {
        const v3::b2Segment segment{v3::b2Vec2{x1, y1}, v3::b2Vec2{x2, y2}};
        return impl_->add(body, v3::b2CreateSegmentShape(impl_->bodies.at(body), &def, &segment), m, 0.0f);
    }
    // 2.4.1's edge has the polygon skin too: a capsule of that radius
    const v3::b2Capsule capsule{v3::b2Vec2{x1, y1}, v3::b2Vec2{x2, y2}, impl_->skin};
    return impl_->add(body, v3::b2CreateCapsuleShape(impl_->bodies.at(body), &def, &capsule), m, impl_->skin);
}

void World3::step(float dt) { v3::b2World_Step(impl_->world, dt, impl_->soft.substeps); }

std::pair<BodyState, ContactState> World3::step_recorded(float dt) {
    BodyState before = bodies();
    step(dt);
    return {std::move(before), contacts()};
}

void World3::remove_body(int body) {
    v3::b2BodyId& b = impl_->bodies.at(body);
    if (!v3::b2Body_IsValid(b)) throw std::invalid_argument("body " + std::to_string(body) + " was removed already");
    v3::b2DestroyBody(b);
}

namespace {

// Islands as 2.4.1 numbers them: bodies joined by contacts, never through a static body,
// numbered in the order the contacts first reach them.
std::vector<int32_t> islands_of(const ContactState& c, const std::vector<int8_t>& is_static) {
    std::vector<int32_t> parent(is_static.size());
    for (std::size_t i = 0; i < parent.size(); ++i) parent[i] = static_cast<int32_t>(i);
    auto root = [&](int32_t i) {
        while (parent[i] != i) i = parent[i] = parent[parent[i]];
        return i;
    };
    for (std::size_t k = 0; k < c.size(); ++k) {
        const int32_t a = c.body_a[k], b = c.body_b[k];
        if (!is_static[a] && !is_static[b]) parent[root(a)] = root(b);
    }
    std::vector<int32_t> number(parent.size(), -1), out(c.size());
    int32_t next = 0;
    for (std::size_t k = 0; k < c.size(); ++k) {
        const int32_t body = is_static[c.body_a[k]] ? c.body_b[k] : c.body_a[k];
        int32_t& n = number[root(body)];
        if (n < 0) n = next++;
        out[k] = n;
    }
    return out;
}

}  // namespace

ContactState World3::contacts() const {
    ContactState s;
    std::vector<v3::b2ContactData> data;
    std::vector<int8_t> is_static(impl_->bodies.size(), 0);
    int32_t manifold = 0;
    for (std::size_t i = 0; i < impl_->bodies.size(); ++i) {
        const v3::b2BodyId b = impl_->bodies[i];
        if (!v3::b2Body_IsValid(b)) continue;
        is_static[i] = v3::b2Body_GetType(b) == v3::b2_staticBody;
        data.resize(static_cast<std::size_t>(v3::b2Body_GetContactCapacity(b)));
        const int n = v3::b2Body_GetContactData(b, data.data(), static_cast<int>(data.size()));
        for (int k = 0; k < n; ++k) {
            const v3::b2ShapeId sa = data[k].shapeIdA, sb = data[k].shapeIdB;
            // each contact once: from the body of shape A
            if (v3::b2Shape_GetBody(sa).index1 != b.index1) continue;
            const v3::b2Manifold& m = data[k].manifold;
            if (m.pointCount == 0) continue;
            const Impl::ShapeInfo& a = impl_->shapes.at(sa.index1), &c = impl_->shapes.at(sb.index1);
            // v3's default mixing rules (b2MixFriction, b2MixRestitution), as 2.4.1's
            const float friction = std::sqrt(a.friction * c.friction);
            const float restitution = std::max(a.restitution, c.restitution);
            for (int j = 0; j < m.pointCount; ++j) {
                const v3::b2ManifoldPoint& p = m.points[j];
                s.manifold.push_back(manifold);
                s.island.push_back(0);
                s.point.push_back(static_cast<int8_t>(j));
                s.point_count.push_back(static_cast<int8_t>(m.pointCount));
                s.manifold_type.push_back(0);   // (2.4.1's local manifold: v3 has none)
                s.body_a.push_back(a.body);
                s.body_b.push_back(c.body);
                s.fixture_a.push_back(a.number);
                s.fixture_b.push_back(c.number);
                s.child_a.push_back(0);
                s.child_b.push_back(0);
                s.id_key.push_back(p.id);
                s.local_normal.insert(s.local_normal.end(), {0.0f, 0.0f});
                s.local_point.insert(s.local_point.end(), {0.0f, 0.0f});
                s.point_local.insert(s.point_local.end(), {0.0f, 0.0f});
                s.position.insert(s.position.end(), {p.point.x, p.point.y});
                s.normal.insert(s.normal.end(), {m.normal.x, m.normal.y});
                s.separation.push_back(p.separation);
                s.friction.push_back(friction);
                s.restitution.push_back(restitution);
                s.restitution_threshold.push_back(impl_->restitution_threshold);
                s.radius_a.push_back(a.radius);
                s.radius_b.push_back(c.radius);
                s.start_normal_impulse.push_back(0.0f);
                s.start_tangent_impulse.push_back(0.0f);
                s.normal_impulse.push_back(p.normalImpulse);
                s.tangent_impulse.push_back(p.tangentImpulse);
                s.total_normal_impulse.push_back(p.totalNormalImpulse);
                s.anchor_a.insert(s.anchor_a.end(), {p.anchorA.x, p.anchorA.y});
                s.anchor_b.insert(s.anchor_b.end(), {p.anchorB.x, p.anchorB.y});
            }
            ++manifold;
        }
    }
    s.island = islands_of(s, is_static);
    // island order (a manifold's points stay together), manifolds renumbered in it
    std::vector<std::size_t> order(s.size());
    for (std::size_t k = 0; k < order.size(); ++k) order[k] = k;
    std::stable_sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) { return s.island[x] < s.island[y]; });
    ContactState out;
#define DC_PERMUTE(T, name, width, solver)                                          \
    out.name.reserve(s.name.size());                                                \
    for (std::size_t k : order)                                                     \
        out.name.insert(out.name.end(), s.name.begin() + width * k, s.name.begin() + width * (k + 1));
    DC_CONTACT_FIELDS(DC_PERMUTE)
#undef DC_PERMUTE
    for (std::size_t k = 0, next = 0; k < out.size(); ++k) {
        if (k > 0 && s.manifold[order[k]] != s.manifold[order[k - 1]]) ++next;
        out.manifold[k] = static_cast<int32_t>(next);
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
