#include "world.hpp"

#include "box2d_access.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <string>

// Box2D 2.4.1 defines this in b2_contact_solver.cpp without declaring it in a public header.
extern B2_API bool g_blockSolve;

namespace dc {
namespace {

// g_blockSolve is one flag for the whole process; worlds that differ must not race on it.
std::mutex g_step_mutex;

// A fixture's index, kept as its user data (as body_index, box2d_access.hpp).
int fixture_index(const b2Fixture* f) {
    return static_cast<int>(const_cast<b2Fixture*>(f)->GetUserData().pointer);
}

void push2(std::vector<float>& v, const b2Vec2& p) {
    v.push_back(p.x);
    v.push_back(p.y);
}

}  // namespace

// Records a step as the discrete velocity solver saw it. PreSolve sees each touching contact
// right after its manifold was rebuilt and the previous impulses matched by feature id: that,
// times dtRatio, is the solver's first iterate. Contacts between sleeping bodies are not
// rebuilt (no PreSolve) yet are solved when their island wakes: they start from the impulses
// stored before the step. PostSolve (b2Island::Report) then hands over every solved contact in
// the solver's own order, islands that fall asleep at the end of the step included.
class World::Recorder : public b2ContactListener {
public:
    explicit Recorder(World& world) : world_(world) {}
    void PreSolve(b2Contact* contact, const b2Manifold*) override {
        if (active) keep_start(contact);
    }
    void PostSolve(b2Contact* contact, const b2ContactImpulse*) override {
        if (active) world_.record_solved(contact);
    }
    void keep_start(const b2Contact* contact) {
        const b2Manifold* m = const_cast<b2Contact*>(contact)->GetManifold();
        auto& s = starts[contact];
        for (int j = 0; j < m->pointCount; ++j) {
            s[2 * j] = warm ? dt_ratio * m->points[j].normalImpulse : 0.0f;
            s[2 * j + 1] = warm ? dt_ratio * m->points[j].tangentImpulse : 0.0f;
        }
    }
    bool active = false;
    bool warm = true;
    float dt_ratio = 0.0f;
    std::unordered_map<const b2Contact*, std::array<float, 4>> starts;

private:
    World& world_;
};

World::World(float gx, float gy)
    : world_(std::make_unique<b2World>(b2Vec2(gx, gy))), recorder_(std::make_unique<Recorder>(*this)) {
    world_->SetContactListener(recorder_.get());
}

World::~World() = default;

b2Body* World::body_at(int index) const {
    if (index < 0 || index >= static_cast<int>(bodies_.size()) || bodies_[index] == nullptr)
        throw std::out_of_range("no body with index " + std::to_string(index));
    return bodies_[index];
}

int World::add_body(const BodySpec& s) {
    if (s.type < 0 || s.type > 2) throw std::invalid_argument("body type must be 0, 1 or 2");
    b2BodyDef def;
    def.type = static_cast<b2BodyType>(s.type);
    def.position.Set(s.x, s.y);
    def.angle = s.angle;
    def.linearVelocity.Set(s.vx, s.vy);
    def.angularVelocity = s.omega;
    def.linearDamping = s.linear_damping;
    def.angularDamping = s.angular_damping;
    def.fixedRotation = s.fixed_rotation;
    def.bullet = s.bullet;
    def.userData.pointer = bodies_.size();
    bodies_.push_back(world_->CreateBody(&def));
    ++live_bodies_;
    ++generation_;
    return static_cast<int>(bodies_.size()) - 1;
}

int World::add_fixture(int body, const b2Shape& shape, const Material& m) {
    b2FixtureDef def;
    def.shape = &shape;
    def.density = m.density;
    def.friction = m.friction;
    def.restitution = m.restitution;
    def.restitutionThreshold = m.restitution_threshold;
    def.userData.pointer = fixtures_.size();
    fixtures_.push_back(body_at(body)->CreateFixture(&def));
    ++generation_;
    return static_cast<int>(fixtures_.size()) - 1;
}

int World::add_circle(int body, float radius, float cx, float cy, const Material& m) {
    if (!(radius > 0.0f)) throw std::invalid_argument("circle radius must be positive");
    b2CircleShape shape;
    shape.m_radius = radius;
    shape.m_p.Set(cx, cy);
    return add_fixture(body, shape, m);
}

int World::add_polygon(int body, const std::vector<float>& xy, const Material& m) {
    const int n = static_cast<int>(xy.size() / 2);
    // Box2D asserts (or misbehaves) on these; the Python layer checks convexity first.
    if (n < 3 || n > b2_maxPolygonVertices)
        throw std::invalid_argument("a polygon needs 3 to " + std::to_string(b2_maxPolygonVertices) + " vertices");
    b2Vec2 points[b2_maxPolygonVertices];
    for (int i = 0; i < n; ++i) points[i].Set(xy[2 * i], xy[2 * i + 1]);
    b2PolygonShape shape;
    shape.Set(points, n);
    // Set() takes the convex hull after welding close points, and quietly substitutes a unit
    // box for a degenerate one: insist that every given vertex survived.
    bool kept = shape.m_count == n;
    for (int i = 0; kept && i < n; ++i)
        kept = std::find_if(shape.m_vertices, shape.m_vertices + shape.m_count, [&](const b2Vec2& v) {
                   return v.x == points[i].x && v.y == points[i].y;
               }) != shape.m_vertices + shape.m_count;
    if (!kept) throw std::invalid_argument("polygon is not strictly convex or has vertices closer than the linear slop");
    return add_fixture(body, shape, m);
}

int World::add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) {
    b2EdgeShape shape;
    shape.SetTwoSided(b2Vec2(x1, y1), b2Vec2(x2, y2));
    return add_fixture(body, shape, m);
}

