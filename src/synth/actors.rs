//! The objects that become annotations: their Lyft categories and their shapes.
//!
//! Every actor is a small union of convex parts (see [`super::shapes`]) in its own frame (origin
//! at the geometric centre of its annotation box, x along the heading, z up), built so that the
//! union's bounds are exactly the annotation box: the box is tight, and every LiDAR return on the
//! actor lies inside it. Cars are a rounded lower body, a narrower rounded cabin with glass sides
//! and a painted roof, and four wheels; vans and ambulances have a taller cabin; trucks a cab and
//! a cargo box on a chassis; buses a rounded box; pedestrians legs, torso and head; cyclists and
//! motorcyclists wheels, frame and rider; animals (dogs) body, head, legs and tail. Sizes follow
//! Lyft's annotations (e.g. cars w 1.8–2.1, l 4.2–5.0, h 1.4–1.9 m), rounded to millimetres.
//! Not modelled: mirrors, open doors, trailers, articulated buses, see-through glass.

use rand::Rng;

use super::shapes::{materials, Axis, Material, Shape};

/// The nine Lyft object categories.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Category {
    Car,
    Pedestrian,
    Animal,
    OtherVehicle,
    Bus,
    Motorcycle,
    Truck,
    EmergencyVehicle,
    Bicycle,
}

impl Category {
    /// All categories, in the order of the real `category.json`.
    pub const ALL: [Category; 9] = [
        Category::Car,
        Category::Pedestrian,
        Category::Animal,
        Category::OtherVehicle,
        Category::Bus,
        Category::Motorcycle,
        Category::Truck,
        Category::EmergencyVehicle,
        Category::Bicycle,
    ];

    /// The Lyft category name.
    pub fn name(self) -> &'static str {
        match self {
            Category::Car => "car",
            Category::Pedestrian => "pedestrian",
            Category::Animal => "animal",
            Category::OtherVehicle => "other_vehicle",
            Category::Bus => "bus",
            Category::Motorcycle => "motorcycle",
            Category::Truck => "truck",
            Category::EmergencyVehicle => "emergency_vehicle",
            Category::Bicycle => "bicycle",
        }
    }

    /// The token of this category in the real Lyft `category.json`.
    pub fn token(self) -> &'static str {
        match self {
            Category::Car => "8eccddb83fa7f8f992b2500f2ad658f65c9095588f3bc0ae338d97aff2dbcb9c",
            Category::Pedestrian => "73e8de69959eb9f5b4cd2859e74bec4b5491417336cad63f27e8edb8530ffbf8",
            Category::Animal => "f81f51e1897311b55c0c6247c3db825466733e08df687c0ea830b026316a1c12",
            Category::OtherVehicle => "a8619a81f5acc7da2a2f034420db2b2f43a015c8c689822e5295b5d6f7a5d8d6",
            Category::Bus => "7ea5868735dc408109bfa74fd139bd8c5aa3767b52e054b8e792cabcf309c6f4",
            Category::Motorcycle => "1248d937c7a1a2eb1022ba9e806ebd5183b6c20c7f5703d8a7320600f1caad27",
            Category::Truck => "8af78d27e148a8f544f4c86b2a3f4bd6192b975d1065dd932ebdb8879778e275",
            Category::EmergencyVehicle => "c4e92c2b854fb03382838643c36d01a349f5624a11f184042d91d916d19acdbd",
            Category::Bicycle => "8c07dfa7af0da0191d59a2db50dc26ad1528be1fad483f17e2586309482d81bd",
        }
    }

    /// Whether this is a road vehicle with four or more wheels.
    pub fn is_vehicle(self) -> bool {
        matches!(
            self,
            Category::Car
                | Category::OtherVehicle
                | Category::Bus
                | Category::Truck
                | Category::EmergencyVehicle
        )
    }
}

/// One convex part of an actor, placed in the actor's frame (no rotation of its own).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Part {
    pub offset: [f64; 3],
    pub shape: Shape,
    pub material: Material,
}

/// An actor's shape: its annotation size and its parts.
#[derive(Debug, Clone, PartialEq)]
pub struct ActorShape {
    /// Length along the heading, width, height (m).
    pub size_lwh: [f64; 3],
    pub parts: Vec<Part>,
}

