//! A bounding-volume hierarchy over a mesh's triangles: boxes split at the median of the
//! longest side, leaves of a few triangles, walked with a fixed stack (no allocation per
//! query). Serves the drop-cutter (XY disc queries pruned by height) and the nearest-point
//! queries that measure offsets.

use super::v3::{dist_to_triangle, V3};

const LEAF: usize = 4;
const STACK: usize = 64;

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: V3,
    hi: V3,
    /// Leaf: first index into `order`; interior: index of the left child (right = left + 1).
    first: u32,
    /// Leaf: number of triangles; interior: 0.
    count: u32,
}

/// The hierarchy over a list of triangles (indices into it are what queries return).
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

impl Bvh {
    /// Builds over `tris`. With `xy_only` the splits are made across X or Y only, which
    /// suits queries from above (the drop-cutter): every box then covers a patch of the
    /// plan view.
    pub fn new(tris: &[[V3; 3]], xy_only: bool) -> Bvh {
        let n = tris.len();
        let boxes: Vec<(V3, V3)> = tris
            .iter()
            .map(|t| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
            .collect();
        let cent: Vec<V3> = boxes.iter().map(|(a, b)| (*a + *b) * 0.5).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity(2 * n / LEAF + 2);
        nodes.push(Node {
            lo: V3::ZERO,
            hi: V3::ZERO,
            first: 0,
            count: 0,
        });
        // (node, start, end) still to build; depth stays ~log2(n/LEAF) as splits are medians
        let mut todo = vec![(0usize, 0usize, n)];
        while let Some((ni, s, e)) = todo.pop() {
            let mut lo = V3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
            let mut hi = -lo;
            let mut clo = lo;
            let mut chi = hi;
            for &t in &order[s..e] {
                let (a, b) = boxes[t as usize];
                lo = lo.min(a);
                hi = hi.max(b);
                clo = clo.min(cent[t as usize]);
                chi = chi.max(cent[t as usize]);
            }
            nodes[ni].lo = lo;
            nodes[ni].hi = hi;
            if e - s <= LEAF {
                nodes[ni].first = s as u32;
                nodes[ni].count = (e - s) as u32;
                continue;
            }
            let ext = chi - clo;
            let axis = if xy_only {
                if ext.x >= ext.y {
                    0
                } else {
                    1
                }
            } else if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = (s + e) / 2;
            order[s..e].select_nth_unstable_by(mid - s, |&a, &b| {
                cent[a as usize]
                    .get(axis)
                    .total_cmp(&cent[b as usize].get(axis))
            });
            let left = nodes.len();
            for _ in 0..2 {
                nodes.push(Node {
                    lo: V3::ZERO,
                    hi: V3::ZERO,
                    first: 0,
                    count: 0,
                });
            }
            nodes[ni].first = left as u32;
            nodes[ni].count = 0;
            todo.push((left, s, mid));
            todo.push((left + 1, mid, e));
        }
        Bvh { nodes, order }
    }

    /// Calls `f(triangle)` for every triangle whose box overlaps the XY rectangle
    /// `[x0, x1] × [y0, y1]` and reaches above `*floor` (`f` may raise the floor as it
    /// goes; boxes no higher than it are skipped, the higher of two children first).
    pub fn visit_xy_above(
        &self,
        x0: f64,
        y0: f64,
        x1: f64,
        y1: f64,
        floor: &mut f64,
        mut f: impl FnMut(usize, &mut f64),
    ) {
        if self.order.is_empty() {
            return;
        }
        let mut stack = [0u32; STACK];
        let mut sp = 1usize;
        let over = |n: &Node| n.lo.x <= x1 && n.hi.x >= x0 && n.lo.y <= y1 && n.hi.y >= y0;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if n.hi.z <= *floor || !over(n) {
                continue;
            }
            if n.count > 0 {
                let s = n.first as usize;
                for &t in &self.order[s..s + n.count as usize] {
                    f(t as usize, floor);
                }
            } else {
                let (l, r) = (n.first, n.first + 1);
                let (hl, hr) = (self.nodes[l as usize].hi.z, self.nodes[r as usize].hi.z);
                // push the lower child first so the higher one is popped first
                let (a, b) = if hl >= hr { (r, l) } else { (l, r) };
                if sp + 2 <= STACK {
                    stack[sp] = a;
                    stack[sp + 1] = b;
                    sp += 2;
                }
            }
        }
    }

    /// Calls `f(triangle)` for every triangle whose box overlaps the box `[lo, hi]`.
    pub fn visit_box(&self, lo: V3, hi: V3, mut f: impl FnMut(usize)) {
        if self.order.is_empty() {
            return;
        }
        let mut stack = [0u32; STACK];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if n.lo.x > hi.x
                || n.hi.x < lo.x
                || n.lo.y > hi.y
                || n.hi.y < lo.y
                || n.lo.z > hi.z
                || n.hi.z < lo.z
            {
                continue;
            }
            if n.count > 0 {
                let s = n.first as usize;
                for &t in &self.order[s..s + n.count as usize] {
                    f(t as usize);
                }
            } else if sp + 2 <= STACK {
                stack[sp] = n.first;
                stack[sp + 1] = n.first + 1;
                sp += 2;
            }
        }
    }

    /// The distance from `p` to the nearest of `tris` (the list the hierarchy was built
    /// on), and that triangle's index.
    pub fn nearest(&self, tris: &[[V3; 3]], p: V3) -> (f64, usize) {
        let mut best = (f64::INFINITY, usize::MAX);
        if self.order.is_empty() {
            return best;
        }
        let box_d2 = |n: &Node| {
            let dx = (n.lo.x - p.x).max(0.0).max(p.x - n.hi.x);
            let dy = (n.lo.y - p.y).max(0.0).max(p.y - n.hi.y);
            let dz = (n.lo.z - p.z).max(0.0).max(p.z - n.hi.z);
            dx * dx + dy * dy + dz * dz
        };
        let mut stack = [0u32; STACK];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if box_d2(n) >= best.0 * best.0 {
                continue;
            }
            if n.count > 0 {
                let s = n.first as usize;
                for &t in &self.order[s..s + n.count as usize] {
                    let d = dist_to_triangle(p, &tris[t as usize]);
                    if d < best.0 {
                        best = (d, t as usize);
                    }
                }
            } else {
                let (l, r) = (n.first, n.first + 1);
                let (dl, dr) = (
                    box_d2(&self.nodes[l as usize]),
                    box_d2(&self.nodes[r as usize]),
                );
                let (a, b) = if dl <= dr { (r, l) } else { (l, r) };
                if sp + 2 <= STACK {
                    stack[sp] = a;
                    stack[sp + 1] = b;
                    sp += 2;
                }
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_agrees_with_brute_force() {
        let mut tris = Vec::new();
        let mut uniform = crate::test_rng::uniform(12345);
        let mut rnd = || uniform() * 10.0;
        for _ in 0..500 {
            let a = V3::new(rnd(), rnd(), rnd());
            tris.push([
                a,
                a + V3::new(rnd() * 0.1, 0.0, 0.0),
                a + V3::new(0.0, rnd() * 0.1, rnd() * 0.1),
            ]);
        }
        let bvh = Bvh::new(&tris, false);
        for _ in 0..50 {
            let p = V3::new(rnd(), rnd(), rnd());
            let brute = tris
                .iter()
                .map(|t| dist_to_triangle(p, t))
                .fold(f64::INFINITY, f64::min);
            assert!((bvh.nearest(&tris, p).0 - brute).abs() < 1e-12);
        }
    }
}
