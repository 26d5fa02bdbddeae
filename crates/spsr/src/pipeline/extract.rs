//! Stage 8 (ALGORITHM.md §9): the iso-surface of χ at γ, extracted block by block from the
//! octree's leaves, with the per-vertex values that need χ, the tree or the density
//! (attributes, density, normals), then mapped back to the input's frame.

use rayon::prelude::*;

use super::Implicit;
use crate::attributes::Attribute;
use crate::bounds::CellBounds;
use crate::evaluate::{CornerField, Evaluator};
use crate::extract::{extract_blocks, Blocks, Cells, ExtractOptions};
use crate::octree::{
    func_index, neighbor_in, neighbor_in_row, window_index, Octree, DEPTH_OFFSET, NONE,
};
use crate::{Mesh, Params, Result};

/// Extracts the mesh of the implicit function (stage 8). Without attributes, the tree and the
/// solution are released before the vertices are numbered.
/// With `keep`, the implicit function is handed back for evaluation at other points instead
/// of being released before the mesh is assembled.
pub(crate) fn extract(
    implicit: Implicit,
    params: &Params,
    keep: bool,
) -> Result<(Mesh, Option<Implicit>)> {
    let Implicit {
        tree,
        solution,
        fem,
        density,
        iso,
        frame,
        data,
        attribute_types,
    } = implicit;
    let eval = Evaluator::new(&tree, fem, &solution);
    let bounds = CellBounds::new(&tree, fem, &solution, iso);
    let cells = TreeCells::new(&tree, params.base_depth(), bounds.as_ref());
    let field = CornerField::new(&eval, cells.max_depth);
    let options = ExtractOptions {
        linear_fit: params.linear_fit,
        normals: params.normals,
    };
    let blocks = extract_blocks(&cells, &field, iso, &options)?;
    drop(cells);
    drop(bounds);
    let (mut mesh, kept) = match (data, keep) {
        (Some(data), _) => {
            // Per-vertex values that need the tree: computed before it goes.
            let mut mesh = blocks.assemble()?;
            mesh.attributes = interpolate_attributes(&mesh, &data, &tree, &attribute_types);
            (mesh, keep.then_some((tree, solution)))
        }
        (None, true) => (blocks.assemble()?, Some((tree, solution))),
        (None, false) => {
            drop(solution);
            drop(tree);
            (blocks.assemble()?, None)
        }
    };
    if let (true, Some(density)) = (params.density, &density) {
        mesh.density = Some(
            mesh.vertices
                .par_iter()
                .map(|p| density.query(*p).depth as f32)
                .collect(),
        );
    }
    for p in &mut mesh.vertices {
        *p = frame.to_world(*p);
    }
    let kept = kept.map(|(tree, solution)| Implicit {
        tree,
        solution,
        fem,
        density,
        iso,
        frame,
        data: None,
        attribute_types: Vec::new(),
    });
    Ok((mesh, kept))
}

/// A slab's share of the extraction (ALGORITHM.md §9; `crate::slabs`): the blocks of unit
/// depth `block_depth` whose x index lies in `columns`, polygonised at `iso`. The blocks of all
/// slabs, put together with [`Blocks::concat`], assemble into one mesh, its vertices on the
/// slabs' shared faces numbered once (they are keyed by their finest edge).
pub(crate) fn slab_blocks(
    tree: &Octree,
    fem: crate::bspline::Basis,
    solution: &crate::solver::Solution,
    iso: f64,
    params: &Params,
    block_depth: u32,
    columns: std::ops::Range<i64>,
) -> Result<Blocks> {
    let eval = Evaluator::new(tree, fem, solution);
    let bounds = CellBounds::new(tree, fem, solution, iso);
    let mut cells = TreeCells::columns(tree, block_depth, columns, bounds.as_ref());
    // Edge keys in units of the asked depth, whatever depth the slab's tree reaches: the
    // slabs' keys must agree on the faces they share (and a sparse cloud's tree may stop
    // short of the asked depth, in some slabs or all). Scaling by a power of two moves no
    // vertex.
    cells.max_depth = cells.max_depth.max(params.depth);
    let field = CornerField::new(&eval, cells.max_depth);
    let options = ExtractOptions {
        linear_fit: params.linear_fit,
        normals: params.normals,
    };
    extract_blocks(&cells, &field, iso, &options)
}

