//! The seeded room layout: walls, floor and ceiling, boxes (some rotated about the vertical, some
//! stacked), an optional wall cabinet and poster, and a board leaning against the far wall.
//!
//! World frame: x right, y **down**, z forward (the camera's axes at zero rotation); the camera path
//! is centred at the origin, the floor is at `y = camera height > 0`. Every object keeps at least
//! [`CLEARANCE`] (in x and z) from the box the camera path stays in.

use nalgebra::{Matrix3, Vector3};

use super::detmath::{cos, sin};
use super::scene::Light;
use super::surface::{Cuboid, Quad, Shape, Surface};
use super::texture::Texture;
use super::trajectory::CameraPath;
use crate::util::rng::SplitMix64;

/// Horizontal distance every object keeps from the camera path's box, metres.
pub(super) const CLEARANCE: f64 = 0.7;
/// Room quads extend this far past the room's edges so that no ray slips through a corner.
pub(super) const SEAM_OVERLAP: f64 = 0.01;
/// Gap kept between objects and walls or each other, metres.
pub(super) const GAP: f64 = 0.03;
/// Camera height above the floor, metres.
const CAMERA_HEIGHT: (f64, f64) = (1.3, 1.6);
/// Room height, half-width, and far-wall distance from the path centre, metres.
const ROOM_HEIGHT: (f64, f64) = (2.5, 3.0);
const ROOM_HALF_WIDTH: (f64, f64) = (2.0, 2.8);
const FAR_WALL: (f64, f64) = (3.9, 4.8);
/// Back wall distance behind the path box, metres.
const BACK_GAP: (f64, f64) = (0.5, 1.0);
/// Number of floor boxes (inclusive range) and placement attempts per box.
const FLOOR_BOXES: (usize, usize) = (4, 7);
pub(super) const PLACEMENT_TRIES: usize = 60;
/// Probability of a box stacked on a floor box, a wall cabinet and a poster.
const STACK_CHANCE: f64 = 0.35;
const CABINET_CHANCE: f64 = 0.5;
const POSTER_CHANCE: f64 = 0.6;
/// Texture period multiplier of the room's walls, floor and ceiling (seen from further away).
const ROOM_TEXTURE_SIZE: f64 = 2.0;
/// Probability that the ceiling, and that one wall, is near-uniform.
const PLAIN_CEILING_CHANCE: f64 = 0.6;
const PLAIN_WALL_CHANCE: f64 = 0.7;
/// Offset of a poster from its wall, metres.
pub(super) const POSTER_OFFSET: f64 = 0.005;

/// A generated room.
pub(super) struct Room {
    pub surfaces: Vec<Surface>,
    pub light: Light,
    pub summary: Vec<String>,
}

/// A footprint on the floor plane (x, z) used to keep objects apart: a disc.
#[derive(Clone, Copy)]
pub(super) struct Footprint {
    pub x: f64,
    pub z: f64,
    pub r: f64,
}

pub(super) struct Builder<'a> {
    pub rng: &'a mut SplitMix64,
    pub surfaces: Vec<Surface>,
    pub summary: Vec<String>,
    pub footprints: Vec<Footprint>,
    /// Camera path box in (x, z): min and max, grown by CLEARANCE.
    pub keep_out: [f64; 4],
    pub half_width: f64,
    pub back: f64,
    pub far: f64,
    pub floor: f64,
    pub ceiling: f64,
}

