//! The room layout of the realistic style ([`Style::Real`](super::Style::Real)): painted walls and
//! ceiling (large, nearly uniform), a photo-textured floor, skirting boards, a door, a bright window, pictures,
//! furniture built from boxes (tables on four legs, cabinets and shelves against the walls, a sofa,
//! boxes on the floor) and slanted planes (a board leaning on the far wall, a panel leaning on a
//! side wall); lit by a soft directional light plus a ceiling lamp ([`Lamp`]).
//!
//! Same world frame and camera keep-out as [`super::layout`]; placement uses its [`Builder`].

use nalgebra::{Matrix3, Vector3};

use super::detmath::{cos, sin};
use super::layout::{yaw_axes, Builder, Footprint, Room, CLEARANCE, GAP, PLACEMENT_TRIES, POSTER_OFFSET};
use super::scene::{Lamp, Light};
use super::surface::{Cuboid, Quad, Shape};
use super::texture::{paint, photo, Texture};
use super::trajectory::CameraPath;
use crate::util::rng::SplitMix64;

/// Camera height above the floor, room height, half-width, far-wall distance and back gap, metres.
const CAMERA_HEIGHT: (f64, f64) = (1.25, 1.7);
const ROOM_HEIGHT: (f64, f64) = (2.4, 3.0);
const ROOM_HALF_WIDTH: (f64, f64) = (2.0, 3.2);
const FAR_WALL: (f64, f64) = (3.9, 5.6);
const BACK_GAP: (f64, f64) = (0.5, 1.2);
/// Offset of doors, windows and pictures from their wall, metres.
const WALL_OFFSET: f64 = 0.006;

/// Which wall: 0 = far, 1 = left, 2 = right, 3 = back.
type Wall = usize;

