//! 1-D B-spline machinery (ALGORITHM.md §5): folded B-splines on [0, 1] for each boundary
//! type, their values, exact 1-D integral tables and the two-scale (prolongation) relation.
//! (Being implemented; the signatures below are the contract used by the rest of the crate.)

/// Boundary condition on the faces of the unit cube (ALGORITHM.md §5.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Boundary {
    /// No condition: functions are cut off at the cube, index range extended.
    Free,
    /// Zero normal derivative: functions folded with even reflections (default).
    #[default]
    Neumann,
    /// Zero value: functions folded with odd reflections.
    Dirichlet,
}

impl Boundary {
    /// The boundary type of derivatives of functions of this type
    /// (Neumann ↔ Dirichlet, free stays free). The vector field V uses it.
    pub fn derivative(self) -> Boundary {
        match self {
            Boundary::Free => Boundary::Free,
            Boundary::Neumann => Boundary::Dirichlet,
            Boundary::Dirichlet => Boundary::Neumann,
        }
    }
}

/// A 1-D B-spline basis: degree (1 or 2) and boundary type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Basis {
    /// Degree, 1 or 2.
    pub degree: u8,
    /// Boundary type.
    pub boundary: Boundary,
}

impl Basis {
    /// A basis of the given degree and boundary type.
    pub const fn new(degree: u8, boundary: Boundary) -> Self {
        Self { degree, boundary }
    }

    /// Inclusive range `(lo, hi)` of the function indices at `depth` (ALGORITHM.md §5.2).
    pub fn index_range(self, depth: u32) -> (i64, i64) {
        let _ = depth;
        unimplemented!()
    }

    /// Value at `x ∈ [0, 1]` of the folded function `(depth, i)`; 0 outside its support.
    pub fn value(self, depth: u32, i: i64, x: f64) -> f64 {
        let _ = (depth, i, x);
        unimplemented!()
    }

    /// Derivative (with respect to x in unit-cube units) of the folded function `(depth, i)`.
    pub fn derivative(self, depth: u32, i: i64, x: f64) -> f64 {
        let _ = (depth, i, x);
        unimplemented!()
    }

    /// The `degree + 1` functions that can be non-zero at `x ∈ [0, 1]`.
    pub fn window(self, depth: u32, x: f64) -> Window {
        let _ = (depth, x);
        unimplemented!()
    }

    /// Two-scale relation (ALGORITHM.md §5.3): writes the `(child index, weight)` pairs with
    /// `B_{depth,i} = Σ weight · B_{depth+1,child}` into `out` (in-range children only, boundary
    /// folding applied) and returns how many were written.
    pub fn children(self, depth: u32, i: i64, out: &mut [(i64, f64); 4]) -> usize {
        let _ = (depth, i, out);
        unimplemented!()
    }
}

/// Values and derivatives of the functions that can be non-zero at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Index of the first function; the others follow consecutively.
    pub first: i64,
    /// Values of functions `first ..= first + degree` (0 for indices out of range).
    pub values: [f64; 3],
    /// Derivatives of the same functions.
    pub derivs: [f64; 3],
}

/// What a [`Table1D`] integrates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Integrand {
    /// ∫ B_a(x) B_b(x) dx
    ValueValue,
    /// ∫ B_a'(x) B_b'(x) dx
    DerivDeriv,
    /// ∫ B_a'(x) B_b(x) dx (derivative on the first function)
    DerivValue,
}

/// 1-D integrals over [0, 1] between every function `i` of a basis at one depth and the
/// functions `j` of a second basis at the same depth or one depth coarser.
#[derive(Debug, Clone)]
pub struct Table1D {
    _private: (),
}

impl Table1D {
    /// Radius of the offset window: offsets run over `-RADIUS..=RADIUS`.
    pub const RADIUS: i64 = 2;

    /// The integral for first-basis index `i` and offset `off`; the offset is `j − i` for a
    /// same-depth table and `j − (i >> 1)` (floor division) for a parent table. Zero for
    /// indices outside the ranges.
    pub fn get(&self, i: i64, off: i64) -> f64 {
        let _ = (i, off);
        unimplemented!()
    }
}

/// Builds the table of integrals over [0, 1] between basis `a` at `depth` (index `i`) and basis
/// `b` at `depth` (or at `depth − 1` when `b_coarser`), for every `i` in `a`'s index range.
pub fn table(a: Basis, b: Basis, depth: u32, b_coarser: bool, integrand: Integrand) -> Table1D {
    let _ = (a, b, depth, b_coarser, integrand);
    unimplemented!()
}
