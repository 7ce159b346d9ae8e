//! A static packed R-tree of boxes (Hilbert-sorted leaves, or leaves in path order, 8 per
//! node): box queries and nearest-distance searches in O(log n) each, built in O(n log n);
//! and, over leaves in path order, the pairs of overlapping boxes (the input check walks
//! them, then the offset's distance questions ask the same tree).

use crate::geom::{hi, lo};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

const NODE: usize = 8;

/// Boxes are [min x, min y, max x, max y].
pub type BBox = [f64; 4];

/// The tree: level 0 holds the items' boxes in Hilbert order, each level above one box per
/// group of `NODE` boxes below it.
#[derive(Clone, Debug, Default)]
pub struct BoxIndex {
    boxes: Vec<BBox>,
    /// for level-0 slots: the item's index; empty when the leaves are the items in order
    /// (a tree packed over boxes as they come: slot i is item i)
    items: Vec<u32>,
    /// how many items
    n: usize,
    /// start of each level in `boxes`; the last level holds the root
    levels: Vec<usize>,
}

fn hilbert(mut x: u32, mut y: u32) -> u32 {
    // 16-bit Hilbert index (after "Fast Hilbert curve generation", public domain formulation)
    let mut a = x ^ y;
    let mut b = 0xFFFF ^ a;
    let mut c = 0xFFFF ^ (x | y);
    let mut d = x & (y ^ 0xFFFF);
    let mut aa = a | (b >> 1);
    let mut bb = (a >> 1) ^ a;
    let mut cc = ((c >> 1) ^ (b & (d >> 1))) ^ c;
    let mut dd = ((a & (c >> 1)) ^ (d >> 1)) ^ d;
    a = aa;
    b = bb;
    c = cc;
    d = dd;
    aa = (a & (a >> 2)) ^ (b & (b >> 2));
    bb = (a & (b >> 2)) ^ (b & ((a ^ b) >> 2));
    cc ^= (a & (c >> 2)) ^ (b & (d >> 2));
    dd ^= (b & (c >> 2)) ^ ((a ^ b) & (d >> 2));
    a = aa;
    b = bb;
    c = cc;
    d = dd;
    aa = (a & (a >> 4)) ^ (b & (b >> 4));
    bb = (a & (b >> 4)) ^ (b & ((a ^ b) >> 4));
    cc ^= (a & (c >> 4)) ^ (b & (d >> 4));
    dd ^= (b & (c >> 4)) ^ ((a ^ b) & (d >> 4));
    a = aa;
    b = bb;
    c = cc;
    d = dd;
    cc ^= (a & (c >> 8)) ^ (b & (d >> 8));
    dd ^= (b & (c >> 8)) ^ ((a ^ b) & (d >> 8));
    a = cc ^ (cc >> 1);
    b = dd ^ (dd >> 1);
    let mut i0 = x ^ y;
    let mut i1 = b | (0xFFFF ^ (i0 | a));
    i0 = (i0 | (i0 << 8)) & 0x00FF00FF;
    i0 = (i0 | (i0 << 4)) & 0x0F0F0F0F;
    i0 = (i0 | (i0 << 2)) & 0x33333333;
    i0 = (i0 | (i0 << 1)) & 0x55555555;
    i1 = (i1 | (i1 << 8)) & 0x00FF00FF;
    i1 = (i1 | (i1 << 4)) & 0x0F0F0F0F;
    i1 = (i1 | (i1 << 2)) & 0x33333333;
    i1 = (i1 | (i1 << 1)) & 0x55555555;
    x = i0;
    y = i1;
    (y << 1) | x
}

/// The box grown by `e` on every side.
pub fn grow(b: BBox, e: f64) -> BBox {
    [b[0] - e, b[1] - e, b[2] + e, b[3] + e]
}

/// The smallest box holding both.
pub fn union(a: &BBox, b: &BBox) -> BBox {
    [
        lo(a[0], b[0]),
        lo(a[1], b[1]),
        hi(a[2], b[2]),
        hi(a[3], b[3]),
    ]
}

