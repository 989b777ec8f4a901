//! A small, safe binding to Box2D 2.3 — pybox2d's own copy of the engine (Box2D 2.3.0 as shipped
//! in the `box2d-py==2.3.8` sdist), the physics Gymnasium's Box2D environments run on.
//!
//! The API covers what those environments use: static and dynamic bodies with polygon, box and
//! edge fixtures, revolute joints with motors and limits, closest-hit ray casts filtered by
//! category bits, and contact begin/end events. Bodies and joints are addressed by checked ids,
//! so a destroyed body can never be touched again from safe code.
//!
//! Contact events are recorded during [`World::step`] and read with
//! [`World::contact_events`]; each names the user tags given to the two bodies at creation.

#![warn(missing_docs)]
// No panic reachable from a file or an argument: errors are returned; each remaining invariant
// is allowed where it holds, with its reason.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

use std::ffi::c_void;
use std::ptr::NonNull;

mod ffi;

/// Which Box2D sources this crate was built from: `"pybox2d-2.3.0"` (bit-identical to
/// Gymnasium), `"box2d-2.3.1-stock"` (same dynamics, different rounding in `b2Sweep::Advance`),
/// or `"unknown"`.
pub const FLAVOR: &str = env!("RDPG_BOX2D_FLAVOR");

/// Whether the engine is pybox2d's Box2D 2.3.0, the one that reproduces Gymnasium bit for bit.
pub fn is_pybox2d_core() -> bool {
    FLAVOR == "pybox2d-2.3.0"
}

/// Kind of rigid body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyKind {
    /// Never moves.
    Static = 0,
    /// Moves by velocity only.
    Kinematic = 1,
    /// Fully simulated.
    Dynamic = 2,
}

/// Material and collision filter of a fixture (Box2D's `b2FixtureDef` without the shape).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixtureDef {
    /// Density in kg/m².
    pub density: f32,
    /// Coulomb friction coefficient.
    pub friction: f32,
    /// Restitution (bounciness).
    pub restitution: f32,
    /// Collision category bits.
    pub category_bits: u16,
    /// Categories this fixture collides with.
    pub mask_bits: u16,
    /// Collision group index.
    pub group_index: i16,
    /// Sensors report contacts but do not collide.
    pub is_sensor: bool,
}

impl Default for FixtureDef {
    /// Box2D's defaults: density 0, friction 0.2, restitution 0, category 1, mask 0xFFFF.
    fn default() -> Self {
        Self {
            density: 0.0,
            friction: 0.2,
            restitution: 0.0,
            category_bits: 0x0001,
            mask_bits: 0xFFFF,
            group_index: 0,
            is_sensor: false,
        }
    }
}

impl FixtureDef {
    fn raw(&self) -> ffi::RbFixtureDef {
        ffi::RbFixtureDef {
            density: self.density,
            friction: self.friction,
            restitution: self.restitution,
            category_bits: self.category_bits,
            mask_bits: self.mask_bits,
            group_index: self.group_index,
            is_sensor: self.is_sensor as i32,
        }
    }
}

/// Definition of a revolute joint between two bodies of the same world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RevoluteDef {
    /// First body.
    pub body_a: BodyId,
    /// Second body.
    pub body_b: BodyId,
    /// Anchor in body A's frame.
    pub local_anchor_a: [f32; 2],
    /// Anchor in body B's frame.
    pub local_anchor_b: [f32; 2],
    /// `angle_b - angle_a` at which the joint angle reads zero.
    pub reference_angle: f32,
    /// Enforce `[lower_angle, upper_angle]`.
    pub enable_limit: bool,
    /// Lower limit (radians).
    pub lower_angle: f32,
    /// Upper limit (radians).
    pub upper_angle: f32,
    /// Drive the joint with a motor.
    pub enable_motor: bool,
    /// Motor target speed (rad/s).
    pub motor_speed: f32,
    /// Maximum motor torque (N·m).
    pub max_motor_torque: f32,
    /// Let the two bodies collide with each other.
    pub collide_connected: bool,
}

