// The contact problem of one step, as Box2D's velocity solver sees it: per contact point the
// lever arms, effective normal and tangent masses and restitution bias, per manifold the 2x2
// block for two-point manifolds, per body the velocity after gravity and damping.
//
// Templated on the scalar. Every expression keeps the operand order of Box2D 2.4.1's own
// (b2_island.cpp, b2_contact_solver.cpp, b2WorldManifold::Initialize), so that with R = float
// and no FMA contraction the numbers are Box2D's, bit for bit.
#pragma once

#include <algorithm>

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "records.hpp"

namespace dc {

template <class R>
struct V2 {
    R x, y;
};
template <class R> inline V2<R> operator+(V2<R> a, V2<R> b) { return {a.x + b.x, a.y + b.y}; }
template <class R> inline V2<R> operator-(V2<R> a, V2<R> b) { return {a.x - b.x, a.y - b.y}; }
template <class R> inline V2<R> operator-(V2<R> a) { return {-a.x, -a.y}; }
template <class R> inline V2<R> operator*(R s, V2<R> a) { return {s * a.x, s * a.y}; }
template <class R> inline R dot(V2<R> a, V2<R> b) { return a.x * b.x + a.y * b.y; }
template <class R> inline R cross(V2<R> a, V2<R> b) { return a.x * b.y - a.y * b.x; }
template <class R> inline V2<R> cross(V2<R> a, R s) { return {s * a.y, -s * a.x}; }
template <class R> inline V2<R> cross(R s, V2<R> a) { return {-s * a.y, s * a.x}; }

template <class R>
struct Rot {
    R s, c;
    explicit Rot(R angle) : s(std::sin(angle)), c(std::cos(angle)) {}  // sinf/cosf for float
    Rot() : s(0), c(1) {}
};
template <class R> inline V2<R> mul(const Rot<R>& q, V2<R> v) { return {q.c * v.x - q.s * v.y, q.s * v.x + q.c * v.y}; }
template <class R>
struct Xf {
    V2<R> p;
    Rot<R> q;
};
template <class R>
inline V2<R> mul(const Xf<R>& t, V2<R> v) {
    R x = (t.q.c * v.x - t.q.s * v.y) + t.p.x;
    R y = (t.q.s * v.x + t.q.c * v.y) + t.p.y;
    return {x, y};
}

// 2x2 matrix stored by columns, as b2Mat22.
template <class R>
struct M22 {
    V2<R> ex{0, 0}, ey{0, 0};
    M22 inverse() const {
        R a = ex.x, b = ey.x, c = ex.y, d = ey.y;
        M22 B;
        R det = a * d - b * c;
        if (det != R(0)) det = R(1) / det;
        B.ex.x = det * d;
        B.ey.x = -det * b;
        B.ex.y = -det * c;
        B.ey.y = det * a;
        return B;
    }
};
template <class R> inline V2<R> mul(const M22<R>& A, V2<R> v) { return {A.ex.x * v.x + A.ey.x * v.y, A.ex.y * v.x + A.ey.y * v.y}; }

template <class R>
struct ContactPoint {
    V2<R> rA, rB;
    R normal_mass, tangent_mass;
    R k_normal, k_tangent;  // effective inverse masses: velocity change per unit impulse
    R bias;                 // restitution velocity bias
    R normal_impulse, tangent_impulse;
};

template <class R>
struct ContactManifold {
    int32_t a, b;           // body rows
    int32_t first;          // first point row in the caller's arrays
    int32_t count;          // points the solver uses (Box2D drops one of an ill-conditioned pair)
    int32_t given;          // points given
    bool friction_row;      // tangent rows present (friction > 0)
    bool angular;           // any rotational inertia on either side
    bool block;             // 2x2 block solver for the normal rows
    V2<R> normal;
    R friction;
    R mA, mB, iA, iB;
    // What a sweep reads of a one-point manifold first, so that it spans the fewest cache lines
    // (a pile's manifolds are one point each); a pair's block after its points.
    ContactPoint<R> p[2];
    M22<R> K, normal_mass;
    R restitution, threshold;   // (read only where the rows are posed)
};

template <class R>
struct BodyVelocity {
    V2<R> v;
    R w;
};

// The solver's inputs: borrowed float32 columns (as Box2D stores them) of the records' solver
// rows (records.hpp), n rows each; contacts name their bodies by row.
struct BodyColumns {
    size_t n = 0;
    DC_BODY_FIELDS(DC_SOLVER_POINTER_FIELD)
};

struct ContactColumns {
    size_t n = 0;
    DC_CONTACT_FIELDS(DC_SOLVER_POINTER_FIELD)
    const int32_t *row_a = nullptr, *row_b = nullptr;
};

// The names of those columns, for the Python layer (solver/problem.py).
inline const char* const kSolverBodyFields[] = {DC_BODY_FIELDS(DC_SOLVER_FIELD_NAME)};
inline const char* const kSolverContactFields[] = {DC_CONTACT_FIELDS(DC_SOLVER_FIELD_NAME)};

struct StepSettings {
    float dt = 0;
    float gravity[2] = {0, 0};
    bool block_solve = true;
    bool prune = true;  // leave out what the scene does not need (tangent rows without friction, ...)
};

// Throws std::invalid_argument (ValueError in Python) naming what is wrong.
inline void check(const StepSettings& st) {
    if (!(st.dt > 0.0f) || !std::isfinite(st.dt)) throw std::invalid_argument("dt must be positive and finite");
    if (!std::isfinite(st.gravity[0]) || !std::isfinite(st.gravity[1]))
        throw std::invalid_argument("gravity must be finite");
}

// The largest inverse mass or inertia a body may have: a body of 1e-20 kg (the lightest a scene
// file may hold, and float32's rounding of 1 / 1e-20 just above it); beyond it the problem is
// degenerate, and no residual means anything.
constexpr double kMaxInverse = 1.00001e20;

inline std::string shown_number(double value) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", value);
    return text;
}