impl Builder<'_> {
    /// A rectangle `w × h` on wall `wall` with its bottom `bottom` above the floor, at a random
    /// place along the wall; `None` if the wall is too short.
    fn wall_quad(&mut self, wall: Wall, w: f64, h: f64, bottom: f64) -> Option<Quad> {
        let (hw, top) = (self.half_width, self.floor - bottom - h);
        let along =
            |rng: &mut SplitMix64, lo: f64, hi: f64| (hi - lo - w > 0.0).then(|| rng.range(lo, hi - w));
        let quad = match wall {
            0 | 3 => {
                let x = along(self.rng, -hw + 0.15, hw - 0.15)?;
                let z = if wall == 0 { self.far - WALL_OFFSET } else { self.back + WALL_OFFSET };
                Quad::new(Vector3::new(x, top, z), Vector3::x(), Vector3::y(), [w, h])
            }
            _ => {
                let z = along(self.rng, self.back + 0.15, self.far - 0.15)?;
                let x = if wall == 1 { -hw + WALL_OFFSET } else { hw - WALL_OFFSET };
                Quad::new(Vector3::new(x, top, z), Vector3::z(), Vector3::y(), [w, h])
            }
        };
        Some(quad)
    }

    fn real_room(&mut self) {
        let planes = self.room_planes();
        let wall_paint = paint(self.rng, 0.55, 0.9);
        let accent = self.rng.chance(0.35).then(|| (2 + self.rng.below(4), paint(self.rng, 0.35, 0.8)));
        for (k, (name, origin, u, v, size)) in planes.into_iter().enumerate() {
            let texture = match k {
                0 if self.rng.chance(0.75) => photo(self.rng, 0.4, 1.2, true),
                0 => paint(self.rng, 0.2, 0.55),
                1 => paint(self.rng, 0.78, 0.95),
                _ => match &accent {
                    Some((a, t)) if *a == k => t.clone(),
                    _ => wall_paint.clone(),
                },
            };
            self.add(Shape::Quad(Quad::new(origin, u, v, size)), texture, name.to_string());
        }
    }

    /// Skirting boards: a strip along the bottom of each wall, just in front of it.
    fn skirting(&mut self) {
        let h = self.rng.range(0.06, 0.12);
        let t = paint(self.rng, 0.2, 0.95);
        let (hw, o) = (self.half_width, WALL_OFFSET);
        let (top, depth) = (self.floor - h, self.far - self.back);
        let strips = [
            (Vector3::new(-hw, top, self.far - o), Vector3::x(), 2.0 * hw),
            (Vector3::new(-hw, top, self.back + o), Vector3::x(), 2.0 * hw),
            (Vector3::new(-hw + o, top, self.back), Vector3::z(), depth),
            (Vector3::new(hw - o, top, self.back), Vector3::z(), depth),
        ];
        for (origin, along, len) in strips {
            self.add(
                Shape::Quad(Quad::new(origin, along, Vector3::y(), [len, h])),
                t.clone(),
                "skirting".into(),
            );
        }
    }

    fn wall_features(&mut self) {
        let wall = self.rng.below(4);
        if let Some(q) = self.wall_quad(wall, 0.85, 2.05, 0.0) {
            let t = if self.rng.chance(0.5) {
                paint(self.rng, 0.3, 0.9)
            } else {
                photo(self.rng, 2.0, 2.8, false)
            };
            self.add(Shape::Quad(q), t, "door".into());
        }
        if self.rng.chance(0.6) {
            let (w, h) = (self.rng.range(0.8, 1.6), self.rng.range(0.8, 1.3));
            let (wall, bottom) = (self.rng.below(3), self.rng.range(0.8, 1.0));
            if let Some(q) = self.wall_quad(wall, w, h, bottom) {
                let t = paint(self.rng, 0.97, 1.0);
                self.add(Shape::Quad(q), t, "bright window".into());
            }
        }
        for _ in 0..self.rng.below(3) {
            let (w, h) = (self.rng.range(0.3, 0.9), self.rng.range(0.3, 0.7));
            let (wall, bottom) = (self.rng.below(3), self.rng.range(1.1, 1.5));
            if let Some(q) = self.wall_quad(wall, w, h, bottom) {
                let t = photo(self.rng, w.max(h) * 1.4, w.max(h) * 2.0, false);
                self.add(Shape::Quad(q), t, format!("picture {w:.2} x {h:.2} m"));
            }
        }
    }

    /// A free floor spot for a footprint of half sides `(hx, hz)`, rotated by a random yaw (or
    /// axis-aligned); returns `(x, z, yaw)`.
    fn floor_spot(&mut self, hx: f64, hz: f64, free_yaw: bool) -> Option<(f64, f64, f64)> {
        let r = (hx * hx + hz * hz).sqrt();
        for _ in 0..PLACEMENT_TRIES {
            let yaw = if free_yaw { self.rng.range(-0.6, 0.6) } else { 0.0 };
            let f = Footprint {
                x: self.rng.range(-self.half_width, self.half_width),
                z: self.rng.range(self.back, self.far),
                r,
            };
            if self.inside_room(&f) && self.clear_of_camera(&f) && self.clear_of_objects(&f) {
                self.footprints.push(f);
                return Some((f.x, f.z, yaw));
            }
        }
        None
    }

    /// A spot against the left, right or far wall for a footprint `2 hx` wide along the wall and
    /// `2 hz` deep: `(x, z, yaw)` with the object's local +z pointing at the wall.
    fn wall_spot(&mut self, hx: f64, hz: f64) -> Option<(f64, f64, f64)> {
        for _ in 0..PLACEMENT_TRIES {
            let wall = self.rng.below(3);
            let (x, z, yaw) = match wall {
                0 => (self.rng.range(-self.half_width + hx, self.half_width - hx), self.far - hz - GAP, 0.0),
                w => {
                    let z = self.rng.range(self.back + hx + GAP, self.far - hx - GAP);
                    // Yaw ±90°: local x runs along the wall, local +z points at the wall.
                    let side = if w == 1 { -1.0 } else { 1.0 };
                    (side * (self.half_width - hz - GAP), z, side * std::f64::consts::FRAC_PI_2)
                }
            };
            let f = Footprint { x, z, r: (hx * hx + hz * hz).sqrt() };
            if self.clear_of_camera(&f) && self.clear_of_objects(&f) {
                self.footprints.push(f);
                return Some((x, z, yaw));
            }
        }
        None
    }

    fn cuboid(
        &mut self,
        centre: Vector3<f64>,
        axes: Matrix3<f64>,
        half: Vector3<f64>,
        t: Texture,
        what: &str,
    ) {
        let what = format!("{what} {:.2} x {:.2} x {:.2} m", 2.0 * half.x, 2.0 * half.y, 2.0 * half.z);
        self.add(Shape::Cuboid(Cuboid { centre, axes, half }), t, what);
    }

    fn furniture_texture(&mut self) -> Texture {
        if self.rng.chance(0.7) {
            photo(self.rng, 0.8, 2.0, false)
        } else {
            paint(self.rng, 0.15, 0.85)
        }
    }

    /// A table: a top slab on four legs.
    fn table(&mut self) {
        let (hx, hz) = (self.rng.range(0.3, 0.8), self.rng.range(0.3, 0.5));
        let Some((x, z, yaw)) = self.floor_spot(hx, hz, true) else { return };
        let (height, thick, leg) =
            (self.rng.range(0.7, 0.78), self.rng.range(0.025, 0.05), self.rng.range(0.02, 0.035));
        let axes = yaw_axes(yaw);
        let top = self.furniture_texture();
        let top_centre = Vector3::new(x, self.floor - height + thick / 2.0, z);
        self.cuboid(top_centre, axes, Vector3::new(hx, thick / 2.0, hz), top, "table top");
        let legs =
            if self.rng.chance(0.5) { paint(self.rng, 0.1, 0.6) } else { photo(self.rng, 0.3, 0.6, false) };
        let leg_half = Vector3::new(leg, (height - thick) / 2.0, leg);
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let local = Vector3::new(sx * (hx - 2.0 * leg), 0.0, sz * (hz - 2.0 * leg));
            let c = Vector3::new(x, self.floor - (height - thick) / 2.0, z) + axes * local;
            self.cuboid(c, axes, leg_half, legs.clone(), "table leg");
        }
    }

    /// A cabinet or shelf against a wall.
    fn wall_cabinet(&mut self) {
        let (hx, hz, hy) = (self.rng.range(0.2, 0.6), self.rng.range(0.15, 0.3), self.rng.range(0.4, 1.0));
        let Some((x, z, yaw)) = self.wall_spot(hx, hz) else { return };
        let t = self.furniture_texture();
        self.cuboid(
            Vector3::new(x, self.floor - hy, z),
            yaw_axes(yaw),
            Vector3::new(hx, hy, hz),
            t,
            "cabinet",
        );
    }

    /// A sofa against a wall: a seat block and a back block.
    fn sofa(&mut self) {
        let (hx, hz) = (self.rng.range(0.6, 1.0), self.rng.range(0.35, 0.45));
        let Some((x, z, yaw)) = self.wall_spot(hx, hz) else { return };
        let axes = yaw_axes(yaw);
        let t = photo(self.rng, 0.5, 1.0, false);
        let seat = self.rng.range(0.2, 0.25);
        let back = self.rng.range(0.09, 0.12);
        let seat_half = Vector3::new(hx, seat, hz - back);
        let c = Vector3::new(x, self.floor - seat, z) + axes * Vector3::new(0.0, 0.0, -back);
        self.cuboid(c, axes, seat_half, t.clone(), "sofa seat");
        let back_half = Vector3::new(hx, self.rng.range(0.38, 0.45), back);
        let c = Vector3::new(x, self.floor - back_half.y, z) + axes * Vector3::new(0.0, 0.0, hz - back);
        self.cuboid(c, axes, back_half, t, "sofa back");
    }

    /// A box on the floor, sometimes with a smaller one on top.
    fn real_box(&mut self) {
        let half =
            Vector3::new(self.rng.range(0.12, 0.4), self.rng.range(0.1, 0.4), self.rng.range(0.12, 0.4));
        let Some((x, z, yaw)) = self.floor_spot(half.x, half.z, true) else { return };
        let t = self.furniture_texture();
        let centre = Vector3::new(x, self.floor - half.y, z);
        self.cuboid(centre, yaw_axes(yaw), half, t, "box");
        if self.rng.chance(0.3) {
            let s = self.rng.range(0.5, 0.8);
            let top = Vector3::new(half.x * s, self.rng.range(0.05, 0.2), half.z * s);
            let c = Vector3::new(x, centre.y - half.y - top.y, z);
            let t = self.furniture_texture();
            let turn = self.rng.range(-0.3, 0.3);
            self.cuboid(c, yaw_axes(yaw + turn), top, t, "stacked box");
        }
    }

    /// A board leaning against the far wall, or a panel against a side wall: slanted planes.
    fn leaning_plane(&mut self, wall: Wall) {
        for _ in 0..PLACEMENT_TRIES {
            let (width, length, lean) =
                (self.rng.range(0.5, 1.1), self.rng.range(0.9, 1.8), self.rng.range(0.15, 0.5));
            let (run, rise) = (length * sin(lean), length * cos(lean));
            let (origin, along, up, f) = if wall == 0 {
                let x0 = self.rng.range(-self.half_width + GAP, self.half_width - GAP - width);
                let f = Footprint { x: x0 + width / 2.0, z: self.far - run / 2.0, r: 0.5 * width.hypot(run) };
                (
                    Vector3::new(x0, self.floor, self.far - run - POSTER_OFFSET),
                    Vector3::x(),
                    Vector3::new(0.0, -rise, run),
                    f,
                )
            } else {
                let side = if wall == 1 { -1.0 } else { 1.0 };
                let z0 = self.rng.range(self.back + GAP, self.far - GAP - width);
                let xw = side * (self.half_width - POSTER_OFFSET);
                let f =
                    Footprint { x: xw - side * run / 2.0, z: z0 + width / 2.0, r: 0.5 * width.hypot(run) };
                (
                    Vector3::new(xw - side * run, self.floor, z0),
                    Vector3::z(),
                    Vector3::new(side * run, -rise, 0.0),
                    f,
                )
            };
            if !(self.clear_of_camera(&f) && self.clear_of_objects(&f)) {
                continue;
            }
            self.footprints.push(f);
            let quad = Quad::new(origin, along, up / length, [width, length]);
            let t = self.furniture_texture();
            let what =
                format!("slanted board {width:.2} x {length:.2} m leaning {:.0} deg", lean.to_degrees());
            self.add(Shape::Quad(quad), t, what);
            return;
        }
    }
}

