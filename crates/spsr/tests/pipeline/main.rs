//! The integration tests of the reconstruction pipeline, one module per subject, in one test
//! binary (each binary links the whole library, so fewer binaries build faster).

#[path = "../common/mod.rs"]
mod common;

mod attributes;
mod diagnosis;
mod grid;
mod hostile;
mod noise;
mod normals;
mod properties;
mod reconstruct;
mod resolution;
mod slabs;
mod trim;
