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
#include <type_traits>

#include "box2d_access.hpp"
#include "world.hpp"

namespace dc {

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
    f.contact_bodies.clear();
    f.static_moves = false;
    f.block_solve = block_solve_;
    for (b2Body* seed = w->GetBodyList(); seed; seed = seed->GetNext()) {
        if ((flags(seed) & kBodyIslandFlag) || !seed->IsAwake() || !seed->IsEnabled()) continue;
        if (seed->GetType() == b2_staticBody) continue;
        const size_t first_body = f.island_bodies.size(), first_contact = f.island_contacts.size();
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
                // (the edge in body A's list is the contact's node A: no read of its fixtures)
                const bool b_is_a = ce == &(c->*member(ContactNodeA()));
                f.contact_bodies.emplace_back(b_is_a ? b : other, b_is_a ? other : b);
                if (flags(other) & kBodyIslandFlag) continue;
                stack.push_back(other);
                flags(other) |= kBodyIslandFlag;
            }
        }
        f.bodies_end.push_back(static_cast<int32_t>(f.island_bodies.size()));
        f.contacts_end.push_back(static_cast<int32_t>(f.island_contacts.size()));
        // the island's contacts know their bodies' slots (a static body has one in each island);
        // the constraints are a kept buffer, grown (never cleared) to the contacts' count
        if (f.constraints.size() < f.island_contacts.size()) f.constraints.resize(f.island_contacts.size());
        for (size_t i = first_contact; i < f.island_contacts.size(); ++i) {
            f.constraints[i].slot_a = f.slot[body_index(f.contact_bodies[i].first)];
            f.constraints[i].slot_b = f.slot[body_index(f.contact_bodies[i].second)];
        }
        // static bodies may join later islands too
        for (size_t i = first_body; i < f.island_bodies.size(); ++i)
            if (f.island_bodies[i]->GetType() == b2_staticBody) flags(f.island_bodies[i]) &= ~kBodyIslandFlag;
    }
    f.constraints.resize(f.island_contacts.size());
}