void World::remove_body(int index) {
    world_->DestroyBody(body_at(index));
    bodies_[index] = nullptr;
    --live_bodies_;
    ++generation_;
}

float World::inv_dt0() const { return world_.get()->*member(WorldInvDt0()); }
// (Box2D scales the next warm start by dt * inv_dt0: a NaN or a negative one poisons it)
void World::set_inv_dt0(float value) {
    if (!(std::isfinite(value) && value >= 0.0f))
        throw std::invalid_argument("inv_dt0 must be finite and at least 0, got " + std::to_string(value));
    world_.get()->*member(WorldInvDt0()) = value;
}

BodyState World::bodies() const {
    BodyState s;
    const size_t n = live_bodies_;
    s.reserve(n);
    for (b2Body* b : bodies_) {
        if (b == nullptr) continue;
        s.index.push_back(body_index(b));
        s.type.push_back(static_cast<int8_t>(b->GetType()));
        push2(s.position, b->GetPosition());
        s.angle.push_back(b->GetAngle());
        push2(s.center, b->GetWorldCenter());
        push2(s.local_center, b->GetLocalCenter());
        push2(s.velocity, b->GetLinearVelocity());
        s.omega.push_back(b->GetAngularVelocity());
        s.mass.push_back(b->GetMass());
        s.inv_mass.push_back(b->*member(BodyInvMass()));
        s.inertia.push_back(b->*member(BodyI()));
        s.inv_inertia.push_back(b->*member(BodyInvI()));
        s.linear_damping.push_back(b->GetLinearDamping());
        s.angular_damping.push_back(b->GetAngularDamping());
        s.gravity_scale.push_back(b->GetGravityScale());
        s.fixed_rotation.push_back(b->IsFixedRotation());
    }
    return s;
}

void World::set_body_state(const int32_t* index, const float* position, const float* angle,
                           const float* velocity, const float* omega, size_t count) {
    for (size_t i = 0; i < count; ++i) {
        b2Body* b = body_at(index[i]);
        b->SetTransform(b2Vec2(position[2 * i], position[2 * i + 1]), angle[i]);
        b->SetLinearVelocity(b2Vec2(velocity[2 * i], velocity[2 * i + 1]));
        b->SetAngularVelocity(omega[i]);
    }
    ++generation_;
}