impl ActorShape {
    /// The bounds (min, max) of the union of the parts in the actor's frame.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.parts {
            let (a, b) = p.shape.local_bounds();
            for k in 0..3 {
                lo[k] = lo[k].min(p.offset[k] + a[k]);
                hi[k] = hi[k].max(p.offset[k] + b[k]);
            }
        }
        (lo, hi)
    }

    /// Whether a point of the actor's frame lies in one of its parts (tolerance in m).
    pub fn contains(&self, p: &[f64; 3], tol: f64) -> bool {
        self.parts.iter().any(|part| {
            let q = [
                p[0] - part.offset[0],
                p[1] - part.offset[1],
                p[2] - part.offset[2],
            ];
            part.shape.contains(&q, tol)
        })
    }
}

fn mm(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

fn part(offset: [f64; 3], shape: Shape, material: Material) -> Part {
    Part {
        offset,
        shape,
        material,
    }
}

fn paint(rng: &mut impl Rng) -> f32 {
    // Black, dark grey, blue/red, silver, white.
    const PALETTE: [f32; 5] = [0.06, 0.12, 0.22, 0.4, 0.6];
    PALETTE[rng.random_range(0..PALETTE.len())]
}

fn clothing(rng: &mut impl Rng) -> Material {
    Material::uniform(rng.random_range(0.08..0.5))
}

/// How car sizes are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CarSizes {
    /// Uniform over 4.2–5.0 × 1.8–2.1 × 1.4–1.9 m, one body shape (the v1–v3 simulator).
    #[default]
    Uniform,
    /// Body types with their own sizes and cabins: compacts 15 % (3.6–4.3 m long, KITTI's
    /// typical car), sedans 30 %, SUVs 40 %, pickups 15 % (5.3–5.9 m, a short cabin and the bed
    /// at belt height); the mean, about 4.74 × 1.90 × 1.66 m, is near real Lyft's 4.75 × 1.92 × 1.71 m.
    Mixed,
}

/// One body type of the `Mixed` car sizes: drawn while u < `up_to` (u uniform in [0, 1)), with
/// length, width and height uniform in their ranges (m) and its cabin.
struct BodyType {
    up_to: f64,
    l: (f64, f64),
    w: (f64, f64),
    h: (f64, f64),
    cabin: Cabin,
}

/// Compact, sedan, SUV, pickup (the cabin forward of the middle, the bed behind it at belt
/// height).
const BODY_TYPES: [BodyType; 4] = [
    BodyType {
        up_to: 0.15,
        l: (3.6, 4.3),
        w: (1.65, 1.8),
        h: (1.4, 1.55),
        cabin: Cabin {
            belt: 0.5,
            length: 0.6,
            x: -0.02,
            width: 0.43,
        },
    },
    BodyType {
        up_to: 0.45,
        l: (4.4, 4.95),
        w: (1.78, 1.9),
        h: (1.4, 1.5),
        cabin: Cabin {
            belt: 0.52,
            length: 0.52,
            x: -0.05,
            width: 0.43,
        },
    },
    BodyType {
        up_to: 0.85,
        l: (4.4, 5.1),
        w: (1.85, 2.05),
        h: (1.7, 1.9),
        cabin: Cabin {
            belt: 0.5,
            length: 0.66,
            x: -0.08,
            width: 0.44,
        },
    },
    BodyType {
        up_to: 1.0,
        l: (5.3, 5.9),
        w: (1.95, 2.1),
        h: (1.8, 1.95),
        cabin: Cabin {
            belt: 0.55,
            length: 0.36,
            x: 0.12,
            width: 0.44,
        },
    },
];

/// A car of the `Mixed` size distribution: one of [`BODY_TYPES`].
fn mixed_car(rng: &mut impl Rng) -> ActorShape {
    let u: f64 = rng.random_range(0.0..1.0);
    let body = BODY_TYPES
        .iter()
        .find(|b| u < b.up_to)
        .unwrap_or(&BODY_TYPES[BODY_TYPES.len() - 1]);
    let l = rng.random_range(body.l.0..body.l.1);
    let w = rng.random_range(body.w.0..body.w.1);
    let h = rng.random_range(body.h.0..body.h.1);
    let rho = paint(rng);
    cabin_vehicle(mm(l), mm(w), mm(h), body.cabin, rho)
}

