//! Cross-process integration tests live in `tests/`; this library only locates the built binaries.