template <class T>
void check_finite(const T* column, size_t values, int width, const char* table, const char* name) {
    if constexpr (std::is_floating_point_v<T>) {
        for (size_t i = 0; i < values; ++i)
            if (!std::isfinite(column[i]))
                throw std::invalid_argument(std::string(table) + " column '" + name + "' holds a value that is not finite (row " +
                                            std::to_string(i / width) + ")");
    }
}

// What a step file's reader holds every value to, for columns handed in directly (a notebook's
// edit): every float the solver reads finite (from the field tables), inverse masses and inertias
// in [0, kMaxInverse], friction and restitution not negative. Throws std::invalid_argument.
inline void check(const BodyColumns& bc, const ContactColumns& cc) {
#define DC_CHECK_BODY(T, name, width, solver) DC_IF_##solver(check_finite(bc.name, bc.n * width, width, "bodies", #name);)
#define DC_CHECK_CONTACT(T, name, width, solver) DC_IF_##solver(check_finite(cc.name, cc.n * width, width, "contacts", #name);)
    DC_BODY_FIELDS(DC_CHECK_BODY)
    DC_CONTACT_FIELDS(DC_CHECK_CONTACT)
#undef DC_CHECK_BODY
#undef DC_CHECK_CONTACT
    for (size_t i = 0; i < bc.n; ++i)
        for (const auto& [name, value] : {std::pair{"inv_mass", bc.inv_mass[i]}, std::pair{"inv_inertia", bc.inv_inertia[i]}})
            if (!(value >= 0 && value <= kMaxInverse))
                throw std::invalid_argument(std::string("bodies column '") + name + "' is " + shown_number(value) +
                                            " at row " + std::to_string(i) +
                                            ": an inverse mass or inertia is from 0 to 1e20 (a body of at least 1e-20 kg, as scene files hold)");
    for (size_t k = 0; k < cc.n; ++k)
        for (const auto& [name, value] : {std::pair{"friction", cc.friction[k]}, std::pair{"restitution", cc.restitution[k]}})
            if (value < 0)
                throw std::invalid_argument(std::string("contacts column '") + name + "' is negative at row " + std::to_string(k));
}