/// Builds a random shape of a category, cars drawn as `car_sizes` says.
pub fn build_with(category: Category, car_sizes: CarSizes, rng: &mut impl Rng) -> ActorShape {
    if category == Category::Car && car_sizes == CarSizes::Mixed {
        return mixed_car(rng);
    }
    build(category, rng)
}

/// Builds a random shape of a category.
pub fn build(category: Category, rng: &mut impl Rng) -> ActorShape {
    match category {
        Category::Car => {
            let l = mm(rng.random_range(4.2..5.0));
            let w = mm(rng.random_range(1.8..2.1));
            let h = mm(rng.random_range(1.4..1.9));
            let rho = paint(rng);
            cabin_vehicle(
                l,
                w,
                h,
                Cabin {
                    belt: 0.52,
                    length: 0.55,
                    x: -0.05,
                    width: 0.43,
                },
                rho,
            )
        }
        Category::OtherVehicle => {
            let l = mm(rng.random_range(5.0..6.2));
            let w = mm(rng.random_range(1.95..2.2));
            let h = mm(rng.random_range(1.9..2.6));
            let rho = paint(rng);
            cabin_vehicle(
                l,
                w,
                h,
                Cabin {
                    belt: 0.45,
                    length: 0.78,
                    x: -0.09,
                    width: 0.46,
                },
                rho,
            )
        }
        Category::EmergencyVehicle => {
            let l = mm(rng.random_range(6.0..7.0));
            let w = mm(rng.random_range(2.2..2.4));
            let h = mm(rng.random_range(2.6..2.9));
            cab_and_box(l, w, h, 0.72, 0.3, 0.7)
        }
        Category::Truck => {
            let l = mm(rng.random_range(6.5..10.0));
            let w = mm(rng.random_range(2.4..2.6));
            let h = mm(rng.random_range(2.8..3.8));
            let rho = paint(rng);
            cab_and_box(l, w, h, 0.78, rho, rng.random_range(0.3..0.6))
        }
        Category::Bus => {
            let l = mm(rng.random_range(10.0..12.5));
            let w = mm(rng.random_range(2.55..2.6));
            let h = mm(rng.random_range(3.0..3.3));
            bus(l, w, h)
        }
        Category::Pedestrian => {
            let l = mm(rng.random_range(0.5..0.9));
            let w = mm(rng.random_range(0.55..0.8));
            let h = mm(rng.random_range(1.5..1.95));
            let cloth = clothing(rng);
            pedestrian(l, w, h, cloth)
        }
        Category::Bicycle => {
            let l = mm(rng.random_range(1.65..1.9));
            let w = mm(rng.random_range(0.6..0.8));
            let h = mm(rng.random_range(1.6..1.85));
            let cloth = clothing(rng);
            bicycle(l, w, h, cloth)
        }
        Category::Motorcycle => {
            let l = mm(rng.random_range(2.0..2.3));
            let w = mm(rng.random_range(0.8..1.0));
            let h = mm(rng.random_range(1.4..1.6));
            let rho = paint(rng);
            let cloth = clothing(rng);
            motorcycle(l, w, h, rho, cloth)
        }
        Category::Animal => {
            let l = mm(rng.random_range(0.7..1.0));
            let w = mm(rng.random_range(0.28..0.4));
            let h = mm(rng.random_range(0.5..0.75));
            animal(l, w, h, Material::uniform(rng.random_range(0.1..0.4)))
        }
    }
}

/// Where the glasshouse of a car-like vehicle sits, as fractions of the box.
#[derive(Debug, Clone, Copy)]
struct Cabin {
    /// Belt line height / h.
    belt: f64,
    /// Cabin length / l.
    length: f64,
    /// Cabin centre x / l.
    x: f64,
    /// Cabin half width / w.
    width: f64,
}

