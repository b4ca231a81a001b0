//! The `terrain` command line.

fn main() {}