// The size of a step's problem, reported with every solve: one table for the struct and its dict.
#define DC_PROBLEM_STATS(X) \
    X(manifolds) X(points) X(normal_rows) X(tangent_rows) X(block_manifolds) X(dropped_points) X(angular_manifolds) X(bias_rows)
#define DC_STAT_FIELD(name) int64_t name = 0;

struct ProblemStats {
    DC_PROBLEM_STATS(DC_STAT_FIELD)
};

template <class R>
struct ContactProblem {
    std::vector<ContactManifold<R>> manifolds;
    std::vector<BodyVelocity<R>> velocity;  // after gravity and damping: the solver's v*
    ProblemStats stats;
    size_t points = 0;
    std::vector<int32_t> order;             // the manifolds in a sweep's order (empty: as posed)
};

// pb.order for Order::gravity: the manifolds from the highest to the lowest, height(i) the height
// of manifold i along gravity; ties keep the posed order (a stable sort). A radix sort of the
// heights' bits, three passes of 11: a stable comparison sort cost a 1000-circle pile's step about
// 35 us, most of what the order cost it. (-0 counts as 0, as a comparison has it: tested on the
// bits, which no compiler's treatment of signed zeros can drop.)
template <class R, class Height>
void order_by_height(ContactProblem<R>& pb, Height height) {
    const size_t n = pb.manifolds.size();
    std::vector<uint32_t> key(n);
    for (size_t i = 0; i < n; ++i) {
        const float h = height(i);
        uint32_t u;
        std::memcpy(&u, &h, sizeof u);
        if (u == 0x80000000u) u = 0;                         // (-0 as +0)
        u = (u & 0x80000000u) ? ~u : (u | 0x80000000u);   // (ascending as the floats are)
        key[i] = ~u;                                        // (the highest first)
    }
    std::vector<int32_t> from(n), to(n);
    for (size_t i = 0; i < n; ++i) from[i] = static_cast<int32_t>(i);
    for (int shift = 0; shift < 33; shift += 11) {
        size_t count[2049] = {0};
        for (size_t i = 0; i < n; ++i) ++count[((key[from[i]] >> shift) & 2047u) + 1];
        for (size_t b = 1; b < 2049; ++b) count[b] += count[b - 1];
        for (size_t i = 0; i < n; ++i) to[count[(key[from[i]] >> shift) & 2047u]++] = from[i];
        from.swap(to);
    }
    pb.order.swap(from);
}

// One point of a face manifold (b2WorldManifold::Initialize): the incident body's clip point
// halfway between it and its projection onto the reference body's face (normal, plane: the face
// in world coordinates). (Box2D adds the two in the order A, B; addition commutes, so the bits are
// Box2D's either way.)
template <class R>
inline V2<R> face_point(const Xf<R>& inc, R radius_ref, R radius_inc, V2<R> normal, V2<R> plane, V2<R> point_local) {
    V2<R> clip = mul(inc, point_local);
    V2<R> on_ref = clip + (radius_ref - dot(clip - plane, normal)) * normal;
    V2<R> on_inc = clip - radius_inc * normal;
    return R(0.5) * (on_ref + on_inc);
}

// A face manifold's points (face_point each); returns the face normal.
template <class R>
V2<R> face_points(const Xf<R>& ref, R radius_ref, const Xf<R>& inc, R radius_inc, V2<R> local_normal,
                  V2<R> local_point, const V2<R>* point_local, int count, V2<R>* points) {
    const V2<R> normal = mul(ref.q, local_normal);
    const V2<R> plane = mul(ref, local_point);
    for (int i = 0; i < count; ++i) points[i] = face_point(inc, radius_ref, radius_inc, normal, plane, point_local[i]);
    return normal;
}

// pb.order for Order::gravity: order_by_height with each manifold's height its higher body's
// centre along -gravity; centres(i) gives manifold i's bodies' centres, A's then B's (the body
// columns' by row, or the loop's bodies as posed). A scene without gravity keeps the posed order.
template <class R, class Centres>
void gravity_order(ContactProblem<R>& pb, const float gravity[2], Centres centres) {
    const float gx = -gravity[0], gy = -gravity[1];
    pb.order.clear();
    if (gx == 0.0f && gy == 0.0f) return;
    order_by_height(pb, [&](size_t i) {
        const auto [a, b] = centres(i);
        return std::max(gx * a.x + gy * a.y, gx * b.x + gy * b.y);
    });
}