/// Squared distance from (x, y) to the box (0 inside).
fn box_dist2(b: &BBox, x: f64, y: f64) -> f64 {
    let dx = (b[0] - x).max(0.0).max(x - b[2]);
    let dy = (b[1] - y).max(0.0).max(y - b[3]);
    dx * dx + dy * dy
}

impl BoxIndex {
    pub fn new(item_boxes: &[BBox]) -> BoxIndex {
        let n = item_boxes.len();
        if n == 0 {
            return BoxIndex::default();
        }
        let mut all = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for b in item_boxes {
            all = union(&all, b);
        }
        let w = (all[2] - all[0]).max(f64::MIN_POSITIVE);
        let h = (all[3] - all[1]).max(f64::MIN_POSITIVE);
        let mut keyed: Vec<(u32, u32)> = item_boxes
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let cx = ((b[0] + b[2]) * 0.5 - all[0]) / w * 65535.0;
                let cy = ((b[1] + b[3]) * 0.5 - all[1]) / h * 65535.0;
                let cx = if cx.is_finite() { cx as u32 } else { 0 };
                let cy = if cy.is_finite() { cy as u32 } else { 0 };
                (hilbert(cx.min(65535), cy.min(65535)), i as u32)
            })
            .collect();
        keyed.sort_unstable();
        let items: Vec<u32> = keyed.iter().map(|k| k.1).collect();
        let boxes: Vec<BBox> = items.iter().map(|&i| item_boxes[i as usize]).collect();
        BoxIndex::pack(boxes, items)
    }

    /// The tree over boxes already in a spatially coherent order (the segments of paths,
    /// one after another), packed as they come: O(n), no sort.
    pub fn in_order(item_boxes: &[BBox]) -> BoxIndex {
        let n = item_boxes.len();
        if n == 0 {
            return BoxIndex::default();
        }
        let mut boxes: Vec<BBox> = Vec::with_capacity(BoxIndex::room(n));
        boxes.extend_from_slice(item_boxes);
        BoxIndex::pack(boxes, Vec::new())
    }

    /// How many boxes a tree over `n` leaves holds, the levels above them included: a
    /// vector of leaves made with this capacity takes the levels without moving (see
    /// [`BoxIndex::in_order_owned`]).
    pub fn room(n: usize) -> usize {
        n + n / (NODE - 1) + 2
    }

    /// [`BoxIndex::in_order`] over boxes handed over (the leaves stay where they are, the
    /// levels above go after them: no copy of the leaves when the vector has the
    /// [`BoxIndex::room`] for them; at 100,000 segments growing it moved 3.2 MB).
    pub fn in_order_owned(mut boxes: Vec<BBox>) -> BoxIndex {
        let n = boxes.len();
        if n == 0 {
            return BoxIndex::default();
        }
        boxes.reserve(BoxIndex::room(n) - n);
        BoxIndex::pack(boxes, Vec::new())
    }

    /// Adds the levels above the leaves (`boxes` holds the leaves; `items` the item of
    /// each, or nothing when they are the items in order).
    fn pack(mut boxes: Vec<BBox>, items: Vec<u32>) -> BoxIndex {
        let n = boxes.len();
        let mut levels = vec![0usize];
        let mut start = 0;
        let mut count = n;
        while count > 1 {
            let end = start + count;
            let mut k = start;
            while k < end {
                let stop = (k + NODE).min(end);
                let mut b = boxes[k];
                for bx in &boxes[k + 1..stop] {
                    b = union(&b, bx);
                }
                boxes.push(b);
                k = stop;
            }
            start = end;
            count = boxes.len() - start;
            levels.push(start);
        }
        BoxIndex {
            boxes,
            items,
            n,
            levels,
        }
    }

    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The item in leaf `slot`.
    #[inline]
    fn item(&self, slot: usize) -> usize {
        if self.items.is_empty() {
            slot
        } else {
            self.items[slot] as usize
        }
    }

    /// Calls `f(item)` for every item whose box overlaps `q`; `f` returns false to stop.
    pub fn query(&self, q: &BBox, mut f: impl FnMut(usize) -> bool) {
        if self.n == 0 {
            return;
        }
        let top = self.levels.len() - 1;
        // (level, slot)
        let mut stack: Vec<(usize, usize)> = vec![(top, self.levels[top])];
        while let Some((lvl, slot)) = stack.pop() {
            let b = &self.boxes[slot];
            if b[0] > q[2] || b[2] < q[0] || b[1] > q[3] || b[3] < q[1] {
                continue;
            }
            if lvl == 0 {
                if !f(self.item(slot)) {
                    return;
                }
                continue;
            }
            let child_lvl_start = self.levels[lvl - 1];
            let child_lvl_end = self.levels[lvl];
            let first = child_lvl_start + (slot - self.levels[lvl]) * NODE;
            let last = (first + NODE).min(child_lvl_end);
            for c in first..last {
                stack.push((lvl - 1, c));
            }
        }
    }

    /// Calls `f(item)` for every item whose box comes nearer (x, y) than `r` (a disc, not
    /// its square: a point that keeps its distance |d| from a boundary sees only the few
    /// nodes by the boundary's nearest stretch, where the square of side 2|d| about it
    /// would hold a large part of the boundary); `f` returns false to stop.
    pub fn query_disc(&self, x: f64, y: f64, r: f64, mut f: impl FnMut(usize) -> bool) {
        if self.n == 0 {
            return;
        }
        let r2 = r * r;
        let top = self.levels.len() - 1;
        if box_dist2(&self.boxes[self.levels[top]], x, y) >= r2 {
            return;
        }
        if top == 0 {
            f(self.item(0));
            return;
        }
        // nodes whose box comes nearer than r (children are tested before they go on the
        // stack, leaves before `f` is called, so nothing is pushed that is then thrown away)
        let mut stack: Vec<(usize, usize)> = Vec::with_capacity(64);
        stack.push((top, self.levels[top]));
        while let Some((lvl, slot)) = stack.pop() {
            let first = self.levels[lvl - 1] + (slot - self.levels[lvl]) * NODE;
            let last = (first + NODE).min(self.levels[lvl]);
            if lvl == 1 {
                for c in first..last {
                    if box_dist2(&self.boxes[c], x, y) < r2 && !f(self.item(c)) {
                        return;
                    }
                }
                continue;
            }
            // the nearest child goes on last, so it is looked into first
            let base = stack.len();
            let (mut near, mut near_d) = (usize::MAX, f64::INFINITY);
            for c in first..last {
                let d2 = box_dist2(&self.boxes[c], x, y);
                if d2 < r2 {
                    if d2 < near_d {
                        near_d = d2;
                        near = stack.len();
                    }
                    stack.push((lvl - 1, c));
                }
            }
            if near != usize::MAX && stack.len() > base + 1 {
                let end = stack.len() - 1;
                stack.swap(near, end);
            }
        }
    }

    /// The nearest items to (x, y) by `dist(item)` (an exact distance no smaller than the
    /// box distance), best first; stops when `f(item, distance)` returns false or when no
    /// box is nearer than `max`.
    pub fn nearest(
        &self,
        x: f64,
        y: f64,
        max: f64,
        mut dist: impl FnMut(usize) -> f64,
        mut f: impl FnMut(usize, f64) -> bool,
    ) {
        #[derive(PartialEq)]
        struct E(f64, usize, usize, bool); // distance, level, slot, exact item
        impl Eq for E {}
        impl PartialOrd for E {
            fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
                Some(self.cmp(o))
            }
        }
        impl Ord for E {
            fn cmp(&self, o: &Self) -> Ordering {
                o.0.partial_cmp(&self.0).unwrap_or(Ordering::Equal)
            }
        }
        if self.n == 0 {
            return;
        }
        let top = self.levels.len() - 1;
        let mut heap = BinaryHeap::new();
        heap.push(E(0.0, top, self.levels[top], false));
        while let Some(E(d, lvl, slot, exact)) = heap.pop() {
            if d > max {
                return;
            }
            if exact {
                if !f(self.item(slot), d) {
                    return;
                }
                continue;
            }
            if lvl == 0 {
                let dd = dist(self.item(slot));
                heap.push(E(dd, 0, slot, true));
                continue;
            }
            let cs = self.levels[lvl - 1];
            let ce = self.levels[lvl];
            let first = cs + (slot - self.levels[lvl]) * NODE;
            let last = (first + NODE).min(ce);
            for c in first..last {
                let bd = box_dist2(&self.boxes[c], x, y).sqrt();
                if bd <= max {
                    heap.push(E(bd, lvl - 1, c, false));
                }
            }
        }
    }
}

