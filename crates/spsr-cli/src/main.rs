//! The `spsr` command line. (Being implemented.)
fn main() {}