/// A car or van: rounded lower body, rounded cabin (painted roof, glass sides), four wheels.
fn cabin_vehicle(l: f64, w: f64, h: f64, cabin: Cabin, rho: f32) -> ActorShape {
    let z0 = -0.5 * h;
    let clearance = 0.22;
    let belt = cabin.belt * h;
    let body_half = [0.5 * l, 0.5 * w, 0.5 * (belt - clearance)];
    let body = part(
        [0.0, 0.0, z0 + 0.5 * (clearance + belt)],
        // The ellipsoid rounds the plan-view corners; the face centres stay on the box.
        Shape::RoundedCuboid {
            half: body_half,
            radii: [0.56 * l, 0.89 * w, 4.0],
            offset: [0.0; 3],
        },
        Material::uniform(rho),
    );
    let hc = h - belt;
    let cab = part(
        [cabin.x * l, 0.0, z0 + belt + 0.5 * hc],
        // An ellipsoid centred below the belt line slopes the glass and touches the box top at
        // the cabin centre, so the roof reaches exactly h.
        Shape::RoundedCuboid {
            half: [0.5 * cabin.length * l, cabin.width * w, 0.5 * hc],
            radii: [0.66 * cabin.length * l, 1.2 * cabin.width * w, 1.5 * hc],
            offset: [0.0, 0.0, -hc],
        },
        Material::two_tone(rho, materials::GLASS),
    );
    let rw = (0.3 + 0.12 * (h - 1.4)).clamp(0.3, 0.4);
    let mut parts = vec![body, cab];
    for (x, y) in wheel_positions(l, w, 0.95, 1.0, 0.13) {
        parts.push(part(
            [x, y, z0 + rw],
            Shape::Cylinder {
                axis: Axis::Y,
                radius: rw,
                half_len: 0.11,
            },
            materials::RUBBER,
        ));
    }
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn wheel_positions(l: f64, w: f64, front: f64, rear: f64, inset: f64) -> [(f64, f64); 4] {
    let (xf, xr, y) = (0.5 * l - front, -0.5 * l + rear, 0.5 * w - inset);
    [(xf, y), (xf, -y), (xr, y), (xr, -y)]
}

/// A truck or ambulance: cab in front, cargo box behind on a chassis, two or three axles.
fn cab_and_box(l: f64, w: f64, h: f64, cab_height: f64, cab_rho: f32, box_rho: f32) -> ActorShape {
    let z0 = -0.5 * h;
    let rw = 0.5;
    let cab_len = 2.2;
    let cab_top = cab_height * h;
    let cab = part(
        [0.5 * l - 0.5 * cab_len, 0.0, z0 + 0.5 * (0.45 + cab_top)],
        Shape::RoundedCuboid {
            half: [0.5 * cab_len, 0.5 * w, 0.5 * (cab_top - 0.45)],
            radii: [1.9, 0.8 * w, 5.0],
            offset: [-0.5, 0.0, 0.0],
        },
        Material::two_tone(cab_rho, materials::GLASS),
    );
    let box_len = l - cab_len - 0.3;
    let cargo = part(
        [-0.5 * l + 0.5 * box_len, 0.0, z0 + 0.5 * (1.0 + h)],
        Shape::Cuboid {
            half: [0.5 * box_len, 0.5 * w, 0.5 * (h - 1.0)],
        },
        Material::uniform(box_rho),
    );
    let chassis = part(
        [0.0, 0.0, z0 + 0.72],
        Shape::Cuboid {
            half: [0.5 * l - 0.4, 0.4 * w, 0.27],
        },
        materials::METAL,
    );
    let mut parts = vec![cab, cargo, chassis];
    let mut axles = vec![0.5 * l - 1.2, -0.5 * l + 1.5];
    if l > 8.0 {
        axles.push(-0.5 * l + 2.7);
    }
    for x in axles {
        for y in [0.5 * w - 0.16, -(0.5 * w - 0.16)] {
            parts.push(part(
                [x, y, z0 + rw],
                Shape::Cylinder {
                    axis: Axis::Y,
                    radius: rw,
                    half_len: 0.15,
                },
                materials::RUBBER,
            ));
        }
    }
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn bus(l: f64, w: f64, h: f64) -> ActorShape {
    let z0 = -0.5 * h;
    let rw = 0.5;
    let hb = h - 0.35;
    let body = part(
        [0.0, 0.0, z0 + 0.35 + 0.5 * hb],
        Shape::RoundedCuboid {
            half: [0.5 * l, 0.5 * w, 0.5 * hb],
            radii: [0.53 * l, 0.75 * w, 3.0 * h],
            offset: [0.0; 3],
        },
        Material::two_tone(0.35, 0.15),
    );
    let mut parts = vec![body];
    for (x, y) in wheel_positions(l, w, 2.5, 3.0, 0.16) {
        parts.push(part(
            [x, y, z0 + rw],
            Shape::Cylinder {
                axis: Axis::Y,
                radius: rw,
                half_len: 0.15,
            },
            materials::RUBBER,
        ));
    }
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn pedestrian(l: f64, w: f64, h: f64, cloth: Material) -> ActorShape {
    let z0 = -0.5 * h;
    let leg = 0.47 * h;
    let r_leg = 0.075;
    let parts = vec![
        // Legs mid-stride: one forward, one back (they make the box length).
        part(
            [0.5 * l - r_leg, 0.1, z0 + 0.5 * leg],
            Shape::Cylinder {
                axis: Axis::Z,
                radius: r_leg,
                half_len: 0.5 * leg,
            },
            cloth,
        ),
        part(
            [-(0.5 * l - r_leg), -0.1, z0 + 0.5 * leg],
            Shape::Cylinder {
                axis: Axis::Z,
                radius: r_leg,
                half_len: 0.5 * leg,
            },
            cloth,
        ),
        // Torso with arms: the box width.
        part(
            [0.0, 0.0, z0 + 0.66 * h],
            Shape::Ellipsoid {
                radii: [0.14, 0.5 * w, 0.19 * h],
            },
            cloth,
        ),
        // Head: the box top.
        part(
            [0.0, 0.0, 0.5 * h - 0.115],
            Shape::Ellipsoid {
                radii: [0.1, 0.08, 0.115],
            },
            materials::SKIN,
        ),
    ];
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn rider(
    parts: &mut Vec<Part>,
    x: f64,
    w: f64,
    h: f64,
    torso_half_width: f64,
    cloth: Material,
    head: Material,
) {
    let torso_rz = 0.28;
    parts.push(part(
        [x, 0.0, 0.5 * h - 0.24 - torso_rz],
        Shape::Ellipsoid {
            radii: [0.17, torso_half_width.min(0.5 * w), torso_rz],
        },
        cloth,
    ));
    parts.push(part(
        [x + 0.03, 0.0, 0.5 * h - 0.12],
        Shape::Ellipsoid {
            radii: [0.12, 0.11, 0.12],
        },
        head,
    ));
}

fn bicycle(l: f64, w: f64, h: f64, cloth: Material) -> ActorShape {
    let z0 = -0.5 * h;
    let rw = 0.34;
    let mut parts = Vec::new();
    for x in [0.5 * l - rw, -(0.5 * l - rw)] {
        parts.push(part(
            [x, 0.0, z0 + rw],
            Shape::Cylinder {
                axis: Axis::Y,
                radius: rw,
                half_len: 0.02,
            },
            materials::RUBBER,
        ));
    }
    parts.push(part(
        [0.0, 0.0, z0 + 0.55],
        Shape::Cuboid {
            half: [0.5 * l - 0.45, 0.03, 0.1],
        },
        materials::METAL,
    ));
    // Handlebar: the box width.
    parts.push(part(
        [0.5 * l - 0.55, 0.0, z0 + 1.0],
        Shape::Cuboid {
            half: [0.03, 0.5 * w, 0.02],
        },
        materials::METAL,
    ));
    // Legs on the pedals.
    parts.push(part(
        [0.0, 0.12, z0 + 0.62],
        Shape::Cylinder {
            axis: Axis::Z,
            radius: 0.07,
            half_len: 0.27,
        },
        cloth,
    ));
    rider(&mut parts, -0.1, w, h, 0.22, cloth, materials::SKIN);
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn motorcycle(l: f64, w: f64, h: f64, rho: f32, cloth: Material) -> ActorShape {
    let z0 = -0.5 * h;
    let rw = 0.32;
    let mut parts = Vec::new();
    for x in [0.5 * l - rw, -(0.5 * l - rw)] {
        parts.push(part(
            [x, 0.0, z0 + rw],
            Shape::Cylinder {
                axis: Axis::Y,
                radius: rw,
                half_len: 0.07,
            },
            materials::RUBBER,
        ));
    }
    parts.push(part(
        [0.0, 0.0, z0 + 0.62],
        Shape::RoundedCuboid {
            half: [0.5 * l - 0.45, 0.22, 0.22],
            radii: [0.5 * l - 0.3, 0.3, 0.35],
            offset: [0.0; 3],
        },
        Material::uniform(rho),
    ));
    parts.push(part(
        [0.5 * l - 0.6, 0.0, z0 + 1.0],
        Shape::Cuboid {
            half: [0.03, 0.5 * w, 0.02],
        },
        materials::METAL,
    ));
    rider(&mut parts, -0.15, w, h, 0.24, cloth, Material::uniform(rho));
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

fn animal(l: f64, w: f64, h: f64, fur: Material) -> ActorShape {
    let z0 = -0.5 * h;
    let leg = 0.5 * h;
    let mut parts = Vec::new();
    for x in [0.25 * l, -0.25 * l] {
        for y in [0.5 * w - 0.05, -(0.5 * w - 0.05)] {
            parts.push(part(
                [x, y, z0 + 0.5 * leg],
                Shape::Cylinder {
                    axis: Axis::Z,
                    radius: 0.035,
                    half_len: 0.5 * leg,
                },
                fur,
            ));
        }
    }
    parts.push(part(
        [-0.05 * l, 0.0, z0 + 0.62 * h],
        Shape::Ellipsoid {
            radii: [0.33 * l, 0.5 * w, 0.16 * h],
        },
        fur,
    ));
    parts.push(part(
        [0.5 * l - 0.12 * l, 0.0, 0.5 * h - 0.14 * h],
        Shape::Ellipsoid {
            radii: [0.12 * l, 0.3 * w, 0.14 * h],
        },
        fur,
    ));
    parts.push(part(
        [-0.5 * l + 0.07 * l, 0.0, z0 + 0.7 * h],
        Shape::Cylinder {
            axis: Axis::X,
            radius: 0.025,
            half_len: 0.07 * l,
        },
        fur,
    ));
    ActorShape {
        size_lwh: [l, w, h],
        parts,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::noise::layout_rng;

    #[test]
    fn every_shape_fills_its_annotation_box_exactly() {
        let mut rng = layout_rng(&[1, 2, 3]);
        for cat in Category::ALL {
            for _ in 0..50 {
                let s = build(cat, &mut rng);
                let (lo, hi) = s.bounds();
                for k in 0..3 {
                    let half = 0.5 * s.size_lwh[k];
                    assert!(
                        (lo[k] + half).abs() < 1e-9,
                        "{cat:?} axis {k}: {} vs {}",
                        lo[k],
                        -half
                    );
                    assert!(
                        (hi[k] - half).abs() < 1e-9,
                        "{cat:?} axis {k}: {} vs {}",
                        hi[k],
                        half
                    );
                }
            }
        }
    }

    #[test]
    fn car_sizes_are_lyft_like_and_not_cuboids() {
        let mut rng = layout_rng(&[4]);
        for _ in 0..100 {
            let s = build(Category::Car, &mut rng);
            let [l, w, h] = s.size_lwh;
            assert!((4.2..=5.0).contains(&l) && (1.8..=2.1).contains(&w) && (1.4..=1.9).contains(&h));
            // The top front corner of the box is empty (hood below the roof line).
            assert!(!s.contains(&[0.45 * l, 0.0, 0.45 * h], 0.0));
            // The plan-view corners are rounded off.
            assert!(!s.contains(&[0.49 * l, 0.49 * w, -0.1 * h], 0.0));
            // The centre of the cabin and of the lower body are solid.
            assert!(s.contains(&[0.0, 0.0, 0.3 * h], 0.0) && s.contains(&[0.3 * l, 0.0, -0.2 * h], 0.0));
        }
    }
}