/// A room rectangle: name, corner, the two unit side directions, side lengths.
pub(super) type RoomPlane = (&'static str, Vector3<f64>, Vector3<f64>, Vector3<f64>, [f64; 2]);

pub(super) fn yaw_axes(yaw: f64) -> Matrix3<f64> {
    let (c, s) = (cos(yaw), sin(yaw));
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

impl Builder<'_> {
    pub(super) fn add(&mut self, shape: Shape, texture: Texture, what: String) {
        self.summary.push(format!("{what}: {}", texture_kind(&texture)));
        self.surfaces.push(Surface { shape, texture });
    }

    /// Whether `f` keeps [`CLEARANCE`] from the camera path's box.
    pub(super) fn clear_of_camera(&self, f: &Footprint) -> bool {
        let [x0, x1, z0, z1] = self.keep_out;
        let dx = (x0 - f.x).max(f.x - x1).max(0.0);
        let dz = (z0 - f.z).max(f.z - z1).max(0.0);
        (dx * dx + dz * dz).sqrt() >= f.r
    }

    /// Whether `f` keeps [`GAP`] from every object placed so far.
    pub(super) fn clear_of_objects(&self, f: &Footprint) -> bool {
        self.footprints.iter().all(|o| {
            let (dx, dz) = (o.x - f.x, o.z - f.z);
            (dx * dx + dz * dz).sqrt() >= o.r + f.r + GAP
        })
    }

    /// Whether `f` keeps [`GAP`] from the walls.
    pub(super) fn inside_room(&self, f: &Footprint) -> bool {
        f.x.abs() + f.r + GAP <= self.half_width
            && f.z - f.r - GAP >= self.back
            && f.z + f.r + GAP <= self.far
    }

    /// The six room rectangles (floor, ceiling, back, far, left, right wall), overlapping at the seams.
    pub(super) fn room_planes(&self) -> [RoomPlane; 6] {
        let (w, e) = (self.half_width, SEAM_OVERLAP);
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
        let depth = self.far - self.back;
        let height = self.floor - self.ceiling;
        [
            (
                "floor",
                Vector3::new(-w - e, self.floor, self.back - e),
                x,
                z,
                [2.0 * (w + e), depth + 2.0 * e],
            ),
            (
                "ceiling",
                Vector3::new(-w - e, self.ceiling, self.back - e),
                x,
                z,
                [2.0 * (w + e), depth + 2.0 * e],
            ),
            (
                "back wall",
                Vector3::new(-w - e, self.ceiling - e, self.back),
                x,
                y,
                [2.0 * (w + e), height + 2.0 * e],
            ),
            (
                "far wall",
                Vector3::new(-w - e, self.ceiling - e, self.far),
                x,
                y,
                [2.0 * (w + e), height + 2.0 * e],
            ),
            (
                "left wall",
                Vector3::new(-w, self.ceiling - e, self.back - e),
                z,
                y,
                [depth + 2.0 * e, height + 2.0 * e],
            ),
            (
                "right wall",
                Vector3::new(w, self.ceiling - e, self.back - e),
                z,
                y,
                [depth + 2.0 * e, height + 2.0 * e],
            ),
        ]
    }

    fn room(&mut self) {
        let planes = self.room_planes();
        // Real rooms have plain surfaces: the ceiling is usually plain, often one wall is too.
        let plain_ceiling = self.rng.chance(PLAIN_CEILING_CHANCE);
        let plain_wall = if self.rng.chance(PLAIN_WALL_CHANCE) { 2 + self.rng.below(4) } else { usize::MAX };
        for (k, (name, origin, u, v, size)) in planes.into_iter().enumerate() {
            let plain = (k == 1 && plain_ceiling) || k == plain_wall;
            let texture = if plain {
                Texture::near_uniform(self.rng)
            } else {
                Texture::random(self.rng, true, ROOM_TEXTURE_SIZE)
            };
            self.add(Shape::Quad(Quad::new(origin, u, v, size)), texture, name.to_string());
        }
    }

    /// A board leaning against the far wall: a slanted plane.
    fn leaning_board(&mut self) {
        for _ in 0..PLACEMENT_TRIES {
            let width = self.rng.range(0.6, 1.2);
            let length = self.rng.range(1.2, 1.9);
            let lean = self.rng.range(0.2, 0.45);
            let x0 = self.rng.range(-self.half_width + GAP, self.half_width - GAP - width);
            let (run, rise) = (length * sin(lean), length * cos(lean));
            let z0 = self.far - run - POSTER_OFFSET;
            let f = Footprint {
                x: x0 + width / 2.0,
                z: self.far - run / 2.0,
                r: 0.5 * (width * width + run * run).sqrt(),
            };
            if !(self.clear_of_camera(&f) && self.clear_of_objects(&f)) {
                continue;
            }
            self.footprints.push(f);
            let up = Vector3::new(0.0, -rise, run) / length;
            let quad = Quad::new(Vector3::new(x0, self.floor, z0), Vector3::x(), up, [width, length]);
            let texture = Texture::random(self.rng, false, 1.0);
            let what = format!("board {width:.2} x {length:.2} m leaning {:.0} deg", lean.to_degrees());
            self.add(Shape::Quad(quad), texture, what);
            return;
        }
    }

    fn floor_box(&mut self) {
        for _ in 0..PLACEMENT_TRIES {
            let half =
                Vector3::new(self.rng.range(0.15, 0.5), self.rng.range(0.15, 0.6), self.rng.range(0.15, 0.5));
            let yaw =
                if self.rng.chance(0.5) { 0.0 } else { self.rng.range(0.0, std::f64::consts::FRAC_PI_2) };
            let r = (half.x * half.x + half.z * half.z).sqrt();
            let x = self.rng.range(-self.half_width, self.half_width);
            let z = self.rng.range(self.back, self.far);
            let f = Footprint { x, z, r };
            if !(self.inside_room(&f) && self.clear_of_camera(&f) && self.clear_of_objects(&f)) {
                continue;
            }
            self.footprints.push(f);
            let centre = Vector3::new(x, self.floor - half.y, z);
            let texture = Texture::random(self.rng, true, 1.0);
            let what = format!(
                "box {:.2} x {:.2} x {:.2} m, yaw {:.0} deg",
                2.0 * half.x,
                2.0 * half.y,
                2.0 * half.z,
                yaw.to_degrees()
            );
            self.add(Shape::Cuboid(Cuboid { centre, axes: yaw_axes(yaw), half }), texture, what);
            if self.rng.chance(STACK_CHANCE) {
                self.stacked_box(centre, half, r);
            }
            return;
        }
    }

    /// A smaller box resting on top of the box at `centre` with half sides `half`.
    fn stacked_box(&mut self, centre: Vector3<f64>, half: Vector3<f64>, r: f64) {
        let s = self.rng.range(0.4, 0.75);
        let top = Vector3::new(half.x.min(half.z) * s, self.rng.range(0.08, 0.3), half.x.min(half.z) * s);
        let yaw = self.rng.range(0.0, std::f64::consts::FRAC_PI_2);
        let slack = (half.x.min(half.z) - top.x * std::f64::consts::SQRT_2).max(0.0) * 0.5;
        let (dx, dz) = (self.rng.range(-slack, slack), self.rng.range(-slack, slack));
        debug_assert!(top.x < r);
        let c = Vector3::new(centre.x + dx, centre.y - half.y - top.y, centre.z + dz);
        let texture = Texture::random(self.rng, true, 1.0);
        let what = format!("stacked box {:.2} x {:.2} x {:.2} m", 2.0 * top.x, 2.0 * top.y, 2.0 * top.z);
        self.add(Shape::Cuboid(Cuboid { centre: c, axes: yaw_axes(yaw), half: top }), texture, what);
    }

    /// A cabinet on the left or right wall, off the floor.
    fn cabinet(&mut self) {
        let side = if self.rng.chance(0.5) { -1.0 } else { 1.0 };
        for _ in 0..PLACEMENT_TRIES {
            let half =
                Vector3::new(self.rng.range(0.12, 0.2), self.rng.range(0.15, 0.3), self.rng.range(0.3, 0.6));
            let bottom = self.rng.range(1.0, 1.5);
            let x = side * (self.half_width - half.x - GAP);
            let z = self.rng.range(self.back, self.far);
            let f = Footprint { x, z, r: half.z.max(half.x) };
            // Cabinets hang above the boxes, so only the camera keep-out and the walls constrain them.
            if !(self.clear_of_camera(&f) && z - half.z - GAP >= self.back && z + half.z + GAP <= self.far) {
                continue;
            }
            let centre = Vector3::new(x, self.floor - bottom - half.y, z);
            let texture = Texture::random(self.rng, true, 1.0);
            let what = format!("wall cabinet {:.2} m above the floor", bottom);
            self.add(Shape::Cuboid(Cuboid { centre, axes: Matrix3::identity(), half }), texture, what);
            return;
        }
    }

    /// A poster just in front of the left, right or far wall.
    fn poster(&mut self) {
        let (w, h) = (self.rng.range(0.5, 1.0), self.rng.range(0.4, 0.8));
        let top = self.ceiling + self.rng.range(0.4, 0.8);
        let which = self.rng.below(3);
        let quad = match which {
            0 | 1 => {
                let x = if which == 0 {
                    -self.half_width + POSTER_OFFSET
                } else {
                    self.half_width - POSTER_OFFSET
                };
                let z = self.rng.range(self.back + 0.3, self.far - 0.3 - w);
                Quad::new(Vector3::new(x, top, z), Vector3::z(), Vector3::y(), [w, h])
            }
            _ => {
                let x = self.rng.range(-self.half_width + 0.3, self.half_width - 0.3 - w);
                Quad::new(Vector3::new(x, top, self.far - POSTER_OFFSET), Vector3::x(), Vector3::y(), [w, h])
            }
        };
        let texture = Texture::random(self.rng, false, 1.0);
        let wall = ["left", "right", "far"][which];
        self.add(Shape::Quad(quad), texture, format!("poster {w:.2} x {h:.2} m on the {wall} wall"));
    }
}

/// Short name of a texture's kind.
pub(super) fn texture_kind(t: &Texture) -> &'static str {
    match t {
        Texture::Uniform { .. } => "near-uniform with faint gradient",
        Texture::Noise { .. } => "fractal value noise",
        Texture::Stripes { .. } => "stripes",
        Texture::Checker { .. } => "checker",
        Texture::Collage { .. } => "patch collage",
        Texture::Paint { .. } => "paint",
        Texture::Photo { .. } => "photo crop",
    }
}