// Every live body's solver row (scene index order: the rows contacts name), rotation and whether
// it was placed since its last step.
void World::place_loop_bodies() {
    loop_.row_of.assign(bodies_.size(), -1);
    loop_.rotation.resize(bodies_.size());
    loop_.stepped_rotation.resize(bodies_.size());
    loop_.placed.resize(bodies_.size());
    int32_t i = 0;
    for (b2Body* b : bodies_) {
        if (b == nullptr) continue;
        const int index = body_index(b);
        loop_.row_of[index] = i++;
        loop_.rotation[index] = loop_.stepped_rotation[index];
        loop_.placed[index] = placed(b, loop_.rotation[index].at(b->GetAngle()));
    }
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

LoopFrame& World::gather_loop() {
    find_islands();
    place_loop_bodies();
    return loop_;
}

// Every live body's v* in R (b2Island::Solve's integration and damping), by solver row; in
// double also its centre and transform (one sine and cosine a body, in this tight pass: the
// contacts' double posing reads them by row, not through the bodies, nor each contact again).
template <class R>
void World::pose_free_velocities(ContactProblem<R>& pb, const StepSettings& st) {
    pb.velocity.resize(live_bodies_);
    if constexpr (!std::is_same_v<R, float>) {
        loop_.transform64.resize(live_bodies_);
        loop_.center64.resize(live_bodies_);
    }
    size_t row = 0;
    for (b2Body* b : bodies_) {
        if (b == nullptr) continue;
        pb.velocity[row] = free_velocity<R>(
            {static_cast<int8_t>(b->GetType()), b->GetLinearVelocity().x, b->GetLinearVelocity().y,
             b->GetAngularVelocity(), b->GetMass(), b->*member(BodyInvMass()), b->*member(BodyInvI()),
             b->GetLinearDamping(), b->GetAngularDamping(), b->GetGravityScale()},
            st);
        if constexpr (!std::is_same_v<R, float>) {
            // (the transform once a body, not once each of its contacts: the same operands, the
            // same bits)
            const Rot<R> q(R(b->GetAngle()));
            const V2<R> center{R(b->GetWorldCenter().x), R(b->GetWorldCenter().y)};
            loop_.center64[row] = center;
            loop_.transform64[row] = {center - mul(q, V2<R>{R(b->GetLocalCenter().x), R(b->GetLocalCenter().y)}), q};
        }
        ++row;
    }
}

// Each island contact posed once, in one pass: its constraint in float32 for the warm start that
// applies the solution, its rows of the step's problem in R (InitializeVelocityConstraints, as
// assemble_into poses them from the columns, bit for bit) and its start; the points counted, the
// deepest penetration measured. From here until the world changes, step() solves these islands.
template <class R>
void World::pose_loop(ContactProblem<R>& pb, const StepSettings& st, bool carried, float warm_scale,
                      std::vector<double>& start_n, std::vector<double>& start_t) {
    LoopFrame& f = loop_;
    pose_free_velocities(pb, st);
    pb.stats = ProblemStats{};
    pb.manifolds.resize(f.island_contacts.size());
    start_n.clear();
    start_t.clear();
    start_n.reserve(2 * f.island_contacts.size());
    start_t.reserve(2 * f.island_contacts.size());
    float deepest = 0.0f;
    size_t first = 0;
    for (size_t i = 0; i < f.island_contacts.size(); ++i) {
        b2Contact* c = f.island_contacts[i];
        LoopFrame::Constraint& k = f.constraints[i];
        deepest = std::max(deepest, penetration(c, pose(c, k)));
        ContactManifold<R>& m = pb.manifolds[i];
        start_manifold(m, f.row_of[body_index(f.contact_bodies[i].first)], f.row_of[body_index(f.contact_bodies[i].second)],
                       first, k.point_count, c->GetFriction(), c->GetRestitution(), c->GetRestitutionThreshold(), k.mA,
                       k.mB, k.iA, k.iB, st);
        pose_geometry(m, k);
        if (k.point_count < 2) m.p[1] = ContactPoint<R>{};   // (a kept buffer: nothing stale in it)
        pose_rows(m, pb.velocity, st, pb.stats);
        // Box2D's warm start: the impulses Collide carried over by feature id, times dtRatio
        // (rounded in float32 first, as Box2D scales them); or zero.
        for (int j = 0; j < k.point_count; ++j) {
            start_n.push_back(carried ? double(warm_scale * k.manifold->points[j].normalImpulse) : 0.0);
            start_t.push_back(carried ? double(warm_scale * k.manifold->points[j].tangentImpulse) : 0.0);
        }
        first += k.point_count;
    }
    pb.points = f.points = first;
    f.deepest = deepest;
    f.finite_answer = true;   // (until an answer is written: pgs_step.cpp)
    loop_generation_ = generation_;
}

// A manifold's normal and lever arms. In float32 they are the constraint's, which pose() computed
// as b2WorldManifold::Initialize does (the same operations world_manifold makes); in double,
// world_manifold from the manifold in body frames and the bodies' centres and transforms
// (pose_free_velocities').
template <class R>
void World::pose_geometry(ContactManifold<R>& m, const LoopFrame::Constraint& k) {
    if constexpr (std::is_same_v<R, float>) {
        m.normal = {k.normal.x, k.normal.y};
        for (int j = 0; j < k.point_count; ++j) {
            m.p[j].rA = {k.rA[j].x, k.rA[j].y};
            m.p[j].rB = {k.rB[j].x, k.rB[j].y};
        }
    } else {
        const LoopFrame& f = loop_;
        const V2<R> cA = f.center64[m.a], cB = f.center64[m.b];
        const Xf<R>& xfA = f.transform64[m.a];
        const Xf<R>& xfB = f.transform64[m.b];
        if (k.type == b2Manifold::e_circles) {   // (a pile's every contact: world_manifold's case inline)
            V2<R> point;
            m.normal = circle_point(xfA, {R(k.local_point.x), R(k.local_point.y)}, R(k.radius_a), xfB,
                                    {R(k.local_points[0].x), R(k.local_points[0].y)}, R(k.radius_b), point);
            m.p[0].rA = point - cA;
            m.p[0].rB = point - cB;
            return;
        }
        // (a face manifold: face_points' case inline, each point written where it is made)
        const bool face_a = k.type == b2Manifold::e_faceA;
        const Xf<R>& ref = face_a ? xfA : xfB;
        const Xf<R>& inc = face_a ? xfB : xfA;
        const R radius_ref = R(face_a ? k.radius_a : k.radius_b), radius_inc = R(face_a ? k.radius_b : k.radius_a);
        const V2<R> normal = mul(ref.q, V2<R>{R(k.local_normal.x), R(k.local_normal.y)});
        const V2<R> plane = mul(ref, V2<R>{R(k.local_point.x), R(k.local_point.y)});
        for (int j = 0; j < k.point_count; ++j) {
            const V2<R> point = face_point(inc, radius_ref, radius_inc, normal, plane,
                                           V2<R>{R(k.local_points[j].x), R(k.local_points[j].y)});
            m.p[j].rA = point - cA;
            m.p[j].rB = point - cB;
        }
        m.normal = face_a ? normal : -normal;   // (the normal points from A to B)
    }
}

template void World::pose_loop<float>(ContactProblem<float>&, const StepSettings&, bool, float, std::vector<double>&,
                                      std::vector<double>&);
template void World::pose_loop<double>(ContactProblem<double>&, const StepSettings&, bool, float, std::vector<double>&,
                                       std::vector<double>&);

// b2World::Step's Solve for the loop: the islands found by gather_loop, stepped with no velocity
// iterations, then the fixtures synchronised and new pairs found.
void World::solve_islands(const b2TimeStep& step) {
    LoopFrame& f = loop_;
    f.positions.resize(f.island_bodies.size());
    f.velocities.resize(f.island_bodies.size());
    f.position_rotation.resize(f.island_bodies.size());
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
        synchronize_fixtures(b);
    }
    const_cast<b2ContactManager&>(w->GetContactManager()).FindNewContacts();
}

