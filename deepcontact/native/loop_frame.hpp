// What the loop's step (pgs_step.cpp) reads out of a Box2D world once a step, into buffers kept
// from step to step: the islands as b2World::Solve builds them, each of their contacts posed once
// in Box2D's float32 arithmetic (the constraint its warm start and position correction read), and
// the step's problem posed from those in the solve's precision.
#pragma once

#include <box2d/box2d.h>

#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

#include "contact_problem.hpp"

namespace dc {

// A rotation kept with the angle it was computed from: b2Rot::Set of the same angle, bit for bit,
// gives the same rotation, so a body's sine and cosine are computed again only where its angle
// moved (Box2D's position correction computes both bodies' at every contact point, and its
// transform each body's again).
struct KeptRotation {
    static constexpr uint64_t kNone = uint64_t(1) << 32;   // (no float's bits)
    uint64_t angle = kNone;
    b2Rot q;
    const b2Rot& at(float a) {
        uint32_t bits;
        std::memcpy(&bits, &a, sizeof bits);
        if (bits != angle) {
            q.Set(a);
            angle = bits;
        }
        return q;
    }
};

struct LoopFrame {
    // The islands in b2World::Solve's order: their bodies (static ones included, as Box2D adds
    // them) and touching contacts, each island's end in both lists.
    std::vector<b2Body*> island_bodies;
    std::vector<b2Contact*> island_contacts;
    std::vector<std::pair<b2Body*, b2Body*>> contact_bodies;   // per island contact: its bodies A and B
    std::vector<int32_t> bodies_end, contacts_end;
    // A static body given a velocity (a body definition keeps one) is moved by every island it is
    // in, and Box2D poses a later island's contacts where an earlier one left it: its own Solve
    // steps such islands.
    bool static_moves = false;
    // Every impulse written into the manifolds is finite. A NaN or infinite one (an answer from a
    // start used as given, exact mode) makes the static bodies it touches NaN, and Box2D poses a
    // later island's contacts from them: its own Solve steps such a step too.
    bool finite_answer = true;
    bool block_solve = true;   // the setting the redundant pairs were cut with

    size_t points = 0;      // the islands' contact points
    bool posed_float64 = false;   // the precision of the problem posed last (pgs_pose)
    float deepest = 0.0f;   // deepest penetration among the points (m), >= 0

    // Per island contact, b2ContactSolver's constraint as its warm start, StoreImpulses and
    // position correction read it (in Box2D's float32 arithmetic, whatever precision the solve is
    // in): the bodies' slots in the island arrays and their inverse masses, the manifold in body
    // frames, and what InitializeVelocityConstraints computes for the warm start (the normal, the
    // lever arms, the points kept: a redundant pair is cut to its first).
    struct Constraint {
        b2Manifold* manifold;
        int32_t slot_a, slot_b;
        float mA, mB, iA, iB;
        b2Vec2 local_center_a, local_center_b;
        b2Vec2 local_normal, local_point, local_points[b2_maxManifoldPoints];
        float radius_a, radius_b;
        b2Manifold::Type type;
        int32_t point_count;   // the manifold's (positions correct every point)
        int32_t count;         // the warm start's
        b2Vec2 normal;
        b2Vec2 rA[b2_maxManifoldPoints], rB[b2_maxManifoldPoints];
    };
    std::vector<Constraint> constraints;
    // Each live body's rotation by scene index: as the step is posed (its sweep's angle then, the
    // step's a0 once stepped), and as the island solve left its transform (the next step's).
    std::vector<KeptRotation> rotation, stepped_rotation;
    // By scene index: the body's transform is not the one its sweep gives (placed since its last
    // step: created or set_body_state, where Box2D keeps the position given).
    std::vector<uint8_t> placed;

    // The island solve's state, one slot per island body; where each body sits in the island
    // being searched (scene index); each live body's solver row (scene index).
    std::vector<b2Position> positions;
    std::vector<b2Velocity> velocities;
    std::vector<KeptRotation> position_rotation;   // (slot: position correction's)
    std::vector<int32_t> slot, row_of;

    // The step's problem, posed into buffers kept from step to step (one for each precision), and
    // each live body's centre and transform in double by solver row (the double posing's).
    ContactProblem<float> problem32;
    ContactProblem<double> problem64;
    std::vector<V2<double>> center64;
    std::vector<Xf<double>> transform64;
};

}  // namespace dc
