//! revisit-colmap (see ARCHITECTURE.md).