// b2Body::SynchronizeFixtures, its rotation at the step's start (a0) the one the step was posed
// with: each fixture's proxy moved in the broad-phase over the body's motion this step.
void World::synchronize_fixtures(b2Body* b) {
    b2BroadPhase* broad_phase = &const_cast<b2ContactManager&>(world_->GetContactManager()).m_broadPhase;
    const b2Transform& xf2 = b->GetTransform();
    b2Transform xf1 = xf2;
    if (b->IsAwake()) {
        const b2Sweep& sweep = b->*member(BodySweep());
        xf1.q = loop_.rotation[body_index(b)].at(sweep.a0);
        xf1.p = sweep.c0 - b2Mul(xf1.q, sweep.localCenter);
    }
    for (b2Fixture* fixture = b->GetFixtureList(); fixture; fixture = fixture->GetNext())
        (fixture->*member(FixtureSynchronize()))(broad_phase, xf1, xf2);
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
        // b2Body::SynchronizeTransform, with the rotation position correction last computed
        KeptRotation& kept = f.stepped_rotation[body_index(b)];
        kept = f.position_rotation[i];
        const b2Rot& q = kept.at(sweep.a);
        b2Transform& xf = b->*member(BodyTransform());
        xf.q = q;
        xf.p = sweep.c - b2Mul(q, sweep.localCenter);
    }
    // b2Island::Report: what the recorder keeps of a step
    if (recorder_active())
        for (int32_t i = contact_begin; i < contact_end; ++i) record_solved(f.island_contacts[i]);
}

// One contact as b2ContactSolver's constructor and InitializeVelocityConstraints pose it for its
// warm start and position correction: the manifold in body frames, the world manifold from the
// transforms the bodies' positions give (each body's rotation kept: place_loop_bodies), the normal
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
    xfA.q = f.rotation[body_index(ba)].q;
    xfB.q = f.rotation[body_index(bb)].q;
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
        xfA.q = f.position_rotation[k.slot_a].at(aA);
        xfB.q = f.position_rotation[k.slot_b].at(aB);
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
