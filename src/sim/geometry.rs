//! Scene geometry in the local frame (metres, z up) and exact ray intersection in f64.
//!
//! Primitives: yawed boxes standing on the ground (walls + roof), ellipsoid crowns, capped vertical
//! cylinders (trunks), the ground disc z = 0 of radius `extent` (with painted flat regions) and the
//! hemispherical backdrop of the same radius that closes it, so every ray starting inside the dome above the
//! ground hits something at a finite distance. Objects are tested brute force behind a per-object AABB
//! slab test (a scene has tens to a few hundred objects). Normals are unit and face the incoming ray.

use glam::DVec3;

use super::scene::{RegionDesc, SceneDesc};

/// A point or direction as stored (hits, ground-truth points); the vector maths below is glam's [`DVec3`].
pub type V3 = [f64; 3];

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the unit ray.
    pub t: f64,
    /// Unit normal facing the ray origin.
    pub normal: V3,
    /// Index into the scene's material list.
    pub material: usize,
    pub kind: HitKind,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitKind {
    Ground,
    Object,
    /// The backdrop dome (not part of the ground-truth surfaces).
    Horizon,
}

#[derive(Debug, Clone)]
enum Shape {
    /// Base centre (x, y, 0), half sizes, yaw as (cos, sin).
    Box {
        c: V3,
        half: V3,
        cs: (f64, f64),
        wall: usize,
        roof: usize,
    },
    Ellipsoid {
        c: V3,
        r: V3,
        material: usize,
    },
    /// Vertical cylinder from z = 0 to `h`, capped at the top.
    Cylinder {
        c: [f64; 2],
        r: f64,
        h: f64,
        material: usize,
    },
}

#[derive(Debug, Clone)]
struct Object {
    shape: Shape,
    lo: V3,
    hi: V3,
}

#[derive(Debug, Clone)]
enum Area {
    Rect { c: [f64; 2], half: [f64; 2], cs: (f64, f64) },
    Polygon(Vec<[f64; 2]>),
    Circle { c: [f64; 2], r2: f64 },
}

#[derive(Debug, Clone)]
struct Region {
    area: Area,
    lo: [f64; 2],
    hi: [f64; 2],
    material: usize,
}

/// The geometry of a scene.
#[derive(Debug, Clone)]
pub struct World {
    objects: Vec<Object>,
    regions: Vec<Region>,
    ground_material: usize,
    horizon_material: usize,
    pub ground_center: [f64; 2],
    pub extent: f64,
}

/// Small offset (m) along the normal for shadow-ray origins.
pub const SHADOW_EPS: f64 = 1e-4;

impl World {
    /// Builds the geometry; `mat` maps a material name (validated to exist) to its index.
    pub fn new(d: &SceneDesc, mat: &dyn Fn(&str) -> usize) -> World {
        let mut objects = Vec::new();
        for b in &d.boxes {
            let (s, c) = b.yaw_deg.to_radians().sin_cos();
            let half = [b.size[0] / 2.0, b.size[1] / 2.0, b.size[2] / 2.0];
            let ex = half[0] * c.abs() + half[1] * s.abs();
            let ey = half[0] * s.abs() + half[1] * c.abs();
            let wall = mat(&b.material);
            objects.push(Object {
                shape: Shape::Box {
                    c: [b.center[0], b.center[1], 0.0],
                    half,
                    cs: (c, s),
                    wall,
                    roof: b.roof.as_deref().map(mat).unwrap_or(wall),
                },
                lo: [b.center[0] - ex, b.center[1] - ey, 0.0],
                hi: [b.center[0] + ex, b.center[1] + ey, b.size[2]],
            });
        }
        for t in &d.trees {
            let [x, y] = t.position;
            let r = t.crown;
            let cz = t.trunk_height + r[2];
            objects.push(Object {
                shape: Shape::Ellipsoid { c: [x, y, cz], r, material: mat(&t.crown_material) },
                lo: [x - r[0], y - r[1], cz - r[2]],
                hi: [x + r[0], y + r[1], cz + r[2]],
            });
            if t.trunk_height > 0.0 {
                let tr = t.trunk_radius;
                objects.push(Object {
                    shape: Shape::Cylinder { c: [x, y], r: tr, h: t.trunk_height, material: mat(&t.trunk_material) },
                    lo: [x - tr, y - tr, 0.0],
                    hi: [x + tr, y + tr, t.trunk_height],
                });
            }
        }
        let regions = d.regions.iter().chain(d.water.iter()).map(|r| region(r, mat)).collect();
        World {
            objects,
            regions,
            ground_material: mat(&d.ground.material),
            horizon_material: mat(d.ground.horizon.as_deref().unwrap_or(&d.ground.material)),
            ground_center: d.ground.center,
            extent: d.ground.extent,
        }
    }

    /// Whether `p` is inside the dome, above the ground (where cameras must be).
    pub fn contains(&self, p: V3) -> bool {
        let dx = p[0] - self.ground_center[0];
        let dy = p[1] - self.ground_center[1];
        p[2] > 0.0 && dx * dx + dy * dy + p[2] * p[2] < self.extent * self.extent
    }

