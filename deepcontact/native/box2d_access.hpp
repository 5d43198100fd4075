// The few private members of Box2D 2.4.1 the project reads or drives: the inverse masses as Box2D
// stores them, the previous step's 1/dt, the world's Solve and SolveTOI, and what the loop's own
// island solve (world_loop.cpp) needs to do exactly what b2World::Solve does (flags, sweeps,
// forces, the fixtures' synchronisation). An explicit template instantiation may name private
// members; this is the standard-conforming way to do so. The tags live in an unnamed namespace,
// so each file that includes this has its own (no instantiation is defined twice).
#pragma once

#include <box2d/box2d.h>

namespace dc {
namespace {

template <typename Tag, typename Tag::type Member>
struct Expose {
    friend typename Tag::type member(Tag) { return Member; }
};

#define DC_BOX2D_MEMBER(Tag, Type, Address)                  \
    struct Tag {                                             \
        using type = Type;                                   \
        friend type member(Tag);                             \
    };                                                       \
    template struct Expose<Tag, Address>;

DC_BOX2D_MEMBER(BodyInvMass, float b2Body::*, &b2Body::m_invMass)
DC_BOX2D_MEMBER(BodyInvI, float b2Body::*, &b2Body::m_invI)
DC_BOX2D_MEMBER(BodyI, float b2Body::*, &b2Body::m_I)
DC_BOX2D_MEMBER(BodyMass, float b2Body::*, &b2Body::m_mass)
DC_BOX2D_MEMBER(BodyFlags, uint16 b2Body::*, &b2Body::m_flags)
DC_BOX2D_MEMBER(BodySweep, b2Sweep b2Body::*, &b2Body::m_sweep)
DC_BOX2D_MEMBER(BodyTransform, b2Transform b2Body::*, &b2Body::m_xf)
DC_BOX2D_MEMBER(BodyForce, b2Vec2 b2Body::*, &b2Body::m_force)
DC_BOX2D_MEMBER(BodyTorque, float b2Body::*, &b2Body::m_torque)
DC_BOX2D_MEMBER(BodyLinearVelocity, b2Vec2 b2Body::*, &b2Body::m_linearVelocity)
DC_BOX2D_MEMBER(BodyAngularVelocity, float b2Body::*, &b2Body::m_angularVelocity)
DC_BOX2D_MEMBER(FixtureSynchronize, void (b2Fixture::*)(b2BroadPhase*, const b2Transform&, const b2Transform&),
                &b2Fixture::Synchronize)
DC_BOX2D_MEMBER(ContactFlags, uint32 b2Contact::*, &b2Contact::m_flags)
DC_BOX2D_MEMBER(ContactNodeA, b2ContactEdge b2Contact::*, &b2Contact::m_nodeA)
DC_BOX2D_MEMBER(WorldInvDt0, float b2World::*, &b2World::m_inv_dt0)
DC_BOX2D_MEMBER(WorldSolveTOI, void (b2World::*)(const b2TimeStep&), &b2World::SolveTOI)
DC_BOX2D_MEMBER(WorldSolve, void (b2World::*)(const b2TimeStep&), &b2World::Solve)
DC_BOX2D_MEMBER(WorldNewContacts, bool b2World::*, &b2World::m_newContacts)
DC_BOX2D_MEMBER(WorldLocked, bool b2World::*, &b2World::m_locked)
DC_BOX2D_MEMBER(WorldStepComplete, bool b2World::*, &b2World::m_stepComplete)
DC_BOX2D_MEMBER(WorldJointCount, int32 b2World::*, &b2World::m_jointCount)

#undef DC_BOX2D_MEMBER

}  // namespace

// A body's scene index, which the project keeps as its user data (Box2D 2.4.1's GetUserData() is
// not const; reading it changes nothing).
inline int body_index(const b2Body* b) { return static_cast<int>(const_cast<b2Body*>(b)->GetUserData().pointer); }

// The flags' values (private enums of b2_body.h and b2_contact.h, 2.4.1).
constexpr uint16 kBodyIslandFlag = 0x0001;
constexpr uint16 kBodyAwakeFlag = 0x0002;
constexpr uint32 kContactIslandFlag = 0x0001;

// A body's and a contact's flags (private members of 2.4.1), to be read and set.
inline uint16& flags(b2Body* b) { return b->*member(BodyFlags()); }
inline uint32& flags(b2Contact* c) { return c->*member(ContactFlags()); }

}  // namespace dc
