// rdpg's C interface to Box2D 2.3 (pybox2d's copy). Our own code: a narrow, flat API over the
// handful of Box2D calls the Gymnasium Box2D environments make, so that Rust can drive the
// engine exactly as pybox2d does. Contact callbacks are recorded into a buffer during Step and
// drained by Rust afterwards, so no callback ever crosses the FFI boundary.
#include <Box2D/Box2D.h>
#include <cstdint>
#include <new>
#include <vector>

extern "C" {

struct RbContactEvent {
    int32_t begin;   // 1 = BeginContact, 0 = EndContact
    uint64_t tag_a;  // user tag of fixture A's body
    uint64_t tag_b;  // user tag of fixture B's body
};

struct RbFixtureDef {
    float density;
    float friction;
    float restitution;
    uint16_t category_bits;
    uint16_t mask_bits;
    int16_t group_index;
    int32_t is_sensor;
};

struct RbBodyState {
    float x, y, angle, vx, vy, angular_velocity;
};

struct RbRevoluteDef {
    b2Body* body_a;
    b2Body* body_b;
    float local_anchor_a[2];
    float local_anchor_b[2];
    float reference_angle;
    int32_t enable_limit;
    float lower_angle;
    float upper_angle;
    int32_t enable_motor;
    float motor_speed;
    float max_motor_torque;
    int32_t collide_connected;
};

}  // extern "C"

namespace {

class Recorder : public b2ContactListener {
public:
    bool enabled = false;
    std::vector<RbContactEvent> events;

    void BeginContact(b2Contact* c) override { push(c, 1); }
    void EndContact(b2Contact* c) override { push(c, 0); }

private:
    void push(b2Contact* c, int32_t begin) {
        if (!enabled) return;
        RbContactEvent e;
        e.begin = begin;
        e.tag_a = (uint64_t)(uintptr_t)c->GetFixtureA()->GetBody()->GetUserData();
        e.tag_b = (uint64_t)(uintptr_t)c->GetFixtureB()->GetBody()->GetUserData();
        events.push_back(e);
    }
};

// Keeps the closest hit among fixtures whose category has all bits of `required` set,
// exactly like Gymnasium's LidarCallback (return -1 to ignore, the fraction to clip).
class ClosestRay : public b2RayCastCallback {
public:
    uint16_t required;
    float fraction = 1.0f;
    b2Vec2 point;
    float32 ReportFixture(b2Fixture* f, const b2Vec2& p, const b2Vec2&, float32 frac) override {
        if ((f->GetFilterData().categoryBits & required) == 0) return -1.0f;
        point = p;
        fraction = frac;
        return frac;
    }
};

struct World {
    b2World world;
    Recorder recorder;
    explicit World(b2Vec2 g) : world(g) { world.SetContactListener(&recorder); }
};

void apply_fixture_def(b2FixtureDef& fd, const RbFixtureDef* d) {
    fd.density = d->density;
    fd.friction = d->friction;
    fd.restitution = d->restitution;
    fd.filter.categoryBits = d->category_bits;
    fd.filter.maskBits = d->mask_bits;
    fd.filter.groupIndex = d->group_index;
    fd.isSensor = d->is_sensor != 0;
}

}  // namespace