/// Each attribute at each vertex, from the data summed up the tree.
fn interpolate_attributes(
    mesh: &Mesh,
    data: &crate::data::DataField,
    tree: &Octree,
    types: &[Attribute],
) -> Vec<Attribute> {
    let k = data.channels();
    let mut values = vec![0.0f64; mesh.vertices.len() * k];
    values
        .par_chunks_mut(k)
        .zip(&mesh.vertices)
        .for_each(|(out, p)| data.eval(tree, *p, out));
    types
        .iter()
        .enumerate()
        .map(|(c, a)| {
            Attribute::new(
                a.name.clone(),
                a.data
                    .like_from_f64(values.iter().skip(c).step_by(k).copied()),
            )
        })
        .collect()
}

/// The octree's leaves inside the unit cube, as extraction sees them. Blocks are the cells of
/// a depth at most the base depth (complete, so every leaf lies in one), chosen so that a
/// block spans about 32 finest cells per axis. With `bounds`, the subtrees where χ cannot
/// reach the iso-value ([`CellBounds`]) are left out: their leaves would make no polygon.
struct TreeCells<'a> {
    tree: &'a Octree,
    max_depth: u32,
    block_level: u32,
    blocks: Vec<u32>,
    bounds: Option<&'a CellBounds<'a>>,
}

impl<'a> TreeCells<'a> {
    /// `base_depth`: a unit depth down to which the tree is complete.
    fn new(tree: &'a Octree, base_depth: u32, bounds: Option<&'a CellBounds<'a>>) -> Self {
        let max_depth = tree.depth_count() - 1 - DEPTH_OFFSET;
        Self::columns(
            tree,
            max_depth.saturating_sub(5).min(base_depth),
            0..i64::MAX,
            bounds,
        )
    }

    /// The blocks of unit depth `block_depth` (at most the complete base depth) whose x index
    /// lies in `columns`: a slab's share of the extraction.
    fn columns(
        tree: &'a Octree,
        block_depth: u32,
        columns: std::ops::Range<i64>,
        bounds: Option<&'a CellBounds<'a>>,
    ) -> Self {
        let max_depth = tree.depth_count() - 1 - DEPTH_OFFSET;
        let block_level = block_depth + DEPTH_OFFSET;
        let d = block_depth;
        let level = &tree.levels[block_level as usize];
        let n = 1i64 << d;
        let blocks = (0..level.len() as u32)
            .filter(|&b| {
                let i = func_index(level.key(b), d);
                i.iter().all(|&c| (0..n).contains(&c)) && columns.contains(&i[0])
            })
            .collect();
        Self {
            tree,
            max_depth,
            block_level,
            blocks,
            bounds,
        }
    }
}

