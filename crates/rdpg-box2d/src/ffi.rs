//! Raw declarations of the C shim in `cpp/shim.cpp`.

use std::ffi::c_void;

#[repr(C)]
pub struct RbContactEvent {
    pub begin: i32,
    pub tag_a: u64,
    pub tag_b: u64,
}

#[repr(C)]
pub struct RbFixtureDef {
    pub density: f32,
    pub friction: f32,
    pub restitution: f32,
    pub category_bits: u16,
    pub mask_bits: u16,
    pub group_index: i16,
    pub is_sensor: i32,
}

#[repr(C)]
#[derive(Default)]
pub struct RbBodyState {
    pub x: f32,
    pub y: f32,
    pub angle: f32,
    pub vx: f32,
    pub vy: f32,
    pub angular_velocity: f32,
}

#[repr(C)]
pub struct RbRevoluteDef {
    pub body_a: *mut c_void,
    pub body_b: *mut c_void,
    pub local_anchor_a: [f32; 2],
    pub local_anchor_b: [f32; 2],
    pub reference_angle: f32,
    pub enable_limit: i32,
    pub lower_angle: f32,
    pub upper_angle: f32,
    pub enable_motor: i32,
    pub motor_speed: f32,
    pub max_motor_torque: f32,
    pub collide_connected: i32,
}

extern "C" {
    pub fn rb_world_new(gx: f32, gy: f32, allow_sleep: i32) -> *mut c_void;
    pub fn rb_world_free(w: *mut c_void);
    pub fn rb_world_step(w: *mut c_void, dt: f32, vel: i32, pos: i32);
    pub fn rb_world_set_contact_recording(w: *mut c_void, enabled: i32);
    pub fn rb_world_contact_events(w: *mut c_void, out: *mut *const RbContactEvent) -> usize;
    pub fn rb_world_clear_contact_events(w: *mut c_void);
    pub fn rb_world_raycast_closest(
        w: *mut c_void,
        x1: f32,
        y1: f32,
        x2: f32,
        y2: f32,
        category: u16,
        hit_xy: *mut f32,
    ) -> f32;
    pub fn rb_body_new(
        w: *mut c_void,
        kind: i32,
        x: f32,
        y: f32,
        angle: f32,
        tag: u64,
    ) -> *mut c_void;
    pub fn rb_body_destroy(w: *mut c_void, b: *mut c_void);
    pub fn rb_body_add_polygon(
        b: *mut c_void,
        xy: *const f32,
        count: i32,
        d: *const RbFixtureDef,
    ) -> i32;
    pub fn rb_body_add_box(b: *mut c_void, hx: f32, hy: f32, d: *const RbFixtureDef);
    pub fn rb_body_add_edge(
        b: *mut c_void,
        x1: f32,
        y1: f32,
        x2: f32,
        y2: f32,
        d: *const RbFixtureDef,
    );
    pub fn rb_body_apply_force_to_center(b: *mut c_void, fx: f32, fy: f32, wake: i32);
    pub fn rb_body_state(b: *const c_void, s: *mut RbBodyState);
    pub fn rb_body_fixture_outline(b: *const c_void, index: i32, xy: *mut f32, cap: i32) -> i32;
    pub fn rb_revolute_new(w: *mut c_void, d: *const RbRevoluteDef) -> *mut c_void;
    pub fn rb_revolute_set_motor(j: *mut c_void, speed: f32, max_torque: f32);
    pub fn rb_revolute_angle(j: *const c_void) -> f32;
    pub fn rb_revolute_speed(j: *const c_void) -> f32;
    pub fn rb_max_polygon_vertices() -> i32;
}
