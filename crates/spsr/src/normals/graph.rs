//! The neighbour graph of a cloud and its minimum spanning forest (Kruskal's algorithm on a
//! parallel sort, with a union–find).

use rayon::prelude::*;

use super::knn::Neighbours;

/// The undirected edges of the symmetric k-nearest-neighbour graph, as `(i, j)` with
/// `i < j`, each once, sorted.
pub(crate) fn symmetric_edges(nb: &Neighbours) -> Vec<(u32, u32)> {
    let n = nb.radius.len();
    let mut keys: Vec<u64> = (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            nb.of(i).filter(move |&j| j != i).map(move |j| {
                let (a, b) = if i < j { (i, j) } else { (j, i) };
                ((a as u64) << 32) | b as u64
            })
        })
        .collect();
    keys.par_sort_unstable();
    keys.dedup();
    keys.into_par_iter()
        .map(|k| ((k >> 32) as u32, k as u32))
        .collect()
}

/// Disjoint sets over `0..n` with path halving and union by size.
pub(crate) struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    pub fn new(n: usize) -> Self {
        Self {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }

    pub fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let g = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = g;
            x = g;
        }
        x
    }

    /// Joins the sets of `a` and `b`; false when they were already one.
    pub fn union(&mut self, a: u32, b: u32) -> bool {
        let (mut a, mut b) = (self.find(a), self.find(b));
        if a == b {
            return false;
        }
        if self.size[a as usize] < self.size[b as usize] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b as usize] = a;
        self.size[a as usize] += self.size[b as usize];
        true
    }
}

/// The minimum spanning forest of `n` vertices and weighted `edges` (weights ≥ 0, not NaN;
/// fewer than 2³² edges), by Kruskal's algorithm. Ties are broken by the edges' order in
/// `edges`, so the forest is unique and does not depend on the thread count. Returns the
/// indices of the chosen edges.
pub(crate) fn spanning_forest(n: usize, edges: &[(u32, u32)], weights: &[f32]) -> Vec<u32> {
    // One 64-bit key per edge: the weight's bits (non-negative floats order like their bit
    // patterns), then the edge's index.
    let mut order: Vec<u64> = weights
        .par_iter()
        .enumerate()
        .map(|(e, w)| (u64::from(w.max(0.0).to_bits()) << 32) | e as u64)
        .collect();
    order.par_sort_unstable();
    let mut sets = UnionFind::new(n);
    let mut chosen = Vec::with_capacity(n.saturating_sub(1));
    for key in order {
        let e = key as u32;
        let (a, b) = edges[e as usize];
        if sets.union(a, b) {
            chosen.push(e);
            if chosen.len() + 1 == n {
                break;
            }
        }
    }
    chosen
}

/// Adjacency lists (compressed rows) of the forest made of `chosen` edges.
pub(crate) struct Forest {
    pub start: Vec<u32>,
    pub adj: Vec<u32>,
}

impl Forest {
    pub fn new(n: usize, edges: &[(u32, u32)], chosen: &[u32]) -> Self {
        let mut start = vec![0u32; n + 1];
        for &e in chosen {
            let (a, b) = edges[e as usize];
            start[a as usize + 1] += 1;
            start[b as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut adj = vec![0u32; 2 * chosen.len()];
        for &e in chosen {
            let (a, b) = edges[e as usize];
            adj[fill[a as usize] as usize] = b;
            fill[a as usize] += 1;
            adj[fill[b as usize] as usize] = a;
            fill[b as usize] += 1;
        }
        Self { start, adj }
    }

    pub fn of(&self, i: usize) -> &[u32] {
        &self.adj[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kruskal_finds_the_minimum_forest_with_ties_broken_by_edge_order() {
        // Two components: a square 0-1-2-3 with a diagonal, and the edge 4-5.
        let edges = [(0, 1), (1, 2), (2, 3), (0, 3), (0, 2), (4, 5)];
        let weights = [0.5f32, 0.1, 0.5, 0.2, 0.1, 0.0];
        let mut chosen = spanning_forest(6, &edges, &weights);
        chosen.sort();
        // 5 (w 0), 1 and 4 (w 0.1), 3 (w 0.2); then every vertex is joined.
        assert_eq!(chosen, vec![1, 3, 4, 5]);
        let f = Forest::new(6, &edges, &chosen);
        assert_eq!(f.of(0), &[3, 2]);
        assert_eq!(f.of(5), &[4]);
    }

    #[test]
    fn union_find_joins_sets() {
        let mut s = UnionFind::new(5);
        assert!(s.union(0, 1));
        assert!(s.union(3, 4));
        assert!(!s.union(1, 0));
        assert!(s.union(1, 4));
        assert_eq!(s.find(0), s.find(3));
        assert_ne!(s.find(2), s.find(0));
    }
}
