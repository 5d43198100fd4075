// A Box2D world built from a scene and stepped whole, with its state moved in and
// out as flat arrays (structure of arrays). No Python here: module.cpp does the glue.
#pragma once

#include <box2d/box2d.h>

#include <array>
#include <cstdint>
#include <memory>
#include <unordered_map>
#include <utility>
#include <vector>

#include "loop_frame.hpp"
#include "records.hpp"
#include "state.hpp"

namespace dc {

class LaggedFactor;   // (lagged_factor.hpp)

class World : public SceneWorld {
public:
    World(float gravity_x, float gravity_y);
    ~World() override;
    World(const World&) = delete;
    World& operator=(const World&) = delete;

    int add_body(const BodySpec& spec) override;
    int add_circle(int body, float radius, float cx, float cy, const Material& m) override;
    int add_polygon(int body, const std::vector<float>& xy, const Material& m) override;
    int add_edge(int body, float x1, float y1, float x2, float y2, const Material& m) override;
    void remove_body(int body);

    // One Box2D step. With record, the body state before the step and the solved
    // contacts (world points computed from the start-of-step transforms, as the solver does)
    // are kept for recorded_bodies() / recorded_contacts().
    // collided: the caller ran collide() on these very positions (the loop's own step): Box2D's
    // Step then skips its Collide, which would rebuild the same manifolds a second time.
    void step(float dt, int velocity_iterations, int position_iterations, bool record, bool collided = false);

    // The pieces of a step, for a solver of our own: Collide, our solve, Step with no velocity
    // iterations (docs/solver.md, "The loop").
    void collide();
    void find_new_contacts();
    // Touching contacts in island order, world points from the current transforms.
    ContactState contacts();
    // Writes impulses into the manifold points of the contacts last returned by contacts().
    void set_manifold_impulses(const float* normal, const float* tangent, size_t count);

    // The loop's step read out once (pgs_step.cpp), after collide(): the islands as b2World::Solve
    // finds them, kept from step to step; then pose_loop poses each of their contacts once, in
    // the solve's precision R (float or double) and in Box2D's float32 for the warm start that
    // applies the solution, with its start (the carried impulses times warm_scale, or zero).
    // Until the world changes, step(..., collided) then steps those islands itself with no
    // velocity iterations (world_loop.cpp) instead of running Box2D's Solve, which would find
    // them again and pose every contact's constraint a second time.
    LoopFrame& gather_loop();
    LoopFrame& loop_frame() { return loop_; }
    // Whether pose_loop's step is still the world's (nothing changed it since).
    bool posed_now() const { return loop_generation_ == generation_; }
    template <class R>
    void pose_loop(ContactProblem<R>& pb, const StepSettings& st, bool carried, float warm_scale,
                   std::vector<double>& start_n, std::vector<double>& start_t);

    BodyState bodies() const;
    void set_body_state(const int32_t* index, const float* position, const float* angle,
                        const float* velocity, const float* omega, size_t count);

    const BodyState& recorded_bodies() const { return recorded_bodies_; }
    const ContactState& recorded_contacts() const { return recorded_contacts_; }
    float last_dt_ratio() const { return last_dt_ratio_; }

    bool continuous() const { return world_->GetContinuousPhysics(); }
    void set_continuous(bool on) { world_->SetContinuousPhysics(on); }
    bool sleeping() const { return world_->GetAllowSleeping(); }
    void set_sleeping(bool on) { world_->SetAllowSleeping(on); }
    bool warm_starting() const { return world_->GetWarmStarting(); }
    void set_warm_starting(bool on) { world_->SetWarmStarting(on); }
    bool block_solve() const { return block_solve_; }
    void set_block_solve(bool on) { block_solve_ = on; }
    // 1/dt of the previous step (0 before the first): Box2D scales warm starts by dt * this.
    float inv_dt0() const;
    void set_inv_dt0(float value);

    int body_count() const { return live_bodies_; }
    int fixture_count() const { return static_cast<int>(fixtures_.size()); }

    // What the project's solver keeps from one step of the native loop to the next (pgs_step):
    // the lagged method's factor (empty until that method runs), made on the loop's first step.
    std::shared_ptr<LaggedFactor> carried_factor;

private:
    class Recorder;
    b2Body* body_at(int index) const;
    int add_fixture(int body, const b2Shape& shape, const Material& m);
    ContactState gather();
    void record_solved(b2Contact* contact);
    static void emit(ContactState& s, b2Contact* c, int island, int manifold, const std::vector<b2Transform>& xf,
                     const std::array<float, 4>* start);

    std::unique_ptr<b2World> world_;
    std::unique_ptr<Recorder> recorder_;
    std::vector<b2Body*> bodies_;        // by scene index; nullptr once removed
    std::vector<b2Fixture*> fixtures_;   // by fixture index
    int live_bodies_ = 0;
    bool block_solve_ = true;
    float last_dt_ratio_ = 0.0f;

    BodyState recorded_bodies_;
    ContactState recorded_contacts_;
    std::vector<b2Transform> record_xf_;
    size_t collided_generation_ = 0;   // generation_ right after the last collide()
    void box2d_step(float dt, int velocity_iterations, int position_iterations, bool collided);   // the bodies' transforms at the start of the step
    bool recorder_active() const;

    // The loop's own island solve (world_loop.cpp).
    bool solves_islands(int velocity_iterations) const;
    void find_islands();
    void place_loop_bodies();
    template <class R>
    void pose_free_velocities(ContactProblem<R>& pb, const StepSettings& st);
    template <class R>
    void pose_geometry(ContactManifold<R>& m, const LoopFrame::Constraint& k);
    void solve_islands(const b2TimeStep& step);
    void synchronize_fixtures(b2Body* body);
    void solve_island(const b2TimeStep& step, int32_t body_begin, int32_t body_end, int32_t contact_begin,
                      int32_t contact_end);
    b2WorldManifold pose(b2Contact* contact, LoopFrame::Constraint& constraint) const;
    static bool placed(const b2Body* body, const b2Rot& rotation);
    float penetration(b2Contact* contact, const b2WorldManifold& posed) const;
    void apply_impulses(const b2TimeStep& step, const LoopFrame::Constraint& constraint);
    float correct_positions(const LoopFrame::Constraint& constraint);
    LoopFrame loop_;
    std::vector<b2Body*> loop_stack_;
    uint64_t loop_generation_ = ~uint64_t(0);   // generation_ when gather_loop() ran
    std::vector<int> record_bodies_;       // the island each body was last seen in
    int record_island_ = -1, record_manifold_ = 0;

    // contacts() remembers which (contact, point) each row was, for set_manifold_impulses;
    // any change to the contact set makes that list stale.
    std::vector<std::pair<b2Contact*, int>> gathered_;
    uint64_t generation_ = 0, gathered_generation_ = ~uint64_t(0);
};

}  // namespace dc