// b2World::Step (b2_world.cpp), and with `collided` the same without its Collide: the caller
// collided these very positions, so Box2D's Collide would rebuild the same manifolds and carry
// the impulses the caller wrote by feature id onto themselves. New fixtures since (Step would
// find their contacts first, then collide them) take Box2D's own Step.
void World::box2d_step(float dt, int velocity_iterations, int position_iterations, bool collided) {
    b2World* w = world_.get();
    if (!collided || w->*member(WorldNewContacts()) || w->IsLocked()) {
        w->Step(dt, velocity_iterations, position_iterations);
        return;
    }
    w->*member(WorldLocked()) = true;
    b2TimeStep step;
    step.dt = dt;
    step.velocityIterations = velocity_iterations;
    step.positionIterations = position_iterations;
    step.inv_dt = dt > 0.0f ? 1.0f / dt : 0.0f;
    step.dtRatio = w->*member(WorldInvDt0()) * dt;
    step.warmStarting = w->GetWarmStarting();
    if (w->*member(WorldStepComplete()) && step.dt > 0.0f) {
        if (solves_islands(velocity_iterations))
            solve_islands(step);
        else
            (w->*member(WorldSolve()))(step);
    }
    if (w->GetContinuousPhysics() && step.dt > 0.0f) (w->*member(WorldSolveTOI()))(step);
    if (step.dt > 0.0f) w->*member(WorldInvDt0()) = step.inv_dt;
    if (w->GetAutoClearForces()) w->ClearForces();
    w->*member(WorldLocked()) = false;
}

bool World::recorder_active() const { return recorder_->active; }

// The islands gather_loop() found are still the world's, posed as Box2D would pose them now, and
// b2World::Solve would do nothing the loop's island solve does not (no joints, no sleeping, no
// velocity iterations, no static body moved from one island to the next).
bool World::solves_islands(int velocity_iterations) const {
    return velocity_iterations == 0 && loop_generation_ == generation_ && !world_->GetAllowSleeping() &&
           world_->GetJointCount() == 0 && !loop_.static_moves && loop_.finite_answer &&
           loop_.block_solve == block_solve_;
}

void World::step(float dt, int velocity_iterations, int position_iterations, bool record, bool collided) {
    // (collided holds only if nothing changed the world since the caller's collide())
    collided = collided && collided_generation_ == generation_;
    const float inv_dt0 = this->inv_dt0();
    last_dt_ratio_ = inv_dt0 * dt;  // as b2World::Step computes step.dtRatio
    if (record) {
        recorded_bodies_ = bodies();
        // The solver rebuilds transforms from the sweep, exactly like SynchronizeTransform.
        b2Transform identity;
        identity.SetIdentity();   // (b2Transform() leaves it uninitialised; a freed body's slot keeps this)
        record_xf_.assign(bodies_.size(), identity);
        for (b2Body* b : bodies_)
            if (b != nullptr) record_xf_[body_index(b)] = b->GetTransform();
        recorded_contacts_ = ContactState();
        record_bodies_.assign(bodies_.size(), -2);  // no island yet
        record_island_ = -1;
        record_manifold_ = 0;
        recorder_->warm = world_->GetWarmStarting();
        recorder_->dt_ratio = last_dt_ratio_;
        recorder_->starts.clear();
        for (b2Contact* c = world_->GetContactList(); c; c = c->GetNext()) recorder_->keep_start(c);
    }
    {
        std::lock_guard<std::mutex> lock(g_step_mutex);
        g_blockSolve = block_solve_;
        if (record && world_->GetContinuousPhysics()) {
            // b2World::Step runs the discrete solve, then time-of-impact sub-steps that rebuild
            // and re-solve contacts. Record the first alone, then run the second as Step would:
            // it reads neither the forces Step clears nor the inv_dt0 Step sets in between.
            world_->SetContinuousPhysics(false);
            recorder_->active = true;
            box2d_step(dt, velocity_iterations, position_iterations, collided);
            recorder_->active = false;
            world_->SetContinuousPhysics(true);
            if (dt > 0.0f) {
                b2TimeStep ts;
                ts.dt = dt;
                ts.inv_dt = 1.0f / dt;
                ts.dtRatio = last_dt_ratio_;
                ts.velocityIterations = velocity_iterations;
                ts.positionIterations = position_iterations;
                ts.warmStarting = world_->GetWarmStarting();
                (world_.get()->*member(WorldSolveTOI()))(ts);
            }
        } else {
            recorder_->active = record;
            box2d_step(dt, velocity_iterations, position_iterations, collided);
            recorder_->active = false;
        }
    }
    ++generation_;
}

