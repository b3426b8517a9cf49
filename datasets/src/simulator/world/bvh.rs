//! A bounding-volume hierarchy over the world's surfaces, so that a ray tests
//! a handful of polygons instead of all of them (rendering casts ~300k rays
//! per image).

use super::surface::Surface;
use crate::math::{Point3, Vec3};

#[derive(Debug, Clone)]
struct Node {
    lo: Point3,
    hi: Point3,
    /// Leaf: `count > 0` surfaces from `first` in `order`; inner: children at `first`, `first + 1`.
    first: usize,
    count: usize,
}

#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<usize>,
}

/// The nearest surface a ray meets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub surface: usize,
    pub t: f64,
}

const LEAF_SIZE: usize = 2;

impl Bvh {
    pub fn build(surfaces: &[Surface]) -> Self {
        let boxes: Vec<(Point3, Point3)> = surfaces
            .iter()
            .map(|s| {
                let (lo, hi) = s.bounds();
                let pad = Vec3::repeat(1e-6);
                (lo - pad, hi + pad)
            })
            .collect();
        let mut bvh = Self { nodes: Vec::new(), order: (0..surfaces.len()).collect() };
        bvh.nodes.push(Node { lo: Point3::origin(), hi: Point3::origin(), first: 0, count: 0 });
        bvh.split(0, 0, surfaces.len(), &boxes);
        bvh
    }

    fn split(&mut self, node: usize, start: usize, end: usize, boxes: &[(Point3, Point3)]) {
        let mut lo = Point3::from(Vec3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vec3::repeat(f64::NEG_INFINITY));
        for &i in &self.order[start..end] {
            lo = lo.inf(&boxes[i].0);
            hi = hi.sup(&boxes[i].1);
        }
        self.nodes[node].lo = lo;
        self.nodes[node].hi = hi;
        if end - start <= LEAF_SIZE {
            self.nodes[node].first = start;
            self.nodes[node].count = end - start;
            return;
        }
        // Surface-area heuristic: of the splits of the centre-sorted lists
        // along each axis, take the one that minimises the expected cost of
        // a ray (box area times surfaces inside, for both halves).
        let mut best = (f64::INFINITY, 0, start + (end - start) / 2);
        for axis in 0..3 {
            let centre = |i: usize| (boxes[i].0[axis] + boxes[i].1[axis]) * 0.5;
            self.order[start..end].sort_by(|&a, &b| centre(a).total_cmp(&centre(b)));
            let n = end - start;
            let mut left_area = vec![0.0; n];
            let (mut lo, mut hi) =
                (Point3::from(Vec3::repeat(f64::INFINITY)), Point3::from(Vec3::repeat(f64::NEG_INFINITY)));
            for (slot, &i) in left_area.iter_mut().zip(&self.order[start..end]) {
                lo = lo.inf(&boxes[i].0);
                hi = hi.sup(&boxes[i].1);
                *slot = area(&lo, &hi);
            }
            let (mut lo, mut hi) =
                (Point3::from(Vec3::repeat(f64::INFINITY)), Point3::from(Vec3::repeat(f64::NEG_INFINITY)));
            for k in (1..n).rev() {
                let i = self.order[start + k];
                lo = lo.inf(&boxes[i].0);
                hi = hi.sup(&boxes[i].1);
                let cost = left_area[k - 1] * k as f64 + area(&lo, &hi) * (n - k) as f64;
                if cost < best.0 {
                    best = (cost, axis, start + k);
                }
            }
        }
        let (_, axis, mid) = best;
        let centre = |i: usize| (boxes[i].0[axis] + boxes[i].1[axis]) * 0.5;
        self.order[start..end].sort_by(|&a, &b| centre(a).total_cmp(&centre(b)));
        let left = self.nodes.len();
        self.nodes.push(Node { lo, hi, first: 0, count: 0 });
        self.nodes.push(Node { lo, hi, first: 0, count: 0 });
        self.nodes[node].first = left;
        self.split(left, start, mid, boxes);
        self.split(left + 1, mid, end, boxes);
    }

    /// The nearest surface along `dir` from `origin` with `t` in `(t_min, t_max)`.
    pub fn nearest(&self, surfaces: &[Surface], origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<Hit> {
        let inv = Vec3::new(1.0 / dir.x, 1.0 / dir.y, 1.0 / dir.z);
        let mut best: Option<Hit> = None;
        let mut limit = t_max;
        let root = &self.nodes[0];
        let entry = slab(&root.lo, &root.hi, origin, &inv, t_min, limit)?;
        // (node, entry distance); children are visited near to far so that
        // the first hits shrink `limit` and prune the rest.
        let mut stack = [(0usize, 0.0f64); 32];
        stack[0] = (0, entry);
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (index, entry) = stack[top];
            if entry >= limit {
                continue;
            }
            let node = &self.nodes[index];
            if node.count > 0 {
                for &i in &self.order[node.first..node.first + node.count] {
                    if let Some(t) = surfaces[i].intersect(origin, dir, t_min, limit) {
                        limit = t;
                        best = Some(Hit { surface: i, t });
                    }
                }
                continue;
            }
            let (a, b) = (node.first, node.first + 1);
            let ta = slab(&self.nodes[a].lo, &self.nodes[a].hi, origin, &inv, t_min, limit);
            let tb = slab(&self.nodes[b].lo, &self.nodes[b].hi, origin, &inv, t_min, limit);
            let (first, second) = match (ta, tb) {
                (Some(x), Some(y)) if y < x => (Some((b, y)), Some((a, x))),
                (x, y) => (x.map(|t| (a, t)), y.map(|t| (b, t))),
            };
            // Push the far child first so that the near one is popped next.
            for item in [second, first].into_iter().flatten() {
                stack[top] = item;
                top += 1;
            }
        }
        best
    }
}

fn area(lo: &Point3, hi: &Point3) -> f64 {
    let d = hi - lo;
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// Where a ray enters an axis-aligned box within `(t_min, t_max)`, if it does.
fn slab(lo: &Point3, hi: &Point3, origin: &Point3, inv: &Vec3, t_min: f64, t_max: f64) -> Option<f64> {
    let (mut t0, mut t1) = (t_min, t_max);
    for a in 0..3 {
        let mut near = (lo[a] - origin[a]) * inv[a];
        let mut far = (hi[a] - origin[a]) * inv[a];
        if near > far {
            std::mem::swap(&mut near, &mut far);
        }
        // NaN (a zero direction component on the slab boundary) keeps the box.
        if near > t0 {
            t0 = near;
        }
        if far < t1 {
            t1 = far;
        }
        if t0 > t1 {
            return None;
        }
    }
    Some(t0)
}