/// Position, angle and velocities of a body.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BodyState {
    /// Origin x.
    pub x: f32,
    /// Origin y.
    pub y: f32,
    /// Angle (radians).
    pub angle: f32,
    /// Linear velocity x.
    pub vx: f32,
    /// Linear velocity y.
    pub vy: f32,
    /// Angular velocity (rad/s).
    pub angular_velocity: f32,
}

/// A contact starting or ending between two bodies, recorded during a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ContactEvent {
    /// `true` for BeginContact, `false` for EndContact.
    pub begin: bool,
    /// User tag of fixture A's body.
    pub tag_a: u64,
    /// User tag of fixture B's body.
    pub tag_b: u64,
}

/// Result of a closest-hit ray cast.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Fraction of the segment at the closest accepted hit, 1.0 if nothing was hit.
    pub fraction: f32,
    /// Hit point (the segment's end when nothing was hit).
    pub point: [f32; 2],
}

/// Identifies a body of a [`World`]; stale ids are rejected, never dereferenced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BodyId {
    index: u32,
    generation: u32,
}

/// Identifies a revolute joint of a [`World`]; it dies with either of its bodies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct JointId {
    index: u32,
    generation: u32,
}

/// Errors of the physics binding.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PhysicsError {
    /// The body was destroyed or belongs to another world.
    #[error("stale or foreign body id")]
    StaleBody,
    /// The joint was destroyed (with one of its bodies) or belongs to another world.
    #[error("stale or foreign joint id")]
    StaleJoint,
    /// A polygon with too few or too many vertices, or a non-finite coordinate.
    #[error("invalid polygon: {0}")]
    InvalidPolygon(String),
    /// Box2D could not allocate a world.
    #[error("Box2D world allocation failed")]
    Alloc,
}

struct Slot<T> {
    ptr: Option<NonNull<T>>,
    generation: u32,
}

struct JointSlot {
    ptr: Option<NonNull<c_void>>,
    generation: u32,
    bodies: [u32; 2],
}

/// A Box2D world. Owns its bodies and joints; dropping it frees everything.
pub struct World {
    raw: NonNull<c_void>,
    bodies: Vec<Slot<c_void>>,
    free_bodies: Vec<u32>,
    joints: Vec<JointSlot>,
    free_joints: Vec<u32>,
}

// SAFETY: a World exclusively owns its Box2D world; nothing in it is shared between threads,
// and Box2D keeps no global mutable state.
unsafe impl Send for World {}

impl World {
    /// A world with gravity `(gx, gy)`; `allow_sleep` as Box2D's `SetAllowSleeping` (pybox2d's
    /// `doSleep`, true by default there).
    pub fn new(gravity: [f32; 2], allow_sleep: bool) -> Result<Self, PhysicsError> {
        // SAFETY: plain constructor; null on allocation failure.
        let raw = unsafe { ffi::rb_world_new(gravity[0], gravity[1], allow_sleep as i32) };
        Ok(Self {
            raw: NonNull::new(raw).ok_or(PhysicsError::Alloc)?,
            bodies: Vec::new(),
            free_bodies: Vec::new(),
            joints: Vec::new(),
            free_joints: Vec::new(),
        })
    }

    /// Advances the world by `dt` seconds with the given solver iterations.
    pub fn step(&mut self, dt: f32, velocity_iterations: i32, position_iterations: i32) {
        // SAFETY: `raw` is a live world.
        unsafe {
            ffi::rb_world_step(
                self.raw.as_ptr(),
                dt,
                velocity_iterations,
                position_iterations,
            )
        }
    }

    /// Turns recording of contact events on or off (pybox2d: setting `contactListener`).
    pub fn set_contact_recording(&mut self, enabled: bool) {
        // SAFETY: `raw` is a live world.
        unsafe { ffi::rb_world_set_contact_recording(self.raw.as_ptr(), enabled as i32) }
    }

    /// Contact events recorded since the last [`World::clear_contact_events`], in the order
    /// Box2D reported them.
    pub fn contact_events(&self) -> Vec<ContactEvent> {
        let mut ptr = std::ptr::null();
        // SAFETY: the shim returns a pointer into its event vector and its length; we copy
        // the events out before any other call can touch the vector.
        let n = unsafe { ffi::rb_world_contact_events(self.raw.as_ptr(), &mut ptr) };
        if n == 0 {
            return Vec::new();
        }
        // SAFETY: see above; `ptr` is valid for `n` events.
        let raw = unsafe { std::slice::from_raw_parts(ptr, n) };
        raw.iter()
            .map(|e| ContactEvent {
                begin: e.begin != 0,
                tag_a: e.tag_a,
                tag_b: e.tag_b,
            })
            .collect()
    }

