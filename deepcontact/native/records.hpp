// The records moved between Box2D, the step files, the contact solver and Python, each from one
// field table: X(type, name, width, solver), width 2 for an (x, y) pair stored interleaved, solver
// 1 where the contact solver reads the field (its input columns are the table's solver rows).
// A field is added here (and filled in world.cpp); the state vectors, the views, the solver's
// columns, the dicts handed to Python and their checked reading back are all generated from the
// table (as MuJoCo's indexer_xmacro.h does).
#pragma once

// Every live body, in scene index order. Inertia is about the centre of mass.
#define DC_BODY_FIELDS(X)                    \
    X(int32_t, index, 1, 0)                  \
    X(int8_t, type, 1, 1)                    \
    X(float, position, 2, 0)                 \
    X(float, angle, 1, 1)                    \
    X(float, center, 2, 1)                   \
    X(float, local_center, 2, 1)             \
    X(float, velocity, 2, 1)                 \
    X(float, omega, 1, 1)                    \
    X(float, mass, 1, 1)                     \
    X(float, inv_mass, 1, 1)                 \
    X(float, inertia, 1, 0)                  \
    X(float, inv_inertia, 1, 1)              \
    X(float, linear_damping, 1, 1)           \
    X(float, angular_damping, 1, 1)          \
    X(float, gravity_scale, 1, 1)

// One row per manifold point of every contact the velocity solver sees, in island order: the
// manifold in body frames, the world manifold, the material, the shapes' collision radii, the
// solver's first iterate and what it produced. (The solver names bodies by row, not by scene
// index: ContactColumns adds row_a and row_b.) The last three are Box2D v3's alone (zero in a
// 2.4.1 step): its total normal impulse over the substeps and the point from each body's origin.
#define DC_CONTACT_FIELDS(X)                 \
    X(int32_t, manifold, 1, 1)               \
    X(int32_t, island, 1, 0)                 \
    X(int8_t, point, 1, 1)                   \
    X(int8_t, point_count, 1, 1)             \
    X(int8_t, manifold_type, 1, 1)           \
    X(int32_t, body_a, 1, 0)                 \
    X(int32_t, body_b, 1, 0)                 \
    X(int32_t, fixture_a, 1, 0)              \
    X(int32_t, fixture_b, 1, 0)              \
    X(int32_t, child_a, 1, 0)                \
    X(int32_t, child_b, 1, 0)                \
    X(uint32_t, id_key, 1, 0)                \
    X(float, local_normal, 2, 1)             \
    X(float, local_point, 2, 1)              \
    X(float, point_local, 2, 1)              \
    X(float, position, 2, 0)                 \
    X(float, normal, 2, 0)                   \
    X(float, separation, 1, 0)               \
    X(float, friction, 1, 1)                 \
    X(float, restitution, 1, 1)              \
    X(float, restitution_threshold, 1, 1)    \
    X(float, radius_a, 1, 1)                 \
    X(float, radius_b, 1, 1)                 \
    X(float, start_normal_impulse, 1, 0)     \
    X(float, start_tangent_impulse, 1, 0)    \
    X(float, normal_impulse, 1, 0)           \
    X(float, tangent_impulse, 1, 0)          \
    X(float, total_normal_impulse, 1, 0)     \
    X(float, anchor_a, 2, 0)                 \
    X(float, anchor_b, 2, 0)

// Generators for the tables. DC_IF_##solver keeps a solver row's text and drops the others'.
#define DC_IF_0(...)
#define DC_IF_1(...) __VA_ARGS__
#define DC_VECTOR_FIELD(T, name, width, solver) std::vector<T> name;
#define DC_RESERVE_FIELD(T, name, width, solver) name.reserve(rows * (width));
#define DC_POINTER_FIELD(T, name, width, solver) const T* name = nullptr;
#define DC_WIDTH_FIELD(T, name, width, solver) static constexpr int name = width;
#define DC_SOLVER_POINTER_FIELD(T, name, width, solver) DC_IF_##solver(const T* name = nullptr;)
#define DC_SOLVER_FIELD_NAME(T, name, width, solver) DC_IF_##solver(#name, )
