//! The command-line tests: one test binary, one module per subcommand, sharing `common`.

mod common;
mod docs;
mod eval;
mod feedback;
mod hardening;
mod normals;
mod reconstruct;
mod render;
mod slabs;
mod trim;