// One solved contact, reported by b2Island::Report in solver order. Islands are reported one
// after another, and each contact of an island after its first touches a body seen before in
// it (the depth-first search reached it through one): a contact touching no such body starts
// the next island.
void World::record_solved(b2Contact* c) {
    const int a = body_index(c->GetFixtureA()->GetBody());
    const int b = body_index(c->GetFixtureB()->GetBody());
    const bool static_a = c->GetFixtureA()->GetBody()->GetType() == b2_staticBody;
    const bool static_b = c->GetFixtureB()->GetBody()->GetType() == b2_staticBody;
    const bool seen = (!static_a && record_bodies_[a] == record_island_) ||
                      (!static_b && record_bodies_[b] == record_island_);
    if (!seen) ++record_island_;
    if (!static_a) record_bodies_[a] = record_island_;
    if (!static_b) record_bodies_[b] = record_island_;
    auto start = recorder_->starts.find(c);
    emit(recorded_contacts_, c, record_island_, record_manifold_++, record_xf_,
         start == recorder_->starts.end() ? nullptr : &start->second);
}

void World::collide() {
    const_cast<b2ContactManager&>(world_->GetContactManager()).Collide();
    collided_generation_ = ++generation_;
}

void World::find_new_contacts() {
    const_cast<b2ContactManager&>(world_->GetContactManager()).FindNewContacts();
    ++generation_;
}

ContactState World::contacts() {
    ContactState s = gather();
    gathered_generation_ = generation_;
    return s;
}

void World::set_manifold_impulses(const float* normal, const float* tangent, size_t count) {
    if (gathered_generation_ != generation_)
        throw std::runtime_error("the contacts changed since contacts() was called; call it again");
    if (count != gathered_.size())
        throw std::invalid_argument("expected " + std::to_string(gathered_.size()) +
                                    " impulses, one per contact point, got " + std::to_string(count));
    for (size_t i = 0; i < count; ++i) {
        b2ManifoldPoint& p = gathered_[i].first->GetManifold()->points[gathered_[i].second];
        p.normalImpulse = normal[i];
        p.tangentImpulse = tangent[i];
    }
}