extern "C" {

void* rb_world_new(float gx, float gy, int32_t allow_sleep) {
    World* w = new (std::nothrow) World(b2Vec2(gx, gy));
    if (w) w->world.SetAllowSleeping(allow_sleep != 0);
    return w;
}

void rb_world_free(void* w) { delete static_cast<World*>(w); }

void rb_world_step(void* w, float dt, int32_t vel_iters, int32_t pos_iters) {
    static_cast<World*>(w)->world.Step(dt, vel_iters, pos_iters);
}

void rb_world_set_contact_recording(void* w, int32_t enabled) {
    static_cast<World*>(w)->recorder.enabled = enabled != 0;
}

size_t rb_world_contact_events(void* w, const RbContactEvent** out) {
    World* world = static_cast<World*>(w);
    *out = world->recorder.events.data();
    return world->recorder.events.size();
}

void rb_world_clear_contact_events(void* w) { static_cast<World*>(w)->recorder.events.clear(); }

float rb_world_raycast_closest(void* w, float x1, float y1, float x2, float y2,
                               uint16_t required_category, float* hit_xy) {
    ClosestRay cb;
    cb.required = required_category;
    cb.point = b2Vec2(x2, y2);
    static_cast<World*>(w)->world.RayCast(&cb, b2Vec2(x1, y1), b2Vec2(x2, y2));
    hit_xy[0] = cb.point.x;
    hit_xy[1] = cb.point.y;
    return cb.fraction;
}

// kind: 0 static, 1 kinematic, 2 dynamic (b2BodyType's values).
b2Body* rb_body_new(void* w, int32_t kind, float x, float y, float angle, uint64_t tag) {
    b2BodyDef def;
    def.type = static_cast<b2BodyType>(kind);
    def.position.Set(x, y);
    def.angle = angle;
    def.userData = (void*)(uintptr_t)tag;
    return static_cast<World*>(w)->world.CreateBody(&def);
}

void rb_body_destroy(void* w, b2Body* b) { static_cast<World*>(w)->world.DestroyBody(b); }

// Polygon through b2PolygonShape::Set (convex hull, welding), as pybox2d's `vertices=` does.
// Returns 0 if the polygon is degenerate (Box2D would assert).
int32_t rb_body_add_polygon(b2Body* b, const float* xy, int32_t count, const RbFixtureDef* d) {
    if (count < 3 || count > b2_maxPolygonVertices) return 0;
    b2Vec2 pts[b2_maxPolygonVertices];
    for (int32_t i = 0; i < count; ++i) pts[i].Set(xy[2 * i], xy[2 * i + 1]);
    b2PolygonShape shape;
    shape.Set(pts, count);
    b2FixtureDef fd;
    apply_fixture_def(fd, d);
    fd.shape = &shape;
    b->CreateFixture(&fd);
    return 1;
}

void rb_body_add_box(b2Body* b, float hx, float hy, const RbFixtureDef* d) {
    b2PolygonShape shape;
    shape.SetAsBox(hx, hy);
    b2FixtureDef fd;
    apply_fixture_def(fd, d);
    fd.shape = &shape;
    b->CreateFixture(&fd);
}

void rb_body_add_edge(b2Body* b, float x1, float y1, float x2, float y2, const RbFixtureDef* d) {
    b2EdgeShape shape;
    shape.Set(b2Vec2(x1, y1), b2Vec2(x2, y2));
    b2FixtureDef fd;
    apply_fixture_def(fd, d);
    fd.shape = &shape;
    b->CreateFixture(&fd);
}

void rb_body_apply_force_to_center(b2Body* b, float fx, float fy, int32_t wake) {
    b->ApplyForceToCenter(b2Vec2(fx, fy), wake != 0);
}

void rb_body_state(const b2Body* b, RbBodyState* s) {
    const b2Vec2& p = b->GetPosition();
    const b2Vec2& v = b->GetLinearVelocity();
    s->x = p.x;
    s->y = p.y;
    s->angle = b->GetAngle();
    s->vx = v.x;
    s->vy = v.y;
    s->angular_velocity = b->GetAngularVelocity();
}

// World-space outline of fixture `index` of a body (polygons: their vertices; edges: 2 points).
// Returns the number of points written (at most `cap`), or -1 if there is no such fixture.
int32_t rb_body_fixture_outline(const b2Body* b, int32_t index, float* xy, int32_t cap) {
    const b2Fixture* f = b->GetFixtureList();
    // Fixtures are prepended by Box2D: walk to the end to count from the first created.
    int32_t n = 0;
    for (const b2Fixture* g = f; g; g = g->GetNext()) ++n;
    if (index < 0 || index >= n) return -1;
    for (int32_t k = 0; k < n - 1 - index; ++k) f = f->GetNext();
    const b2Transform& xf = b->GetTransform();
    int32_t written = 0;
    if (f->GetType() == b2Shape::e_polygon) {
        const b2PolygonShape* s = static_cast<const b2PolygonShape*>(f->GetShape());
        for (int32_t i = 0; i < s->m_count && written < cap; ++i, ++written) {
            b2Vec2 p = b2Mul(xf, s->m_vertices[i]);
            xy[2 * written] = p.x;
            xy[2 * written + 1] = p.y;
        }
    } else if (f->GetType() == b2Shape::e_edge) {
        const b2EdgeShape* s = static_cast<const b2EdgeShape*>(f->GetShape());
        const b2Vec2 ends[2] = {b2Mul(xf, s->m_vertex1), b2Mul(xf, s->m_vertex2)};
        for (int32_t i = 0; i < 2 && written < cap; ++i, ++written) {
            xy[2 * written] = ends[i].x;
            xy[2 * written + 1] = ends[i].y;
        }
    }
    return written;
}

b2RevoluteJoint* rb_revolute_new(void* w, const RbRevoluteDef* d) {
    b2RevoluteJointDef def;
    def.bodyA = d->body_a;
    def.bodyB = d->body_b;
    def.localAnchorA.Set(d->local_anchor_a[0], d->local_anchor_a[1]);
    def.localAnchorB.Set(d->local_anchor_b[0], d->local_anchor_b[1]);
    def.referenceAngle = d->reference_angle;
    def.enableLimit = d->enable_limit != 0;
    def.lowerAngle = d->lower_angle;
    def.upperAngle = d->upper_angle;
    def.enableMotor = d->enable_motor != 0;
    def.motorSpeed = d->motor_speed;
    def.maxMotorTorque = d->max_motor_torque;
    def.collideConnected = d->collide_connected != 0;
    return static_cast<b2RevoluteJoint*>(static_cast<World*>(w)->world.CreateJoint(&def));
}

void rb_revolute_set_motor(b2RevoluteJoint* j, float speed, float max_torque) {
    j->SetMotorSpeed(speed);
    j->SetMaxMotorTorque(max_torque);
}

float rb_revolute_angle(const b2RevoluteJoint* j) { return j->GetJointAngle(); }

float rb_revolute_speed(const b2RevoluteJoint* j) { return j->GetJointSpeed(); }

int32_t rb_max_polygon_vertices() { return b2_maxPolygonVertices; }

}  // extern "C"
