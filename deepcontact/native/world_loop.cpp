// The loop's step without Box2D's velocity solver, and without doing its work twice
// (docs/solver.md, "The loop"): the islands are found once, by b2World::Solve's own depth-first
// search, as the project's solver is given its columns; after the solve, the islands are stepped
// as b2Island::Solve steps them with no velocity iterations (velocities integrated, the written
// impulses applied as its warm start, positions integrated and corrected, fixtures synchronised,
// new pairs found), skipping what zero iterations never read (effective masses, restitution
// biases). Every expression keeps Box2D 2.4.1's operand order (b2_world.cpp, b2_island.cpp,
// b2_contact_solver.cpp) and the module is built without FMA contraction, so the bits are the same
// as Box2D's own Step with zero velocity iterations would leave.
#include <algorithm>
#include <cstring>

#include "box2d_access.hpp"
#include "world.hpp"

namespace dc {
namespace {

uint16& flags(b2Body* b) { return b->*member(BodyFlags()); }
uint32& flags(b2Contact* c) { return c->*member(ContactFlags()); }

template <class T>
void put2(std::vector<T>& v, size_t k, const b2Vec2& p) {
    v[2 * k] = p.x;
    v[2 * k + 1] = p.y;
}

}  // namespace

BodyColumns LoopFrame::body_columns() const {
    BodyColumns c;
    c.n = body_count;
#define DC_TAKE(T, name, width, solver) DC_IF_##solver(c.name = bodies.name.data();)
    DC_BODY_FIELDS(DC_TAKE)
#undef DC_TAKE
    return c;
}

ContactColumns LoopFrame::contact_columns() const {
    ContactColumns c;
    c.n = points;
#define DC_TAKE(T, name, width, solver) DC_IF_##solver(c.name = contacts.name.data();)
    DC_CONTACT_FIELDS(DC_TAKE)
#undef DC_TAKE
    c.row_a = contacts.row_a.data();
    c.row_b = contacts.row_b.data();
    return c;
}

// b2World::Solve's islands: flags cleared, then a depth-first search from each awake non-static
// seed in body-list order, not crossing static bodies (which it adds and leaves). The bodies it
// reaches are woken only when they are stepped (solve_island): where Box2D's own Solve steps
// them instead, a body woken here would seed a search of its own there.
void World::find_islands() {
    LoopFrame& f = loop_;
    f.island_bodies.clear();
    f.island_contacts.clear();
    f.bodies_end.clear();
    f.contacts_end.clear();
    b2World* w = world_.get();
    for (b2Body* b = w->GetBodyList(); b; b = b->GetNext()) flags(b) &= ~kBodyIslandFlag;
    for (b2Contact* c = w->GetContactList(); c; c = c->GetNext()) flags(c) &= ~kContactIslandFlag;
    std::vector<b2Body*>& stack = loop_stack_;
    f.slot.resize(bodies_.size());
    f.constraints.clear();
    f.static_moves = false;
    f.block_solve = block_solve_;
    for (b2Body* seed = w->GetBodyList(); seed; seed = seed->GetNext()) {
        if ((flags(seed) & kBodyIslandFlag) || !seed->IsAwake() || !seed->IsEnabled()) continue;
        if (seed->GetType() == b2_staticBody) continue;
        const size_t first_body = f.island_bodies.size();
        stack.assign(1, seed);
        flags(seed) |= kBodyIslandFlag;
        while (!stack.empty()) {
            b2Body* b = stack.back();
            stack.pop_back();
            f.slot[body_index(b)] = static_cast<int32_t>(f.island_bodies.size());
            f.island_bodies.push_back(b);
            if (b->GetType() == b2_staticBody) {
                f.static_moves |= b->GetLinearVelocity() != b2Vec2_zero || b->GetAngularVelocity() != 0.0f;
                continue;
            }
            for (b2ContactEdge* ce = b->GetContactList(); ce; ce = ce->next) {
                b2Contact* c = ce->contact;
                if ((flags(c) & kContactIslandFlag) || !c->IsEnabled() || !c->IsTouching()) continue;
                if (c->GetFixtureA()->IsSensor() || c->GetFixtureB()->IsSensor()) continue;
                f.island_contacts.push_back(c);
                flags(c) |= kContactIslandFlag;
                b2Body* other = ce->other;
                if (flags(other) & kBodyIslandFlag) continue;
                stack.push_back(other);
                flags(other) |= kBodyIslandFlag;
            }
        }
        f.bodies_end.push_back(static_cast<int32_t>(f.island_bodies.size()));
        f.contacts_end.push_back(static_cast<int32_t>(f.island_contacts.size()));
        // the island's contacts know their bodies' slots (a static body has one in each island)
        for (size_t i = f.constraints.size(); i < f.island_contacts.size(); ++i) {
            LoopFrame::Constraint& k = f.constraints.emplace_back();
            k.slot_a = f.slot[body_index(f.island_contacts[i]->GetFixtureA()->GetBody())];
            k.slot_b = f.slot[body_index(f.island_contacts[i]->GetFixtureB()->GetBody())];
        }
        // static bodies may join later islands too
        for (size_t i = first_body; i < f.island_bodies.size(); ++i)
            if (f.island_bodies[i]->GetType() == b2_staticBody) flags(f.island_bodies[i]) &= ~kBodyIslandFlag;
    }
}

// Every live body's solver columns, in scene index order (the rows contacts name).
void World::gather_loop_bodies() {
    LoopFrame::Bodies& s = loop_.bodies;
    const size_t n = live_bodies_;
    s.type.resize(n);
    s.angle.resize(n);
    s.center.resize(2 * n);
    s.local_center.resize(2 * n);
    s.velocity.resize(2 * n);
    s.omega.resize(n);
    s.mass.resize(n);
    s.inv_mass.resize(n);
    s.inv_inertia.resize(n);
    s.linear_damping.resize(n);
    s.angular_damping.resize(n);
    s.gravity_scale.resize(n);
    loop_.row_of.assign(bodies_.size(), -1);
    loop_.rotation.resize(bodies_.size());
    loop_.placed.resize(bodies_.size());
    size_t i = 0;
    for (b2Body* b : bodies_) {
        if (b == nullptr) continue;
        loop_.row_of[body_index(b)] = static_cast<int32_t>(i);
        loop_.rotation[body_index(b)].Set(b->GetAngle());   // (the same angle gives the same bits)
        loop_.placed[body_index(b)] = placed(b, loop_.rotation[body_index(b)]);
        s.type[i] = static_cast<int8_t>(b->GetType());
        s.angle[i] = b->GetAngle();
        put2(s.center, i, b->GetWorldCenter());
        put2(s.local_center, i, b->GetLocalCenter());
        put2(s.velocity, i, b->GetLinearVelocity());
        s.omega[i] = b->GetAngularVelocity();
        s.mass[i] = b->GetMass();
        s.inv_mass[i] = b->*member(BodyInvMass());
        s.inv_inertia[i] = b->*member(BodyInvI());
        s.linear_damping[i] = b->GetLinearDamping();
        s.angular_damping[i] = b->GetAngularDamping();
        s.gravity_scale[i] = b->GetGravityScale();
        ++i;
    }
    loop_.body_count = n;
}

// Whether a body's transform differs, in any bit, from the one Box2D's solver rebuilds from its
// sweep (rotation: its angle's).
bool World::placed(const b2Body* b, const b2Rot& rotation) {
    const b2Sweep& sweep = b->*member(BodySweep());
    const b2Transform rebuilt(sweep.c - b2Mul(rotation, sweep.localCenter), rotation);
    return std::memcmp(&rebuilt, &b->GetTransform(), sizeof rebuilt) != 0;
}

// The deepest penetration of a contact's points as contacts() measures it: from the bodies'
// transforms, which are the posed ones but for a body placed since its last step.
float World::penetration(b2Contact* c, const b2WorldManifold& posed) const {
    const b2Fixture* fa = c->GetFixtureA();
    const b2Fixture* fb = c->GetFixtureB();
    const b2Body* ba = fa->GetBody();
    const b2Body* bb = fb->GetBody();
    b2WorldManifold measured = posed;
    if (loop_.placed[body_index(ba)] || loop_.placed[body_index(bb)])
        measured.Initialize(c->GetManifold(), ba->GetTransform(), fa->GetShape()->m_radius, bb->GetTransform(),
                            fb->GetShape()->m_radius);
    float deepest = 0.0f;
    for (int j = 0; j < c->GetManifold()->pointCount; ++j) deepest = std::max(deepest, -measured.separations[j]);
    return deepest;
}

// Every point of the islands' contacts, in island order (the rows set_manifold_impulses writes),
// each contact posed once for the warm start that applies the solution.
void World::gather_loop_contacts() {
    LoopFrame::Contacts& s = loop_.contacts;
    size_t n = 0;
    for (b2Contact* c : loop_.island_contacts) n += c->GetManifold()->pointCount;
#define DC_SIZE(T, name, width, solver) DC_IF_##solver(s.name.resize(n * (width));)
    DC_CONTACT_FIELDS(DC_SIZE)
#undef DC_SIZE
    for (auto* v : {&s.row_a, &s.row_b}) v->resize(n);
    for (auto* v : {&s.normal_impulse, &s.tangent_impulse}) v->resize(n);
    gathered_.clear();
    float deepest = 0.0f;
    size_t k = 0, index = 0;
    int32_t manifold = 0;
    for (b2Contact* c : loop_.island_contacts) {
        const b2Fixture* fa = c->GetFixtureA();
        const b2Fixture* fb = c->GetFixtureB();
        const b2Body* ba = fa->GetBody();
        const b2Body* bb = fb->GetBody();
        const b2Manifold* m = c->GetManifold();
        const b2WorldManifold wm = pose(c, loop_.constraints[index++]);
        deepest = std::max(deepest, penetration(c, wm));
        for (int j = 0; j < m->pointCount; ++j, ++k) {
            const b2ManifoldPoint& p = m->points[j];
            s.manifold[k] = manifold;
            s.point[k] = static_cast<int8_t>(j);
            s.point_count[k] = static_cast<int8_t>(m->pointCount);
            s.manifold_type[k] = static_cast<int8_t>(m->type);
            put2(s.local_normal, k, m->localNormal);
            put2(s.local_point, k, m->localPoint);
            put2(s.point_local, k, p.localPoint);
            s.friction[k] = c->GetFriction();
            s.restitution[k] = c->GetRestitution();
            s.restitution_threshold[k] = c->GetRestitutionThreshold();
            s.radius_a[k] = fa->GetShape()->m_radius;
            s.radius_b[k] = fb->GetShape()->m_radius;
            s.row_a[k] = loop_.row_of[body_index(ba)];
            s.row_b[k] = loop_.row_of[body_index(bb)];
            s.normal_impulse[k] = p.normalImpulse;
            s.tangent_impulse[k] = p.tangentImpulse;
            gathered_.emplace_back(c, j);
        }
        ++manifold;
    }
    loop_.points = n;
    loop_.deepest = deepest;
}

LoopFrame& World::gather_loop() {
    find_islands();
    gather_loop_bodies();
    gather_loop_contacts();
    gathered_generation_ = generation_;
    loop_generation_ = generation_;
    return loop_;
}

// b2World::Step's Solve for the loop: the islands found by gather_loop, stepped with no velocity
// iterations, then the fixtures synchronised and new pairs found.
void World::solve_islands(const b2TimeStep& step) {
    LoopFrame& f = loop_;
    f.positions.resize(f.island_bodies.size());
    f.velocities.resize(f.island_bodies.size());
    int32_t first_body = 0, first_contact = 0;
    for (size_t island = 0; island < f.bodies_end.size(); ++island) {
        solve_island(step, first_body, f.bodies_end[island], first_contact, f.contacts_end[island]);
        first_body = f.bodies_end[island];
        first_contact = f.contacts_end[island];
    }
    b2World* w = world_.get();
    for (b2Body* b = w->GetBodyList(); b; b = b->GetNext()) {
        // a body in no island did not move
        if ((flags(b) & kBodyIslandFlag) == 0 || b->GetType() == b2_staticBody) continue;
        (b->*member(BodySynchronizeFixtures()))();
    }
    const_cast<b2ContactManager&>(w->GetContactManager()).FindNewContacts();
}

// b2Island::Solve with zero velocity iterations (and no joints, no sleeping: the loop allows
// neither).
void World::solve_island(const b2TimeStep& step, int32_t body_begin, int32_t body_end, int32_t contact_begin,
                         int32_t contact_end) {
    LoopFrame& f = loop_;
    const float h = step.dt;
    const b2Vec2 gravity = world_->GetGravity();
    b2Position* positions = f.positions.data();
    b2Velocity* velocities = f.velocities.data();
    // Integrate velocities and apply damping.
    for (int32_t i = body_begin; i < body_end; ++i) {
        b2Body* b = f.island_bodies[i];
        // (b2World::Solve's search wakes them, without resetting their sleep time)
        if (b->GetType() != b2_staticBody) flags(b) |= kBodyAwakeFlag;
        b2Sweep& sweep = b->*member(BodySweep());
        b2Vec2 c = sweep.c;
        float a = sweep.a;
        b2Vec2 v = b->*member(BodyLinearVelocity());
        float w = b->*member(BodyAngularVelocity());
        sweep.c0 = sweep.c;
        sweep.a0 = sweep.a;
        if (b->GetType() == b2_dynamicBody) {
            v += h * (b->*member(BodyInvMass())) *
                 (b->GetGravityScale() * (b->*member(BodyMass())) * gravity + b->*member(BodyForce()));
            w += h * (b->*member(BodyInvI())) * (b->*member(BodyTorque()));
            v *= 1.0f / (1.0f + h * b->GetLinearDamping());
            w *= 1.0f / (1.0f + h * b->GetAngularDamping());
        }
        positions[i].c = c;
        positions[i].a = a;
        velocities[i].v = v;
        velocities[i].w = w;
    }
    // The impulses written into the manifolds, applied as b2ContactSolver's warm start and stored
    // back as StoreImpulses stores them.
    for (int32_t i = contact_begin; i < contact_end; ++i) apply_impulses(step, f.constraints[i]);
    // Integrate positions.
    for (int32_t i = body_begin; i < body_end; ++i) {
        b2Vec2 c = positions[i].c;
        float a = positions[i].a;
        b2Vec2 v = velocities[i].v;
        float w = velocities[i].w;
        b2Vec2 translation = h * v;
        if (b2Dot(translation, translation) > b2_maxTranslationSquared) {
            float ratio = b2_maxTranslation / translation.Length();
            v *= ratio;
        }
        float rotation = h * w;
        if (rotation * rotation > b2_maxRotationSquared) {
            float ratio = b2_maxRotation / b2Abs(rotation);
            w *= ratio;
        }
        c += h * v;
        a += h * w;
        positions[i].c = c;
        positions[i].a = a;
        velocities[i].v = v;
        velocities[i].w = w;
    }
    for (int32_t it = 0; it < step.positionIterations; ++it) {
        bool solved = true;
        float min_separation = 0.0f;
        for (int32_t i = contact_begin; i < contact_end; ++i)
            min_separation = b2Min(min_separation, correct_positions(f.constraints[i]));
        solved = min_separation >= -3.0f * b2_linearSlop;
        if (solved) break;
    }
    // Copy the state back to the bodies.
    for (int32_t i = body_begin; i < body_end; ++i) {
        b2Body* b = f.island_bodies[i];
        b2Sweep& sweep = b->*member(BodySweep());
        sweep.c = positions[i].c;
        sweep.a = positions[i].a;
        b->*member(BodyLinearVelocity()) = velocities[i].v;
        b->*member(BodyAngularVelocity()) = velocities[i].w;
        (b->*member(BodySynchronizeTransform()))();
    }
    // b2Island::Report: what the recorder keeps of a step
    if (recorder_active())
        for (int32_t i = contact_begin; i < contact_end; ++i) record_solved(f.island_contacts[i]);
}

// One contact as b2ContactSolver's constructor and InitializeVelocityConstraints pose it for its
// warm start and position correction: the manifold in body frames, the world manifold from the
// transforms the bodies' positions give (each body's rotation computed once a step), the normal
// and lever arms, and the block solver's cut of a redundant pair. Returns the world manifold
// (its separations: the penetration).
b2WorldManifold World::pose(b2Contact* contact, LoopFrame::Constraint& k) const {
    const LoopFrame& f = loop_;
    b2Fixture* fa = contact->GetFixtureA();
    b2Fixture* fb = contact->GetFixtureB();
    b2Body* ba = fa->GetBody();
    b2Body* bb = fb->GetBody();
    const b2Sweep& sa = ba->*member(BodySweep());
    const b2Sweep& sb = bb->*member(BodySweep());
    b2Manifold* manifold = contact->GetManifold();
    k.manifold = manifold;
    k.mA = ba->*member(BodyInvMass());
    k.mB = bb->*member(BodyInvMass());
    k.iA = ba->*member(BodyInvI());
    k.iB = bb->*member(BodyInvI());
    k.local_center_a = sa.localCenter;
    k.local_center_b = sb.localCenter;
    k.local_normal = manifold->localNormal;
    k.local_point = manifold->localPoint;
    k.radius_a = fa->GetShape()->m_radius;
    k.radius_b = fb->GetShape()->m_radius;
    k.type = manifold->type;
    k.point_count = k.count = manifold->pointCount;

    const b2Vec2 cA = sa.c, cB = sb.c;
    b2Transform xfA, xfB;
    xfA.q = f.rotation[body_index(ba)];
    xfB.q = f.rotation[body_index(bb)];
    xfA.p = cA - b2Mul(xfA.q, k.local_center_a);
    xfB.p = cB - b2Mul(xfB.q, k.local_center_b);
    b2WorldManifold wm;
    wm.Initialize(manifold, xfA, k.radius_a, xfB, k.radius_b);
    k.normal = wm.normal;
    for (int32 j = 0; j < k.point_count; ++j) {
        k.local_points[j] = manifold->points[j].localPoint;
        k.rA[j] = wm.points[j] - cA;
        k.rB[j] = wm.points[j] - cB;
    }
    if (k.count == 2 && block_solve_ &&
        !pair_block(k.mA, k.mB, k.iA, k.iB, b2Cross(k.rA[0], k.normal), b2Cross(k.rB[0], k.normal),
                    b2Cross(k.rA[1], k.normal), b2Cross(k.rB[1], k.normal)).kept())
        k.count = 1;
    return wm;
}

// One contact of b2ContactSolver: the impulses written into its manifold applied as WarmStart
// applies them, then stored as StoreImpulses stores them.
void World::apply_impulses(const b2TimeStep& step, const LoopFrame::Constraint& k) {
    LoopFrame& f = loop_;
    b2ManifoldPoint* points = k.manifold->points;
    float normal_impulse[b2_maxManifoldPoints], tangent_impulse[b2_maxManifoldPoints];
    for (int32 j = 0; j < k.count; ++j) {
        normal_impulse[j] = step.warmStarting ? step.dtRatio * points[j].normalImpulse : 0.0f;
        tangent_impulse[j] = step.warmStarting ? step.dtRatio * points[j].tangentImpulse : 0.0f;
    }
    if (step.warmStarting) {
        b2Velocity& A = f.velocities[k.slot_a];
        b2Velocity& B = f.velocities[k.slot_b];
        b2Vec2 vA = A.v;
        float wA = A.w;
        b2Vec2 vB = B.v;
        float wB = B.w;
        const b2Vec2 normal = k.normal;
        const b2Vec2 tangent = b2Cross(normal, 1.0f);
        for (int32 j = 0; j < k.count; ++j) {
            b2Vec2 P = normal_impulse[j] * normal + tangent_impulse[j] * tangent;
            wA -= k.iA * b2Cross(k.rA[j], P);
            vA -= k.mA * P;
            wB += k.iB * b2Cross(k.rB[j], P);
            vB += k.mB * P;
        }
        A.v = vA;
        A.w = wA;
        B.v = vB;
        B.w = wB;
    }
    for (int32 j = 0; j < k.count; ++j) {
        points[j].normalImpulse = normal_impulse[j];
        points[j].tangentImpulse = tangent_impulse[j];
    }
}

// One contact of b2ContactSolver::SolvePositionConstraints (b2PositionSolverManifold inline);
// returns the least separation it saw.
float World::correct_positions(const LoopFrame::Constraint& k) {
    LoopFrame& f = loop_;
    const float mA = k.mA, mB = k.mB, iA = k.iA, iB = k.iB;
    b2Vec2 cA = f.positions[k.slot_a].c;
    float aA = f.positions[k.slot_a].a;
    b2Vec2 cB = f.positions[k.slot_b].c;
    float aB = f.positions[k.slot_b].a;
    float min_separation = 0.0f;
    for (int32 j = 0; j < k.point_count; ++j) {
        b2Transform xfA, xfB;
        xfA.q.Set(aA);
        xfB.q.Set(aB);
        xfA.p = cA - b2Mul(xfA.q, k.local_center_a);
        xfB.p = cB - b2Mul(xfB.q, k.local_center_b);
        b2Vec2 normal, point;
        float separation;
        switch (k.type) {
        case b2Manifold::e_circles: {
            b2Vec2 pointA = b2Mul(xfA, k.local_point);
            b2Vec2 pointB = b2Mul(xfB, k.local_points[0]);
            normal = pointB - pointA;
            normal.Normalize();
            point = 0.5f * (pointA + pointB);
            separation = b2Dot(pointB - pointA, normal) - k.radius_a - k.radius_b;
        } break;
        case b2Manifold::e_faceA: {
            normal = b2Mul(xfA.q, k.local_normal);
            b2Vec2 planePoint = b2Mul(xfA, k.local_point);
            b2Vec2 clipPoint = b2Mul(xfB, k.local_points[j]);
            separation = b2Dot(clipPoint - planePoint, normal) - k.radius_a - k.radius_b;
            point = clipPoint;
        } break;
        default: {   // e_faceB: the normal still points from A to B
            normal = b2Mul(xfB.q, k.local_normal);
            b2Vec2 planePoint = b2Mul(xfB, k.local_point);
            b2Vec2 clipPoint = b2Mul(xfA, k.local_points[j]);
            separation = b2Dot(clipPoint - planePoint, normal) - k.radius_a - k.radius_b;
            point = clipPoint;
            normal = -normal;
        } break;
        }
        b2Vec2 rA = point - cA;
        b2Vec2 rB = point - cB;
        min_separation = b2Min(min_separation, separation);
        float C = b2Clamp(b2_baumgarte * (separation + b2_linearSlop), -b2_maxLinearCorrection, 0.0f);
        float rnA = b2Cross(rA, normal);
        float rnB = b2Cross(rB, normal);
        float K = mA + mB + iA * rnA * rnA + iB * rnB * rnB;
        float impulse = K > 0.0f ? -C / K : 0.0f;
        b2Vec2 P = impulse * normal;
        cA -= mA * P;
        aA -= iA * b2Cross(rA, P);
        cB += mB * P;
        aB += iB * b2Cross(rB, P);
    }
    f.positions[k.slot_a].c = cA;
    f.positions[k.slot_a].a = aA;
    f.positions[k.slot_b].c = cB;
    f.positions[k.slot_b].a = aB;
    return min_separation;
}

}  // namespace dc