    /// The nearest hit of the ray `o + t·d` (d unit), t > 0. Always returns a hit for origins inside the dome.
    pub fn trace(&self, o: V3, d: V3) -> Hit {
        let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut best: Option<Hit> = None;
        let mut tmax = f64::INFINITY;
        // Ground disc.
        if d[2] != 0.0 {
            let t = -o[2] / d[2];
            if t > 0.0 {
                let p = [o[0] + t * d[0], o[1] + t * d[1]];
                let (dx, dy) = (p[0] - self.ground_center[0], p[1] - self.ground_center[1]);
                if dx * dx + dy * dy <= self.extent * self.extent {
                    let nz = if d[2] < 0.0 { 1.0 } else { -1.0 };
                    best = Some(Hit {
                        t,
                        normal: [0.0, 0.0, nz],
                        material: self.ground_material_at(p),
                        kind: HitKind::Ground,
                    });
                    tmax = t;
                }
            }
        }
        for ob in &self.objects {
            if !aabb_hit(o, inv, ob.lo, ob.hi, tmax) {
                continue;
            }
            if let Some(h) = intersect(&ob.shape, o, d) {
                if h.t < tmax {
                    tmax = h.t;
                    best = Some(h);
                }
            }
        }
        if let Some(mut h) = best {
            if DVec3::from(h.normal).dot(DVec3::from(d)) > 0.0 {
                h.normal = h.normal.map(|x| -x);
            }
            return h;
        }
        // Backdrop: far root of the sphere of radius `extent` about (centre, 0).
        let d = DVec3::from(d);
        let oc = DVec3::new(o[0] - self.ground_center[0], o[1] - self.ground_center[1], o[2]);
        let b = oc.dot(d);
        let c = oc.length_squared() - self.extent * self.extent;
        let t = -b + (b * b - c).max(0.0).sqrt();
        let t = t.max(0.0);
        let n = -(oc + t * d) / self.extent;
        Hit { t, normal: n.to_array(), material: self.horizon_material, kind: HitKind::Horizon }
    }

    /// Whether an object blocks the ray from `o` towards `d` (shadow rays; the ground and dome never do).
    pub fn occluded(&self, o: V3, d: V3) -> bool {
        let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        self.objects
            .iter()
            .any(|ob| aabb_hit(o, inv, ob.lo, ob.hi, f64::INFINITY) && intersect(&ob.shape, o, d).is_some())
    }

    /// The material painted on the ground at (x, y): the last region containing it, else the ground's.
    pub fn ground_material_at(&self, p: [f64; 2]) -> usize {
        for r in self.regions.iter().rev() {
            if p[0] < r.lo[0] || p[0] > r.hi[0] || p[1] < r.lo[1] || p[1] > r.hi[1] {
                continue;
            }
            if area_contains(&r.area, p) {
                return r.material;
            }
        }
        self.ground_material
    }
}

fn region(r: &RegionDesc, mat: &dyn Fn(&str) -> usize) -> Region {
    let (area, lo, hi) = if let Some(rc) = &r.rect {
        let (s, c) = rc.yaw_deg.to_radians().sin_cos();
        let half = [rc.size[0] / 2.0, rc.size[1] / 2.0];
        let ex = half[0] * c.abs() + half[1] * s.abs();
        let ey = half[0] * s.abs() + half[1] * c.abs();
        (
            Area::Rect { c: rc.center, half, cs: (c, s) },
            [rc.center[0] - ex, rc.center[1] - ey],
            [rc.center[0] + ex, rc.center[1] + ey],
        )
    } else if let Some(ci) = &r.circle {
        let [x, y] = ci.center;
        (
            Area::Circle { c: ci.center, r2: ci.radius * ci.radius },
            [x - ci.radius, y - ci.radius],
            [x + ci.radius, y + ci.radius],
        )
    } else {
        let p = r.polygon.clone().unwrap_or_default();
        let lo = p.iter().fold([f64::INFINITY; 2], |a, v| [a[0].min(v[0]), a[1].min(v[1])]);
        let hi = p.iter().fold([f64::NEG_INFINITY; 2], |a, v| [a[0].max(v[0]), a[1].max(v[1])]);
        (Area::Polygon(p), lo, hi)
    };
    Region { area, lo, hi, material: mat(&r.material) }
}

fn area_contains(a: &Area, p: [f64; 2]) -> bool {
    match a {
        Area::Rect { c, half, cs } => {
            let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
            let lx = cs.0 * dx + cs.1 * dy;
            let ly = -cs.1 * dx + cs.0 * dy;
            lx.abs() <= half[0] && ly.abs() <= half[1]
        }
        Area::Circle { c, r2 } => (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) <= *r2,
        Area::Polygon(v) => {
            // Even-odd rule.
            let mut inside = false;
            let mut j = v.len() - 1;
            for i in 0..v.len() {
                let (a, b) = (v[i], v[j]);
                if (a[1] > p[1]) != (b[1] > p[1]) && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0] {
                    inside = !inside;
                }
                j = i;
            }
            inside
        }
    }
}

