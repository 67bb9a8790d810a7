//! revisit-features (see ARCHITECTURE.md).