// One row per manifold point, the world manifold computed from the given transforms.
void World::emit(ContactState& s, b2Contact* c, int island, int manifold, const std::vector<b2Transform>& xf,
                 const std::array<float, 4>* start) {
    const b2Fixture* fa = c->GetFixtureA();
    const b2Fixture* fb = c->GetFixtureB();
    const b2Body* ba = fa->GetBody();
    const b2Body* bb = fb->GetBody();
    b2Manifold* m = c->GetManifold();
    b2WorldManifold wm;
    wm.Initialize(m, xf[body_index(ba)], fa->GetShape()->m_radius, xf[body_index(bb)], fb->GetShape()->m_radius);
    for (int j = 0; j < m->pointCount; ++j) {
        const b2ManifoldPoint& p = m->points[j];
        s.manifold.push_back(manifold);
        s.island.push_back(island);
        s.point.push_back(static_cast<int8_t>(j));
        s.point_count.push_back(static_cast<int8_t>(m->pointCount));
        s.manifold_type.push_back(static_cast<int8_t>(m->type));
        s.body_a.push_back(body_index(ba));
        s.body_b.push_back(body_index(bb));
        s.fixture_a.push_back(fixture_index(fa));
        s.fixture_b.push_back(fixture_index(fb));
        s.child_a.push_back(c->GetChildIndexA());
        s.child_b.push_back(c->GetChildIndexB());
        s.id_key.push_back(p.id.key);
        push2(s.local_normal, m->localNormal);
        push2(s.local_point, m->localPoint);
        push2(s.point_local, p.localPoint);
        push2(s.position, wm.points[j]);
        push2(s.normal, wm.normal);
        s.separation.push_back(wm.separations[j]);
        s.friction.push_back(c->GetFriction());
        s.restitution.push_back(c->GetRestitution());
        s.restitution_threshold.push_back(c->GetRestitutionThreshold());
        s.radius_a.push_back(fa->GetShape()->m_radius);
        s.radius_b.push_back(fb->GetShape()->m_radius);
        s.start_normal_impulse.push_back(start ? (*start)[2 * j] : 0.0f);
        s.start_tangent_impulse.push_back(start ? (*start)[2 * j + 1] : 0.0f);
        s.normal_impulse.push_back(p.normalImpulse);
        s.tangent_impulse.push_back(p.tangentImpulse);
        s.total_normal_impulse.push_back(0.0f);   // (v3's fields: no 2.4.1 counterpart)
        s.anchor_a.insert(s.anchor_a.end(), {0.0f, 0.0f});
        s.anchor_b.insert(s.anchor_b.end(), {0.0f, 0.0f});
    }
}

// The touching contacts in the order b2World::Solve would hand them to the contact solver: a
// depth-first search over the constraint graph seeded by the body list, islands not crossing
// static bodies. Used between the pieces of a step run by our own solver (no sleeping there).
ContactState World::gather() {
    ContactState s;
    s.reserve(2 * static_cast<size_t>(world_->GetContactCount()));   // (at most two points a contact)
    gathered_.clear();
    gathered_.reserve(2 * static_cast<size_t>(world_->GetContactCount()));
    std::vector<char> body_seen(bodies_.size(), 0);
    // (a contact seen: Box2D's island flag, as b2World::Solve marks it; its Solve and the loop's
    // island search clear every contact's before they search)
    for (b2Contact* c = world_->GetContactList(); c; c = c->GetNext()) flags(c) &= ~kContactIslandFlag;
    std::vector<b2Body*> stack;
    std::vector<b2Transform> xf(bodies_.size());
    for (b2Body* b : bodies_)
        if (b != nullptr) xf[body_index(b)] = b->GetTransform();
    int island = 0, manifold = 0;

    for (b2Body* seed = world_->GetBodyList(); seed; seed = seed->GetNext()) {
        if (body_seen[body_index(seed)]) continue;
        if (!seed->IsAwake() || !seed->IsEnabled() || seed->GetType() == b2_staticBody) continue;
        stack.push_back(seed);
        body_seen[body_index(seed)] = 1;
        bool any = false;
        while (!stack.empty()) {
            b2Body* b = stack.back();
            stack.pop_back();
            for (b2ContactEdge* ce = b->GetContactList(); ce; ce = ce->next) {
                b2Contact* c = ce->contact;
                if (flags(c) & kContactIslandFlag) continue;
                if (!c->IsEnabled() || !c->IsTouching()) continue;
                if (c->GetFixtureA()->IsSensor() || c->GetFixtureB()->IsSensor()) continue;
                flags(c) |= kContactIslandFlag;
                emit(s, c, island, manifold++, xf, nullptr);
                for (int j = 0; j < c->GetManifold()->pointCount; ++j) gathered_.emplace_back(c, j);
                any = true;
                b2Body* other = ce->other;
                // Box2D pushes static bodies too but never searches from them: skipping
                // them leaves the order of everything else unchanged.
                if (other->GetType() == b2_staticBody || body_seen[body_index(other)]) continue;
                stack.push_back(other);
                body_seen[body_index(other)] = 1;
            }
        }
        if (any) ++island;
    }
    return s;
}

}  // namespace dc