// b2WorldManifold::Initialize of a circles manifold: its one point, and the normal returned.
template <class R>
inline V2<R> circle_point(const Xf<R>& xfA, V2<R> local_point, R radiusA, const Xf<R>& xfB, V2<R> point_local,
                          R radiusB, V2<R>& point) {
    const R eps = R(FLT_EPSILON);
    V2<R> normal{R(1), R(0)};
    V2<R> pointA = mul(xfA, local_point);
    V2<R> pointB = mul(xfB, point_local);
    V2<R> d = pointA - pointB;
    if (d.x * d.x + d.y * d.y > eps * eps) {
        normal = pointB - pointA;
        R length = std::sqrt(normal.x * normal.x + normal.y * normal.y);
        if (!(length < eps)) {
            R inv = R(1) / length;
            normal.x *= inv;
            normal.y *= inv;
        }
    }
    V2<R> cA = pointA + radiusA * normal;
    V2<R> cB = pointB - radiusB * normal;
    point = R(0.5) * (cA + cB);
    return normal;
}

// Box2D's b2WorldManifold::Initialize.
template <class R>
void world_manifold(int type, V2<R> local_normal, V2<R> local_point, const V2<R>* point_local, int count,
                    const Xf<R>& xfA, R radiusA, const Xf<R>& xfB, R radiusB, V2<R>& normal, V2<R>* points) {
    if (type == 0) {  // circles
        normal = circle_point(xfA, local_point, radiusA, xfB, point_local[0], radiusB, points[0]);
    } else if (type == 1) {  // face A
        normal = face_points(xfA, radiusA, xfB, radiusB, local_normal, local_point, point_local, count, points);
    } else {  // face B: the normal still points from A to B
        normal = -face_points(xfB, radiusB, xfA, radiusA, local_normal, local_point, point_local, count, points);
    }
}

// The 2x2 block of a two-point manifold's normal rows (b2ContactSolver::InitializeVelocityConstraints),
// from each point's lever arms crossed with the normal; Box2D keeps the pair for its block solver
// where K's condition number is under 1000, else solves the first point only.
template <class R>
struct PairBlock {
    R k11, k12, k22;
    bool kept() const { return k11 * k11 < R(1000) * (k11 * k22 - k12 * k12); }
};

template <class R>
PairBlock<R> pair_block(R mA, R mB, R iA, R iB, R rn1A, R rn1B, R rn2A, R rn2B) {
    return {mA + mB + iA * rn1A * rn1A + iB * rn1B * rn1B, mA + mB + iA * rn1A * rn2A + iB * rn1B * rn2B,
            mA + mB + iA * rn2A * rn2A + iB * rn2B * rn2B};
}

// One body's values as Box2D stores them (float32), what the solver's v* is made from.
struct FreeBody {
    int8_t type;   // b2BodyType: 2 is dynamic
    float vx, vy, omega, mass, inv_mass, inv_inertia, linear_damping, angular_damping, gravity_scale;
};

// b2Island::Solve for one body: integrate its velocity, then damping (dynamic bodies only).
template <class R>
BodyVelocity<R> free_velocity(const FreeBody& body, const StepSettings& st) {
    const R h = R(st.dt);
    const V2<R> gravity{R(st.gravity[0]), R(st.gravity[1])};
    const bool has_gravity = gravity.x != R(0) || gravity.y != R(0);
    V2<R> v{R(body.vx), R(body.vy)};
    R w = R(body.omega);
    if (body.type == 2) {
        const R inv_mass = R(body.inv_mass);
        if (has_gravity || !st.prune) {
            const V2<R> force = (R(body.gravity_scale) * R(body.mass)) * gravity + V2<R>{R(0), R(0)};
            v = v + (h * inv_mass) * force;
            w = w + h * R(body.inv_inertia) * R(0);
        }
        const R ld = R(body.linear_damping), ad = R(body.angular_damping);
        if (ld != R(0) || ad != R(0) || !st.prune) {
            const R sv = R(1) / (R(1) + h * ld);
            v.x *= sv;
            v.y *= sv;
            w *= R(1) / (R(1) + h * ad);
        }
    }
    return {v, w};
}