impl BoxIndex {
    /// The one nearest item to (x, y) by `dist(item)` (an exact distance no smaller than
    /// the box distance) and its distance, if any lies within `max`: a depth-first branch
    /// and bound, nearest child first, that descends only into boxes nearer than the best
    /// item found so far. Same answer as `nearest` stopped at its first item, with far fewer
    /// boxes visited and no heap (the checkers ask it once per sample point).
    pub fn nearest_one(
        &self,
        x: f64,
        y: f64,
        max: f64,
        mut dist: impl FnMut(usize) -> f64,
    ) -> Option<(usize, f64)> {
        if self.n == 0 {
            return None;
        }
        let mut best: Option<(usize, f64)> = None;
        // a box or item counts while it is no farther than `max`, and, once an item is
        // found, only while it is nearer than that item
        let beats = |d: f64, best: &Option<(usize, f64)>| match best {
            None => d <= max,
            Some((_, b)) => d < *b,
        };
        let mut visit_item = |slot: usize, best: &mut Option<(usize, f64)>| {
            let item = self.item(slot);
            let d = dist(item);
            if beats(d, best) {
                *best = Some((item, d));
            }
        };
        let top = self.levels.len() - 1;
        if top == 0 {
            for slot in 0..self.n {
                visit_item(slot, &mut best);
            }
            return best;
        }
        // (box distance, level, slot); children go on nearest last, so popped first
        let mut stack: Vec<(f64, usize, usize)> = Vec::with_capacity(NODE * top);
        stack.push((0.0, top, self.levels[top]));
        let mut children: [(f64, usize); NODE] = [(0.0, 0); NODE];
        while let Some((d, lvl, slot)) = stack.pop() {
            if !beats(d, &best) {
                continue;
            }
            let first = self.levels[lvl - 1] + (slot - self.levels[lvl]) * NODE;
            let last = (first + NODE).min(self.levels[lvl]);
            let mut k = 0;
            for c in first..last {
                let bd = box_dist2(&self.boxes[c], x, y).sqrt();
                if beats(bd, &best) {
                    children[k] = (bd, c);
                    k += 1;
                }
            }
            let near = &mut children[..k];
            near.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            if lvl == 1 {
                for &(bd, c) in near.iter() {
                    if !beats(bd, &best) {
                        break;
                    }
                    visit_item(c, &mut best);
                }
            } else {
                stack.extend(near.iter().rev().map(|&(bd, c)| (bd, lvl - 1, c)));
            }
        }
        best
    }
}