#[inline]
fn aabb_hit(o: V3, inv: V3, lo: V3, hi: V3, tmax: f64) -> bool {
    let mut t0: f64 = 0.0;
    let mut t1 = tmax;
    for k in 0..3 {
        let a = (lo[k] - o[k]) * inv[k];
        let b = (hi[k] - o[k]) * inv[k];
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        // NaN (0 · inf on a slab boundary) compares false and keeps the interval: conservative.
        if a > t0 {
            t0 = a;
        }
        if b < t1 {
            t1 = b;
        }
    }
    t0 <= t1
}

/// Nearest intersection with t > 0 (normals not yet flipped towards the ray).
fn intersect(s: &Shape, o: V3, d: V3) -> Option<Hit> {
    const EPS: f64 = 1e-9;
    match *s {
        Shape::Box { c, half, cs, wall, roof } => {
            // Into the box frame: rotate by -yaw about the vertical through the base centre; z from mid-height.
            let (dx, dy) = (o[0] - c[0], o[1] - c[1]);
            let lo = [cs.0 * dx + cs.1 * dy, -cs.1 * dx + cs.0 * dy, o[2] - half[2]];
            let ld = [cs.0 * d[0] + cs.1 * d[1], -cs.1 * d[0] + cs.0 * d[1], d[2]];
            let mut tn = f64::NEG_INFINITY;
            let mut tf = f64::INFINITY;
            let mut axis = 0;
            let mut sign = 0.0;
            for k in 0..3 {
                if ld[k] == 0.0 {
                    if lo[k].abs() > half[k] {
                        return None;
                    }
                    continue;
                }
                let a = (-half[k] - lo[k]) / ld[k];
                let b = (half[k] - lo[k]) / ld[k];
                let (a, b, sg) = if a < b { (a, b, -1.0) } else { (b, a, 1.0) };
                if a > tn {
                    tn = a;
                    axis = k;
                    sign = sg;
                }
                tf = tf.min(b);
            }
            if tn > tf || tn <= EPS {
                return None;
            }
            let ln = match axis {
                0 => [sign, 0.0],
                1 => [0.0, sign],
                _ => [0.0, 0.0],
            };
            let normal = [cs.0 * ln[0] - cs.1 * ln[1], cs.1 * ln[0] + cs.0 * ln[1], if axis == 2 { sign } else { 0.0 }];
            let material = if axis == 2 && sign > 0.0 { roof } else { wall };
            Some(Hit { t: tn, normal, material, kind: HitKind::Object })
        }
        Shape::Ellipsoid { c, r, material } => {
            let (o, d, c, r) = (DVec3::from(o), DVec3::from(d), DVec3::from(c), DVec3::from(r));
            let oc = (o - c) / r;
            let dd = d / r;
            let a = dd.length_squared();
            let b = oc.dot(dd);
            let cc = oc.length_squared() - 1.0;
            let disc = b * b - a * cc;
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            // Numerically stable roots.
            let q = -(b + b.signum() * sq);
            let (t0, t1) = if q != 0.0 { (q / a, cc / q) } else { (0.0, 0.0) };
            let (t0, t1) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
            let t = if t0 > EPS {
                t0
            } else if t1 > EPS {
                t1
            } else {
                return None;
            };
            let p = o + t * d - c;
            let g = p / (r * r);
            Some(Hit { t, normal: (g / g.length()).to_array(), material, kind: HitKind::Object })
        }
        Shape::Cylinder { c, r, h, material } => {
            let mut best: Option<Hit> = None;
            let (ox, oy) = (o[0] - c[0], o[1] - c[1]);
            let a = d[0] * d[0] + d[1] * d[1];
            if a > 0.0 {
                let b = ox * d[0] + oy * d[1];
                let cc = ox * ox + oy * oy - r * r;
                let disc = b * b - a * cc;
                if disc >= 0.0 {
                    let sq = disc.sqrt();
                    for t in [(-b - sq) / a, (-b + sq) / a] {
                        let z = o[2] + t * d[2];
                        if t > EPS && (0.0..=h).contains(&z) {
                            let n = [(ox + t * d[0]) / r, (oy + t * d[1]) / r, 0.0];
                            best = Some(Hit { t, normal: n, material, kind: HitKind::Object });
                            break;
                        }
                    }
                }
            }
            if d[2] != 0.0 {
                let t = (h - o[2]) / d[2];
                let (x, y) = (ox + t * d[0], oy + t * d[1]);
                if t > EPS && x * x + y * y <= r * r && best.is_none_or(|b| t < b.t) {
                    best = Some(Hit { t, normal: [0.0, 0.0, 1.0], material, kind: HitKind::Object });
                }
            }
            best
        }
    }
}