    /// Forgets the recorded contact events.
    pub fn clear_contact_events(&mut self) {
        // SAFETY: `raw` is a live world.
        unsafe { ffi::rb_world_clear_contact_events(self.raw.as_ptr()) }
    }

    /// Casts a ray from `p1` to `p2` and returns the closest hit among fixtures whose category
    /// bits intersect `category` (others are ignored, as Gymnasium's lidar callback does).
    pub fn raycast_closest(&self, p1: [f32; 2], p2: [f32; 2], category: u16) -> RayHit {
        let mut point = [0.0f32; 2];
        // SAFETY: `raw` is a live world; `point` has room for two floats.
        let fraction = unsafe {
            ffi::rb_world_raycast_closest(
                self.raw.as_ptr(),
                p1[0],
                p1[1],
                p2[0],
                p2[1],
                category,
                point.as_mut_ptr(),
            )
        };
        RayHit { fraction, point }
    }

    /// Creates a body at `position` with `angle`, tagged with `tag` for contact events.
    #[allow(
        clippy::expect_used,
        reason = "Box2D returns null only while its world is locked, inside a step, where no rdpg code runs"
    )]
    pub fn create_body(
        &mut self,
        kind: BodyKind,
        position: [f32; 2],
        angle: f32,
        tag: u64,
    ) -> BodyId {
        // SAFETY: `raw` is a live world; Box2D copies the definition.
        let ptr = unsafe {
            ffi::rb_body_new(
                self.raw.as_ptr(),
                kind as i32,
                position[0],
                position[1],
                angle,
                tag,
            )
        };
        let ptr = NonNull::new(ptr).expect("Box2D returned a null body (world locked?)");
        if let Some(index) = self.free_bodies.pop() {
            let slot = &mut self.bodies[index as usize];
            slot.ptr = Some(ptr);
            BodyId {
                index,
                generation: slot.generation,
            }
        } else {
            self.bodies.push(Slot {
                ptr: Some(ptr),
                generation: 0,
            });
            BodyId {
                index: (self.bodies.len() - 1) as u32,
                generation: 0,
            }
        }
    }

    fn body_ptr(&self, id: BodyId) -> Result<*mut c_void, PhysicsError> {
        match self.bodies.get(id.index as usize) {
            Some(Slot {
                ptr: Some(p),
                generation,
            }) if *generation == id.generation => Ok(p.as_ptr()),
            _ => Err(PhysicsError::StaleBody),
        }
    }

    fn joint_ptr(&self, id: JointId) -> Result<*mut c_void, PhysicsError> {
        match self.joints.get(id.index as usize) {
            Some(JointSlot {
                ptr: Some(p),
                generation,
                ..
            }) if *generation == id.generation => Ok(p.as_ptr()),
            _ => Err(PhysicsError::StaleJoint),
        }
    }

    /// Destroys a body, its fixtures and the joints attached to it.
    pub fn destroy_body(&mut self, id: BodyId) -> Result<(), PhysicsError> {
        let ptr = self.body_ptr(id)?;
        // SAFETY: `ptr` is a live body of this world.
        unsafe { ffi::rb_body_destroy(self.raw.as_ptr(), ptr) };
        let slot = &mut self.bodies[id.index as usize];
        slot.ptr = None;
        slot.generation = slot.generation.wrapping_add(1);
        self.free_bodies.push(id.index);
        for (j, joint) in self.joints.iter_mut().enumerate() {
            if joint.ptr.is_some() && joint.bodies.contains(&id.index) {
                joint.ptr = None;
                joint.generation = joint.generation.wrapping_add(1);
                self.free_joints.push(j as u32);
            }
        }
        Ok(())
    }

    /// Adds a polygon fixture through `b2PolygonShape::Set` (convex hull of the points, as
    /// pybox2d's `polygonShape(vertices=...)`).
    pub fn add_polygon(
        &mut self,
        body: BodyId,
        points: &[[f32; 2]],
        def: &FixtureDef,
    ) -> Result<(), PhysicsError> {
        let ptr = self.body_ptr(body)?;
        // SAFETY: no pointer involved.
        let max = unsafe { ffi::rb_max_polygon_vertices() } as usize;
        if points.len() < 3 || points.len() > max {
            return Err(PhysicsError::InvalidPolygon(format!(
                "{} vertices (3..={max} allowed)",
                points.len()
            )));
        }
        if points.iter().flatten().any(|v| !v.is_finite()) {
            return Err(PhysicsError::InvalidPolygon("non-finite vertex".into()));
        }
        if polygon_area2(points).abs() <= f32::EPSILON {
            return Err(PhysicsError::InvalidPolygon("zero area".into()));
        }
        let flat: Vec<f32> = points.iter().flatten().copied().collect();
        let raw = def.raw();
        // SAFETY: `ptr` is a live body; `flat` holds 2 * len floats.
        let ok = unsafe { ffi::rb_body_add_polygon(ptr, flat.as_ptr(), points.len() as i32, &raw) };
        if ok == 0 {
            return Err(PhysicsError::InvalidPolygon("rejected by Box2D".into()));
        }
        Ok(())
    }

    /// Adds a box fixture with half-extents `(hx, hy)` centred on the body origin.
    pub fn add_box(
        &mut self,
        body: BodyId,
        hx: f32,
        hy: f32,
        def: &FixtureDef,
    ) -> Result<(), PhysicsError> {
        let ptr = self.body_ptr(body)?;
        if !(hx.is_finite() && hy.is_finite() && hx > 0.0 && hy > 0.0) {
            return Err(PhysicsError::InvalidPolygon(format!(
                "box half-extents {hx} x {hy}"
            )));
        }
        let raw = def.raw();
        // SAFETY: `ptr` is a live body.
        unsafe { ffi::rb_body_add_box(ptr, hx, hy, &raw) };
        Ok(())
    }

    /// Adds a two-sided edge fixture from `a` to `b` (no ghost vertices).
    pub fn add_edge(
        &mut self,
        body: BodyId,
        a: [f32; 2],
        b: [f32; 2],
        def: &FixtureDef,
    ) -> Result<(), PhysicsError> {
        let ptr = self.body_ptr(body)?;
        if a.iter().chain(&b).any(|v| !v.is_finite()) {
            return Err(PhysicsError::InvalidPolygon(
                "non-finite edge vertex".into(),
            ));
        }
        let raw = def.raw();
        // SAFETY: `ptr` is a live body.
        unsafe { ffi::rb_body_add_edge(ptr, a[0], a[1], b[0], b[1], &raw) };
        Ok(())
    }

    /// Applies a force at the body's centre of mass (`wake` wakes a sleeping body).
    pub fn apply_force_to_center(
        &mut self,
        body: BodyId,
        force: [f32; 2],
        wake: bool,
    ) -> Result<(), PhysicsError> {
        let ptr = self.body_ptr(body)?;
        // SAFETY: `ptr` is a live body.
        unsafe { ffi::rb_body_apply_force_to_center(ptr, force[0], force[1], wake as i32) };
        Ok(())
    }

    /// Position, angle and velocities of a body.
    pub fn body_state(&self, body: BodyId) -> Result<BodyState, PhysicsError> {
        let ptr = self.body_ptr(body)?;
        let mut s = ffi::RbBodyState::default();
        // SAFETY: `ptr` is a live body; `s` is a valid out-parameter.
        unsafe { ffi::rb_body_state(ptr, &mut s) };
        Ok(BodyState {
            x: s.x,
            y: s.y,
            angle: s.angle,
            vx: s.vx,
            vy: s.vy,
            angular_velocity: s.angular_velocity,
        })
    }

    /// World-space outline of the body's `index`-th fixture (in creation order): polygon
    /// vertices, or the two ends of an edge. `None` if there is no such fixture.
    pub fn fixture_outline(
        &self,
        body: BodyId,
        index: usize,
    ) -> Result<Option<Vec<[f32; 2]>>, PhysicsError> {
        let ptr = self.body_ptr(body)?;
        let mut buf = [0.0f32; 64];
        // SAFETY: `ptr` is a live body; `buf` has room for 32 points.
        let n = unsafe { ffi::rb_body_fixture_outline(ptr, index as i32, buf.as_mut_ptr(), 32) };
        if n < 0 {
            return Ok(None);
        }
        Ok(Some(
            buf[..2 * n as usize]
                .chunks_exact(2)
                .map(|c| [c[0], c[1]])
                .collect(),
        ))
    }

    /// Creates a revolute joint.
    #[allow(
        clippy::expect_used,
        reason = "Box2D returns null only while its world is locked, inside a step, where no rdpg code runs"
    )]
    pub fn create_revolute(&mut self, def: &RevoluteDef) -> Result<JointId, PhysicsError> {
        let a = self.body_ptr(def.body_a)?;
        let b = self.body_ptr(def.body_b)?;
        let raw = ffi::RbRevoluteDef {
            body_a: a,
            body_b: b,
            local_anchor_a: def.local_anchor_a,
            local_anchor_b: def.local_anchor_b,
            reference_angle: def.reference_angle,
            enable_limit: def.enable_limit as i32,
            lower_angle: def.lower_angle,
            upper_angle: def.upper_angle,
            enable_motor: def.enable_motor as i32,
            motor_speed: def.motor_speed,
            max_motor_torque: def.max_motor_torque,
            collide_connected: def.collide_connected as i32,
        };
        // SAFETY: both bodies are live bodies of this world; Box2D copies the definition.
        let ptr = unsafe { ffi::rb_revolute_new(self.raw.as_ptr(), &raw) };
        let ptr = NonNull::new(ptr).expect("Box2D returned a null joint (world locked?)");
        let bodies = [def.body_a.index, def.body_b.index];
        if let Some(index) = self.free_joints.pop() {
            let slot = &mut self.joints[index as usize];
            slot.ptr = Some(ptr);
            slot.bodies = bodies;
            Ok(JointId {
                index,
                generation: slot.generation,
            })
        } else {
            self.joints.push(JointSlot {
                ptr: Some(ptr),
                generation: 0,
                bodies,
            });
            Ok(JointId {
                index: (self.joints.len() - 1) as u32,
                generation: 0,
            })
        }
    }

    /// Sets a joint motor's target speed, then its maximum torque (both wake the bodies), in
    /// the order Gymnasium's walker does.
    pub fn set_motor(
        &mut self,
        joint: JointId,
        speed: f32,
        max_torque: f32,
    ) -> Result<(), PhysicsError> {
        let ptr = self.joint_ptr(joint)?;
        // SAFETY: `ptr` is a live revolute joint.
        unsafe { ffi::rb_revolute_set_motor(ptr, speed, max_torque) };
        Ok(())
    }

    /// Joint angle: `angle_b - angle_a - reference_angle`.
    pub fn joint_angle(&self, joint: JointId) -> Result<f32, PhysicsError> {
        let ptr = self.joint_ptr(joint)?;
        // SAFETY: `ptr` is a live revolute joint.
        Ok(unsafe { ffi::rb_revolute_angle(ptr) })
    }

    /// Joint speed: `omega_b - omega_a`.
    pub fn joint_speed(&self, joint: JointId) -> Result<f32, PhysicsError> {
        let ptr = self.joint_ptr(joint)?;
        // SAFETY: `ptr` is a live revolute joint.
        Ok(unsafe { ffi::rb_revolute_speed(ptr) })
    }
}