/// Generate a room around `path`.
pub(super) fn generate(rng: &mut SplitMix64, path: &CameraPath) -> Room {
    let c = path.centre();
    let ext = CameraPath::half_extent();
    let camera_height = rng.range(CAMERA_HEIGHT.0, CAMERA_HEIGHT.1);
    let floor = c.y + camera_height;
    let ceiling = floor - rng.range(ROOM_HEIGHT.0, ROOM_HEIGHT.1);
    let half_width = rng.range(ROOM_HALF_WIDTH.0, ROOM_HALF_WIDTH.1);
    let far = c.z + rng.range(FAR_WALL.0, FAR_WALL.1);
    let back = c.z - ext.z - rng.range(BACK_GAP.0, BACK_GAP.1);
    let keep_out =
        [c.x - ext.x - CLEARANCE, c.x + ext.x + CLEARANCE, c.z - ext.z - CLEARANCE, c.z + ext.z + CLEARANCE];
    let light_dir = Vector3::new(rng.range(-0.4, 0.4), 1.0, rng.range(0.1, 0.5)).normalize();
    let ambient = rng.range(0.5, 0.65);
    let light = Light { direction: light_dir, ambient, diffuse: 1.0 - ambient };
    let mut b = Builder {
        rng,
        surfaces: Vec::new(),
        summary: vec![format!(
            "room {:.2} m wide, {:.2} m high, {:.2} m deep; camera {:.2} m above the floor",
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
    b.room();
    b.leaning_board();
    let boxes = FLOOR_BOXES.0 + b.rng.below(FLOOR_BOXES.1 - FLOOR_BOXES.0 + 1);
    for _ in 0..boxes {
        b.floor_box();
    }
    if b.rng.chance(CABINET_CHANCE) {
        b.cabinet();
    }
    if b.rng.chance(POSTER_CHANCE) {
        b.poster();
    }
    Room { surfaces: b.surfaces, light, summary: b.summary }
}
