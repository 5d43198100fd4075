// What the loop's step (pgs_step.cpp) reads out of a Box2D world once a step, into buffers kept
// from step to step: the islands as b2World::Solve builds them, and the solver's columns of their
// bodies and contact points (records.hpp's solver rows, and nothing else).
#pragma once

#include <box2d/box2d.h>

#include <cstdint>
#include <vector>

#include "contact_problem.hpp"
#include "records.hpp"

namespace dc {

struct LoopFrame {
    // The islands in b2World::Solve's order: their bodies (static ones included, as Box2D adds
    // them) and touching contacts, each island's end in both lists.
    std::vector<b2Body*> island_bodies;
    std::vector<b2Contact*> island_contacts;
    std::vector<int32_t> bodies_end, contacts_end;

    // The solver's columns: every live body in scene index order; every point of the islands'
    // contacts in island order, with what Collide carried over by feature id.
#define DC_LOOP_COLUMN(T, name, width, solver) DC_IF_##solver(std::vector<T> name;)
    struct Bodies {
        DC_BODY_FIELDS(DC_LOOP_COLUMN)
    } bodies;
    struct Contacts {
        DC_CONTACT_FIELDS(DC_LOOP_COLUMN)
        std::vector<int32_t> row_a, row_b;
        std::vector<float> normal_impulse, tangent_impulse;
    } contacts;
#undef DC_LOOP_COLUMN
    size_t body_count = 0, points = 0;
    float deepest = 0.0f;   // deepest penetration among the points (m), >= 0

    // Scratch of the island solve: each island body's state, and where a body sits in its island.
    std::vector<b2Position> positions;
    std::vector<b2Velocity> velocities;
    std::vector<int32_t> slot, row_of;

    BodyColumns body_columns() const;
    ContactColumns contact_columns() const;
};

}  // namespace dc
