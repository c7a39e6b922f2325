//! No code. The CLI and the Python bindings depend on this crate so that every build command
//! resolves the same features for the dependencies they share (see its `Cargo.toml`), and the
//! workspace is compiled once for both.
