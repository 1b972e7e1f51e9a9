//! A small static 3-d tree in f64 for nearest-neighbour and k-nearest-neighbour queries (outlier removal,
//! cloud comparison).
//!
//! Written here rather than taken from a crate: it needs exact f64 distances (so analytic tests are exact),
//! must accept any number of points sharing a coordinate (grid-like and flat clouds; kiddo's mutable tree
//! panics when a bucket overflows with equal values), and is ~150 lines. Median splits on the axis of largest
//! extent, leaves of up to 16 points; ties in distance go to the lower point index, so results are deterministic.

const LEAF: usize = 16;

enum Node {
    Leaf { start: u32, end: u32 },
    Split { axis: u8, value: f64, left: u32, right: u32 },
}

/// A k-d tree over a copy of the points.
pub struct KdTree {
    /// Input points (only during the build).
    points: Vec<[f64; 3]>,
    /// Point indices, permuted so every leaf is a contiguous range.
    order: Vec<u32>,
    /// `points[order[k]]`: leaf points contiguous in memory (cache-friendly scans).
    sorted: Vec<[f64; 3]>,
    nodes: Vec<Node>,
}

/// Squared Euclidean distance.
pub fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

impl KdTree {
    /// Builds the tree (O(n log n)). At most `u32::MAX` points.
    pub fn new(points: &[[f64; 3]]) -> KdTree {
        let mut t = KdTree {
            points: points.to_vec(),
            order: (0..points.len() as u32).collect(),
            sorted: Vec::new(),
            nodes: Vec::new(),
        };
        if !points.is_empty() {
            t.build(0, points.len());
        }
        t.sorted = t.order.iter().map(|&i| t.points[i as usize]).collect();
        t.points = Vec::new();
        t
    }

    pub fn len(&self) -> usize {
        self.order.len()
    }

    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// The point indices in leaf order (spatially coherent): querying in this order is cache-friendly.
    pub fn leaf_order(&self) -> &[u32] {
        &self.order
    }

    fn build(&mut self, start: usize, end: usize) -> u32 {
        let id = self.nodes.len() as u32;
        if end - start <= LEAF {
            self.nodes.push(Node::Leaf { start: start as u32, end: end as u32 });
            return id;
        }
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for &i in &self.order[start..end] {
            let p = &self.points[i as usize];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        if hi[axis].partial_cmp(&lo[axis]) != Some(std::cmp::Ordering::Greater) {
            // All points equal (or non-finite extents): one leaf, however large.
            self.nodes.push(Node::Leaf { start: start as u32, end: end as u32 });
            return id;
        }
        let mid = (start + end) / 2;
        let pts = &self.points;
        self.order[start..end]
            .select_nth_unstable_by(mid - start, |&a, &b| pts[a as usize][axis].total_cmp(&pts[b as usize][axis]));
        let value = self.points[self.order[mid] as usize][axis];
        self.nodes.push(Node::Split { axis: axis as u8, value, left: 0, right: 0 });
        let left = self.build(start, mid);
        let right = self.build(mid, end);
        self.nodes[id as usize] = Node::Split { axis: axis as u8, value, left, right };
        id
    }

    /// The nearest point to `q`: (index, squared distance). `None` for an empty tree.
    pub fn nearest(&self, q: &[f64; 3]) -> Option<(usize, f64)> {
        if self.is_empty() {
            return None;
        }
        let mut best = (usize::MAX, f64::INFINITY);
        self.nearest_in(0, q, &mut best);
        Some(best)
    }

    fn nearest_in(&self, node: u32, q: &[f64; 3], best: &mut (usize, f64)) {
        match self.nodes[node as usize] {
            Node::Leaf { start, end } => {
                let (s, e) = (start as usize, end as usize);
                for (&i, p) in self.order[s..e].iter().zip(&self.sorted[s..e]) {
                    let d = dist2(q, p);
                    if d < best.1 || (d == best.1 && (i as usize) < best.0) {
                        *best = (i as usize, d);
                    }
                }
            }
            Node::Split { axis, value, left, right } => {
                let diff = q[axis as usize] - value;
                let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
                self.nearest_in(near, q, best);
                if diff * diff <= best.1 {
                    self.nearest_in(far, q, best);
                }
            }
        }
    }

    /// The `k` nearest points to `q` (the point itself included when it is in the tree), nearest first:
    /// (index, squared distance).
    pub fn knn(&self, q: &[f64; 3], k: usize) -> Vec<(usize, f64)> {
        let mut heap: Vec<(usize, f64)> = Vec::with_capacity(k + 1);
        if k > 0 && !self.is_empty() {
            self.knn_in(0, q, k, &mut heap);
        }
        heap
    }

    fn worse(a: &(usize, f64), b: &(usize, f64)) -> bool {
        a.1 > b.1 || (a.1 == b.1 && a.0 > b.0)
    }

    fn knn_in(&self, node: u32, q: &[f64; 3], k: usize, heap: &mut Vec<(usize, f64)>) {
        match self.nodes[node as usize] {
            Node::Leaf { start, end } => {
                let (s, e) = (start as usize, end as usize);
                for (&i, p) in self.order[s..e].iter().zip(&self.sorted[s..e]) {
                    let cand = (i as usize, dist2(q, p));
                    if heap.len() == k && !Self::worse(&heap[k - 1], &cand) {
                        continue;
                    }
                    // Sorted insertion (k is small).
                    let pos = heap.iter().position(|h| Self::worse(h, &cand)).unwrap_or(heap.len());
                    heap.insert(pos, cand);
                    heap.truncate(k);
                }
            }
            Node::Split { axis, value, left, right } => {
                let diff = q[axis as usize] - value;
                let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
                self.knn_in(near, q, k, heap);
                if heap.len() < k || diff * diff <= heap[heap.len() - 1].1 {
                    self.knn_in(far, q, k, heap);
                }
            }
        }
    }
}
