//! Vectors in 3D: the arithmetic the mesh code shares (points and directions alike).

use crate::toolpath::P3;
use serde::{Deserialize, Serialize};
use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

/// A point or a direction in 3D, in millimetres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct V3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl V3 {
    pub const ZERO: V3 = V3::new(0.0, 0.0, 0.0);
    pub const Z: V3 = V3::new(0.0, 0.0, 1.0);

    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        V3 { x, y, z }
    }
    pub fn dot(self, o: V3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: V3) -> V3 {
        V3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    pub fn len2(self) -> f64 {
        self.dot(self)
    }
    pub fn len(self) -> f64 {
        self.len2().sqrt()
    }
    pub fn dist(self, o: V3) -> f64 {
        (self - o).len()
    }
    /// The unit vector along `self` (zero stays zero).
    pub fn unit(self) -> V3 {
        let l = self.len();
        if l > 0.0 {
            self / l
        } else {
            self
        }
    }
    pub fn lerp(self, o: V3, t: f64) -> V3 {
        self + (o - self) * t
    }
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
    pub fn min(self, o: V3) -> V3 {
        V3::new(self.x.min(o.x), self.y.min(o.y), self.z.min(o.z))
    }
    pub fn max(self, o: V3) -> V3 {
        V3::new(self.x.max(o.x), self.y.max(o.y), self.z.max(o.z))
    }
    pub fn p3(self) -> P3 {
        P3::new(self.x, self.y, self.z)
    }
    pub fn from_p3(p: P3) -> V3 {
        V3::new(p.x, p.y, p.z)
    }
    pub fn get(self, axis: usize) -> f64 {
        match axis {
            0 => self.x,
            1 => self.y,
            _ => self.z,
        }
    }
}

impl Add for V3 {
    type Output = V3;
    fn add(self, o: V3) -> V3 {
        V3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl AddAssign for V3 {
    fn add_assign(&mut self, o: V3) {
        *self = *self + o;
    }
}
impl Sub for V3 {
    type Output = V3;
    fn sub(self, o: V3) -> V3 {
        V3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl Mul<f64> for V3 {
    type Output = V3;
    fn mul(self, k: f64) -> V3 {
        V3::new(self.x * k, self.y * k, self.z * k)
    }
}
impl Div<f64> for V3 {
    type Output = V3;
    fn div(self, k: f64) -> V3 {
        V3::new(self.x / k, self.y / k, self.z / k)
    }
}
impl Neg for V3 {
    type Output = V3;
    fn neg(self) -> V3 {
        V3::new(-self.x, -self.y, -self.z)
    }
}

/// The point of triangle `t` nearest `p` (Ericson, Real-Time Collision Detection, 5.1.5).
pub fn closest_on_triangle(p: V3, t: &[V3; 3]) -> V3 {
    let [a, b, c] = *t;
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + (c - b) * w;
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    a + ab * v + ac * w
}

/// The point of the segment from `a` to `b` nearest `p`.
pub fn closest_on_segment(p: V3, a: V3, b: V3) -> V3 {
    let ab = b - a;
    let l2 = ab.len2();
    if l2 == 0.0 {
        return a;
    }
    a + ab * ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
}

/// The distance from `p` to triangle `t`.
pub fn dist_to_triangle(p: V3, t: &[V3; 3]) -> f64 {
    p.dist(closest_on_triangle(p, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions_of_a_triangle() {
        let t = [
            V3::new(0.0, 0.0, 0.0),
            V3::new(4.0, 0.0, 0.0),
            V3::new(0.0, 4.0, 0.0),
        ];
        // above the face, beyond a vertex, beyond an edge, beyond the hypotenuse
        assert_eq!(
            closest_on_triangle(V3::new(1.0, 1.0, 3.0), &t),
            V3::new(1.0, 1.0, 0.0)
        );
        assert_eq!(closest_on_triangle(V3::new(-1.0, -1.0, 1.0), &t), t[0]);
        assert_eq!(
            closest_on_triangle(V3::new(2.0, -3.0, 0.0), &t),
            V3::new(2.0, 0.0, 0.0)
        );
        let q = closest_on_triangle(V3::new(3.0, 3.0, 0.0), &t);
        assert!(q.dist(V3::new(2.0, 2.0, 0.0)) < 1e-12, "{q:?}");
    }
}
