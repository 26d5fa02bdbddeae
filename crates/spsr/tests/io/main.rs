//! The integration tests of reading, writing and evaluating files and meshes, one module per
//! subject, in one test binary (each binary links the whole library, so fewer binaries build
//! faster).

#[path = "../common/mod.rs"]
mod common;

mod eval;
mod formats;
mod fuzz_regressions;
mod io_roundtrip;
mod mesh_formats;