impl Drop for World {
    fn drop(&mut self) {
        // SAFETY: `raw` came from rb_world_new and is freed once; b2World's destructor frees
        // all bodies and joints.
        unsafe { ffi::rb_world_free(self.raw.as_ptr()) }
    }
}

/// Twice the signed area of a polygon.
fn polygon_area2(points: &[[f32; 2]]) -> f32 {
    let n = points.len();
    (0..n)
        .map(|i| {
            let [x1, y1] = points[i];
            let [x2, y2] = points[(i + 1) % n];
            x1 * y2 - x2 * y1
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_falls_onto_edge_and_reports_contact() {
        let mut w = World::new([0.0, -10.0], true).unwrap();
        w.set_contact_recording(true);
        let ground = w.create_body(BodyKind::Static, [0.0, 0.0], 0.0, 1);
        w.add_edge(ground, [-10.0, 0.0], [10.0, 0.0], &FixtureDef::default())
            .unwrap();
        let b = w.create_body(BodyKind::Dynamic, [0.0, 2.0], 0.0, 2);
        let fd = FixtureDef {
            density: 1.0,
            category_bits: 0x2,
            ..FixtureDef::default()
        };
        w.add_box(b, 0.5, 0.5, &fd).unwrap();
        let mut began = false;
        for _ in 0..100 {
            w.clear_contact_events();
            w.step(1.0 / 50.0, 8, 3);
            began |= w.contact_events().iter().any(|e| {
                e.begin && [e.tag_a, e.tag_b].contains(&2) && [e.tag_a, e.tag_b].contains(&1)
            });
        }
        assert!(began, "no BeginContact between box and ground");
        let s = w.body_state(b).unwrap();
        assert!(
            (s.y - 0.5).abs() < 0.02,
            "box rests on the ground, y = {}",
            s.y
        );
        let ground_hit = w.raycast_closest([0.0, 5.0], [0.0, -5.0], 0x1);
        assert_eq!(
            ground_hit.fraction, 0.5,
            "the edge at y = 0, ignoring the box"
        );
        let box_hit = w.raycast_closest([0.0, 5.0], [0.0, -5.0], 0x2);
        assert!(
            (box_hit.fraction - 0.4).abs() < 3e-3,
            "box top, {}",
            box_hit.fraction
        );
        let outline = w.fixture_outline(b, 0).unwrap().unwrap();
        assert_eq!(outline.len(), 4);
        assert!(w.fixture_outline(b, 1).unwrap().is_none());
    }

    #[test]
    fn stale_ids_are_rejected() {
        let mut w = World::new([0.0, -10.0], true).unwrap();
        let a = w.create_body(BodyKind::Dynamic, [0.0, 0.0], 0.0, 0);
        let b = w.create_body(BodyKind::Dynamic, [1.0, 0.0], 0.0, 0);
        let fd = FixtureDef {
            density: 1.0,
            ..FixtureDef::default()
        };
        w.add_box(a, 0.1, 0.1, &fd).unwrap();
        w.add_box(b, 0.1, 0.1, &fd).unwrap();
        let j = w
            .create_revolute(&RevoluteDef {
                body_a: a,
                body_b: b,
                local_anchor_a: [0.5, 0.0],
                local_anchor_b: [-0.5, 0.0],
                reference_angle: 0.0,
                enable_limit: true,
                lower_angle: -0.5,
                upper_angle: 0.5,
                enable_motor: true,
                motor_speed: 1.0,
                max_motor_torque: 10.0,
                collide_connected: false,
            })
            .unwrap();
        w.step(1.0 / 50.0, 8, 3);
        assert!(w.joint_angle(j).is_ok());
        w.destroy_body(a).unwrap();
        assert_eq!(w.body_state(a), Err(PhysicsError::StaleBody));
        assert_eq!(w.joint_angle(j), Err(PhysicsError::StaleJoint));
        assert_eq!(w.destroy_body(a), Err(PhysicsError::StaleBody));
        let c = w.create_body(BodyKind::Static, [0.0, 0.0], 0.0, 0);
        assert_ne!(c, a, "a reused slot gets a new generation");
        assert!(w.body_state(b).is_ok());
    }

    #[test]
    fn degenerate_polygons_are_errors() {
        let mut w = World::new([0.0, -10.0], true).unwrap();
        let b = w.create_body(BodyKind::Static, [0.0, 0.0], 0.0, 0);
        let fd = FixtureDef::default();
        assert!(w.add_polygon(b, &[[0.0, 0.0], [1.0, 0.0]], &fd).is_err());
        assert!(w
            .add_polygon(b, &[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], &fd)
            .is_err());
        assert!(w
            .add_polygon(b, &[[0.0, 0.0], [1.0, f32::NAN], [2.0, 1.0]], &fd)
            .is_err());
        assert!(w
            .add_polygon(b, &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], &fd)
            .is_ok());
        assert!(w.add_box(b, 0.0, 1.0, &fd).is_err());
    }
}