// A manifold's bodies (rows, inverse masses) and material, before its geometry: what the solver
// keeps of it, no block yet.
template <class R>
void start_manifold(ContactManifold<R>& m, int32_t a, int32_t b, size_t first, int count, float friction,
                    float restitution, float threshold, float mA, float mB, float iA, float iB, const StepSettings& st) {
    m.a = a;
    m.b = b;
    m.first = static_cast<int32_t>(first);
    m.count = m.given = count;
    m.friction = R(friction);
    m.restitution = R(restitution);
    m.threshold = R(threshold);
    m.mA = R(mA);
    m.mB = R(mB);
    m.iA = R(iA);
    m.iB = R(iB);
    m.friction_row = !st.prune || m.friction > R(0);
    m.angular = !st.prune || m.iA != R(0) || m.iB != R(0);
    m.block = false;
    m.K = M22<R>{};
    m.normal_mass = M22<R>{};
}

// b2ContactSolver::InitializeVelocityConstraints for a manifold whose bodies, normal and lever
// arms are set: each point's effective masses and restitution bias, then the block solver's 2x2
// block of a two-point manifold (or its cut to the first point); counted in stats.
template <class R>
void pose_rows(ContactManifold<R>& m, const std::vector<BodyVelocity<R>>& velocity, const StepSettings& st,
               ProblemStats& stats) {
    const R mA = m.mA, mB = m.mB, iA = m.iA, iB = m.iB;
    const V2<R> vA = velocity[m.a].v, vB = velocity[m.b].v;
    const R wA = velocity[m.a].w, wB = velocity[m.b].w;
    const V2<R> tangent = cross(m.normal, R(1));
    for (int j = 0; j < m.given; ++j) {
        ContactPoint<R>& p = m.p[j];
        R rnA = cross(p.rA, m.normal);
        R rnB = cross(p.rB, m.normal);
        R kNormal = mA + mB + iA * rnA * rnA + iB * rnB * rnB;
        p.k_normal = kNormal;
        p.normal_mass = kNormal > R(0) ? R(1) / kNormal : R(0);
        R rtA = cross(p.rA, tangent);
        R rtB = cross(p.rB, tangent);
        R kTangent = mA + mB + iA * rtA * rtA + iB * rtB * rtB;
        p.k_tangent = kTangent;
        p.tangent_mass = kTangent > R(0) ? R(1) / kTangent : R(0);
        p.bias = R(0);
        if (m.restitution != R(0) || !st.prune) {
            R vRel = dot(m.normal, vB + cross(wB, p.rB) - vA - cross(wA, p.rA));
            if (vRel < -m.threshold) {
                p.bias = -m.restitution * vRel;
                ++stats.bias_rows;
            }
        }
    }
    if (m.given == 2 && st.block_solve) {
        const ContactPoint<R>& p1 = m.p[0];
        const ContactPoint<R>& p2 = m.p[1];
        const PairBlock<R> pair = pair_block(mA, mB, iA, iB, cross(p1.rA, m.normal), cross(p1.rB, m.normal),
                                             cross(p2.rA, m.normal), cross(p2.rB, m.normal));
        if (pair.kept()) {
            m.K.ex = {pair.k11, pair.k12};
            m.K.ey = {pair.k12, pair.k22};
            m.normal_mass = m.K.inverse();
            m.block = true;
        } else {
            m.count = 1;  // redundant pair: Box2D solves the first point only
            ++stats.dropped_points;
        }
    }
    stats.manifolds += 1;
    stats.points += m.given;
    stats.normal_rows += m.count;
    stats.tangent_rows += m.friction_row ? m.count : 0;
    stats.block_manifolds += m.block;
    stats.angular_manifolds += m.angular;
}