impl Cells for TreeCells<'_> {
    type Handle = (u32, u32);

    fn max_depth(&self) -> u32 {
        self.max_depth
    }

    fn block_count(&self) -> usize {
        self.blocks.len()
    }

    fn for_each_leaf(&self, b: usize, f: &mut dyn FnMut((u32, u32), u32, [u32; 3])) {
        // Depth-first, children in order: Morton order within the block.
        let mut stack = vec![(self.block_level, self.blocks[b])];
        while let Some((t, n)) = stack.pop() {
            if self.bounds.is_some_and(|b| b.one_side(t, n)) {
                continue;
            }
            let level = &self.tree.levels[t as usize];
            let c = level.child(n);
            if c == NONE {
                let d = t - DEPTH_OFFSET;
                let o = func_index(level.key(n), d);
                f((t, n), d, [o[0] as u32, o[1] as u32, o[2] as u32]);
            } else {
                for k in (0..8).rev() {
                    stack.push((t + 1, c * 8 + k));
                }
            }
        }
    }

    fn refined_around(&self, (t, n): (u32, u32), _depth: u32, _offset: [u32; 3]) -> u32 {
        let level = &self.tree.levels[t as usize];
        let next = self.tree.levels.get(t as usize + 1);
        let mut mask = 0;
        if next.is_none() || !level.row_has_children(n >> 3) {
            return 0;
        }
        let row = level.brood_row(n >> 3);
        for s in 0..27u32 {
            let o = [
                i64::from(s % 3) - 1,
                i64::from((s / 3) % 3) - 1,
                i64::from(s / 9) - 1,
            ];
            let m = neighbor_in_row(&row, n, window_index(o));
            if m != NONE && level.child(m) != NONE {
                mask |= 1 << s;
            }
        }
        mask
    }

    fn refined(&self, (t, n): (u32, u32), depth: u32, offset: [u32; 3]) -> bool {
        let d = t - DEPTH_OFFSET;
        let levels = &self.tree.levels;
        let own = func_index(levels[t as usize].key(n), d);
        // The cell's ancestor at the leaf's depth is a neighbour of the leaf.
        let shift = depth.saturating_sub(d);
        let rel: [i64; 3] = std::array::from_fn(|a| i64::from(offset[a] >> shift) - own[a]);
        let (mut tt, mut m) = if depth >= d && rel.iter().all(|&r| (-2..=2).contains(&r)) {
            (t, neighbor_in(&levels[t as usize], n, window_index(rel)))
        } else {
            // Not expected (the cell touches the leaf and is no coarser); look it up from the
            // root.
            let key: [u64; 3] = std::array::from_fn(|a| u64::from(offset[a]) + (1u64 << depth));
            let tk = depth + DEPTH_OFFSET;
            let (reached, node) = self.tree.descend(key, tk, tk);
            if reached != tk {
                return false;
            }
            (tk, node)
        };
        if m == NONE {
            return false;
        }
        while tt < depth + DEPTH_OFFSET {
            let b = levels[tt as usize].child(m);
            if b == NONE {
                return false;
            }
            tt += 1;
            let s = depth + DEPTH_OFFSET - tt;
            let bits = ((offset[0] >> s) & 1)
                | (((offset[1] >> s) & 1) << 1)
                | (((offset[2] >> s) & 1) << 2);
            m = b * 8 + bits;
        }
        levels[tt as usize].child(m) != NONE
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extract::Field;
    use crate::pipeline::tests::sphere;
    use crate::pipeline::{solve_implicit, Input, Run};
    use crate::{Boundary, PointCloud};

    /// The test clouds: a sphere, the same with its points pushed in and out by up to 2 % of
    /// the radius (a bumpy χ), and its upper half (an open surface that meets the cube's faces).
    fn clouds() -> Vec<(&'static str, PointCloud)> {
        let round = sphere(20_000, [0.1, -0.2, 0.3], 1.0);
        let bumpy = {
            let pos = round
                .positions
                .iter()
                .zip(&round.normals)
                .enumerate()
                .map(|(i, (p, n))| {
                    let s = 0.02 * ((i as f64 * 0.618_033_988_75).fract() * 2.0 - 1.0);
                    [0, 1, 2].map(|a| p[a] + s * n[a])
                })
                .collect();
            PointCloud::new(pos, round.normals.clone()).unwrap()
        };
        let upper = {
            let (pos, nor): (Vec<_>, Vec<_>) = round
                .positions
                .iter()
                .zip(&round.normals)
                .filter(|(p, _)| p[2] > 0.3)
                .map(|(p, n)| (*p, *n))
                .unzip();
            PointCloud::new(pos, nor).unwrap()
        };
        vec![
            ("sphere", round),
            ("bumpy sphere", bumpy),
            ("upper half", upper),
        ]
    }

    fn solved(cloud: &PointCloud, boundary: Boundary) -> Implicit {
        let params = Params {
            depth: 6,
            boundary,
            ..Params::default()
        };
        solve_implicit(Input::Borrowed(cloud), &params, &mut Run::new(&|_| {}))
            .unwrap()
            .0
    }

    /// Every leaf under a node that [`CellBounds::one_side`] passes over has χ − γ of one
    /// strict sign class (all above γ, or all at most γ) at its corners, as extraction
    /// evaluates them; and the bounds do pass over many of the leaves (45 % on the sphere).
    #[test]
    fn the_skipped_subtrees_hold_no_sign_change() {
        for (name, cloud) in clouds() {
            for boundary in [Boundary::Neumann, Boundary::Dirichlet] {
                let imp = solved(&cloud, boundary);
                let bounds = CellBounds::new(&imp.tree, imp.fem, &imp.solution, imp.iso).unwrap();
                let all = TreeCells::new(&imp.tree, 3, None);
                let eval = Evaluator::new(&imp.tree, imp.fem, &imp.solution);
                let field = CornerField::new(&eval, all.max_depth);
                let (mut leaves, mut skipped) = (0usize, 0usize);
                for b in 0..all.block_count() {
                    all.for_each_leaf(b, &mut |(t, n), depth, offset| {
                        leaves += 1;
                        // The leaf's ancestors (itself included) that the bounds pass over.
                        let (mut tt, mut m) = (t, n);
                        let mut over = None;
                        while tt >= all.block_level {
                            if bounds.one_side(tt, m) {
                                over = Some((tt, m));
                            }
                            if tt == all.block_level {
                                break;
                            }
                            m = imp.tree.parent(tt, m);
                            tt -= 1;
                        }
                        let Some(node) = over else { return };
                        skipped += 1;
                        let s = 1u32 << (all.max_depth - depth);
                        let inside: Vec<bool> = (0..8u32)
                            .map(|c| {
                                let p = std::array::from_fn(|a| (offset[a] + (c >> a & 1)) * s);
                                field.value(p, (t, n)) > imp.iso
                            })
                            .collect();
                        assert!(
                            inside.iter().all(|&i| i == inside[0]),
                            "{name}, {boundary:?}: a leaf under the skipped node {node:?} \
                             has corners on both sides"
                        );
                    });
                }
                assert!(
                    skipped * 3 > leaves,
                    "{name}, {boundary:?}: only {skipped} of {leaves} leaves skipped"
                );
            }
        }
    }

    /// Skipping the subtrees leaves the mesh as it was, bit for bit.
    #[test]
    fn skipping_subtrees_keeps_the_mesh_bits() {
        for (name, cloud) in clouds() {
            for boundary in [Boundary::Neumann, Boundary::Dirichlet] {
                let imp = solved(&cloud, boundary);
                let eval = Evaluator::new(&imp.tree, imp.fem, &imp.solution);
                let bounds = CellBounds::new(&imp.tree, imp.fem, &imp.solution, imp.iso);
                let mesh = |bounds: Option<&CellBounds>| {
                    let cells = TreeCells::new(&imp.tree, 3, bounds);
                    let field = CornerField::new(&eval, cells.max_depth);
                    let opts = ExtractOptions {
                        linear_fit: false,
                        normals: true,
                    };
                    extract_blocks(&cells, &field, imp.iso, &opts)
                        .unwrap()
                        .assemble()
                        .unwrap()
                };
                let (all, skipping) = (mesh(None), mesh(bounds.as_ref()));
                assert!(!all.triangles.is_empty(), "{name}, {boundary:?}: no mesh");
                assert_eq!(all.vertices, skipping.vertices, "{name}, {boundary:?}");
                assert_eq!(all.triangles, skipping.triangles, "{name}, {boundary:?}");
                assert_eq!(all.normals, skipping.normals, "{name}, {boundary:?}");
            }
        }
    }
}