impl BoxIndex {
    /// Calls `f(i, j)` (i < j) for every pair of overlapping leaves of a tree packed over
    /// boxes in path order ([`BoxIndex::in_order`], [`BoxIndex::in_order_owned`]: each box
    /// next to the one before, as the segments of paths one after another). The tree is
    /// walked against itself, descending only into pairs of nodes whose boxes overlap. A
    /// path that does not come back near itself meets only its own node and its neighbours
    /// at each level, so the work is linear in n plus the pairs; unlike a sweep along one
    /// axis, a long stretch running along the other axis costs nothing extra. The same
    /// tree then answers the distance questions over the same segments (`prune::InputSet`).
    // (index loops: the indices are what is reported and stacked; the iterator forms
    // counted more instructions)
    #[allow(clippy::needless_range_loop)]
    pub fn overlapping_pairs(&self, mut f: impl FnMut(usize, usize)) {
        debug_assert!(self.items.is_empty(), "a tree in path order");
        // all four comparisons, no early out: most pairs asked about are near misses,
        // whose outcome no branch predicts (the boxes are finite)
        let overlap =
            |a: &BBox, b: &BBox| (a[0] <= b[2]) & (a[2] >= b[0]) & (a[1] <= b[3]) & (a[3] >= b[1]);
        if self.n < 2 {
            return;
        }
        let top = self.levels.len() - 1;
        let level = |k: usize| -> &[BBox] {
            let end = if k < top {
                self.levels[k + 1]
            } else {
                self.boxes.len()
            };
            &self.boxes[self.levels[k]..end]
        };
        // (level, node a, node b) with a <= b and overlapping boxes
        let mut stack: Vec<(usize, usize, usize)> = vec![(top, 0, 0)];
        // of two different nodes' children, the ones that reach into the common part of
        // the nodes' boxes: a child outside it overlaps no child of the other node (each
        // lies in its node's box), so only these are paired; two neighbours along a path
        // share a corner's worth of their boxes, and a few children each
        let (mut ia, mut jb) = ([0usize; NODE], [0usize; NODE]);
        while let Some((k, a, b)) = stack.pop() {
            let below = level(k - 1);
            let (a1, b1) = (
                ((a + 1) * NODE).min(below.len()),
                ((b + 1) * NODE).min(below.len()),
            );
            // A node's pairs of children go on the stack last to first, so the walk takes
            // them in path order, as it reports the pairs of boxes within a node. When it
            // took them backwards (each group of NODE segments in order, the groups in
            // reverse), the crossing search of the million-vertex gear ran 23 or 52 ms by
            // where its buffers lay in the heap; in path order it runs 18 ms either way.
            if a == b {
                if k == 1 {
                    // the boxes themselves: report the pairs here rather than through the
                    // stack
                    for i in a * NODE..a1 {
                        let bi = below[i];
                        for j in i + 1..b1 {
                            if overlap(&bi, &below[j]) {
                                f(i, j);
                            }
                        }
                    }
                } else {
                    for i in (a * NODE..a1).rev() {
                        let bi = below[i];
                        for j in (i..b1).rev() {
                            if overlap(&bi, &below[j]) {
                                stack.push((k - 1, i, j));
                            }
                        }
                    }
                }
                continue;
            }
            let nodes = level(k);
            let (na, nb) = (nodes[a], nodes[b]);
            let common = [
                na[0].max(nb[0]),
                na[1].max(nb[1]),
                na[2].min(nb[2]),
                na[3].min(nb[3]),
            ];
            let mut n_a = 0;
            for i in a * NODE..a1 {
                if overlap(&below[i], &common) {
                    ia[n_a] = i;
                    n_a += 1;
                }
            }
            let mut n_b = 0;
            for j in b * NODE..b1 {
                if overlap(&below[j], &common) {
                    jb[n_b] = j;
                    n_b += 1;
                }
            }
            if k == 1 {
                for &i in &ia[..n_a] {
                    let bi = below[i];
                    for &j in &jb[..n_b] {
                        if overlap(&bi, &below[j]) {
                            f(i, j);
                        }
                    }
                }
            } else {
                for &i in ia[..n_a].iter().rev() {
                    let bi = below[i];
                    for &j in jb[..n_b].iter().rev() {
                        if overlap(&bi, &below[j]) {
                            stack.push((k - 1, i, j));
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hilbert_order_walks_to_neighbouring_cells() {
        let mut v = Vec::new();
        for x in 0..64u32 {
            for y in 0..64u32 {
                v.push((hilbert(x << 10, y << 10), x as i32, y as i32));
            }
        }
        v.sort();
        for w in v.windows(2) {
            assert_eq!((w[0].1 - w[1].1).abs() + (w[0].2 - w[1].2).abs(), 1);
        }
    }

    #[test]
    fn the_one_nearest_item_is_the_brute_force_nearest_within_the_bound() {
        // scattered boxes of many sizes (n from 1 to a few levels), each item's distance
        // a little above its box's, points inside and far outside, bounds that cut some off
        let mut rnd = crate::test_rng::uniform(12345);
        for n in [1usize, 2, 7, 8, 9, 64, 65, 300, 5000] {
            let boxes: Vec<BBox> = (0..n)
                .map(|_| {
                    let (x, y) = (rnd() * 100.0, rnd() * 100.0);
                    [x, y, x + rnd() * 5.0, y + rnd() * 5.0]
                })
                .collect();
            let idx = BoxIndex::new(&boxes);
            let extra: Vec<f64> = (0..n).map(|_| rnd()).collect();
            for _ in 0..200 {
                let (x, y) = (rnd() * 160.0 - 30.0, rnd() * 160.0 - 30.0);
                let max = if rnd() < 0.5 {
                    f64::INFINITY
                } else {
                    rnd() * 20.0
                };
                let dist = |i: usize| box_dist2(&boxes[i], x, y).sqrt() + extra[i];
                let brute = (0..n)
                    .map(dist)
                    .filter(|&d| d <= max)
                    .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.min(d))));
                let got = idx.nearest_one(x, y, max, dist);
                assert_eq!(got.map(|(_, d)| d), brute, "n {n}, ({x}, {y}), max {max}");
                if let Some((i, d)) = got {
                    assert_eq!(dist(i), d);
                }
            }
        }
    }

    #[test]
    fn queries_find_exactly_the_overlapping_boxes() {
        let mut boxes = Vec::new();
        for i in 0..1000 {
            let x = (i % 37) as f64 * 3.0;
            let y = (i / 37) as f64 * 2.0;
            boxes.push([x, y, x + 1.5, y + 1.0]);
        }
        let idx = BoxIndex::new(&boxes);
        let q = [10.0, 10.0, 30.0, 20.0];
        let mut got = Vec::new();
        idx.query(&q, |i| {
            got.push(i);
            true
        });
        got.sort();
        let want: Vec<usize> = (0..boxes.len())
            .filter(|&i| {
                let b = boxes[i];
                !(b[0] > q[2] || b[2] < q[0] || b[1] > q[3] || b[3] < q[1])
            })
            .collect();
        assert_eq!(got, want);
        let mut brute = Vec::new();
        for i in 0..boxes.len() {
            for j in i + 1..boxes.len() {
                let (a, b) = (boxes[i], boxes[j]);
                if !(a[0] > b[2] || a[2] < b[0] || a[1] > b[3] || a[3] < b[1]) {
                    brute.push((i, j));
                }
            }
        }
        // the tree in path order: the pairs, and the same answers as the sorted one
        let in_order = BoxIndex::in_order(&boxes);
        let mut walked = Vec::new();
        in_order.overlapping_pairs(|i, j| walked.push((i, j)));
        walked.sort();
        assert_eq!(walked, brute);
        assert_eq!(in_order.len(), boxes.len());
        // the disc query: exactly the boxes nearer the point than the radius
        for (x, y, r) in [(50.2, 7.3, 4.0), (0.0, 0.0, 0.5), (120.0, 60.0, 30.0)] {
            let want: Vec<usize> = (0..boxes.len())
                .filter(|&i| box_dist2(&boxes[i], x, y) < r * r)
                .collect();
            for tree in [&idx, &in_order] {
                let mut got = Vec::new();
                tree.query_disc(x, y, r, |i| {
                    got.push(i);
                    true
                });
                got.sort();
                assert_eq!(got, want, "disc about ({x}, {y}) of radius {r}");
            }
        }
        let mut best = None;
        idx.nearest(
            50.2,
            7.3,
            f64::INFINITY,
            |i| box_dist2(&boxes[i], 50.2, 7.3).sqrt(),
            |i, d| {
                best = Some((i, d));
                false
            },
        );
        let brute = (0..boxes.len())
            .map(|i| box_dist2(&boxes[i], 50.2, 7.3).sqrt())
            .fold(f64::INFINITY, f64::min);
        assert_eq!(best.unwrap().1, brute);
    }
}