// The problem posed from the columns into pb, whose buffers are reused.
template <class R>
void assemble_into(ContactProblem<R>& pb, const BodyColumns& bc, const ContactColumns& cc, const StepSettings& st) {
    pb.manifolds.clear();
    pb.stats = ProblemStats{};

    pb.velocity.resize(bc.n);
    for (size_t i = 0; i < bc.n; ++i)
        pb.velocity[i] = free_velocity<R>({bc.type[i], bc.velocity[2 * i], bc.velocity[2 * i + 1], bc.omega[i], bc.mass[i],
                                           bc.inv_mass[i], bc.inv_inertia[i], bc.linear_damping[i],
                                           bc.angular_damping[i], bc.gravity_scale[i]},
                                          st);

    // b2ContactSolver::InitializeVelocityConstraints, manifold by manifold in the given order.
    // Each body's rotation is computed once (a body touches several manifolds; the same angle
    // gives the same sine and cosine, so the result is Box2D's bit for bit).
    std::vector<Rot<R>> rotation(bc.n);
    std::vector<uint8_t> rotated(bc.n, 0);
    auto rot = [&](int32_t i) -> const Rot<R>& {
        if (!rotated[i]) {
            rotation[i] = Rot<R>(R(bc.angle[i]));
            rotated[i] = 1;
        }
        return rotation[i];
    };
    pb.manifolds.reserve(cc.n);   // (at most one a point)
    size_t k = 0;
    while (k < cc.n) {
        const int32_t m_id = cc.manifold[k];
        const int count = cc.point_count[k];
        if (count < 1 || count > 2 || k + count > cc.n)
            throw std::invalid_argument("contact point " + std::to_string(k) + ": bad point count");
        for (int j = 0; j < count; ++j)
            if (cc.manifold[k + j] != m_id || cc.point[k + j] != j || cc.point_count[k + j] != count)
                throw std::invalid_argument("the points of manifold " + std::to_string(m_id) +
                                            " must be consecutive rows, point 0 first");
        const int32_t a = cc.row_a[k], b = cc.row_b[k];
        if (a < 0 || b < 0 || static_cast<size_t>(a) >= bc.n || static_cast<size_t>(b) >= bc.n)
            throw std::out_of_range("contact point " + std::to_string(k) + " names a body that is not given");

        ContactManifold<R> m{};
        start_manifold(m, a, b, k, count, cc.friction[k], cc.restitution[k], cc.restitution_threshold[k],
                       bc.inv_mass[a], bc.inv_mass[b], bc.inv_inertia[a], bc.inv_inertia[b], st);

        const V2<R> cA{R(bc.center[2 * a]), R(bc.center[2 * a + 1])};
        const V2<R> cB{R(bc.center[2 * b]), R(bc.center[2 * b + 1])};
        Xf<R> xfA{{0, 0}, rot(a)}, xfB{{0, 0}, rot(b)};
        xfA.p = cA - mul(xfA.q, V2<R>{R(bc.local_center[2 * a]), R(bc.local_center[2 * a + 1])});
        xfB.p = cB - mul(xfB.q, V2<R>{R(bc.local_center[2 * b]), R(bc.local_center[2 * b + 1])});
        V2<R> point_local[2], points[2];
        for (int j = 0; j < count; ++j)
            point_local[j] = {R(cc.point_local[2 * (k + j)]), R(cc.point_local[2 * (k + j) + 1])};
        world_manifold<R>(cc.manifold_type[k], {R(cc.local_normal[2 * k]), R(cc.local_normal[2 * k + 1])},
                          {R(cc.local_point[2 * k]), R(cc.local_point[2 * k + 1])}, point_local, count, xfA,
                          R(cc.radius_a[k]), xfB, R(cc.radius_b[k]), m.normal, points);
        for (int j = 0; j < count; ++j) {
            m.p[j].rA = points[j] - cA;
            m.p[j].rB = points[j] - cB;
        }
        pose_rows(m, pb.velocity, st, pb.stats);
        pb.manifolds.push_back(m);
        k += count;
    }
    pb.points = cc.n;
}

template <class R>
ContactProblem<R> assemble(const BodyColumns& bc, const ContactColumns& cc, const StepSettings& st) {
    ContactProblem<R> pb;
    assemble_into(pb, bc, cc, st);
    return pb;
}

}  // namespace dc