/// Generate a realistic-style room around `path`.
pub(super) fn generate(rng: &mut SplitMix64, path: &CameraPath) -> (Room, Lamp) {
    let (c, ext) = (path.centre(), CameraPath::half_extent());
    let camera_height = rng.range(CAMERA_HEIGHT.0, CAMERA_HEIGHT.1);
    let floor = c.y + camera_height;
    let ceiling = floor - rng.range(ROOM_HEIGHT.0, ROOM_HEIGHT.1);
    let half_width = rng.range(ROOM_HALF_WIDTH.0, ROOM_HALF_WIDTH.1);
    let far = c.z + rng.range(FAR_WALL.0, FAR_WALL.1);
    let back = c.z - ext.z - rng.range(BACK_GAP.0, BACK_GAP.1);
    let keep_out =
        [c.x - ext.x - CLEARANCE, c.x + ext.x + CLEARANCE, c.z - ext.z - CLEARANCE, c.z + ext.z + CLEARANCE];
    let light_dir = Vector3::new(rng.range(-0.5, 0.5), 1.0, rng.range(-0.2, 0.6)).normalize();
    let ambient = rng.range(0.6, 0.8);
    let light = Light { direction: light_dir, ambient, diffuse: rng.range(0.15, 0.35) };
    let lamp = Lamp {
        position: Vector3::new(
            rng.range(-half_width * 0.6, half_width * 0.6),
            ceiling + 0.3,
            rng.range(back + 0.5, far - 0.5),
        ),
        power: rng.range(0.2, 0.5),
        radius: rng.range(1.5, 2.5),
    };
    let mut b = Builder {
        rng,
        surfaces: Vec::new(),
        summary: vec![format!(
            "realistic room {:.2} m wide, {:.2} m high, {:.2} m deep; camera {:.2} m above the floor",
            2.0 * half_width,
            floor - ceiling,
            far - back,
            camera_height
        )],
        footprints: Vec::new(),
        keep_out,
        half_width,
        back,
        far,
        floor,
        ceiling,
    };
    b.real_room();
    if b.rng.chance(0.7) {
        b.skirting();
    }
    b.wall_features();
    if b.rng.chance(0.8) {
        b.leaning_plane(0);
    }
    if b.rng.chance(0.5) {
        let side = 1 + b.rng.below(2);
        b.leaning_plane(side);
    }
    if b.rng.chance(0.5) {
        b.sofa();
    }
    for _ in 0..b.rng.below(3) {
        b.table();
    }
    for _ in 0..1 + b.rng.below(3) {
        b.wall_cabinet();
    }
    for _ in 0..3 + b.rng.below(6) {
        b.real_box();
    }
    (Room { surfaces: b.surfaces, light, summary: b.summary }, lamp)
}
